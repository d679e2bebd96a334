//! The engine running real diagrams: failures stay contained, controls apply live, stop joins all.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use std::sync::Arc;
use std::thread::sleep;
use std::time::{Duration, Instant};

mod common;

use common::{component, connect, diagram, eventually, stats};
use kairos_diagram::Value;
use kairos_runtime::{ComponentState, ControlError, Engine, EngineState, StatsSnapshot};
use kairos_sdk_core::descriptor::Descriptor;
use kairos_sdk_core::{
    Component, ComponentResult, Context, DataType, Payload, RealTimeClock, Registry, TypeFilter,
};

/// Panics on the third sample it reads.
#[derive(Default)]
struct PanicsOnThird {
    seen: u32,
}

impl Component for PanicsOnThird {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        self.seen += 1;
        assert!(self.seen < 3, "third sample");
        ctx.forward("out", &sample)
    }
}

/// Panics when made.
struct PanicsWhenMade;

impl Default for PanicsWhenMade {
    fn default() -> Self {
        panic!("no instance today");
    }
}

impl Component for PanicsWhenMade {
    fn core(&mut self, _ctx: &mut Context) -> ComponentResult {
        Ok(())
    }
}

/// Periodic at 1 kHz, each cycle taking 5 ms: it cannot keep its rate.
#[derive(Default)]
struct SlowerThanItsPeriod;

impl Component for SlowerThanItsPeriod {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        ctx.set_period(Duration::from_millis(1));
        Ok(())
    }

    fn core(&mut self, _ctx: &mut Context) -> ComponentResult {
        sleep(Duration::from_millis(5));
        Ok(())
    }
}

/// What `SlowRecorder` read, in order (only one test uses it).
static RECORDED: std::sync::Mutex<Vec<i64>> = std::sync::Mutex::new(Vec::new());

/// Takes 2 ms per sample and records the values it reads.
#[derive(Default)]
struct SlowRecorder;

impl Component for SlowRecorder {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        sleep(Duration::from_millis(2));
        if let Payload::I64(value) = sample.payload {
            RECORDED.lock().unwrap().push(value);
        }
        Ok(())
    }
}

/// Each cycle takes 50 ms; it has a live property.
#[derive(Default)]
struct BusyCycles;

impl Component for BusyCycles {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        ctx.set_period(Duration::from_millis(10));
        Ok(())
    }

    fn core(&mut self, _ctx: &mut Context) -> ComponentResult {
        sleep(Duration::from_millis(50));
        Ok(())
    }
}

/// Periodic at 1 kHz: writes a burst of 200 samples, then nothing, and stays running.
#[derive(Default)]
struct BurstThenQuiet {
    written: u32,
}

impl Component for BurstThenQuiet {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        ctx.set_period(Duration::from_millis(1));
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        if self.written < 200 {
            self.written += 1;
            ctx.write("out", Payload::F64(f64::from(self.written)))?;
        }
        Ok(())
    }
}

/// Counts what it reads and says so in its status, which it leaves to the runtime to publish.
#[derive(Default)]
struct CountsInItsStatus {
    read: u64,
}

impl Component for CountsInItsStatus {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        ctx.read("in")?;
        self.read += 1;
        Ok(())
    }

    fn status(&self) -> Option<serde_json::Value> {
        Some(serde_json::json!({ "read": self.read }))
    }
}

/// Takes 2 ms per sample and forwards it: slower than a 1 kHz source.
#[derive(Default)]
struct SlowCopy;

impl Component for SlowCopy {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        sleep(Duration::from_millis(2));
        ctx.forward("out", &sample)
    }
}

/// Periodic, with an input it never reads: a consumer that is stuck as far as its links can tell.
#[derive(Default)]
struct NeverReads;

impl Component for NeverReads {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        ctx.set_period(Duration::from_millis(10));
        Ok(())
    }

    fn core(&mut self, _ctx: &mut Context) -> ComponentResult {
        Ok(())
    }
}

/// Reads `a` alone, though `b` is fed too: `b`'s samples wait for a read that never comes.
#[derive(Default)]
struct ReadsOnlyA;

impl Component for ReadsOnlyA {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        ctx.read("a")?;
        Ok(())
    }
}

fn registry() -> Registry {
    let mut registry = Registry::new();
    kairos_pack_core::register(&mut registry);
    registry
        .pack("faulty", "1.0.0", "test")
        .component::<PanicsWhenMade>(
            Descriptor::new("faulty.panics_when_made", "test", "Panics when made").build(),
        )
        .component::<SlowerThanItsPeriod>(
            Descriptor::new("faulty.slower_than_its_period", "test", "Cycles of 5 ms at 1 kHz")
                .mode(kairos_sdk_core::ExecutionMode::Periodic)
                .build(),
        )
        .component::<BusyCycles>(
            Descriptor::new("faulty.busy", "test", "Cycles of 50 ms")
                .mode(kairos_sdk_core::ExecutionMode::Periodic)
                .property(kairos_sdk_core::descriptor::Property::f64("level", 1.0).live())
                .build(),
        )
        .component::<SlowRecorder>(
            Descriptor::new(
                "faulty.slow_recorder",
                "test",
                "Records what it reads, 2 ms a sample",
            )
            .input_with_policy(
                "in",
                TypeFilter::Any,
                kairos_diagram::ReaderPolicy::LastOrNext,
                "",
            )
            .build(),
        )
        .component::<BurstThenQuiet>(
            Descriptor::new(
                "faulty.burst_then_quiet",
                "test",
                "200 samples at 1 kHz, then none",
            )
            .mode(kairos_sdk_core::ExecutionMode::Periodic)
            .output("out", DataType::F64, "")
            .build(),
        )
        .component::<CountsInItsStatus>(
            Descriptor::new("faulty.counts", "test", "Counts what it reads in its status")
                .input("in", TypeFilter::Any, "")
                .build(),
        )
        .component::<SlowCopy>(
            Descriptor::new("faulty.slow_copy", "test", "Forwards, 2 ms a sample")
                .input_with_policy(
                    "in",
                    TypeFilter::Any,
                    kairos_diagram::ReaderPolicy::NeverSkipping,
                    "",
                )
                .output("out", DataType::F64, "")
                .build(),
        )
        .component::<NeverReads>(
            Descriptor::new("faulty.never_reads", "test", "Never reads its input")
                .mode(kairos_sdk_core::ExecutionMode::Periodic)
                .input("in", TypeFilter::Any, "")
                .build(),
        )
        .component::<ReadsOnlyA>(
            Descriptor::new("faulty.reads_only_a", "test", "Reads its input a, never b")
                .input("a", TypeFilter::Any, "")
                .input("b", TypeFilter::Any, "")
                .build(),
        )
        .component::<PanicsOnThird>(
            Descriptor::new("faulty.panics_on_third", "test", "Panics on its third sample")
                .input("in", TypeFilter::Any, "")
                .output("out", DataType::F64, "")
                .build(),
        );
    registry
}

fn state_of(snapshot: &StatsSnapshot, id: &str) -> ComponentState {
    stats(snapshot, id).state.clone()
}

fn written(snapshot: &StatsSnapshot, link: &str) -> u64 {
    snapshot
        .links
        .iter()
        .find(|l| l.link == link)
        .unwrap()
        .counters
        .written
}

fn cycles(snapshot: &StatsSnapshot, id: &str) -> u64 {
    stats(snapshot, id).cycles
}

/// The first sample `tap` gives that `wanted` accepts, waited for.
fn sample_from(
    tap: &mut kairos_sdk_core::host::Reader,
    wanted: impl Fn(&kairos_sdk_core::Sample) -> bool,
) -> kairos_sdk_core::Sample {
    let mut found = None;
    eventually("the sample wanted", || {
        found = tap.try_read().filter(&wanted);
        found.is_some()
    });
    found.unwrap()
}

#[test]
fn a_panicking_constructor_fails_its_component_alone() {
    let d = diagram(
        vec![
            component("unmade", "faulty.panics_when_made", &[]),
            component("source", "core.sine", &[("rate", Value::F64(200.0))]),
            component("gain", "core.gain", &[]),
        ],
        vec![connect("source.out", "gain.in")],
    );
    let mut engine = Engine::build(&d, &registry(), RealTimeClock::shared()).unwrap();
    engine.start().unwrap();
    eventually("'unmade' fails and the source writes", || {
        let snapshot = engine.snapshot();
        matches!(state_of(&snapshot, "unmade"), ComponentState::Failed(_))
            && written(&snapshot, "source.out -> gain.in") > 10
    });
    let snapshot = engine.snapshot();
    match state_of(&snapshot, "unmade") {
        ComponentState::Failed(message) => assert!(
            message.contains("its constructor panicked: no instance today"),
            "{message}"
        ),
        other => panic!("expected failed, got {other:?}"),
    }
    assert_eq!(state_of(&snapshot, "gain"), ComponentState::Running);
    engine.stop();
}

#[test]
fn a_panicking_component_fails_alone_and_the_rest_keeps_running() {
    let rate = Value::F64(200.0);
    let d = diagram(
        vec![
            component("source", "core.sine", &[("rate", rate.clone())]),
            component("bad", "faulty.panics_on_third", &[]),
            component("other", "core.sine", &[("rate", rate)]),
            component("gain", "core.gain", &[]),
        ],
        vec![connect("source.out", "bad.in"), connect("other.out", "gain.in")],
    );
    let mut engine = Engine::build(&d, &registry(), RealTimeClock::shared()).unwrap();
    engine.start().unwrap();
    eventually("'bad' fails on its third sample", || {
        matches!(state_of(&engine.snapshot(), "bad"), ComponentState::Failed(_))
    });
    // The healthy chain and the failed one's producer run on: 50 more cycles each (a quarter of a second
    // at 200 Hz on a fast machine), waited for twice, the first time for the failed reader to leave.
    let ran_on = |since: &StatsSnapshot| {
        let mut now = engine.snapshot();
        eventually("the rest runs on", || {
            now = engine.snapshot();
            written(&now, "other.out -> gain.in") > written(since, "other.out -> gain.in") + 50
                && ["source", "other", "gain"]
                    .into_iter()
                    .all(|id| cycles(&now, id) > cycles(since, id) + 50)
        });
        now
    };
    let before = ran_on(&engine.snapshot());
    match state_of(&before, "bad") {
        ComponentState::Failed(message) => assert!(message.contains("third sample"), "{message}"),
        other => panic!("expected failed, got {other:?}"),
    }
    let after = ran_on(&before);
    assert_eq!(state_of(&after, "gain"), ComponentState::Running);
    // The failed reader left its link: its counts froze where it failed.
    assert_eq!(
        written(&after, "source.out -> bad.in"),
        written(&before, "source.out -> bad.in")
    );
    engine.stop();
    let last = engine.snapshot();
    assert!(matches!(state_of(&last, "bad"), ComponentState::Failed(_)));
    assert_eq!(state_of(&last, "gain"), ComponentState::Stopped);
    for link in &last.links {
        assert!(link.counters.balanced(), "{link:?}");
    }
}

#[test]
fn live_property_changes_apply_and_bad_values_keep_the_old_one() {
    let d = diagram(
        vec![
            component(
                "constant",
                "core.constant",
                &[("rate", Value::F64(200.0)), ("value", Value::F64(1.0))],
            ),
            component("gain", "core.gain", &[("gain", Value::F64(2.0))]),
            component("avg", "core.moving_average", &[("window", Value::I64(1))]),
        ],
        vec![connect("constant.out", "gain.in"), connect("gain.out", "avg.in")],
    );
    let mut engine = Engine::build(&d, &registry(), RealTimeClock::shared()).unwrap();
    let mut tap = engine.output_buffer("gain", "out").unwrap().attach(
        kairos_sdk_core::host::ReaderConfig::new(kairos_diagram::ReaderPolicy::Sampling, "tap"),
        Arc::new(kairos_sdk_core::RunSignal::new()),
    );
    engine.start().unwrap();
    assert_eq!(sample_from(&mut tap, |_| true).payload, Payload::F64(2.0));

    engine.set_property("gain", "gain", &Value::F64(5.0)).unwrap();
    let applied = sample_from(&mut tap, |s| s.payload == Payload::F64(5.0));

    // A value of the wrong type, an unknown property, a property that is not live: refused, nothing changes.
    assert!(matches!(
        engine.set_property("gain", "gain", &Value::Text("loud".into())),
        Err(ControlError::InvalidValue { .. })
    ));
    assert!(matches!(
        engine.set_property("gain", "gian", &Value::F64(1.0)),
        Err(ControlError::UnknownProperty { .. })
    ));
    assert!(matches!(
        engine.set_property("csv", "gain", &Value::F64(1.0)),
        Err(ControlError::UnknownComponent(_))
    ));
    assert!(matches!(
        engine.set_property("avg", "window", &Value::I64(0)),
        Err(ControlError::InvalidValue { .. })
    ));
    // A sample made after them still has the gain of 5.
    let later = sample_from(&mut tap, |s| s.sequence > applied.sequence);
    assert_eq!(later.payload, Payload::F64(5.0));
    engine.stop();
}

#[test]
fn actions_reach_the_component() {
    let mut counter = component("counter", "core.counter", &[("rate", Value::F64(200.0))]);
    // Room for the tap below to hold the whole run: a ring is sized when the diagram is built.
    counter.outputs.insert(
        "out".into(),
        kairos_diagram::OutputSettings {
            buffer_size: Some(4096),
            subsampling: None,
        },
    );
    let d = diagram(vec![counter], vec![]);
    let mut engine = Engine::build(&d, &registry(), RealTimeClock::shared()).unwrap();
    let mut tap_config = kairos_sdk_core::host::ReaderConfig::new(kairos_diagram::ReaderPolicy::Fifo, "tap");
    tap_config.capacity = Some(4096);
    let mut tap = engine
        .output_buffer("counter", "out")
        .unwrap()
        .attach(tap_config, Arc::new(kairos_sdk_core::RunSignal::new()));
    engine.start().unwrap();
    eventually("the counter counts past 11", || {
        cycles(&engine.snapshot(), "counter") > 11
    });
    engine.trigger_action("counter", "reset").unwrap();
    let reset_at = cycles(&engine.snapshot(), "counter");
    eventually("the counter counts again", || {
        cycles(&engine.snapshot(), "counter") > reset_at + 2
    });
    engine.stop();
    let values: Vec<i64> = std::iter::from_fn(|| tap.try_read())
        .map(|s| if let Payload::I64(v) = s.payload { v } else { -1 })
        .collect();
    let restart = values
        .iter()
        .skip(1)
        .position(|v| *v == 0)
        .expect("the count restarted from 0");
    assert!(restart > 10, "{values:?}");
    assert!(matches!(
        engine.trigger_action("counter", "explode"),
        Err(ControlError::UnknownAction { .. })
    ));
}

#[test]
fn pause_holds_sources_and_resume_restarts_them() {
    let d = diagram(
        vec![
            component("sine", "core.sine", &[("rate", Value::F64(500.0))]),
            component("gain", "core.gain", &[]),
        ],
        vec![connect("sine.out", "gain.in")],
    );
    let mut engine = Engine::build(&d, &registry(), RealTimeClock::shared()).unwrap();
    engine.start().unwrap();
    sleep(Duration::from_millis(100));
    engine.pause();
    assert_eq!(engine.state(), EngineState::Paused);
    eventually("the sine pauses", || {
        state_of(&engine.snapshot(), "sine") == ComponentState::Paused
    });
    let paused = written(&engine.snapshot(), "sine.out -> gain.in");
    sleep(Duration::from_millis(200));
    assert_eq!(
        written(&engine.snapshot(), "sine.out -> gain.in"),
        paused,
        "nothing is written while paused"
    );
    assert_eq!(state_of(&engine.snapshot(), "sine"), ComponentState::Paused);
    engine.resume();
    eventually("the sine writes again", || {
        written(&engine.snapshot(), "sine.out -> gain.in") > paused + 20
    });
    engine.stop();
    assert_eq!(engine.state(), EngineState::Stopped);
}

#[test]
fn simulated_time_stands_still_while_the_diagram_is_paused() {
    let d = diagram(
        vec![component("sine", "core.sine", &[("rate", Value::F64(100.0))])],
        vec![],
    );
    let start = kairos_sdk_core::Timestamp::from_secs_f64(1_767_225_600.0);
    let clock: Arc<dyn kairos_sdk_core::Clock> = Arc::new(kairos_sdk_core::SimulatedClock::new(start, 1.0));
    let mut engine = Engine::build(&d, &registry(), Arc::clone(&clock)).unwrap();
    engine.start().unwrap();
    sleep(Duration::from_millis(100));
    engine.pause();
    let paused = clock.now();
    sleep(Duration::from_millis(300));
    assert!(
        clock.now().nanos_since(paused) < 50_000_000,
        "simulated time went on while paused"
    );
    engine.resume();
    sleep(Duration::from_millis(100));
    assert!(clock.now().nanos_since(paused) >= 90_000_000, "and goes on after");
    engine.stop();
}

#[test]
fn an_invalid_diagram_is_refused_with_every_problem() {
    let d = diagram(
        vec![
            component("a", "core.nothing", &[]),
            component("b", "core.gain", &[("gain", Value::Text("x".into()))]),
        ],
        vec![],
    );
    let error = Engine::build(&d, &registry(), RealTimeClock::shared()).unwrap_err();
    let message = error.to_string();
    assert!(
        message.contains("core.nothing") && message.contains("gain"),
        "{message}"
    );
}

#[test]
fn stop_joins_components_blocked_on_never_skipping_and_silent_inputs() {
    let mut slow = connect("sine.out", "gain.in");
    slow.policy = Some(kairos_diagram::ReaderPolicy::NeverSkipping);
    let d = diagram(
        vec![
            component("sine", "core.sine", &[("rate", Value::F64(1000.0))]),
            component("gain", "core.gain", &[]),
            component("idle", "core.console", &[]),
        ],
        vec![slow],
    );
    let mut engine = Engine::build(&d, &registry(), RealTimeClock::shared()).unwrap();
    engine.start().unwrap();
    sleep(Duration::from_millis(100));
    engine.stop();
    let last = engine.snapshot();
    assert!(
        last.components.iter().all(|c| c.state == ComponentState::Stopped),
        "{last:?}"
    );
}

#[test]
fn a_stop_lets_each_consumer_read_what_its_producers_wrote_first() {
    // sine (1 kHz) -> slow copy (2 ms a sample, NeverSkipping) -> counter: the copy is always behind.
    let mut behind = connect("sine.out", "copy.in");
    behind.buffer_size = Some(64);
    let d = diagram(
        vec![
            component("sine", "core.sine", &[("rate", Value::F64(1000.0))]),
            component("copy", "faulty.slow_copy", &[]),
            component("counts", "faulty.counts", &[]),
        ],
        vec![behind, connect("copy.out", "counts.in")],
    );
    let mut engine = Engine::build(&d, &registry(), RealTimeClock::shared()).unwrap();
    engine.start().unwrap();
    eventually("the copy falls behind", || {
        let snapshot = engine.snapshot();
        let link = snapshot
            .links
            .iter()
            .find(|l| l.link == "sine.out -> copy.in")
            .unwrap();
        link.counters.queued >= 32
    });
    engine.stop();
    let last = engine.snapshot();
    for link in &last.links {
        let counters = &link.counters;
        assert_eq!(counters.queued, 0, "{}: {counters:?}", link.link);
        assert_eq!(counters.read, counters.written, "{}: {counters:?}", link.link);
    }
    let copied = written(&last, "copy.out -> counts.in");
    assert_eq!(written(&last, "sine.out -> copy.in"), copied);
    assert_eq!(
        status_of(&last, "counts").unwrap()["read"],
        serde_json::json!(copied),
        "the last consumer read every sample the source wrote"
    );
}

#[test]
fn a_consumer_that_reads_nothing_holds_a_stop_for_the_drain_limit_only() {
    let d = diagram(
        vec![
            component("sine", "core.sine", &[("rate", Value::F64(1000.0))]),
            component("stuck", "faulty.never_reads", &[]),
        ],
        vec![connect("sine.out", "stuck.in")],
    );
    let mut engine = Engine::build(&d, &registry(), RealTimeClock::shared()).unwrap();
    engine.start().unwrap();
    eventually("samples queue up", || {
        engine.snapshot().links.iter().all(|l| l.counters.queued > 0)
    });
    let asked = Instant::now();
    engine.stop();
    let took = asked.elapsed();
    assert!(
        took >= kairos_runtime::engine::DRAIN_LIMIT,
        "the stop gave up before the drain limit: {took:?}"
    );
    assert!(
        took < kairos_runtime::engine::DRAIN_LIMIT * 3,
        "the stop took {took:?}"
    );
    let last = engine.snapshot();
    assert!(
        last.links
            .iter()
            .all(|l| l.counters.queued > 0 && l.counters.balanced()),
        "{last:?}"
    );
    assert_eq!(state_of(&last, "stuck"), ComponentState::Stopped);
}

#[test]
fn a_consumer_asleep_for_input_its_stopped_producers_will_never_write_does_not_hold_a_stop() {
    // `b` fills while the consumer waits on `a`, whose producer stops first: nothing more will come.
    let d = diagram(
        vec![
            component("slow", "core.sine", &[("rate", Value::F64(10.0))]),
            component("fast", "core.sine", &[("rate", Value::F64(1000.0))]),
            component("waits", "faulty.reads_only_a", &[]),
        ],
        vec![connect("slow.out", "waits.a"), connect("fast.out", "waits.b")],
    );
    let mut engine = Engine::build(&d, &registry(), RealTimeClock::shared()).unwrap();
    engine.start().unwrap();
    eventually("samples queue up on b", || {
        let snapshot = engine.snapshot();
        let link = snapshot
            .links
            .iter()
            .find(|l| l.link == "fast.out -> waits.b")
            .unwrap();
        link.counters.queued > 0
    });
    let asked = Instant::now();
    engine.stop();
    let took = asked.elapsed();
    assert!(
        took < kairos_runtime::engine::DRAIN_LIMIT / 2,
        "the stop waited {took:?} for a read that could not come"
    );
    let last = engine.snapshot();
    let b = last
        .links
        .iter()
        .find(|l| l.link == "fast.out -> waits.b")
        .unwrap();
    assert!(b.counters.queued > 0 && b.counters.balanced(), "{b:?}");
}

/// Doubles its input without a thread of its own.
#[derive(Default)]
struct ReactiveDouble;

impl Component for ReactiveDouble {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        let value = sample.payload.as_f64().unwrap_or_default();
        ctx.write_processed("out", &sample, Payload::F64(2.0 * value))
    }
}

#[test]
fn reactive_components_run_in_their_producer_and_output_subsampling_applies() {
    let mut registry = registry();
    registry
        .pack("reactive", "1.0.0", "test")
        .component::<ReactiveDouble>(
            Descriptor::new("reactive.double", "test", "Doubles, reactively")
                .mode(kairos_diagram::ExecutionMode::Reactive)
                .input("in", TypeFilter::Any, "")
                .output("out", DataType::F64, "")
                .build(),
        );
    let mut double = component("double", "reactive.double", &[]);
    double.outputs.insert(
        "out".into(),
        kairos_diagram::OutputSettings {
            // Room for the tap below to hold the whole run.
            buffer_size: Some(4096),
            subsampling: Some(2),
        },
    );
    let d = diagram(
        vec![
            component("counter", "core.counter", &[("rate", Value::F64(500.0))]),
            double,
            component("gain", "core.gain", &[]),
        ],
        vec![
            connect("counter.out", "double.in"),
            connect("double.out", "gain.in"),
        ],
    );
    let mut engine = Engine::build(&d, &registry, RealTimeClock::shared()).unwrap();
    let mut tap_config = kairos_sdk_core::host::ReaderConfig::new(kairos_diagram::ReaderPolicy::Fifo, "tap");
    tap_config.capacity = Some(4096);
    let mut tap = engine
        .output_buffer("double", "out")
        .unwrap()
        .attach(tap_config, Arc::new(kairos_sdk_core::RunSignal::new()));
    engine.start().unwrap();
    // 42 samples doubled, of which 21 are kept.
    eventually("the double runs 42 cycles", || {
        cycles(&engine.snapshot(), "double") >= 42
    });
    engine.stop();
    let values: Vec<f64> = std::iter::from_fn(|| tap.try_read())
        .filter_map(|s| s.payload.as_f64())
        .collect();
    // The counter writes 0, 1, 2, ...; doubled gives 0, 2, 4, ...; keeping one in two gives 0, 4, 8, ...
    assert!(values.len() > 20, "{values:?}");
    for (index, value) in values.iter().enumerate() {
        assert_eq!(*value as i64, 4 * index as i64, "{values:?}");
    }
    let snapshot = engine.snapshot();
    let double = snapshot.components.iter().find(|c| c.id == "double").unwrap();
    assert!(double.cycles as usize >= 2 * values.len() - 1, "{double:?}");
    assert_eq!(double.state, ComponentState::Stopped);
}

fn status_of(snapshot: &StatsSnapshot, id: &str) -> Option<serde_json::Value> {
    snapshot
        .components
        .iter()
        .find(|c| c.id == id)
        .unwrap()
        .status
        .clone()
}

#[test]
fn a_status_covers_everything_done_once_the_input_goes_quiet_and_at_stop() {
    let d = diagram(
        vec![
            component("burst", "faulty.burst_then_quiet", &[]),
            component("counter", "faulty.counts", &[]),
        ],
        vec![connect("burst.out", "counter.in")],
    );
    let mut engine = Engine::build(&d, &registry(), RealTimeClock::shared()).unwrap();
    engine.start().unwrap();
    // The burst lasts about 200 ms, less than a status period: without a publication when the input
    // goes quiet, the status would stay at what the first cycle said.
    let all = serde_json::json!({ "read": 200 });
    eventually("the status says all 200 were read", || {
        status_of(&engine.snapshot(), "counter") == Some(all.clone())
    });
    // Going quiet wakes the reader once, not in a loop.
    let quiet_cycles = cycles(&engine.snapshot(), "counter");
    sleep(Duration::from_millis(1_200));
    let later = cycles(&engine.snapshot(), "counter");
    assert!(
        later <= quiet_cycles + 1,
        "{quiet_cycles} cycles, then {later} while quiet"
    );
    engine.stop();
    assert_eq!(status_of(&engine.snapshot(), "counter"), Some(all));
}

#[test]
fn missed_periodic_ticks_are_counted() {
    let d = diagram(
        vec![
            component("slow", "faulty.slower_than_its_period", &[]),
            component("source", "core.sine", &[("rate", Value::F64(100.0))]),
        ],
        Vec::new(),
    );
    let mut engine = Engine::build(&d, &registry(), RealTimeClock::shared()).unwrap();
    engine.start().unwrap();
    eventually("the slow component runs 11 cycles", || {
        cycles(&engine.snapshot(), "slow") > 10
    });
    let snapshot = engine.snapshot();
    engine.stop();
    let missed = |id: &str| {
        snapshot
            .components
            .iter()
            .find(|c| c.id == id)
            .unwrap()
            .missed_ticks
    };
    // About 4 of every 5 ticks are skipped: each 5 ms cycle spans five 1 ms periods.
    let (slow_cycles, slow_missed) = (
        snapshot
            .components
            .iter()
            .find(|c| c.id == "slow")
            .unwrap()
            .cycles,
        missed("slow"),
    );
    assert!(
        slow_missed >= 2 * slow_cycles && slow_cycles > 10,
        "{slow_cycles} cycles, {slow_missed} missed"
    );
    // A 100 Hz sine with short cycles misses fewer (how many a loaded machine costs it is for the
    // benchmarks).
    assert!(
        missed("source") < slow_missed,
        "{} missed by the sine, {slow_missed} by the slow one",
        missed("source")
    );
    assert!(snapshot.table().contains("missed"), "{}", snapshot.table());
}

#[test]
fn an_overloaded_subsampled_reader_of_the_newest_reads_kept_samples_only_and_queues_within_its_share() {
    let mut counter = component("counter", "core.counter", &[("rate", Value::F64(2000.0))]);
    counter.outputs.insert(
        "out".into(),
        kairos_diagram::OutputSettings {
            buffer_size: Some(1),
            subsampling: None,
        },
    );
    let mut link = connect("counter.out", "slow.in");
    link.subsampling = Some(3);
    let d = diagram(
        vec![counter, component("slow", "faulty.slow_recorder", &[])],
        vec![link],
    );
    let mut engine = Engine::build(&d, &registry(), RealTimeClock::shared()).unwrap();
    // The ring holds the newest kept sample whatever the share: one in 3 needs 3 slots.
    assert!(engine.output_buffer("counter", "out").unwrap().slots() >= 3);
    engine.start().unwrap();
    // Snapshots along the run, until the reader has read 40 values (80 ms of 2 ms cycles on a fast
    // machine).
    let mut snapshots = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(30);
    while snapshots.len() < 10 || RECORDED.lock().unwrap().len() < 40 {
        assert!(
            Instant::now() < deadline,
            "the reader waited for fresh samples: {} read in 30 s",
            RECORDED.lock().unwrap().len()
        );
        sleep(Duration::from_millis(30));
        snapshots.push(engine.snapshot());
    }
    engine.stop();
    let values = RECORDED.lock().unwrap().clone();
    // Never a value that subsampling leaves out, in order.
    assert!(values.iter().all(|v| v % 3 == 0), "{values:?}");
    assert!(values.windows(2).all(|w| w[0] < w[1]), "{values:?}");
    for snapshot in &snapshots {
        let counters = &snapshot.links[0].counters;
        assert!(counters.balanced(), "{counters:?}");
        assert!(counters.queued <= 1, "queued beyond the share of 1: {counters:?}");
    }
}

#[test]
fn a_control_request_blocks_through_the_callers_wait_only_when_the_answer_is_not_there_at_once() {
    let d = diagram(
        vec![
            component("busy", "faulty.busy", &[]),
            component("source", "core.sine", &[("rate", Value::F64(100.0))]),
            component("gain", "core.gain", &[]),
        ],
        vec![connect("source.out", "gain.in")],
    );
    let mut engine = Engine::build(&d, &registry(), RealTimeClock::shared()).unwrap();
    engine.start().unwrap();
    sleep(Duration::from_millis(20));
    let long_waits = std::cell::Cell::new(0);
    let counting = |wait: &mut dyn FnMut()| {
        long_waits.set(long_waits.get() + 1);
        wait();
    };
    // A component in a 50 ms cycle answers after it: the caller is asked to block.
    engine
        .set_property_waiting("busy", "level", &Value::F64(2.0), &counting)
        .unwrap();
    assert_eq!(long_waits.get(), 1);
    // A component waiting for data answers at once: no blocking wait.
    let mut quick = 0;
    for attempt in 0..20 {
        long_waits.set(0);
        engine
            .set_property_waiting("gain", "gain", &Value::F64(f64::from(attempt)), &counting)
            .unwrap();
        quick += usize::from(long_waits.get() == 0);
    }
    engine.stop();
    assert!(quick >= 15, "{quick} of 20 answered without a blocking wait");
}

#[test]
fn a_control_request_to_a_component_whose_thread_ended_is_refused_at_once() {
    // Nothing feeds the gain: it stops at its first read.
    let d = diagram(vec![component("gain", "core.gain", &[])], Vec::new());
    let mut engine = Engine::build(&d, &registry(), RealTimeClock::shared()).unwrap();
    engine.start().unwrap();
    eventually("the gain stops", || {
        state_of(&engine.snapshot(), "gain") == ComponentState::Stopped
    });
    let long_waits = std::cell::Cell::new(0);
    let counting = |wait: &mut dyn FnMut()| {
        long_waits.set(long_waits.get() + 1);
        wait();
    };
    let refused = engine
        .set_property_waiting("gain", "gain", &Value::F64(3.0), &counting)
        .unwrap_err();
    engine.stop();
    assert!(refused.to_string().contains("has stopped"), "{refused}");
    assert_eq!(long_waits.get(), 0, "refused at once, without a blocking wait");
}
