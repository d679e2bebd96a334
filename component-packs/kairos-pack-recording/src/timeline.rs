//! A recording opened for replay: its channels, an index of its blocks (chunks, or messages outside
//! chunks) with their time ranges, and where a damaged file stops being readable.
//!
//! Opening walks the file's top-level records once with [`crate::safe_read::walk`], which reads each block
//! through the length-limited, CRC-checking reader and leaves damaged chunks out whole; nothing is kept in
//! memory but the index. Replay then reads
//! one block at a time by its offset, so a recording of any size replays in bounded memory, and seeking
//! is a binary search over block times.

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::os::unix::fs::FileExt as _;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::SystemTime;

use crate::safe_read::{Catalog, read_records, walk};

/// Why a recording cannot be opened or read.
#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    /// A folder that cannot be listed.
    #[error("cannot list {}: {source}", .path.display())]
    List {
        /// The folder.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// A folder without a recording in it.
    #[error("a folder with no MCAP or .db3 file")]
    NoRecording,
    /// A folder of a split recording: which file first is the user's to say.
    #[error(
        "a folder of {count} MCAP files (a split recording): give them as path, path2, ... in order, first {}",
        .first.display()
    )]
    Split {
        /// How many MCAP files.
        count: usize,
        /// The first by name.
        first: PathBuf,
    },
    /// A `SQLite` bag that could not be converted.
    #[error(transparent)]
    Db3(#[from] crate::ros2::db3::Db3Error),
    /// Missing, or not readable by this user.
    #[error("cannot read {}: {source}", .path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// The file could not be opened.
    #[error("cannot open {}: {source}", .path.display())]
    Open {
        /// The file.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// Not an MCAP file at all.
    #[error("{} is not an MCAP recording (it does not start with the MCAP magic bytes)", .0.display())]
    NotMcap(PathBuf),
    /// A block that could not be read again.
    #[error("cannot read {} at byte {offset}: {source}", .path.display())]
    ReadAt {
        /// The file.
        path: PathBuf,
        /// Where the block starts.
        offset: u64,
        /// What the system said.
        source: std::io::Error,
    },
    /// The file was changed under the index: a block it found whole is now damaged.
    #[error("{} changed since it was opened: the record at byte {offset} is damaged: {damage}", .path.display())]
    Changed {
        /// The file.
        path: PathBuf,
        /// Where the block starts.
        offset: u64,
        /// The damage, as the reader describes it.
        damage: String,
    },
}

/// The MCAP file a path names: `path` itself, or the one file of a rosbag2 folder (`metadata.yaml` beside
/// its storage files), as `ros2 bag record` leaves it. A `SQLite` bag (`.db3`, or a folder of them) is
/// converted once to MCAP ([`crate::ros2::db3`]) and that file named.
pub fn recording_file(path: &Path) -> Result<PathBuf, RecordingError> {
    let has_extension = |file: &Path, wanted: &str| file.extension().is_some_and(|e| e == wanted);
    if !path.is_dir() {
        if has_extension(path, "db3") {
            return Ok(crate::ros2::db3::as_mcap(&[path.to_owned()])?);
        }
        return Ok(path.to_owned());
    }
    let mut files: Vec<PathBuf> = std::fs::read_dir(path)
        .map_err(|source| RecordingError::List {
            path: path.to_owned(),
            source,
        })?
        .map_while(Result::ok)
        .map(|entry| entry.path())
        .collect();
    files.sort();
    let mcap: Vec<&PathBuf> = files.iter().filter(|f| has_extension(f, "mcap")).collect();
    let db3: Vec<PathBuf> = files
        .iter()
        .filter(|f| has_extension(f, "db3"))
        .cloned()
        .collect();
    match mcap.as_slice() {
        [one] => Ok((*one).clone()),
        [] if !db3.is_empty() => Ok(crate::ros2::db3::as_mcap(&db3)?),
        [] => Err(RecordingError::NoRecording),
        several => Err(RecordingError::Split {
            count: several.len(),
            first: several[0].clone(),
        }),
    }
}

/// One recorded channel.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChannelEntry {
    /// The channel's id in its file.
    pub id: u16,
    /// The topic (`camera.image`).
    pub topic: String,
    /// The schema's name (`foxglove.RawImage`, `kairos.F64`); empty for schemaless channels.
    pub schema: String,
    /// The message encoding (`protobuf`, `json`, ...).
    pub encoding: String,
    /// Intact messages.
    pub messages: u64,
}

/// A run of messages read together: one chunk, or one message outside any chunk.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Block {
    offset: u64,
    length: u64,
    first_log_time: u64,
    last_log_time: u64,
}

/// One message as recorded.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RawMessage {
    /// Its channel's id.
    pub channel: u16,
    /// MCAP log time: the sample's time of issue.
    pub log_time: u64,
    /// MCAP publish time: the sample's timestamp.
    pub publish_time: u64,
    /// The encoded payload.
    pub data: Vec<u8>,
}

/// The index of one recording.
#[derive(Debug)]
pub struct RecordingIndex {
    path: PathBuf,
    file: File,
    catalog: Catalog,
    channels: Vec<ChannelEntry>,
    blocks: Vec<Block>,
    damage: Option<String>,
    /// Markers: log time and text, in time order.
    markers: Vec<(u64, String)>,
    /// The last `kairos.clock` metadata record: the recording clock's source and state.
    clock: Option<BTreeMap<String, String>>,
}

type CacheKey = (PathBuf, u64, Option<SystemTime>);

/// Indexes already built, so validating, building and starting a diagram read a file once.
fn cache() -> &'static Mutex<HashMap<CacheKey, Arc<RecordingIndex>>> {
    static CACHE: OnceLock<Mutex<HashMap<CacheKey, Arc<RecordingIndex>>>> = OnceLock::new();
    CACHE.get_or_init(|| Mutex::new(HashMap::new()))
}

const CACHE_ENTRIES: usize = 16;

impl RecordingIndex {
    /// Opens and indexes `path`, or returns the index already built for the file as it is now.
    ///
    /// A damaged file opens: the index stops before the damage, which [`Self::damage`] describes. Only a
    /// file that cannot be read at all, or is not MCAP, is an error.
    pub fn open(path: &Path) -> Result<Arc<RecordingIndex>, RecordingError> {
        let metadata = std::fs::metadata(path).map_err(|source| RecordingError::Read {
            path: path.to_owned(),
            source,
        })?;
        let key = (path.to_owned(), metadata.len(), metadata.modified().ok());
        let mut cache = cache().lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some(index) = cache.get(&key) {
            return Ok(Arc::clone(index));
        }
        let index = Arc::new(Self::scan(path)?);
        if cache.len() >= CACHE_ENTRIES {
            cache.clear();
        }
        cache.insert(key, Arc::clone(&index));
        Ok(index)
    }

    fn scan(path: &Path) -> Result<RecordingIndex, RecordingError> {
        let file = File::open(path).map_err(|source| RecordingError::Open {
            path: path.to_owned(),
            source,
        })?;
        let mut magic = [0_u8; 8];
        if file.read_exact_at(&mut magic, 0).is_err() || magic[..] != *mcap::MAGIC {
            return Err(RecordingError::NotMcap(path.to_owned()));
        }
        let mut index = RecordingIndex {
            path: path.to_owned(),
            file,
            catalog: Catalog::default(),
            channels: Vec::new(),
            blocks: Vec::new(),
            damage: None,
            markers: Vec::new(),
            clock: None,
        };
        let mut clock = None;
        let mut markers = Vec::new();
        let mut channels: BTreeMap<u16, ChannelEntry> = BTreeMap::new();
        let mut blocks = Vec::new();
        let walked = walk(
            &index.file,
            Catalog::default(),
            |block| {
                let mut times: Option<(u64, u64)> = None;
                for message in block.messages {
                    let channel = &message.channel;
                    channels
                        .entry(channel.id)
                        .or_insert_with(|| ChannelEntry {
                            id: channel.id,
                            topic: channel.topic.clone(),
                            schema: channel
                                .schema
                                .as_ref()
                                .map_or_else(String::new, |s| s.name.clone()),
                            encoding: channel.message_encoding.clone(),
                            messages: 0,
                        })
                        .messages += 1;
                    if is_markers_topic(&channel.topic) {
                        let schema = channel.schema.as_ref().map_or("", |s| s.name.as_str());
                        if let Ok(kairos_sdk::Payload::Text(text)) =
                            crate::decode::decode(schema, &message.data)
                        {
                            markers.push((message.log_time, text.to_string()));
                        }
                    }
                    let (first, last) = times.get_or_insert((message.log_time, message.log_time));
                    *first = (*first).min(message.log_time);
                    *last = (*last).max(message.log_time);
                }
                if let Some((first_log_time, last_log_time)) = times {
                    blocks.push(Block {
                        offset: block.offset,
                        length: block.length,
                        first_log_time,
                        last_log_time,
                    });
                }
            },
            |metadata| {
                if metadata.name == "kairos.clock" {
                    clock = Some(metadata.metadata);
                }
            },
            |_| {},
        )
        .map_err(|source| RecordingError::Read {
            path: path.to_owned(),
            source,
        })?;
        index.blocks = blocks;
        index.clock = clock;
        markers.sort_by_key(|(at, _)| *at);
        index.markers = markers;
        index.damage = walked.summary();
        index.catalog = walked.catalog;
        index.channels = channels.into_values().collect();
        index
            .channels
            .sort_by(|a, b| a.topic.cmp(&b.topic).then(a.id.cmp(&b.id)));
        Ok(index)
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The markers in the file (written by a recorder's mark action or input): log time and text, in
    /// time order.
    pub fn markers(&self) -> &[(u64, String)] {
        &self.markers
    }

    /// The recording clock as the file last recorded it (`kairos.clock`: source, state, error), when it
    /// says.
    pub fn clock(&self) -> Option<&BTreeMap<String, String>> {
        self.clock.as_ref()
    }

    /// The full definition (schema included) of channel `id`.
    pub fn channel_definition(&self, id: u16) -> Option<&Arc<mcap::Channel<'static>>> {
        self.catalog.channel(id)
    }

    /// The channels that have intact messages, by topic.
    pub fn channels(&self) -> &[ChannelEntry] {
        &self.channels
    }

    /// What is damaged in the file (chunks left out, where it stops); every intact block replays.
    pub fn damage(&self) -> Option<&str> {
        self.damage.as_deref()
    }

    /// How many blocks replay.
    pub fn block_count(&self) -> usize {
        self.blocks.len()
    }

    /// The log time of the first intact message.
    pub fn first_log_time(&self) -> Option<u64> {
        self.blocks.iter().map(|b| b.first_log_time).min()
    }

    /// The log time of the last intact message.
    pub fn last_log_time(&self) -> Option<u64> {
        self.blocks.iter().map(|b| b.last_log_time).max()
    }

    /// The first block that may hold a message logged at or after `log_time`.
    pub fn block_at(&self, log_time: u64) -> usize {
        // Blocks are in file order, which is time order for files written live; the running maximum of
        // their last times is monotonic even where chunks overlap a little.
        let mut latest = 0;
        self.blocks
            .iter()
            .position(|b| {
                latest = latest.max(b.last_log_time);
                latest >= log_time
            })
            .unwrap_or(self.blocks.len())
    }

    /// The messages of block `block`, by log time (ties in file order).
    pub fn read_block(&self, block: usize) -> Result<Vec<RawMessage>, RecordingError> {
        let Some(entry) = self.blocks.get(block) else {
            return Ok(Vec::new());
        };
        let mut bytes = vec![0_u8; usize::try_from(entry.length).unwrap_or(0)];
        self.file
            .read_exact_at(&mut bytes, entry.offset)
            .map_err(|source| RecordingError::ReadAt {
                path: self.path.clone(),
                offset: entry.offset,
                source,
            })?;
        let mut messages = Vec::new();
        let damage = read_records(
            &bytes,
            false,
            &mut self.catalog.clone(),
            |message| {
                messages.push(RawMessage {
                    channel: message.channel.id,
                    log_time: message.log_time,
                    publish_time: message.publish_time,
                    data: message.data.to_vec(),
                });
            },
            |_| {},
        );
        if let Some(damage) = damage {
            return Err(RecordingError::Changed {
                path: self.path.clone(),
                offset: entry.offset,
                damage,
            });
        }
        messages.sort_by_key(|m| m.log_time);
        Ok(messages)
    }
}

/// The channel markers are written on (text messages), for the player's timeline and for Foxglove.
pub const MARKERS_TOPIC: &str = "kairos.markers";

/// Whether `topic` carries markers: the recorder's own, or one prefixed by `kairos merge` (`car/kairos.markers`).
pub fn is_markers_topic(topic: &str) -> bool {
    topic == MARKERS_TOPIC
        || topic
            .strip_suffix(MARKERS_TOPIC)
            .is_some_and(|host| host.ends_with('/'))
}

/// Seconds (a property's value) as nanoseconds on a recording's timeline.
pub(crate) fn seconds_to_nanos(seconds: f64) -> i64 {
    #[allow(
        clippy::cast_possible_truncation,
        reason = "property ranges keep it far inside i64"
    )]
    let nanos = (seconds * 1e9).round() as i64;
    nanos
}
