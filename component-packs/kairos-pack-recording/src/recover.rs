//! `kairos recover`: rewrites an unfinished or damaged recording into a complete, indexed one, keeping
//! every message and metadata record that precedes the damage.

use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

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
    let mut recovered = Recovered {
        messages: 0,
        metadata: 0,
        damage: None,
    };
    let mut failure = None;
    let mut metadata = Vec::new();
    recovered.damage = crate::safe_read::read_intact(
        &bytes,
        |message| {
            if failure.is_none() {
                match writer.write(message) {
                    Ok(()) => recovered.messages += 1,
                    Err(error) => failure = Some(error.to_string()),
                }
            }
        },
        |record| metadata.push(record),
    );
    if let Some(error) = failure {
        return Err(io_error(output, error));
    }
    for record in &metadata {
        writer.write_metadata(record).map_err(|e| io_error(output, e))?;
        recovered.metadata += 1;
    }
    writer.finish().map_err(|e| io_error(output, e))?;
    Ok(recovered)
}
