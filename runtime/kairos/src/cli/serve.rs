//! `kairos serve` and `kairos status`: a runtime the control protocol drives, and what runtimes are doing.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use kairos_sdk_core::Registry;

use super::run::FoxgloveArgs;
use crate::duration::parse_duration;

/// What `kairos serve` takes.
#[derive(Debug, clap::Args)]
pub struct ServeArgs {
    /// Where to listen. Anything but loopback requires --token-file.
    #[arg(long, default_value = kairos_server::DEFAULT_LISTEN, value_name = "HOST:PORT")]
    pub listen: String,
    /// The operator token: read from FILE, or a fresh one written there (owner-only) if FILE is missing.
    #[arg(long, value_name = "FILE")]
    pub token_file: Option<PathBuf>,
    /// A token for read-only (monitor) clients, read or made the same way.
    #[arg(long, value_name = "FILE")]
    pub monitor_token_file: Option<PathBuf>,
    /// Deploy this diagram at boot.
    #[arg(long, value_name = "FILE")]
    pub diagram: Option<PathBuf>,
    /// Start the --diagram at boot, for unattended targets.
    #[arg(long, requires = "diagram")]
    pub start: bool,
    /// The most clients served at once.
    #[arg(long, default_value_t = kairos_protocol::DEFAULT_MAX_CONNECTIONS)]
    pub max_connections: usize,
    /// Stop when standard input closes: the program that started this runtime (the studio) ended,
    /// even if it was killed.
    #[arg(long)]
    pub stop_with_stdin: bool,
    /// Remove the --token-file at exit, and its folder when that leaves it empty (a token made for this
    /// run alone).
    #[arg(long, requires = "token_file")]
    pub temporary_token: bool,
    /// Be the clock master of other runtimes: answer their clock exchanges on this UDP address
    /// (`0.0.0.0:7401`).
    #[arg(long, value_name = "HOST:PORT", conflicts_with = "clock_slave_of")]
    pub clock_master: Option<String>,
    /// Follow the clock of the master at this UDP address: every diagram deployed here runs on it.
    #[arg(long, value_name = "HOST:PORT", conflicts_with = "clock_system_against")]
    pub clock_slave_of: Option<String>,
    /// Run on this machine's system clock, kept by PTP or chrony, and only measure it against the
    /// clock master at this UDP address, raising an alarm past --clock-alarm.
    #[arg(long, value_name = "HOST:PORT")]
    pub clock_system_against: Option<String>,
    /// How far from its master the system clock may be before the alarm (--clock-system-against):
    /// `500us`, `1ms`.
    #[arg(long, value_name = "DURATION", value_parser = parse_duration, default_value = "1ms")]
    pub clock_alarm: Duration,
    /// Serve over TLS (wss://) with this certificate chain (PEM); clients trust it or its issuer.
    #[arg(long, value_name = "FILE", requires = "tls_key")]
    pub tls_cert: Option<PathBuf>,
    /// The certificate's private key (PEM).
    #[arg(long, value_name = "FILE", requires = "tls_cert")]
    pub tls_key: Option<PathBuf>,
    /// Where to write packs that a deploying machine ships here (default
    /// `~/.local/share/kairos/shipped-packs`).
    #[arg(long, value_name = "DIR")]
    pub shipped_pack_dir: Option<PathBuf>,
    #[command(flatten)]
    pub hosts: CoordinatingArgs,
    #[command(flatten)]
    pub foxglove: FoxgloveArgs,
}

impl ServeArgs {
    /// Serves until stopped.
    pub(super) fn execute(self, registry: Registry) -> anyhow::Result<ExitCode> {
        kairos_server::serve(
            registry,
            &kairos_server::ServeOptions {
                listen: self.listen,
                token_file: self.token_file,
                monitor_token_file: self.monitor_token_file,
                diagram: self.diagram,
                start: self.start,
                max_connections: self.max_connections,
                stop_with_stdin: self.stop_with_stdin,
                temporary_token: self.temporary_token,
                clock_master: self.clock_master,
                clock_slave_of: self.clock_slave_of,
                clock_system: self.clock_system_against.map(|master| (master, self.clock_alarm)),
                tls: self.tls_cert.zip(self.tls_key),
                shipped_pack_folder: self.shipped_pack_dir,
                host_tokens: if self.hosts.allow_clear_text_tokens {
                    kairos_server::HostTokens::ClearTextAllowed
                } else {
                    kairos_server::HostTokens::Protected
                },
                foxglove_backlog: self.foxglove.foxglove_backlog,
                foxglove: self.foxglove.options(),
            },
        )
    }
}

/// What `serve` takes for the hosts it coordinates, when deployed a diagram spread over them (the studio's
/// Run).
#[derive(Debug, clap::Args)]
pub struct CoordinatingArgs {
    /// Send the hosts' tokens over plain ws:// to machines off this one, on a network you trust (else
    /// only over wss:// or on loopback).
    #[arg(long)]
    pub allow_clear_text_tokens: bool,
}

/// What `kairos status` takes.
#[derive(Debug, clap::Args)]
pub struct StatusArgs {
    /// A diagram with a hosts section, or a runtime's endpoint (ws://ADDRESS:PORT).
    pub target: String,
    /// The runtime's token file, with an endpoint (a diagram names its own).
    #[arg(long)]
    pub token_file: Option<PathBuf>,
    /// With a wss:// endpoint: the certificate to trust (PEM).
    #[arg(long)]
    pub certificate: Option<PathBuf>,
    /// Send tokens over plain ws:// to runtimes off this machine (see `deploy`).
    #[arg(long)]
    pub allow_clear_text_tokens: bool,
}

impl StatusArgs {
    /// Prints each runtime's line; exit 1 when one could not be reached.
    pub(super) fn execute(self) -> anyhow::Result<ExitCode> {
        let reached_all = crate::status::print(
            &self.target,
            self.token_file.as_deref(),
            self.certificate.as_deref(),
            self.allow_clear_text_tokens,
        )?;
        Ok(if reached_all {
            ExitCode::SUCCESS
        } else {
            ExitCode::from(1)
        })
    }
}
