//! Watching a running deployment: hosts lost and back, their links, their statuses.

use std::collections::{BTreeMap, BTreeSet};
use std::time::Duration;

use anyhow::{Context as _, bail};
use kairos_diagram::{Diagram, Value};
use kairos_protocol::{ClockState, LinkNetwork, ReferenceWatch, References, RequestBody};

use crate::clocks::clock_of;
use crate::host::{Host, Reach};
use crate::plan::Plan;
use crate::ship::ship_packs;
use crate::start::STOP_LEAD;

/// How often the deploying machine asks each host whether it is still there: a killed host or a cut link
/// is reported within a second (Zenoh's 0.7 s lease, then at most this until the next look, with room
/// for the answers on a loaded machine).
const HEALTH_PERIOD: Duration = Duration::from_millis(200);
/// How often a lost host is tried again, and how long reaching it may take then.
const RETRY_PERIOD: Duration = Duration::from_secs(1);

/// A running deployment, watched from the deploying machine: a host that stops answering is reported
/// with the links it cuts while the others keep running. When it answers again still running the part
/// this deployment gave it (a network blip), it is watched again and its links resume, its part
/// untouched; when it restarted meanwhile, its part is deployed (and started) again. A host that runs
/// another deployment's diagram now leaves this one, untouched.
#[derive(Debug)]
pub struct Watch {
    diagram: Diagram,
    plan: Plan,
    networks: BTreeMap<Option<String>, LinkNetwork>,
    reach: Reach,
    /// The hosts answering.
    pub hosts: Vec<Host>,
    /// The hosts lost, with when to try each again.
    lost: BTreeMap<String, std::time::Instant>,
    last_check: std::time::Instant,
    /// Each answering host's last status (the result of `status`).
    statuses: BTreeMap<String, serde_json::Value>,
    /// Whether the parts run: a host that returns is started again only then.
    running: bool,
    /// The identity of the part each host was given (its `status` says the one it runs).
    deployments: BTreeMap<String, String>,
    /// The hosts that left: another deployment's diagram runs there now.
    left: BTreeSet<String>,
    /// The links whose sender on a host has no receiver matched: cut, though both hosts may answer.
    cut_links: BTreeSet<String>,
    /// The links that matched but delivered nothing while samples were on their way, since when, and
    /// whether it was said.
    starving_links: BTreeMap<String, (std::time::Instant, bool)>,
    /// Each host's clock state at the last check, for those that follow one.
    clock_states: BTreeMap<String, ClockState>,
    /// How each host's clock's references usually come, to say when they stop.
    references: BTreeMap<String, ReferenceWatch>,
    /// Each lost host's last status, until it answers again.
    last_seen: BTreeMap<String, serde_json::Value>,
    /// What the link ends on hosts that restarted had counted before (by host and component): a
    /// link's counts run over every life of its ends.
    earlier: BTreeMap<(String, String), BTreeMap<&'static str, u64>>,
}

/// How long that must hold before it is said: over two looks. A receiver publishes its status the moment
/// its quiet becomes unusual and the moment a sample ends it, so a quiet that ends as the sender's new
/// sample arrives is gone by the next look.
const STARVING_HELD: Duration = HEALTH_PERIOD;

/// Says a link that matches but delivers nothing: its sender sent samples its receiver never got
/// while its receiver received nothing for longer than is usual on it (its consumer stalled, or a path Zenoh
/// still sees as up that carries nothing, seen for minutes after a reconnection that flapped once
/// more). Only the two ends' statuses together tell it: each end alone sees nothing wrong.
fn report_starving(
    starving_links: &mut BTreeMap<String, (std::time::Instant, bool)>,
    statuses: &BTreeMap<String, serde_json::Value>,
    link: &crate::plan::CrossLink,
    sending_end: &serde_json::Value,
    words: &str,
) {
    let (Some(receiving_host), receiver) = &link.receiver else {
        return;
    };
    let Some(receiving_end) = statuses
        .get(receiving_host)
        .map(|status| component_status(status, receiver))
        .filter(|end| !end.is_null())
    else {
        return;
    };
    let count = |end: &serde_json::Value, field: &str| end[field].as_u64().unwrap_or(0);
    let sent = count(sending_end, "sent");
    let arrived = count(receiving_end, "received") + count(receiving_end, "lost");
    let quiet_ms = receiving_end["last_sample_age_ms"].as_u64();
    let quiet_for = quiet_ms.map(Duration::from_millis);
    let matched = sending_end["matched"] == true;
    let starving = kairos_protocol::link_delivers_nothing(
        matched,
        sent,
        arrived,
        quiet_ms,
        receiving_end["quiet_after_ms"].as_u64(),
    );
    let now = std::time::Instant::now();
    if !starving {
        // A cut ends it too (a dead path is first quiet, then unmatched): the cut is what is said then.
        if let Some((_, true)) = starving_links.remove(&link.key)
            && matched
        {
            tracing::info!("link {words} delivers again");
        }
        return;
    }
    let (since, said) = starving_links.entry(link.key.clone()).or_insert((now, false));
    if !*said && now.duration_since(*since) >= STARVING_HELD {
        *said = true;
        let quiet = quiet_for.map_or_else(
            || "nothing yet".to_owned(),
            |quiet| format!("nothing for {:.1} s", quiet.as_secs_f64()),
        );
        tracing::error!(
            "link {words} delivers nothing: it matches, but its receiver has received {quiet} while \
             {} more were sent; its consumer on host '{receiving_host}' is stalled, or the path between \
             the hosts carries nothing though both ends still see each other; what never arrives is \
             counted lost",
            sent - arrived
        );
    }
}

/// The counts of a link end's status that run over its host's restarts.
const LINK_COUNTS: [&str; 5] = ["sent", "sent_unmatched", "failed", "received", "lost"];

/// What a host that answers runs, against what this deployment gave it.
enum Runs {
    /// The part this deployment gave it.
    Ours,
    /// Nothing: the server started afresh since.
    Nothing,
    /// Another deployment's diagram.
    Another,
}

impl Watch {
    /// Watches `hosts`, all started.
    pub fn new(
        diagram: Diagram,
        plan: Plan,
        networks: BTreeMap<Option<String>, LinkNetwork>,
        reach: Reach,
        hosts: Vec<Host>,
    ) -> Self {
        let deployments = hosts
            .iter()
            .filter_map(|h| Some((h.name().to_owned(), h.deployment()?.to_owned())))
            .collect();
        Watch {
            diagram,
            plan,
            networks,
            reach,
            hosts,
            lost: BTreeMap::new(),
            last_check: std::time::Instant::now(),
            statuses: BTreeMap::new(),
            running: true,
            deployments,
            left: BTreeSet::new(),
            cut_links: BTreeSet::new(),
            starving_links: BTreeMap::new(),
            clock_states: BTreeMap::new(),
            references: BTreeMap::new(),
            last_seen: BTreeMap::new(),
            earlier: BTreeMap::new(),
        }
    }

    /// Host `name` restarted: what its link ends counted in `status`, its last before, is kept to add to
    /// what they count from now on.
    fn count_before_restart(&mut self, name: &str, status: Option<serde_json::Value>) {
        let Some(status) = status else {
            return;
        };
        let ends = self
            .plan
            .links
            .iter()
            .flat_map(|link| [&link.sender, &link.receiver]);
        for (host, id) in ends {
            if host.as_deref() != Some(name) {
                continue;
            }
            let counted = component_status(&status, id);
            let earlier = self.earlier.entry((name.to_owned(), id.clone())).or_default();
            for key in LINK_COUNTS {
                *earlier.entry(key).or_default() += counted[key].as_u64().unwrap_or(0);
            }
        }
    }

    /// `status`, that of component `id` on host `name`, with what it counted before its host restarted
    /// added: a link's counts over every life of its ends.
    pub fn counted_over_restarts(
        &self,
        name: &str,
        id: &str,
        mut status: serde_json::Value,
    ) -> serde_json::Value {
        let Some(earlier) = self.earlier.get(&(name.to_owned(), id.to_owned())) else {
            return status;
        };
        if !status.is_object() {
            status = serde_json::json!({});
        }
        for (key, before) in earlier {
            let now = status[*key].as_u64().unwrap_or(0);
            status[*key] = serde_json::json!(now + before);
        }
        status
    }

    /// What host `name`, whose status is `status`, runs.
    fn runs(&self, name: &str, status: &serde_json::Value) -> Runs {
        match (status["deployment"].as_str(), self.deployments.get(name)) {
            (None, _) => Runs::Nothing,
            (Some(running), Some(ours)) if running == ours => Runs::Ours,
            // A host older than deployment identities: taken to run what it was given.
            (Some(_), None) => Runs::Ours,
            (Some(_), Some(_)) => Runs::Another,
        }
    }

    /// The hosts that left this deployment: another deployment's diagram runs there now.
    pub fn left(&self) -> impl Iterator<Item = &str> {
        self.left.iter().map(String::as_str)
    }

    /// Whether the parts run (they do when a watch is made): a host that returns gets its part deployed
    /// again, and started only while they run.
    pub fn set_running(&mut self, running: bool) {
        self.running = running;
    }

    /// How the diagram was split.
    pub fn plan(&self) -> &Plan {
        &self.plan
    }

    /// Each answering host's status as of the last [`Watch::check`].
    pub fn statuses(&self) -> &BTreeMap<String, serde_json::Value> {
        &self.statuses
    }

    /// The hosts that stopped answering.
    pub fn lost(&self) -> impl Iterator<Item = &str> {
        self.lost.keys().map(String::as_str)
    }

    /// Sends `body` to host `name` and waits for its reply.
    ///
    /// # Errors
    ///
    /// The host is lost, or refuses (the reason named).
    pub fn call_on(&mut self, name: &str, body: RequestBody) -> anyhow::Result<serde_json::Value> {
        let Some(host) = self.hosts.iter_mut().find(|h| h.name() == name) else {
            bail!("host '{name}' is lost: its part is deployed again when it answers");
        };
        host.call(body)
    }

    /// Changes a property of `component` on host `name`, and in the part deployed there again if the
    /// host is lost and returns.
    ///
    /// # Errors
    ///
    /// As [`Watch::call_on`].
    pub fn set_property(
        &mut self,
        name: &str,
        component: &str,
        property: &str,
        value: &Value,
    ) -> anyhow::Result<()> {
        self.call_on(
            name,
            RequestBody::SetProperty {
                component: component.to_owned(),
                property: property.to_owned(),
                value: value.clone(),
            },
        )?;
        if let Some(instance) = self
            .plan
            .parts
            .get_mut(&Some(name.to_owned()))
            .and_then(|part| part.component_mut(component))
        {
            instance.properties.insert(property.to_owned(), value.clone());
        }
        Ok(())
    }

    /// Whether any host is part of the deployment.
    pub fn is_empty(&self) -> bool {
        self.hosts.is_empty() && self.lost.is_empty()
    }

    /// The links that cross to or from `host`, in words.
    fn links_of(&self, host: &str) -> Vec<String> {
        let words = format!("host '{host}'");
        self.plan
            .links
            .iter()
            .filter(|l| l.from.ends_with(&words) || l.to.ends_with(&words))
            .map(|l| format!("{} -> {}", l.from, l.to))
            .collect()
    }

    /// How long until [`Watch::check`] next looks: callers wake then, rather than on a tick of their own
    /// that would add to the time a fault takes to be said.
    pub fn next_look_in(&self) -> Duration {
        HEALTH_PERIOD.saturating_sub(self.last_check.elapsed())
    }

    /// Asks each host whether it is there (at most every [`HEALTH_PERIOD`]) and tries lost ones again.
    pub fn check(&mut self) {
        if self.last_check.elapsed() < HEALTH_PERIOD {
            return;
        }
        self.last_check = std::time::Instant::now();
        let mut answering = Vec::new();
        for mut host in std::mem::take(&mut self.hosts) {
            let name = host.name().to_owned();
            match host.ping() {
                Ok(status) => match self.runs(&name, &status) {
                    Runs::Ours => {
                        self.statuses.insert(name, status);
                        answering.push(host);
                    }
                    Runs::Nothing => {
                        tracing::error!(
                            "host '{name}' restarted: its part is gone{}; it is deployed again",
                            self.cut(&name)
                        );
                        let before = self.statuses.remove(&name);
                        self.count_before_restart(&name, before);
                        self.lost.insert(name, std::time::Instant::now());
                    }
                    Runs::Another => self.leave(&name),
                },
                Err(error) => {
                    if let Some(last) = self.statuses.remove(&name) {
                        self.last_seen.insert(name.clone(), last);
                    }
                    tracing::error!(
                        "host '{name}' is lost ({error:#}){}; the other hosts keep running, and it is \
                         watched again when it answers",
                        self.cut(&name)
                    );
                    self.lost.insert(name, std::time::Instant::now() + RETRY_PERIOD);
                }
            }
        }
        self.hosts = answering;
        self.report_links();
        self.report_clocks();
        let due: Vec<String> = self
            .lost
            .iter()
            .filter(|(_, at)| **at <= std::time::Instant::now())
            .map(|(name, _)| name.clone())
            .collect();
        for name in due {
            match self.rejoin(&name) {
                Ok(Some(host)) => {
                    self.lost.remove(&name);
                    self.hosts.push(host);
                }
                Ok(None) => {
                    self.lost.remove(&name);
                }
                Err(error) => {
                    tracing::debug!("host '{name}' is still lost: {error:#}");
                    self.lost.insert(name, std::time::Instant::now() + RETRY_PERIOD);
                }
            }
        }
    }

    /// Says which links between hosts were cut, or resumed, since the last check, from their senders'
    /// statuses on the hosts that answer: a network cut between hosts' Zenoh ports leaves their control
    /// connections up, and would otherwise be said only in the hosts' own logs. Senders on this machine
    /// say it in this machine's log themselves.
    fn report_links(&mut self) {
        for link in &self.plan.links {
            let (Some(host), sender) = &link.sender else {
                continue;
            };
            let Some(status) = self
                .statuses
                .get(host)
                .map(|status| component_status(status, sender))
            else {
                continue;
            };
            let Some(matched) = status["matched"].as_bool() else {
                continue;
            };
            let words = format!("{} -> {}", link.from, link.to);
            if !matched && self.cut_links.insert(link.key.clone()) {
                tracing::error!(
                    "link {words} is cut: no receiver on the far end; a link whose consumer never skips \
                     keeps what it sends and sends it again when the far end returns (for up to its \
                     ride_out_s), any other drops it (sent_unmatched on {sender})"
                );
            } else if matched && self.cut_links.remove(&link.key) {
                tracing::info!("link {words} resumed");
            }
            report_starving(&mut self.starving_links, &self.statuses, link, status, &words);
        }
    }

    /// Says which hosts' clocks left lock, or came back to it, since the last check: samples stamped on a
    /// clock out of lock drift against the other hosts'.
    fn report_clocks(&mut self) {
        for (name, status) in &self.statuses {
            let Some(clock) = clock_of(status) else {
                continue;
            };
            let error = format!("error {}", kairos_protocol::error_ms(clock.error_ns));
            let bound = clock.error_bound_ns.map_or_else(String::new, |b| {
                format!(", error bound {:.3} ms", b as f64 * 1e-6)
            });
            let locked = clock.state == ClockState::Locked;
            let references = self.references.entry(name.clone()).or_default();
            let now = std::time::Instant::now();
            match references.look(now, clock.state, clock.references, clock.since_reference_s) {
                References::Stopped { for_s } => tracing::warn!(
                    "host '{name}': its clock has had no reference from {} for {for_s:.1} s; it runs on at \
                     its own rate ({error}{bound}) and leaves lock if none comes within 3 s",
                    clock.source
                ),
                References::Back => {
                    tracing::info!(
                        "host '{name}': its clock has references from {} again",
                        clock.source
                    );
                }
                References::AsUsual => {}
            }
            match self.clock_states.insert(name.clone(), clock.state) {
                Some(ClockState::Locked) if !locked => tracing::error!(
                    "host '{name}': its clock left lock ({}, {error}{bound}); what it stamps now drifts \
                     against the other hosts",
                    clock.state
                ),
                Some(previous) if previous != ClockState::Locked && locked => {
                    tracing::info!("host '{name}': its clock is locked again ({error})");
                }
                _ => {}
            }
        }
    }

    /// The links host `name` cuts, as the end of a sentence.
    fn cut(&self, name: &str) -> String {
        let links = self.links_of(name);
        if links.is_empty() {
            String::new()
        } else {
            format!("; links cut: {}", links.join(", "))
        }
    }

    /// Host `name` runs another deployment's diagram: it leaves this one, untouched.
    fn leave(&mut self, name: &str) {
        tracing::error!(
            "host '{name}' runs another diagram now, deployed from elsewhere{}: it leaves this deployment, \
             untouched",
            self.cut(name)
        );
        self.statuses.remove(name);
        self.left.insert(name.to_owned());
    }

    /// Reaches host `name` again: re-attached when it still runs its part, given its part again when it
    /// restarted, left alone (`None`) when it runs another deployment's diagram.
    fn rejoin(&mut self, name: &str) -> anyhow::Result<Option<Host>> {
        let spec = self
            .diagram
            .hosts
            .get(name)
            .with_context(|| format!("no host '{name}'"))?;
        let mut host = Host::reach_within(name, spec, &self.reach, RETRY_PERIOD)?;
        let status = host.call(RequestBody::Status)?;
        let before = self.last_seen.remove(name);
        match self.runs(name, &status) {
            Runs::Ours => {
                let state = status["state"].as_str().unwrap_or("unknown");
                tracing::info!(
                    "host '{name}' is back: its part kept running ({state}), untouched, and its links resume"
                );
                self.statuses.insert(name.to_owned(), status);
                Ok(Some(host))
            }
            Runs::Nothing => {
                self.count_before_restart(name, before);
                self.redeploy(&mut host)?;
                let again = if self.running {
                    "deployed and started again"
                } else {
                    "deployed again"
                };
                tracing::info!("host '{name}' is back after a restart: its part was {again}");
                if let Some(deployment) = host.deployment() {
                    self.deployments.insert(name.to_owned(), deployment.to_owned());
                }
                Ok(Some(host))
            }
            Runs::Another => {
                self.leave(name);
                Ok(None)
            }
        }
    }

    /// Gives `host` its part again, and starts it while the parts run.
    fn redeploy(&self, host: &mut Host) -> anyhow::Result<()> {
        let key = Some(host.name().to_owned());
        ship_packs(host, self.plan.packs.get(&key).map_or(&[], Vec::as_slice))?;
        let part = self.plan.parts.get(&key).map(Diagram::to_ron).unwrap_or_default();
        host.deploy(part, self.networks.get(&key).cloned())?;
        if self.running {
            host.call(RequestBody::Start {
                at_ns: None,
                forced: None,
                start_unlocked: false,
                lock_bound_ns: None,
            })?;
        }
        Ok(())
    }

    /// Stops every host's part and, with `stop_here`, this machine's, all at one instant
    /// [`STOP_LEAD`] ahead, each host on its own clock, as they started.
    pub fn stop_together(&mut self, stop_here: impl FnOnce()) {
        use kairos_sdk_core::Clock as _;
        let wall = kairos_sdk_core::RealTimeClock::new();
        let at = wall.now().after(STOP_LEAD);
        let asked: Vec<anyhow::Result<u64>> = self
            .hosts
            .iter_mut()
            .map(|host| {
                host.send(RequestBody::Stop {
                    at_ns: Some(at.as_nanos()),
                })
            })
            .collect();
        while wall.now() < at {
            std::thread::sleep(Duration::from_micros(200));
        }
        stop_here();
        for (host, id) in self.hosts.iter_mut().zip(asked) {
            match id.and_then(|id| host.wait(id)) {
                Ok(_) => tracing::info!("host '{}' stopped", host.name()),
                Err(error) => tracing::warn!("{error:#}"),
            }
        }
        for name in self.lost.keys() {
            tracing::warn!("host '{name}' was lost and could not be stopped: stop it there");
        }
    }

    /// Once every part has stopped: says what each link between hosts sent, received and lost, with the
    /// counts its ends leave (`here(component)`: the status of a component of this machine's part). Every
    /// sample sent was received or counted lost.
    pub fn report_final_counts(&mut self, here: impl Fn(&str) -> serde_json::Value) {
        if self.plan.links.is_empty() {
            return;
        }
        for host in &mut self.hosts {
            if let Ok(status) = host.call(RequestBody::Status) {
                self.statuses.insert(host.name().to_owned(), status);
            }
        }
        // A host lost at the end counts as it last said.
        let status_of = |host: Option<&str>, id: &str| match host {
            None => here(id),
            Some(name) => {
                let last = self.statuses.get(name).or_else(|| self.last_seen.get(name));
                let status = last
                    .map(|status| component_status(status, id).clone())
                    .unwrap_or_default();
                self.counted_over_restarts(name, id, status)
            }
        };
        let counts = crate::links::cross_links(&self.plan, status_of, true);
        for (link, counted) in self.plan.links.iter().zip(counts) {
            let text = format!(
                "link {} -> {}: sent {}, received {}, lost {}",
                link.from, link.to, counted.sent, counted.received, counted.lost
            );
            if counted.lost == 0 {
                tracing::info!("{text}");
            } else {
                tracing::warn!("{text}");
            }
        }
    }
}
/// The status component `id` published, as a host's `status` reply tells it (null when it has none).
/// Component `id`'s own status in a host's `status` reply (`null` when it has none).
pub fn component_status<'s>(status: &'s serde_json::Value, id: &str) -> &'s serde_json::Value {
    status["telemetry"]["components"]
        .as_array()
        .and_then(|components| components.iter().find(|c| c["id"] == id))
        .map_or(&serde_json::Value::Null, |component| &component["status"])
}
