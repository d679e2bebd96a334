//! `gnss.nmea`: a GNSS receiver speaking NMEA 0183, read from a serial port, UDP, a TCP server or a file.

use std::sync::Arc;

use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{
    Component, ComponentError, ComponentInfo, ComponentResult, Context, DataType, GnssFix, Payload,
    Timestamp, Value,
};
use kairos_sdk::{DeviceKind, Throttle, WARNING_PERIOD};

use kairos_pack_serial::link::{Endpoint, LiveSource, SerialSettings, file_lines};

use crate::sentence::{Decoder, MAX_SENTENCE_LEN, Reading, SentenceError};

/// The component's type name.
pub const TYPE_NAME: &str = "gnss.nmea";

/// Vertical error relative to horizontal error, as receivers typically report (GGA has no VDOP).
const VERTICAL_FACTOR: f64 = 1.5;

/// The most sentences held for the clock's first reference (a receiver without a fix for minutes sends
/// thousands): past it, they are written on the machine's clock.
const MOST_HELD: usize = 256;

/// The outputs, in the descriptor's order (written by index: no name lookup per sample).
const FIX: usize = 0;
const UTC: usize = 1;
const SATELLITES: usize = 2;
const HDOP: usize = 3;
const SPEED: usize = 4;
const COURSE: usize = 5;
const SENTENCE: usize = 6;

/// The descriptor of `gnss.nmea`.
pub fn descriptor() -> ComponentInfo {
    Descriptor::new(
        TYPE_NAME,
        "GNSS",
        "GNSS receiver speaking NMEA 0183 (GGA, GNS, RMC, VTG, ZDA; any talker) on a serial port, UDP, a TCP \
         server or a file: fixes (a lost fix as one with status no fix), the receiver's UTC time, \
         satellites, HDOP, speed and course, and the sentences as text. Samples are stamped when the \
         sentence arrives",
    )
    .label("GNSS receiver (NMEA)")
    .time_source()
    .output(
        "fix",
        DataType::GnssFix,
        "Position, altitude above the ellipsoid, accuracy from HDOP, fix status (GGA, GNS); without a \
         position, NaN and status no fix",
    )
    .output(
        "utc",
        DataType::F64,
        "The receiver's UTC time, seconds since 1970 (once a date is known)",
    )
    .output("satellites", DataType::I64, "Satellites used in the fix (GGA)")
    .output("hdop", DataType::F64, "Horizontal dilution of precision (GGA)")
    .output("speed", DataType::F64, "Speed over ground, m/s (RMC, VTG)")
    .output(
        "course",
        DataType::F64,
        "Course over ground, degrees from true north (RMC, VTG)",
    )
    .output(
        "sentence",
        DataType::Text,
        "Every sentence with a valid checksum, as received",
    )
    .property(
        Property::choice("source", &["serial", "udp", "tcp", "file"], "serial")
            .doc("Where the sentences come from"),
    )
    .property(
        Property::path("device", "/dev/ttyUSB0")
            .doc("Serial: the port")
            .device(DeviceKind::Serial),
    )
    .property(
        Property::i64("baud", 9600)
            .unit("bit/s")
            .int_range(300, 4_000_000)
            .doc("Serial: the speed"),
    )
    .property(Property::choice("parity", &["none", "even", "odd"], "none").doc("Serial: parity"))
    .property(
        Property::i64("stop_bits", 1)
            .int_range(1, 2)
            .doc("Serial: stop bits"),
    )
    .property(
        Property::choice("flow_control", &["none", "software", "hardware"], "none")
            .doc("Serial: flow control (software: XON/XOFF, hardware: RTS/CTS)"),
    )
    .property(
        Property::text("address", "0.0.0.0:10110")
            .doc("UDP: the local address to listen on; TCP: the receiver's address to connect to"),
    )
    .property(Property::path("path", "").doc("File: NMEA sentences, one per line"))
    .property(
        Property::choice("replay", &["timing", "fast"], "timing")
            .doc("File: at the receiver's timing (from the sentences' UTC times) or as fast as possible"),
    )
    .property(Property::bool("loop", false).doc("File: start again at the end"))
    .property(
        Property::f64("accuracy_per_hdop_m", 3.0)
            .unit("m")
            .range(0.0, 100.0)
            .live()
            .doc("Horizontal one-sigma accuracy per unit of HDOP (the user range error), m"),
    )
    .build()
}

/// A file being replayed.
struct Replay {
    /// Shared, so that handing one out costs no copy.
    lines: Vec<Arc<[u8]>>,
    /// Lines dropped for being longer than a sentence can be.
    overlong: u64,
    next: usize,
    at_timing: bool,
    looping: bool,
    /// The first sentence time and the clock time it was replayed at.
    anchor: Option<(f64, Timestamp)>,
}

enum Input {
    Live(LiveSource),
    File(Replay),
}

/// What bad input was seen, for the status and the warnings.
#[derive(Debug, Default)]
struct Counts {
    sentences: u64,
    bad_checksum: u64,
    malformed: u64,
    last_problem: String,
    warned: Throttle,
    unreported: u64,
}

/// The component. See [`descriptor`].
#[derive(Default)]
pub struct NmeaReceiver {
    input: Option<Input>,
    /// The `accuracy_per_hdop_m` property, kept here: read for every fix.
    accuracy_per_hdop: f64,
    decoder: Decoder,
    counts: Counts,
    connected: bool,
    /// Set when a reference stepped the runtime clock: the stepping sentence's time of day and its
    /// arrival on the new clock, from which a replay takes its schedule again.
    clock_stepped: Option<(f64, Timestamp)>,
    /// What was received while the runtime clock, following this receiver, awaited its first time
    /// from it: written once the time is known, on it.
    held: Vec<(Arc<str>, Reading, Timestamp)>,
    /// Lines dropped for their length, as the input last counted them.
    overlong: u64,
}

impl std::fmt::Debug for NmeaReceiver {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("NmeaReceiver")
            .field("sentences", &self.counts.sentences)
            .finish_non_exhaustive()
    }
}

impl NmeaReceiver {
    fn open(ctx: &Context) -> Result<Input, ComponentError> {
        let endpoint = match ctx.text_property("source")?.as_str() {
            "file" => {
                let path = ctx.text_property("path")?;
                if path.is_empty() {
                    return Err(ComponentError::failed(
                        "source is file but no path is given: set the property path",
                    ));
                }
                let (lines, overlong) =
                    file_lines(&path, MAX_SENTENCE_LEN).map_err(ComponentError::failed)?;
                return Ok(Input::File(Replay {
                    lines: lines.into_iter().map(Arc::from).collect(),
                    overlong,
                    next: 0,
                    at_timing: ctx.text_property("replay")? == "timing",
                    looping: ctx.bool_property("loop")?,
                    anchor: None,
                }));
            }
            "udp" => Endpoint::Udp(ctx.text_property("address")?),
            "tcp" => Endpoint::Tcp(ctx.text_property("address")?),
            _ => Endpoint::Serial(SerialSettings {
                device: ctx.text_property("device")?,
                baud: u32::try_from(ctx.i64_property("baud")?).unwrap_or(9600),
                parity: ctx.text_property("parity")?,
                stop_bits: u8::try_from(ctx.i64_property("stop_bits")?).unwrap_or(1),
                flow_control: ctx.text_property("flow_control")?,
            }),
        };
        let tcp = matches!(endpoint, Endpoint::Tcp(_));
        let mut source = LiveSource::new(endpoint, MAX_SENTENCE_LEN);
        // A missing port or an address in use fails the component at once, saying which; a TCP receiver
        // may come up later, and is tried again every second.
        match source.open_now() {
            Ok(()) => {}
            Err(reason) if tcp => tracing::warn!("{reason}; trying again every second"),
            Err(reason) => return Err(ComponentError::failed(reason)),
        }
        Ok(Input::Live(source))
    }

    /// Decodes one line received at `received` (read off the runtime clock just before) and writes what
    /// it says. A time the receiver vouches for is first a reference for the runtime clock (when this
    /// component is its source): a reference that steps the clock stamps the sentence's samples on the
    /// new time, so none goes back behind them. Returns that step, in nanoseconds (0 for none).
    fn handle(
        &mut self,
        ctx: &mut Context,
        line: &[u8],
        mut received: Timestamp,
    ) -> Result<i64, ComponentError> {
        let decoded = std::str::from_utf8(line)
            .map_err(|_| SentenceError::Malformed("not text".to_owned()))
            .and_then(|text| Ok((text, self.decoder.decode(text)?)));
        let (text, reading) = match decoded {
            Ok(decoded) => decoded,
            Err(error) => {
                match error {
                    SentenceError::BadChecksum => self.counts.bad_checksum += 1,
                    SentenceError::Malformed(_) => self.counts.malformed += 1,
                }
                let shown: String = String::from_utf8_lossy(line).chars().take(40).collect();
                self.counts.last_problem = format!("{error} in {shown:?}");
                self.warn_bad_input();
                return Ok(0);
            }
        };
        self.counts.sentences += 1;
        let text: Arc<str> = Arc::from(text);
        let mut step = 0;
        if let Some(utc) = reading.utc_s.filter(|_| reading.time_valid) {
            if ctx.clock_reference(received, Timestamp::from_secs_f64(utc)) {
                // The first reference may step the clock (by more than a second; a slew moves it by far
                // less): what this sentence says is stamped on the new time.
                let moved = ctx.now().nanos_since(received);
                if moved.abs() > 1_000_000_000 {
                    step = moved;
                    received = Timestamp(received.0.saturating_add(step));
                    self.clock_stepped = reading.time_of_day_s.map(|day| (day, received));
                }
            }
        } else if Self::awaits_its_first_reference(ctx) && self.held.len() < MOST_HELD {
            // Stamped now, the clock's first reference could step behind it.
            self.held.push((text, reading, received));
            return Ok(0);
        }
        for (text, reading, at) in std::mem::take(&mut self.held) {
            self.write_sentence(ctx, text, &reading, Timestamp(at.0.saturating_add(step)))?;
        }
        self.write_sentence(ctx, text, &reading, received)?;
        Ok(step)
    }

    /// Writes what was held for a first reference that never came (the stream ended first), as received.
    fn write_held(&mut self, ctx: &mut Context) -> ComponentResult {
        for (text, reading, at) in std::mem::take(&mut self.held) {
            self.write_sentence(ctx, text, &reading, at)?;
        }
        Ok(())
    }

    /// Whether the runtime clock follows this receiver and has had no time from it yet.
    fn awaits_its_first_reference(ctx: &Context) -> bool {
        ctx.clock_status()
            .is_some_and(|clock| clock.source == ctx.id() && clock.references == 0)
    }

    /// Writes what one sentence says, every sample stamped `at` and issued at one clock read.
    fn write_sentence(
        &self,
        ctx: &mut Context,
        text: Arc<str>,
        reading: &Reading,
        at: Timestamp,
    ) -> ComponentResult {
        let issued = ctx.now();
        let mut write = |output: usize, payload: Payload| ctx.write_issued(output, payload, at, issued);
        write(SENTENCE, Payload::Text(text))?;
        if let Some(fix) = reading.fix {
            let horizontal = fix.hdop.map_or(f64::NAN, |hdop| hdop * self.accuracy_per_hdop);
            write(
                FIX,
                Payload::GnssFix(GnssFix {
                    latitude_deg: fix.latitude_deg,
                    longitude_deg: fix.longitude_deg,
                    altitude_m: fix.altitude_ellipsoid_m().unwrap_or(f64::NAN),
                    horizontal_accuracy_m: horizontal,
                    vertical_accuracy_m: horizontal * VERTICAL_FACTOR,
                    status: fix.status,
                }),
            )?;
            if let Some(satellites) = fix.satellites {
                write(SATELLITES, Payload::I64(i64::from(satellites)))?;
            }
            if let Some(hdop) = fix.hdop {
                write(HDOP, Payload::F64(hdop))?;
            }
        }
        if let Some(utc) = reading.utc_s {
            write(UTC, Payload::F64(utc))?;
        }
        if let Some(motion) = reading.motion {
            if let Some(speed) = motion.speed_mps {
                write(SPEED, Payload::F64(speed))?;
            }
            if let Some(course) = motion.course_deg {
                write(COURSE, Payload::F64(course))?;
            }
        }
        Ok(())
    }

    /// Logs bad input at most once a second, with how much there was since the last warning.
    fn warn_bad_input(&mut self) {
        self.counts.unreported += 1;
        if !self.counts.warned.ready(WARNING_PERIOD) {
            return;
        }
        tracing::warn!(
            "{} bad line(s) skipped (last: {}); {} bad checksums and {} malformed lines in all",
            self.counts.unreported,
            self.counts.last_problem,
            self.counts.bad_checksum,
            self.counts.malformed
        );
        self.counts.unreported = 0;
    }

    /// The next line of a replayed file, once its time has come; `None` at the end.
    fn next_replayed(
        replay: &mut Replay,
        decoder: &Decoder,
        ctx: &Context,
    ) -> Result<Option<Arc<[u8]>>, ComponentError> {
        if replay.next >= replay.lines.len() {
            if !replay.looping || replay.lines.is_empty() {
                return Ok(None);
            }
            replay.next = 0;
            replay.anchor = None;
        }
        let Some(line) = replay.lines.get(replay.next) else {
            return Ok(None);
        };
        if replay.at_timing
            && let Some(time) = std::str::from_utf8(line)
                .ok()
                .and_then(|text| decoder.clone().decode(text).ok())
                .and_then(|reading| reading.time_of_day_s)
        {
            match replay.anchor {
                None => replay.anchor = Some((time, ctx.now())),
                Some((first, at)) => {
                    // A day wraps at midnight.
                    let elapsed = (time - first).rem_euclid(86_400.0);
                    #[allow(clippy::cast_possible_truncation, reason = "seconds of a day in nanoseconds")]
                    let deadline = Timestamp(at.0 + (elapsed * 1e9).round() as i64);
                    // Interrupted (a control request) comes back here: the line is not consumed yet.
                    ctx.wait_until(deadline)?;
                }
            }
        }
        replay.next += 1;
        Ok(Some(Arc::clone(line)))
    }
}

impl Component for NmeaReceiver {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        self.decoder = Decoder::new();
        self.accuracy_per_hdop = ctx.f64_property("accuracy_per_hdop_m")?;
        self.input = Some(Self::open(ctx)?);
        self.connected = true;
        ctx.publish_status(self);
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        match &mut self.input {
            Some(Input::Live(source)) => {
                let received = source.receive();
                self.overlong = source.dropped_overlong();
                let changed = received.problem.is_some() || received.recovered;
                if let Some(problem) = received.problem {
                    tracing::warn!("{problem}");
                    self.connected = false;
                }
                if received.recovered {
                    tracing::info!("receiving again");
                    self.connected = true;
                }
                if changed {
                    ctx.publish_status(self);
                }
                // One clock read for what arrived together; a line that steps the clock moves the
                // lines after it onto the new time, so none is stamped behind it.
                let mut now = ctx.now();
                for line in received.lines {
                    let step = self.handle(ctx, &line, now)?;
                    now = Timestamp(now.0.saturating_add(step));
                }
            }
            Some(Input::File(replay)) => {
                self.overlong = replay.overlong;
                let Some(line) = Self::next_replayed(replay, &self.decoder, ctx)? else {
                    self.write_held(ctx)?;
                    return Err(ComponentError::EndOfStream);
                };
                let now = ctx.now();
                self.handle(ctx, &line, now)?;
                // After a step, the schedule goes on from the stepping sentence at its new arrival time:
                // anchored on the next line instead, a line later in the file would be replayed as if
                // it came when this one did, and every reference would find the clock that much ahead.
                if let Some(anchor) = self.clock_stepped.take()
                    && let Some(Input::File(replay)) = &mut self.input
                {
                    replay.anchor = Some(anchor);
                }
            }
            None => return Err(ComponentError::Stopped),
        }
        Ok(())
    }

    fn death(&mut self, _ctx: &mut Context) -> ComponentResult {
        self.input = None;
        Ok(())
    }

    fn status(&self) -> Option<serde_json::Value> {
        Some(serde_json::json!({
            "kind": "gnss",
            "connected": self.connected,
            "sentences": self.counts.sentences,
            "bad_checksum": self.counts.bad_checksum,
            "malformed": self.counts.malformed,
            "overlong": self.overlong,
        }))
    }

    fn property_changed(&mut self, name: &str, value: &Value, _ctx: &mut Context) -> ComponentResult {
        if name == "accuracy_per_hdop_m"
            && let Some(value) = value.as_f64()
        {
            self.accuracy_per_hdop = value;
        }
        Ok(())
    }
}
