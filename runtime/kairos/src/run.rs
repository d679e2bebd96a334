//! `kairos run`: load, validate, start, report, stop.

use std::path::Path;
use std::process::ExitCode;
use std::sync::{Arc, mpsc};
use std::time::{Duration, Instant};

use anyhow::{Context as _, bail};
use kairos_diagram::{Diagram, Value};
use kairos_runtime::{ComponentState, Engine, StatsSnapshot};
use kairos_sdk_core::Registry;
use kairos_sdk_core::host::RegistryValidation as _;

/// How `kairos run` behaves.
#[derive(Debug, Clone, Default)]
pub struct RunOptions {
    /// Stop after this long; `None` runs until Ctrl-C (or until every component has finished).
    pub duration: Option<Duration>,
    /// Print statistics at this interval, and a final table.
    pub stats: Option<Duration>,
    /// Property overrides, `ID.PROPERTY=VALUE`.
    pub overrides: Vec<String>,
    /// The component the clock follows, over the diagram's `clock_source`.
    pub clock_source: Option<String>,
    /// The pack path searched, for messages about missing packs.
    pub searched: Vec<std::path::PathBuf>,
    /// What on it was refused, for the same.
    pub refused: Vec<kairos_runtime::RefusedLibrary>,
    /// `kairos deploy`: the components with a `host` go to that host's `kairos serve`, the rest runs here.
    pub deploy: Option<DeployOptions>,
    /// Publish outputs live to Foxglove.
    pub foxglove: Option<kairos_server::FoxgloveOptions>,
}

/// What `kairos deploy` adds to `kairos run`.
#[derive(Debug, Clone, Copy, Default)]
pub struct DeployOptions {
    /// Send tokens over plain ws:// to hosts off this machine (refused otherwise).
    pub clear_text_tokens: bool,
    /// How far from its master a host's clock may be for the start to go ahead.
    pub lock_bound: Duration,
    /// Start even with hosts whose clocks are not locked within `lock_bound`.
    pub start_unlocked: bool,
}

/// Parses `ID.PROPERTY=VALUE`; the value is a boolean, an integer, a number, or else text.
pub fn parse_override(text: &str) -> anyhow::Result<(String, String, Value)> {
    let Some((target, value)) = text.split_once('=') else {
        bail!("--set '{text}': expected ID.PROPERTY=VALUE, e.g. sine1.frequency=2.5");
    };
    let Some((id, property)) = target.rsplit_once('.') else {
        bail!("--set '{text}': expected ID.PROPERTY before '=', e.g. sine1.frequency");
    };
    let value = value.trim();
    let parsed = if let Ok(b) = value.parse::<bool>() {
        Value::Bool(b)
    } else if let Ok(i) = value.parse::<i64>() {
        Value::I64(i)
    } else if let Ok(f) = value.parse::<f64>() {
        Value::F64(f)
    } else {
        Value::Text(value.trim_matches('"').to_owned())
    };
    Ok((id.to_owned(), property.to_owned(), parsed))
}

/// Exit code when the run ended with a failed component.
const EXIT_COMPONENT_FAILED: u8 = 2;

/// `--set` and `--clock-source` applied to the diagram read.
fn apply_options(parsed: &mut kairos_diagram::ParsedDiagram, options: &RunOptions) -> anyhow::Result<()> {
    for text in &options.overrides {
        let (id, property, value) = parse_override(text)?;
        let Some(component) = parsed.diagram.component_mut(&id) else {
            bail!("--set '{text}': the diagram has no component '{id}'");
        };
        component.properties.insert(property, value);
    }
    if let Some(source) = &options.clock_source {
        if parsed.diagram.component(source).is_none() {
            bail!("--clock-source '{source}': the diagram has no component '{source}'");
        }
        parsed.diagram.clock_source = Some(source.clone());
        parsed.source_map.clock_source = None;
    }
    Ok(())
}

/// The diagram at `path` with `options` applied, checked against `registry`; `None` when it cannot be read
/// or has errors (printed, located).
fn load_checked(
    registry: &Registry,
    path: &Path,
    options: &RunOptions,
) -> anyhow::Result<Option<kairos_diagram::ParsedDiagram>> {
    let (source, flattened) = match kairos_diagram::load_flattened(path, registry.subgraphs()) {
        Ok(loaded) => loaded,
        Err(error) => {
            eprint!("{}", error.render());
            return Ok(None);
        }
    };
    let mut parsed = flattened.parsed;
    apply_options(&mut parsed, options)?;
    let mut diagnostics = registry.validate(&parsed.diagram, Some(&parsed.source_map));
    flattened.origins.annotate(&mut diagnostics);
    if !diagnostics.is_empty() {
        crate::packs::say_refused(&mut diagnostics, &options.refused);
        eprint!(
            "{}",
            kairos_diagram::render_all(&diagnostics, &path.display().to_string(), &source)
        );
        crate::packs::explain_missing(&diagnostics, &options.searched);
    }
    Ok((!diagnostics.iter().any(kairos_diagram::Diagnostic::is_error)).then_some(parsed))
}

/// Runs the diagram at `path` with the components of `registry`.
pub fn run(registry: &Registry, path: &Path, options: &RunOptions) -> anyhow::Result<ExitCode> {
    let Some(mut parsed) = load_checked(registry, path, options)? else {
        return Ok(ExitCode::from(1));
    };

    let (stop_tx, stop_rx) = mpsc::sync_channel::<()>(1);
    ctrlc::set_handler(move || {
        let _ = stop_tx.try_send(());
    })
    .context("installing the Ctrl-C handler")?;

    let note = kairos_clock_sync::StartNote::default();
    let build = |diagram: &Diagram| -> anyhow::Result<Engine> {
        let clock = kairos_clock_sync::NotedClock::new(
            kairos_runtime::clock_for(diagram, registry),
            Arc::clone(&note),
        );
        Engine::build(diagram, registry, Arc::new(clock)).map_err(|error| anyhow::anyhow!("{error}"))
    };
    // Deploying: every host's part and this machine's are prepared before any host's is committed, and
    // all are started together; then the diagram run here is this machine's part alone.
    let mut watch = None;
    let in_all = parsed.diagram.components.len();
    let mut engine = match options.deploy {
        Some(deploy) => {
            let folder = path.parent().unwrap_or_else(|| Path::new("."));
            let ((engine, here), deployed) = kairos_coordinator::deploy_everywhere(
                &parsed.diagram,
                registry,
                folder,
                deploy.clear_text_tokens,
                |here| Ok((build(here)?, here.clone())),
            )?;
            parsed.diagram = here;
            watch = Some(deployed);
            engine
        }
        None => build(&parsed.diagram)?,
    };
    let foxglove = options
        .foxglove
        .as_ref()
        .map(|f| kairos_server::start_foxglove(Arc::new(kairos_server::EngineOutputs::of(&engine)), f))
        .transpose()?;
    start_everywhere(
        &mut engine,
        watch.as_mut().map_or(&mut [], |w| &mut w.hosts),
        options.deploy.unwrap_or_default(),
        &note,
    )?;
    let here = parsed.diagram.components.len();
    let components = match &watch {
        // A spread diagram: what runs here is this machine's part alone.
        Some(watch) => format!(
            "{in_all} components over {} hosts, {here} of them here",
            watch.hosts.len()
        ),
        None => format!("{here} components"),
    };
    tracing::info!(
        "running {} ({components}){}",
        path.display(),
        options
            .duration
            .map_or_else(|| "; Ctrl-C stops".to_owned(), |d| format!(" for {d:?}"))
    );

    let started = Instant::now();
    let mut last_stats = engine.snapshot();
    let mut last_print = Instant::now();
    let first = last_stats.clone();
    loop {
        // At the watch's next look when sooner: a cut is said within a second.
        let tick = watch.as_ref().map_or(Duration::from_millis(50), |watch| {
            watch
                .next_look_in()
                .clamp(Duration::from_millis(1), Duration::from_millis(50))
        });
        let stop_requested = !matches!(stop_rx.recv_timeout(tick), Err(mpsc::RecvTimeoutError::Timeout));
        if stop_requested {
            tracing::info!("stopping (Ctrl-C)");
            break;
        }
        if options.duration.is_some_and(|d| started.elapsed() >= d) {
            break;
        }
        if let Some(watch) = &mut watch {
            watch.check();
        }
        if engine.all_finished() && watch.as_ref().is_none_or(kairos_coordinator::Watch::is_empty) {
            tracing::info!("every component has finished");
            break;
        }
        if let Some(interval) = options.stats
            && last_print.elapsed() >= interval
        {
            let now = engine.snapshot();
            eprintln!(
                "--- {:.1} s ---\n{}",
                started.elapsed().as_secs_f64(),
                now.clone().with_rates_since(&last_stats).table()
            );
            last_stats = now;
            last_print = Instant::now();
        }
    }
    let mut left = Vec::new();
    match &mut watch {
        Some(watch) => {
            watch.stop_together(|| engine.stop());
            let here = engine.snapshot();
            watch.report_final_counts(|id| {
                here.components
                    .iter()
                    .find(|c| c.id == id)
                    .and_then(|c| c.status.clone())
                    .unwrap_or_default()
            });
            left.extend(watch.left().map(|name| format!("'{name}'")));
        }
        None => engine.stop(),
    }
    if let Some(foxglove) = foxglove {
        foxglove.shutdown();
    }
    let last = engine.snapshot().with_rates_since(&first);
    if options.stats.is_some() {
        eprintln!(
            "=== final, {:.1} s (rates are averages over the run) ===\n{}",
            started.elapsed().as_secs_f64(),
            last.table()
        );
    }
    if !left.is_empty() {
        tracing::error!(
            "host(s) {} left this deployment during the run: another diagram runs there now",
            left.join(", ")
        );
        report_failures(&last);
        return Ok(ExitCode::from(1));
    }
    Ok(report_failures(&last))
}

/// Starts this machine's part, and with hosts, every host's part at one instant, each on its own clock.
///
/// A start forced with hosts' clocks not locked (`--start-unlocked`) says so in `note`, which every
/// recording here and on the hosts carries.
fn start_everywhere(
    engine: &mut Engine,
    hosts: &mut [kairos_coordinator::Host],
    deploy: DeployOptions,
    note: &kairos_clock_sync::StartNote,
) -> anyhow::Result<()> {
    if hosts.is_empty() {
        engine.start().context("starting the diagram")?;
    } else {
        let started =
            kairos_coordinator::start_together(hosts, deploy.lock_bound, deploy.start_unlocked, |forced| {
                *note.lock().unwrap_or_else(std::sync::PoisonError::into_inner) = forced.map(str::to_owned);
                engine.start().context("starting the diagram")
            });
        if started.is_err() {
            engine.stop();
        }
        started?;
    }
    Ok(())
}

fn report_failures(snapshot: &StatsSnapshot) -> ExitCode {
    let failed: Vec<_> = snapshot
        .components
        .iter()
        .filter_map(|c| match &c.state {
            ComponentState::Failed(error) => Some((c.id.as_str(), error.as_str())),
            _ => None,
        })
        .collect();
    if failed.is_empty() {
        return ExitCode::SUCCESS;
    }
    for (id, error) in &failed {
        eprintln!("component '{id}' failed: {error}");
    }
    ExitCode::from(EXIT_COMPONENT_FAILED)
}
