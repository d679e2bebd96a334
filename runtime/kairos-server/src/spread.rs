//! A diagram spread over hosts and coordinated by this runtime: what `kairos deploy` does from a terminal,
//! done for a client of the control protocol (the studio's Run). This runtime runs the part without a host,
//! deploys every other part to its host, starts and stops them all at one instant, forwards property
//! changes and actions to the host of the component, and folds every host's telemetry into its own.

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError, Weak};
use std::time::Duration;

use kairos_diagram::{Diagram, Value};
use kairos_protocol::{HostTelemetry, RequestBody, RuntimeState, Telemetry};
use kairos_sdk_core::Registry;

use kairos_coordinator::{self as deploy, Watch};

/// The shortest sleep between two looks at the hosts (the watch says when the next look is due).
const REFRESH_LEAST: Duration = Duration::from_millis(5);

/// The clock bound a start checks, as `kairos deploy`'s default `--lock-bound`.
pub const LOCK_BOUND: Duration = Duration::from_millis(1);

/// A spread diagram's hosts, watched from here.
#[derive(Debug)]
pub struct Spread {
    watch: Mutex<Watch>,
    /// Set when the deployment is replaced or the server shuts down: the refresher ends.
    ended: AtomicBool,
}

/// Whether `diagram` places any component on a host, so that deploying it here means coordinating it.
pub fn is_spread(diagram: &Diagram) -> bool {
    diagram.components.iter().any(|c| c.host.is_some())
}

impl Spread {
    /// Splits `whole`, prepares each host's part (shipping the packs it lacks) and this runtime's with
    /// `prepare_here`, commits them all, joins this runtime's links and waits for every link to match: the
    /// spread, and what `prepare_here` made of the part that runs here. Nothing starts. Tokens go over
    /// plain ws:// to hosts off this machine only with `clear_text_tokens`.
    ///
    /// # Errors
    ///
    /// An unreachable host, a refused part or pack (then no host was changed), a link that does not
    /// match: named with the reason.
    pub fn deploy<T>(
        whole: &Diagram,
        registry: &Registry,
        folder: &Path,
        clear_text_tokens: bool,
        prepare_here: impl FnOnce(&Diagram) -> anyhow::Result<T>,
    ) -> anyhow::Result<(Arc<Spread>, T)> {
        let (here, mut watch) =
            deploy::deploy_everywhere(whole, registry, folder, clear_text_tokens, prepare_here)?;
        // A host that returns while the diagram is stopped gets its part back, not started.
        watch.set_running(false);
        let spread = Arc::new(Spread {
            watch: Mutex::new(watch),
            ended: AtomicBool::new(false),
        });
        let weak = Arc::downgrade(&spread);
        std::thread::Builder::new()
            .name("kairos-spread".to_owned())
            .spawn(move || refresh(&weak))?;
        Ok((spread, here))
    }

    fn watch(&self) -> MutexGuard<'_, Watch> {
        self.watch.lock().unwrap_or_else(PoisonError::into_inner)
    }

    /// The host `component` runs on, when not here.
    pub fn host_of(&self, component: &str) -> Option<String> {
        let watch = self.watch();
        watch
            .plan()
            .parts
            .iter()
            .find(|(_, part)| part.component(component).is_some())
            .and_then(|(host, _)| host.clone())
    }

    /// Starts every host's part and, with `start_here`, this runtime's, at one instant
    /// [`deploy::START_LEAD`] ahead, each host on its own clock; refused while a host's clock is not locked
    /// to its master, unless `start_unlocked`.
    ///
    /// # Errors
    ///
    /// A clock not locked, a host refusing or lost, or `start_here` failing: every host is stopped again
    /// (the caller stops its own part).
    /// `start_unlocked` starts although hosts' clocks are not locked; `start_here` is then told which, in
    /// words, for the recordings.
    pub fn start(
        &self,
        start_unlocked: bool,
        lock_bound: Option<Duration>,
        start_here: impl FnOnce(Option<&str>) -> anyhow::Result<()>,
    ) -> anyhow::Result<()> {
        let mut watch = self.watch();
        if let Some(lost) = watch.lost().next() {
            anyhow::bail!(
                "host '{lost}' is lost, so nothing was started: start it again, or wait for it to answer"
            );
        }
        let bound = lock_bound.unwrap_or(LOCK_BOUND);
        deploy::start_together(&mut watch.hosts, bound, start_unlocked, start_here)?;
        watch.set_running(true);
        Ok(())
    }

    /// Stops every host's part and, with `stop_here`, this runtime's, at one instant.
    pub fn stop(&self, stop_here: impl FnOnce()) {
        let mut watch = self.watch();
        watch.set_running(false);
        watch.stop_together(stop_here);
    }

    /// Sends `body` to every answering host.
    ///
    /// # Errors
    ///
    /// The first refusal, with its host; the others are still asked.
    pub fn call_all(&self, body: &RequestBody) -> anyhow::Result<()> {
        let mut watch = self.watch();
        let mut first = None;
        for host in &mut watch.hosts {
            if let Err(e) = host.call(body.clone()) {
                first.get_or_insert(e);
            }
        }
        first.map_or(Ok(()), Err)
    }

    /// Forwards a property change to `host`, keeping the value for a redeploy there.
    ///
    /// # Errors
    ///
    /// The host is lost, or refuses the value (its reason).
    pub fn set_property(
        &self,
        host: &str,
        component: &str,
        property: &str,
        value: &Value,
    ) -> anyhow::Result<()> {
        self.watch().set_property(host, component, property, value)
    }

    /// Forwards an action to `host`.
    ///
    /// # Errors
    ///
    /// The host is lost, or refuses the action (its reason).
    pub fn trigger_action(&self, host: &str, component: &str, action: &str) -> anyhow::Result<()> {
        self.watch()
            .call_on(
                host,
                RequestBody::TriggerAction {
                    component: component.to_owned(),
                    action: action.to_owned(),
                },
            )
            .map(drop)
    }

    /// Folds the hosts' telemetry, as of their last status, into this runtime's: their components and
    /// links (a link end's components left out: they are counted as `cross_links`), each host's state and
    /// clock, and each connection between hosts.
    pub fn merge_into(&self, telemetry: &mut Telemetry) {
        let watch = self.watch();
        let mut remote: Vec<(String, Telemetry)> = Vec::new();
        for (name, status) in watch.statuses() {
            let state: Option<RuntimeState> = serde_json::from_value(status["state"].clone()).ok();
            telemetry.hosts.push(HostTelemetry {
                name: name.clone(),
                answering: true,
                state,
                clock: serde_json::from_value(status["clock"].clone()).ok(),
            });
            if let Ok(theirs) = serde_json::from_value::<Telemetry>(status["telemetry"].clone()) {
                remote.push((name.clone(), theirs));
            }
        }
        telemetry.hosts.extend(watch.lost().map(|name| HostTelemetry {
            name: name.to_owned(),
            answering: false,
            state: None,
            clock: None,
        }));
        let plan = watch.plan();
        let status_of = |host: Option<&str>, id: &str| -> serde_json::Value {
            let components = match host {
                None => Some(&telemetry.components),
                Some(name) => remote.iter().find(|(h, _)| h == name).map(|(_, t)| &t.components),
            };
            let status = components
                .and_then(|list| list.iter().find(|c| c.id == id))
                .and_then(|c| c.status.clone())
                .unwrap_or_default();
            match host {
                Some(name) => watch.counted_over_restarts(name, id, status),
                None => status,
            }
        };
        let active = |state: &serde_json::Value| state == "running" || state == "paused";
        let stopped = !matches!(telemetry.state, RuntimeState::Running | RuntimeState::Paused)
            && !watch.statuses().values().any(|status| active(&status["state"]));
        let cross_links = deploy::links::cross_links(plan, status_of, stopped);
        // The consumer reads a receiver's output, named by every host as the output it comes from (as in
        // the diagram). A sender's input buffer is the producer's side of the same connection, counted in
        // `cross_links`.
        let sender_inputs: Vec<String> = plan
            .links
            .iter()
            .map(|link| format!(" -> {}.in", link.sender.1))
            .collect();
        for (_, theirs) in remote {
            telemetry.components.extend(theirs.components);
            telemetry.links.extend(theirs.links);
        }
        telemetry
            .components
            .retain(|c| !kairos_pack_link::is_link(&c.type_name));
        telemetry
            .links
            .retain(|l| !sender_inputs.iter().any(|input| l.link.ends_with(input.as_str())));
        telemetry.cross_links = cross_links;
    }

    /// Stops every host's part and the refresher: the deployment is replaced, or the server shuts down.
    pub fn end(&self) {
        self.ended.store(true, Ordering::Release);
        let mut watch = self.watch();
        watch.set_running(false);
        deploy::stop_all(&mut watch.hosts);
    }
}

/// Asks the hosts for their status whenever the watch's next look is due, until the spread ends; a host
/// that stops answering is reported, and its part deployed again when it answers.
fn refresh(spread: &Weak<Spread>) {
    loop {
        let Some(wait) = spread.upgrade().map(|spread| spread.watch().next_look_in()) else {
            return;
        };
        std::thread::sleep(wait.max(REFRESH_LEAST));
        let Some(spread) = spread.upgrade() else { return };
        if spread.ended.load(Ordering::Acquire) {
            return;
        }
        spread.watch().check();
    }
}
