//! What a socket component carries: raw bytes (third-party devices and programs) or whole Kairos samples
//! (another runtime), and the receiving side of the latter: decode, check the type, count the link's
//! gaps and reordering, write with both times kept.

use std::collections::BTreeMap;

use kairos_sdk::descriptor::Property;
use kairos_sdk::{
    ComponentError, ComponentResult, Context, DataType, DescribeError, Sample, Throttle, Value,
};

use crate::sample_frame::{self, SequenceTracker};

/// The output of a receiver in Kairos mode.
pub const SAMPLES: &str = "samples";

/// The property choosing what a socket component carries.
pub fn property() -> Property {
    Property::choice("encoding", &["raw", "kairos"], "raw").doc(
        "raw: bytes as they come, stamped on reception (devices and programs of any kind); kairos: whole \
         samples with both times and their sequence number, in the control protocol's frame format \
         (another Kairos runtime)",
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
    trackers: BTreeMap<String, SequenceTracker>,
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

    /// Takes one frame from `peer`: writes its sample on [`SAMPLES`] when it decodes, has the expected type
    /// and comes in order; counts it otherwise.
    pub fn take(&mut self, frame: &[u8], peer: &str, ctx: &mut Context) -> ComponentResult {
        let received = match sample_frame::decode(frame) {
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
        let tracker = self
            .trackers
            .entry(format!("{peer} {}", received.output))
            .or_default();
        if tracker.take(received.sequence) {
            self.received += 1;
            ctx.write_replayed(SAMPLES, payload, timestamp, time_of_issue)?;
        }
        Ok(())
    }

    /// The link's figures for the component's status.
    pub fn status(&self) -> serde_json::Value {
        let sum = |field: fn(&SequenceTracker) -> u64| self.trackers.values().map(field).sum::<u64>();
        serde_json::json!({
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

/// Merges `extra`'s fields into the status object `status`.
pub fn merged(mut status: serde_json::Value, extra: serde_json::Value) -> serde_json::Value {
    if let (Some(status), serde_json::Value::Object(extra)) = (status.as_object_mut(), extra) {
        status.extend(extra);
    }
    status
}
