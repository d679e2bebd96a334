//! `serial.reader` and `serial.writer`: a serial port's bytes in and out, for devices Kairos has no
//! dedicated component for.

use std::io::Write as _;
use std::sync::Arc;
use std::time::Instant;

use kairos_sdk::DeviceKind;
use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{
    Component, ComponentError, ComponentInfo, ComponentResult, Context, DataType, Payload, ReaderPolicy,
    TypeFilter, Value,
};

use crate::link::{Endpoint, LiveSource, REOPEN_AFTER, SerialSettings};

/// The longest line `serial.reader` passes on; longer ones are dropped and counted.
pub const LONGEST_LINE: usize = 64 * 1024;

/// The properties every serial component has.
pub fn serial_properties(descriptor: Descriptor) -> Descriptor {
    descriptor
        .property(
            Property::path("device", "/dev/ttyUSB0")
                .doc("The port")
                .device(DeviceKind::Serial),
        )
        .property(
            Property::i64("baud", 115_200)
                .unit("bit/s")
                .int_range(300, 4_000_000)
                .doc("The speed"),
        )
        .property(Property::choice("parity", &["none", "even", "odd"], "none").doc("Parity"))
        .property(Property::i64("stop_bits", 1).int_range(1, 2).doc("Stop bits"))
        .property(
            Property::choice("flow_control", &["none", "software", "hardware"], "none")
                .doc("Flow control (software: XON/XOFF, hardware: RTS/CTS)"),
        )
}

/// The serial settings in `ctx`'s properties (as [`serial_properties`] declares them).
///
/// # Errors
///
/// A property is missing (a descriptor without [`serial_properties`]).
pub fn serial_settings(ctx: &Context) -> Result<SerialSettings, ComponentError> {
    Ok(SerialSettings {
        device: ctx.text_property("device")?,
        baud: u32::try_from(ctx.i64_property("baud")?).unwrap_or(9600),
        parity: ctx.text_property("parity")?,
        stop_bits: u8::try_from(ctx.i64_property("stop_bits")?).unwrap_or(1),
        flow_control: ctx.text_property("flow_control")?,
    })
}

/// The descriptor of `serial.reader`.
pub fn reader_descriptor() -> ComponentInfo {
    serial_properties(
        Descriptor::new(
            "serial.reader",
            "serial",
            "Reads a serial port: a text sample per line, or a bytes sample per read; stamped on arrival",
        )
        .label("Serial port reader")
        .output(
            "line",
            DataType::Text,
            "Each line, without its line ending (lines mode)",
        )
        .output("bytes", DataType::Bytes, "The bytes of each read (bytes mode)"),
    )
    .property(
        Property::choice("mode", &["lines", "bytes"], "lines")
            .doc("Lines (text up to each line ending) or bytes as they come"),
    )
    .build()
}

/// `serial.reader`. See [`reader_descriptor`].
#[derive(Debug, Default)]
pub struct SerialReader {
    source: Option<LiveSource>,
    lines: bool,
    connected: bool,
    received: u64,
    overlong: u64,
}

impl Component for SerialReader {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        self.lines = ctx.text_property("mode")? == "lines";
        let mut source = LiveSource::new(Endpoint::Serial(serial_settings(ctx)?), LONGEST_LINE);
        source.open_now().map_err(ComponentError::failed)?;
        self.source = Some(source);
        self.connected = true;
        ctx.publish_status(self);
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let Some(source) = self.source.as_mut() else {
            return Err(ComponentError::Stopped);
        };
        let (lines, bytes, received) = if self.lines {
            let mut received = source.receive();
            (std::mem::take(&mut received.lines), Vec::new(), received)
        } else {
            let (bytes, received) = source.receive_bytes();
            (Vec::new(), bytes, received)
        };
        self.overlong = source.dropped_overlong();
        if let Some(problem) = &received.problem {
            tracing::warn!("{problem}");
            self.connected = false;
        }
        if received.recovered {
            tracing::info!("receiving again");
            self.connected = true;
        }
        let now = ctx.now();
        for line in lines {
            self.received += 1;
            let text = String::from_utf8_lossy(&line);
            ctx.write_at("line", Payload::Text(Arc::from(text.as_ref())), now)?;
        }
        if !bytes.is_empty() {
            self.received += 1;
            ctx.write_at("bytes", Payload::Bytes(Arc::from(bytes)), now)?;
        }
        if received.problem.is_some() || received.recovered {
            ctx.publish_status(self);
        }
        Ok(())
    }

    fn death(&mut self, _ctx: &mut Context) -> ComponentResult {
        self.source = None;
        Ok(())
    }

    fn status(&self) -> Option<serde_json::Value> {
        Some(serde_json::json!({
            "kind": "serial",
            "connected": self.connected,
            "received": self.received,
            "overlong": self.overlong,
        }))
    }

    fn property_changed(&mut self, _name: &str, _value: &Value, _ctx: &mut Context) -> ComponentResult {
        Ok(())
    }
}

/// The descriptor of `serial.writer`.
pub fn writer_descriptor() -> ComponentInfo {
    serial_properties(
        Descriptor::new(
            "serial.writer",
            "serial",
            "Writes to a serial port: text with a line ending, or bytes as they are",
        )
        .label("Serial port writer")
        .input_with_policy(
            "in",
            TypeFilter::OneOf(vec![DataType::Text, DataType::Bytes]),
            ReaderPolicy::NeverSkipping,
            "What to send",
        ),
    )
    .property(
        Property::choice("line_ending", &["crlf", "lf", "none"], "crlf")
            .doc("Appended to each text sample (crlf: \\r\\n, lf: \\n); bytes go as they are"),
    )
    .build()
}

/// `serial.writer`. See [`writer_descriptor`].
#[derive(Default)]
pub struct SerialWriter {
    port: Option<Box<dyn serialport::SerialPort>>,
    settings: Option<SerialSettings>,
    /// When the port failed, and whether that was reported.
    failed: Option<Instant>,
    dropped: u64,
    sent: u64,
}

impl std::fmt::Debug for SerialWriter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SerialWriter")
            .field("sent", &self.sent)
            .field("dropped", &self.dropped)
            .finish_non_exhaustive()
    }
}

impl SerialWriter {
    /// The port, opened again once a second after a failure.
    fn port(&mut self) -> Option<&mut Box<dyn serialport::SerialPort>> {
        if self.port.is_none()
            && self.failed.is_none_or(|at| at.elapsed() >= REOPEN_AFTER)
            && let Some(settings) = &self.settings
        {
            match settings.open() {
                Ok(port) => {
                    if self.failed.take().is_some() {
                        tracing::info!("{} open again", settings.device);
                    }
                    self.port = Some(port);
                }
                Err(_) => self.failed = Some(Instant::now()),
            }
        }
        self.port.as_mut()
    }
}

impl Component for SerialWriter {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        let settings = serial_settings(ctx)?;
        self.port = Some(settings.open().map_err(ComponentError::failed)?);
        self.settings = Some(settings);
        ctx.publish_status(self);
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        let ending: &[u8] = match ctx.text_property("line_ending")?.as_str() {
            "crlf" => b"\r\n",
            "lf" => b"\n",
            _ => b"",
        };
        let bytes: Vec<u8> = match &sample.payload {
            Payload::Text(text) => [text.as_bytes(), ending].concat(),
            Payload::Bytes(bytes) => bytes.to_vec(),
            other => {
                return Err(ComponentError::failed(format_args!(
                    "expected text or bytes, got {}",
                    other.data_type()
                )));
            }
        };
        let device = self
            .settings
            .as_ref()
            .map_or_else(String::new, |s| s.device.clone());
        let written = match self.port() {
            Some(port) => port.write_all(&bytes).and_then(|()| port.flush()),
            None => Err(std::io::Error::other("not open")),
        };
        match written {
            Ok(()) => self.sent += 1,
            Err(error) => {
                self.dropped += 1;
                if self.port.take().is_some() || self.failed.is_none() {
                    tracing::warn!(
                        "cannot write to the serial port {device}: {error}; samples are dropped (and counted) \
                         until it opens again, tried once a second"
                    );
                }
                self.failed.get_or_insert_with(Instant::now);
                ctx.publish_status(self);
            }
        }
        Ok(())
    }

    fn death(&mut self, _ctx: &mut Context) -> ComponentResult {
        self.port = None;
        Ok(())
    }

    fn status(&self) -> Option<serde_json::Value> {
        Some(serde_json::json!({
            "kind": "serial",
            "connected": self.port.is_some(),
            "sent": self.sent,
            "dropped": self.dropped,
        }))
    }

    fn property_changed(&mut self, _name: &str, _value: &Value, _ctx: &mut Context) -> ComponentResult {
        Ok(())
    }
}
