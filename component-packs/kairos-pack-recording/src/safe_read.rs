//! Reading an MCAP file defensively, for files that may be damaged or hostile.
//!
//! The `mcap` crate's file readers trust the record lengths they find and reserve that much memory before
//! decompressing: a flipped bit aborts the process with an allocation of petabytes (found by the property
//! test in `tests/damaged_files.rs`). Here the crate's lower-level reader runs with a record length limit and
//! chunk CRC checks, and reading stops, reporting where, at the first record that fails.

use std::collections::HashMap;
use std::sync::Arc;

use mcap::records::{Metadata, Record};
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
use mcap::{Channel, Message, Schema};

/// Where and why reading stopped.
pub type Damage = Option<String>;

/// The schemas and channels read so far; messages refer to them by id.
#[derive(Default, Clone)]
pub struct Catalog {
    schemas: HashMap<u16, Arc<Schema<'static>>>,
    channels: HashMap<u16, Arc<Channel<'static>>>,
}

impl std::fmt::Debug for Catalog {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Catalog")
            .field("schemas", &self.schemas.len())
            .field("channels", &self.channels.len())
            .finish()
    }
}

impl Catalog {
    /// Handles one record from the file or from inside a chunk; returns a message to visit, if any.
    fn absorb<'a>(&mut self, record: Record<'a>) -> Result<Option<Message<'a>>, String> {
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
                    Some(self.schemas.get(&channel.schema_id).cloned().ok_or_else(|| {
                        format!(
                            "channel {} names unknown schema {}",
                            channel.id, channel.schema_id
                        )
                    })?)
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
                    .ok_or_else(|| format!("message on unknown channel {}", header.channel_id))?;
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

/// Visits every intact message and metadata record of `bytes`, in file order, and returns where reading
/// stopped on a damaged file.
pub fn read_intact(
    bytes: &[u8],
    on_message: impl FnMut(&Message<'_>),
    on_metadata: impl FnMut(Metadata),
) -> Damage {
    read_records(bytes, true, &mut Catalog::default(), on_message, on_metadata)
}

/// Like [`read_intact`], telling `on_progress` how many bytes were read so far, now and then.
pub fn read_intact_with_progress(
    bytes: &[u8],
    on_message: impl FnMut(&Message<'_>),
    on_metadata: impl FnMut(Metadata),
    on_progress: impl FnMut(usize),
) -> Damage {
    read_records_with_progress(
        bytes,
        true,
        &mut Catalog::default(),
        on_message,
        on_metadata,
        on_progress,
    )
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
    read_records_with_progress(bytes, whole_file, catalog, on_message, on_metadata, |_| {})
}

fn read_records_with_progress(
    bytes: &[u8],
    whole_file: bool,
    catalog: &mut Catalog,
    mut on_message: impl FnMut(&Message<'_>),
    mut on_metadata: impl FnMut(Metadata),
    mut on_progress: impl FnMut(usize),
) -> Damage {
    let options = LinearReaderOptions::default()
        .with_skip_start_magic(!whole_file)
        .with_skip_end_magic(true)
        .with_validate_chunk_crcs(true)
        .with_record_length_limit(MAX_RECORD_BYTES);
    let mut reader = LinearReader::new_with_options(options);
    let mut offset = 0;
    while let Some(event) = reader.next_event() {
        match event {
            Err(error) => return Some(format!("{error}, after byte {offset}")),
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
                    Err(error) => return Some(format!("{error}, before byte {offset}")),
                };
                match record {
                    Record::Metadata(metadata) => on_metadata(metadata),
                    Record::DataEnd(_) | Record::Footer(_) => return None,
                    other => match catalog.absorb(other) {
                        Ok(Some(message)) => on_message(&message),
                        Ok(None) => {}
                        Err(error) => return Some(format!("{error}, before byte {offset}")),
                    },
                }
            }
        }
    }
    None
}
