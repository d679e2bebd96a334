//! Reading a recording back for `kairos inspect`: channels, types, counts, rates, duration, metadata, and
//! where a damaged file stops being readable.

use std::collections::BTreeMap;
use std::path::Path;

use mcap::read::Summary;
use serde::Serialize;

use crate::safe_read::{Catalog, DamagedRegion};

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
    /// How many messages the file's summary counts, when it has one: more than `messages` when chunks
    /// are damaged.
    pub summary_messages: Option<u64>,
    /// Messages left out in damaged chunks, as far as their message indexes tell.
    pub messages_left_out: u64,
    /// The damaged chunks (and other records) left out, in file order: offset, length, messages, reason.
    pub damaged_chunks: Vec<DamagedRegion>,
    /// The damage in one line: each damaged chunk, and where a file that was not closed stops.
    pub damage: Option<String>,
    /// Said when the file comes from a host that followed a clock master and was recorded while that
    /// clock was not locked: its times may not line up with other hosts' recordings.
    pub clock_warning: Option<String>,
    /// For a merged file made with `--allow-damaged`: the damaged inputs and what they lost. Such a
    /// file is whole, but its data is not (`kairos inspect` exits 3, as for a damaged file).
    pub input_damage: Option<String>,
    /// How a file that was not closed ends (the last part of `damage`).
    #[serde(skip)]
    ending: Option<String>,
}

/// What to say of a recording's `kairos.clock` record when its clock followed a master (or another
/// source) without being locked to it: `recorded while its clock was acquiring (following master
/// 10.0.0.1:7401)`. Nothing for a clock that was locked, or that was this machine's own.
pub fn unlocked_clock(clock: &BTreeMap<String, String>) -> Option<String> {
    let state = clock.get("state").map_or("unknown", String::as_str);
    let source = clock.get("source").map_or("unknown", String::as_str);
    (!crate::merge::clock_agrees(clock) && source != "this machine").then(|| {
        format!(
            "recorded while its clock was {state} (following {source}): its times may not line up with \
             other hosts' recordings"
        )
    })
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
    // A rosbag2 folder: its MCAP file.
    let file = crate::timeline::recording_file(path).map_err(|reason| InspectError::NotMcap {
        path: shown.clone(),
        reason: reason.to_string(),
    })?;
    let path = file.as_path();
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
    mut on_progress: impl FnMut(usize),
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
    let catalog = summary
        .as_ref()
        .map_or_else(Catalog::default, Catalog::from_summary);
    // Count by reading every message: it works the same on complete and damaged files, and a damaged
    // chunk's messages are not counted.
    let mut tallies: BTreeMap<String, Tally> = BTreeMap::new();
    let walked = crate::safe_read::walk(
        bytes,
        catalog,
        |block| {
            for message in block.messages {
                let channel = &message.channel;
                let tally = tallies.entry(channel.topic.clone()).or_insert_with(|| Tally {
                    schema: channel
                        .schema
                        .as_ref()
                        .map_or_else(String::new, |s| s.name.clone()),
                    encoding: channel.message_encoding.clone(),
                    kairos_type: channel.metadata.get("kairos.type").cloned().or_else(|| {
                        // A rosbag2 channel: the type it replays as.
                        channel
                            .schema
                            .as_ref()
                            .filter(|s| s.encoding == crate::ros2::SCHEMA_ENCODING)
                            .map(|s| crate::ros2::data_type_of(&s.name).to_string())
                    }),
                    first: message.publish_time,
                    ..Tally::default()
                });
                tally.messages += 1;
                tally.first = tally.first.min(message.publish_time);
                tally.last = tally.last.max(message.publish_time);
            }
        },
        // The last record of a name wins: the recorder rewrites its drop counts as it goes.
        |record| {
            metadata.insert(record.name, record.metadata);
        },
        |done| on_progress(usize::try_from(done).unwrap_or(usize::MAX)),
    )
    .map_err(|error| InspectError::Io {
        path: shown.clone(),
        error,
    })?;
    let ending = if let Some(cut) = &walked.cut_short {
        Some(format!("{cut}; every chunk before it is intact"))
    } else if !complete {
        Some("the file has no summary: it was not closed (a crash?); every closed chunk is intact".to_owned())
    } else {
        None
    };
    let damage: Vec<String> = walked
        .damaged
        .iter()
        .map(ToString::to_string)
        .chain(ending.clone())
        .collect();
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
        clock_warning: metadata.get("kairos.clock").and_then(unlocked_clock),
        input_damage: metadata
            .get("kairos.merge")
            .and_then(|merge| merge.get(crate::merge::DAMAGED_INPUTS).cloned()),
        metadata,
        summary_messages: summary.and_then(|s| s.stats).map(|stats| stats.message_count),
        messages_left_out: walked.messages_left_out(),
        damaged_chunks: walked.damaged,
        damage: (!damage.is_empty()).then(|| damage.join("; ")),
        ending,
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
        if let Some(warning) = &self.clock_warning {
            let _ = writeln!(out, "warning: {warning}");
        }
        if let Some(damage) = &self.input_damage {
            let _ = writeln!(
                out,
                "warning: merged from damaged recordings, what was past their damage is missing: {damage}"
            );
        }
        let width = self
            .channels
            .iter()
            .map(|c| c.topic.len())
            .max()
            .unwrap_or(5)
            .max(5);
        let schema_width = self
            .channels
            .iter()
            .map(|c| c.schema.len())
            .max()
            .unwrap_or(0)
            .max(24);
        let _ = writeln!(
            out,
            "\n{:<width$}  {:<schema_width$} {:<14} {:>9} {:>9}",
            "topic", "schema", "type", "messages", "rate/s"
        );
        for channel in &self.channels {
            let _ = writeln!(
                out,
                "{:<width$}  {:<schema_width$} {:<14} {:>9} {:>9.2}",
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
        if !self.damaged_chunks.is_empty() {
            let _ = writeln!(
                out,
                "\n{} damaged chunk(s) left out, holding {}{} messages:",
                self.damaged_chunks.len(),
                if self.damaged_chunks.iter().any(|d| d.messages.is_none()) {
                    "at least "
                } else {
                    ""
                },
                self.messages_left_out,
            );
            for region in &self.damaged_chunks {
                let _ = writeln!(out, "  {region}");
            }
            if let Some(total) = self.summary_messages {
                let _ = writeln!(
                    out,
                    "  the summary counts {total} messages; {} are intact",
                    self.messages
                );
            }
        }
        if let Some(ending) = &self.ending {
            let _ = writeln!(out, "\ndamage: {ending}");
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use super::inspect_bytes;

    /// An MCAP file in memory holding one `kairos.clock` record.
    fn recording_with_clock(source: &str, state: &str) -> Vec<u8> {
        let mut bytes = std::io::Cursor::new(Vec::new());
        let mut writer = mcap::Writer::new(&mut bytes).unwrap();
        writer
            .write_metadata(&mcap::records::Metadata {
                name: "kairos.clock".to_owned(),
                metadata: BTreeMap::from([
                    ("source".to_owned(), source.to_owned()),
                    ("state".to_owned(), state.to_owned()),
                ]),
            })
            .unwrap();
        writer.finish().unwrap();
        drop(writer);
        bytes.into_inner()
    }

    #[test]
    fn a_recording_made_on_a_clock_not_locked_to_its_master_says_so() {
        let acquiring = recording_with_clock("master 10.0.0.1:7401", "acquiring");
        let report = inspect_bytes("car.mcap", &acquiring).unwrap();
        let warning = report.clock_warning.clone().unwrap();
        assert!(
            warning.contains("clock was acquiring (following master 10.0.0.1:7401)"),
            "{warning}"
        );
        assert!(report.text().contains(&format!("warning: {warning}")));
        for (source, state) in [
            ("master 10.0.0.1:7401", "locked"),
            ("this machine", "free"),
            ("this machine (the clock master)", "master"),
        ] {
            let report = inspect_bytes("car.mcap", &recording_with_clock(source, state)).unwrap();
            assert_eq!(report.clock_warning, None, "{source}: {state}");
        }
    }
}
