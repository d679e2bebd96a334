//! `kairos recover`: rewrites an unfinished or damaged recording into a complete, indexed one, keeping
//! every message and metadata record that precedes the damage.

use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

use mcap::read::{LinearReader, MessageStream, Options};
use mcap::records::Record;
use serde::Serialize;

use crate::inspect::InspectError;

/// What a recovery kept.
#[derive(Debug, Clone, Serialize)]
pub struct Recovered {
    /// Messages copied.
    pub messages: u64,
    /// Metadata records copied.
    pub metadata: u64,
    /// Where reading stopped, if the input was damaged.
    pub damage: Option<String>,
}

fn io_error(path: &Path, error: impl std::fmt::Display) -> InspectError {
    InspectError::NotMcap {
        path: path.display().to_string(),
        reason: error.to_string(),
    }
}

/// Copies everything intact from `input` into a new, complete recording at `output`.
pub fn recover(input: &Path, output: &Path) -> Result<Recovered, InspectError> {
    let bytes = std::fs::read(input).map_err(|source| InspectError::Io {
        path: input.display().to_string(),
        source,
    })?;
    if bytes.get(..8) != Some(mcap::MAGIC) {
        return Err(io_error(input, "it does not start with the MCAP magic bytes"));
    }
    if input.canonicalize().ok() == output.canonicalize().ok() && output.exists() {
        return Err(io_error(
            output,
            "refusing to overwrite the file being recovered; choose another output",
        ));
    }
    let file = File::create(output).map_err(|source| InspectError::Io {
        path: output.display().to_string(),
        source,
    })?;
    let mut writer = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .profile("kairos")
        .create(BufWriter::new(file))
        .map_err(|e| io_error(output, e))?;
    let options = Options::IgnoreEndMagic | Options::ValidateChunkCrcs;
    let mut recovered = Recovered {
        messages: 0,
        metadata: 0,
        damage: None,
    };
    // Metadata records sit outside chunks: a linear pass finds those written before the damage.
    if let Ok(records) = LinearReader::new_with_options(&bytes, options) {
        for record in records {
            match record {
                Ok(Record::Metadata(metadata)) => {
                    writer
                        .write_metadata(&metadata)
                        .map_err(|e| io_error(output, e))?;
                    recovered.metadata += 1;
                }
                Ok(_) => {}
                Err(_) => break,
            }
        }
    }
    match MessageStream::new_with_options(&bytes, options) {
        Err(error) => recovered.damage = Some(error.to_string()),
        Ok(stream) => {
            for message in stream {
                match message {
                    Ok(message) => {
                        writer.write(&message).map_err(|e| io_error(output, e))?;
                        recovered.messages += 1;
                    }
                    Err(error) => {
                        recovered.damage = Some(error.to_string());
                        break;
                    }
                }
            }
        }
    }
    writer.finish().map_err(|e| io_error(output, e))?;
    Ok(recovered)
}
