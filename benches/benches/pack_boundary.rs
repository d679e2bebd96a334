//! Benchmark 6: the same component built in and loaded from a shared library, in the same run.
//!
//! A 1 kHz counter feeds `filters.low_pass`, which feeds a moving average. Each repetition runs the chain
//! once with the filter linked in and once with it loaded from `libkairos_pack_filters` through the pack
//! ABI, interleaved. Figures: the latency of the filter's output link (time of issue − timestamp: from the
//! counter's stamp to the filter's write, i.e. one hand-off through the component, reader idle), and the
//! filter's CPU time per sample. A third figure times `core` alone, back to back, to show the raw cost of
//! the boundary crossing without a wake-up.

use std::path::PathBuf;

use std::time::{Duration, Instant};

use kairos_benches::{Goal, Spread, Table, header, machine, quick, ratio, repetitions, size, time};
use kairos_diagram::{ComponentInstance, Connection, Diagram, PortRef, ReaderPolicy, Value};
use kairos_runtime::Engine;
use kairos_sdk_core::harness::Harness;
use kairos_sdk_core::{Payload, RealTimeClock, Registry, Timestamp};

fn library_path() -> Option<PathBuf> {
    let exe = std::env::current_exe().ok()?;
    let deps = exe.parent()?;
    let name = format!(
        "{}kairos_pack_filters{}",
        std::env::consts::DLL_PREFIX,
        std::env::consts::DLL_SUFFIX
    );
    [deps.join(&name), deps.parent()?.join(&name)]
        .into_iter()
        .find(|p| p.exists())
}

fn registries(
    library: &std::path::Path,
) -> Result<(Registry, Registry), kairos_runtime::pack_host::PackLoadError> {
    let mut built_in = Registry::new();
    kairos_pack_core::register(&mut built_in);
    kairos_pack_filters::register(&mut built_in);
    let mut loaded = Registry::new();
    kairos_pack_core::register(&mut loaded);
    kairos_runtime::pack_host::load_pack(library)?.register(&mut loaded);
    Ok((built_in, loaded))
}

fn diagram(rate_hz: f64) -> Diagram {
    let mut counter = ComponentInstance::new("counter", "core.counter");
    counter.properties.insert("rate".into(), Value::F64(rate_hz));
    let mut filter = ComponentInstance::new("filter", "filters.low_pass");
    let mut sink = ComponentInstance::new("sink", "core.moving_average");
    // Every hand-over crosses cores, as in the other two-thread benchmarks: same-core hand-overs (a
    // context switch, ~2 µs) and cross-core ones (~20 µs) would otherwise mix from run to run.
    counter.thread.affinity = vec![0];
    filter.thread.affinity = vec![1];
    sink.thread.affinity = vec![0];
    let link = |from: &str, to: &str| {
        let mut c = Connection::new(
            PortRef::parse(from).unwrap_or_else(|| PortRef::new("", "")),
            PortRef::parse(to).unwrap_or_else(|| PortRef::new("", "")),
        );
        c.policy = Some(ReaderPolicy::Fifo);
        c
    };
    Diagram {
        components: vec![counter, filter, sink],
        connections: vec![link("counter.out", "filter.in"), link("filter.out", "sink.in")],
        ..Diagram::default()
    }
}

/// (p50 latency of the filter's output, CPU ns per filter cycle) for one run.
fn run_chain(registry: &Registry, run_for: Duration) -> Option<(f64, f64)> {
    let mut engine = Engine::build(&diagram(1000.0), registry, RealTimeClock::shared()).ok()?;
    engine.start().ok()?;
    std::thread::sleep(run_for);
    engine.stop();
    let snapshot = engine.snapshot();
    let link = snapshot
        .links
        .iter()
        .find(|l| l.link == "filter.out -> sink.in")?;
    let filter = snapshot.components.iter().find(|c| c.id == "filter")?;
    Some((
        link.counters.latency.p50_nanos as f64,
        filter.busy_nanos as f64 / filter.cycles.max(1) as f64,
    ))
}

/// Nanoseconds per `core` call, back to back, through the offline harness.
fn core_alone(registry: &Registry, samples: usize) -> Option<f64> {
    let registered = registry.component("filters.low_pass")?;
    let mut harness = Harness::boxed(registered.info.clone(), (registered.factory)());
    for i in 0..samples {
        harness.push("in", Payload::F64(i as f64), Timestamp::from_micros(i as i64));
    }
    let started = Instant::now();
    let out = harness.run().ok()?;
    let elapsed = started.elapsed();
    (out.samples("out").len() == samples).then(|| elapsed.as_nanos() as f64 / samples as f64)
}

fn main() {
    header(
        "6. The pack boundary: a component built in vs loaded from a shared library",
        "reader idle (1 kHz chain); back-to-back for the core-alone figure",
        "counter 1 kHz (CPU 0) → filters.low_pass (CPU 1) → moving_average (CPU 0)",
    );
    let Some(library) = library_path() else {
        println!(
            "libkairos_pack_filters not found next to the benchmark: build with `cargo bench -p kairos-benches`."
        );
        return;
    };
    let (built_in, loaded) = match registries(&library) {
        Ok(pair) => pair,
        Err(error) => {
            println!("cannot load {}: {error}", library.display());
            return;
        }
    };
    let run_for = Duration::from_millis(size(700, 3000));
    let samples = size(20_000, 200_000);
    let mut latency = (Vec::new(), Vec::new());
    let mut cpu = (Vec::new(), Vec::new());
    let mut alone = (Vec::new(), Vec::new());
    for repetition in 0..repetitions() {
        // Alternate which goes first, so drifts of the machine hit both alike.
        let order: [(&Registry, bool); 2] = if repetition % 2 == 0 {
            [(&built_in, false), (&loaded, true)]
        } else {
            [(&loaded, true), (&built_in, false)]
        };
        for (registry, is_loaded) in order {
            let (Some((p50, per_cycle)), Some(core)) =
                (run_chain(registry, run_for), core_alone(registry, samples))
            else {
                println!("a run failed");
                return;
            };
            let (l, c, a) = if is_loaded {
                (&mut latency.1, &mut cpu.1, &mut alone.1)
            } else {
                (&mut latency.0, &mut cpu.0, &mut alone.0)
            };
            l.push(p50);
            c.push(per_cycle);
            a.push(core);
        }
    }
    let mut table = Table::new(&["figure", "built in", "loaded", "loaded / built in", "goal"]);
    let ratios = |pair: &(Vec<f64>, Vec<f64>)| Spread::of(pair.1.iter().zip(&pair.0).map(|(l, b)| l / b));
    let goal = Goal::AtMost(1.05);
    for (name, pair, with_goal) in [
        ("hand-off latency p50 (reader idle)", &latency, true),
        ("filter CPU per sample (reader idle)", &cpu, true),
        ("core alone, back to back", &alone, false),
    ] {
        let r = ratios(pair);
        table.row(vec![
            name.to_owned(),
            Spread::of(pair.0.iter().copied()).show(time),
            Spread::of(pair.1.iter().copied()).show(time),
            r.show(ratio),
            if with_goal {
                format!(
                    "{} {}",
                    goal.show(),
                    if goal.met_by(r.median) { "met" } else { "missed" }
                )
            } else {
                "context".to_owned()
            },
        ]);
    }
    table.print();
    println!(
        "\nlibrary: {}\nmachine: {}\nmode: {}",
        library.display(),
        machine(),
        if quick() { "quick" } else { "full" }
    );
}
