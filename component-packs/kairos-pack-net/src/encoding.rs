//! What a socket component carries: raw bytes (third-party devices and programs) or whole Kairos samples
//! (another runtime). Both ends of the latter live here, shared by the UDP and TCP components: the sender
//! encodes into one reused buffer; the receiver decodes, checks the type, counts the link's gaps and
//! reordering, and writes with both times kept.

use std::collections::BTreeMap;

use kairos_sdk::descriptor::Property;
use kairos_sdk::{
    ComponentError, ComponentResult, Context, DataType, DescribeError, Payload, Sample, Throttle, TypeFilter,
    Value,
};

use crate::framing;
use kairos_sample_frame::{self as sample_frame, SequenceTracker};

/// The output of a receiver in Kairos mode.
pub const SAMPLES: &str = "samples";

/// The property choosing what a socket component carries.
pub fn property() -> Property {
    Property::choice("encoding", &["raw", "kairos"], "raw").doc(
        "raw: bytes as they come, stamped on reception (devices and programs of any kind); kairos: whole \
         samples with both times and their sequence number, in the binary sample frame (another Kairos \
         runtime; see docs/net.md)",
    )
}

/// The property giving the type a Kairos-mode receiver outputs.
pub fn data_type_property() -> Property {
    let names: Vec<&str> = DataType::BUILT_IN.iter().map(DataType::name).collect();
    Property::choice("data_type", &names, "f64").doc(
        "With encoding kairos: the type of the samples the sender sends (others are counted and dropped)",
    )
}

/// Whether `properties` ask for Kairos samples.
pub fn is_kairos(properties: &BTreeMap<String, Value>) -> bool {
    properties.get("encoding").and_then(Value::as_text) == Some("kairos")
}

/// What a sender with `properties` accepts: text or bytes raw, any type as Kairos samples.
pub fn sender_accepts(properties: &BTreeMap<String, Value>) -> TypeFilter {
    if is_kairos(properties) {
        TypeFilter::Any
    } else {
        TypeFilter::OneOf(vec![DataType::Bytes, DataType::Text])
    }
}

/// The bytes a raw-mode sender sends of `payload`.
pub fn raw_bytes(payload: &Payload) -> Result<&[u8], ComponentError> {
    match payload {
        Payload::Bytes(bytes) => Ok(bytes),
        Payload::Text(text) => Ok(text.as_bytes()),
        other => Err(ComponentError::failed(format_args!(
            "expected bytes or text, got {}",
            other.data_type()
        ))),
    }
}

/// The name a sender's samples travel under: the output feeding the component's first input, or the
/// component's input itself when nothing does.
pub fn source_name(ctx: &Context) -> String {
    ctx.inputs()
        .first()
        .and_then(|input| input.source())
        .map_or_else(|| format!("{}.in", ctx.id()), str::to_owned)
}

/// The sending end of a Kairos-sample link: the name its samples travel under, and one frame buffer
/// reused for every sample.
#[derive(Debug)]
pub struct SampleSender {
    output: String,
    frame: Vec<u8>,
}

impl SampleSender {
    /// A sender naming its samples after the output feeding the component's first input (or the
    /// component itself when nothing does).
    pub fn of(ctx: &Context) -> Self {
        SampleSender {
            output: source_name(ctx),
            frame: Vec::new(),
        }
    }

    /// `sample` as one frame, after its length when `length_prefixed` (a stream's framing): the payload's
    /// bytes are copied once, into the buffer the socket sends from.
    pub fn frame(&mut self, sample: &Sample, length_prefixed: bool) -> &[u8] {
        let (head, body) = sample_frame::encode(&self.output, sample);
        self.frame.clear();
        if length_prefixed {
            self.frame
                .extend_from_slice(&framing::length_prefix(head.len() + body.len()));
        }
        self.frame.extend_from_slice(&head);
        self.frame.extend_from_slice(&body);
        &self.frame
    }
}

/// The type a Kairos-mode receiver with `properties` outputs.
pub fn data_type_of(properties: &BTreeMap<String, Value>) -> Result<DataType, DescribeError> {
    let name = properties
        .get("data_type")
        .and_then(Value::as_text)
        .unwrap_or("f64");
    let data_type = DataType::from_name(name);
    if matches!(data_type, DataType::Custom(_)) {
        return Err(
            DescribeError::property("data_type", format!("{name:?} is not a data type"))
                .with_suggestion("choose one of f64, image, point_cloud, imu, gnss_fix, ..."),
        );
    }
    Ok(data_type)
}

/// The receiving end of a Kairos-sample link: one sequence count per sender.
#[derive(Debug, Default)]
pub struct SampleReceiver {
    expected: Option<DataType>,
    /// Per sender: its address, its output's name, and what its sequence numbers said. A few senders at
    /// most, so a list looked up without building a key per sample.
    trackers: Vec<(String, String, SequenceTracker)>,
    transit: Transit,
    /// The sequence number of the last sample written.
    newest: Option<u64>,
    received: u64,
    malformed: u64,
    wrong_type: u64,
    warnings: Throttle,
}

impl SampleReceiver {
    /// A receiver outputting samples of the type the component's properties give.
    pub fn of(ctx: &Context) -> Result<Self, ComponentError> {
        let expected = data_type_of(ctx.properties()).map_err(|e| ComponentError::failed(e.message))?;
        Ok(SampleReceiver {
            expected: Some(expected),
            ..SampleReceiver::default()
        })
    }

    /// A receiver outputting samples of `data_type` (any, custom types included).
    pub fn expecting(data_type: DataType) -> Self {
        SampleReceiver {
            expected: Some(data_type),
            ..SampleReceiver::default()
        }
    }

    /// Takes one frame from `peer`: writes its sample on [`SAMPLES`] when it decodes, has the expected type
    /// and comes in order; counts it otherwise.
    pub fn take(&mut self, frame: &[u8], peer: &str, ctx: &mut Context) -> ComponentResult {
        self.take_decoded(sample_frame::decode(frame), peer, ctx)
    }

    /// [`Self::take`] for a frame that arrived in pieces (a large one, fragmented on its way): an image's
    /// pixels go from the pieces straight into the shared pixel pool, without first joining them.
    pub fn take_pieces(&mut self, pieces: &[&[u8]], peer: &str, ctx: &mut Context) -> ComponentResult {
        self.take_decoded(sample_frame::decode_pieces(pieces), peer, ctx)
    }

    fn take_decoded(
        &mut self,
        decoded: Result<sample_frame::Received, sample_frame::FrameDecodeError>,
        peer: &str,
        ctx: &mut Context,
    ) -> ComponentResult {
        let received = match decoded {
            Ok(received) => received,
            Err(reason) => {
                self.malformed += 1;
                let count = self.malformed;
                self.warnings
                    .warn(|| format!("{peer}: not a Kairos sample frame ({reason}); {count} in all"));
                return Ok(());
            }
        };
        let Sample {
            payload,
            timestamp,
            time_of_issue,
            ..
        } = received.sample;
        if self
            .expected
            .as_ref()
            .is_some_and(|expected| !payload.is_of(expected))
        {
            self.wrong_type += 1;
            let (got, expected) = (
                payload.data_type(),
                self.expected.clone().unwrap_or(DataType::Bytes),
            );
            self.warnings.warn(|| {
                format!(
                    "{peer} sends {got} samples of {}; this receiver's data_type is {expected}: dropped",
                    received.output
                )
            });
            return Ok(());
        }
        let known = self
            .trackers
            .iter()
            .position(|(from, output, _)| from == peer && *output == received.output);
        let index = known.unwrap_or_else(|| {
            self.trackers.push((
                peer.to_owned(),
                received.output.clone(),
                SequenceTracker::default(),
            ));
            self.trackers.len() - 1
        });
        let Some((_, _, tracker)) = self.trackers.get_mut(index) else {
            return Ok(());
        };
        if tracker.take(received.sequence) {
            self.received += 1;
            self.newest = Some(received.sequence);
            self.transit.record(ctx.now().nanos_since(time_of_issue));
            ctx.write_replayed(SAMPLES, payload, timestamp, time_of_issue)?;
        }
        Ok(())
    }

    /// The sequence number of the last sample written, as its sender numbered it.
    pub fn newest(&self) -> Option<u64> {
        self.newest
    }

    /// The link's figures for the component's status.
    pub fn status(&self) -> serde_json::Value {
        let sum = |field: fn(&SequenceTracker) -> u64| {
            self.trackers
                .iter()
                .map(|(_, _, tracker)| field(tracker))
                .sum::<u64>()
        };
        let (transit_p50_ns, transit_max_ns) = self.transit.figures().unzip();
        serde_json::json!({
            "transit_p50_ns": transit_p50_ns,
            "transit_max_ns": transit_max_ns,
            "received": self.received,
            "lost": sum(|t| t.lost),
            "reordered": sum(|t| t.reordered),
            "duplicates": sum(|t| t.duplicates),
            "restarts": sum(|t| t.restarts),
            "malformed": self.malformed,
            "wrong_type": self.wrong_type,
            "senders": self.trackers.len(),
        })
    }
}

/// How long the last samples were in transit: this machine's clock at their arrival less their time of
/// issue on the sender's (the same clock across hosts synchronised by Kairos).
#[derive(Debug, Default)]
struct Transit {
    recent: std::collections::VecDeque<i64>,
}

/// The samples the transit figures are taken over.
const TRANSIT_WINDOW: usize = 256;

impl Transit {
    fn record(&mut self, nanos: i64) {
        if self.recent.len() == TRANSIT_WINDOW {
            self.recent.pop_front();
        }
        self.recent.push_back(nanos);
    }

    /// The median and the most, over the last samples; `None` before any.
    fn figures(&self) -> Option<(i64, i64)> {
        let mut sorted: Vec<i64> = self.recent.iter().copied().collect();
        sorted.sort_unstable();
        Some((*sorted.get(sorted.len() / 2)?, *sorted.last()?))
    }
}

/// A receiver component's `status`, with the link's figures when it receives Kairos samples.
pub fn status_with(mut status: serde_json::Value, samples: Option<&SampleReceiver>) -> serde_json::Value {
    if let (Some(status), Some(serde_json::Value::Object(figures))) =
        (status.as_object_mut(), samples.map(SampleReceiver::status))
    {
        status.extend(figures);
    }
    status
}
