//! Benchmark 22 — the pre-trigger ring against the plain recorder.
//!
//! 1. CPU per sample: the recorder's thread (its CPU time, from the engine's statistics) per sample it
//!    takes, armed in pre-trigger mode and never triggered (every sample goes to the ring), against the
//!    plain recorder writing every sample to an uncompressed file on tmpfs (`/dev/shm`: its in-memory
//!    path, no disk). The same real engine and sensors: a 640×480 camera at 30 Hz, the lidar at 10 Hz,
//!    the IMU at 100 Hz and GNSS at 10 Hz. Repetitions alternate the two.
//! 2. Memory: a 1920×1080 camera at 30 Hz into a ring bounded at 100 MB (and an hour, so the bytes bind),
//!    for long enough to pass the bound many times over; the process's resident memory above the same
//!    diagram with a ring of 1 MB, against the bound.

use std::time::Duration;

use kairos_benches::{Goal, Ratios, Spread, Table, header, repetitions, size};
use kairos_runtime::Engine;
use kairos_sdk_core::{RealTimeClock, Registry};

fn registry() -> Registry {
    let mut registry = Registry::new();
    kairos_pack_sensors::register(&mut registry);
    kairos_pack_recording::register(&mut registry);
    registry
}

fn engine(text: &str, registry: &Registry) -> Option<Engine> {
    let diagram = kairos_diagram::parse(text).ok()?.diagram;
    Engine::build(&diagram, registry, RealTimeClock::shared()).ok()
}

/// The recorder's CPU time per sample taken, in nanoseconds, and how many it took.
fn cpu_per_sample(recorder: &str, registry: &Registry, run_for: Duration) -> Option<(f64, u64)> {
    let text = format!(
        r#"Diagram(format: 1, components: [
            Component(id: "camera", type: "sensors.camera", properties: {{"width": 640, "height": 480, "rate": 30.0}}),
            Component(id: "lidar", type: "sensors.lidar"),
            Component(id: "imu", type: "sensors.imu", properties: {{"rate": 100.0}}),
            Component(id: "gnss", type: "sensors.gnss"),
            Component(id: "recorder", type: "recording.recorder", properties: {{{recorder}}}),
        ], connections: [
            Connection(from: "camera.image", to: "recorder.in1"),
            Connection(from: "lidar.points", to: "recorder.in2"),
            Connection(from: "imu.imu", to: "recorder.in3", buffer_size: 64),
            Connection(from: "gnss.fix", to: "recorder.in4"),
        ])"#
    );
    let mut engine = engine(&text, registry)?;
    engine.start().ok()?;
    std::thread::sleep(run_for);
    let snapshot = engine.snapshot();
    engine.stop();
    let busy = snapshot
        .components
        .iter()
        .find(|c| c.id == "recorder")?
        .busy_nanos;
    let taken: u64 = snapshot
        .links
        .iter()
        .filter(|l| l.link.contains("-> recorder."))
        .map(|l| l.counters.read)
        .sum();
    (taken > 0).then(|| (busy as f64 / taken as f64, taken))
}

fn resident_bytes() -> f64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|l| l.split_whitespace().next()?.parse::<f64>().ok())
        .map_or(f64::NAN, |kib| kib * 1024.0)
}

/// The process's resident memory after `run_for` of a 1080p camera into a ring of `ring_mb`, and the
/// bytes the ring says it holds.
fn ring_memory(ring_mb: f64, registry: &Registry, run_for: Duration) -> Option<(f64, f64)> {
    let text = format!(
        r#"Diagram(format: 1, components: [
            Component(id: "camera", type: "sensors.camera", properties: {{"width": 1920, "height": 1080, "rate": 30.0}}),
            Component(id: "recorder", type: "recording.recorder", properties: {{
                "mode": "pre_trigger", "pre_trigger_s": 3600.0, "ring_mb": {ring_mb:.1}, "path": "/dev/null/never",
            }}),
        ], connections: [Connection(from: "camera.image", to: "recorder.in1")])"#
    );
    let mut engine = engine(&text, registry)?;
    let before = resident_bytes();
    engine.start().ok()?;
    std::thread::sleep(run_for);
    let resident = resident_bytes();
    println!(
        "ring of {ring_mb} MB: the process's resident memory {:.1} MB before the start, {:.1} MB after {} s",
        before / 1e6,
        resident / 1e6,
        run_for.as_secs()
    );
    let snapshot = engine.snapshot();
    engine.stop();
    let status = snapshot
        .components
        .iter()
        .find(|c| c.id == "recorder")?
        .status
        .clone()?;
    Some((resident, status["ring_bytes"].as_f64()?))
}

fn main() {
    let run_for = Duration::from_secs(size(2, 5));
    header(
        "22. Pre-trigger ring against the plain recorder",
        "real engine; camera 640×480 30 Hz, lidar 10 Hz, IMU 100 Hz, GNSS 10 Hz; then a 1080p camera",
        &format!("{} s per run, alternating", run_for.as_secs()),
    );
    let registry = registry();
    let plain = r#""path": "/dev/shm/kairos-bench-plain.mcap", "compression": "none", "min_free_mb": 0.0"#;
    let ring = r#""mode": "pre_trigger", "pre_trigger_s": 10.0, "ring_mb": 2000.0, "path": "/dev/shm/kairos-bench-ring.mcap""#;
    let mut table = Table::new(&[
        "rep",
        "plain recorder (tmpfs)",
        "samples",
        "pre-trigger ring",
        "samples",
    ]);
    let mut ratios_per_rep = Vec::new();
    for rep in 0..repetitions() {
        let (Some((plain_ns, plain_n)), Some((ring_ns, ring_n))) = (
            cpu_per_sample(plain, &registry, run_for),
            cpu_per_sample(ring, &registry, run_for),
        ) else {
            eprintln!("a run failed");
            return;
        };
        let _ = std::fs::remove_file("/dev/shm/kairos-bench-plain.mcap");
        table.row(vec![
            rep.to_string(),
            kairos_benches::time(plain_ns),
            plain_n.to_string(),
            kairos_benches::time(ring_ns),
            ring_n.to_string(),
        ]);
        ratios_per_rep.push(ring_ns / plain_ns);
    }
    table.print();

    let memory_for = Duration::from_secs(size(4, 10));
    let bound_mb = 100.0;
    let (Some((small, _)), Some((resident, held))) = (
        ring_memory(1.0, &registry, memory_for),
        ring_memory(bound_mb, &registry, memory_for),
    ) else {
        eprintln!("a memory run failed");
        return;
    };
    let above = (resident - small) / 1e6;
    println!(
        "1080p at 30 Hz for {} s ({:.0} MB through the ring): the ring holds {:.1} MB; resident memory {:.1} MB above a 1 MB ring",
        memory_for.as_secs(),
        memory_for.as_secs_f64() * 30.0 * 1920.0 * 1080.0 * 3.0 / 1e6,
        held / 1e6,
        above
    );
    let mut ratios = Ratios::new();
    ratios.add(
        "CPU per sample: pre-trigger ring / plain recorder",
        Spread::of(ratios_per_rep),
        Some(Goal::AtMost(1.1)),
    );
    let single = |value: f64| Spread {
        median: value,
        min: value,
        max: value,
    };
    ratios.add(
        "memory: resident above a 1 MB ring / 100 MB bound",
        single(above / bound_mb),
        Some(Goal::AtMost(1.05)),
    );
    ratios.add(
        "memory: the ring's own count / 100 MB bound",
        single(held / 1e6 / bound_mb),
        Some(Goal::AtMost(1.05)),
    );
    ratios.print();
}
