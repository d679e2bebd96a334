//! The command line: one `Args` struct per subcommand, each carried out by its module; `execute` only
//! loads the packs and dispatches.

mod library;
mod new;
mod recordings;
mod run;
mod serve;

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use kairos_runtime::PackScan;
use kairos_sdk_core::Registry;

pub use library::{ComponentsArgs, DevicesArgs, PacksArgs, ValidateArgs};
pub use new::NewCommand;
pub use recordings::{InspectArgs, MergeArgs, RecoverArgs};
pub use run::{DeployArgs, FoxgloveArgs, RunArgs};
pub use serve::{ServeArgs, StatusArgs};

/// Kairos: real-time multi-sensor prototyping, headless.
#[derive(Debug, Parser)]
#[command(name = "kairos", version, about, long_about = None)]
pub struct Cli {
    /// More log output (-v: debug, -vv: trace). `RUST_LOG` overrides it.
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    pub verbose: u8,
    /// A folder of pack libraries to load (repeatable); `KAIROS_PACK_PATH` and a `packs/` folder beside
    /// the diagram are searched too.
    #[arg(long = "pack-path", value_name = "DIR", global = true)]
    pub pack_path: Vec<PathBuf>,
    /// What to do.
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Run a diagram until Ctrl-C, or for a given time.
    Run(RunArgs),
    /// Run a diagram over several machines: each component marked with a `host` on that host's `kairos
    /// serve`, the others here; everything starts or nothing does, and Ctrl-C stops every host.
    Deploy(DeployArgs),
    /// Serve a headless runtime that the studio or any WebSocket client drives (the control protocol).
    Serve(ServeArgs),
    /// Check diagrams against the component library; exit 0 when all are valid.
    Validate(ValidateArgs),
    /// Describe a recording: channels, types, counts, rates, duration, drops and metadata.
    Inspect(InspectArgs),
    /// Rewrite an unfinished or damaged recording into a complete one, keeping everything intact.
    Recover(RecoverArgs),
    /// Merge recordings made on several hosts into one file on one timeline, each channel prefixed by its
    /// host (`car/camera.image`).
    Merge(MergeArgs),
    /// List the packs: built-in and loaded from the pack path, with the libraries refused and why.
    Packs(PacksArgs),
    /// List the component library.
    Components(ComponentsArgs),
    /// List this machine's serial ports, CAN interfaces and cameras, for the device properties.
    Devices(DevicesArgs),
    /// Show what each host of a diagram is doing (state, clock against its master, links), or one
    /// runtime given its ws:// endpoint. Exits with 1 when a host cannot be reached.
    Status(StatusArgs),
    /// Generate a pack or a component from the templates.
    #[command(subcommand)]
    New(NewCommand),
}

/// Whether log lines may carry colour codes: only to a terminal, and not when `NO_COLOR` is set to anything
/// but the empty text (<https://no-color.org>). A file or journald gets plain text.
fn colour_logs() -> bool {
    use std::io::IsTerminal as _;
    let no_color = std::env::var_os("NO_COLOR").is_some_and(|v| !v.is_empty());
    std::io::stderr().is_terminal() && !no_color
}

/// Sets up logging to standard error.
pub fn init_logging(verbose: u8) {
    use tracing_subscriber::Layer as _;
    use tracing_subscriber::layer::SubscriberExt as _;
    use tracing_subscriber::util::SubscriberInitExt as _;
    let level = match verbose {
        0 => "info",
        1 => "debug",
        _ => "trace",
    };
    // Zenoh's own messages (retries, its configuration) only when asked: the links report what matters
    // themselves, naming the hosts and components.
    let zenoh = if verbose >= 2 { level } else { "error" };
    let default = format!(
        "{level},zenoh={zenoh},zenoh_transport={zenoh},zenoh_link_tcp={zenoh},zenoh_link_commons={zenoh},zenoh_config={zenoh}"
    );
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default));
    let _ = tracing_subscriber::registry()
        .with(filter)
        .with(
            tracing_subscriber::fmt::layer()
                .with_writer(std::io::stderr)
                .with_ansi(colour_logs())
                .with_target(false)
                // What a console sink prints is on standard output already; clients get it from the tap.
                .with_filter(tracing_subscriber::filter::filter_fn(|meta| {
                    meta.target() != kairos_pack_core::sinks::CONSOLE_TARGET
                })),
        )
        .with(kairos_server::log_tap::LogTap)
        .try_init();
}

/// The diagrams a command names, whose `packs/` folders join the pack path.
fn diagrams_of(command: &Command) -> Vec<&Path> {
    match command {
        Command::Run(args) | Command::Deploy(DeployArgs { run: args, .. }) => vec![args.diagram.as_path()],
        Command::Serve(args) => args.diagram.iter().map(PathBuf::as_path).collect(),
        Command::Validate(args) => args.diagrams.iter().map(PathBuf::as_path).collect(),
        Command::Packs(_)
        | Command::Components(_)
        | Command::New(_)
        | Command::Inspect(_)
        | Command::Recover(_)
        | Command::Merge(_)
        | Command::Devices(_)
        | Command::Status(_) => Vec::new(),
    }
}

/// Says which pack libraries were refused and which component types two packs offer.
fn warn_about_packs(registry: &Registry, scan: &PackScan) {
    for refused in &scan.refused {
        tracing::warn!(
            "pack library {} refused: {}",
            refused.path.display(),
            refused.reason
        );
    }
    for duplicate in registry.duplicates() {
        tracing::warn!(
            "component type '{}' is offered by packs '{}' and '{}'; using the one from '{}'",
            duplicate.type_name,
            duplicate.kept_from,
            duplicate.refused_from,
            duplicate.kept_from
        );
    }
}

/// Runs a parsed command line.
pub fn execute(cli: Cli) -> anyhow::Result<ExitCode> {
    let (registry, scan) = crate::registry_with_packs(&cli.pack_path, &diagrams_of(&cli.command));
    if !matches!(cli.command, Command::Packs(_)) {
        warn_about_packs(&registry, &scan);
    }
    match cli.command {
        Command::Run(args) => run::run(&registry, args, &scan),
        Command::Deploy(args) => run::deploy(&registry, args, &scan),
        Command::Serve(args) => args.execute(registry),
        Command::Validate(args) => Ok(args.execute(&registry, &scan)),
        Command::Inspect(args) => args.execute(),
        Command::Recover(args) => args.execute(),
        Command::Merge(args) => args.execute(),
        Command::Status(args) => args.execute(),
        Command::Devices(args) => args.execute(),
        Command::Packs(args) => args.execute(&registry, &scan),
        Command::Components(args) => args.execute(&registry),
        Command::New(what) => Ok(new::new(what, &registry)),
    }
}
