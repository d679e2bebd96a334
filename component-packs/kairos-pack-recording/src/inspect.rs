//! Reading a recording back for `kairos inspect`: channels, types, counts, rates, duration, metadata, and
//! where a damaged file stops being readable.

use std::collections::BTreeMap;
use std::path::Path;

use mcap::read::Summary;
use serde::Serialize;

/// One channel of a recording.
#[derive(Debug, Clone, Serialize)]
pub struct ChannelReport {
    /// The topic (the recorded output, `camera.image`).
    pub topic: String,
    /// The schema's name (`foxglove.RawImage`, `kairos.F64`).
    pub schema: String,
    /// The message encoding.
    pub encoding: String,
    /// The Kairos data type, when the recorder wrote it.
    pub kairos_type: Option<String>,
    /// Messages on the channel.
    pub messages: u64,
    /// Messages per second between the first and the last (publish times), to the thousandth.
    pub rate_hz: f64,
}

/// What a recording holds.
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    /// The file.
    pub path: String,
    /// Its size.
    pub size_bytes: u64,
    /// Whether it ends properly with a summary (false after a crash: `kairos recover` rewrites it).
    pub complete: bool,
    /// All messages.
    pub messages: u64,
    /// Which of the messages' times `start_ns`, `end_ns`, `duration_s` and the rates use: always
    /// `publish_time`, the samples' timestamps (`log_time` is when the recorder wrote them).
    pub time: String,
    /// First publish time (the samples' timestamps), ns since the UNIX epoch.
    pub start_ns: u64,
    /// Last publish time.
    pub end_ns: u64,
    /// `end − start`, in seconds, to the microsecond.
    pub duration_s: f64,
    /// Per channel, by topic.
    pub channels: Vec<ChannelReport>,
    /// Metadata records, by name.
    pub metadata: BTreeMap<String, BTreeMap<String, String>>,
    /// Where reading stopped on a damaged file, and why.
    pub damage: Option<String>,
}

/// `value` rounded to `1 / scale` (1e3: thousandths), so reports print figures a person reads, not
/// floating-point noise.
fn round_to(value: f64, scale: f64) -> f64 {
    (value * scale).round() / scale
}

/// Why a file could not be inspected at all.
#[derive(Debug, thiserror::Error)]
pub enum InspectError {
    /// It could not be read.
    // The system's reason is part of the message and not a `source`: printed with its causes (as `kairos`
    // prints errors), a source would say it twice.
    #[error("cannot read {path}: {error}")]
    Io {
        /// The file.
        path: String,
        /// Why.
        error: std::io::Error,
    },
    /// It is not MCAP.
    #[error("{path} is not an MCAP recording: {reason}")]
    NotMcap {
        /// The file.
        path: String,
        /// Why.
        reason: String,
    },
}

#[derive(Default)]
struct Tally {
    schema: String,
    encoding: String,
    kairos_type: Option<String>,
    messages: u64,
    first: u64,
    last: u64,
}

/// Reads `path`; a damaged file is read as far as it is intact and the damage reported.
pub fn inspect(path: &Path) -> Result<Report, InspectError> {
    inspect_with_progress(path, |_| {})
}

/// What [`inspect_with_progress`] is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Progress {
    /// Reading the file: bytes read, of the total.
    Reading(u64, u64),
    /// Checking and counting its records: bytes done, of the total.
    Checking(u64, u64),
}

/// Like [`inspect`], reporting progress now and then (for a progress bar on large files).
pub fn inspect_with_progress(
    path: &Path,
    mut progress: impl FnMut(Progress),
) -> Result<Report, InspectError> {
    use std::io::Read as _;
    let shown = path.display().to_string();
    let io_error = |error| InspectError::Io {
        path: shown.clone(),
        error,
    };
    let mut file = std::fs::File::open(path).map_err(io_error)?;
    let total = file.metadata().map_err(io_error)?.len();
    let mut bytes = Vec::with_capacity(usize::try_from(total).unwrap_or(0));
    let mut piece = vec![0_u8; 8 << 20];
    loop {
        let read = file.read(&mut piece).map_err(io_error)?;
        if read == 0 {
            break;
        }
        bytes.extend_from_slice(piece.get(..read).unwrap_or_default());
        progress(Progress::Reading(bytes.len() as u64, total));
    }
    inspect_bytes_with_progress(&shown, &bytes, |done| {
        progress(Progress::Checking(done as u64, total));
    })
}

/// Like [`inspect`] for a recording already in memory; `shown` names it in the report.
pub fn inspect_bytes(shown: &str, bytes: &[u8]) -> Result<Report, InspectError> {
    inspect_bytes_with_progress(shown, bytes, |_| {})
}

fn inspect_bytes_with_progress(
    shown: &str,
    bytes: &[u8],
    on_progress: impl FnMut(usize),
) -> Result<Report, InspectError> {
    let shown = shown.to_owned();
    if bytes.get(..8) != Some(mcap::MAGIC) {
        return Err(InspectError::NotMcap {
            path: shown,
            reason: "it does not start with the MCAP magic bytes".to_owned(),
        });
    }
    let summary = Summary::read(bytes).ok().flatten();
    let complete = summary.is_some();
    let mut metadata = BTreeMap::new();
    if let Some(summary) = &summary {
        for index in &summary.metadata_indexes {
            if let Ok(record) = mcap::read::metadata(bytes, index) {
                metadata.insert(record.name, record.metadata);
            }
        }
    }
    // Count by reading every message: it works the same on complete and damaged files.
    let mut tallies: BTreeMap<String, Tally> = BTreeMap::new();
    let mut damage = crate::safe_read::read_intact_with_progress(
        bytes,
        |message| {
            let channel = &message.channel;
            let tally = tallies.entry(channel.topic.clone()).or_insert_with(|| Tally {
                schema: channel
                    .schema
                    .as_ref()
                    .map_or_else(String::new, |s| s.name.clone()),
                encoding: channel.message_encoding.clone(),
                kairos_type: channel.metadata.get("kairos.type").cloned(),
                first: message.publish_time,
                ..Tally::default()
            });
            tally.messages += 1;
            tally.first = tally.first.min(message.publish_time);
            tally.last = tally.last.max(message.publish_time);
        },
        |_| {},
        on_progress,
    )
    .map(|d| format!("{d} (messages before this point are intact)"));
    if !complete && damage.is_none() {
        damage = Some(
            "the file has no summary: it was not closed (a crash?); every closed chunk is intact".to_owned(),
        );
    }
    let messages = tallies.values().map(|t| t.messages).sum();
    let start_ns = tallies.values().map(|t| t.first).min().unwrap_or(0);
    let end_ns = tallies.values().map(|t| t.last).max().unwrap_or(0);
    let channels = tallies
        .into_iter()
        .map(|(topic, t)| {
            let span = (t.last.saturating_sub(t.first)) as f64 * 1e-9;
            ChannelReport {
                topic,
                schema: t.schema,
                encoding: t.encoding,
                kairos_type: t.kairos_type,
                messages: t.messages,
                rate_hz: if span > 0.0 {
                    round_to((t.messages.saturating_sub(1)) as f64 / span, 1e3)
                } else {
                    0.0
                },
            }
        })
        .collect();
    Ok(Report {
        path: shown,
        size_bytes: bytes.len() as u64,
        complete,
        messages,
        time: "publish_time".to_owned(),
        start_ns,
        end_ns,
        duration_s: round_to(end_ns.saturating_sub(start_ns) as f64 * 1e-9, 1e6),
        channels,
        metadata,
        damage,
    })
}

impl Report {
    /// The report as text for people.
    pub fn text(&self) -> String {
        use std::fmt::Write as _;
        let mut out = String::new();
        let _ = writeln!(
            out,
            "{}: {} bytes, {}",
            self.path,
            self.size_bytes,
            if self.complete { "complete" } else { "NOT complete" }
        );
        let _ = writeln!(out, "{} messages over {:.3} s", self.messages, self.duration_s);
        let width = self
            .channels
            .iter()
            .map(|c| c.topic.len())
            .max()
            .unwrap_or(5)
            .max(5);
        let _ = writeln!(
            out,
            "\n{:<width$}  {:<24} {:<14} {:>9} {:>9}",
            "topic", "schema", "type", "messages", "rate/s"
        );
        for channel in &self.channels {
            let _ = writeln!(
                out,
                "{:<width$}  {:<24} {:<14} {:>9} {:>9.2}",
                channel.topic,
                channel.schema,
                channel.kairos_type.as_deref().unwrap_or("-"),
                channel.messages,
                channel.rate_hz
            );
        }
        for (name, entries) in &self.metadata {
            let _ = writeln!(out, "\nmetadata {name}:");
            for (key, value) in entries {
                // Long values (the diagram's text) would drown the rest: `--json` has them whole.
                if value.len() > 160 || value.contains('\n') {
                    let _ = writeln!(out, "  {key}: ({} bytes; see --json)", value.len());
                } else {
                    let _ = writeln!(out, "  {key}: {value}");
                }
            }
        }
        if let Some(damage) = &self.damage {
            let _ = writeln!(out, "\ndamage: {damage}");
        }
        out
    }
}
