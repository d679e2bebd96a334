//! `kairos merge`: recordings made on several hosts into one file on one timeline, each channel
//! prefixed by its host (`car/camera.image`). Messages stream through in log-time order, a block of
//! each file at a time, so files far larger than memory merge.

use std::collections::{BTreeMap, HashMap, VecDeque};
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use mcap::records::{MessageHeader, Metadata};

use crate::timeline::{RawMessage, RecordingIndex};

/// Why a merge was refused. (Causes are part of each message, not a `source`: `kairos` prints errors
/// with their causes, and would say them twice.)
#[derive(Debug, thiserror::Error)]
pub enum MergeError {
    /// One recording makes no merge.
    #[error("give at least two recordings to merge")]
    TooFew,
    /// Two inputs under one host name would mix their channels.
    #[error(
        "{} and {} would both put their channels under '{host}/': name them, e.g. car={} roadside={}",
        .first.display(), .second.display(), .first.display(), .second.display()
    )]
    SameHost {
        /// The host name given twice.
        host: String,
        /// The first input with it.
        first: PathBuf,
        /// The second.
        second: PathBuf,
    },
    /// Writing over an input would destroy it.
    #[error("{} is an input: choose another output", .0.display())]
    OutputIsInput(PathBuf),
    /// An input that cannot be opened or read.
    #[error("{0}")]
    Recording(crate::timeline::RecordingError),
    /// Clocks not locked to one master: refused unless allowed.
    #[error(
        "the recordings were not made on synchronised clocks, so their times do not line up: {}. Record with the hosts' clocks locked to one clock master (kairos serve --clock-master on one, --clock-slave-of on the others), or pass --allow-unsynchronised to merge anyway (the merged file says so)",
        .0.join("; ")
    )]
    Unsynchronised(Vec<String>),
    /// Damaged inputs: refused unless allowed.
    #[error(
        "damaged recordings: {}. Merged, they would lose what is past the damage: see `kairos inspect` on each, `kairos recover` one that was not closed, or pass --allow-damaged to merge what is intact (the merged file says what was lost)",
        .0.join("; ")
    )]
    Damaged(Vec<String>),
    /// The output could not be made.
    #[error("cannot create {}: {error}", .path.display())]
    Create {
        /// The output.
        path: PathBuf,
        /// What the system said.
        error: std::io::Error,
    },
    /// The output could not be written (a full disk).
    #[error("cannot write {}: {error}", .path.display())]
    Write {
        /// The output.
        path: PathBuf,
        /// What the writer said.
        error: mcap::McapError,
    },
}

/// What a merge wrote.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Merged {
    /// Messages written.
    pub messages: u64,
    /// The channels written, prefixed.
    pub channels: Vec<String>,
    /// Files whose clock was not locked, with their state, when the merge was allowed anyway.
    pub unsynchronised: Vec<String>,
    /// Damaged files, with what was lost, when the merge was allowed anyway.
    pub damaged: Vec<String>,
}

/// What a merge lets through that it refuses by default.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MergeOptions {
    /// Recordings whose clocks did not line up (the merged file says so).
    pub allow_unsynchronised: bool,
    /// Damaged or truncated recordings, of which what is intact is merged (the merged file says what
    /// was lost).
    pub allow_damaged: bool,
}

/// The name under which the merged file's `kairos.merge` record lists damaged inputs.
pub const DAMAGED_INPUTS: &str = "DAMAGED INPUTS";

/// Whether a recording's `kairos.clock` record says its times line up with the rig's: recorded locked
/// to the clock master, or on the master itself.
pub fn clock_agrees(clock: &BTreeMap<String, String>) -> bool {
    matches!(clock.get("state").map(String::as_str), Some("locked" | "master"))
}

/// Of `files` (each named as the user knows it), those whose times do not line up with the others', with
/// their clock's state: none when every clock was locked to the master or was it, or when one runtime
/// made them all (the same clock, down to the epoch it read at start).
pub fn unsynchronised<'a>(files: impl IntoIterator<Item = (String, &'a RecordingIndex)>) -> Vec<String> {
    let files: Vec<(String, &RecordingIndex)> = files.into_iter().collect();
    let descriptions: Vec<Option<&String>> = files
        .iter()
        .map(|(_, index)| index.clock().and_then(|c| c.get("description")))
        .collect();
    if descriptions.iter().all(|d| d.is_some() && *d == descriptions[0]) {
        return Vec::new();
    }
    files
        .iter()
        .filter(|(_, index)| !index.clock().is_some_and(clock_agrees))
        .map(|(name, index)| {
            let state = index
                .clock()
                .and_then(|c| c.get("state").cloned())
                .unwrap_or_else(|| "unknown".to_owned());
            format!("{name}: clock {state}")
        })
        .collect()
}

/// One input: its host name (the channels' prefix) and its file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MergeInput {
    /// The prefix.
    pub host: String,
    /// The recording.
    pub path: PathBuf,
}

impl MergeInput {
    /// `HOST=FILE`, or `FILE` (the host is then the file's stem).
    pub fn parse(argument: &str) -> MergeInput {
        match argument.split_once('=') {
            Some((host, path)) if !host.is_empty() && !host.contains('/') => MergeInput {
                host: host.to_owned(),
                path: PathBuf::from(path),
            },
            _ => {
                let path = PathBuf::from(argument);
                let host = path
                    .file_stem()
                    .map_or_else(|| "recording".to_owned(), |s| s.to_string_lossy().into_owned());
                MergeInput { host, path }
            }
        }
    }
}

struct Source {
    host: String,
    index: Arc<RecordingIndex>,
    next_block: usize,
    pending: VecDeque<RawMessage>,
}

impl Source {
    /// The log time of the next message, reading the next block when the last one is used up.
    fn peek(&mut self) -> Result<Option<u64>, MergeError> {
        while self.pending.is_empty() && self.next_block < self.index.block_count() {
            let block = self
                .index
                .read_block(self.next_block)
                .map_err(MergeError::Recording)?;
            self.next_block += 1;
            self.pending.extend(block);
        }
        Ok(self.pending.front().map(|m| m.log_time))
    }
}

/// Merges `inputs` into `output`. Recordings from different hosts must have been made with their clocks
/// locked to one master or on the master itself (or by one runtime, on one clock), or the merge is
/// refused naming each file and its clock's state, unless `options.allow_unsynchronised`. A damaged or
/// truncated input is refused, naming what it holds and what it lost, unless `options.allow_damaged`.
/// What was let through is written in the merged file's `kairos.merge` record.
pub fn merge(inputs: &[MergeInput], output: &Path, options: MergeOptions) -> Result<Merged, MergeError> {
    check_names(inputs, output)?;
    let mut sources = open_sources(inputs)?;
    let unsynchronised = unsynchronised(
        sources
            .iter()
            .zip(inputs)
            .map(|(s, i)| (format!("{} ({})", i.path.display(), i.host), &*s.index)),
    );
    if !unsynchronised.is_empty() && !options.allow_unsynchronised {
        return Err(MergeError::Unsynchronised(unsynchronised));
    }
    let damaged: Vec<String> = sources
        .iter()
        .zip(inputs)
        .filter_map(|(source, input)| {
            let damage = source.index.damage()?;
            let kept: u64 = source.index.channels().iter().map(|c| c.messages).sum();
            Some(format!(
                "{} ({}): {damage}; {kept} messages intact",
                input.path.display(),
                input.host
            ))
        })
        .collect();
    if !damaged.is_empty() && !options.allow_damaged {
        return Err(MergeError::Damaged(damaged));
    }
    let file = File::create(output).map_err(|error| MergeError::Create {
        path: output.to_owned(),
        error,
    })?;
    let writer = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .profile("kairos")
        .create(BufWriter::new(file))
        .map_err(|e| write_error(output, e))?;
    let mut out = Output {
        path: output,
        writer,
        channels: HashMap::new(),
        schemas: HashMap::new(),
        topics: Vec::new(),
        sequences: HashMap::new(),
    };
    let mut messages = 0;
    while let Some(at) = earliest(&mut sources)? {
        let Some(message) = sources[at].pending.pop_front() else {
            break;
        };
        if out.write(&sources[at], at, &message)? {
            messages += 1;
        }
    }
    let mut about = BTreeMap::new();
    for (source, input) in sources.iter().zip(inputs) {
        let clock = source.index.clock().map_or_else(
            || "unknown".to_owned(),
            |c| {
                c.iter()
                    .map(|(k, v)| format!("{k}={v}"))
                    .collect::<Vec<_>>()
                    .join(" ")
            },
        );
        about.insert(
            format!("host {}", source.host),
            format!("{} · clock {clock}", input.path.display()),
        );
    }
    if !unsynchronised.is_empty() {
        about.insert("UNSYNCHRONISED CLOCKS".to_owned(), unsynchronised.join("; "));
    }
    if !damaged.is_empty() {
        about.insert(DAMAGED_INPUTS.to_owned(), damaged.join("; "));
    }
    out.writer
        .write_metadata(&Metadata {
            name: "kairos.merge".to_owned(),
            metadata: about,
        })
        .map_err(|e| write_error(output, e))?;
    out.writer.finish().map_err(|e| write_error(output, e))?;
    Ok(Merged {
        messages,
        channels: out.topics,
        unsynchronised,
        damaged,
    })
}

fn write_error(path: &Path, error: mcap::McapError) -> MergeError {
    MergeError::Write {
        path: path.to_owned(),
        error,
    }
}

/// Refuses two inputs under one host name, and an output that is an input.
fn check_names(inputs: &[MergeInput], output: &Path) -> Result<(), MergeError> {
    if inputs.len() < 2 {
        return Err(MergeError::TooFew);
    }
    let mut hosts: BTreeMap<&str, &Path> = BTreeMap::new();
    for input in inputs {
        if let Some(first) = hosts.insert(&input.host, &input.path) {
            return Err(MergeError::SameHost {
                host: input.host.clone(),
                first: first.to_owned(),
                second: input.path.clone(),
            });
        }
        if input
            .path
            .canonicalize()
            .ok()
            .is_some_and(|p| output.canonicalize().ok() == Some(p))
        {
            return Err(MergeError::OutputIsInput(output.to_owned()));
        }
    }
    Ok(())
}

/// The inputs' indexes.
fn open_sources(inputs: &[MergeInput]) -> Result<Vec<Source>, MergeError> {
    inputs
        .iter()
        .map(|input| {
            Ok(Source {
                host: input.host.clone(),
                index: RecordingIndex::open(&input.path).map_err(MergeError::Recording)?,
                next_block: 0,
                pending: VecDeque::new(),
            })
        })
        .collect()
}

/// The source whose next message was logged first.
fn earliest(sources: &mut [Source]) -> Result<Option<usize>, MergeError> {
    let mut best: Option<(usize, u64)> = None;
    for (at, source) in sources.iter_mut().enumerate() {
        if let Some(time) = source.peek()?
            && best.is_none_or(|(_, t)| time < t)
        {
            best = Some((at, time));
        }
    }
    Ok(best.map(|(at, _)| at))
}

/// The merged file, and the channels and schemas written to it so far.
struct Output<'a> {
    path: &'a Path,
    writer: mcap::Writer<BufWriter<File>>,
    /// (source, channel) → the merged file's channel id; schema (name, data) → its id.
    channels: HashMap<(usize, u16), u16>,
    schemas: HashMap<(String, Vec<u8>), u16>,
    topics: Vec<String>,
    sequences: HashMap<u16, u32>,
}

impl Output<'_> {
    /// Writes `message` of `source` (number `at`), defining its channel on first use; false when the
    /// source does not define the channel.
    fn write(&mut self, source: &Source, at: usize, message: &RawMessage) -> Result<bool, MergeError> {
        let channel = if let Some(id) = self.channels.get(&(at, message.channel)) {
            *id
        } else {
            let Some(definition) = source.index.channel_definition(message.channel) else {
                return Ok(false);
            };
            let id = self.define(source, definition)?;
            self.channels.insert((at, message.channel), id);
            id
        };
        let sequence = self.sequences.entry(channel).or_insert(0);
        *sequence = sequence.wrapping_add(1);
        let header = MessageHeader {
            channel_id: channel,
            sequence: *sequence,
            log_time: message.log_time,
            publish_time: message.publish_time,
        };
        self.writer
            .write_to_known_channel(&header, &message.data)
            .map_err(|e| write_error(self.path, e))?;
        Ok(true)
    }

    fn define(&mut self, source: &Source, definition: &mcap::Channel<'static>) -> Result<u16, MergeError> {
        let schema = match &definition.schema {
            Some(schema) => {
                let key = (schema.name.clone(), schema.data.to_vec());
                if let Some(id) = self.schemas.get(&key) {
                    *id
                } else {
                    let id = self
                        .writer
                        .add_schema(&schema.name, &schema.encoding, &schema.data)
                        .map_err(|e| write_error(self.path, e))?;
                    self.schemas.insert(key, id);
                    id
                }
            }
            None => 0,
        };
        let topic = format!("{}/{}", source.host, definition.topic);
        let mut metadata = definition.metadata.clone();
        metadata.insert("kairos.host".to_owned(), source.host.clone());
        let id = self
            .writer
            .add_channel(schema, &topic, &definition.message_encoding, &metadata)
            .map_err(|e| write_error(self.path, e))?;
        self.topics.push(topic);
        Ok(id)
    }
}
