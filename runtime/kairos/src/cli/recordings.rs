//! `kairos inspect`, `kairos recover` and `kairos merge`: recordings described, repaired and joined.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context as _;

/// What `kairos inspect` takes.
#[derive(Debug, clap::Args)]
pub struct InspectArgs {
    /// The MCAP file.
    pub file: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

impl InspectArgs {
    /// Prints the report; exit 3 when the recording is damaged.
    pub(super) fn execute(self) -> anyhow::Result<ExitCode> {
        let report = inspect_showing_progress(&self.file)?;
        if self.json {
            println!(
                "{}",
                serde_json::to_string_pretty(&report).context("encoding the report as JSON")?
            );
        } else {
            print!("{}", report.text());
        }
        Ok(if report.damage.is_some() || report.input_damage.is_some() {
            ExitCode::from(3)
        } else {
            ExitCode::SUCCESS
        })
    }
}

/// What `kairos recover` takes.
#[derive(Debug, clap::Args)]
pub struct RecoverArgs {
    /// The damaged recording.
    pub input: PathBuf,
    /// Where to write the complete one.
    pub output: PathBuf,
}

impl RecoverArgs {
    /// Writes the complete recording and says what was left out.
    pub(super) fn execute(self) -> anyhow::Result<ExitCode> {
        let (input, output) = (self.input, self.output);
        let recovered = kairos_pack_recording::recover(&input, &output)?;
        println!(
            "{}: {} messages and {} metadata records recovered",
            output.display(),
            recovered.messages,
            recovered.metadata,
        );
        if !recovered.left_out.is_empty() {
            println!(
                "left out {} damaged chunk(s) of {}, holding {}{} messages:",
                recovered.left_out.len(),
                input.display(),
                if recovered.left_out.iter().any(|d| d.messages.is_none()) {
                    "at least "
                } else {
                    ""
                },
                recovered.messages_left_out()
            );
            for region in &recovered.left_out {
                println!("  {region}");
            }
        }
        if let Some(cut) = &recovered.cut_short {
            println!("{cut}: everything before it was recovered");
        }
        Ok(ExitCode::SUCCESS)
    }
}

/// What `kairos merge` takes.
#[derive(Debug, clap::Args)]
pub struct MergeArgs {
    /// The recordings: FILE (its host is the file's name) or HOST=FILE.
    #[arg(required = true, num_args = 2..)]
    pub inputs: Vec<String>,
    /// The merged file.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Merge recordings whose clocks were not locked all the same (the merged file says so).
    #[arg(long)]
    pub allow_unsynchronised: bool,
    /// Merge what is intact of damaged or truncated recordings (the merged file says what was lost).
    #[arg(long)]
    pub allow_damaged: bool,
}

impl MergeArgs {
    /// Writes the merged recording and names its channels.
    pub(super) fn execute(self) -> anyhow::Result<ExitCode> {
        let inputs: Vec<_> = self
            .inputs
            .iter()
            .map(|a| kairos_pack_recording::merge::MergeInput::parse(a))
            .collect();
        let output = self.output;
        let options = kairos_pack_recording::merge::MergeOptions {
            allow_unsynchronised: self.allow_unsynchronised,
            allow_damaged: self.allow_damaged,
        };
        let merged = kairos_pack_recording::merge::merge(&inputs, &output, options)?;
        println!(
            "{}: {} messages on {} channels ({})",
            output.display(),
            merged.messages,
            merged.channels.len(),
            merged.channels.join(", ")
        );
        for warning in &merged.unsynchronised {
            println!("merged although not synchronised: {warning}");
        }
        for warning in &merged.damaged {
            println!("merged although damaged (what was past the damage is lost): {warning}");
        }
        Ok(ExitCode::SUCCESS)
    }
}

/// Files smaller than this are inspected without a progress bar: it would only flicker.
const PROGRESS_BAR_FROM_BYTES: u64 = 64 << 20;

/// `kairos inspect`'s reading, with a progress bar on standard error for large files when it is a terminal.
fn inspect_showing_progress(
    file: &std::path::Path,
) -> Result<kairos_pack_recording::Report, kairos_pack_recording::InspectError> {
    use kairos_pack_recording::Progress;
    use std::io::{IsTerminal as _, Write as _};
    let large = std::fs::metadata(file).is_ok_and(|m| m.len() >= PROGRESS_BAR_FROM_BYTES);
    if !large || !std::io::stderr().is_terminal() {
        return kairos_pack_recording::inspect(file);
    }
    let mut shown_percent = u64::MAX;
    let report = kairos_pack_recording::inspect_with_progress(file, |progress| {
        let (phase, done, total) = match progress {
            Progress::Reading(done, total) => ("reading ", done, total),
            Progress::Checking(done, total) => ("checking", done, total),
        };
        let percent = (done * 100).checked_div(total).unwrap_or(100);
        if percent == shown_percent {
            return;
        }
        shown_percent = percent;
        let filled = usize::try_from(percent / 4).unwrap_or(25);
        let mut stderr = std::io::stderr();
        let _ = write!(
            stderr,
            "\r{phase} [{}{}] {percent:>3} % of {:.1} MB",
            "#".repeat(filled),
            " ".repeat(25 - filled.min(25)),
            total as f64 / 1e6
        );
        let _ = stderr.flush();
    });
    eprint!("\r{}\r", " ".repeat(60));
    report
}
