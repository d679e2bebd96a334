//! Benchmark 26: replaying a rosbag2 bag as fast as possible, against the `rosbags` reader on the same
//! file in the same run.
//!
//! `benches/peers/rosbags/bag.py` writes the bag once with `rosbags` (MCAP storage, CDR, no compression,
//! as `ros2 bag record` writes by default): 1080p RGB images and 100 000-point clouds, alternating, about
//! 1 GB (200 MB in quick mode), in the temporary folder. Kairos replays it as a diagram runs it: a
//! `recording.player` on the bag's folder, `mode: as_fast_as_possible`, every message decoded into a
//! Kairos sample on its output, from the engine's start to the player's end. The baseline reads and
//! deserialises every message with `rosbags`' `AnyReader`, as a ROS user's script does. Both read the
//! file from the page cache (each is run once before timing); the figure is the bag's message bytes per
//! second.
//!
//! `cargo bench -p kairos-benches --bench rosbag_replay` with a `python3` that has `rosbags` and numpy
//! first on PATH (`tests/run` puts one in `target/test-python/bin`), or named by `KAIROS_PYTHON`.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use kairos_benches::{Goal, Ratios, Spread, Table, header, repetitions, size};
use kairos_diagram::{ComponentInstance, Diagram, Value};
use kairos_runtime::Engine;
use kairos_sdk_core::Registry;

fn python() -> String {
    std::env::var("KAIROS_PYTHON").unwrap_or_else(|_| "python3".to_owned())
}

fn peer() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("peers/rosbags/bag.py")
}

/// The bag's folder, written if it is not there yet (its size in the name).
fn bag(megabytes: f64) -> Option<PathBuf> {
    let folder = std::env::temp_dir().join(format!("kairos-bench-rosbag-{megabytes:.0}mb"));
    if folder.join("drive").join("metadata.yaml").is_file() {
        return Some(folder);
    }
    let _ = std::fs::remove_dir_all(&folder);
    std::fs::create_dir_all(&folder).ok()?;
    let written = Command::new(python())
        .arg(peer())
        .args(["write", &folder.display().to_string(), &megabytes.to_string()])
        .status()
        .ok()?;
    written.success().then_some(folder)
}

/// What `rosbags` took to read and deserialise every message, and the bytes of those messages.
fn rosbags_read(folder: &Path) -> Option<(f64, u64)> {
    let output = Command::new(python())
        .arg(peer())
        .args(["read", &folder.display().to_string()])
        .output()
        .ok()?;
    let report: serde_json::Value = serde_json::from_slice(&output.stdout).ok()?;
    Some((report["seconds"].as_f64()?, report["bytes"].as_u64()?))
}

/// Wall seconds for a diagram to replay the bag with its player as fast as possible.
fn kairos_replay(folder: &Path, registry: &Registry) -> f64 {
    let mut player = ComponentInstance::new("player", "recording.player");
    player.properties.insert(
        "path".to_owned(),
        Value::Text(folder.join("drive").display().to_string()),
    );
    player
        .properties
        .insert("mode".to_owned(), Value::Text("as_fast_as_possible".to_owned()));
    let mut diagram = Diagram::default();
    diagram.components.push(player);
    let clock = kairos_runtime::clock_for(&diagram, registry);
    let mut engine = Engine::build(&diagram, registry, clock).expect("the diagram builds");
    let started = Instant::now();
    engine.start().expect("the diagram starts");
    while !engine.all_finished() {
        std::thread::sleep(Duration::from_micros(200));
    }
    let wall = started.elapsed().as_secs_f64();
    engine.stop();
    wall
}

fn main() {
    header(
        "26. Replaying a rosbag2 bag as fast as possible, against the rosbags reader",
        "",
        "1080p rgb8 images and 100 000-point clouds, MCAP storage, CDR, no compression",
    );
    let megabytes = size(200.0, 1000.0);
    let Some(folder) = bag(megabytes) else {
        println!("skipped: cannot write the bag (a python3 with rosbags and numpy, or KAIROS_PYTHON)");
        return;
    };
    let registry = kairos::builtin_registry();
    // Once each, untimed: the file in the page cache for both.
    let Some((_, bytes)) = rosbags_read(&folder) else {
        println!("skipped: the rosbags reader did not run");
        return;
    };
    kairos_replay(&folder, &registry);
    let mut kairos_rates = Vec::new();
    let mut rosbags_rates = Vec::new();
    for _ in 0..repetitions() {
        let wall = kairos_replay(&folder, &registry);
        kairos_rates.push(bytes as f64 / wall / 1e6);
        if let Some((seconds, _)) = rosbags_read(&folder) {
            rosbags_rates.push(bytes as f64 / seconds / 1e6);
        }
    }
    let mut table = Table::new(&["reader", "MB of messages per s"]);
    for (name, rates) in [
        ("Kairos: recording.player, as fast as possible", &kairos_rates),
        ("rosbags: AnyReader, read and deserialise", &rosbags_rates),
    ] {
        table.row(vec![
            name.to_owned(),
            Spread::of(rates.iter().copied()).show(|v| format!("{v:.0}")),
        ]);
    }
    table.print();
    let mut ratios = Ratios::new();
    ratios.add(
        "Kairos rate / rosbags rate",
        Spread::of(kairos_rates.iter().zip(&rosbags_rates).map(|(k, r)| k / r)),
        Some(Goal::AtLeast(1.0)),
    );
    ratios.print();
    println!("{:.0} MB of messages in {}", bytes as f64 / 1e6, folder.display());
}
