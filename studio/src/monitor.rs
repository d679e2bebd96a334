//! Live monitoring, fed by the runtime's telemetry: each link's rate, latency and losses, each component's
//! state, cycle rate and CPU share, a short history of each for sparklines, and notices when samples are lost
//! or a component fails. The canvas draws the latest figures on connections and nodes; the monitoring panel
//! lists them all.

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::time::{Duration, Instant};

use egui::{Color32, RichText, Sense, Stroke, Vec2};
use kairos_protocol::{
    ClockState, ClockTelemetry, ComponentState, ComponentTelemetry, GroupTelemetry, LinkTelemetry, LogLevel,
    ReferenceWatch, References, Telemetry,
};

use crate::notices::{Notices, Problem};

/// How many telemetry periods a sparkline shows (a minute at the studio's 4 Hz).
const HISTORY: usize = 240;
/// How long a connection stays marked after it lost samples.
pub const DROP_MARK: Duration = Duration::from_secs(3);
/// The least time between two log lines about the same link's losses.
const NOTICE_EVERY: Duration = Duration::from_secs(5);

/// One link's latest figures and recent history.
#[derive(Debug, Clone)]
pub struct LinkHistory {
    /// The latest telemetry.
    pub latest: LinkTelemetry,
    /// Samples per second, oldest first.
    pub rates: VecDeque<f32>,
    /// p99 latency in milliseconds, oldest first.
    pub latencies_ms: VecDeque<f32>,
    /// When it last lost samples (overwritten unread).
    pub last_drop: Option<Instant>,
    last_notice: Option<Instant>,
}

impl LinkHistory {
    /// Whether it lost samples lately.
    pub fn dropping(&self) -> bool {
        self.last_drop.is_some_and(|at| at.elapsed() < DROP_MARK)
    }
}

/// One component's latest figures and recent history.
#[derive(Debug, Clone)]
pub struct ComponentHistory {
    /// The latest telemetry.
    pub latest: ComponentTelemetry,
    /// Cycles per second, oldest first.
    pub rates: VecDeque<f32>,
    /// Share of one core in percent, oldest first.
    pub cpu: VecDeque<f32>,
}

/// What the panel's tables are sorted by.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SortBy {
    /// Name (link or component id).
    Name,
    /// Rate.
    Rate,
    /// Latency (links) or CPU share (components).
    Cost,
    /// Samples lost (links) or state (components).
    Trouble,
}

/// The monitoring state of the studio.
#[derive(Debug)]
pub struct Monitor {
    /// Per link name (`a.out -> b.in`).
    pub links: BTreeMap<String, LinkHistory>,
    /// Per component id.
    pub components: BTreeMap<String, ComponentHistory>,
    /// The problems over the canvas.
    pub notices: Notices,
    /// With a diagram spread over hosts: each connection between two of them, by link name.
    pub cross_links: BTreeMap<String, kairos_protocol::CrossLinkTelemetry>,
    /// Each execution group's latest figures, by name.
    pub groups: BTreeMap<String, GroupTelemetry>,
    /// Each subgraph instance's figures, rolled up from its inner components (`front/...`): cycles,
    /// missed ticks and CPU added, the fastest rate, the worst state.
    pub subgraphs: BTreeMap<String, ComponentTelemetry>,
    /// Per subgraph instance, the samples lost (overwritten) on the links into its parts.
    pub lost_inside: BTreeMap<String, u64>,
    /// How many times each component failed in this deployment.
    failures: BTreeMap<String, u64>,
    /// The hosts not answering now, and how many times each was lost or each link cut.
    lost_hosts: BTreeSet<String>,
    /// The links between hosts cut now (seen matched before).
    cut_links: BTreeSet<String>,
    /// The links between hosts that match but deliver nothing: since when (the runtime clock, ns), and
    /// whether it was said.
    silent_links: BTreeMap<String, (i64, bool)>,
    /// Each host's clock that follows a source: its references watched, and its state at the last look.
    clocks: BTreeMap<String, (ReferenceWatch, ClockState)>,
    /// The first telemetry's time and when it came: later ones' times become instants from it, so the
    /// clocks' references are timed on the runtime's clock.
    clock_epoch: Option<(i64, Instant)>,
    cuts: BTreeMap<Problem, u64>,
    sort: SortBy,
    descending: bool,
}

/// The figures of each subgraph instance, from its inner components' (ids `instance/...`, nested ones
/// counted in their outermost instance).
pub fn rolled_up(components: &[ComponentTelemetry]) -> BTreeMap<String, ComponentTelemetry> {
    use kairos_protocol::ComponentState;
    // Which state a subgraph shows: a failed part fails it, a running part makes it run.
    let rank = |state: ComponentState| match state {
        ComponentState::Failed => 5,
        ComponentState::Running => 4,
        ComponentState::Paused => 3,
        ComponentState::Idle => 2,
        ComponentState::Finished => 1,
        ComponentState::Stopped | ComponentState::Unknown => 0,
    };
    let mut rolled: BTreeMap<String, ComponentTelemetry> = BTreeMap::new();
    for inner in components {
        let Some((instance, _)) = inner.id.split_once('/') else {
            continue;
        };
        let Some(sum) = rolled.get_mut(instance) else {
            let mut first = inner.clone();
            instance.clone_into(&mut first.id);
            first.status = None;
            first.group = None;
            first.error = first.error.map(|e| format!("{}: {e}", inner.id));
            rolled.insert(instance.to_owned(), first);
            continue;
        };
        sum.cycles += inner.cycles;
        sum.missed_ticks += inner.missed_ticks;
        sum.cpu_share += inner.cpu_share;
        sum.cycle_rate_hz = sum.cycle_rate_hz.max(inner.cycle_rate_hz);
        if rank(inner.state) > rank(sum.state) {
            sum.state = inner.state;
            sum.error = inner.error.as_ref().map(|e| format!("{}: {e}", inner.id));
        }
    }
    rolled
}

impl Default for Monitor {
    fn default() -> Self {
        Monitor {
            links: BTreeMap::new(),
            components: BTreeMap::new(),
            notices: Notices::default(),
            cross_links: BTreeMap::new(),
            groups: BTreeMap::new(),
            subgraphs: BTreeMap::new(),
            lost_inside: BTreeMap::new(),
            failures: BTreeMap::new(),
            lost_hosts: BTreeSet::new(),
            cut_links: BTreeSet::new(),
            silent_links: BTreeMap::new(),
            clocks: BTreeMap::new(),
            clock_epoch: None,
            cuts: BTreeMap::new(),
            sort: SortBy::Name,
            descending: false,
        }
    }
}

fn push(history: &mut VecDeque<f32>, value: f32) {
    if history.len() == HISTORY {
        history.pop_front();
    }
    history.push_back(value);
}

impl Monitor {
    /// Forgets everything (a new deployment).
    pub fn clear(&mut self) {
        self.links.clear();
        self.components.clear();
        self.notices.clear();
        self.cross_links.clear();
        self.groups.clear();
        self.failures.clear();
        self.lost_hosts.clear();
        self.cut_links.clear();
        self.silent_links.clear();
        self.cuts.clear();
    }

    /// The counts of the connection `from -> to` between two hosts, when the diagram is spread.
    pub fn cross_link(
        &self,
        from: &kairos_diagram::PortRef,
        to: &kairos_diagram::PortRef,
    ) -> Option<&kairos_protocol::CrossLinkTelemetry> {
        self.cross_links.get(&format!("{from} -> {to}"))
    }

    /// Takes in one telemetry event, raising or updating the notices of its problems (samples lost, a
    /// component failed, a host lost, a link between hosts cut); returns what to add to the log: each new
    /// problem and each end of one across hosts, and a link's losses again at most every few seconds.
    pub fn update(&mut self, telemetry: &Telemetry) -> Vec<(LogLevel, String)> {
        let now = Instant::now();
        self.subgraphs = rolled_up(&telemetry.components);
        self.lost_inside.clear();
        for link in &telemetry.links {
            // `a.out -> front/edges.in`: a reader inside `front`.
            let reader = link.link.rsplit(" -> ").next().unwrap_or_default();
            if let Some((instance, _)) = reader.split_once('/')
                && link.overwritten > 0
            {
                *self.lost_inside.entry(instance.to_owned()).or_default() += link.overwritten;
            }
        }
        let mut raised = self.follow_hosts(telemetry);
        self.groups = telemetry
            .groups
            .iter()
            .map(|group| (group.name.clone(), group.clone()))
            .collect();
        self.cross_links = telemetry
            .cross_links
            .iter()
            .map(|link| (format!("{} -> {}", link.from, link.to), link.clone()))
            .collect();
        for link in &telemetry.links {
            let entry = self
                .links
                .entry(link.link.clone())
                .or_insert_with(|| LinkHistory {
                    latest: link.clone(),
                    rates: VecDeque::new(),
                    latencies_ms: VecDeque::new(),
                    last_drop: (link.overwritten > 0).then_some(now),
                    last_notice: None,
                });
            let lost = link.overwritten.saturating_sub(entry.latest.overwritten);
            if lost > 0 || (entry.rates.is_empty() && link.overwritten > 0) {
                entry.last_drop = Some(now);
                let text = format!(
                    "{} loses samples: its reader is slower than its writer and the {} buffer overflows; \
                     a larger buffer, subsampling or LastOrNext helps",
                    link.link, link.policy
                );
                self.notices
                    .raise(Problem::Losses(link.link.clone()), text.clone(), link.overwritten);
                if entry.last_notice.is_none_or(|at| now - at >= NOTICE_EVERY) {
                    entry.last_notice = Some(now);
                    raised.push((
                        LogLevel::Warn,
                        format!("{text} ({} lost so far)", link.overwritten),
                    ));
                }
            }
            push(&mut entry.rates, link.rate_hz as f32);
            push(&mut entry.latencies_ms, link.latency.p99_ns as f32 / 1e6);
            entry.latest = link.clone();
        }
        for component in &telemetry.components {
            let entry = self
                .components
                .entry(component.id.clone())
                .or_insert_with(|| ComponentHistory {
                    latest: component.clone(),
                    rates: VecDeque::new(),
                    cpu: VecDeque::new(),
                });
            let newly_failed = component.state == ComponentState::Failed
                && (entry.latest.state != ComponentState::Failed || entry.rates.is_empty());
            let problem = Problem::Failed(component.id.clone());
            if newly_failed {
                let times = self.failures.entry(component.id.clone()).or_insert(0);
                *times += 1;
                let text = format!(
                    "{} failed: {}",
                    component.id,
                    component.error.as_deref().unwrap_or("no reason given")
                );
                self.notices.raise(problem, text.clone(), *times);
                raised.push((LogLevel::Error, text));
            } else if component.state == ComponentState::Running {
                self.notices.resolve(&problem);
            }
            push(&mut entry.rates, component.cycle_rate_hz as f32);
            push(&mut entry.cpu, (component.cpu_share * 100.0) as f32);
            entry.latest = component.clone();
        }
        raised
    }

    /// Raises a notice when a host of a spread diagram stops answering or a connection between hosts loses
    /// its far end, and takes it back when they return; what to log of it.
    ///
    /// The coordinating runtime logs each host lost and back, each clock's silence and lock, and each cut
    /// or silence of a link whose sender runs on another host, in its own words, and its log is the
    /// studio's: those are shown as notices and not logged twice. A link whose sender runs on the
    /// coordinating machine is said by its sender by peer alone, so the studio logs it by name.
    fn follow_hosts(&mut self, telemetry: &Telemetry) -> Vec<(LogLevel, String)> {
        let mut said = Vec::new();
        for host in &telemetry.hosts {
            let problem = Problem::HostLost(host.name.clone());
            if !host.answering && self.lost_hosts.insert(host.name.clone()) {
                let text = format!(
                    "host '{}' is lost: it does not answer (the network, or the machine); the other hosts run \
                     on, and it is watched again when it answers",
                    host.name
                );
                let times = self.cuts.entry(problem.clone()).or_insert(0);
                *times += 1;
                self.notices.raise(problem, text, *times);
            } else if host.answering && self.lost_hosts.remove(&host.name) {
                self.notices.resolve(&problem);
            }
            if let Some(clock) = &host.clock {
                self.follow_clock(telemetry.at_ns, &host.name, clock);
            }
        }
        for link in &telemetry.cross_links {
            let name = format!("{} -> {}", link.from, link.to);
            // A link not seen matched yet (its sender has not said so before the start) is not cut.
            let was_matched = self.cross_links.get(&name).is_some_and(|l| l.matched);
            let problem = Problem::LinkCut(name.clone());
            let between = format!(
                "{} -> {}",
                link.from_host.as_deref().unwrap_or("here"),
                link.to_host.as_deref().unwrap_or("here")
            );
            let mut about_link = Vec::new();
            if !link.matched && was_matched {
                self.cut_links.insert(name.clone());
                let text = format!(
                    "link {name} ({between}) is cut: its far end is out of reach; a consumer that never skips \
                     gets what was sent again when it returns (within its host's ride_out_s), any other \
                     loses it, counted"
                );
                let times = self.cuts.entry(problem.clone()).or_insert(0);
                *times += 1;
                self.notices.raise(problem, text.clone(), *times);
                about_link.push((LogLevel::Error, text));
            } else if link.matched && self.cut_links.remove(&name) {
                self.notices.resolve(&problem);
                about_link.push((LogLevel::Info, format!("link {name} ({between}) resumed")));
            }
            self.follow_silence(telemetry.at_ns, link, &name, &between, &mut about_link);
            if link.from_host.is_none() {
                said.extend(about_link);
            }
        }
        said
    }

    /// Raises a notice when a host's clock has had no reference for well over its usual wait (its master
    /// or receiver silent, long before the clock leaves lock) and when it leaves lock; takes them back
    /// when references come again and when it locks again. As `kairos deploy` says them (the
    /// coordinator's log says them too).
    fn follow_clock(&mut self, at_ns: i64, host: &str, clock: &ClockTelemetry) {
        let (epoch_ns, epoch) = *self.clock_epoch.get_or_insert((at_ns, Instant::now()));
        let now = epoch + Duration::from_nanos(u64::try_from(at_ns - epoch_ns).unwrap_or(0));
        let error = format!("error {}", kairos_protocol::error_ms(clock.error_ns));
        let (watch, state) = self
            .clocks
            .entry(host.to_owned())
            .or_insert_with(|| (ReferenceWatch::default(), clock.state));
        let silent = Problem::ClockSilent(host.to_owned());
        match watch.look(now, clock.state, clock.references, clock.since_reference_s) {
            References::Stopped { for_s } => {
                let text = format!(
                    "host '{host}': its clock has had no reference from {} for {for_s:.1} s; it runs on at its \
                     own rate ({error}) and leaves lock if none comes within 3 s",
                    clock.source
                );
                let times = self.cuts.entry(silent.clone()).or_insert(0);
                *times += 1;
                self.notices.raise(silent.clone(), text, *times);
            }
            References::Back => {
                self.notices.resolve(&silent);
            }
            References::AsUsual => {}
        }
        let was = std::mem::replace(state, clock.state);
        let unlocked = Problem::ClockUnlocked(host.to_owned());
        if was == ClockState::Locked && clock.state != ClockState::Locked {
            // Out of lock, its state says it all.
            self.notices.resolve(&silent);
            let text = format!(
                "host '{host}': its clock left lock ({}, {error}); what it stamps now drifts against the \
                 other hosts",
                clock.state
            );
            let times = self.cuts.entry(unlocked.clone()).or_insert(0);
            *times += 1;
            self.notices.raise(unlocked, text, *times);
        } else if was != ClockState::Locked && clock.state == ClockState::Locked {
            self.notices.resolve(&unlocked);
        }
    }

    /// Says a link between hosts that matches but delivers nothing, once it has held over two telemetry
    /// messages (its ends' figures are read at different instants), and its return.
    fn follow_silence(
        &mut self,
        at_ns: i64,
        link: &kairos_protocol::CrossLinkTelemetry,
        name: &str,
        between: &str,
        said: &mut Vec<(LogLevel, String)>,
    ) {
        let problem = Problem::LinkSilent(name.to_owned());
        if !link.delivers_nothing() {
            if let Some((_, true)) = self.silent_links.remove(name) {
                self.notices.resolve(&problem);
                // A cut ends it too (a dead path is first quiet, then unmatched): the cut is said then.
                if link.matched {
                    said.push((LogLevel::Info, format!("link {name} ({between}) delivers again")));
                }
            }
            return;
        }
        let (since, was_said) = self.silent_links.entry(name.to_owned()).or_insert((at_ns, false));
        if *was_said || at_ns <= *since {
            return;
        }
        *was_said = true;
        let quiet = link.last_sample_age_ms.map_or_else(
            || "nothing yet".to_owned(),
            |ms| format!("nothing for {:.1} s", ms as f64 / 1000.0),
        );
        let text = format!(
            "link {name} ({between}) delivers nothing: it matches, but its far end has received {quiet} \
             while {} more were sent; a consumer there is stalled, or the path between the hosts carries \
             nothing though both ends see each other; what never arrives is counted lost",
            link.sent - link.received - link.lost
        );
        let times = self.cuts.entry(problem.clone()).or_insert(0);
        *times += 1;
        self.notices.raise(problem, text.clone(), *times);
        said.push((LogLevel::Error, text));
    }

    /// A link's figures, by its ends.
    pub fn link(&self, from: &kairos_diagram::PortRef, to: &kairos_diagram::PortRef) -> Option<&LinkHistory> {
        self.links.get(&format!("{from} -> {to}"))
    }

    /// The notices shown now, as they read, oldest first.
    pub fn recent_notices(&self) -> impl Iterator<Item = String> {
        self.notices.shown().map(crate::notices::Notice::line)
    }

    /// Shows the notices inside the canvas (`over`), top right.
    pub fn show_notices(&mut self, ui: &mut egui::Ui) {
        self.notices.show(ui);
    }

    /// Whether a notice is to be shown over the canvas now.
    pub fn has_notices(&self) -> bool {
        self.notices.any_shown()
    }

    fn sort_header(&mut self, ui: &mut egui::Ui, label: &str, by: SortBy) {
        let arrow = match (self.sort == by, self.descending) {
            (true, false) => " ^",
            (true, true) => " v",
            _ => "",
        };
        if ui
            .add(egui::Button::new(RichText::new(format!("{label}{arrow}")).strong()).frame(false))
            .on_hover_text("sort by this column")
            .clicked()
        {
            if self.sort == by {
                self.descending = !self.descending;
            } else {
                self.sort = by;
                self.descending = by != SortBy::Name;
            }
        }
    }

    /// Link names in the panel's order.
    pub fn sorted_links(&self) -> Vec<&LinkHistory> {
        let mut links: Vec<&LinkHistory> = self.links.values().collect();
        links.sort_by(|a, b| {
            let (a, b) = (&a.latest, &b.latest);
            match self.sort {
                SortBy::Name => a.link.cmp(&b.link),
                SortBy::Rate => a.rate_hz.total_cmp(&b.rate_hz),
                SortBy::Cost => a.latency.p99_ns.cmp(&b.latency.p99_ns),
                SortBy::Trouble => a.overwritten.cmp(&b.overwritten),
            }
        });
        if self.descending {
            links.reverse();
        }
        links
    }

    fn sorted_components(&self) -> Vec<&ComponentHistory> {
        let mut components: Vec<&ComponentHistory> = self.components.values().collect();
        components.sort_by(|a, b| {
            let (a, b) = (&a.latest, &b.latest);
            match self.sort {
                SortBy::Name => a.id.cmp(&b.id),
                SortBy::Rate => a.cycle_rate_hz.total_cmp(&b.cycle_rate_hz),
                SortBy::Cost => a.cpu_share.total_cmp(&b.cpu_share),
                SortBy::Trouble => a.state.word().cmp(b.state.word()),
            }
        });
        if self.descending {
            components.reverse();
        }
        components
    }

    /// The monitoring panel: every link and component, sortable by clicking a column's title, with
    /// sparklines of the last minute.
    pub fn panel(&mut self, ui: &mut egui::Ui) {
        if self.links.is_empty() && self.components.is_empty() {
            ui.weak("Nothing deployed: run a diagram to see its links and components here.");
            return;
        }
        // Both ways: a narrow panel scrolls rather than cutting the last columns.
        egui::ScrollArea::both()
            .auto_shrink([false, true])
            .show(ui, |ui| {
                // Groups, when there are any, first: a few rows that sum up hundreds of components.
                if !self.groups.is_empty() {
                    self.groups_grid(ui);
                    ui.separator();
                }
                // Losses first: what the panel is most often opened for.
                egui::Grid::new("links")
                    .striped(true)
                    .num_columns(7)
                    .show(ui, |ui| {
                        self.sort_header(ui, "link", SortBy::Name);
                        self.sort_header(ui, "lost", SortBy::Trouble);
                        ui.strong("queued / skipped");
                        ui.strong("policy");
                        self.sort_header(ui, "rate", SortBy::Rate);
                        ui.strong("last minute");
                        self.sort_header(ui, "latency p50 / p99", SortBy::Cost);
                        ui.end_row();
                        for link in self.sorted_links() {
                            let t = &link.latest;
                            ui.label(&t.link);
                            let lost = RichText::new(t.overwritten.to_string());
                            ui.label(if link.dropping() {
                                lost.color(Color32::from_rgb(240, 110, 60)).strong()
                            } else {
                                lost
                            })
                            .on_hover_text("samples overwritten before this reader read them");
                            ui.label(format!("{} / {}", t.queued, t.skipped));
                            ui.label(t.policy.name());
                            ui.label(format!("{:.1} Hz", t.rate_hz));
                            sparkline(ui, &link.rates, Color32::LIGHT_BLUE);
                            ui.label(format!(
                                "{} / {}",
                                milliseconds(t.latency.p50_ns),
                                milliseconds(t.latency.p99_ns)
                            ));
                            ui.end_row();
                        }
                    });
                ui.separator();
                egui::Grid::new("components")
                    .striped(true)
                    .num_columns(7)
                    .show(ui, |ui| {
                        self.sort_header(ui, "component", SortBy::Name);
                        self.sort_header(ui, "state", SortBy::Trouble);
                        ui.strong("missed ticks").on_hover_text(
                            "periodic ticks skipped because a cycle took longer than its period",
                        );
                        self.sort_header(ui, "cycles/s", SortBy::Rate);
                        ui.strong("last minute");
                        self.sort_header(ui, "CPU", SortBy::Cost);
                        ui.strong("last minute");
                        ui.end_row();
                        for component in self.sorted_components() {
                            let t = &component.latest;
                            ui.label(&t.id);
                            let state = RichText::new(t.state.word());
                            let state = if t.state == ComponentState::Failed {
                                state.color(Color32::LIGHT_RED)
                            } else {
                                state
                            };
                            let response = ui.label(state);
                            if let Some(error) = &t.error {
                                response.on_hover_text(error);
                            }
                            let missed = RichText::new(t.missed_ticks.to_string());
                            ui.label(if t.missed_ticks > 0 {
                                missed.color(Color32::from_rgb(240, 110, 60))
                            } else {
                                missed
                            });
                            ui.label(format!("{:.1}", t.cycle_rate_hz));
                            sparkline(ui, &component.rates, Color32::LIGHT_GREEN);
                            ui.label(format!("{:.1} %", t.cpu_share * 100.0));
                            sparkline(ui, &component.cpu, Color32::GOLD);
                            ui.end_row();
                        }
                    });
            });
    }

    /// Each execution group: its thread's CPU, its passes and how long they take, the ticks its members
    /// missed and who took the time.
    fn groups_grid(&self, ui: &mut egui::Ui) {
        egui::Grid::new("groups")
            .striped(true)
            .num_columns(7)
            .show(ui, |ui| {
                ui.strong("group")
                    .on_hover_text("an execution group: its members share one thread");
                ui.strong("members");
                ui.strong("CPU")
                    .on_hover_text("the group's thread, share of one core");
                ui.strong("passes/s")
                    .on_hover_text("a pass calls every member that has something to do");
                ui.strong("pass mean / longest");
                ui.strong("missed ticks")
                    .on_hover_text("periodic ticks its members skipped because a pass ran past them");
                ui.strong("slowest member")
                    .on_hover_text("the member that took most of the longest pass");
                ui.end_row();
                for group in self.groups.values() {
                    ui.label(&group.name);
                    ui.label(group.members.len().to_string())
                        .on_hover_text(group.members.join(", "));
                    ui.label(format!("{:.1} %", group.cpu_share * 100.0));
                    ui.label(format!("{:.1}", group.pass_rate_hz));
                    ui.label(format!(
                        "{} / {}",
                        milliseconds(i64::try_from(group.mean_pass_ns).unwrap_or(i64::MAX)),
                        milliseconds(i64::try_from(group.longest_pass_ns).unwrap_or(i64::MAX))
                    ));
                    let missed = RichText::new(group.missed_ticks.to_string());
                    ui.label(if group.missed_ticks > 0 {
                        missed.color(Color32::from_rgb(240, 110, 60))
                    } else {
                        missed
                    });
                    ui.label(group.slowest_member.as_deref().unwrap_or("–"));
                    ui.end_row();
                }
            });
    }
}

/// A latency in nanoseconds, in milliseconds or microseconds.
pub fn milliseconds(ns: i64) -> String {
    if ns.abs() >= 1_000_000 {
        format!("{:.1} ms", ns as f64 / 1e6)
    } else {
        format!("{} µs", ns / 1_000)
    }
}

/// A small line of `values` scaled to their own maximum.
fn sparkline(ui: &mut egui::Ui, values: &VecDeque<f32>, color: Color32) {
    let (rect, _) = ui.allocate_exact_size(Vec2::new(90.0, 16.0), Sense::hover());
    let max = values.iter().copied().fold(0.0_f32, f32::max).max(f32::EPSILON);
    let step = rect.width() / (HISTORY - 1) as f32;
    let start = rect.right() - step * values.len().saturating_sub(1) as f32;
    let points: Vec<egui::Pos2> = values
        .iter()
        .enumerate()
        .map(|(i, v)| egui::pos2(start + step * i as f32, rect.bottom() - rect.height() * (v / max)))
        .collect();
    ui.painter().rect_filled(rect, 2.0, ui.visuals().extreme_bg_color);
    ui.painter()
        .add(egui::Shape::line(points, Stroke::new(1.2, color)));
}

#[cfg(test)]
mod tests {
    use kairos_protocol::{
        ClockState, ClockTelemetry, CrossLinkTelemetry, HostTelemetry, LogLevel, RuntimeState, Telemetry,
    };

    use super::Monitor;

    /// Telemetry of a diagram with host b, fed from here over one link.
    fn telemetry(answering: bool, matched: bool) -> Telemetry {
        Telemetry {
            at_ns: 0,
            state: RuntimeState::Running,
            links: Vec::new(),
            components: Vec::new(),
            clock: None,
            groups: Vec::new(),
            hosts: vec![HostTelemetry {
                name: "b".to_owned(),
                answering,
                state: None,
                clock: None,
            }],
            cross_links: vec![CrossLinkTelemetry {
                from: "count.out".to_owned(),
                to: "gain.in".to_owned(),
                from_host: None,
                to_host: Some("b".to_owned()),
                sent: 10,
                received: 10,
                lost: 0,
                matched,
                last_sample_age_ms: None,
                quiet_after_ms: None,
                transit_p50_ns: None,
                transit_max_ns: None,
            }],
        }
    }

    #[test]
    fn a_subgraph_instance_sums_its_parts_cpu_takes_their_fastest_rate_worst_state_and_losses_inside() {
        let part = |id: &str, state: &str, rate: f64, cpu: f64| {
            serde_json::json!({"id": id, "type_name": "core.gain", "state": state, "cycles": 10,
                "cycle_rate_hz": rate, "cpu_share": cpu})
        };
        let link = |name: &str, overwritten: u64| {
            serde_json::json!({"link": name, "policy": "Fifo", "written": 100, "read": 90, "skipped": 0,
                "overwritten": overwritten, "queued": 0, "repeated": 0, "rate_hz": 10.0,
                "latency": {"count": 0, "min_ns": 0, "mean_ns": 0, "p50_ns": 0, "p99_ns": 0, "max_ns": 0}})
        };
        let mut telemetry = telemetry(true, true);
        telemetry.components = serde_json::from_value(serde_json::json!([
            part("cam", "running", 30.0, 0.01),
            part("front/grey", "running", 15.0, 0.05),
            part("front/inner/edges", "failed", 12.0, 0.20),
        ]))
        .unwrap();
        telemetry.links = serde_json::from_value(serde_json::json!([
            link("cam.image -> front/grey.in", 3),
            link("front/grey.out -> front/inner/edges.in", 4),
            link("front/inner/edges.out -> log.in", 50),
        ]))
        .unwrap();
        let mut monitor = Monitor::default();
        monitor.update(&telemetry);
        let front = &monitor.subgraphs["front"];
        assert!((front.cpu_share - 0.25).abs() < 1e-9);
        assert!((front.cycle_rate_hz - 15.0).abs() < 1e-9);
        assert_eq!(front.cycles, 20);
        assert_eq!(front.state, kairos_protocol::ComponentState::Failed);
        assert!(!monitor.subgraphs.contains_key("cam"));
        // Lost on the links into its parts; what a reader outside lost is not the subgraph's.
        assert_eq!(monitor.lost_inside["front"], 7);
        assert_eq!(monitor.lost_inside.len(), 1);
    }

    /// The texts of the notices shown.
    fn shown(monitor: &Monitor) -> Vec<&str> {
        monitor
            .notices
            .shown()
            .map(|notice| notice.text.as_str())
            .collect()
    }

    #[test]
    fn a_host_lost_and_a_link_cut_are_shown_until_they_return_and_logged_once_by_whoever_says_them() {
        let mut monitor = Monitor::default();
        // Before the start, a link's sender has not said it matched: neither a cut nor a return.
        assert!(monitor.update(&telemetry(true, false)).is_empty());
        assert!(monitor.update(&telemetry(true, true)).is_empty());
        // The host's loss is in the coordinator's log; the cut of a link sent from here, by name, in
        // the studio's.
        let said = monitor.update(&telemetry(false, false));
        assert_eq!(said.len(), 1, "{said:?}");
        assert_eq!(said[0].0, LogLevel::Error);
        assert!(
            said[0]
                .1
                .starts_with("link count.out -> gain.in (here -> b) is cut"),
            "{said:?}"
        );
        let notices = shown(&monitor);
        assert_eq!(notices.len(), 2, "{notices:?}");
        assert!(
            notices.iter().any(|text| text.starts_with("host 'b' is lost")),
            "{notices:?}"
        );
        assert!(monitor.update(&telemetry(false, false)).is_empty(), "said once");
        let back = monitor.update(&telemetry(true, true));
        assert_eq!(
            back,
            [(
                LogLevel::Info,
                "link count.out -> gain.in (here -> b) resumed".to_owned()
            )]
        );
        assert_eq!(monitor.notices.shown().count(), 0);
        // A link sent from another host: the coordinator logs its cut; the studio shows it.
        let from_b = |up: bool| {
            let mut telemetry = telemetry(true, up);
            let link = &mut telemetry.cross_links[0];
            (link.from_host, link.to_host) = (Some("b".to_owned()), None);
            telemetry
        };
        assert!(monitor.update(&from_b(true)).is_empty());
        assert!(monitor.update(&from_b(false)).is_empty());
        assert!(shown(&monitor)[0].starts_with("link count.out -> gain.in (b -> here) is cut"));
        assert!(monitor.update(&from_b(true)).is_empty());
        assert_eq!(monitor.notices.shown().count(), 0);
    }

    #[test]
    fn a_matched_link_that_delivers_nothing_is_said_once_it_holds_and_so_is_its_return() {
        let mut monitor = Monitor::default();
        let at = |seconds: f64, sent: u64, received: u64, age_ms: u64| {
            let mut telemetry = telemetry(true, true);
            telemetry.at_ns = (seconds * 1e9) as i64;
            let link = &mut telemetry.cross_links[0];
            (link.sent, link.received, link.last_sample_age_ms) = (sent, received, Some(age_ms));
            telemetry
        };
        assert!(monitor.update(&at(0.0, 100, 100, 10)).is_empty());
        // Nothing outstanding, or outstanding but fresh: nothing to say.
        assert!(monitor.update(&at(1.0, 100, 100, 5000)).is_empty());
        assert!(monitor.update(&at(2.0, 150, 120, 100)).is_empty());
        // Outstanding and quiet: said once it held a second.
        assert!(monitor.update(&at(3.0, 200, 120, 1600)).is_empty());
        let said = monitor.update(&at(4.0, 300, 120, 2600));
        assert_eq!(said.len(), 1, "{said:?}");
        assert_eq!(said[0].0, LogLevel::Error);
        assert!(
            said[0].1.starts_with(
                "link count.out -> gain.in (here -> b) delivers nothing: it matches, but its far end has \
                 received nothing for 2.6 s while 180 more were sent"
            ),
            "{said:?}"
        );
        assert_eq!(monitor.notices.shown().count(), 1);
        assert!(monitor.update(&at(5.0, 400, 120, 3600)).is_empty(), "said once");
        let back = monitor.update(&at(6.0, 500, 480, 5));
        assert_eq!(
            back,
            [(
                LogLevel::Info,
                "link count.out -> gain.in (here -> b) delivers again".to_owned()
            )]
        );
        assert_eq!(monitor.notices.shown().count(), 0);
        // A fast link's receiver learnt that 400 ms of quiet is unusual: said at the second message.
        let fast = |seconds: f64, sent: u64, age_ms: u64| {
            let mut telemetry = at(seconds, sent, 480, age_ms);
            telemetry.cross_links[0].quiet_after_ms = Some(400);
            telemetry
        };
        assert!(monitor.update(&fast(7.0, 520, 300)).is_empty());
        assert!(monitor.update(&fast(7.25, 540, 450)).is_empty());
        let said = monitor.update(&fast(7.5, 560, 700));
        assert_eq!(said.len(), 1, "{said:?}");
        assert!(said[0].1.contains("nothing for 0.7 s while 80 more"), "{said:?}");
        // Then the lease ends and the link is cut: the cut is said, not that it delivers again.
        let mut cut = fast(7.75, 560, 950);
        cut.cross_links[0].matched = false;
        let said = monitor.update(&cut);
        assert!(
            said.iter().all(|(_, text)| !text.contains("delivers again")),
            "{said:?}"
        );
    }

    #[test]
    fn a_clock_master_that_stops_answering_is_said_before_the_clock_leaves_lock_and_both_end() {
        let mut monitor = Monitor::default();
        let at = |look: u32, state: ClockState, references: u64, since_s: f64| {
            let mut telemetry = telemetry(true, true);
            telemetry.at_ns = i64::from(look) * 250_000_000;
            telemetry.hosts[0].clock = Some(ClockTelemetry {
                source: "master 10.0.0.1:7401".to_owned(),
                state,
                error_ns: 20_000,
                step_ns: 0,
                references,
                since_reference_s: Some(since_s),
                error_bound_ns: Some(40_000),
                rate_ppm: None,
            });
            telemetry
        };
        // A reference between each two telemetry messages, 250 ms apart.
        for look in 0..12 {
            assert!(
                monitor
                    .update(&at(look, ClockState::Locked, u64::from(look), 0.1))
                    .is_empty()
            );
        }
        // The master dies: shown once its silence is over 1 s, while the clock is still locked (the
        // coordinator's log says it).
        for look in 12..18 {
            let silence = f64::from(look - 11) * 0.25;
            assert!(
                monitor
                    .update(&at(look, ClockState::Locked, 11, silence))
                    .is_empty()
            );
            if look == 12 {
                assert_eq!(
                    monitor.notices.shown().count(),
                    0,
                    "a quarter of a second is usual"
                );
            }
        }
        assert!(
            shown(&monitor)[0].starts_with("host 'b': its clock has had no reference from master"),
            "{:?}",
            shown(&monitor)
        );
        // Holdover: the state speaks, and the silence's notice gives way to it.
        assert!(monitor.update(&at(24, ClockState::Holdover, 11, 3.25)).is_empty());
        let notices = shown(&monitor);
        assert_eq!(notices.len(), 1, "{notices:?}");
        assert!(
            notices[0].contains("its clock left lock (holdover, error +0.020 ms)"),
            "{notices:?}"
        );
        assert!(monitor.update(&at(30, ClockState::Locked, 12, 0.1)).is_empty());
        assert_eq!(monitor.notices.shown().count(), 0);
    }
}
