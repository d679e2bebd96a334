//! Benchmark 19: one hop through a pass-through component written in Python vs one written in Rust.
//!
//! A source feeds a pass-through, which feeds a sink. The figure is the hop: the pass-through's time of
//! issue minus the source's, for the same sample (one hand-off into the component and its write, reader
//! idle), after a one-second warm-up. Rust: `core.subsampler` with factor 1 (it
//! forwards the sample, payload shared). Python: `py_vision.pass_through` (`ctx.forward(ctx.read(..))` in
//! a worker process). Two payloads: a counter's integer at 1 kHz, and a 1920×1080 RGB image from the
//! simulated camera at 30 Hz, whose pixels the Python worker maps and writes back by reference; the
//! pixel bytes copied per image are reported from the component's status. The two variants alternate
//! within each repetition. Two placements, both in the same run: unpinned, as `kairos run` places
//! threads by default, and pinned with every hand-over crossing cores. The CPU the pass-through costs
//! (its thread, and for Python its worker process too) is reported as a share of one core.
//!
//! Needs `python3` with numpy first on the `PATH` (`tests/run --setup-only` makes one in
//! `target/test-python`).

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use kairos_benches::{
    Goal, Percentiles, Spread, Table, header, machine, quick, ratio, repetitions, size, time,
};
use kairos_diagram::{ComponentInstance, Connection, Diagram, PortRef, ReaderPolicy, Value};
use kairos_runtime::Engine;
use kairos_sdk_core::host::ReaderConfig;
use kairos_sdk_core::{RealTimeClock, Registry, RunSignal};

#[derive(Clone, Copy, PartialEq)]
enum Payload {
    Scalar,
    Image,
}

fn pack_folder() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../examples/python/packs")
}

/// Where the threads run.
#[derive(Clone, Copy, PartialEq)]
enum Placement {
    /// Wherever the kernel puts them, as `kairos run` does unless a diagram pins them.
    Unpinned,
    /// Source and sink on CPU 0, the pass-through on CPU 1 (the worker inherits its proxy's core).
    Pinned,
}

fn diagram(payload: Payload, pass_type: &str, placement: Placement) -> Diagram {
    let mut source = match payload {
        Payload::Scalar => {
            let mut counter = ComponentInstance::new("source", "core.counter");
            counter.properties.insert("rate".into(), Value::F64(1000.0));
            counter
        }
        Payload::Image => {
            let mut camera = ComponentInstance::new("source", "sensors.camera");
            camera.properties.insert("rate".into(), Value::F64(30.0));
            camera.properties.insert("width".into(), Value::I64(1920));
            camera.properties.insert("height".into(), Value::I64(1080));
            camera
        }
    };
    let mut pass = ComponentInstance::new("pass", pass_type);
    if pass_type == "core.subsampler" {
        pass.properties.insert("factor".into(), Value::I64(1));
    }
    let mut sink = ComponentInstance::new("sink", "core.latency_probe");
    if placement == Placement::Pinned {
        // As in the other hand-off benchmarks, every hand-over crosses cores.
        source.thread.affinity = vec![0];
        pass.thread.affinity = vec![1];
        sink.thread.affinity = vec![0];
    }
    let out = match payload {
        Payload::Scalar => "source.out",
        Payload::Image => "source.image",
    };
    let link = |from: &str, to: &str| {
        let mut c = Connection::new(
            PortRef::parse(from).unwrap_or_else(|| PortRef::new("", "")),
            PortRef::parse(to).unwrap_or_else(|| PortRef::new("", "")),
        );
        c.policy = Some(ReaderPolicy::Fifo);
        c
    };
    Diagram {
        components: vec![source, pass, sink],
        connections: vec![link(out, "pass.in"), link("pass.out", "sink.in")],
        ..Diagram::default()
    }
}

/// CPU time of a process so far (user and system), from `/proc/PID/stat`, whose times are in
/// hundredths of a second on Linux (`USER_HZ`, fixed whatever the kernel's tick).
fn process_cpu_nanos(pid: u64) -> Option<f64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // After the command's closing parenthesis: the state is the first field, utime the 12th, stime the 13th.
    let fields: Vec<&str> = stat.rsplit_once(')')?.1.split_whitespace().collect();
    let ticks = fields.get(11)?.parse::<f64>().ok()? + fields.get(12)?.parse::<f64>().ok()?;
    Some(ticks * 1e7)
}

/// The pass-through's CPU so far: its thread's, and its Python worker's where it has one.
fn pass_cpu_nanos(engine: &Engine) -> f64 {
    let snapshot = engine.snapshot();
    let Some(pass) = snapshot.components.iter().find(|c| c.id == "pass") else {
        return 0.0;
    };
    let worker = pass
        .status
        .as_ref()
        .and_then(|status| status["python"]["pid"].as_u64())
        .and_then(process_cpu_nanos)
        .unwrap_or(0.0);
    pass.busy_nanos as f64 + worker
}

/// (p50, p99 of the hop, p50 from the source's stamp, pixel bytes copied per image, the pass-through's
/// CPU in % of a core) for one run. The hop is the pass-through's time of issue minus the source's, for
/// the same sample (matched by timestamp), after a warm-up that lets the Python worker start.
fn run(
    registry: &Registry,
    payload: Payload,
    pass_type: &str,
    placement: Placement,
    run_for: Duration,
) -> Option<[f64; 5]> {
    let mut engine = Engine::build(
        &diagram(payload, pass_type, placement),
        registry,
        RealTimeClock::shared(),
    )
    .ok()?;
    let source_output = if payload == Payload::Scalar {
        "out"
    } else {
        "image"
    };
    let attach = |component: &str, output: &str| {
        engine.output_buffer(component, output).map(|buffer| {
            buffer.attach(
                ReaderConfig::new(ReaderPolicy::Fifo, format!("{component}.{output} -> bench")),
                Arc::new(RunSignal::new()),
            )
        })
    };
    let (mut sources, mut passed) = (attach("source", source_output)?, attach("pass", "out")?);
    engine.start().ok()?;
    let warm = Instant::now() + Duration::from_secs(1);
    let end = warm + run_for;
    let mut issued = HashMap::new();
    let mut hops = Vec::new();
    let mut from_stamp = Vec::new();
    let mut cpu_at_warm = None;
    while Instant::now() < end {
        if cpu_at_warm.is_none() && Instant::now() >= warm {
            cpu_at_warm = Some((Instant::now(), pass_cpu_nanos(&engine)));
        }
        while let Some(sample) = sources.try_read() {
            issued.insert(sample.timestamp, sample.time_of_issue);
        }
        while let Some(sample) = passed.try_read() {
            if Instant::now() < warm {
                continue;
            }
            while let Some(source) = sources.try_read() {
                issued.insert(source.timestamp, source.time_of_issue);
            }
            if let Some(source_issued) = issued.remove(&sample.timestamp) {
                hops.push(sample.time_of_issue.nanos_since(source_issued) as f64);
                from_stamp.push(sample.latency_nanos() as f64);
            }
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    let cpu = cpu_at_warm.map_or(0.0, |(at, before)| {
        (pass_cpu_nanos(&engine) - before) / at.elapsed().as_nanos() as f64 * 100.0
    });
    let snapshot = engine.snapshot();
    engine.stop();
    let pass = snapshot.components.iter().find(|c| c.id == "pass")?;
    let copied = pass.status.as_ref().map_or(0.0, |status| {
        let python = &status["python"];
        python["pixels_copied_bytes"].as_f64().unwrap_or(0.0)
            / python["images"].as_f64().unwrap_or(1.0).max(1.0)
    });
    (hops.len() > 10).then(|| {
        let percentiles = Percentiles::of(&mut hops);
        [
            percentiles.p50,
            percentiles.p99,
            Percentiles::of(&mut from_stamp).p50,
            copied,
            cpu,
        ]
    })
}

fn main() {
    header(
        "19. One hop through a Python component vs a Rust one",
        "reader idle (counter at 1 kHz, as benchmark 6; camera 1920×1080 RGB at 30 Hz)",
        "source → pass-through (Python: proxy thread and worker process) → latency probe; unpinned, then \
         pinned (source and probe on CPU 0, pass-through on CPU 1)",
    );
    let mut registry = Registry::new();
    kairos_pack_core::register(&mut registry);
    kairos_pack_sensors::register(&mut registry);
    let scan = kairos_runtime::load_packs(&mut registry, &[pack_folder()]);
    if registry.component("py_vision.pass_through").is_none() {
        println!(
            "the Python pack did not load ({:?}): put python3 with numpy first on the PATH \
             (tests/run --setup-only, then PATH=target/test-python/bin:$PATH)",
            scan.refused
        );
        return;
    }
    let run_for = Duration::from_millis(size(1500, 5000));
    let mut table = Table::new(&[
        "placement",
        "payload",
        "figure",
        "Rust",
        "Python",
        "Python / Rust",
        "goal",
    ]);
    for (placement, placed) in [(Placement::Unpinned, "unpinned"), (Placement::Pinned, "pinned")] {
        for (payload, name, goal) in [
            (Payload::Scalar, "integer, 1 kHz", Goal::AtMost(3.0)),
            (Payload::Image, "1080p RGB (6.2 MB), 30 Hz", Goal::AtMost(1.5)),
        ] {
            let (mut rust, mut python) = (
                [Vec::new(), Vec::new(), Vec::new(), Vec::new()],
                [Vec::new(), Vec::new(), Vec::new(), Vec::new()],
            );
            let mut copied = Vec::new();
            for repetition in 0..repetitions() {
                let mut order = [("core.subsampler", false), ("py_vision.pass_through", true)];
                if repetition % 2 == 1 {
                    order.reverse();
                }
                for (pass_type, is_python) in order {
                    let Some([p50, p99, stamped, bytes, cpu]) =
                        run(&registry, payload, pass_type, placement, run_for)
                    else {
                        println!("a run of {pass_type} failed");
                        return;
                    };
                    let figures = if is_python { &mut python } else { &mut rust };
                    figures[0].push(p50);
                    figures[1].push(p99);
                    figures[2].push(stamped);
                    figures[3].push(cpu);
                    if is_python {
                        copied.push(bytes);
                    }
                }
            }
            let rows = [
                ("hop p50", &rust[0], &python[0], payload == Payload::Scalar),
                ("hop p99", &rust[1], &python[1], false),
                (
                    "p50 from the source's stamp",
                    &rust[2],
                    &python[2],
                    payload == Payload::Image,
                ),
            ];
            for (figure, r, p, with_goal) in rows {
                let ratios = Spread::of(p.iter().zip(r).map(|(p, r)| p / r));
                table.row(vec![
                    placed.to_owned(),
                    name.to_owned(),
                    figure.to_owned(),
                    Spread::of(r.iter().copied()).show(time),
                    Spread::of(p.iter().copied()).show(time),
                    ratios.show(ratio),
                    if with_goal {
                        format!("{} {}", goal.show(), goal.verdict(ratios.median))
                    } else {
                        "context".to_owned()
                    },
                ]);
            }
            let percent = |share: f64| format!("{share:.1} %");
            table.row(vec![
                placed.to_owned(),
                name.to_owned(),
                "pass-through CPU, % of a core".to_owned(),
                Spread::of(rust[3].iter().copied()).show(percent),
                Spread::of(python[3].iter().copied()).show(percent),
                String::new(),
                "context".to_owned(),
            ]);
            if payload == Payload::Image {
                table.row(vec![
                    placed.to_owned(),
                    name.to_owned(),
                    "pixel bytes copied per image".to_owned(),
                    "0 (the payload's Arc is shared)".to_owned(),
                    format!("{:.0}", Spread::of(copied.iter().copied()).max),
                    String::new(),
                    "0".to_owned(),
                ]);
            }
        }
    }
    table.print();
    println!(
        "\nmachine: {}\nmode: {}",
        machine(),
        if quick() { "quick" } else { "full" }
    );
}
