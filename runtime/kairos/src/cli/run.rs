//! `kairos run` and `kairos deploy`: a diagram here, or over the hosts it names.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use kairos_runtime::PackScan;
use kairos_sdk_core::Registry;

use crate::duration::parse_duration;

/// What `run` and `deploy` take.
#[derive(Debug, clap::Args)]
pub struct RunArgs {
    /// The diagram file (.ron).
    pub diagram: PathBuf,
    /// Stop after this long (e.g. 10s, 500ms, 2m).
    #[arg(long = "for", value_parser = parse_duration)]
    pub duration: Option<Duration>,
    /// Print per-link and per-component statistics periodically and a final table at exit.
    #[arg(long)]
    pub stats: bool,
    /// How often --stats prints.
    #[arg(long, value_parser = parse_duration, default_value = "1s")]
    pub stats_interval: Duration,
    /// Override a property before running, e.g. `--set sine1.frequency=2.5` (repeatable).
    #[arg(long = "set", value_name = "ID.PROPERTY=VALUE")]
    pub overrides: Vec<String>,
    /// Make the runtime clock follow this component's time (a GNSS receiver), overriding the
    /// diagram's `clock_source`.
    #[arg(long, value_name = "ID")]
    pub clock_source: Option<String>,
    #[command(flatten)]
    pub foxglove: FoxgloveArgs,
}

/// Live in Foxglove, for `kairos serve` and `kairos run`.
#[derive(Debug, Clone, clap::Args)]
pub struct FoxgloveArgs {
    /// Publish outputs live to Foxglove (its WebSocket protocol) on this address, loopback by default
    /// (`127.0.0.1:8765`): every output of the diagram, or those given with --foxglove-output. Nothing is
    /// encoded for an output no Foxglove client subscribes to.
    #[arg(
        long,
        value_name = "HOST:PORT",
        num_args = 0..=1,
        default_missing_value = kairos_server::DEFAULT_FOXGLOVE_ADDRESS
    )]
    pub foxglove: Option<String>,
    /// Publish only this output to Foxglove (`camera.image`); give it once per output.
    #[arg(
        long = "foxglove-output",
        value_name = "COMPONENT.OUTPUT",
        requires = "foxglove"
    )]
    pub foxglove_outputs: Vec<String>,
    /// Let --foxglove listen off loopback. Foxglove's protocol carries no token: anyone who can reach the
    /// address sees the published outputs.
    #[arg(long, requires = "foxglove")]
    pub foxglove_open_to_network: bool,
    /// Messages queued per Foxglove client before the oldest are dropped: what a slow viewer can hold.
    #[arg(long, value_name = "MESSAGES", default_value_t = kairos_server::DEFAULT_FOXGLOVE_BACKLOG)]
    pub foxglove_backlog: usize,
}

impl FoxgloveArgs {
    /// What `--foxglove` asks for, if it was given.
    pub(super) fn options(self) -> Option<kairos_server::FoxgloveOptions> {
        let backlog = self.foxglove_backlog;
        self.foxglove.map(|address| kairos_server::FoxgloveOptions {
            address,
            selection: kairos_server::Selection {
                all: self.foxglove_outputs.is_empty(),
                chosen: self.foxglove_outputs.into_iter().collect(),
            },
            open_to_network: self.foxglove_open_to_network,
            backlog,
        })
    }
}

/// What `deploy` takes.
#[derive(Debug, clap::Args)]
pub struct DeployArgs {
    #[command(flatten)]
    pub run: RunArgs,
    /// Send tokens to hosts off this machine over plain ws://, where anyone on the network path can read
    /// them and take control of those runtimes. Without it, such a deploy is refused: use wss:// instead.
    #[arg(long)]
    pub allow_clear_text_tokens: bool,
    /// How far from its master a host's clock may be for the start to go ahead (hosts started with
    /// `--clock-slave-of`).
    #[arg(long, value_parser = parse_duration, default_value = "1ms")]
    pub lock_bound: Duration,
    /// Start even when a host's clock is not locked within --lock-bound: the parts may start apart.
    #[arg(long)]
    pub start_unlocked: bool,
}

/// `kairos run`.
pub(super) fn run(registry: &Registry, args: RunArgs, scan: &PackScan) -> anyhow::Result<ExitCode> {
    run_with(registry, args, None, scan)
}

/// `kairos deploy`.
pub(super) fn deploy(registry: &Registry, args: DeployArgs, scan: &PackScan) -> anyhow::Result<ExitCode> {
    let deploy = crate::run::DeployOptions {
        clear_text_tokens: args.allow_clear_text_tokens,
        lock_bound: args.lock_bound,
        start_unlocked: args.start_unlocked,
    };
    run_with(registry, args.run, Some(deploy), scan)
}

fn run_with(
    registry: &Registry,
    args: RunArgs,
    deploy: Option<crate::run::DeployOptions>,
    scan: &PackScan,
) -> anyhow::Result<ExitCode> {
    crate::run::run(
        registry,
        &args.diagram,
        &crate::run::RunOptions {
            duration: args.duration,
            stats: args.stats.then_some(args.stats_interval),
            overrides: args.overrides,
            clock_source: args.clock_source,
            searched: scan.searched.clone(),
            refused: scan.refused.clone(),
            deploy,
            foxglove: args.foxglove.options(),
        },
    )
}
