//! Argument parsing and dispatch.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::Context as _;
use clap::{Parser, Subcommand};
use kairos_diagram::LibraryInfo;
use kairos_sdk::Registry;

use crate::duration::parse_duration;

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

/// What `run` and `deploy` take.
#[derive(Debug, clap::Args)]
pub struct RunArgs {
    /// The diagram file (.ron).
    diagram: PathBuf,
    /// Stop after this long (e.g. 10s, 500ms, 2m).
    #[arg(long = "for", value_parser = parse_duration)]
    duration: Option<Duration>,
    /// Print per-link and per-component statistics periodically and a final table at exit.
    #[arg(long)]
    stats: bool,
    /// How often --stats prints.
    #[arg(long, value_parser = parse_duration, default_value = "1s")]
    stats_interval: Duration,
    /// Override a property before running, e.g. `--set sine1.frequency=2.5` (repeatable).
    #[arg(long = "set", value_name = "ID.PROPERTY=VALUE")]
    overrides: Vec<String>,
    /// Make the runtime clock follow this component's time (a GNSS receiver), overriding the
    /// diagram's `clock_source`.
    #[arg(long, value_name = "ID")]
    clock_source: Option<String>,
    #[command(flatten)]
    foxglove: FoxgloveArgs,
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
        default_missing_value = crate::serve::DEFAULT_FOXGLOVE_ADDRESS
    )]
    foxglove: Option<String>,
    /// Publish only this output to Foxglove (`camera.image`); give it once per output.
    #[arg(
        long = "foxglove-output",
        value_name = "COMPONENT.OUTPUT",
        requires = "foxglove"
    )]
    foxglove_outputs: Vec<String>,
    /// Let --foxglove listen off loopback. Foxglove's protocol carries no token: anyone who can reach the
    /// address sees the published outputs.
    #[arg(long, requires = "foxglove")]
    foxglove_open_to_network: bool,
    /// Messages queued per Foxglove client before the oldest are dropped: what a slow viewer can hold.
    #[arg(long, value_name = "MESSAGES", default_value_t = crate::serve::DEFAULT_FOXGLOVE_BACKLOG)]
    foxglove_backlog: usize,
}

impl FoxgloveArgs {
    /// What `--foxglove` asks for, if it was given.
    fn options(self) -> Option<crate::serve::FoxgloveOptions> {
        let backlog = self.foxglove_backlog;
        self.foxglove.map(|address| crate::serve::FoxgloveOptions {
            address,
            selection: crate::serve::Selection {
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
    run: RunArgs,
    /// Send tokens to hosts off this machine over plain ws://, where anyone on the network path can read
    /// them and take control of those runtimes. Without it, such a deploy is refused: use wss:// instead.
    #[arg(long)]
    allow_clear_text_tokens: bool,
    /// How far from its master a host's clock may be for the start to go ahead (hosts started with
    /// `--clock-slave-of`).
    #[arg(long, value_parser = parse_duration, default_value = "1ms")]
    lock_bound: Duration,
    /// Start even when a host's clock is not locked within --lock-bound: the parts may start apart.
    #[arg(long)]
    start_unlocked: bool,
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
    Serve {
        /// Where to listen. Anything but loopback requires --token-file.
        #[arg(long, default_value = crate::serve::DEFAULT_LISTEN, value_name = "HOST:PORT")]
        listen: String,
        /// The operator token: read from FILE, or a fresh one written there (owner-only) if FILE is missing.
        #[arg(long, value_name = "FILE")]
        token_file: Option<PathBuf>,
        /// A token for read-only (monitor) clients, read or made the same way.
        #[arg(long, value_name = "FILE")]
        monitor_token_file: Option<PathBuf>,
        /// Deploy this diagram at boot.
        #[arg(long, value_name = "FILE")]
        diagram: Option<PathBuf>,
        /// Start the --diagram at boot, for unattended targets.
        #[arg(long, requires = "diagram")]
        start: bool,
        /// The most clients served at once.
        #[arg(long, default_value_t = kairos_protocol::DEFAULT_MAX_CONNECTIONS)]
        max_connections: usize,
        /// Stop when standard input closes: the program that started this runtime (the studio) ended,
        /// even if it was killed.
        #[arg(long)]
        stop_with_stdin: bool,
        /// Remove the --token-file at exit, and its folder when that leaves it empty (a token made for this
        /// run alone).
        #[arg(long, requires = "token_file")]
        temporary_token: bool,
        /// Be the clock master of other runtimes: answer their clock exchanges on this UDP address
        /// (`0.0.0.0:7401`).
        #[arg(long, value_name = "HOST:PORT", conflicts_with = "clock_slave_of")]
        clock_master: Option<String>,
        /// Follow the clock of the master at this UDP address: every diagram deployed here runs on it.
        #[arg(long, value_name = "HOST:PORT", conflicts_with = "clock_system_against")]
        clock_slave_of: Option<String>,
        /// Run on this machine's system clock, kept by PTP or chrony, and only measure it against the
        /// clock master at this UDP address, raising an alarm past --clock-alarm.
        #[arg(long, value_name = "HOST:PORT")]
        clock_system_against: Option<String>,
        /// How far from its master the system clock may be before the alarm (--clock-system-against):
        /// `500us`, `1ms`.
        #[arg(long, value_name = "DURATION", value_parser = parse_duration, default_value = "1ms")]
        clock_alarm: Duration,
        /// Serve over TLS (wss://) with this certificate chain (PEM); clients trust it or its issuer.
        #[arg(long, value_name = "FILE", requires = "tls_key")]
        tls_cert: Option<PathBuf>,
        /// The certificate's private key (PEM).
        #[arg(long, value_name = "FILE", requires = "tls_cert")]
        tls_key: Option<PathBuf>,
        /// Where to write packs that a deploying machine ships here (default
        /// `~/.local/share/kairos/shipped-packs`).
        #[arg(long, value_name = "DIR")]
        shipped_pack_dir: Option<PathBuf>,
        #[command(flatten)]
        foxglove: FoxgloveArgs,
    },
    /// Check diagrams against the component library; exit 0 when all are valid.
    Validate {
        /// The diagram files.
        #[arg(required = true)]
        diagrams: Vec<PathBuf>,
    },
    /// Describe a recording: channels, types, counts, rates, duration, drops and metadata.
    Inspect {
        /// The MCAP file.
        file: PathBuf,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Rewrite an unfinished or damaged recording into a complete one, keeping everything intact.
    Recover {
        /// The damaged recording.
        input: PathBuf,
        /// Where to write the complete one.
        output: PathBuf,
    },
    /// Merge recordings made on several hosts into one file on one timeline, each channel prefixed by its
    /// host (`car/camera.image`).
    Merge {
        /// The recordings: FILE (its host is the file's name) or HOST=FILE.
        #[arg(required = true, num_args = 2..)]
        inputs: Vec<String>,
        /// The merged file.
        #[arg(short, long)]
        output: PathBuf,
        /// Merge recordings whose clocks were not locked all the same (the merged file says so).
        #[arg(long)]
        allow_unsynchronised: bool,
    },
    /// List the packs: built-in and loaded from the pack path, with the libraries refused and why.
    Packs {
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
    /// List the component library.
    Components {
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
        /// Show only types containing this text.
        filter: Option<String>,
    },
    /// List this machine's serial ports, CAN interfaces and cameras, for the device properties.
    Devices {
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Show what each host of a diagram is doing (state, clock against its master, links), or one
    /// runtime given its ws:// endpoint. Exits with 1 when a host cannot be reached.
    Status {
        /// A diagram with a hosts section, or a runtime's endpoint (ws://ADDRESS:PORT).
        target: String,
        /// The runtime's token file, with an endpoint (a diagram names its own).
        #[arg(long)]
        token_file: Option<PathBuf>,
        /// With a wss:// endpoint: the certificate to trust (PEM).
        #[arg(long)]
        certificate: Option<PathBuf>,
        /// Send tokens over plain ws:// to runtimes off this machine (see `deploy`).
        #[arg(long)]
        allow_clear_text_tokens: bool,
    },
    /// Generate a pack or a component from the templates.
    #[command(subcommand)]
    New(NewCommand),
}

/// What `kairos new` generates.
#[derive(Debug, Subcommand)]
pub enum NewCommand {
    /// A pack crate (built in or loaded at run time) with an example component and its unit test.
    Pack {
        /// The pack's name (lower case, digits and _): the prefix of its component types.
        name: String,
        /// The folder to create the pack in (it goes in PATH/NAME).
        #[arg(long, default_value = ".")]
        path: PathBuf,
        /// The kairos-sdk to depend on (default: this installation's).
        #[arg(long, value_name = "PATH")]
        sdk: Option<PathBuf>,
        /// The pack's language: a Rust crate, C++ against the C header of the pack ABI, or Python
        /// (`.py` files, nothing to build).
        #[arg(long, value_enum, default_value = "rust")]
        lang: crate::wizard::Lang,
        /// Overwrite files that exist.
        #[arg(long)]
        force: bool,
    },
    /// A component in a pack made by `kairos new pack`, registered in it. Without a name, it asks.
    Component {
        /// The component's name in the pack (lower case, digits and _); none: ask for every answer.
        name: Option<String>,
        /// The pack's folder.
        #[arg(long, value_name = "DIR", default_value = ".")]
        pack: PathBuf,
        /// An input, NAME:TYPE (TYPE: f64, i64, bool, vector, matrix, text, bytes, image, `point_cloud`, imu,
        /// `gnss_fix`, `can_frame`, pose or any); repeatable.
        #[arg(long = "input", value_name = "NAME:TYPE")]
        inputs: Vec<String>,
        /// An output, NAME:TYPE; repeatable.
        #[arg(long = "output", value_name = "NAME:TYPE")]
        outputs: Vec<String>,
        /// A property, NAME:TYPE=DEFAULT (TYPE: f64, i64, bool, text, path); repeatable.
        #[arg(long = "property", value_name = "NAME:TYPE=DEFAULT")]
        properties: Vec<String>,
        /// An action (a button in the studio); repeatable.
        #[arg(long = "action", value_name = "NAME")]
        actions: Vec<String>,
        /// How it runs.
        #[arg(long, value_enum, default_value = "threaded")]
        mode: crate::wizard::Mode,
        /// The pack's language, checked against the pack (which decides it).
        #[arg(long, value_enum)]
        lang: Option<crate::wizard::Lang>,
        /// Overwrite the component's file if it exists.
        #[arg(long)]
        force: bool,
        /// Check the answers and say what is wrong, writing nothing.
        #[arg(long)]
        dry_run: bool,
    },
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
        .with(crate::log_tap::LogTap)
        .try_init();
}

/// Runs a parsed command line.
#[allow(clippy::too_many_lines, reason = "one arm per subcommand, each a call")]
pub fn execute(cli: Cli) -> anyhow::Result<ExitCode> {
    let diagrams: Vec<&std::path::Path> = match &cli.command {
        Command::Run(args) | Command::Deploy(DeployArgs { run: args, .. }) => vec![args.diagram.as_path()],
        Command::Serve { diagram, .. } => diagram.iter().map(PathBuf::as_path).collect(),
        Command::Validate { diagrams } => diagrams.iter().map(PathBuf::as_path).collect(),
        Command::Packs { .. }
        | Command::Components { .. }
        | Command::New(_)
        | Command::Inspect { .. }
        | Command::Recover { .. }
        | Command::Merge { .. }
        | Command::Devices { .. }
        | Command::Status { .. } => Vec::new(),
    };
    let (registry, scan) = crate::registry_with_packs(&cli.pack_path, &diagrams);
    if !matches!(cli.command, Command::Packs { .. }) {
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
    match cli.command {
        Command::Run(args) => run_with(&registry, args, None, &scan.searched),
        Command::Deploy(args) => run_with(
            &registry,
            args.run,
            Some(crate::run::DeployOptions {
                clear_text_tokens: args.allow_clear_text_tokens,
                lock_bound: args.lock_bound,
                start_unlocked: args.start_unlocked,
            }),
            &scan.searched,
        ),
        Command::Validate { diagrams } => Ok(validate(&registry, &diagrams, &scan.searched)),
        Command::Serve {
            listen,
            token_file,
            monitor_token_file,
            diagram,
            start,
            max_connections,
            stop_with_stdin,
            temporary_token,
            clock_master,
            clock_slave_of,
            clock_system_against,
            clock_alarm,
            tls_cert,
            tls_key,
            shipped_pack_dir,
            foxglove,
        } => crate::serve::serve(
            registry,
            &crate::serve::ServeOptions {
                listen,
                token_file,
                monitor_token_file,
                diagram,
                start,
                max_connections,
                stop_with_stdin,
                temporary_token,
                clock_master,
                clock_slave_of,
                clock_system: clock_system_against.map(|master| (master, clock_alarm)),
                tls: tls_cert.zip(tls_key),
                shipped_pack_folder: shipped_pack_dir,
                foxglove_backlog: foxglove.foxglove_backlog,
                foxglove: foxglove.options(),
            },
        ),
        Command::Inspect { file, json } => {
            let report = inspect_showing_progress(&file)?;
            if json {
                println!(
                    "{}",
                    serde_json::to_string_pretty(&report).context("encoding the report as JSON")?
                );
            } else {
                print!("{}", report.text());
            }
            Ok(if report.damage.is_some() {
                ExitCode::from(3)
            } else {
                ExitCode::SUCCESS
            })
        }
        Command::Merge {
            inputs,
            output,
            allow_unsynchronised,
        } => {
            let inputs: Vec<_> = inputs
                .iter()
                .map(|a| kairos_pack_recording::merge::MergeInput::parse(a))
                .collect();
            let merged = kairos_pack_recording::merge::merge(&inputs, &output, allow_unsynchronised)?;
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
            Ok(ExitCode::SUCCESS)
        }
        Command::Recover { input, output } => {
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
        Command::Status {
            target,
            token_file,
            certificate,
            allow_clear_text_tokens,
        } => {
            let reached_all = crate::status::print(
                &target,
                token_file.as_deref(),
                certificate.as_deref(),
                allow_clear_text_tokens,
            )?;
            Ok(if reached_all {
                ExitCode::SUCCESS
            } else {
                ExitCode::from(1)
            })
        }
        Command::Devices { json } => {
            let devices = crate::devices::list(std::path::Path::new("/"));
            if json {
                println!(
                    "{}",
                    serde_json::to_string_pretty(&devices).context("encoding the devices as JSON")?
                );
            } else {
                print!("{}", crate::devices::text(&devices));
            }
            Ok(ExitCode::SUCCESS)
        }
        Command::Packs { json } => {
            crate::packs::list(&registry, &scan, json)?;
            Ok(ExitCode::SUCCESS)
        }
        Command::Components { json, filter } => {
            components(&registry.library_info(), json, filter.as_deref())?;
            Ok(ExitCode::SUCCESS)
        }
        Command::New(what) => Ok(new(what, &registry)),
    }
}

/// What to do with a pack `kairos new pack` made.
fn print_pack_next_steps(
    lang: crate::wizard::Lang,
    name: &str,
    folder: &std::path::Path,
    path: &std::path::Path,
) {
    if lang == crate::wizard::Lang::Python {
        println!("  cd {} && python3 -m pytest", folder.display());
        println!("  kairos --pack-path {} components {name}.", path.display());
    } else if lang == crate::wizard::Lang::Cpp {
        println!("  cd {} && make", folder.display());
        println!(
            "  kairos --pack-path {}/build components {name}.",
            folder.display()
        );
    } else {
        println!("  cd {} && cargo test && cargo build --release", folder.display());
        println!(
            "  kairos --pack-path {}/target/release components {name}.",
            folder.display()
        );
    }
}

/// `kairos new`: prints what was made, or why nothing was.
fn new(what: NewCommand, registry: &Registry) -> ExitCode {
    let result = match what {
        NewCommand::Pack {
            name,
            path,
            sdk,
            lang,
            force,
        } => {
            let sdk = sdk.unwrap_or_else(crate::wizard::default_sdk_path);
            let library = registry.library_info();
            crate::wizard::new_pack(&name, &path, &sdk, &library, lang, force).map(|(folder, notes)| {
                println!("made the pack '{name}' in {}", folder.display());
                print_pack_next_steps(lang, &name, &folder, &path);
                notes
            })
        }
        NewCommand::Component {
            name,
            pack,
            inputs,
            outputs,
            properties,
            actions,
            mode,
            lang,
            force,
            dry_run,
        } => {
            let (spec, pack) = match name {
                Some(name) => (
                    crate::wizard::ComponentSpec {
                        name,
                        inputs,
                        outputs,
                        properties,
                        actions,
                        mode,
                    },
                    pack,
                ),
                None => match crate::wizard::ask(&mut std::io::stdin().lock(), &mut std::io::stdout()) {
                    Ok(answers) => answers,
                    Err(error) => {
                        eprintln!("error: {error}");
                        return ExitCode::from(1);
                    }
                },
            };
            let name = spec.name.clone();
            if let (Some(wanted), Some(found)) = (lang, crate::wizard::pack_lang(&pack))
                && wanted != found
            {
                eprintln!(
                    "error: the pack at {} is a {} pack, not {}: make a {} pack with `kairos new pack NAME --lang {}`",
                    pack.display(),
                    found.name(),
                    wanted.name(),
                    wanted.name(),
                    format!("{wanted:?}").to_lowercase()
                );
                return ExitCode::from(1);
            }
            if dry_run {
                return match crate::wizard::check_component(&spec, &pack, &registry.library_info(), force) {
                    Ok(()) => {
                        println!("ok: {name} can be made in {}", pack.display());
                        ExitCode::SUCCESS
                    }
                    Err(error) => {
                        eprintln!("error: {error}");
                        ExitCode::from(1)
                    }
                };
            }
            crate::wizard::new_component(&spec, &pack, &registry.library_info(), force).inspect(|_| {
                let file = match crate::wizard::pack_lang(&pack) {
                    Some(crate::wizard::Lang::Python) => pack.join(format!("{name}.py")),
                    Some(crate::wizard::Lang::Cpp) => pack.join("src").join(format!("{name}.cpp")),
                    _ => pack.join("src").join(format!("{name}.rs")),
                };
                println!("made the component '{name}' in {}", file.display());
            })
        }
    };
    match result {
        Ok(notes) => {
            for note in notes {
                eprintln!("note: {note}");
            }
            ExitCode::SUCCESS
        }
        Err(error) => {
            eprintln!("error: {error}");
            ExitCode::from(1)
        }
    }
}

fn validate(registry: &Registry, paths: &[PathBuf], searched: &[PathBuf]) -> ExitCode {
    let mut all_valid = true;
    for path in paths {
        match kairos_diagram::load(path) {
            Err(error) => {
                all_valid = false;
                eprint!("{}", error.render());
            }
            Ok((source, parsed)) => {
                let diagnostics = registry.validate(&parsed.diagram, Some(&parsed.source_map));
                let name = path.display().to_string();
                if diagnostics.is_empty() {
                    println!("{name}: valid");
                } else {
                    eprint!("{}", kairos_diagram::render_all(&diagnostics, &name, &source));
                    crate::packs::explain_missing(&diagnostics, searched);
                    if diagnostics.iter().any(kairos_diagram::Diagnostic::is_error) {
                        all_valid = false;
                    } else {
                        println!("{name}: valid (with warnings)");
                    }
                }
            }
        }
    }
    if all_valid {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    }
}

fn components(library: &LibraryInfo, json: bool, filter: Option<&str>) -> anyhow::Result<()> {
    let selected: Vec<_> = library
        .components
        .values()
        .filter(|c| filter.is_none_or(|f| c.type_name.contains(f)))
        .collect();
    if json {
        let document = serde_json::json!({
            "packs": library.packs.values().collect::<Vec<_>>(),
            "components": selected,
        });
        println!(
            "{}",
            serde_json::to_string_pretty(&document).context("encoding the library as JSON")?
        );
        return Ok(());
    }
    let mut out = String::new();
    for component in selected {
        let _ = writeln!(
            out,
            "{} ({})  [{} / {}, {:?}]",
            component.type_name,
            component.display_name(),
            component.pack,
            component.category,
            component.mode
        );
        let _ = writeln!(out, "    {}", component.doc);
        for input in &component.inputs {
            let _ = writeln!(
                out,
                "    in   {:<12} {} (default {})  {}",
                input.name, input.filter, input.default_policy, input.doc
            );
        }
        for output in &component.outputs {
            let data_type = output.follows_input.as_ref().map_or_else(
                || output.data_type.to_string(),
                |i| format!("same as input '{i}'"),
            );
            let _ = writeln!(
                out,
                "    out  {:<12} {} (buffer {})  {}",
                output.name, data_type, output.default_buffer_size, output.doc
            );
        }
        for property in &component.properties {
            let _ = writeln!(
                out,
                "    prop {:<12} {} = {}{}  {}",
                property.name,
                property.kind.describe(),
                property.default,
                if property.live { " (live)" } else { "" },
                property.doc
            );
        }
        for action in &component.actions {
            let _ = writeln!(out, "    act  {:<12} {}", action.name, action.doc);
        }
        out.push('\n');
    }
    print!("{out}");
    Ok(())
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

fn run_with(
    registry: &Registry,
    args: RunArgs,
    deploy: Option<crate::run::DeployOptions>,
    searched: &[PathBuf],
) -> anyhow::Result<ExitCode> {
    crate::run::run(
        registry,
        &args.diagram,
        &crate::run::RunOptions {
            duration: args.duration,
            stats: args.stats.then_some(args.stats_interval),
            overrides: args.overrides,
            clock_source: args.clock_source,
            searched: searched.to_vec(),
            deploy,
            foxglove: args.foxglove.options(),
        },
    )
}
