//! Execution groups: members share one thread, run in the order of their links, lose nothing, and obey
//! stop, pause and live controls as threads do.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use std::sync::Mutex;
use std::thread::sleep;
use std::time::{Duration, Instant};

mod common;

use common::{connect, diagram, eventually, stats};
use kairos_diagram::{ComponentInstance, Diagram, ReaderPolicy, Value};
use kairos_runtime::{ComponentState, Engine};
use kairos_sdk_core::descriptor::Descriptor;
use kairos_sdk_core::{
    Component, ComponentError, ComponentResult, Context, DataType, Payload, RealTimeClock, Registry,
    TypeFilter,
};

/// A source that keeps its own time: writes `count` numbers as fast as it can, then its stream ends.
#[derive(Default)]
struct Burst {
    next: i64,
}

impl Component for Burst {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        if self.next >= ctx.i64_property("count")? {
            return Err(ComponentError::EndOfStream);
        }
        // A value that depends on the order of what came before: any reordering changes the outputs.
        ctx.write("out", Payload::I64(self.next * 7 % 13))?;
        self.next += 1;
        Ok(())
    }
}

/// What `Collect` instances read, by id.
static COLLECTED: Mutex<Vec<(String, f64)>> = Mutex::new(Vec::new());

/// Keeps every number it reads.
#[derive(Default)]
struct Collect;

impl Component for Collect {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        let value = match sample.payload {
            Payload::F64(value) => value,
            Payload::I64(value) => value as f64,
            _ => f64::NAN,
        };
        COLLECTED.lock().unwrap().push((ctx.id().to_owned(), value));
        Ok(())
    }
}

/// Periodic at 100 Hz, each cycle taking 30 ms: it holds its group's thread.
#[derive(Default)]
struct Slow;

impl Component for Slow {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        ctx.set_period(Duration::from_millis(10));
        Ok(())
    }

    fn core(&mut self, _ctx: &mut Context) -> ComponentResult {
        sleep(Duration::from_millis(30));
        Ok(())
    }
}

/// Panics on the third sample it reads.
#[derive(Default)]
struct PanicsOnThird {
    seen: u32,
}

impl Component for PanicsOnThird {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        ctx.read("in")?;
        self.seen += 1;
        assert!(self.seen < 3, "third sample");
        Ok(())
    }
}

/// Periodic at 100 Hz, writing five numbers in each cycle.
#[derive(Default)]
struct Flood;

impl Component for Flood {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        ctx.set_period(Duration::from_millis(10));
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        for n in 0..5 {
            ctx.write("out", Payload::I64(n))?;
        }
        Ok(())
    }
}

fn registry() -> Registry {
    let mut registry = Registry::new();
    kairos_pack_core::register(&mut registry);
    registry
        .pack("test", "1.0.0", "test")
        .component::<Burst>(
            Descriptor::new("test.burst", "test", "Numbers as fast as it can, then the end")
                .output("out", DataType::I64, "")
                .property(kairos_sdk_core::descriptor::Property::i64("count", 1000))
                .build(),
        )
        .component::<Collect>(
            Descriptor::new("test.collect", "test", "Keeps what it reads")
                .input("in", TypeFilter::Any, "")
                .build(),
        )
        .component::<PanicsOnThird>(
            Descriptor::new("test.panics_on_third", "test", "Panics on its third sample")
                .input("in", TypeFilter::Any, "")
                .build(),
        )
        .component::<Flood>(
            Descriptor::new("test.flood", "test", "Five numbers a cycle at 100 Hz")
                .mode(kairos_sdk_core::ExecutionMode::Periodic)
                .output("out", DataType::I64, "")
                .build(),
        )
        .component::<Slow>(
            Descriptor::new("test.slow", "test", "Cycles of 30 ms at 100 Hz")
                .mode(kairos_sdk_core::ExecutionMode::Periodic)
                .build(),
        );
    registry
}

/// [`common::component`], in `group` when given.
fn component(
    id: &str,
    type_name: &str,
    group: Option<&str>,
    properties: &[(&str, Value)],
) -> ComponentInstance {
    let mut instance = common::component(id, type_name, properties);
    instance.group = group.map(str::to_owned);
    instance
}

fn collected(id: &str) -> Vec<f64> {
    COLLECTED
        .lock()
        .unwrap()
        .iter()
        .filter(|(who, _)| who == id)
        .map(|(_, value)| *value)
        .collect()
}

/// A chain of sine → gain → gain → collect in one group.
fn grouped_chain(group: &str, sink: &str) -> Diagram {
    let g = Some(group);
    let mut d = diagram(
        vec![
            // Listed backwards: the group runs them in the order of their links, not of the file.
            component(sink, "test.collect", g, &[]),
            component(
                &format!("{group}_gain2"),
                "core.gain",
                g,
                &[("gain", Value::F64(-1.0))],
            ),
            component(
                &format!("{group}_gain1"),
                "core.gain",
                g,
                &[("gain", Value::F64(2.0))],
            ),
            component(
                &format!("{group}_source"),
                "core.counter",
                g,
                &[("rate", Value::F64(200.0))],
            ),
        ],
        Vec::new(),
    );
    d.connections = vec![
        connect(&format!("{group}_source.out"), &format!("{group}_gain1.in")),
        connect(&format!("{group}_gain1.out"), &format!("{group}_gain2.in")),
        connect(&format!("{group}_gain2.out"), &format!("{sink}.in")),
    ];
    d
}

#[test]
fn a_group_runs_its_chain_in_one_thread_in_link_order_and_loses_nothing() {
    let d = grouped_chain("chain", "chain_sink");
    let mut engine = Engine::build(&d, &registry(), RealTimeClock::shared()).unwrap();
    engine.start().unwrap();
    eventually("100 samples through the chain", || {
        collected("chain_sink").len() >= 100
    });
    engine.stop();
    let snapshot = engine.snapshot();
    let group = snapshot.groups.iter().find(|g| g.name == "chain").unwrap();
    assert_eq!(
        group.members,
        ["chain_source", "chain_gain1", "chain_gain2", "chain_sink"],
        "producers first"
    );
    assert!(group.passes > 0 && group.cpu_nanos > 0, "{group:?}");
    assert_eq!(stats(&snapshot, "chain_gain1").group.as_deref(), Some("chain"));
    // Every value, in order, through both gains: the counter's n as -2n.
    let values = collected("chain_sink");
    for (n, value) in values.iter().enumerate() {
        assert!((*value + 2.0 * n as f64).abs() < 1e-9, "sample {n} of {values:?}");
    }
    for link in &snapshot.links {
        let c = &link.counters;
        assert_eq!(c.written, c.read + c.queued, "{}: {c:?}", link.link);
        assert_eq!(c.overwritten + c.skipped, 0, "{}: {c:?}", link.link);
    }
    // The members ran once per sample: the gains' cycles are the counter's.
    let source = stats(&snapshot, "chain_source").cycles;
    assert!(
        stats(&snapshot, "chain_gain2").cycles + 1 >= source,
        "{snapshot:?}"
    );
}

/// Runs a sequential diagram replaying a burst as fast as it can, to its end; returns what the sink read.
fn sequential_run() -> Vec<f64> {
    let mut d = diagram(
        vec![
            component("burst", "test.burst", None, &[("count", Value::I64(3000))]),
            component("twice", "core.gain", None, &[("gain", Value::F64(2.0))]),
            component("average", "core.moving_average", None, &[]),
            component("sequential_sink", "test.collect", None, &[]),
        ],
        vec![
            connect("burst.out", "twice.in"),
            connect("twice.out", "average.in"),
            connect("average.out", "sequential_sink.in"),
        ],
    );
    d.sequential = true;
    // Small buffers: a member that fell behind its producer would lose samples and change the outputs.
    for connection in &mut d.connections {
        connection.buffer_size = Some(2);
        connection.policy = Some(ReaderPolicy::Fifo);
    }
    COLLECTED
        .lock()
        .unwrap()
        .retain(|(id, _)| id != "sequential_sink");
    let mut engine = Engine::build(&d, &registry(), RealTimeClock::shared()).unwrap();
    engine.start().unwrap();
    eventually("the burst runs to its end through every member", || {
        engine.all_finished()
    });
    let snapshot = engine.snapshot();
    engine.stop();
    for id in ["burst", "twice", "average", "sequential_sink"] {
        assert_eq!(stats(&snapshot, id).state, ComponentState::Finished, "{id}");
    }
    for link in &snapshot.links {
        assert_eq!(link.counters.overwritten, 0, "{}", link.link);
    }
    collected("sequential_sink")
}

#[test]
fn a_sequential_replay_as_fast_as_possible_gives_the_same_outputs_every_run() {
    let first = sequential_run();
    assert_eq!(first.len(), 3000, "every sample reaches the sink");
    for _ in 0..2 {
        assert_eq!(sequential_run(), first);
    }
}

#[test]
fn a_member_takes_live_properties_pauses_and_stops_with_the_rest() {
    let d = grouped_chain("live", "live_sink");
    let mut engine = Engine::build(&d, &registry(), RealTimeClock::shared()).unwrap();
    engine.start().unwrap();
    eventually("samples through", || !collected("live_sink").is_empty());
    engine
        .set_property("live_gain2", "gain", &Value::F64(1.0))
        .unwrap();
    let changed_at = collected("live_sink").len();
    eventually("the new gain applies", || {
        collected("live_sink").iter().skip(changed_at).any(|v| *v > 0.0)
    });
    engine.pause();
    eventually("every member says it is paused", || {
        let snapshot = engine.snapshot();
        ["live_source", "live_gain1", "live_gain2", "live_sink"]
            .iter()
            .all(|id| stats(&snapshot, id).state == ComponentState::Paused)
    });
    let paused_at = collected("live_sink").len();
    sleep(Duration::from_millis(100));
    assert!(
        collected("live_sink").len() <= paused_at + 1,
        "nothing runs while paused"
    );
    engine.resume();
    eventually("it runs again", || collected("live_sink").len() > paused_at + 5);
    engine.stop();
    let snapshot = engine.snapshot();
    assert_eq!(stats(&snapshot, "live_gain1").state, ComponentState::Stopped);
}

#[test]
fn a_slow_member_makes_its_neighbours_miss_ticks_and_is_named() {
    let group = Some("shared");
    let d = diagram(
        vec![
            component("fast", "core.counter", group, &[("rate", Value::F64(1000.0))]),
            component("slow", "test.slow", group, &[]),
        ],
        Vec::new(),
    );
    let mut engine = Engine::build(&d, &registry(), RealTimeClock::shared()).unwrap();
    engine.start().unwrap();
    eventually("the fast member misses ticks", || {
        stats(&engine.snapshot(), "fast").missed_ticks > 10
    });
    let snapshot = engine.snapshot();
    engine.stop();
    let group = snapshot.groups.iter().find(|g| g.name == "shared").unwrap();
    assert!(
        group.missed_ticks >= stats(&snapshot, "fast").missed_ticks,
        "{group:?}"
    );
    assert_eq!(group.slowest_member.as_deref(), Some("slow"), "{group:?}");
}

#[test]
fn a_group_driven_by_a_blocking_source_stops_while_the_source_waits() {
    let group = Some("driven");
    // The driver waits 10 s between samples; stop must not wait for it.
    let mut d = diagram(
        vec![
            component(
                "waits",
                "core.delay",
                group,
                &[("delay_ms", Value::F64(10_000.0))],
            ),
            component("feeder", "core.counter", None, &[("rate", Value::F64(100.0))]),
            component("driven_sink", "test.collect", group, &[]),
        ],
        vec![
            connect("feeder.out", "waits.in"),
            connect("waits.out", "driven_sink.in"),
        ],
    );
    d.components.sort_by(|a, b| a.id.cmp(&b.id));
    let mut engine = Engine::build(&d, &registry(), RealTimeClock::shared()).unwrap();
    engine.start().unwrap();
    eventually("the driver is running", || {
        stats(&engine.snapshot(), "waits").state == ComponentState::Running
    });
    sleep(Duration::from_millis(50));
    let stopping = Instant::now();
    engine.stop();
    assert!(
        stopping.elapsed() < Duration::from_secs(5),
        "{:?}",
        stopping.elapsed()
    );
}

#[test]
fn two_members_that_wait_in_one_group_are_refused() {
    let group = Some("two");
    let d = diagram(
        vec![
            component("first", "test.burst", group, &[]),
            component("second", "test.burst", group, &[]),
        ],
        Vec::new(),
    );
    let error = Engine::build(&d, &registry(), RealTimeClock::shared()).unwrap_err();
    let message = error.to_string();
    assert!(
        message.contains("group 'two' can hold one member that waits") && message.contains("'second'"),
        "{message}"
    );
}

#[test]
fn a_member_that_panics_fails_alone_and_the_rest_of_its_group_runs_on() {
    let group = Some("shared");
    let rate = Value::F64(200.0);
    let d = diagram(
        vec![
            component("feed", "core.counter", group, &[("rate", rate.clone())]),
            component("bad", "test.panics_on_third", group, &[]),
            component("other", "core.counter", group, &[("rate", rate)]),
            component("panic_sink", "test.collect", group, &[]),
        ],
        vec![
            connect("feed.out", "bad.in"),
            connect("other.out", "panic_sink.in"),
        ],
    );
    let mut engine = Engine::build(&d, &registry(), RealTimeClock::shared()).unwrap();
    engine.start().unwrap();
    eventually("'bad' fails on its third sample", || {
        matches!(stats(&engine.snapshot(), "bad").state, ComponentState::Failed(_))
    });
    let failed_at = collected("panic_sink").len();
    eventually("the rest of the group runs on", || {
        collected("panic_sink").len() > failed_at + 50
    });
    let snapshot = engine.snapshot();
    engine.stop();
    match &stats(&snapshot, "bad").state {
        ComponentState::Failed(message) => assert!(message.contains("third sample"), "{message}"),
        other => panic!("expected failed, got {other:?}"),
    }
    assert_eq!(stats(&snapshot, "feed").state, ComponentState::Running);
}

#[test]
fn a_write_that_overfills_a_never_skipping_link_inside_its_group_fails_the_writer_rather_than_hang() {
    let group = Some("flooded");
    let mut d = diagram(
        vec![
            component("flood", "test.flood", group, &[]),
            component("flood_sink", "test.collect", group, &[]),
        ],
        vec![connect("flood.out", "flood_sink.in")],
    );
    // Two samples fit; a cycle writes five, and the reader runs only once the cycle returns.
    d.connections[0].buffer_size = Some(2);
    d.connections[0].policy = Some(ReaderPolicy::NeverSkipping);
    let mut engine = Engine::build(&d, &registry(), RealTimeClock::shared()).unwrap();
    engine.start().unwrap();
    eventually("the writer fails", || {
        matches!(
            stats(&engine.snapshot(), "flood").state,
            ComponentState::Failed(_)
        )
    });
    // What was written before the failure is read, none of it lost.
    eventually("the reader reads what fitted", || {
        collected("flood_sink").len() == 2
    });
    let snapshot = engine.snapshot();
    let stopping = Instant::now();
    engine.stop();
    assert!(
        stopping.elapsed() < Duration::from_secs(5),
        "{:?}",
        stopping.elapsed()
    );
    match &stats(&snapshot, "flood").state {
        ComponentState::Failed(message) => assert!(
            message.contains("NeverSkipping link")
                && message.contains("is full (2 samples)")
                && message.contains("same thread"),
            "{message}"
        ),
        other => panic!("expected failed, got {other:?}"),
    }
    let link = &snapshot.links[0].counters;
    assert_eq!(link.written, 2, "{link:?}");
    assert_eq!(collected("flood_sink"), [0.0, 1.0]);
}
