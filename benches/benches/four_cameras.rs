//! Benchmark 9 — recording four 1920×1080 cameras at 80 % of the machine's bare MCAP write rate, measured
//! in the same run: does the recorder keep up without dropping a frame?
//!
//! The bare rate comes from the same loop as benchmark 7 (encode each frame as `foxglove.RawImage`, write it
//! with the `mcap` crate, sync), sustained over about as many bytes as the camera run writes. Then a diagram of four simulated cameras (colour bars, the cheapest pattern
//! to draw) feeding one recorder runs on the real engine, the cameras' rate set so that together they
//! produce 80 % of that many bytes per second. Reported: frames each camera produced against its schedule,
//! frames the recorder lost (overwritten or skipped on its four inputs) and frames recorded.

use std::time::Duration;

use kairos_benches::{Table, header, quick, repetitions, size};
use kairos_runtime::Engine;
use kairos_sdk_core::{RealTimeClock, Registry};

const WIDTH: u32 = 1920;
const HEIGHT: u32 = 1080;
const FRAME_BYTES: f64 = (WIDTH * HEIGHT * 3) as f64;

/// Bytes per second the bare `mcap` loop of benchmark 7 sustains over `frames` frames.
fn bare_rate(dir: &std::path::Path, frames: usize) -> Option<f64> {
    let pixels: Vec<u8> = (0..(WIDTH * HEIGHT * 3) as usize)
        .map(|p| (p % 251) as u8)
        .collect();
    let path = dir.join("bare.mcap");
    let rate = kairos_benches::bare_mcap_rate(&path, WIDTH, HEIGHT, frames, |_| &pixels[..]);
    let _ = std::fs::remove_file(&path);
    rate
}

struct Outcome {
    /// CPU share (of one core) of the four cameras together, and of the recorder.
    cameras_cpu: f64,
    recorder_cpu: f64,
    scheduled: u64,
    produced: u64,
    lost: u64,
    recorded: u64,
}

fn four_cameras(dir: &std::path::Path, fps: f64, run_for: Duration) -> Option<Outcome> {
    let path = dir.join("four.mcap");
    let _ = std::fs::remove_file(&path);
    let mut components: Vec<String> = (1..=4)
        .map(|camera| {
            format!(
                "Component(id: \"cam{camera}\", type: \"sensors.camera\", properties: {{\"width\": {WIDTH}, \"height\": {HEIGHT}, \"rate\": {fps}, \"pattern\": \"color_bars\"}})"
            )
        })
        .collect();
    components.push(format!(
        "Component(id: \"recorder\", type: \"recording.recorder\", properties: {{\"path\": \"{}\", \"compression\": \"none\", \"min_free_mb\": 0.0}})",
        path.display()
    ));
    let connections: Vec<String> = (1..=4)
        .map(|camera| format!("Connection(from: \"cam{camera}.image\", to: \"recorder.in{camera}\")"))
        .collect();
    let text = format!(
        "Diagram(format: 1, packs: [Pack(name: \"sensors\", version: \"^0.1\"), Pack(name: \"recording\", version: \"^0.1\")], components: [{}], connections: [{}])",
        components.join(", "),
        connections.join(", ")
    );
    let diagram = kairos_diagram::parse(&text).ok()?.diagram;
    let mut registry = Registry::new();
    kairos_pack_sensors::register(&mut registry);
    kairos_pack_recording::register(&mut registry);
    let mut engine = Engine::build(&diagram, &registry, RealTimeClock::shared()).ok()?;
    engine.start().ok()?;
    std::thread::sleep(run_for);
    let snapshot = engine.snapshot();
    engine.stop();
    let mut outcome = Outcome {
        #[allow(
            clippy::cast_possible_truncation,
            clippy::cast_sign_loss,
            reason = "a small positive count"
        )]
        scheduled: (4.0 * fps * run_for.as_secs_f64()) as u64,
        produced: 0,
        lost: 0,
        recorded: 0,
        cameras_cpu: 0.0,
        recorder_cpu: 0.0,
    };
    for component in &snapshot.components {
        let share = component.busy_nanos as f64 / run_for.as_nanos() as f64;
        if component.id == "recorder" {
            outcome.recorder_cpu = share;
        } else {
            outcome.cameras_cpu += share;
        }
    }
    for link in &snapshot.links {
        outcome.produced += link.counters.written;
        outcome.lost += link.counters.overwritten + link.counters.skipped;
        outcome.recorded += link.counters.read;
    }
    let _ = std::fs::remove_file(&path);
    Some(outcome)
}

fn main() {
    let run_for = Duration::from_secs(size(2, 5));
    header(
        "9. Four 1920×1080 cameras recorded at 80 % of the bare write rate",
        "real engine, real-time clock, uncompressed, to a temp folder",
        &format!("{} s per run", run_for.as_secs()),
    );
    let Ok(dir) =
        std::env::var("KAIROS_BENCH_DIR").map_or_else(|_| tempfile::tempdir(), tempfile::tempdir_in)
    else {
        return;
    };
    let mut table = Table::new(&[
        "rep",
        "bare rate",
        "frames/s per camera",
        "produced / scheduled",
        "lost",
        "recorded",
        "CPU cameras / recorder",
    ]);
    let mut all_kept = true;
    for repetition in 0..repetitions() {
        // As many bytes as the camera run writes: a short burst would land in the page cache and
        // overstate what the disk sustains.
        let Some(bare) = bare_rate(dir.path(), size(300, 750)) else {
            println!("the bare loop failed");
            return;
        };
        let fps = (0.8 * bare / FRAME_BYTES / 4.0).min(240.0);
        let Some(outcome) = four_cameras(dir.path(), fps, run_for) else {
            println!("the diagram failed");
            return;
        };
        all_kept &= outcome.lost == 0;
        table.row(vec![
            repetition.to_string(),
            format!("{:.0} MB/s", bare / 1e6),
            format!("{fps:.1}"),
            format!("{} / {}", outcome.produced, outcome.scheduled),
            outcome.lost.to_string(),
            outcome.recorded.to_string(),
            format!(
                "{:.0} % / {:.0} %",
                outcome.cameras_cpu * 100.0,
                outcome.recorder_cpu * 100.0
            ),
        ]);
    }
    table.print();
    println!(
        "\ngoal: no frame lost by the recorder: {}\nmode: {}",
        if all_kept { "met" } else { "MISSED" },
        if quick() { "quick" } else { "full" }
    );
}
