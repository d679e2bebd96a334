//! `recording.recorder`: writes every sample of its inputs to MCAP, one channel per input.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{
    Component, ComponentError, ComponentInfo, ComponentResult, Context, ReaderPolicy, Sample, TypeFilter,
    Value,
};
use mcap::records::{MessageHeader, Metadata};

use crate::encode::{encode, schema_for};
use crate::timeline::seconds_to_nanos;
pub use crate::timeline::{MARKERS_TOPIC, is_markers_topic};

/// How many inputs a recorder offers.
pub const RECORDER_INPUTS: usize = 8;
const INPUT_NAMES: [&str; RECORDER_INPUTS] = ["in1", "in2", "in3", "in4", "in5", "in6", "in7", "in8"];
/// The input whose samples are markers, after the recorded ones.
const MARK_INPUT: usize = RECORDER_INPUTS;
/// The input whose samples are triggers (pre-trigger mode).
const TRIGGER_INPUT: usize = RECORDER_INPUTS + 1;

fn input_name(index: usize) -> &'static str {
    match index {
        MARK_INPUT => "mark",
        TRIGGER_INPUT => "trigger",
        _ => INPUT_NAMES.get(index).copied().unwrap_or("in"),
    }
}

/// Whether a trigger input's sample is a trigger: any sample but `false` and zero (a threshold's output
/// going low is not an event).
fn is_trigger(payload: &kairos_sdk::Payload) -> bool {
    match payload {
        kairos_sdk::Payload::Bool(on) => *on,
        kairos_sdk::Payload::F64(v) => *v != 0.0,
        kairos_sdk::Payload::I64(v) => *v != 0,
        _ => true,
    }
}
const SPACE_CHECK_PERIOD: Duration = Duration::from_secs(1);
/// The free-space check never runs more often than once per this many bytes written.
const SPACE_CHECK_MIN_BYTES: u64 = 64 * 1024;

struct OpenFile {
    writer: mcap::Writer<BufWriter<File>>,
    path: PathBuf,
    opened: Instant,
    last_chunk: Instant,
    bytes: u64,
    channels: BTreeMap<usize, (u16, u32)>,
    schemas: BTreeMap<String, u16>,
    /// Messages written into this file, per input.
    counts: BTreeMap<usize, u64>,
    /// Pre-trigger mode: per input, the samples the ring pushed out since the previous event's file.
    ring_dropped_before: BTreeMap<usize, u64>,
    /// Written as a rosbag2 recording: ROS 2 messages in CDR, topics named as ROS names them.
    rosbag2: bool,
}

/// After an event could not be written, how long new triggers wait before another file is tried: a
/// trigger storm on a full disk makes one attempt a second, not one per trigger.
const RETRY_EVENTS_AFTER: Duration = Duration::from_secs(1);

/// The recorder component. See [`Recorder::info`].
/// The default chunk size. The MCAP writer holds each chunk's index (about 300 B) until the file closes,
/// for its summary: at a 640×480 camera's 27.6 MB/s, 1 MiB chunks closed 28 times a second and grew the
/// recorder by 19 MB an hour; 16 MiB ones close about twice (once by size, once by `chunk_period_s`). The
/// period still bounds what a crash loses to a second.
const CHUNK_SIZE_KB: i64 = 16 * 1024;

#[derive(Default)]
#[allow(
    clippy::struct_excessive_bools,
    reason = "independent switches: recording, a split asked for, the mode, the mark input's level"
)]
pub struct Recorder {
    file: Option<OpenFile>,
    recording: bool,
    part: u32,
    connected: Vec<usize>,
    scratch: Vec<u8>,
    last_space_check: Option<Instant>,
    /// Bytes written since the last free-space check, and how many may be before the next one.
    written_since_check: u64,
    check_budget: u64,
    split_requested: bool,
    /// When the status was last published, and the files closed so far.
    published: Option<Instant>,
    closed_files: u32,
    /// The last file closed whole, for the studio's Replay.
    last_file: Option<PathBuf>,
    /// Markers written since the start.
    markers: u64,
    /// Pre-trigger mode: the ring, the end of the event being written, and the events so far.
    pre_trigger: bool,
    ring: crate::pretrigger::Ring,
    event_until: Option<kairos_sdk::Timestamp>,
    events: u64,
    last_error: Option<String>,
    /// Pre-trigger mode: events that could not be written, when the next may be tried, the error log's
    /// throttle, and the ring's drops per input when the last event's file opened.
    failures: u64,
    retry_after: Option<Instant>,
    failure_log: kairos_sdk::Throttle,
    ring_dropped_at_event: BTreeMap<usize, u64>,
    /// Whether the last sample on the `mark` input was on (true, non-zero): a marker is written when it
    /// turns on, not for every sample while it stays on.
    mark_was_on: bool,
}

impl std::fmt::Debug for Recorder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recorder")
            .field("recording", &self.recording)
            .field("part", &self.part)
            .finish_non_exhaustive()
    }
}

fn failed(path: &Path, what: &str, error: impl std::fmt::Display) -> ComponentError {
    ComponentError::failed(format_args!("{what} {}: {error}", path.display()))
}

/// `error` and its causes: the `mcap` crate's I/O errors say only "I/O error" and keep the reason (no
/// space left on device, ...) as their source.
fn with_causes(error: &dyn std::error::Error) -> String {
    let mut text = error.to_string();
    let mut cause = error.source();
    while let Some(inner) = cause {
        text.push_str(": ");
        text.push_str(&inner.to_string());
        cause = inner.source();
    }
    text
}

/// The `kairos.clock` record: what the runtime clock was when it was written (at the start, with every
/// chunk and at the end; the last is the latest). A recording made while the clock was not locked to its
/// source (a master, a GNSS receiver) says so here: `state` is not `locked`.
fn clock_record(ctx: &Context) -> Metadata {
    let mut clock = BTreeMap::from([("description".to_owned(), ctx.clock_description())]);
    if let Some(status) = ctx.clock_status() {
        let state = serde_json::to_value(status.state)
            .ok()
            .and_then(|v| v.as_str().map(str::to_owned))
            .unwrap_or_default();
        clock.insert("source".to_owned(), status.source);
        clock.insert("state".to_owned(), state);
        clock.insert("error_ns".to_owned(), status.error_ns.to_string());
        clock.insert("step_ns".to_owned(), status.step_ns.to_string());
        clock.insert("references".to_owned(), status.references.to_string());
        if let Some(bound) = status.error_bound_ns {
            clock.insert("error_bound_ns".to_owned(), bound.to_string());
        }
    } else {
        clock.insert("source".to_owned(), "this machine".to_owned());
        clock.insert("state".to_owned(), "free".to_owned());
    }
    Metadata {
        name: "kairos.clock".to_owned(),
        metadata: clock,
    }
}

impl Recorder {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        let mut descriptor = Descriptor::new(
            "recording.recorder",
            "recording",
            "Records its inputs to an MCAP file: one channel per input, both times kept, Foxglove schemas where they exist",
        )
        .label("MCAP recorder");
        for name in INPUT_NAMES {
            descriptor =
                descriptor.input_with_policy(name, TypeFilter::Any, ReaderPolicy::Fifo, "A stream to record");
        }
        pre_trigger_properties(descriptor)
            .input_with_policy(
                "mark",
                TypeFilter::Any,
                ReaderPolicy::Fifo,
                "Each sample writes a marker (a trigger such as a threshold's output): its text when it is text, else marker_text",
            )
            .input_with_policy(
                "trigger",
                TypeFilter::Any,
                ReaderPolicy::Fifo,
                "Pre-trigger mode: each sample (but false or 0) writes the seconds before it and after it",
            )
            .property(
                Property::path("path", "recording.mcap").doc(
                    "The file; later parts of a split are named <stem>_001.mcap, ... A file already there is \
                     never replaced unless `overwrite` is set: the recording goes beside it, as <stem>-1.mcap \
                     (the first free number), and the log and the status say so",
                ),
            )
            .property(
                Property::bool("overwrite", false)
                    .doc("Replace a file already at the path instead of recording beside it under a new name"),
            )
            .property(
                Property::choice("compression", &["zstd", "lz4", "none"], "zstd").doc("Chunk compression"),
            )
            .property(Property::choice("profile", &["kairos", "rosbag2"], "kairos").doc(
                "kairos: Foxglove's schemas and ours, every Kairos type exactly; rosbag2: ROS 2 messages in CDR \
                 (sensor_msgs, geometry_msgs, std_msgs, can_msgs) under ROS topic names (camera.image as \
                 /camera/image), which ROS 2 tools read",
            ))
            .property(
                Property::i64("chunk_size_kb", CHUNK_SIZE_KB)
                    .unit("KiB")
                    .int_range(16, 1_048_576)
                    .doc("A chunk closes at this size..."),
            )
            .property(
                Property::f64("chunk_period_s", 1.0)
                    .unit("s")
                    .range(0.05, 60.0)
                    .doc("...or this long after it opened: a crash loses at most the open chunk"),
            )
            .property(
                Property::f64("split_size_mb", 0.0)
                    .unit("MB")
                    .range(0.0, 1e9)
                    .live()
                    .doc("Start a new file past this size (0: never)"),
            )
            .property(
                Property::f64("split_duration_s", 0.0)
                    .unit("s")
                    .range(0.0, 1e9)
                    .live()
                    .doc("Start a new file after this long (0: never)"),
            )
            .property(
                Property::f64("min_free_mb", 256.0)
                    .unit("MB")
                    .range(0.0, 1e9)
                    .live()
                    .doc("Stop recording cleanly when the disk has less free space than this"),
            )
            .property(
                Property::bool("record_at_start", true)
                    .doc("Record from the start; otherwise wait for the start action"),
            )
            .property(
                Property::text("marker_text", "mark")
                    .live()
                    .doc("The text of markers written by the mark action, or by a mark sample that is not text"),
            )
            .action("trigger", "Pre-trigger mode: write the seconds before now and after it")
            .action("mark", "Write a marker into the recording, at this instant")
            .action("start", "Start recording (a new file if one was closed)")
            .action("stop", "Stop recording and close the file")
            .action(
                "split",
                "Close the current file and continue in a new one, losing no sample",
            )
            .build()
    }

    fn part_path(base: &Path, part: u32) -> PathBuf {
        if part == 0 {
            return base.to_owned();
        }
        let stem = base
            .file_stem()
            .map_or_else(|| "recording".into(), |s| s.to_string_lossy().into_owned());
        let extension = base
            .extension()
            .map_or_else(|| "mcap".into(), |e| e.to_string_lossy().into_owned());
        base.with_file_name(format!("{stem}_{part:03}.{extension}"))
    }

    fn open(&mut self, ctx: &Context) -> ComponentResult {
        let base = PathBuf::from(ctx.text_property("path")?);
        let path = Self::part_path(&base, self.part);
        let compression = match ctx.text_property("compression")?.as_str() {
            "zstd" => Some(mcap::Compression::Zstd),
            "lz4" => Some(mcap::Compression::Lz4),
            _ => None,
        };
        let chunk_size = u64::try_from(ctx.i64_property("chunk_size_kb")?).unwrap_or(1024) * 1024;
        let rosbag2 = ctx.text_property("profile")? == "rosbag2";
        let (file, path) =
            kairos_sdk::files::create_for(ctx, &path).map_err(|e| failed(&path, "cannot create", e))?;
        let writer = match Self::start_file(ctx, file, &path, compression, chunk_size, rosbag2) {
            Ok(writer) => writer,
            Err(error) => {
                // A file that could not even be started (a full disk) is not left behind empty.
                let _ = std::fs::remove_file(&path);
                return Err(error);
            }
        };
        // The number is used only once the file is there: files are numbered without gaps.
        self.part += 1;
        tracing::info!("recording to {}", path.display());
        let now = Instant::now();
        let ring_dropped_before = self
            .ring
            .dropped_by_input
            .iter()
            .map(|(input, total)| {
                let before = self.ring_dropped_at_event.get(input).copied().unwrap_or(0);
                (*input, total - before)
            })
            .filter(|(_, dropped)| *dropped > 0)
            .collect();
        self.ring_dropped_at_event = self.ring.dropped_by_input.clone();
        self.file = Some(OpenFile {
            writer,
            path,
            opened: now,
            last_chunk: now,
            bytes: 0,
            channels: BTreeMap::new(),
            schemas: BTreeMap::new(),
            counts: BTreeMap::new(),
            ring_dropped_before,
            rosbag2,
        });
        Ok(())
    }

    /// A new MCAP file on `file`, its opening records written.
    fn start_file(
        ctx: &Context,
        file: File,
        path: &Path,
        compression: Option<mcap::Compression>,
        chunk_size: u64,
        rosbag2: bool,
    ) -> Result<mcap::Writer<BufWriter<File>>, ComponentError> {
        let mut writer = mcap::WriteOptions::new()
            .compression(compression)
            .chunk_size(Some(chunk_size))
            // MCAP's profile for ROS 2 recordings, as rosbag2 writes it.
            .profile(if rosbag2 { "ros2" } else { "kairos" })
            .library(concat!("kairos-pack-recording ", env!("CARGO_PKG_VERSION")))
            .create(BufWriter::new(file))
            .map_err(|e| failed(path, "cannot start", with_causes(&e)))?;
        let about = BTreeMap::from([
            ("recorder".to_owned(), ctx.id().to_owned()),
            ("clock".to_owned(), ctx.clock_description()),
            ("opened_at_ns".to_owned(), ctx.now().as_nanos().to_string()),
            (
                "publish_time".to_owned(),
                "the sample's timestamp (when the data originated)".to_owned(),
            ),
            (
                "log_time".to_owned(),
                "the sample's time of issue (when it was last written)".to_owned(),
            ),
            ("sdk_version".to_owned(), kairos_sdk::SDK_VERSION.to_owned()),
        ]);
        writer
            .write_metadata(&Metadata {
                name: "kairos.recording".to_owned(),
                metadata: about,
            })
            .map_err(|e| failed(path, "cannot write to", with_causes(&e)))?;
        if let Some(text) = ctx.diagram_text() {
            writer
                .write_metadata(&Metadata {
                    name: "kairos.diagram".to_owned(),
                    metadata: BTreeMap::from([("ron".to_owned(), text.to_string())]),
                })
                .map_err(|e| failed(path, "cannot write to", with_causes(&e)))?;
        }
        writer
            .write_metadata(&clock_record(ctx))
            .map_err(|e| failed(path, "cannot write to", with_causes(&e)))?;
        // The opening records reach the disk now: a file that cannot hold them fails here, not later.
        writer
            .flush()
            .map_err(|e| failed(path, "cannot write to", with_causes(&e)))?;
        Ok(writer)
    }

    /// The `kairos.drops` record: per track, its link's counters now. Written with every chunk the period
    /// closes and at the end, so a file that was never closed still tells what was lost until then (the
    /// last record of that name is the latest).
    fn drop_counts(&self, ctx: &Context, file: Option<&OpenFile>) -> Metadata {
        let mut drops = BTreeMap::new();
        for index in &self.connected {
            let (Some(source), Some(counters)) = (
                ctx.inputs().get(*index).and_then(kairos_sdk::InputPort::source),
                ctx.input_counters(*index),
            ) else {
                continue;
            };
            let name = input_name(*index);
            // The link's counters are the run's so far; `in_file` is what this file holds, and in
            // pre-trigger mode `ring_dropped_before` what the ring let go since the previous event's file
            // (older than pre_trigger_s, or over ring_mb, when the trigger came).
            let in_file = file.and_then(|f| f.counts.get(index).copied()).unwrap_or(0);
            let mut counts = format!(
                "written={} recorded={} overwritten={} skipped={} queued={} in_file={in_file}",
                counters.written, counters.read, counters.overwritten, counters.skipped, counters.queued
            );
            if self.pre_trigger {
                let dropped = file
                    .and_then(|f| f.ring_dropped_before.get(index).copied())
                    .unwrap_or(0);
                let _ = write!(counts, " ring_dropped_before={dropped}");
            }
            drops.insert(format!("{name} {source}"), counts);
        }
        Metadata {
            name: "kairos.drops".to_owned(),
            metadata: drops,
        }
    }

    /// Writes the drop counts of every track and closes the file; it is complete and indexed.
    fn close(&mut self, ctx: &Context) -> ComponentResult {
        let Some(mut file) = self.file.take() else {
            return Ok(());
        };
        self.closed_files += 1;
        let result = file
            .writer
            .write_metadata(&self.drop_counts(ctx, Some(&file)))
            .and_then(|()| file.writer.write_metadata(&clock_record(ctx)))
            .and_then(|()| file.writer.finish().map(|_| ()));
        let inner = file.writer.into_inner();
        let flushed = inner
            .into_inner()
            .map_err(std::io::IntoInnerError::into_error)
            .and_then(|f| f.sync_all());
        result.map_err(|e| failed(&file.path, "cannot finish", with_causes(&e)))?;
        flushed.map_err(|e| failed(&file.path, "cannot flush", e))?;
        self.last_file = Some(file.path.clone());
        tracing::info!(
            "closed {} ({} bytes of messages)",
            file.path.display(),
            file.bytes
        );
        Ok(())
    }

    fn record(&mut self, ctx: &Context, input: usize, sample: &Sample) -> ComponentResult {
        if self.file.is_none() {
            self.open(ctx)?;
        }
        let Some(file) = self.file.as_mut() else {
            return Ok(());
        };
        let path = file.path.clone();
        let (channel, sequence) = if let Some(entry) = file.channels.get_mut(&input) {
            entry.1 = entry.1.wrapping_add(1);
            *entry
        } else {
            let spec = if file.rosbag2 {
                let ros_type = crate::ros2::write::ros_type_of(&sample.payload);
                crate::encode::SchemaSpec {
                    name: ros_type.to_owned(),
                    encoding: crate::ros2::SCHEMA_ENCODING.to_owned(),
                    data: crate::ros2::write::definition_of(ros_type).into_bytes(),
                    message_encoding: crate::ros2::MESSAGE_ENCODING.to_owned(),
                }
            } else {
                schema_for(&sample.payload)
            };
            let schema = if let Some(id) = file.schemas.get(&spec.name) {
                *id
            } else {
                let id = file
                    .writer
                    .add_schema(&spec.name, &spec.encoding, &spec.data)
                    .map_err(|e| failed(&path, "cannot write to", with_causes(&e)))?;
                file.schemas.insert(spec.name.clone(), id);
                id
            };
            let source = ctx.inputs().get(input).and_then(kairos_sdk::InputPort::source);
            let mut topic = if input == MARK_INPUT {
                MARKERS_TOPIC.to_owned()
            } else {
                source.map_or_else(|| input_name(input).to_owned(), str::to_owned)
            };
            if file.rosbag2 {
                topic = crate::ros2::write::ros_topic(&topic);
            }
            let metadata = BTreeMap::from([
                ("input".to_owned(), input_name(input).to_owned()),
                ("kairos.type".to_owned(), sample.payload.data_type().to_string()),
            ]);
            let id = file
                .writer
                .add_channel(schema, &topic, &spec.message_encoding, &metadata)
                .map_err(|e| failed(&path, "cannot write to", with_causes(&e)))?;
            file.channels.insert(input, (id, 0));
            (id, 0)
        };
        let frame_id = ctx
            .inputs()
            .get(input)
            .and_then(kairos_sdk::InputPort::source)
            .unwrap_or("");
        if file.rosbag2 {
            crate::ros2::write::encode(&sample.payload, sample.timestamp, frame_id, &mut self.scratch)
                .map_err(crate::encode::EncodeError::from)
        } else {
            encode(&sample.payload, sample.timestamp, frame_id, &mut self.scratch)
        }
        .map_err(|e| failed(&path, "cannot encode a sample for", e))?;
        let header = MessageHeader {
            channel_id: channel,
            sequence,
            log_time: u64::try_from(sample.time_of_issue.as_nanos()).unwrap_or(0),
            publish_time: u64::try_from(sample.timestamp.as_nanos()).unwrap_or(0),
        };
        file.writer
            .write_to_known_channel(&header, &self.scratch)
            .map_err(|e| failed(&path, "cannot write to", with_causes(&e)))?;
        file.bytes += self.scratch.len() as u64;
        *file.counts.entry(input).or_default() += 1;
        let chunk_due =
            file.last_chunk.elapsed() >= Duration::from_secs_f64(ctx.f64_property("chunk_period_s")?);
        self.written_since_check += self.scratch.len() as u64;
        if chunk_due {
            // The metadata record closes the chunk; the flush hands both to the system.
            let drops = self.drop_counts(ctx, self.file.as_ref());
            if let Some(file) = self.file.as_mut() {
                file.last_chunk = Instant::now();
                file.writer
                    .write_metadata(&drops)
                    .and_then(|()| file.writer.write_metadata(&clock_record(ctx)))
                    .and_then(|()| file.writer.flush())
                    .map_err(|e| failed(&path, "cannot write to", with_causes(&e)))?;
            }
        }
        Ok(())
    }

    /// Pre-trigger mode: a sample goes to the event being written, or to the ring; a trigger starts or
    /// extends an event; a mark is written while an event is.
    fn pre_trigger_sample(&mut self, ctx: &Context, input: usize, sample: Sample) -> ComponentResult {
        let at = sample.timestamp;
        if self.event_until.is_some_and(|until| at > until) {
            self.end_event(ctx)?;
        }
        match input {
            TRIGGER_INPUT => {
                if is_trigger(&sample.payload) {
                    self.trigger(ctx, at)?;
                }
                Ok(())
            }
            MARK_INPUT => self.mark_sample(ctx, &sample),
            _ if self.event_until.is_some() => {
                if let Err(error) = self.record(ctx, input, &sample) {
                    // The disk filled, say: the event ends, the sample stays in memory with the others.
                    self.event_until = None;
                    self.write_failed(ctx, &error);
                    self.keep_in_ring(ctx, input, sample)?;
                    return Ok(());
                }
                self.end_event_if_short_of_space(ctx)
            }
            _ => self.keep_in_ring(ctx, input, sample),
        }
    }

    fn keep_in_ring(&mut self, ctx: &Context, input: usize, sample: Sample) -> ComponentResult {
        let keep = seconds_to_nanos(ctx.f64_property("pre_trigger_s")?);
        #[allow(
            clippy::cast_possible_truncation,
            clippy::cast_sign_loss,
            reason = "a positive byte count, far below usize::MAX"
        )]
        let max_bytes = (ctx.f64_property("ring_mb")? * 1e6) as usize;
        self.ring.push(input, sample, keep, max_bytes);
        Ok(())
    }

    /// A trigger at `at`: a new event writes the ring's seconds before `at`; one under way is extended.
    /// A write that fails keeps what it did not write in the ring and names the error; the recorder
    /// goes on.
    fn trigger(&mut self, ctx: &Context, at: kairos_sdk::Timestamp) -> ComponentResult {
        let until = at.after(Duration::from_secs_f64(ctx.f64_property("post_trigger_s")?));
        if let Some(current) = self.event_until {
            self.event_until = Some(current.max(until));
            return Ok(());
        }
        // An event failed a moment ago (a full disk): the seconds stay in the ring for a later trigger.
        if self.retry_after.is_some_and(|at| Instant::now() < at) {
            return Ok(());
        }
        let before = seconds_to_nanos(ctx.f64_property("pre_trigger_s")?);
        let kept = self
            .ring
            .take_from(kairos_sdk::Timestamp(at.as_nanos().saturating_sub(before)));
        if self.file.is_none()
            && let Err(error) = Self::room_for_an_event(ctx).and_then(|()| self.open(ctx))
        {
            self.ring.restore(kept.into_iter());
            self.write_failed(ctx, &error);
            return Ok(());
        }
        self.events += 1;
        self.event_until = Some(until);
        let mut kept = kept.into_iter();
        while let Some((input, sample)) = kept.next() {
            if let Err(error) = self.record(ctx, input, &sample) {
                let unwritten: Vec<(usize, Sample)> = std::iter::once((input, sample)).chain(kept).collect();
                self.ring.restore(unwritten.into_iter());
                self.event_until = None;
                self.write_failed(ctx, &error);
                return Ok(());
            }
            if input == MARK_INPUT {
                self.markers += 1;
            }
        }
        let file = self
            .file
            .as_ref()
            .map(|f| f.path.display().to_string())
            .unwrap_or_default();
        tracing::info!("{}: event {} into {file}", ctx.id(), self.events);
        Ok(())
    }

    /// The event is over: its file closes (a file per event), or stays open for the next one.
    fn end_event(&mut self, ctx: &Context) -> ComponentResult {
        self.event_until = None;
        if ctx.text_property("event_files")? == "one_per_event" {
            self.close(ctx)?;
        }
        Ok(())
    }

    /// Pre-trigger mode: an event could not be written (a full disk). What it started is completed if
    /// it can be (the file closed, valid, with what it holds), else removed; the ring keeps what was not
    /// written; new events wait a moment; the error is logged at most once a second, with a count.
    fn write_failed(&mut self, ctx: &Context, error: &ComponentError) {
        self.failures += 1;
        self.retry_after = Some(Instant::now() + RETRY_EVENTS_AFTER);
        let what_became = match self.file.take() {
            None => String::new(),
            Some(file) => self.settle_failed_file(ctx, file),
        };
        let message = format!(
            "{error}{what_became}; the last seconds are still in memory, for the next trigger ({} event(s) \
             not written in all)",
            self.failures
        );
        if self.failure_log.ready(kairos_sdk::WARNING_PERIOD) {
            tracing::error!("{}: {message}", ctx.id());
        }
        self.last_error = Some(message);
    }

    /// A file an event failed in: closed if it still can be; else, holding this event alone, removed
    /// (its number is used again), or left for `kairos recover` when it holds earlier events too.
    fn settle_failed_file(&mut self, ctx: &Context, mut file: OpenFile) -> String {
        let path = file.path.clone();
        let finished = file
            .writer
            .write_metadata(&self.drop_counts(ctx, Some(&file)))
            .and_then(|()| file.writer.finish().map(|_| ()))
            .is_ok()
            && file
                .writer
                .into_inner()
                .into_inner()
                .is_ok_and(|f| f.sync_all().is_ok());
        if finished {
            self.closed_files += 1;
            self.last_file = Some(path.clone());
            return format!(
                "; {} is closed and valid, holding the event up to the failure",
                path.display()
            );
        }
        let one_per_event = ctx
            .text_property("event_files")
            .is_ok_and(|files| files == "one_per_event");
        if one_per_event {
            let _ = std::fs::remove_file(&path);
            self.part = self.part.saturating_sub(1).max(1);
            self.events = self.events.saturating_sub(1);
            return format!("; the event's partial file {} is removed", path.display());
        }
        format!(
            "; {} is not closed (it holds earlier events: `kairos recover` makes a valid copy)",
            path.display()
        )
    }

    /// A sample on the `mark` input: a marker when it is text (its text), or when it turns on (true or
    /// non-zero after a false, a zero or nothing: `marker_text`), as a threshold crossing does.
    fn mark_sample(&mut self, ctx: &Context, sample: &Sample) -> ComponentResult {
        let text = match &sample.payload {
            kairos_sdk::Payload::Text(text) => text.to_string(),
            other => {
                let on = is_trigger(other);
                let turned_on = on && !self.mark_was_on;
                self.mark_was_on = on;
                if !turned_on {
                    return Ok(());
                }
                ctx.text_property("marker_text")?
            }
        };
        self.mark(ctx, &text, sample.timestamp)
    }

    /// Writes a marker stamped `at`: a text message on the markers channel. While not recording there is
    /// no file to mark; that is said, and nothing fails. In pre-trigger mode, outside an event, the
    /// marker waits in the ring like a sample and is written with the event it falls in.
    fn mark(&mut self, ctx: &Context, text: &str, at: kairos_sdk::Timestamp) -> ComponentResult {
        if !self.recording {
            tracing::warn!(
                "{}: marker '{text}' not written: the recorder is not recording",
                ctx.id()
            );
            return Ok(());
        }
        let marker = Sample {
            payload: kairos_sdk::Payload::Text(text.into()),
            timestamp: at,
            time_of_issue: at,
            sequence: self.markers,
        };
        if self.pre_trigger && self.event_until.is_none() {
            return self.keep_in_ring(ctx, MARK_INPUT, marker);
        }
        self.record(ctx, MARK_INPUT, &marker)?;
        self.markers += 1;
        tracing::info!("{}: marker '{text}'", ctx.id());
        Ok(())
    }

    fn split_due(&self, ctx: &Context) -> Result<bool, ComponentError> {
        let Some(file) = &self.file else { return Ok(false) };
        let size_mb = ctx.f64_property("split_size_mb")?;
        let duration_s = ctx.f64_property("split_duration_s")?;
        Ok(self.split_requested
            || (size_mb > 0.0 && file.bytes as f64 >= size_mb * 1e6)
            || (duration_s > 0.0 && file.opened.elapsed().as_secs_f64() >= duration_s))
    }

    /// Stops cleanly, before the disk is full: the file is closed and valid, and the error names it.
    fn check_free_space(&mut self, ctx: &Context) -> ComponentResult {
        let Some((path, free_mb, minimum)) = self.short_of_space(ctx)? else {
            return Ok(());
        };
        self.close(ctx)?;
        self.recording = false;
        Err(ComponentError::failed(format_args!(
            "stopped recording {}: {free_mb:.0} MB free on its disk, below min_free_mb = {minimum}; the file is closed and valid",
            path.display()
        )))
    }

    /// The open file's path, the MB free on its disk and `min_free_mb`, when the disk has less free than
    /// that. Looked at once a second, and sooner when a fast writer could use half the margin left
    /// before then.
    fn short_of_space(&mut self, ctx: &Context) -> Result<Option<(PathBuf, f64, f64)>, ComponentError> {
        if self
            .last_space_check
            .is_some_and(|t| t.elapsed() < SPACE_CHECK_PERIOD)
            && self.written_since_check < self.check_budget
        {
            return Ok(None);
        }
        self.last_space_check = Some(Instant::now());
        self.written_since_check = 0;
        let Some(file) = &self.file else { return Ok(None) };
        let path = file.path.clone();
        let Some(free_mb) = free_mb_beside(&path) else {
            return Ok(None);
        };
        let minimum = ctx.f64_property("min_free_mb")?;
        #[allow(
            clippy::cast_possible_truncation,
            clippy::cast_sign_loss,
            reason = "a positive byte count"
        )]
        let budget = ((free_mb - minimum).max(0.0) * 1e6 / 2.0) as u64;
        self.check_budget = budget.max(SPACE_CHECK_MIN_BYTES);
        Ok((free_mb < minimum).then_some((path, free_mb, minimum)))
    }

    /// Pre-trigger mode: a disk short of space ends the event being written, its file closed and valid;
    /// the recorder stays armed, keeping the last seconds in memory for the next trigger.
    fn end_event_if_short_of_space(&mut self, ctx: &Context) -> ComponentResult {
        let Some((path, free_mb, minimum)) = self.short_of_space(ctx)? else {
            return Ok(());
        };
        self.event_until = None;
        self.close(ctx)?;
        let message = format!(
            "stopped writing {}: {free_mb:.1} MB free on its disk, below min_free_mb = {minimum}; the file is \
             closed and valid, and the last seconds are kept in memory for the next trigger",
            path.display()
        );
        tracing::error!("{}: {message}", ctx.id());
        self.last_error = Some(message);
        Ok(())
    }

    /// Pre-trigger mode: whether the disk of `path` has `min_free_mb` free before an event starts there.
    fn room_for_an_event(ctx: &Context) -> ComponentResult {
        let path = PathBuf::from(ctx.text_property("path")?);
        let minimum = ctx.f64_property("min_free_mb")?;
        match free_mb_beside(&path) {
            Some(free_mb) if free_mb < minimum => Err(ComponentError::failed(format_args!(
                "no event written to {}: {free_mb:.1} MB free on its disk, below min_free_mb = {minimum}",
                path.display()
            ))),
            _ => Ok(()),
        }
    }
}

/// The MB free on the disk that holds (or will hold) `path`; `None` when it cannot be told.
fn free_mb_beside(path: &Path) -> Option<f64> {
    let folder = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let stats = nix::sys::statvfs::statvfs(folder).ok()?;
    Some((stats.blocks_available() as f64) * (stats.fragment_size() as f64) / 1e6)
}

impl Component for Recorder {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        self.connected = (0..=TRIGGER_INPUT).filter(|i| ctx.is_connected(*i)).collect();
        self.pre_trigger = ctx.text_property("mode")? == "pre_trigger";
        self.recording = ctx.bool_property("record_at_start")? || self.pre_trigger;
        if self.pre_trigger && ctx.text_property("event_files")? == "one_per_event" {
            // Events are numbered from the first: event_001.mcap, event_002.mcap, ...
            self.part = self.part.max(1);
        }
        // In pre-trigger mode the first file opens with the first event.
        if self.recording && !self.pre_trigger {
            self.open(ctx)?;
        }
        self.publish_status(ctx, true);
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let result = self.cycle(ctx);
        self.publish_status(ctx, result.is_err());
        result
    }

    fn death(&mut self, ctx: &mut Context) -> ComponentResult {
        let result = self.close(ctx);
        self.publish_status(ctx, true);
        result
    }

    fn property_changed(&mut self, _name: &str, _value: &Value, _ctx: &mut Context) -> ComponentResult {
        Ok(())
    }

    fn action(&mut self, name: &str, ctx: &mut Context) -> ComponentResult {
        let result = self.act(name, ctx);
        self.publish_status(ctx, true);
        result
    }
}

impl Recorder {
    /// Publishes whether it records, to which file and how much (for the studio), at most twice a second
    /// unless `now`.
    fn publish_status(&mut self, ctx: &Context, now: bool) {
        if !now
            && self
                .published
                .is_some_and(|at| at.elapsed() < Duration::from_millis(500))
        {
            return;
        }
        self.published = Some(Instant::now());
        let (path, bytes) = self
            .file
            .as_ref()
            .map_or((None, 0), |f| (Some(f.path.display().to_string()), f.bytes));
        // What the file takes on disk so far, compressed (the chunk being filled is not in it yet).
        let disk_bytes = self
            .file
            .as_ref()
            .and_then(|f| std::fs::metadata(&f.path).ok())
            .map_or(0, |metadata| metadata.len());
        ctx.set_status(serde_json::json!({
            "kind": "recorder",
            // Pre-trigger mode: armed (keeping seconds in memory), whether or not an event is being written.
            "recording": self.recording && (self.file.is_some() || self.pre_trigger),
            "path": path,
            "bytes": bytes,
            "disk_bytes": disk_bytes,
            "files_closed": self.closed_files,
            "last_file": self.last_file.as_ref().map(|p| p.display().to_string()),
            "markers": self.markers,
            "mode": if self.pre_trigger { "pre_trigger" } else { "continuous" },
            "events": self.events,
            "in_event": self.event_until.is_some(),
            "ring_s": self.ring.span_s(),
            "ring_bytes": self.ring.bytes(),
            "ring_dropped": self.ring.dropped,
            "events_not_written": self.failures,
            "last_error": self.last_error,
        }));
    }

    fn cycle(&mut self, ctx: &mut Context) -> ComponentResult {
        if self.connected.is_empty() {
            return Err(ComponentError::Stopped);
        }
        let inputs = self.connected.clone();
        let (position, sample) = ctx.read_any(&inputs)?;
        if !self.recording {
            return Ok(());
        }
        let input = inputs.get(position).copied().unwrap_or(0);
        if self.pre_trigger {
            return self.pre_trigger_sample(ctx, input, sample);
        }
        if input == MARK_INPUT {
            return self.mark_sample(ctx, &sample);
        }
        self.record(ctx, input, &sample)?;
        if self.split_due(ctx)? {
            self.split_requested = false;
            self.close(ctx)?;
            self.open(ctx)?;
        }
        self.check_free_space(ctx)
    }

    fn act(&mut self, name: &str, ctx: &Context) -> ComponentResult {
        match name {
            "start" => {
                if !self.recording {
                    self.recording = true;
                    // Pre-trigger mode arms: its files open with events.
                    if self.file.is_none() && !self.pre_trigger {
                        self.open(ctx)?;
                    }
                }
                Ok(())
            }
            "stop" => {
                self.recording = false;
                self.close(ctx)
            }
            "split" => {
                if self.file.is_some() {
                    self.split_requested = true;
                }
                Ok(())
            }
            "mark" => {
                let text = ctx.text_property("marker_text")?;
                self.mark(ctx, &text, ctx.now())
            }
            "trigger" if self.pre_trigger => self.trigger(ctx, ctx.now()),
            "trigger" => Err(ComponentError::failed(
                "trigger is for pre-trigger mode: set mode = \"pre_trigger\" (the recorder now writes everything)",
            )),
            other => Err(ComponentError::failed(format_args!(
                "no action '{other}' (start, stop, split, mark, trigger)"
            ))),
        }
    }
}

/// The properties of pre-trigger mode.
fn pre_trigger_properties(descriptor: Descriptor) -> Descriptor {
    descriptor
            .property(
                Property::choice("mode", &["continuous", "pre_trigger"], "continuous").doc(
                    "continuous: everything to the file; pre_trigger: the last seconds kept in memory, written around each trigger",
                ),
            )
            .property(
                Property::f64("pre_trigger_s", 10.0)
                    .unit("s")
                    .range(0.0, 3600.0)
                    .live()
                    .doc("Pre-trigger mode: seconds kept before a trigger"),
            )
            .property(
                Property::f64("post_trigger_s", 10.0)
                    .unit("s")
                    .range(0.0, 3600.0)
                    .live()
                    .doc("Pre-trigger mode: seconds written after a trigger (a trigger meanwhile extends the event)"),
            )
            .property(
                Property::f64("ring_mb", 256.0)
                    .unit("MB")
                    .range(1.0, 1e6)
                    .live()
                    .doc("Pre-trigger mode: most memory the kept seconds may take; the oldest samples go first"),
            )
            .property(
                Property::choice("event_files", &["one_per_event", "single_file"], "one_per_event")
                    .doc("Pre-trigger mode: a file per event (<stem>_001.mcap, ...), or every event in one file"),
            )
}
