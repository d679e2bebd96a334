//! `can.candump_reader`, `can.candump_writer` and `can.dbc_decoder`.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::fs::File;
use std::io::{BufRead as _, BufReader, BufWriter, Write as _};
use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use kairos_sdk::Throttle;
use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{
    Component, ComponentError, ComponentInfo, ComponentResult, Context, DataType, DescribeError, Payload,
    ReaderPolicy, Timestamp, TypeFilter, Value,
};

use crate::candump::{self, Logged};
use crate::dbc::Database;

fn failed(error: impl std::fmt::Display) -> ComponentError {
    ComponentError::failed(error)
}

fn can_frames() -> TypeFilter {
    TypeFilter::OneOf(vec![DataType::CanFrame])
}

/// The descriptor of `can.candump_reader`.
pub fn reader_descriptor() -> ComponentInfo {
    Descriptor::new(
        "can.candump_reader",
        "CAN",
        "Replays a candump log (can-utils' candump -l) at its timing or as fast as possible: one frame \
         sample per logged frame; error frames and malformed lines counted",
    )
    .label("CAN log player (candump)")
    .output("frame", DataType::CanFrame, "Each logged frame")
    .property(Property::path("path", "").doc("The log file"))
    .property(
        Property::choice("replay", &["timing", "fast"], "timing")
            .doc("At the log's timing, or as fast as the readers take the frames"),
    )
    .property(Property::text("interface", "").doc("Only frames logged on this interface (empty: all)"))
    .property(Property::bool("loop", false).doc("Start again at the end"))
    .build()
}

/// `can.candump_reader`. See [`reader_descriptor`].
#[derive(Debug, Default)]
pub struct CandumpReader {
    path: String,
    lines: Option<std::io::Lines<BufReader<File>>>,
    line_number: u64,
    /// The first frame's log time and the clock time it was replayed at.
    anchor: Option<(f64, Timestamp)>,
    /// A frame whose wait a control request interrupted.
    pending: Option<(f64, kairos_sdk::CanFrame)>,
    frames: u64,
    error_frames: u64,
    malformed: u64,
    warnings: Throttle,
    /// The properties `core` follows, read when they change rather than for every frame.
    interface: String,
    at_timing: bool,
    looping: bool,
}

impl CandumpReader {
    fn read_properties(&mut self, ctx: &Context) -> ComponentResult {
        self.interface = ctx.text_property("interface")?;
        self.at_timing = ctx.text_property("replay")? == "timing";
        self.looping = ctx.bool_property("loop")?;
        Ok(())
    }

    fn open(&mut self) -> Result<(), ComponentError> {
        let file = File::open(&self.path)
            .map_err(|e| failed(format_args!("cannot open the log {}: {e}", self.path)))?;
        self.lines = Some(BufReader::new(file).lines());
        self.line_number = 0;
        self.anchor = None;
        Ok(())
    }

    /// The next frame of the log on the chosen interface, or `None` at its end.
    fn next_frame(&mut self) -> Result<Option<(f64, kairos_sdk::CanFrame)>, ComponentError> {
        loop {
            let Some(lines) = &mut self.lines else {
                return Ok(None);
            };
            let Some(line) = lines.next() else { return Ok(None) };
            self.line_number += 1;
            let line = line.map_err(|e| failed(format_args!("cannot read {}: {e}", self.path)))?;
            if line.trim().is_empty() {
                continue;
            }
            match candump::parse(&line) {
                Ok(Logged::Frame {
                    time_s,
                    interface: logged_on,
                    frame,
                }) => {
                    if self.interface.is_empty() || logged_on == self.interface {
                        return Ok(Some((time_s, frame)));
                    }
                }
                Ok(Logged::Error { .. }) => self.error_frames += 1,
                Err(error) => {
                    self.malformed += 1;
                    let (path, number, count) = (&self.path, self.line_number, self.malformed);
                    self.warnings.warn(|| {
                        format!("{path}:{number}: {error}; skipped ({count} malformed lines in all)")
                    });
                }
            }
        }
    }
}

impl Component for CandumpReader {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        self.path = ctx.text_property("path")?;
        if self.path.is_empty() {
            return Err(failed("no log to replay: set the property path to a candump log"));
        }
        self.read_properties(ctx)?;
        self.open()
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let next = match self.pending.take() {
            Some(frame) => Some(frame),
            None => match self.next_frame()? {
                Some(frame) => Some(frame),
                None if self.looping && self.frames > 0 => {
                    self.open()?;
                    self.next_frame()?
                }
                None => None,
            },
        };
        let Some((time_s, frame)) = next else {
            return Err(ComponentError::EndOfStream);
        };
        let now = ctx.now();
        let (first, at) = *self.anchor.get_or_insert((time_s, now));
        let due = if self.at_timing {
            #[allow(clippy::cast_possible_truncation, reason = "nanoseconds of a log")]
            let offset = ((time_s - first).max(0.0) * 1e9).round() as i64;
            let due = Timestamp(at.0 + offset);
            if let Err(interrupted) = ctx.wait_until(due) {
                self.pending = Some((time_s, frame));
                return Err(interrupted);
            }
            due
        } else {
            now
        };
        self.frames += 1;
        ctx.write_at(FRAME, Payload::CanFrame(frame), due)?;
        Ok(())
    }

    fn status(&self) -> Option<serde_json::Value> {
        Some(serde_json::json!({
            "kind": "can", "frames": self.frames, "error_frames": self.error_frames, "malformed": self.malformed,
        }))
    }

    fn property_changed(&mut self, _name: &str, _value: &Value, ctx: &mut Context) -> ComponentResult {
        self.read_properties(ctx)
    }
}

/// `can.candump_reader`'s one output.
const FRAME: usize = 0;

/// How often the log writer hands what it wrote to the system: a crash loses at most this much.
const FLUSH_PERIOD: Duration = Duration::from_secs(1);

/// The descriptor of `can.candump_writer`.
pub fn writer_descriptor() -> ComponentInfo {
    Descriptor::new(
        "can.candump_writer",
        "CAN",
        "Writes frames to a candump log (readable by can-utils' canplayer and by can.candump_reader), \
         each at its timestamp",
    )
    .label("CAN log writer (candump)")
    .input_with_policy(
        "frame",
        can_frames(),
        ReaderPolicy::NeverSkipping,
        "The frames to log",
    )
    .property(Property::path("path", "can.log").doc(
        "The log file. A file already there is never replaced unless `overwrite` is set: the log goes beside \
         it as NAME-1.log (the first free number), and the log says so",
    ))
    .property(
        Property::bool("overwrite", false)
            .doc("Replace a file already at the path instead of writing beside it under a new name"),
    )
    .property(Property::text("interface", "can0").doc("The interface name written on each line"))
    .build()
}

/// `can.candump_writer`. See [`writer_descriptor`].
#[derive(Debug, Default)]
pub struct CandumpWriter {
    file: Option<BufWriter<File>>,
    path: String,
    interface: String,
    last_flush: Throttle,
}

impl Component for CandumpWriter {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        self.path = ctx.text_property("path")?;
        self.interface = ctx.text_property("interface")?;
        let (file, path) = kairos_sdk::files::create_for(ctx, Path::new(&self.path))
            .map_err(|e| failed(format_args!("cannot create {}: {e}", self.path)))?;
        self.path = path.display().to_string();
        self.file = Some(BufWriter::new(file));
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read(0)?; // `frame`
        let Payload::CanFrame(frame) = &sample.payload else {
            return Err(failed(format_args!(
                "expected a CAN frame, got {}",
                sample.payload.data_type()
            )));
        };
        let line = candump::format(frame, sample.timestamp.as_nanos(), &self.interface);
        let Some(file) = self.file.as_mut() else {
            return Ok(());
        };
        writeln!(file, "{line}").map_err(|e| failed(format_args!("cannot write {}: {e}", self.path)))?;
        // A log a crash leaves behind holds all but the last second.
        if self.last_flush.ready(FLUSH_PERIOD) {
            file.flush()
                .map_err(|e| failed(format_args!("cannot write {}: {e}", self.path)))?;
        }
        Ok(())
    }

    fn death(&mut self, _ctx: &mut Context) -> ComponentResult {
        if let Some(mut file) = self.file.take() {
            file.flush()
                .map_err(|e| failed(format_args!("cannot write {}: {e}", self.path)))?;
        }
        Ok(())
    }

    fn property_changed(&mut self, _name: &str, _value: &Value, _ctx: &mut Context) -> ComponentResult {
        Ok(())
    }
}

/// The descriptor of `can.dbc_decoder` before its DBC is read: the outputs every instance has.
pub fn decoder_descriptor() -> ComponentInfo {
    decoder_base().build()
}

fn decoder_base() -> Descriptor {
    Descriptor::new(
        "can.dbc_decoder",
        "CAN",
        "Decodes CAN frames with a DBC database into named, scaled signals with units: every signal of a \
         frame as one line of text, one number output per signal of the database, and one text output per \
         signal whose values the database describes (VAL_: `On`, `Off`)",
    )
    .label("CAN decoder (DBC)")
    .input_with_policy("frame", can_frames(), ReaderPolicy::Fifo, "The frames to decode")
    .output(
        "signals",
        DataType::Text,
        "Each decoded frame: `Message: Signal = value unit; ...`, a described value in its words",
    )
    .property(Property::path("dbc", "").doc("The DBC file"))
}

/// `value` as people write it, without the floating-point noise of the scaling (`38.4`, not
/// `38.400000000000006`): rounded to nine decimals, then written in the fewest digits that read back.
pub fn readable(value: f64) -> f64 {
    let rounded = (value * 1e9).round() / 1e9;
    if rounded == 0.0 { 0.0 } else { rounded }
}

/// The output of a signal: `Message_Signal`.
fn output_name(message: &str, signal: &str) -> String {
    format!("{message}_{signal}")
}

/// The text output of a signal with value descriptions: `Message_Signal_text`.
fn text_output_name(message: &str, signal: &str) -> String {
    format!("{message}_{signal}_text")
}

/// `can.dbc_decoder`'s descriptor for an instance: one output per signal of its DBC, then one text output
/// per signal with value descriptions (after every number output, so theirs keep their places).
///
/// # Errors
///
/// The DBC cannot be read or parsed (the error is on the property `dbc`, with the line and column).
pub fn describe_decoder(properties: &BTreeMap<String, Value>) -> Result<ComponentInfo, DescribeError> {
    let (_, database) = database_of(properties)?;
    let mut descriptor = decoder_base();
    for message in database.messages.values() {
        for signal in &message.signals {
            descriptor = descriptor.output(
                &output_name(&message.name, &signal.name),
                DataType::F64,
                &signal_doc(&message.name, signal),
            );
        }
    }
    for message in database.messages.values() {
        for signal in message.signals.iter().filter(|s| !s.choices.is_empty()) {
            let words: Vec<&str> = signal.choices.values().map(String::as_str).take(4).collect();
            descriptor = descriptor.output(
                &text_output_name(&message.name, &signal.name),
                DataType::Text,
                &format!(
                    "{}.{} in words ({}{})",
                    message.name,
                    signal.name,
                    words.join(", "),
                    if signal.choices.len() > words.len() {
                        ", …"
                    } else {
                        ""
                    }
                ),
            );
        }
    }
    Ok(descriptor.build())
}

/// The DBC the property `dbc` names, with its path; a missing or broken file is an error on that property.
fn database_of(properties: &BTreeMap<String, Value>) -> Result<(&str, Database), DescribeError> {
    let path = properties.get("dbc").and_then(Value::as_text).unwrap_or("");
    if path.is_empty() {
        return Err(
            DescribeError::property("dbc", "no DBC file").with_suggestion("set 'dbc' to the bus's .dbc file")
        );
    }
    let database = Database::open(Path::new(path)).map_err(|e| DescribeError::property("dbc", e.0))?;
    Ok((path, database))
}

/// What a signal's port says of it: `Message.Signal, unit`.
fn signal_doc(message: &str, signal: &crate::dbc::SignalSpec) -> String {
    if signal.unit.is_empty() {
        format!("{message}.{}", signal.name)
    } else {
        format!("{message}.{}, {}", signal.name, signal.unit)
    }
}

/// `can.dbc_decoder`. See [`decoder_descriptor`].
#[derive(Debug, Default)]
pub struct DbcDecoder {
    database: Database,
    /// Per message, the output index of its first signal (outputs follow the database's order, as
    /// [`describe_decoder`] makes them).
    first_output: BTreeMap<(u32, bool), usize>,
    /// Per message and signal index, the text output of a signal with value descriptions.
    text_outputs: BTreeMap<((u32, bool), usize), usize>,
    unknown: u64,
    decoded: u64,
    /// The longest text line so far: each line is built in one allocation of that size.
    longest_line: usize,
}

impl Component for DbcDecoder {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        let path = ctx.text_property("dbc")?;
        self.database = Database::open(Path::new(&path)).map_err(|e| failed(e.0))?;
        // Output 0 is `signals`.
        let mut next = 1;
        for (key, message) in &self.database.messages {
            self.first_output.insert(*key, next);
            next += message.signals.len();
        }
        for (key, message) in &self.database.messages {
            for (index, signal) in message.signals.iter().enumerate() {
                if !signal.choices.is_empty() {
                    self.text_outputs.insert((*key, index), next);
                    next += 1;
                }
            }
        }
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read(0)?; // `frame`
        let Payload::CanFrame(frame) = &sample.payload else {
            return Err(failed(format_args!(
                "expected a CAN frame, got {}",
                sample.payload.data_type()
            )));
        };
        let Some(signals) = self.database.decode(frame) else {
            self.unknown += 1;
            return Ok(());
        };
        self.decoded += 1;
        let mut line = String::with_capacity(self.longest_line);
        for (index, signal) in signals.iter().enumerate() {
            if index == 0 {
                line.push_str(signal.message);
                line.push_str(": ");
            } else {
                line.push_str("; ");
            }
            if let Some(words) = signal.choice {
                let _ = write!(line, "{} = {words}", signal.signal);
            } else {
                let _ = write!(line, "{} = {}", signal.signal, readable(signal.value));
                if !signal.unit.is_empty() {
                    line.push(' ');
                    line.push_str(signal.unit);
                }
            }
        }
        self.longest_line = self.longest_line.max(line.len());
        let key = (frame.id, frame.extended);
        let first = self.first_output.get(&key).copied().unwrap_or(0);
        // One frame's samples: its timestamp, and one clock read for their time of issue.
        let issued = ctx.now();
        ctx.write_issued(0, Payload::Text(Arc::from(line)), sample.timestamp, issued)?;
        for signal in &signals {
            ctx.write_issued(
                first + signal.index,
                Payload::F64(signal.value),
                sample.timestamp,
                issued,
            )?;
            if let (Some(&output), Some(words)) = (self.text_outputs.get(&(key, signal.index)), signal.choice)
            {
                ctx.write_issued(output, Payload::Text(Arc::from(words)), sample.timestamp, issued)?;
            }
        }
        Ok(())
    }

    fn status(&self) -> Option<serde_json::Value> {
        Some(serde_json::json!({"kind": "can", "decoded": self.decoded, "unknown_ids": self.unknown}))
    }

    fn property_changed(&mut self, _name: &str, _value: &Value, _ctx: &mut Context) -> ComponentResult {
        Ok(())
    }
}

/// The descriptor of `can.dbc_encoder` before its DBC is read: the output every instance has.
pub fn encoder_descriptor() -> ComponentInfo {
    encoder_base().build()
}

fn encoder_base() -> Descriptor {
    Descriptor::new(
        "can.dbc_encoder",
        "CAN",
        "Encodes named signals into frames of one DBC message: one input per signal of the message, one \
         frame out for each value received, carrying the newest value of every signal",
    )
    .label("CAN encoder (DBC)")
    .output("frame", DataType::CanFrame, "The encoded frames")
    .property(Property::path("dbc", "").doc("The DBC file"))
    .property(Property::text("message", "").doc("The message to encode, by its name in the DBC"))
}

/// The message named by `properties`, from the DBC they name.
fn encoded_message(
    properties: &BTreeMap<String, Value>,
) -> Result<(Database, crate::dbc::MessageSpec), DescribeError> {
    let (path, database) = database_of(properties)?;
    let name = properties.get("message").and_then(Value::as_text).unwrap_or("");
    let names: Vec<&str> = database.messages.values().map(|m| m.name.as_str()).collect();
    let Some(message) = database.messages.values().find(|m| m.name == name).cloned() else {
        let problem = if name.is_empty() {
            "no message chosen".to_owned()
        } else {
            format!("{path} has no message {name:?}")
        };
        return Err(DescribeError::property("message", problem)
            .with_suggestion(format!("one of: {}", names.join(", "))));
    };
    Ok((database, message))
}

/// `can.dbc_encoder`'s descriptor for an instance: one input per signal of its message.
///
/// # Errors
///
/// The DBC cannot be read or parsed, or has no such message.
pub fn describe_encoder(properties: &BTreeMap<String, Value>) -> Result<ComponentInfo, DescribeError> {
    let (_, message) = encoded_message(properties)?;
    let mut descriptor = encoder_base();
    let numbers = TypeFilter::OneOf(vec![DataType::F64, DataType::I64, DataType::Bool]);
    for signal in &message.signals {
        descriptor = descriptor.input_with_policy(
            &signal.name,
            numbers.clone(),
            ReaderPolicy::Fifo,
            &signal_doc(&message.name, signal),
        );
    }
    Ok(descriptor.build())
}

/// `can.dbc_encoder`. See [`encoder_descriptor`].
#[derive(Debug, Default)]
pub struct DbcEncoder {
    database: Database,
    message: String,
    signals: Vec<String>,
    values: BTreeMap<String, f64>,
    encoded: u64,
}

impl Component for DbcEncoder {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        let (database, message) = encoded_message(ctx.properties()).map_err(|e| failed(e.message))?;
        self.database = database;
        self.signals = message.signals.iter().map(|s| s.name.clone()).collect();
        // A signal nobody feeds is sent as 0 (its raw value is the offset's opposite, as the DBC says).
        self.values = self.signals.iter().map(|s| (s.clone(), 0.0)).collect();
        self.message = message.name;
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let inputs: Vec<usize> = (0..self.signals.len()).collect();
        let (position, sample) = ctx.read_any(&inputs)?;
        let value = match sample.payload {
            Payload::F64(v) => v,
            #[allow(clippy::cast_precision_loss, reason = "a signal's raw value fits in 53 bits")]
            Payload::I64(v) => v as f64,
            Payload::Bool(v) => f64::from(u8::from(v)),
            ref other => {
                return Err(failed(format_args!(
                    "expected a number, got {}",
                    other.data_type()
                )));
            }
        };
        if let Some(signal) = self.signals.get(position) {
            self.values.insert(signal.clone(), value);
        }
        if let Some(frame) = self.database.encode(&self.message, &self.values) {
            self.encoded += 1;
            ctx.write_processed("frame", &sample, Payload::CanFrame(frame))?;
        }
        Ok(())
    }

    fn status(&self) -> Option<serde_json::Value> {
        Some(serde_json::json!({"kind": "can", "encoded": self.encoded}))
    }

    fn property_changed(&mut self, _name: &str, _value: &Value, _ctx: &mut Context) -> ComponentResult {
        Ok(())
    }
}
