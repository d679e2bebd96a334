//! `kairos recover`: rewrites an unfinished or damaged recording into a complete, indexed one, keeping
//! every intact chunk and metadata record. A damaged chunk is left out whole (its messages cannot be
//! trusted, and a copy with fresh checksums would hide that), reported with its offset and message
//! count; every intact chunk after it is kept.

use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

use serde::Serialize;

use crate::inspect::InspectError;
use crate::safe_read::{Catalog, DamagedRegion};

/// What a recovery kept.
#[derive(Debug, Clone, Serialize)]
pub struct Recovered {
    /// Messages copied.
    pub messages: u64,
    /// Metadata records copied.
    pub metadata: u64,
    /// The damaged chunks left out, in file order.
    pub left_out: Vec<DamagedRegion>,
    /// Where the input stops in the middle of a record, when it does (it was not closed).
    pub cut_short: Option<String>,
}

impl Recovered {
    /// Messages left out with the damaged chunks, as far as their indexes tell.
    pub fn messages_left_out(&self) -> u64 {
        self.left_out.iter().filter_map(|d| d.messages).sum()
    }
}

fn io_error(path: &Path, error: impl std::fmt::Display) -> InspectError {
    InspectError::NotMcap {
        path: path.display().to_string(),
        reason: error.to_string(),
    }
}

/// Copies everything intact from `input` into a new, complete recording at `output`.
pub fn recover(input: &Path, output: &Path) -> Result<Recovered, InspectError> {
    let bytes = std::fs::read(input).map_err(|error| InspectError::Io {
        path: input.display().to_string(),
        error,
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
    let file = File::create(output).map_err(|error| InspectError::Io {
        path: output.display().to_string(),
        error,
    })?;
    let mut writer = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .profile("kairos")
        .create(BufWriter::new(file))
        .map_err(|e| io_error(output, e))?;
    let catalog = mcap::read::Summary::read(&bytes)
        .ok()
        .flatten()
        .map_or_else(Catalog::default, |summary| Catalog::from_summary(&summary));
    let mut messages = 0;
    let mut failure = None;
    let mut metadata = Vec::new();
    let walked = crate::safe_read::walk(
        bytes.as_slice(),
        catalog,
        |block| {
            for message in block.messages {
                if failure.is_none() {
                    match writer.write(message) {
                        Ok(()) => messages += 1,
                        Err(error) => failure = Some(error.to_string()),
                    }
                }
            }
        },
        |record| metadata.push(record),
        |_| {},
    )
    .map_err(|error| InspectError::Io {
        path: input.display().to_string(),
        error,
    })?;
    if let Some(error) = failure {
        return Err(io_error(output, error));
    }
    for record in &metadata {
        writer.write_metadata(record).map_err(|e| io_error(output, e))?;
    }
    writer.finish().map_err(|e| io_error(output, e))?;
    Ok(Recovered {
        messages,
        metadata: metadata.len() as u64,
        left_out: walked.damaged,
        cut_short: walked.cut_short,
    })
}
