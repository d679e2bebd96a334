//! The runtime a server drives: the deployed diagram and its engine, and every operation a request maps to.
//!
//! One lock guards the deployment; operations that may block (start, stop, a property change waiting for
//! the component's answer) run on blocking threads, never on the server's network threads.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError, RwLock, RwLockReadGuard, TryLockError};

use kairos_diagram::{Diagnostic, Diagram, Value};
use kairos_protocol::{
    ClockState, ClockTelemetry, ComponentTelemetry, DeployResult, ErrorCode, GroupTelemetry,
    LatencyTelemetry, LinkTelemetry, ProtocolError, RequestBody, RuntimeState, Telemetry,
};
use kairos_runtime::{ComponentState, ControlError, Engine, EngineState, LongWait, StatsSnapshot};
use kairos_sdk_core::Registry;
use kairos_sdk_core::host::OutputBuffer;
use kairos_sdk_core::host::RegistryValidation as _;

use super::spread::{Spread, is_spread};

/// The deployed diagram, its text as deployed, and the engine built from it.
#[derive(Default)]
struct Deployment {
    /// What runs here: the diagram, or with a spread one, the part without a host.
    diagram: Option<Diagram>,
    engine: Option<Engine>,
    previous: Option<StatsSnapshot>,
    /// A diagram spread over hosts and coordinated here, as deployed and changed since, and its hosts.
    spread: Option<(Diagram, Arc<Spread>)>,
    /// A part prepared by `prepare_deploy`, waiting for its commit; the deployed one runs meanwhile.
    prepared: Option<(u64, Part)>,
    /// The ticket the next prepared part gets.
    next_ticket: u64,
    /// How many diagrams were deployed: with the server's `boot`, the deployed one's identity.
    installed: u64,
    /// How late the deployed diagram's last start at an agreed instant came, ns.
    start_late_ns: Option<i64>,
}

/// A diagram validated and built, not yet deployed.
struct Part {
    diagram: Diagram,
    engine: Engine,
    diagnostics: Vec<Diagnostic>,
    network: Option<kairos_protocol::LinkNetwork>,
}

/// The shared runtime state of a server.
pub struct Runtime {
    /// Grows when a pack is shipped here (`install_pack`); never shrinks.
    registry: RwLock<Registry>,
    deployment: Mutex<Deployment>,
    /// Changes whenever the engine is replaced: sample subscriptions re-attach when it does. Outside the
    /// lock, so their frequent checks never wait behind a control operation.
    generation: AtomicU64,
    /// The clock every deployed diagram runs on, when this runtime follows a clock master.
    clock: Mutex<Option<Arc<dyn kairos_sdk_core::Clock>>>,
    /// Whether this runtime is the clock master of others.
    clock_master: AtomicBool,
    /// Whether tokens may go over plain ws:// to hosts off this machine when it coordinates them.
    clear_text_tokens: AtomicBool,
    /// How the current run was started when it was forced: in every clock's description.
    start_note: kairos_clock_sync::StartNote,
    /// Drawn at random when the server starts: a deployment's identity includes it, so that one made
    /// before a restart is never taken for one made after.
    boot: u64,
}

impl std::fmt::Debug for Runtime {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Runtime").finish_non_exhaustive()
    }
}

fn error(code: ErrorCode, message: impl Into<String>) -> ProtocolError {
    ProtocolError::new(code, message)
}

fn control_error(e: &ControlError) -> ProtocolError {
    let code = match e {
        ControlError::UnknownComponent(_)
        | ControlError::UnknownProperty { .. }
        | ControlError::UnknownAction { .. } => ErrorCode::NotFound,
        ControlError::InvalidValue { .. } => ErrorCode::InvalidValue,
        ControlError::NotLive { .. } | ControlError::Refused { .. } => ErrorCode::WrongState,
    };
    error(code, e.to_string())
}

/// A diagram whose every component has finished (a replay at its end, a simulation past its duration) is
/// stopped, as `kairos run` stops, and said in the log: a client sees it ready to run again rather than
/// running for ever. A diagram spread over hosts from here is left to its hosts, which may still run.
fn stop_once_all_finished(deployment: &mut Deployment) {
    if deployment.spread.is_some() {
        return;
    }
    if let Some(engine) = deployment.engine.as_mut()
        && engine.state() == EngineState::Running
        && engine.all_finished()
    {
        engine.stop();
        tracing::info!("every component has finished: the diagram stopped");
    }
}

fn state_of(deployment: &Deployment) -> RuntimeState {
    match (&deployment.diagram, deployment.engine.as_ref().map(Engine::state)) {
        (None, _) => RuntimeState::Empty,
        (Some(_), Some(EngineState::Running)) => RuntimeState::Running,
        (Some(_), Some(EngineState::Paused)) => RuntimeState::Paused,
        (Some(_), _) => RuntimeState::Ready,
    }
}

/// A component's state as the protocol says it (the reason of a failure travels apart, in `error`).
fn wire_state(state: &ComponentState) -> kairos_protocol::ComponentState {
    use kairos_protocol::ComponentState as Wire;
    match state {
        ComponentState::Idle => Wire::Idle,
        ComponentState::Running => Wire::Running,
        ComponentState::Paused => Wire::Paused,
        ComponentState::Finished => Wire::Finished,
        ComponentState::Stopped => Wire::Stopped,
        ComponentState::Failed(_) => Wire::Failed,
    }
}

fn telemetry(snapshot: &StatsSnapshot, state: RuntimeState) -> Telemetry {
    Telemetry {
        at_ns: snapshot.at.as_nanos(),
        state,
        links: snapshot
            .links
            .iter()
            .map(|l| LinkTelemetry {
                link: l.link.clone(),
                policy: l.policy,
                written: l.counters.written,
                read: l.counters.read,
                skipped: l.counters.skipped,
                overwritten: l.counters.overwritten,
                queued: l.counters.queued,
                repeated: l.counters.repeated,
                rate_hz: l.rate_hz,
                latency: LatencyTelemetry {
                    count: l.counters.latency.count,
                    min_ns: l.counters.latency.min_nanos,
                    mean_ns: l.counters.latency.mean_nanos,
                    p50_ns: l.counters.latency.p50_nanos,
                    p99_ns: l.counters.latency.p99_nanos,
                    max_ns: l.counters.latency.max_nanos,
                },
            })
            .collect(),
        components: snapshot
            .components
            .iter()
            .map(|c| ComponentTelemetry {
                id: c.id.clone(),
                type_name: c.type_name.clone(),
                state: wire_state(&c.state),
                error: match &c.state {
                    ComponentState::Failed(why) => Some(why.clone()),
                    _ => None,
                },
                cycles: c.cycles,
                cycle_rate_hz: c.cycle_rate_hz,
                cpu_share: c.cpu_share,
                missed_ticks: c.missed_ticks,
                status: c.status.clone(),
                group: c.group.clone(),
            })
            .collect(),
        clock: snapshot.clock.as_ref().map(clock_telemetry),
        groups: snapshot
            .groups
            .iter()
            .map(|g| GroupTelemetry {
                name: g.name.clone(),
                members: g.members.clone(),
                pass_rate_hz: g.pass_rate_hz,
                cpu_share: g.cpu_share,
                mean_pass_ns: g.mean_pass_nanos,
                longest_pass_ns: g.longest_pass_nanos,
                missed_ticks: g.missed_ticks,
                slowest_member: g.slowest_member.clone(),
            })
            .collect(),
        hosts: Vec::new(),
        cross_links: Vec::new(),
    }
}

fn clock_telemetry(clock: &kairos_sdk_core::ClockStatus) -> ClockTelemetry {
    ClockTelemetry {
        source: clock.source.clone(),
        state: match clock.state {
            kairos_sdk_core::ClockState::Acquiring => ClockState::Acquiring,
            kairos_sdk_core::ClockState::Locked => ClockState::Locked,
            kairos_sdk_core::ClockState::Slewing => ClockState::Slewing,
            kairos_sdk_core::ClockState::Holdover => ClockState::Holdover,
            kairos_sdk_core::ClockState::Lost => ClockState::Lost,
            kairos_sdk_core::ClockState::Alarm => ClockState::Alarm,
            kairos_sdk_core::ClockState::Master => ClockState::Master,
        },
        error_ns: clock.error_ns,
        step_ns: clock.step_ns,
        references: clock.references,
        since_reference_s: clock.since_reference_s,
        error_bound_ns: clock.error_bound_ns,
        rate_ppm: clock.rate_ppm,
    }
}

impl Runtime {
    /// A runtime with nothing deployed.
    pub fn new(registry: Registry) -> Arc<Self> {
        Arc::new(Runtime {
            registry: RwLock::new(registry),
            deployment: Mutex::new(Deployment::default()),
            generation: AtomicU64::new(0),
            clock: Mutex::new(None),
            clock_master: AtomicBool::new(false),
            clear_text_tokens: AtomicBool::new(false),
            start_note: kairos_clock_sync::StartNote::default(),
            boot: {
                use std::hash::{BuildHasher as _, Hasher as _};
                std::collections::hash_map::RandomState::new()
                    .build_hasher()
                    .finish()
            },
        })
    }

    /// The deployed diagram's identity: a new one with every deployment and every start of the server.
    pub fn deployment_identity(&self) -> Option<String> {
        let deployment = self.lock();
        deployment
            .diagram
            .as_ref()
            .map(|_| self.identity(deployment.installed))
    }

    /// Records how late the deployed diagram started after the instant agreed with the other hosts.
    pub fn record_start_lateness(&self, late_ns: i64) {
        self.lock().start_late_ns = Some(late_ns);
    }

    /// How late the deployed diagram's last start at an agreed instant came, ns.
    pub fn start_lateness(&self) -> Option<i64> {
        self.lock().start_late_ns
    }

    /// The identity of the `installed`-th deployment since the server started.
    fn identity(&self, installed: u64) -> String {
        format!("{:016x}-{installed}", self.boot)
    }

    /// Runs every diagram deployed from now on on `clock` (a clock synchronised with a master).
    pub fn set_clock(&self, clock: Arc<dyn kairos_sdk_core::Clock>) {
        if let Ok(mut slot) = self.clock.lock() {
            *slot = Some(clock);
        }
    }

    /// The time on this runtime's clock: the master's, when it follows one; the machine's otherwise.
    pub fn now(&self) -> kairos_sdk_core::Timestamp {
        match self.clock.lock().ok().and_then(|slot| slot.clone()) {
            Some(shared) => shared.now(),
            None => kairos_sdk_core::Clock::now(&kairos_sdk_core::RealTimeClock::new()),
        }
    }

    /// Lets the tokens of the hosts this runtime coordinates go over plain ws:// off this machine
    /// (`kairos serve --allow-clear-text-tokens`: a network the user trusts).
    pub fn allow_clear_text_tokens(&self) {
        self.clear_text_tokens.store(true, Ordering::Release);
    }

    /// Makes this runtime the clock master of others: its own clock is the reference.
    pub fn set_clock_master(&self) {
        self.clock_master.store(true, Ordering::Release);
    }

    /// Where this runtime's clock stands when it follows a master or is one (whatever is deployed).
    pub fn clock_telemetry(&self) -> Option<ClockTelemetry> {
        if let Some(clock) = self.clock.lock().ok().and_then(|slot| slot.clone()) {
            return clock.status().as_ref().map(clock_telemetry);
        }
        self.clock_master.load(Ordering::Acquire).then(|| ClockTelemetry {
            source: "this machine".to_owned(),
            state: ClockState::Master,
            error_ns: 0,
            step_ns: 0,
            references: 0,
            since_reference_s: None,
            error_bound_ns: Some(0),
            rate_ppm: None,
        })
    }

    /// The clock a diagram deployed here runs on.
    fn clock_for(&self, diagram: &Diagram, registry: &Registry) -> Arc<dyn kairos_sdk_core::Clock> {
        let clock = match self.clock.lock().ok().and_then(|slot| slot.clone()) {
            Some(shared) => shared,
            None => kairos_runtime::clock_for(diagram, registry),
        };
        let noted = kairos_clock_sync::NotedClock::new(clock, Arc::clone(&self.start_note));
        if self.clock_master.load(Ordering::Acquire) {
            Arc::new(noted.of_the_master())
        } else {
            Arc::new(noted)
        }
    }

    fn lock(&self) -> MutexGuard<'_, Deployment> {
        self.deployment.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The deployment at once if it is free; otherwise blocking through `long_wait` (a deploy or a stop
    /// may hold it for as long as threads take to join).
    fn lock_waiting(&self, long_wait: LongWait<'_>) -> MutexGuard<'_, Deployment> {
        match self.deployment.try_lock() {
            Ok(guard) => guard,
            Err(TryLockError::Poisoned(poisoned)) => poisoned.into_inner(),
            Err(TryLockError::WouldBlock) => {
                let mut guard = None;
                long_wait(&mut || guard = Some(self.lock()));
                guard.unwrap_or_else(|| self.lock())
            }
        }
    }

    fn registry(&self) -> RwLockReadGuard<'_, Registry> {
        self.registry.read().unwrap_or_else(PoisonError::into_inner)
    }

    /// Writes `library` (pack `name` at `version`, shipped by a deploying machine) into `folder`, loads it
    /// and registers its components. Already loaded at that version: nothing to do.
    ///
    /// # Errors
    ///
    /// Another version of the pack is loaded, the library cannot be written or loaded, or it is not the
    /// pack announced.
    pub fn install_pack(
        &self,
        name: &str,
        version: &str,
        library: &[u8],
        folder: &Path,
    ) -> Result<PathBuf, ProtocolError> {
        let mut registry = self.registry.write().unwrap_or_else(PoisonError::into_inner);
        if let Some(loaded) = already_loaded(&registry, name, version) {
            return loaded;
        }
        let file = folder.join(format!(
            "{}{name}-{version}{}",
            std::env::consts::DLL_PREFIX,
            std::env::consts::DLL_SUFFIX
        ));
        let written = std::fs::create_dir_all(folder)
            .and_then(|()| {
                // Written aside then renamed, so a half-written library is never loaded.
                let partial = file.with_extension(format!("partial-{}", std::process::id()));
                std::fs::write(&partial, library)?;
                std::fs::rename(&partial, &file)
            })
            .map_err(|e| {
                error(
                    ErrorCode::Internal,
                    format!("cannot write pack '{name}' to {}: {e}", file.display()),
                )
            });
        written?;
        let pack = kairos_runtime::pack_host::load_pack(&file).map_err(|e| {
            error(
                ErrorCode::InvalidValue,
                format!("pack '{name}' {version} does not load here: {e}"),
            )
        })?;
        if pack.name != name || pack.version != version {
            return Err(error(
                ErrorCode::InvalidValue,
                format!(
                    "the library sent as pack '{name}' {version} is pack '{}' {}",
                    pack.name, pack.version
                ),
            ));
        }
        pack.register(&mut registry);
        tracing::info!("installed pack {name} {version}, shipped to {}", file.display());
        Ok(file)
    }

    /// Installs a Python pack shipped as a tar archive of its folder: unpacked into
    /// `folder/NAME-VERSION` (aside first, so a half-written pack is never loaded), then loaded as a pack
    /// found on the pack path would be.
    pub fn install_python_pack(
        &self,
        name: &str,
        version: &str,
        archive: &[u8],
        folder: &Path,
    ) -> Result<PathBuf, ProtocolError> {
        let mut registry = self.registry.write().unwrap_or_else(PoisonError::into_inner);
        if let Some(loaded) = already_loaded(&registry, name, version) {
            return loaded;
        }
        let target = folder.join(format!("{name}-{version}"));
        let unpacked = unpack_python_pack(archive, &target).map_err(|e| {
            error(
                ErrorCode::Internal,
                format!("cannot write pack '{name}' to {}: {e}", target.display()),
            )
        })?;
        let mut refused = Vec::new();
        let loaded = kairos_runtime::python_host::load_python_pack(&mut registry, &unpacked, &mut refused);
        let reasons: Vec<String> = refused
            .iter()
            .map(|r| format!("{}: {}", r.path.display(), r.reason))
            .collect();
        let Some(loaded) = loaded else {
            return Err(error(
                ErrorCode::InvalidValue,
                format!(
                    "Python pack '{name}' {version} does not load here: {}",
                    reasons.join("; ")
                ),
            ));
        };
        for reason in &reasons {
            tracing::warn!("shipped pack {name}: {reason}");
        }
        let found = registry
            .packs()
            .find(|p| p.name == loaded)
            .map(|p| p.version.clone());
        if loaded != name || found.as_deref() != Some(version) {
            return Err(error(
                ErrorCode::InvalidValue,
                format!(
                    "the folder sent as pack '{name}' {version} is pack '{loaded}' {}",
                    found.unwrap_or_default()
                ),
            ));
        }
        tracing::info!(
            "installed Python pack {name} {version}, shipped to {}",
            unpacked.display()
        );
        Ok(unpacked)
    }

    /// The component library as plain data.
    pub fn library(&self) -> kairos_diagram::LibraryInfo {
        self.registry().library_info()
    }

    /// Describes the instances of `text` whose ports depend on their properties.
    pub fn describe_instances(&self, text: &str) -> Result<kairos_protocol::Described, ProtocolError> {
        let parsed = kairos_diagram::parse(text).map_err(|diagnostics| invalid(text, diagnostics))?;
        let mut described = kairos_protocol::Described::default();
        for (id, result) in self.registry().instance_infos(&parsed.diagram) {
            match result {
                Ok(info) => {
                    described.instances.insert(id, info);
                }
                Err(problem) => {
                    described.problems.insert(id, problem);
                }
            }
        }
        Ok(described)
    }

    /// The deployed diagram's canonical text.
    pub fn diagram_text(&self) -> Option<String> {
        let deployment = self.lock();
        match &deployment.spread {
            Some((whole, _)) => Some(whole.to_ron()),
            None => deployment.diagram.as_ref().map(Diagram::to_ron),
        }
    }

    /// Validates `text` and makes it the deployed diagram, stopping and replacing the running one. A
    /// diagram placing components on hosts is coordinated from here: each host gets its part (its token
    /// files and certificates found in `folder`), this runtime runs the rest; a part a host refuses, or
    /// this runtime's own, changes no host.
    pub fn deploy(
        &self,
        text: &str,
        network: Option<&kairos_protocol::LinkNetwork>,
        folder: Option<&Path>,
    ) -> Result<DeployResult, ProtocolError> {
        let (diagram, diagnostics) = self.validated(text, folder)?;
        if !is_spread(&diagram) {
            let part = self.build_part(diagram, diagnostics, network.cloned())?;
            return self.install(part, None);
        }
        // The previous deployment's hosts are released before this one reaches them.
        if let Some((_, old)) = self.lock().spread.take() {
            old.end();
        }
        let folder = folder.map_or_else(|| std::env::current_dir().unwrap_or_default(), Path::to_owned);
        let clear_text_tokens = self.clear_text_tokens.load(Ordering::Acquire);
        let (spread, part) = Spread::deploy(&diagram, &self.registry(), &folder, clear_text_tokens, |here| {
            self.build_part(here.clone(), diagnostics.clone(), None)
                .map_err(|e| anyhow::anyhow!("this runtime's part: {}", e.message))
        })
        .map_err(|e| error(ErrorCode::InvalidDiagram, format!("{e:#}")))?;
        let components = diagram.components.len();
        let mut result = self.install(part, Some((diagram, spread)))?;
        result.components = components;
        Ok(result)
    }

    /// The first phase of a deployment over hosts (`prepare_deploy`): `text` validated and built, kept
    /// until [`Runtime::commit`] or [`Runtime::abandon`]; the deployed diagram runs on meanwhile.
    pub fn prepare(
        &self,
        text: &str,
        network: Option<&kairos_protocol::LinkNetwork>,
    ) -> Result<kairos_protocol::Prepared, ProtocolError> {
        let (diagram, diagnostics) = self.validated(text, None)?;
        if is_spread(&diagram) {
            return Err(error(
                ErrorCode::InvalidDiagram,
                "prepare_deploy takes one host's part; a diagram placing components on hosts is deployed \
                 with `deploy`, which coordinates it",
            ));
        }
        let part = self.build_part(diagram, diagnostics, network.cloned())?;
        let mut deployment = self.lock();
        deployment.next_ticket += 1;
        let ticket = deployment.next_ticket;
        let prepared = kairos_protocol::Prepared {
            ticket,
            diagnostics: part.diagnostics.clone(),
            components: part.diagram.components.len(),
        };
        if let Some((replaced, _)) = deployment.prepared.replace((ticket, part)) {
            tracing::info!("prepared deployment {replaced} was replaced by {ticket} before its commit");
        }
        Ok(prepared)
    }

    /// Makes the part prepared under `ticket` the deployed diagram (`commit_deploy`).
    pub fn commit(&self, ticket: u64) -> Result<DeployResult, ProtocolError> {
        let part = {
            let mut deployment = self.lock();
            match deployment.prepared.take() {
                Some((prepared, part)) if prepared == ticket => part,
                other => {
                    deployment.prepared = other;
                    return Err(error(
                        ErrorCode::WrongState,
                        format!(
                            "no prepared deployment {ticket}: it was committed, abandoned or replaced by a \
                             newer prepare_deploy; prepare it again"
                        ),
                    ));
                }
            }
        };
        self.install(part, None)
    }

    /// Drops the part prepared under `ticket` (`abandon_deploy`); the deployed diagram is untouched.
    pub fn abandon(&self, ticket: u64) {
        let mut deployment = self.lock();
        if deployment
            .prepared
            .as_ref()
            .is_some_and(|(prepared, _)| *prepared == ticket)
        {
            deployment.prepared = None;
            tracing::info!("prepared deployment {ticket} abandoned: the deployed diagram is unchanged");
        }
    }

    /// `text` parsed and validated against the library: the diagram and its warnings.
    /// `text` parsed, its subgraphs flattened (read from `folder`, the diagram's folder on this
    /// machine, when the client gave it) and checked against the registry.
    fn validated(
        &self,
        text: &str,
        folder: Option<&Path>,
    ) -> Result<(Diagram, Vec<Diagnostic>), ProtocolError> {
        let parsed = kairos_diagram::parse(text).map_err(|diagnostics| invalid(text, diagnostics))?;
        let file = folder.map_or_else(|| Path::new("diagram.ron").to_owned(), |f| f.join("diagram.ron"));
        let mut read = |path: &Path| -> Result<String, kairos_diagram::subgraph::SubgraphReadError> {
            if folder.is_none() {
                return Err(kairos_diagram::subgraph::SubgraphReadError::WithoutFolder(
                    path.to_owned(),
                ));
            }
            Ok(std::fs::read_to_string(path)?)
        };
        let registry = self.registry();
        let mut sources = kairos_diagram::Sources {
            read: &mut read,
            shipped: registry.subgraphs(),
        };
        let flattened = kairos_diagram::flatten_from(parsed, &file, &mut sources)
            .map_err(|diagnostics| invalid(text, diagnostics))?;
        let parsed = flattened.parsed;
        let mut diagnostics = registry.validate(&parsed.diagram, Some(&parsed.source_map));
        flattened.origins.annotate(&mut diagnostics);
        if diagnostics.iter().any(Diagnostic::is_error) {
            return Err(invalid(text, diagnostics));
        }
        Ok((parsed.diagram, diagnostics))
    }

    /// Builds `diagram`'s engine, touching nothing deployed.
    fn build_part(
        &self,
        diagram: Diagram,
        diagnostics: Vec<Diagnostic>,
        network: Option<kairos_protocol::LinkNetwork>,
    ) -> Result<Part, ProtocolError> {
        let engine = {
            let registry = self.registry();
            Engine::build(&diagram, &registry, self.clock_for(&diagram, &registry))
        }
        .map_err(|e| error(ErrorCode::InvalidDiagram, e.to_string()))?;
        Ok(Part {
            diagram,
            engine,
            diagnostics,
            network,
        })
    }

    /// Makes `part` the deployed diagram, stopping and replacing the running one; `spread`: the whole
    /// diagram it is this runtime's part of, and its hosts.
    fn install(
        &self,
        part: Part,
        spread: Option<(Diagram, Arc<Spread>)>,
    ) -> Result<DeployResult, ProtocolError> {
        let mut deployment = self.lock();
        if let Some(mut old) = deployment.engine.take() {
            old.stop();
        }
        if spread.is_none()
            && let Some((_, old)) = deployment.spread.take()
        {
            old.end();
        }
        let coordinated = spread.is_some();
        deployment.spread = spread;
        // The part's links to other hosts are declared now, so they match before anything starts.
        if let Some(network) = &part.network {
            kairos_pack_link::network::join(network)
                .map_err(|e| error(ErrorCode::InvalidDiagram, format!("{e:#}")))?;
        }
        // A coordinated diagram's links here were declared, and matched, as it was deployed.
        if !coordinated {
            kairos_pack_link::network::prepare(&part.diagram)
                .map_err(|e| error(ErrorCode::InvalidDiagram, format!("{e:#}")))?;
        }
        let components = part.diagram.components.len();
        deployment.diagram = Some(part.diagram);
        deployment.engine = Some(part.engine);
        deployment.previous = None;
        deployment.installed += 1;
        deployment.start_late_ns = None;
        let identity = self.identity(deployment.installed);
        self.generation.fetch_add(1, Ordering::Release);
        match components {
            // A spread diagram's coordinator with every component on other hosts.
            0 => tracing::info!("deployed: none of the diagram's components runs on this machine"),
            1 => tracing::info!("deployed a diagram of 1 component"),
            _ => tracing::info!("deployed a diagram of {components} components"),
        }
        Ok(DeployResult {
            diagnostics: part.diagnostics,
            components,
            deployment: Some(identity),
        })
    }

    /// Starts the deployed diagram (building it afresh if it ran before).
    ///
    /// `forced`: the hosts whose clocks were not locked when the start was forced, written into every
    /// recording it begins. `start_unlocked`: for a diagram this runtime coordinates over hosts, start
    /// although some hosts' clocks are not locked (their names then go into the recordings instead).
    /// `lock_bound`: how close to their master hosts' clocks must be (absent: [`crate::spread::LOCK_BOUND`]).
    pub fn start(
        &self,
        forced: Option<&str>,
        start_unlocked: bool,
        lock_bound: Option<std::time::Duration>,
    ) -> Result<(), ProtocolError> {
        let mut deployment = self.lock();
        *self.start_note.lock().unwrap_or_else(PoisonError::into_inner) = forced.map(str::to_owned);
        let Some((_, spread)) = deployment.spread.clone() else {
            return self.start_here(&mut deployment);
        };
        if deployment.engine.as_ref().map(Engine::state) == Some(EngineState::Paused) {
            return resume(&mut deployment, Some(&spread));
        }
        let started = spread.start(start_unlocked, lock_bound, |unlocked| {
            if let Some(unlocked) = unlocked {
                *self.start_note.lock().unwrap_or_else(PoisonError::into_inner) = Some(unlocked.to_owned());
            }
            self.start_here(&mut deployment)
                .map_err(|e| anyhow::anyhow!("this runtime's part: {}", e.message))
        });
        if let Err(refused) = started {
            // Everything or nothing: this part stops with the hosts.
            if let Some(engine) = deployment.engine.as_mut() {
                engine.stop();
            }
            return Err(error(ErrorCode::WrongState, format!("{refused:#}")));
        }
        Ok(())
    }

    /// Starts the part that runs here.
    fn start_here(&self, deployment: &mut Deployment) -> Result<(), ProtocolError> {
        let Some(diagram) = deployment.diagram.clone() else {
            return Err(error(
                ErrorCode::WrongState,
                "nothing to start: deploy a diagram first",
            ));
        };
        let stale = deployment
            .engine
            .as_ref()
            .is_none_or(|e| e.state() == EngineState::Stopped);
        if stale {
            let engine = {
                let registry = self.registry();
                Engine::build(&diagram, &registry, self.clock_for(&diagram, &registry))
            }
            .map_err(|e| error(ErrorCode::InvalidDiagram, e.to_string()))?;
            deployment.engine = Some(engine);
            deployment.previous = None;
            self.generation.fetch_add(1, Ordering::Release);
        }
        let Some(engine) = deployment.engine.as_mut() else {
            return Err(error(ErrorCode::Internal, "no engine after building one"));
        };
        match engine.state() {
            EngineState::Ready => engine.start().map_err(|e| {
                error(
                    ErrorCode::Internal,
                    format!("cannot start a component thread: {e}"),
                )
            }),
            EngineState::Paused => {
                engine.resume();
                Ok(())
            }
            EngineState::Running | EngineState::Stopped => Ok(()),
        }
    }

    /// Pauses a running diagram (every host's part with it).
    pub fn pause(&self) -> Result<(), ProtocolError> {
        let mut deployment = self.lock();
        let spread = deployment.spread.as_ref().map(|(_, s)| Arc::clone(s));
        match deployment.engine.as_mut() {
            Some(engine) if engine.state() == EngineState::Running => {
                engine.pause();
                forward_to_hosts(spread.as_deref(), &RequestBody::Pause)
            }
            _ => Err(error(ErrorCode::WrongState, "nothing is running")),
        }
    }

    /// Resumes a paused diagram (every host's part with it).
    pub fn resume(&self) -> Result<(), ProtocolError> {
        let mut deployment = self.lock();
        let spread = deployment.spread.as_ref().map(|(_, s)| Arc::clone(s));
        resume(&mut deployment, spread.as_deref())
    }

    /// Stops the diagram, on every host at one instant when it is spread; it stays deployed and can start
    /// again.
    pub fn stop(&self) -> Result<(), ProtocolError> {
        let mut deployment = self.lock();
        let spread = deployment.spread.as_ref().map(|(_, s)| Arc::clone(s));
        let stop_here = |deployment: &mut Deployment| {
            if let Some(engine) = deployment.engine.as_mut() {
                engine.stop();
            }
        };
        match spread {
            Some(spread) => spread.stop(|| stop_here(&mut deployment)),
            None => stop_here(&mut deployment),
        }
        Ok(())
    }

    /// Changes a property. While the diagram runs the component applies it (or refuses it, keeping the old
    /// value); otherwise the deployed diagram changes, validated, for the next start. Either way the
    /// deployed diagram remembers the new value.
    ///
    /// `long_wait` is how to block when the deployment is busy or the component does not answer at once.
    pub fn set_property(
        &self,
        component: &str,
        property: &str,
        value: &Value,
        long_wait: LongWait<'_>,
    ) -> Result<(), ProtocolError> {
        if let Some((spread, host)) = self.placed_elsewhere(component, long_wait) {
            let mut outcome = Ok(());
            long_wait(&mut || outcome = spread.set_property(&host, component, property, value));
            outcome.map_err(|e| error(ErrorCode::InvalidValue, format!("{e:#}")))?;
            remember_in_whole(&mut self.lock(), component, property, value);
            return Ok(());
        }
        let mut deployment = self.lock_waiting(long_wait);
        let Some(diagram) = deployment.diagram.as_ref() else {
            return Err(error(ErrorCode::WrongState, "no diagram deployed"));
        };
        let mut changed = diagram.clone();
        let Some(instance) = changed.component_mut(component) else {
            return Err(error(
                ErrorCode::NotFound,
                format!("no component '{component}' in the diagram"),
            ));
        };
        instance.properties.insert(property.to_owned(), value.clone());
        let live = deployment.engine.as_ref().is_some_and(|e| {
            matches!(
                e.state(),
                EngineState::Running | EngineState::Paused | EngineState::Ready
            )
        });
        if live {
            if let Some(engine) = deployment.engine.as_ref() {
                engine
                    .set_property_waiting(component, property, value, long_wait)
                    .map_err(|e| control_error(&e))?;
            }
        } else {
            // Validation may open files (a player's recordings): a long wait.
            let mut problems: Vec<Diagnostic> = Vec::new();
            long_wait(&mut || {
                problems = self
                    .registry()
                    .validate(&changed, None)
                    .into_iter()
                    .filter(Diagnostic::is_error)
                    .collect();
            });
            if let Some(first) = problems.first() {
                let mut refused = error(
                    ErrorCode::InvalidValue,
                    format!("{}; it keeps its value", first.message),
                );
                refused.diagnostics = problems;
                return Err(refused);
            }
            // Rebuilt with the new value at the next start.
            deployment.engine = None;
        }
        deployment.diagram = Some(changed);
        remember_in_whole(&mut deployment, component, property, value);
        Ok(())
    }

    /// The spread and the host `component` runs on, when it runs on another host than this one.
    fn placed_elsewhere(&self, component: &str, long_wait: LongWait<'_>) -> Option<(Arc<Spread>, String)> {
        let spread = Arc::clone(&self.lock_waiting(long_wait).spread.as_ref()?.1);
        let host = spread.host_of(component)?;
        Some((spread, host))
    }

    /// Triggers an action on a running (or ready) component.
    pub fn trigger_action(
        &self,
        component: &str,
        action: &str,
        long_wait: LongWait<'_>,
    ) -> Result<(), ProtocolError> {
        if let Some((spread, host)) = self.placed_elsewhere(component, long_wait) {
            let mut outcome = Ok(());
            long_wait(&mut || outcome = spread.trigger_action(&host, component, action));
            return outcome.map_err(|e| error(ErrorCode::WrongState, format!("{e:#}")));
        }
        let deployment = self.lock_waiting(long_wait);
        let Some(engine) = deployment.engine.as_ref() else {
            return Err(error(ErrorCode::WrongState, "no diagram is running"));
        };
        engine
            .trigger_action_waiting(component, action, long_wait)
            .map_err(|e| control_error(&e))
    }

    /// The runtime's state.
    pub fn state(&self) -> RuntimeState {
        let mut deployment = self.lock();
        stop_once_all_finished(&mut deployment);
        state_of(&deployment)
    }

    /// Statistics now, with rates since the previous call.
    pub fn telemetry(&self) -> Option<Telemetry> {
        let mut deployment = self.lock();
        stop_once_all_finished(&mut deployment);
        let state = state_of(&deployment);
        let snapshot = deployment.engine.as_ref()?.snapshot();
        let with_rates = match &deployment.previous {
            Some(previous) => snapshot.clone().with_rates_since(previous),
            None => snapshot.clone(),
        };
        deployment.previous = Some(snapshot);
        let spread = deployment.spread.as_ref().map(|(_, s)| Arc::clone(s));
        drop(deployment);
        let mut telemetry = telemetry(&with_rates, state);
        if let Some(spread) = spread {
            spread.merge_into(&mut telemetry);
        }
        Some(telemetry)
    }

    /// The buffer of output `component.output` of the current engine, and the engine's generation.
    pub fn output(&self, component: &str, output: &str) -> Option<(OutputBuffer, u64)> {
        let deployment = self.lock();
        let buffer = deployment
            .engine
            .as_ref()?
            .output_buffer(component, output)?
            .clone();
        Some((buffer, self.generation.load(Ordering::Acquire)))
    }

    /// Every output of the current engine (`component.port`); none when nothing is deployed.
    pub fn output_names(&self) -> Vec<String> {
        self.lock()
            .engine
            .as_ref()
            .map_or_else(Vec::new, Engine::output_names)
    }

    /// Which engine is current: changes when one is replaced.
    pub fn generation(&self) -> u64 {
        self.generation.load(Ordering::Acquire)
    }

    /// Stops everything (the server is shutting down).
    pub fn shutdown(&self) {
        let mut deployment = self.lock();
        if let Some((_, spread)) = deployment.spread.take() {
            spread.end();
        }
        if let Some(mut engine) = deployment.engine.take() {
            engine.stop();
        }
    }
}

/// Resumes the paused part here, and every host's of `spread`.
fn resume(deployment: &mut Deployment, spread: Option<&Spread>) -> Result<(), ProtocolError> {
    match deployment.engine.as_mut() {
        Some(engine) if engine.state() == EngineState::Paused => {
            engine.resume();
            forward_to_hosts(spread, &RequestBody::Resume)
        }
        _ => Err(error(ErrorCode::WrongState, "nothing is paused")),
    }
}

/// Keeps a property's new value in the spread diagram, if any, so `get_diagram` returns it.
fn remember_in_whole(deployment: &mut Deployment, component: &str, property: &str, value: &Value) {
    if let Some(instance) = deployment
        .spread
        .as_mut()
        .and_then(|(whole, _)| whole.component_mut(component))
    {
        instance.properties.insert(property.to_owned(), value.clone());
    }
}

/// Sends `body` to every host of `spread`: the first refusal, with its host.
fn forward_to_hosts(spread: Option<&Spread>, body: &RequestBody) -> Result<(), ProtocolError> {
    spread.map_or(Ok(()), |spread| {
        spread
            .call_all(body)
            .map_err(|e| error(ErrorCode::WrongState, format!("{e:#}")))
    })
}

fn invalid(text: &str, diagnostics: Vec<Diagnostic>) -> ProtocolError {
    let errors = diagnostics.iter().filter(|d| d.is_error()).count();
    let mut refused = error(
        ErrorCode::InvalidDiagram,
        format!(
            "the diagram has {errors} error(s), nothing was deployed:\n{}",
            kairos_diagram::render_all(&diagnostics, "diagram", text)
        ),
    );
    refused.diagnostics = diagnostics;
    refused
}

/// Unpacks a shipped Python pack into `target`, replacing an earlier copy; the folder it is in.
fn unpack_python_pack(archive: &[u8], target: &Path) -> std::io::Result<PathBuf> {
    let parent = target.parent().unwrap_or(Path::new("."));
    std::fs::create_dir_all(parent)?;
    let partial = target.with_extension(format!("partial-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&partial);
    std::fs::create_dir_all(&partial)?;
    // `unpack` writes nothing outside `partial`, whatever the paths in the archive say.
    tar::Archive::new(archive).unpack(&partial)?;
    let _ = std::fs::remove_dir_all(target);
    std::fs::rename(&partial, target)?;
    Ok(target.to_owned())
}

/// For a pack about to be installed: where it was loaded from when this version is loaded already, or why
/// it cannot be when another version is; `None` when no pack of that name is loaded.
fn already_loaded(registry: &Registry, name: &str, version: &str) -> Option<Result<PathBuf, ProtocolError>> {
    let loaded = registry.packs().find(|p| p.name == name)?;
    Some(if loaded.version == version {
        Ok(PathBuf::from(&loaded.origin))
    } else {
        Err(error(
            ErrorCode::WrongState,
            format!(
                "pack '{name}' {} is already loaded here (from {}); a second version cannot be loaded beside \
                 it: replace it with {version} on this machine's pack path and restart kairos serve",
                loaded.version, loaded.origin
            ),
        ))
    })
}
