//! rosbag2's older storage, `SQLite` (`.db3`, the default before ROS 2 Iron), replayed by converting it
//! once to an MCAP recording: the player, `kairos inspect` and the studio then read it as any other.
//!
//! A `.db3` bag holds a `topics` table (name, type, serialization format) and a `messages` table (topic,
//! receive time, CDR bytes); bags from Iron on add `message_definitions`, the `ros2msg` text of each type.
//! An older bag carries no definitions: the types Kairos itself writes are described from its own
//! definitions ([`super::write::definition_of`]), and any other type's messages are refused, saying so.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use std::ops::ControlFlow;

use super::sqlite::{Database, SqliteError};

/// Where `db3` files (one bag's, in order) are converted to: a file in the system's temporary folder,
/// named after their paths, sizes and modification times, so a bag is converted once and again only when
/// it changes.
pub fn converted_path(db3: &[PathBuf]) -> PathBuf {
    use std::hash::{Hash as _, Hasher as _};
    let mut hasher = std::collections::hash_map::DefaultHasher::new();
    for file in db3 {
        file.canonicalize()
            .unwrap_or_else(|_| file.clone())
            .hash(&mut hasher);
        if let Ok(metadata) = file.metadata() {
            metadata.len().hash(&mut hasher);
            metadata.modified().ok().hash(&mut hasher);
        }
    }
    let stem = db3
        .first()
        .and_then(|f| f.file_stem())
        .map_or_else(|| "bag".to_owned(), |s| s.to_string_lossy().into_owned());
    std::env::temp_dir()
        .join("kairos-rosbag2")
        .join(format!("{stem}-{:016x}.mcap", hasher.finish()))
}

/// Why a `SQLite` bag could not be converted to MCAP: nothing half written is left.
#[derive(Debug, thiserror::Error)]
pub enum Db3Error {
    /// The conversions' folder or file could not be made.
    #[error("cannot create {}: {source}", .path.display())]
    Create {
        /// The folder or file.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// The finished conversion could not be put in place.
    #[error("cannot write {}: {source}", .path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// Writing the MCAP file failed (a full disk).
    #[error("{0}")]
    Mcap(#[from] mcap::McapError),
    /// A bag file that `SQLite` does not read.
    #[error(transparent)]
    Sqlite(#[from] SqliteError),
    /// Which file of a split bag the problem is in.
    #[error("{}: {source}", .path.display())]
    InFile {
        /// The `.db3` file.
        path: PathBuf,
        /// What went wrong with it.
        source: Box<Db3Error>,
    },
}

/// The MCAP recording of the bag made of `db3` (its files in order), converted if not already.
pub fn as_mcap(db3: &[PathBuf]) -> Result<PathBuf, Db3Error> {
    let out = converted_path(db3);
    if out.is_file() {
        return Ok(out);
    }
    let folder = out.parent().unwrap_or_else(|| Path::new("."));
    std::fs::create_dir_all(folder).map_err(|source| Db3Error::Create {
        path: folder.to_owned(),
        source,
    })?;
    // Written beside, then renamed: a conversion cut short never passes for a finished one.
    let partial = out.with_extension("mcap.partial");
    let messages = convert(db3, &partial).inspect_err(|_| {
        let _ = std::fs::remove_file(&partial);
    })?;
    if let Err(source) = std::fs::rename(&partial, &out) {
        return Err(Db3Error::Write { path: out, source });
    }
    tracing::info!(
        "{}: a SQLite rosbag2 recording, converted once to {} ({messages} messages) to replay",
        db3.first().map_or_else(String::new, |f| f.display().to_string()),
        out.display()
    );
    Ok(out)
}

/// One topic of a bag: its type and how its messages are serialised.
struct Topic {
    name: String,
    type_name: String,
    format: String,
}

/// Writes the messages of `db3` to a new MCAP file at `out`; returns how many.
fn convert(db3: &[PathBuf], out: &Path) -> Result<u64, Db3Error> {
    let file = File::create(out).map_err(|source| Db3Error::Create {
        path: out.to_owned(),
        source,
    })?;
    let mut writer = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .profile("ros2")
        .library(concat!("kairos-pack-recording ", env!("CARGO_PKG_VERSION")))
        .create(BufWriter::new(file))?;
    // A topic's channel, by name: the same in every file of a split bag.
    let mut channels: BTreeMap<String, u16> = BTreeMap::new();
    let mut schemas: BTreeMap<String, u16> = BTreeMap::new();
    let mut written = 0_u64;
    for path in db3 {
        let place = |e: Db3Error| Db3Error::InFile {
            path: path.clone(),
            source: Box::new(e),
        };
        let database = Database::open(path).map_err(|e| place(e.into()))?;
        let definitions = definitions_of(&database).map_err(|e| place(e.into()))?;
        let mut topics: BTreeMap<i64, Topic> = BTreeMap::new();
        database
            .query("SELECT id, name, type, serialization_format FROM topics", |row| {
                topics.insert(
                    row.integer(0),
                    Topic {
                        name: row.text(1),
                        type_name: row.text(2),
                        format: row.text(3),
                    },
                );
                ControlFlow::Continue(())
            })
            .map_err(|e| place(e.into()))?;
        let mut by_id: BTreeMap<i64, u16> = BTreeMap::new();
        for (id, topic) in &topics {
            let schema = if let Some(schema) = schemas.get(&topic.type_name) {
                *schema
            } else {
                // No definition in an older bag: an empty one, read with Kairos' own when it has one
                // (`ChannelDecoder::of`), else refused with the reason.
                let definition = definitions.get(&topic.type_name).cloned().unwrap_or_default();
                let schema =
                    writer.add_schema(&topic.type_name, super::SCHEMA_ENCODING, definition.as_bytes())?;
                schemas.insert(topic.type_name.clone(), schema);
                schema
            };
            let channel = if let Some(channel) = channels.get(&topic.name) {
                *channel
            } else {
                let channel = writer.add_channel(schema, &topic.name, &topic.format, &BTreeMap::new())?;
                channels.insert(topic.name.clone(), channel);
                channel
            };
            by_id.insert(*id, channel);
        }
        let mut sequence = 0_u32;
        let mut failure = None;
        database
            .query(
                "SELECT topic_id, timestamp, data FROM messages ORDER BY timestamp, id",
                |row| {
                    let Some(channel) = by_id.get(&row.integer(0)) else {
                        return ControlFlow::Continue(());
                    };
                    let time = u64::try_from(row.integer(1)).unwrap_or(0);
                    let header = mcap::records::MessageHeader {
                        channel_id: *channel,
                        sequence,
                        log_time: time,
                        publish_time: time,
                    };
                    sequence = sequence.wrapping_add(1);
                    if let Err(error) = writer.write_to_known_channel(&header, row.blob(2)) {
                        failure = Some(error);
                        return ControlFlow::Break(());
                    }
                    written += 1;
                    ControlFlow::Continue(())
                },
            )
            .map_err(|e| place(e.into()))?;
        if let Some(error) = failure {
            return Err(place(error.into()));
        }
    }
    writer.finish()?;
    Ok(written)
}

/// The `ros2msg` definitions a bag from ROS 2 Iron on carries, by type; none from an older bag.
fn definitions_of(database: &Database) -> Result<BTreeMap<String, String>, SqliteError> {
    let mut has_table = false;
    database.query(
        "SELECT name FROM sqlite_master WHERE type = 'table' AND name = 'message_definitions'",
        |_| {
            has_table = true;
            ControlFlow::Continue(())
        },
    )?;
    let mut definitions = BTreeMap::new();
    if has_table {
        database.query(
            "SELECT topic_type, encoding, encoded_message_definition FROM message_definitions",
            |row| {
                if row.text(1) == super::SCHEMA_ENCODING {
                    definitions.insert(row.text(0), row.text(2));
                }
                ControlFlow::Continue(())
            },
        )?;
    }
    Ok(definitions)
}
