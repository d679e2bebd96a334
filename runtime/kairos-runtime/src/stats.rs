//! Statistics snapshots: per link and per component, with rates computed between two snapshots.

use std::collections::BTreeMap;

use kairos_diagram::ReaderPolicy;
use kairos_sdk_core::{LinkCounters, Timestamp};
use serde::{Deserialize, Serialize};

/// The life state of a component.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", tag = "state", content = "error")]
pub enum ComponentState {
    /// Built, not started.
    Idle,
    /// Running its cycles.
    Running,
    /// Paused by the user.
    Paused,
    /// Its stream ended and it finished on its own.
    Finished,
    /// Stopped by the runtime.
    Stopped,
    /// It returned an error or panicked; the message says which and why.
    Failed(String),
}

impl ComponentState {
    /// A short word for tables.
    pub fn word(&self) -> &'static str {
        match self {
            ComponentState::Idle => "idle",
            ComponentState::Running => "running",
            ComponentState::Paused => "paused",
            ComponentState::Finished => "finished",
            ComponentState::Stopped => "stopped",
            ComponentState::Failed(_) => "FAILED",
        }
    }
}

/// One link's statistics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LinkStats {
    /// `from -> to`.
    pub link: String,
    /// The reader policy.
    pub policy: ReaderPolicy,
    /// Counters since the run started.
    pub counters: LinkCounters,
    /// Samples written per second over the last interval.
    pub rate_hz: f64,
}

/// One component's statistics.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ComponentStats {
    /// The instance id.
    pub id: String,
    /// The component type.
    pub type_name: String,
    /// Its state.
    pub state: ComponentState,
    /// `core` calls completed.
    pub cycles: u64,
    /// CPU time spent by the component (its thread's CPU time; wall time in `core` for reactive ones).
    pub busy_nanos: u64,
    /// Periodic ticks skipped because the component fell more than a period behind (0 for other modes).
    #[serde(default)]
    pub missed_ticks: u64,
    /// Cycles per second over the last interval.
    pub cycle_rate_hz: f64,
    /// Share of one core over the last interval (0.0 to 1.0).
    pub cpu_share: f64,
    /// What the component last published about itself ([`kairos_sdk_core::Context::set_status`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub status: Option<serde_json::Value>,
    /// The execution group it runs in; `None`: a thread of its own (or its producer's, when reactive).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub group: Option<String>,
}

/// One execution group's statistics: its thread, which runs its members one after the other.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GroupStats {
    /// The group's name.
    pub name: String,
    /// Its members' ids, in the order they run.
    pub members: Vec<String>,
    /// Passes over the members that called at least one of them.
    pub passes: u64,
    /// The CPU time of the group's thread.
    pub cpu_nanos: u64,
    /// The wall time of every pass, added up.
    pub pass_nanos: u64,
    /// The longest pass.
    pub longest_pass_nanos: u64,
    /// Periodic ticks its members skipped because a pass ran past them.
    pub missed_ticks: u64,
    /// The member that took most of the longest pass.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub slowest_member: Option<String>,
    /// Passes per second over the last interval.
    pub pass_rate_hz: f64,
    /// Share of one core over the last interval (0.0 to 1.0).
    pub cpu_share: f64,
    /// The mean pass over the last interval.
    pub mean_pass_nanos: u64,
}

/// Statistics of a whole running diagram at one instant.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct StatsSnapshot {
    /// When it was taken, on the runtime clock.
    pub at: Timestamp,
    /// Per link, in diagram order.
    pub links: Vec<LinkStats>,
    /// Per component, in diagram order.
    pub components: Vec<ComponentStats>,
    /// The clock, when a component of the diagram disciplines it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub clock: Option<kairos_sdk_core::ClockStatus>,
    /// Per execution group, by name.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub groups: Vec<GroupStats>,
}

impl StatsSnapshot {
    /// Fills in rates from an earlier snapshot of the same run.
    #[must_use]
    pub fn with_rates_since(mut self, earlier: &StatsSnapshot) -> StatsSnapshot {
        let seconds = self.at.nanos_since(earlier.at) as f64 * 1e-9;
        if seconds <= 0.0 {
            return self;
        }
        let links: BTreeMap<&str, &LinkStats> = earlier.links.iter().map(|l| (l.link.as_str(), l)).collect();
        for link in &mut self.links {
            if let Some(before) = links.get(link.link.as_str()) {
                link.rate_hz = link.counters.written.saturating_sub(before.counters.written) as f64 / seconds;
            }
        }
        let components: BTreeMap<&str, &ComponentStats> =
            earlier.components.iter().map(|c| (c.id.as_str(), c)).collect();
        for component in &mut self.components {
            if let Some(before) = components.get(component.id.as_str()) {
                component.cycle_rate_hz = component.cycles.saturating_sub(before.cycles) as f64 / seconds;
                component.cpu_share =
                    component.busy_nanos.saturating_sub(before.busy_nanos) as f64 * 1e-9 / seconds;
            }
        }
        let groups: BTreeMap<&str, &GroupStats> =
            earlier.groups.iter().map(|g| (g.name.as_str(), g)).collect();
        for group in &mut self.groups {
            if let Some(before) = groups.get(group.name.as_str()) {
                let passes = group.passes.saturating_sub(before.passes);
                group.pass_rate_hz = passes as f64 / seconds;
                group.cpu_share = group.cpu_nanos.saturating_sub(before.cpu_nanos) as f64 * 1e-9 / seconds;
                group.mean_pass_nanos = group
                    .pass_nanos
                    .saturating_sub(before.pass_nanos)
                    .checked_div(passes)
                    .unwrap_or(0);
            }
        }
        self
    }

    /// Renders the snapshot as two aligned text tables.
    pub fn table(&self) -> String {
        use std::fmt::Write as _;
        let mut out = String::new();
        if let Some(clock) = &self.clock {
            let state = serde_json::to_value(clock.state)
                .ok()
                .and_then(|v| v.as_str().map(str::to_owned))
                .unwrap_or_default();
            let _ = write!(
                out,
                "clock: follows '{}', {state}, error {:+.3} ms, stepped {:+.3} s at lock, {} references",
                clock.source,
                clock.error_ns as f64 * 1e-6,
                clock.step_ns as f64 * 1e-9,
                clock.references
            );
            if let Some(since) = clock.since_reference_s {
                let _ = write!(out, ", the last {since:.1} s ago");
            }
            out.push('\n');
        }
        let width = self.links.iter().map(|l| l.link.len()).max().unwrap_or(4).max(4);
        let _ = writeln!(
            out,
            "{:<width$}  {:<13} {:>9} {:>9} {:>8} {:>11} {:>6} {:>9}  {:>10} {:>10} {:>10}",
            "link",
            "policy",
            "written",
            "read",
            "skipped",
            "overwritten",
            "queued",
            "rate/s",
            "lat min",
            "lat mean",
            "lat p99"
        );
        for link in &self.links {
            let c = &link.counters;
            let _ = writeln!(
                out,
                "{:<width$}  {:<13} {:>9} {:>9} {:>8} {:>11} {:>6} {:>9.1}  {:>10} {:>10} {:>10}",
                link.link,
                link.policy.name(),
                c.written,
                c.read,
                c.skipped,
                c.overwritten,
                c.queued,
                link.rate_hz,
                micros(c.latency.min_nanos, c.latency.count),
                micros(c.latency.mean_nanos, c.latency.count),
                micros(c.latency.p99_nanos, c.latency.count),
            );
        }
        let width = self
            .components
            .iter()
            .map(|c| c.id.len())
            .max()
            .unwrap_or(9)
            .max(9);
        let _ = writeln!(out);
        let _ = writeln!(
            out,
            "{:<width$}  {:<22} {:<8} {:>10} {:>9} {:>6} {:>7}",
            "component", "type", "state", "cycles", "cycles/s", "cpu%", "missed"
        );
        for component in &self.components {
            let _ = writeln!(
                out,
                "{:<width$}  {:<22} {:<8} {:>10} {:>9.1} {:>6.1} {:>7}",
                component.id,
                component.type_name,
                component.state.word(),
                component.cycles,
                component.cycle_rate_hz,
                component.cpu_share * 100.0,
                component.missed_ticks,
            );
            if let ComponentState::Failed(error) = &component.state {
                let _ = writeln!(out, "{:<width$}    error: {error}", "");
            }
            if let Some(counters) = component.status.as_ref().and_then(status_counters) {
                let _ = writeln!(out, "{:<width$}    {counters}", "");
            }
        }
        if !self.groups.is_empty() {
            self.group_table(&mut out);
        }
        self.subgraph_table(&mut out);
        out
    }

    /// Each subgraph instance's parts added up (nested ones in their outermost instance), as the
    /// studio's node shows them: the worst state, the fastest rate, CPU and missed ticks added, and the
    /// samples overwritten on the links into its parts.
    fn subgraph_table(&self, out: &mut String) {
        use std::fmt::Write as _;
        #[derive(Default)]
        struct Instance {
            parts: usize,
            state: Option<&'static str>,
            rate: f64,
            cpu: f64,
            missed: u64,
            lost_inside: u64,
        }
        // Which state an instance shows: a failed part fails it, a running part makes it run.
        let rank = |word: &str| match word {
            "FAILED" => 5,
            "running" => 4,
            "paused" => 3,
            "idle" => 2,
            "finished" => 1,
            _ => 0,
        };
        let mut instances: BTreeMap<&str, Instance> = BTreeMap::new();
        for component in &self.components {
            let Some((outer, _)) = component.id.split_once('/') else {
                continue;
            };
            let instance = instances.entry(outer).or_default();
            instance.parts += 1;
            let word = component.state.word();
            if instance.state.is_none_or(|shown| rank(word) > rank(shown)) {
                instance.state = Some(word);
            }
            instance.rate = instance.rate.max(component.cycle_rate_hz);
            instance.cpu += component.cpu_share;
            instance.missed += component.missed_ticks;
        }
        if instances.is_empty() {
            return;
        }
        for link in &self.links {
            let reader = link.link.rsplit(" -> ").next().unwrap_or_default();
            if let Some((outer, _)) = reader.split_once('/')
                && let Some(instance) = instances.get_mut(outer)
            {
                instance.lost_inside += link.counters.overwritten;
            }
        }
        let width = instances.keys().map(|name| name.len()).max().unwrap_or(8).max(8);
        let _ = writeln!(out);
        let _ = writeln!(
            out,
            "{:<width$}  {:>5} {:<8} {:>9} {:>6} {:>7} {:>11}",
            "subgraph", "parts", "state", "cycles/s", "cpu%", "missed", "lost inside"
        );
        for (name, instance) in &instances {
            let _ = writeln!(
                out,
                "{:<width$}  {:>5} {:<8} {:>9.1} {:>6.1} {:>7} {:>11}",
                name,
                instance.parts,
                instance.state.unwrap_or("-"),
                instance.rate,
                instance.cpu * 100.0,
                instance.missed,
                instance.lost_inside,
            );
        }
    }

    fn group_table(&self, out: &mut String) {
        use std::fmt::Write as _;
        let width = self.groups.iter().map(|g| g.name.len()).max().unwrap_or(5).max(5);
        let _ = writeln!(out);
        let _ = writeln!(
            out,
            "{:<width$}  {:>7} {:>9} {:>6} {:>10} {:>10} {:>7}  slowest",
            "group", "members", "passes/s", "cpu%", "pass mean", "pass max", "missed"
        );
        for group in &self.groups {
            let _ = writeln!(
                out,
                "{:<width$}  {:>7} {:>9.1} {:>6.1} {:>10} {:>10} {:>7}  {}",
                group.name,
                group.members.len(),
                group.pass_rate_hz,
                group.cpu_share * 100.0,
                micros(
                    i64::try_from(group.mean_pass_nanos).unwrap_or(i64::MAX),
                    group.passes
                ),
                micros(
                    i64::try_from(group.longest_pass_nanos).unwrap_or(i64::MAX),
                    group.passes
                ),
                group.missed_ticks,
                group.slowest_member.as_deref().unwrap_or("-"),
            );
        }
    }
}

/// The counts, flags and errors a component's status holds, in words (`decoded 300, unknown_ids 8`,
/// nested names joined by dots: `python.images 46`); `None` when it has none. Other words are left to
/// the studio's inspector, which shows the whole status.
fn status_counters(status: &serde_json::Value) -> Option<String> {
    let mut counters = Vec::new();
    collect_counters("", status.as_object()?, &mut counters);
    (!counters.is_empty()).then(|| counters.join(", "))
}

fn collect_counters(
    prefix: &str,
    fields: &serde_json::Map<String, serde_json::Value>,
    counters: &mut Vec<String>,
) {
    for (name, value) in fields {
        let name = if prefix.is_empty() {
            name.clone()
        } else {
            format!("{prefix}.{name}")
        };
        match value {
            serde_json::Value::Number(number) => counters.push(format!("{name} {number}")),
            serde_json::Value::Bool(flag) => counters.push(format!("{name} {flag}")),
            serde_json::Value::String(text) if name.ends_with("error") => {
                counters.push(format!("{name} \"{text}\""));
            }
            serde_json::Value::Object(inner) => collect_counters(&name, inner, counters),
            _ => {}
        }
    }
}

fn micros(nanos: i64, count: u64) -> String {
    if count == 0 {
        "-".to_owned()
    } else {
        format!("{:.1}µs", nanos as f64 / 1000.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_status_s_counts_and_flags_are_listed_its_words_left_out() {
        let status = serde_json::json!({"kind": "can", "decoded": 300, "unknown_ids": 8, "connected": true, "last_error": "x"});
        assert_eq!(
            status_counters(&status).as_deref(),
            Some("connected true, decoded 300, last_error \"x\", unknown_ids 8")
        );
        assert_eq!(status_counters(&serde_json::json!({"kind": "text"})), None);
        let python =
            serde_json::json!({"python": {"images": 46, "pid": 7, "reload_error": "a.py:3: SyntaxError"}});
        assert_eq!(
            status_counters(&python).as_deref(),
            Some("python.images 46, python.pid 7, python.reload_error \"a.py:3: SyntaxError\"")
        );
    }

    #[test]
    fn each_subgraph_instance_adds_up_its_parts_and_the_losses_on_the_links_into_them() {
        let component = |id: &str, state: ComponentState, cpu_share: f64, missed_ticks: u64| ComponentStats {
            id: id.to_owned(),
            type_name: "core.gain".to_owned(),
            state,
            cycles: 10,
            busy_nanos: 0,
            missed_ticks,
            cycle_rate_hz: 10.0,
            cpu_share,
            status: None,
            group: None,
        };
        let link = |name: &str, overwritten: u64| LinkStats {
            link: name.to_owned(),
            policy: ReaderPolicy::Fifo,
            counters: LinkCounters {
                overwritten,
                ..LinkCounters::default()
            },
            rate_hz: 0.0,
        };
        let snapshot = StatsSnapshot {
            components: vec![
                component("camera", ComponentState::Running, 0.5, 0),
                component("front/grey", ComponentState::Running, 0.1, 1),
                component("front/deep/edges", ComponentState::Failed("x".into()), 0.2, 2),
            ],
            links: vec![
                link("camera.out -> front/grey.in", 7),
                link("front/grey.out -> front/deep/edges.in", 3),
                link("front/grey.out -> camera.in", 100),
            ],
            ..StatsSnapshot::default()
        };
        let table = snapshot.table();
        let row = table
            .lines()
            .find(|line| line.starts_with("front "))
            .unwrap_or_else(|| panic!("no row for front in\n{table}"));
        let words: Vec<&str> = row.split_whitespace().collect();
        assert_eq!(words, ["front", "2", "FAILED", "10.0", "30.0", "3", "10"]);
        assert!(
            !table
                .lines()
                .any(|line| line.starts_with("camera ") && line.contains("parts"))
        );
        let plain = StatsSnapshot {
            components: vec![component("camera", ComponentState::Running, 0.5, 0)],
            ..StatsSnapshot::default()
        };
        assert!(!plain.table().contains("subgraph"));
    }
}
