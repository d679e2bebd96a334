//! Reading an MCAP file defensively, for files that may be damaged or hostile.
//!
//! The `mcap` crate's file readers trust the record lengths they find and reserve that much memory before
//! decompressing: a flipped bit aborts the process with an allocation of petabytes (found by the property
//! test in `tests/damaged_files.rs`). Here the crate's lower-level reader runs with a record length limit and
//! chunk CRC checks.
//!
//! [`walk`] goes over a file's top-level records itself and reads each chunk (or each record outside a
//! chunk) on its own. A chunk that fails its CRC, does not parse, or refers to an unknown channel is left out
//! whole, reported with its offset and the message count its message indexes give, and the walk goes on
//! with the next record; where a record's length itself is damaged, it resynchronises on the next record
//! that parses as a chunk. Nothing of a damaged chunk reaches a caller as a message: a chunk is kept whole
//! or not at all. Its schema and channel definitions are taken, though, where no intact record defines
//! them: later chunks of a file that was never closed refer to them, and a wrong definition shows as a
//! topic, not as wrong data.

use std::collections::HashMap;
use std::fmt;
use std::sync::Arc;

use mcap::records::{Metadata, Record, op};
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
use mcap::{Channel, Message, Schema};
use serde::Serialize;

/// Where and why reading stopped.
pub type Damage = Option<String>;

/// A record that refers to a definition the file has not given: the file is damaged there.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CatalogError {
    /// A channel of a schema never defined.
    #[error("channel {channel} names unknown schema {schema}")]
    UnknownSchema {
        /// The channel's id.
        channel: u16,
        /// The schema id it names.
        schema: u16,
    },
    /// A message on a channel never defined.
    #[error("message on unknown channel {0}")]
    UnknownChannel(u16),
}

/// The schemas and channels read so far; messages refer to them by id.
#[derive(Default, Clone)]
pub struct Catalog {
    schemas: HashMap<u16, Arc<Schema<'static>>>,
    channels: HashMap<u16, Arc<Channel<'static>>>,
}

impl fmt::Debug for Catalog {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Catalog")
            .field("schemas", &self.schemas.len())
            .field("channels", &self.channels.len())
            .finish()
    }
}

impl Catalog {
    /// The channel of id `id`, with its schema.
    pub fn channel(&self, id: u16) -> Option<&Arc<Channel<'static>>> {
        self.channels.get(&id)
    }

    /// A catalog holding the schemas and channels of a file's summary.
    pub fn from_summary(summary: &mcap::read::Summary) -> Self {
        Catalog {
            schemas: summary.schemas.clone(),
            channels: summary.channels.clone(),
        }
    }

    /// Takes the schemas and channels of `other` that this one lacks; returns how many.
    fn adopt_missing(&mut self, other: Catalog) -> usize {
        let mut adopted = 0;
        for (id, schema) in other.schemas {
            self.schemas.entry(id).or_insert_with(|| {
                adopted += 1;
                schema
            });
        }
        for (id, channel) in other.channels {
            self.channels.entry(id).or_insert_with(|| {
                adopted += 1;
                channel
            });
        }
        adopted
    }

    /// Handles one record from the file or from inside a chunk; returns a message to visit, if any.
    fn absorb<'a>(&mut self, record: Record<'a>) -> Result<Option<Message<'a>>, CatalogError> {
        match record {
            Record::Schema { header, data } => {
                let schema = Schema {
                    id: header.id,
                    name: header.name,
                    encoding: header.encoding,
                    data: std::borrow::Cow::Owned(data.into_owned()),
                };
                self.schemas.insert(schema.id, Arc::new(schema));
                Ok(None)
            }
            Record::Channel(channel) => {
                let schema = if channel.schema_id == 0 {
                    None
                } else {
                    Some(self.schemas.get(&channel.schema_id).cloned().ok_or(
                        CatalogError::UnknownSchema {
                            channel: channel.id,
                            schema: channel.schema_id,
                        },
                    )?)
                };
                let channel = Channel {
                    id: channel.id,
                    topic: channel.topic,
                    schema,
                    message_encoding: channel.message_encoding,
                    metadata: channel.metadata,
                };
                self.channels.insert(channel.id, Arc::new(channel));
                Ok(None)
            }
            Record::Message { header, data } => {
                let channel = self
                    .channels
                    .get(&header.channel_id)
                    .cloned()
                    .ok_or(CatalogError::UnknownChannel(header.channel_id))?;
                Ok(Some(Message {
                    channel,
                    sequence: header.sequence,
                    log_time: header.log_time,
                    publish_time: header.publish_time,
                    data,
                }))
            }
            _ => Ok(None),
        }
    }
}

/// The longest record accepted, a message inside a chunk included: it bounds every allocation the reader
/// makes from a size found in the file.
pub(crate) const MAX_RECORD_BYTES: usize = 1 << 30;

/// Bytes read by position: a file, or a recording already in memory.
pub trait Source {
    /// The length in bytes.
    fn size(&self) -> u64;
    /// Fills `buffer` from `offset`.
    fn read_at(&self, buffer: &mut [u8], offset: u64) -> std::io::Result<()>;
}

impl Source for [u8] {
    fn size(&self) -> u64 {
        self.len() as u64
    }

    fn read_at(&self, buffer: &mut [u8], offset: u64) -> std::io::Result<()> {
        let start = usize::try_from(offset).unwrap_or(usize::MAX);
        let bytes = start
            .checked_add(buffer.len())
            .and_then(|end| self.get(start..end))
            .ok_or_else(|| std::io::Error::from(std::io::ErrorKind::UnexpectedEof))?;
        buffer.copy_from_slice(bytes);
        Ok(())
    }
}

impl Source for std::fs::File {
    fn size(&self) -> u64 {
        self.metadata().map_or(0, |m| m.len())
    }

    fn read_at(&self, buffer: &mut [u8], offset: u64) -> std::io::Result<()> {
        std::os::unix::fs::FileExt::read_exact_at(self, buffer, offset)
    }
}

/// A run of a file left out because it is damaged.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct DamagedRegion {
    /// The byte offset of the damaged record.
    pub offset: u64,
    /// How many bytes were left out from there.
    pub length: u64,
    /// The messages it held, as the message indexes after it tell; `None` when none do.
    pub messages: Option<u64>,
    /// What is wrong with it.
    pub reason: String,
}

impl fmt::Display for DamagedRegion {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "bytes {} to {}: {}; left out with ",
            self.offset,
            self.offset + self.length,
            self.reason
        )?;
        match self.messages {
            Some(1) => write!(f, "its 1 message"),
            Some(count) => write!(f, "its {count} messages"),
            None => write!(f, "an unknown number of messages (no message index follows it)"),
        }
    }
}

/// One intact chunk, or one record outside any chunk, and the messages it holds in file order.
#[derive(Debug)]
pub struct IntactBlock<'a> {
    /// The byte offset of its record.
    pub offset: u64,
    /// The record's length, header included.
    pub length: u64,
    /// Its messages.
    pub messages: &'a [Message<'static>],
}

/// What a [`walk`] found besides the intact blocks.
#[derive(Debug, Default)]
pub struct Walk {
    /// The damaged regions left out, in file order.
    pub damaged: Vec<DamagedRegion>,
    /// Why the data ended early, when the file stops in the middle of a record (a crash while writing).
    pub cut_short: Option<String>,
    /// Whether the data section ended properly (a Data End record).
    pub data_end: bool,
    /// The schemas and channels known at the end.
    pub catalog: Catalog,
}

impl Walk {
    /// The damage in one line, or `None` for an intact file. A file that stops between two whole
    /// records (a writer killed right after a chunk) is damaged too: its data section never ended.
    pub fn summary(&self) -> Option<String> {
        let mut parts: Vec<String> = self.damaged.iter().map(ToString::to_string).collect();
        parts.extend(self.cut_short.clone());
        if self.cut_short.is_none() && !self.data_end {
            parts.push(
                "the file stops after its last whole record without a data end (it was not closed?)"
                    .to_owned(),
            );
        }
        (!parts.is_empty()).then(|| parts.join("; "))
    }

    /// Messages left out in damaged regions, as far as their indexes tell.
    pub fn messages_left_out(&self) -> u64 {
        self.damaged.iter().filter_map(|d| d.messages).sum()
    }
}

/// Walks the top-level records of the MCAP file in `source` (magic included), starting from `catalog`'s
/// schemas and channels (a summary's, or none). Calls `on_block` for each intact chunk or record outside a
/// chunk, `on_metadata` for each metadata record, and `on_progress` with the bytes done now and then.
///
/// # Errors
///
/// Only when `source` cannot be read; damage is reported in the [`Walk`].
pub fn walk<S: Source + ?Sized>(
    source: &S,
    catalog: Catalog,
    mut on_block: impl FnMut(&IntactBlock<'_>),
    mut on_metadata: impl FnMut(Metadata),
    mut on_progress: impl FnMut(u64),
) -> std::io::Result<Walk> {
    let size = source.size();
    let mut walk = Walk {
        catalog,
        ..Walk::default()
    };
    let mut offset = mcap::MAGIC.len() as u64;
    let mut record = Vec::new();
    while offset < size {
        on_progress(offset);
        let Some((opcode, end)) = record_header(source, offset, size)? else {
            // The length is damaged, or the file stops inside this record.
            let Some(next) = next_record_start(source, offset + 1, size)? else {
                walk.cut_short = Some(format!(
                    "the record at byte {offset} runs past the end of the file (truncated: it was not closed?)"
                ));
                break;
            };
            walk.damaged.push(DamagedRegion {
                offset,
                length: next - offset,
                messages: None,
                reason: "its length is damaged; reading resumed at the next chunk".to_owned(),
            });
            offset = next;
            continue;
        };
        match opcode {
            op::DATA_END | op::FOOTER => {
                walk.data_end = true;
                break;
            }
            op::CHUNK | op::MESSAGE | op::SCHEMA | op::CHANNEL => {
                read_record(source, offset, end, &mut record)?;
                match read_block(&record, &mut walk.catalog) {
                    BlockRead::Intact(messages) => on_block(&IntactBlock {
                        offset,
                        length: end - offset,
                        messages: &messages,
                    }),
                    BlockRead::Damaged(reason) => {
                        let adopted = salvage_definitions(&record, &mut walk.catalog);
                        let reason = if adopted > 0 {
                            format!("{reason} (its {adopted} schema and channel definitions were kept)")
                        } else {
                            reason
                        };
                        walk.damaged.push(DamagedRegion {
                            offset,
                            length: end - offset,
                            messages: indexed_messages(source, end, size)?,
                            reason,
                        });
                    }
                }
            }
            op::METADATA => {
                read_record(source, offset, end, &mut record)?;
                match record.get(9..).map(|body| mcap::parse_record(op::METADATA, body)) {
                    Some(Ok(Record::Metadata(metadata))) => on_metadata(metadata),
                    _ => walk.damaged.push(DamagedRegion {
                        offset,
                        length: end - offset,
                        messages: Some(0),
                        reason: "a metadata record does not parse".to_owned(),
                    }),
                }
            }
            // Indexes, attachments, statistics: nothing to read here. Opcodes from 0x80 are for
            // extensions, which readers skip; a lower unknown one is a damaged opcode.
            op::MESSAGE_INDEX
            | op::CHUNK_INDEX
            | op::ATTACHMENT
            | op::ATTACHMENT_INDEX
            | op::STATISTICS
            | op::METADATA_INDEX
            | op::SUMMARY_OFFSET
            | op::HEADER => {}
            opcode if opcode >= 0x80 => {}
            opcode => walk.damaged.push(DamagedRegion {
                offset,
                length: end - offset,
                messages: indexed_messages(source, end, size)?,
                reason: format!("a record of unknown type 0x{opcode:02x} (a damaged type byte?)"),
            }),
        }
        offset = end;
    }
    on_progress(size);
    Ok(walk)
}

/// The opcode and end of the record at `offset`, or `None` when its length runs past the file or the
/// limit.
fn record_header<S: Source + ?Sized>(
    source: &S,
    offset: u64,
    size: u64,
) -> std::io::Result<Option<(u8, u64)>> {
    if offset + 9 > size {
        return Ok(None);
    }
    let mut header = [0_u8; 9];
    source.read_at(&mut header, offset)?;
    let [opcode, length @ ..] = header;
    let body = u64::from_le_bytes(length);
    let end = offset.saturating_add(9).saturating_add(body);
    Ok((body <= MAX_RECORD_BYTES as u64 && end <= size).then_some((opcode, end)))
}

fn read_record<S: Source + ?Sized>(
    source: &S,
    offset: u64,
    end: u64,
    into: &mut Vec<u8>,
) -> std::io::Result<()> {
    into.resize(usize::try_from(end - offset).unwrap_or(0), 0);
    source.read_at(into, offset)
}

/// What reading one top-level record gave: all its messages, or where and why it is damaged.
enum BlockRead {
    Intact(Vec<Message<'static>>),
    Damaged(String),
}

/// The messages of one top-level record (a chunk, or a record outside any chunk), all or nothing: on
/// damage `catalog` is left as it was.
fn read_block(record: &[u8], catalog: &mut Catalog) -> BlockRead {
    let mut trial = catalog.clone();
    // Held by channel id: a message borrows its channel from the reader for the call only.
    let mut read = Vec::new();
    let damage = read_records(
        record,
        false,
        &mut trial,
        |message| {
            read.push((
                message.channel.id,
                message.sequence,
                message.log_time,
                message.publish_time,
                message.data.to_vec(),
            ));
        },
        |_| {},
    );
    if let Some(damage) = damage {
        return BlockRead::Damaged(damage);
    }
    let messages = read
        .into_iter()
        .filter_map(|(channel, sequence, log_time, publish_time, data)| {
            Some(Message {
                channel: Arc::clone(trial.channels.get(&channel)?),
                sequence,
                log_time,
                publish_time,
                data: std::borrow::Cow::Owned(data),
            })
        })
        .collect();
    *catalog = trial;
    BlockRead::Intact(messages)
}

/// Reads a damaged record again without its CRC check, to keep the schema and channel definitions it
/// holds that `catalog` lacks; returns how many.
fn salvage_definitions(record: &[u8], catalog: &mut Catalog) -> usize {
    let mut found = catalog.clone();
    let _ = read_with(record, false, false, &mut found, |_| {}, |_| {}, |_| {});
    catalog.adopt_missing(found)
}

/// How many messages the message index records right after `end` list, if any follow.
fn indexed_messages<S: Source + ?Sized>(source: &S, mut end: u64, size: u64) -> std::io::Result<Option<u64>> {
    let mut count = None;
    let mut record = Vec::new();
    while let Some((op::MESSAGE_INDEX, next)) = record_header(source, end, size)? {
        read_record(source, end, next, &mut record)?;
        let Some(Ok(Record::MessageIndex(index))) = record
            .get(9..)
            .map(|body| mcap::parse_record(op::MESSAGE_INDEX, body))
        else {
            break;
        };
        *count.get_or_insert(0) += index.records.len() as u64;
        end = next;
    }
    Ok(count)
}

/// The offset of the first record at or after `from` that parses as a chunk header or is the Data End
/// record, if any: where reading resumes after a record whose length is damaged.
fn next_record_start<S: Source + ?Sized>(source: &S, from: u64, size: u64) -> std::io::Result<Option<u64>> {
    const WINDOW: u64 = 1 << 20;
    let mut window = Vec::new();
    let mut start = from;
    while start < size {
        let end = (start + WINDOW).min(size);
        window.resize(usize::try_from(end - start).unwrap_or(0), 0);
        source.read_at(&mut window, start)?;
        for (at, byte) in window.iter().enumerate() {
            let offset = start + at as u64;
            if (*byte == op::CHUNK || *byte == op::DATA_END) && starts_a_record(source, offset, size)? {
                return Ok(Some(offset));
            }
        }
        start = end;
    }
    Ok(None)
}

/// Whether a plausible chunk (its header parses, with a known compression) or Data End record starts at
/// `offset`.
fn starts_a_record<S: Source + ?Sized>(source: &S, offset: u64, size: u64) -> std::io::Result<bool> {
    let Some((opcode, end)) = record_header(source, offset, size)? else {
        return Ok(false);
    };
    if opcode == op::DATA_END {
        return Ok(end - offset == 9 + 4);
    }
    let mut record = Vec::new();
    read_record(source, offset, end, &mut record)?;
    Ok(
        match record.get(9..).map(|body| mcap::parse_record(op::CHUNK, body)) {
            Some(Ok(Record::Chunk { header, .. })) => {
                matches!(header.compression.as_str(), "" | "zstd" | "lz4")
                    && header.message_start_time <= header.message_end_time
                    && header.uncompressed_size <= MAX_RECORD_BYTES as u64
            }
            _ => false,
        },
    )
}

/// Visits every intact message and metadata record of `bytes`, a whole file in memory, in file order,
/// and returns the damage in one line (`None` for an intact file). Damaged chunks are left out whole.
pub fn read_intact(
    bytes: &[u8],
    mut on_message: impl FnMut(&Message<'_>),
    on_metadata: impl FnMut(Metadata),
) -> Damage {
    let walked = walk(
        bytes,
        Catalog::default(),
        |block| block.messages.iter().for_each(&mut on_message),
        on_metadata,
        |_| {},
    );
    match walked {
        Ok(walk) => walk.summary(),
        Err(error) => Some(error.to_string()),
    }
}

/// Visits the intact messages and metadata of `bytes`: a whole file when `whole_file` (it starts with the
/// magic), otherwise a run of records cut from one (a chunk); `catalog` carries schemas and channels from
/// one call to the next. Returns where reading stopped on damaged data.
pub fn read_records(
    bytes: &[u8],
    whole_file: bool,
    catalog: &mut Catalog,
    on_message: impl FnMut(&Message<'_>),
    on_metadata: impl FnMut(Metadata),
) -> Damage {
    read_with(bytes, whole_file, true, catalog, on_message, on_metadata, |_| {})
}

fn read_with(
    bytes: &[u8],
    whole_file: bool,
    check_crcs: bool,
    catalog: &mut Catalog,
    mut on_message: impl FnMut(&Message<'_>),
    mut on_metadata: impl FnMut(Metadata),
    mut on_progress: impl FnMut(usize),
) -> Damage {
    let options = LinearReaderOptions::default()
        .with_skip_start_magic(!whole_file)
        .with_skip_end_magic(true)
        .with_validate_chunk_crcs(check_crcs)
        .with_record_length_limit(MAX_RECORD_BYTES);
    let mut reader = LinearReader::new_with_options(options);
    let mut offset = 0;
    let of = if whole_file { "" } else { " of the record" };
    while let Some(event) = reader.next_event() {
        match event {
            Err(error) => return Some(format!("{error}, after byte {offset}{of}")),
            Ok(LinearReadEvent::ReadRequest(wanted)) => {
                let available = bytes.len().saturating_sub(offset);
                if available == 0 {
                    if !whole_file {
                        return None;
                    }
                    return Some("the file ends in the middle of a record".to_owned());
                }
                let take = wanted.min(available);
                let source = bytes.get(offset..offset + take)?;
                reader.insert(take).copy_from_slice(source);
                reader.notify_read(take);
                offset += take;
                on_progress(offset);
            }
            Ok(LinearReadEvent::Record { data, opcode }) => {
                let record = match mcap::parse_record(opcode, data) {
                    Ok(record) => record,
                    Err(error) => return Some(format!("{error}, before byte {offset}{of}")),
                };
                match record {
                    Record::Metadata(metadata) => on_metadata(metadata),
                    Record::DataEnd(_) | Record::Footer(_) => return None,
                    other => match catalog.absorb(other) {
                        Ok(Some(message)) => on_message(&message),
                        Ok(None) => {}
                        Err(error) => return Some(format!("{error}, before byte {offset}{of}")),
                    },
                }
            }
        }
    }
    None
}
