//! Execution groups: several components in one thread (RTMaps' sequential behaviour, per group).
//!
//! A group's thread runs passes. In a pass it goes through its members in the order of the links
//! between them and runs each one that has something to do: a periodic member whose tick is due, a
//! member whose inputs received samples. A sample written by one member is read by the next in the same
//! pass: a hand-off is a buffer write and a call, with no thread woken. Samples still go through the
//! members' output buffers, so the reader policies, the link counters, viewers and recorders see a group
//! exactly as they see threads.
//!
//! Members read without blocking (their signal is reactive): a read with nothing new returns
//! [`ComponentError::NoData`] and the member waits for the next pass. One member may wait inside its
//! calls (a source that keeps its own time, see [`kairos_diagram::ComponentInfo::blocking_reason`]): it
//! is the group's driver, called first, and the other members run after each of its cycles. Between
//! passes the thread sleeps until a periodic member is due, a sample arrives from outside the group, or
//! the engine asks for attention (stop, pause, a property change).

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::thread::Thread;
use std::time::{Duration, Instant};

use kairos_diagram::{ExecutionMode, ThreadSettings};
use kairos_sdk_core::component::StatusSchedule;
use kairos_sdk_core::host::ContextHost as _;
use kairos_sdk_core::{Clock, Component, ComponentError, Context, RunSignal, Timestamp};

use crate::engine::{CPU_SAMPLE_PERIOD, MissedTicks, Monitor, apply_controls, guarded, lock};
use crate::scheduling;
use crate::start_gate::StartGate;
use crate::stats::{ComponentState, GroupStats};

/// A member that read samples runs again at once while it finds more, at most this many times a pass:
/// a long backlog on one input must not hold the rest of the group.
const CALLS_PER_PASS: usize = 64;
/// Passes in a row before the thread looks at stop, pause and control requests again: a stream that
/// never lets the group go quiet must not keep them waiting.
const PASSES_PER_TURN: usize = 16;
/// How often a sleeping group looks whether its members' input streams ended: a closed stream wakes
/// the thread but says nothing of which member it feeds.
const EXHAUSTION_CHECK: Duration = Duration::from_millis(100);

/// What a group's thread, its members' signals and the engine share.
#[derive(Debug)]
pub(crate) struct GroupShared {
    pub(crate) name: String,
    thread: OnceLock<Thread>,
    driver: OnceLock<Arc<RunSignal>>,
    /// The thread is inside a pass: a sample written now is seen by the end of the pass, no wake-up
    /// needed.
    in_pass: AtomicBool,
    passes: AtomicU64,
    cpu_nanos: AtomicU64,
    pass_nanos: AtomicU64,
    longest_pass_nanos: AtomicU64,
    missed_ticks: AtomicU64,
    /// The member whose calls took longest in the longest pass, and how long they took.
    slowest: Mutex<Option<(String, u64)>>,
}

impl GroupShared {
    pub(crate) fn new(name: &str) -> Self {
        GroupShared {
            name: name.to_owned(),
            thread: OnceLock::new(),
            driver: OnceLock::new(),
            in_pass: AtomicBool::new(false),
            passes: AtomicU64::new(0),
            cpu_nanos: AtomicU64::new(0),
            pass_nanos: AtomicU64::new(0),
            longest_pass_nanos: AtomicU64::new(0),
            missed_ticks: AtomicU64::new(0),
            slowest: Mutex::new(None),
        }
    }

    /// Wakes the group's thread, if it has started.
    pub(crate) fn wake(&self) {
        if let Some(thread) = self.thread.get() {
            thread.unpark();
        }
    }

    /// The driver's signal: the group's thread waits inside the driver's calls.
    pub(crate) fn set_driver(&self, signal: &Arc<RunSignal>) {
        let _ = self.driver.set(Arc::clone(signal));
    }

    /// Gets the thread's attention for a member's control request: the driver's wait is interrupted
    /// (it applies none itself), so that the request does not wait for the driver's next sample.
    pub(crate) fn attention(&self) {
        match self.driver.get() {
            Some(driver) => driver.raise_control(),
            None => self.wake(),
        }
    }

    /// The signal of a member that is not the driver: a write to one of its inputs marks it ready, and
    /// wakes the thread only when it is between passes.
    pub(crate) fn member_signal(self: &Arc<Self>, ready: &Arc<AtomicBool>) -> RunSignal {
        let shared = Arc::clone(self);
        let ready = Arc::clone(ready);
        RunSignal::reactive(move || {
            // SeqCst with the thread's `in_pass` store and scan of `ready`: either the scan sees this
            // mark, or this sees the thread out of its pass and wakes it.
            ready.store(true, Ordering::SeqCst);
            if !shared.in_pass.load(Ordering::SeqCst) {
                shared.wake();
            }
        })
    }

    /// The group's statistics now, with `members` ids.
    pub(crate) fn stats(&self, members: Vec<String>) -> GroupStats {
        let slowest = lock(&self.slowest).clone();
        GroupStats {
            name: self.name.clone(),
            members,
            passes: self.passes.load(Ordering::Relaxed),
            cpu_nanos: self.cpu_nanos.load(Ordering::Relaxed),
            pass_nanos: self.pass_nanos.load(Ordering::Relaxed),
            longest_pass_nanos: self.longest_pass_nanos.load(Ordering::Relaxed),
            missed_ticks: self.missed_ticks.load(Ordering::Relaxed),
            slowest_member: slowest.map(|(id, _)| id),
            pass_rate_hz: 0.0,
            cpu_share: 0.0,
            mean_pass_nanos: 0,
        }
    }
}

/// A member of a group, with what its calls need.
pub(crate) struct Member {
    pub(crate) id: String,
    pub(crate) mode: ExecutionMode,
    /// Links into it do not order the group (see [`run_order`]).
    pub(crate) holds_inputs: bool,
    /// It waits inside its calls: called first at every turn of the loop, never skipped.
    pub(crate) drives: bool,
    pub(crate) component: Box<dyn Component>,
    pub(crate) ctx: Context,
    pub(crate) signal: Arc<RunSignal>,
    pub(crate) monitor: Arc<Monitor>,
    /// Set when one of its inputs received a sample.
    pub(crate) ready: Arc<AtomicBool>,
    pub(crate) status: StatusSchedule,
    pub(crate) next_tick: Option<Timestamp>,
    pub(crate) missed: MissedTicks,
    /// Finished, failed or stopped: no more calls.
    pub(crate) done: bool,
}

impl Member {
    fn has_connected_inputs(&self) -> bool {
        self.ctx
            .inputs()
            .iter()
            .any(kairos_sdk_core::InputPort::is_connected)
    }

    /// Every connected input's stream ended and was read to its end.
    fn inputs_exhausted(&self) -> bool {
        let inputs = self.ctx.inputs();
        self.has_connected_inputs()
            && inputs
                .iter()
                .enumerate()
                .filter(|(_, port)| port.is_connected())
                .all(|(index, _)| self.ctx.is_input_exhausted(index))
    }

    /// Ends the member's calls in `state`; a finished one closes its outputs so that its readers finish
    /// in turn.
    fn finish(&mut self, state: ComponentState) {
        self.done = true;
        if matches!(state, ComponentState::Finished) {
            for buffer in self.ctx.output_buffers() {
                buffer.close();
            }
        }
        if !self.monitor.is_failed() {
            self.monitor.set_state(state);
        }
    }

    /// Whether the member waits for a pass: ready, and neither periodic (its ticks call it) nor the
    /// driver (called at every turn) nor done.
    fn wants_pass(&self) -> bool {
        !self.done && !self.drives && self.next_tick.is_none() && self.ready.load(Ordering::SeqCst)
    }

    /// One `core` call, its time added to the member's, its outcome applied.
    fn call(&mut self) -> Called {
        let started = Instant::now();
        self.ctx.begin_cycle();
        let result = guarded(|| self.component.core(&mut self.ctx));
        let now = Instant::now();
        self.status
            .after_core(self.component.as_ref(), &self.ctx, false, now);
        let nanos = u64::try_from(now.duration_since(started).as_nanos()).unwrap_or(u64::MAX);
        self.monitor.busy_nanos.fetch_add(nanos, Ordering::Relaxed);
        let mut more = false;
        match result {
            Ok(()) => {
                self.monitor.cycles.fetch_add(1, Ordering::Relaxed);
                // Called again only for what is already there: a call to find nothing costs as much as
                // one that works.
                more = self.ctx.samples_read_this_cycle() > 0 && self.ctx.has_unread_input();
            }
            Err(ComponentError::Stopped) => self.finish(ComponentState::Stopped),
            Err(ComponentError::EndOfStream) => self.finish(ComponentState::Finished),
            Err(ComponentError::Interrupted | ComponentError::NoData) => {}
            Err(failure) => {
                self.monitor.fail(&self.id, "core", &failure.to_string());
                self.done = true;
            }
        }
        Called {
            more: more && !self.done,
            nanos,
        }
    }
}

/// What a call did.
#[derive(Clone, Copy)]
struct Called {
    /// It read a sample, ended well, and more samples wait for it.
    more: bool,
    /// Its wall time.
    nanos: u64,
}

/// A group ready to start: its members in the order they run, and its thread's settings.
pub(crate) struct GroupRun {
    pub(crate) shared: Arc<GroupShared>,
    pub(crate) settings: ThreadSettings,
    pub(crate) members: Vec<Member>,
    pub(crate) clock: Arc<dyn Clock>,
    pub(crate) gate: Option<Arc<StartGate>>,
}

impl GroupRun {
    /// The group's thread: births, passes until every member is done or a stop, deaths.
    pub(crate) fn run(mut self) {
        let shared = Arc::clone(&self.shared);
        let _ = shared.thread.set(std::thread::current());
        for member in &self.members {
            member.signal.bind_current_thread();
        }
        scheduling::apply_to_current_thread(&format!("group {}", shared.name), &self.settings);
        let span = tracing::info_span!("group", name = %shared.name);
        let _entered = span.enter();
        let cpu_start = scheduling::thread_cpu_nanos();
        self.births();
        let mut cpu_checked = Instant::now();
        let mut exhaustion_checked = Instant::now();
        let mut paused = false;
        while let Some(first) = self.members.first() {
            if first.signal.stop_requested() {
                break;
            }
            if first.signal.is_paused() {
                if !paused {
                    paused = true;
                    self.set_running_state(&ComponentState::Paused);
                }
                std::thread::park_timeout(Duration::from_millis(100));
                continue;
            }
            if paused {
                paused = false;
                self.set_running_state(&ComponentState::Running);
                self.after_pause();
            }
            self.apply_controls();
            if let Some(driver) = self.members.iter_mut().find(|m| m.drives && !m.done) {
                let _ = driver.call();
            }
            let more = self.passes_until_quiet();
            let now = Instant::now();
            if now.saturating_duration_since(exhaustion_checked) >= EXHAUSTION_CHECK {
                exhaustion_checked = now;
                self.finish_exhausted();
            }
            if now.saturating_duration_since(cpu_checked) >= CPU_SAMPLE_PERIOD {
                cpu_checked = now;
                shared.cpu_nanos.store(
                    scheduling::thread_cpu_nanos().saturating_sub(cpu_start),
                    Ordering::Relaxed,
                );
            }
            if self.members.iter().all(|m| m.done) {
                break;
            }
            if !more && !self.members.iter().any(|m| m.drives && !m.done) {
                self.sleep_until_work();
            }
        }
        self.deaths();
        shared.cpu_nanos.store(
            scheduling::thread_cpu_nanos().saturating_sub(cpu_start),
            Ordering::Relaxed,
        );
    }

    /// Every member's birth, in order; then the start gate, passed once for all of them.
    fn births(&mut self) {
        for member in &mut self.members {
            member.monitor.set_state(ComponentState::Running);
            if let Err(error) = guarded(|| member.component.birth(&mut member.ctx)) {
                member.monitor.fail(&member.id, "birth", &error.to_string());
                member.done = true;
                continue;
            }
            if member.mode == ExecutionMode::Periodic && !member.drives {
                if member.ctx.period().is_none() {
                    member.monitor.fail(
                        &member.id,
                        "birth",
                        "a periodic component must set its period (ctx.set_frequency)",
                    );
                    member.done = true;
                    continue;
                }
                member.next_tick = Some(self.clock.now());
            }
        }
        if let Some(gate) = self.gate.take() {
            let Some((last, others)) = self.members.split_last() else {
                return;
            };
            for member in others {
                gate.arrive(&member.id);
            }
            gate.arrive_and_wait(&last.id, &last.signal);
        }
        // Samples may have arrived during the births, while no one was marked.
        for member in &self.members {
            member.ready.store(true, Ordering::SeqCst);
        }
        let now = self.clock.now();
        for member in &mut self.members {
            if member.next_tick.is_some() {
                member.next_tick = Some(now);
            }
        }
    }

    fn set_running_state(&self, state: &ComponentState) {
        for member in self.members.iter().filter(|m| !m.done) {
            if !member.monitor.is_failed() {
                member.monitor.set_state(state.clone());
            }
        }
    }

    /// Back from a pause: ticks start again from now, and whatever arrived meanwhile is read.
    fn after_pause(&mut self) {
        let now = self.clock.now();
        for member in &mut self.members {
            if member.next_tick.is_some() {
                member.next_tick = Some(now);
            }
            member.ready.store(true, Ordering::SeqCst);
        }
    }

    fn apply_controls(&mut self) {
        for member in self.members.iter_mut().filter(|m| !m.done) {
            if member.signal.take_control()
                && !apply_controls(
                    &member.id,
                    member.component.as_mut(),
                    &mut member.ctx,
                    &member.monitor,
                )
            {
                member.done = true;
            }
        }
    }

    /// Passes while samples wait for members, [`PASSES_PER_TURN`] at most; whether some still wait.
    /// A periodic member runs once a pass when due: only samples call for another pass.
    fn passes_until_quiet(&mut self) -> bool {
        for _ in 0..PASSES_PER_TURN {
            self.shared.in_pass.store(true, Ordering::SeqCst);
            self.pass();
            self.shared.in_pass.store(false, Ordering::SeqCst);
            if !self.members.iter().any(Member::wants_pass) {
                return false;
            }
        }
        true
    }

    /// One pass over the members in order.
    fn pass(&mut self) {
        let started = Instant::now();
        let now = self.clock.now();
        let mut worked = false;
        let mut slowest: Option<(usize, u64)> = None;
        let mut late: Vec<(usize, u64, Duration)> = Vec::new();
        for (index, member) in self.members.iter_mut().enumerate() {
            if member.done || member.drives {
                continue;
            }
            let mut spent = 0;
            let mut called = false;
            if let Some(tick) = member.next_tick {
                if now >= tick {
                    member.ready.store(false, Ordering::Relaxed);
                    spent = member.call().nanos;
                    called = true;
                    if let Some(period) = member.ctx.period() {
                        let (next, skipped) = next_tick(tick, period, self.clock.now());
                        member.next_tick = Some(next);
                        if skipped > 0 {
                            late.push((index, skipped, period));
                        }
                    }
                }
            } else if member.ready.load(Ordering::Relaxed) && member.ready.swap(false, Ordering::SeqCst) {
                called = true;
                for calls in 1..=CALLS_PER_PASS {
                    let outcome = member.call();
                    spent += outcome.nanos;
                    if !outcome.more {
                        break;
                    }
                    if calls == CALLS_PER_PASS {
                        // More is waiting: the next pass goes on with it.
                        member.ready.store(true, Ordering::SeqCst);
                    }
                }
            }
            if called {
                worked = true;
                if slowest.is_none_or(|(_, longest)| spent > longest) {
                    slowest = Some((index, spent));
                }
            }
        }
        if worked {
            self.account_pass(started, slowest, &late);
        }
    }

    /// Adds a pass to the group's statistics; says which members missed ticks, and who took the time.
    fn account_pass(
        &mut self,
        started: Instant,
        slowest: Option<(usize, u64)>,
        late: &[(usize, u64, Duration)],
    ) {
        let shared = &self.shared;
        let spent = u64::try_from(started.elapsed().as_nanos()).unwrap_or(u64::MAX);
        shared.passes.fetch_add(1, Ordering::Relaxed);
        shared.pass_nanos.fetch_add(spent, Ordering::Relaxed);
        let slowest_id =
            slowest.and_then(|(index, nanos)| Some((self.members.get(index)?.id.clone(), nanos)));
        if spent > shared.longest_pass_nanos.fetch_max(spent, Ordering::Relaxed) {
            lock(&shared.slowest).clone_from(&slowest_id);
        }
        for &(index, skipped, period) in late {
            shared.missed_ticks.fetch_add(skipped, Ordering::Relaxed);
            let Some(member) = self.members.get_mut(index) else {
                continue;
            };
            member.monitor.missed_ticks.fetch_add(skipped, Ordering::Relaxed);
            let culprit = slowest_id
                .as_ref()
                .map(|(id, nanos)| {
                    format!(
                        "; the slowest member of the pass was '{id}' ({:.1} ms)",
                        *nanos as f64 * 1e-6
                    )
                })
                .unwrap_or_default();
            member.missed.skipped(
                &member.id,
                skipped,
                period,
                &format!("in group '{}'{culprit}", shared.name),
            );
        }
    }

    /// Members whose every input ended finish, and close their outputs for the members after them.
    fn finish_exhausted(&mut self) {
        for member in &mut self.members {
            if member.done || member.next_tick.is_some() || member.drives {
                continue;
            }
            if member.inputs_exhausted() {
                // What arrived before the end is read first.
                while member.call().more {}
                if !member.done {
                    member.finish(ComponentState::Finished);
                }
            }
        }
    }

    /// Sleeps until the next periodic tick, a sample from outside, or the engine's call.
    fn sleep_until_work(&self) {
        let next_tick = self
            .members
            .iter()
            .filter(|m| !m.done)
            .filter_map(|m| m.next_tick)
            .min();
        let mut timeout = EXHAUSTION_CHECK;
        if let Some(tick) = next_tick {
            let now = self.clock.now();
            if tick <= now {
                return;
            }
            // Simulated time run as fast as possible: nothing happens in between, so time moves on.
            if self.clock.jumps()
                && let Some(first) = self.members.first()
            {
                self.clock.wait_until(tick, &first.signal);
                return;
            }
            timeout = timeout.min(tick.duration_since(now));
        }
        std::thread::park_timeout(timeout);
    }

    fn deaths(&mut self) {
        let stopped = self.members.first().is_some_and(|m| m.signal.stop_requested());
        for member in &mut self.members {
            if let Err(error) = guarded(|| member.component.death(&mut member.ctx)) {
                member.monitor.fail(&member.id, "death", &error.to_string());
            }
            member.status.at_end(member.component.as_ref(), &member.ctx);
            if !member.done {
                member.finish(if stopped {
                    ComponentState::Stopped
                } else {
                    ComponentState::Finished
                });
            }
        }
    }
}

/// The tick after `tick` and how many were skipped: fallen more than a period behind, a member skips
/// the missed ticks rather than run them back to back.
fn next_tick(tick: Timestamp, period: Duration, now: Timestamp) -> (Timestamp, u64) {
    let next = tick.after(period);
    let behind = now.nanos_since(next);
    let period_nanos = i64::try_from(period.as_nanos()).unwrap_or(i64::MAX).max(1);
    if behind <= period_nanos {
        return (next, 0);
    }
    (now, (behind / period_nanos) as u64)
}

/// The order a group's members run in: the order of the links between them (a producer before its
/// readers), ties and anything the links leave free in the diagram's order. A link into a member that
/// `holds` its inputs (a simulator reading its commands at its ticks) does not order it, so a loop may
/// close through it. Validation refuses other loops inside a group; were one there, its members would
/// follow in the diagram's order.
pub(crate) fn run_order(
    diagram: &kairos_diagram::Diagram,
    members: &[String],
    holds: &dyn Fn(&str) -> bool,
) -> Vec<String> {
    use std::collections::{BTreeMap, BTreeSet};
    let position: BTreeMap<&str, usize> = members
        .iter()
        .enumerate()
        .map(|(index, id)| (id.as_str(), index))
        .collect();
    let mut feeds: Vec<BTreeSet<usize>> = vec![BTreeSet::new(); members.len()];
    let mut fed_by = vec![0_usize; members.len()];
    for connection in &diagram.connections {
        let (Some(&from), Some(&to)) = (
            position.get(connection.from.component.as_str()),
            position.get(connection.to.component.as_str()),
        ) else {
            continue;
        };
        if from != to
            && !holds(&connection.to.component)
            && let Some(targets) = feeds.get_mut(from)
            && targets.insert(to)
            && let Some(count) = fed_by.get_mut(to)
        {
            *count += 1;
        }
    }
    // Kahn's algorithm, always taking the earliest free member in the diagram's order.
    let mut free: BTreeSet<usize> = (0..members.len())
        .filter(|&i| fed_by.get(i) == Some(&0))
        .collect();
    let mut order = Vec::with_capacity(members.len());
    let mut placed = vec![false; members.len()];
    while let Some(next) = free.pop_first() {
        order.push(next);
        if let Some(slot) = placed.get_mut(next) {
            *slot = true;
        }
        for &target in feeds.get(next).into_iter().flatten() {
            if let Some(count) = fed_by.get_mut(target) {
                *count -= 1;
                if *count == 0 {
                    free.insert(target);
                }
            }
        }
    }
    order.extend((0..members.len()).filter(|&i| !placed.get(i).copied().unwrap_or(true)));
    order
        .into_iter()
        .filter_map(|i| members.get(i).cloned())
        .collect()
}

#[cfg(test)]
mod tests {
    use kairos_diagram::{ComponentInstance, Connection, Diagram, PortRef};

    use super::*;

    fn chain(ids: &[&str], links: &[(&str, &str)]) -> (Diagram, Vec<String>) {
        let mut diagram = Diagram::default();
        for id in ids {
            diagram.components.push(ComponentInstance::new(*id, "core.gain"));
        }
        for (from, to) in links {
            diagram.connections.push(Connection::new(
                PortRef::new(*from, "out"),
                PortRef::new(*to, "in"),
            ));
        }
        (diagram, ids.iter().map(|id| (*id).to_owned()).collect())
    }

    #[test]
    fn members_run_producers_first_and_otherwise_in_the_diagram_s_order() {
        let (diagram, members) = chain(
            &["sink", "gain2", "gain1", "source", "lone"],
            &[("source", "gain1"), ("gain1", "gain2"), ("gain2", "sink")],
        );
        assert_eq!(
            run_order(&diagram, &members, &|_| false),
            ["source", "gain1", "gain2", "sink", "lone"]
        );
    }

    #[test]
    fn a_loop_that_slipped_past_validation_keeps_every_member() {
        let (diagram, members) = chain(&["a", "b", "c"], &[("a", "b"), ("b", "a"), ("c", "a")]);
        assert_eq!(run_order(&diagram, &members, &|_| false), ["c", "a", "b"]);
    }

    #[test]
    fn a_loop_closes_through_a_member_that_holds_its_inputs_which_runs_first() {
        // A simulator feeds a camera, whose processing feeds the simulator's commands back.
        let (diagram, members) = chain(
            &["controller", "camera", "vehicle"],
            &[
                ("vehicle", "camera"),
                ("camera", "controller"),
                ("controller", "vehicle"),
            ],
        );
        assert_eq!(
            run_order(&diagram, &members, &|id| id == "vehicle"),
            ["vehicle", "camera", "controller"]
        );
    }

    #[test]
    fn a_member_far_behind_skips_its_missed_ticks_and_counts_them() {
        let period = Duration::from_millis(10);
        let tick = Timestamp(0);
        assert_eq!(
            next_tick(tick, period, Timestamp(5_000_000)),
            (Timestamp(10_000_000), 0)
        );
        let (next, skipped) = next_tick(tick, period, Timestamp(45_000_000));
        assert_eq!((next, skipped), (Timestamp(45_000_000), 3));
    }
}
