//! Benchmark 7: recording throughput, the recorder component against a bare `mcap` writer loop writing the
//! same samples (the same Foxglove `RawImage` encoding, the same chunk compression: none, zstd, lz4;
//! synced to disk at the end) to the same folder; and the compression ratio of each on the simulated
//! camera, lidar, IMU and GNSS.

use std::time::Instant;

use kairos_benches::{Goal, Spread, Table, header, machine, quick, ratio, repetitions, size};
use kairos_pack_recording::recorder::Recorder;
use kairos_sdk_core::harness::Harness;
use kairos_sdk_core::{Image, Payload, Timestamp};

const WIDTH: u32 = 1920;
const HEIGHT: u32 = 1080;

/// Frames of the simulated camera, a second apart (so the road scene moves), as compression sees real
/// images better than a synthetic pattern.
fn frames(count: usize) -> Vec<Payload> {
    let mut camera = Harness::new(
        kairos_pack_sensors::camera::descriptor(),
        kairos_pack_sensors::CameraSensor::default(),
    );
    camera.leave_unconnected("vehicle");
    let _ = camera.set_property("width", i64::from(WIDTH));
    let _ = camera.set_property("height", i64::from(HEIGHT));
    let _ = camera.set_property("rate", 1.0);
    let out = camera.run_periodic(count).unwrap_or_default();
    out.samples("image").iter().map(|s| s.payload.clone()).collect()
}

/// The file sizes of 5 s of the simulated camera (640×480 at 30 Hz), lidar (10 Hz), IMU (100 Hz) and GNSS
/// (10 Hz) recorded with each compression, and the ratio to the uncompressed file.
fn compression_ratios(dir: &std::path::Path) {
    use kairos_pack_sensors::{camera, gnss, imu, lidar};
    let mut streams: Vec<(&str, kairos_sdk_core::Sample)> = Vec::new();
    let mut collect = |input: &'static str, out: kairos_sdk_core::harness::HarnessOutput, port: &str| {
        streams.extend(out.samples(port).iter().map(|s| (input, s.clone())));
    };
    let mut cam = Harness::new(camera::descriptor(), kairos_pack_sensors::CameraSensor::default());
    cam.leave_unconnected("vehicle");
    let _ = cam.set_property("width", 640_i64);
    let _ = cam.set_property("height", 480_i64);
    collect("in1", cam.run_periodic(150).unwrap_or_default(), "image");
    let mut scanner = Harness::new(lidar::descriptor(), lidar::LidarSensor::default());
    scanner.leave_unconnected("vehicle");
    collect("in2", scanner.run_periodic(50).unwrap_or_default(), "points");
    let mut unit = Harness::new(imu::descriptor(), kairos_pack_sensors::ImuSensor::default());
    unit.leave_unconnected("vehicle");
    collect("in3", unit.run_periodic(500).unwrap_or_default(), "imu");
    let mut receiver = Harness::new(gnss::descriptor(), kairos_pack_sensors::GnssSensor::default());
    receiver.leave_unconnected("vehicle");
    collect("in4", receiver.run_periodic(50).unwrap_or_default(), "fix");
    streams.sort_by_key(|(_, s)| s.timestamp);
    let mut sizes = Vec::new();
    for compression in ["none", "zstd", "lz4"] {
        let path = dir.join(format!("sensors-{compression}.mcap"));
        let mut recorder = Harness::new(Recorder::info(), Recorder::default());
        let _ = recorder.set_property("path", path.display().to_string());
        let _ = recorder.set_property("compression", compression);
        for (input, sample) in &streams {
            recorder.push_sample(input, sample.clone());
        }
        if recorder.finish().is_err() {
            println!("recording the sensors failed ({compression})");
            return;
        }
        sizes.push((compression, std::fs::metadata(&path).map_or(0, |m| m.len())));
    }
    let plain = sizes.first().map_or(1, |(_, s)| *s).max(1);
    println!("\ncompression on 5 s of the simulated camera (640×480, 30 Hz), lidar, IMU and GNSS:");
    for (compression, size) in sizes {
        println!(
            "  {compression:<5} {:>7.1} MB   {:.2}× smaller",
            size as f64 / 1e6,
            plain as f64 / size.max(1) as f64
        );
    }
}

fn compression_of(name: &str) -> Option<mcap::Compression> {
    match name {
        "zstd" => Some(mcap::Compression::Zstd),
        "lz4" => Some(mcap::Compression::Lz4),
        _ => None,
    }
}

/// Message bytes per second through the bare `mcap` loop, same frames, same compression.
fn bare_loop(dir: &std::path::Path, frames: &[Payload], compression: &str) -> Option<f64> {
    let images: Vec<&Image> = frames
        .iter()
        .filter_map(|f| {
            if let Payload::Image(image) = f {
                Some(image)
            } else {
                None
            }
        })
        .collect();
    let first = images.first()?;
    kairos_benches::bare_mcap_rate_compressed(
        &dir.join("bare.mcap"),
        (first.width, first.height),
        images.len(),
        |i| images.get(i).map_or(&[][..], |image| &image.pixels[..]),
        compression_of(compression),
    )
}

/// Message bytes per second through the recorder component, driven by the offline harness.
fn recorder(dir: &std::path::Path, frames: &[Payload], compression: &str) -> Option<f64> {
    let path = dir.join("ours.mcap");
    let _ = std::fs::remove_file(&path);
    let mut harness = Harness::new(Recorder::info(), Recorder::default());
    harness.set_property("path", path.display().to_string()).ok()?;
    harness.set_property("compression", compression).ok()?;
    // Image messages: the pixels and a small header, as the bare loop counts them.
    let bytes: usize = frames.iter().map(Payload::heavy_size_bytes).sum();
    for (index, frame) in frames.iter().enumerate() {
        harness.push("in1", frame.clone(), Timestamp::from_millis(index as i64 * 33));
    }
    let started = Instant::now();
    harness.run().ok()?;
    harness.finish().ok()?;
    let elapsed = started.elapsed().as_secs_f64();
    let report = kairos_pack_recording::inspect(&path).ok()?;
    (report.messages == frames.len() as u64).then(|| bytes as f64 / elapsed)
}

fn main() {
    header(
        "7. Recording throughput: the recorder vs a bare mcap writer loop",
        "throughput, one thread, each compression, to the same folder (message bytes per second)",
        "1920×1080 frames of the simulated camera (6.2 MB), foxglove.RawImage",
    );
    let frames = frames(size(12, 48));
    let Ok(dir) =
        std::env::var("KAIROS_BENCH_DIR").map_or_else(|_| tempfile::tempdir(), tempfile::tempdir_in)
    else {
        return;
    };
    let goal = Goal::AtLeast(0.9);
    let mut table = Table::new(&["compression", "recorder", "bare mcap loop", "ratio", "goal"]);
    let mb = |v: f64| format!("{:.0} MB/s", v / 1e6);
    for compression in ["none", "zstd", "lz4"] {
        let mut ours = Vec::new();
        let mut bare = Vec::new();
        for repetition in 0..repetitions() {
            let pair = if repetition % 2 == 0 {
                (
                    recorder(dir.path(), &frames, compression),
                    bare_loop(dir.path(), &frames, compression),
                )
            } else {
                let b = bare_loop(dir.path(), &frames, compression);
                (recorder(dir.path(), &frames, compression), b)
            };
            let (Some(o), Some(b)) = pair else {
                println!("a run failed ({compression})");
                return;
            };
            ours.push(o);
            bare.push(b);
        }
        let r = Spread::of(ours.iter().zip(&bare).map(|(o, b)| o / b));
        table.row(vec![
            compression.into(),
            Spread::of(ours.iter().copied()).show(mb),
            Spread::of(bare.iter().copied()).show(mb),
            r.show(ratio),
            format!(
                "{} {}",
                goal.show(),
                if goal.met_by(r.median) { "met" } else { "missed" }
            ),
        ]);
    }
    table.print();
    compression_ratios(dir.path());
    println!(
        "\nmachine: {}\nmode: {}",
        machine(),
        if quick() { "quick" } else { "full" }
    );
}
