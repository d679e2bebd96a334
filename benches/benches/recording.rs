//! Benchmark 7: recording throughput, the recorder component against a bare `mcap` writer loop writing the
//! same samples (the same Foxglove `RawImage` encoding, no compression, synced to disk at the end) to the
//! same folder.

use std::sync::Arc;
use std::time::Instant;

use kairos_benches::{Goal, Spread, Table, header, machine, quick, ratio, repetitions, size};
use kairos_pack_recording::recorder::Recorder;
use kairos_sdk::harness::Harness;
use kairos_sdk::{Image, Payload, PixelFormat, Timestamp};

const WIDTH: u32 = 1920;
const HEIGHT: u32 = 1080;

fn frames(count: usize) -> Vec<Payload> {
    (0..count)
        .map(|i| {
            let pixels: Vec<u8> = (0..(WIDTH * HEIGHT * 3) as usize)
                .map(|p| ((p + i * 7) % 251) as u8)
                .collect();
            Payload::Image(
                Image::packed(WIDTH, HEIGHT, PixelFormat::Rgb8, Arc::<[u8]>::from(pixels))
                    .unwrap_or_else(|_| unreachable!()),
            )
        })
        .collect()
}

/// Bytes per second through the bare `mcap` loop, same frames.
fn bare_loop(dir: &std::path::Path, frames: &[Payload]) -> Option<f64> {
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
    kairos_benches::bare_mcap_rate(
        &dir.join("bare.mcap"),
        first.width,
        first.height,
        images.len(),
        |i| images.get(i).map_or(&[][..], |image| &image.pixels[..]),
    )
}

/// Bytes per second through the recorder component, driven by the offline harness.
fn recorder(dir: &std::path::Path, frames: &[Payload]) -> Option<f64> {
    let path = dir.join("ours.mcap");
    let _ = std::fs::remove_file(&path);
    let mut harness = Harness::new(Recorder::info(), Recorder::default());
    harness.set_property("path", path.display().to_string()).ok()?;
    harness.set_property("compression", "none").ok()?;
    for (index, frame) in frames.iter().enumerate() {
        harness.push("in1", frame.clone(), Timestamp::from_millis(index as i64 * 33));
    }
    let started = Instant::now();
    harness.run().ok()?;
    harness.finish().ok()?;
    let elapsed = started.elapsed().as_secs_f64();
    let report = kairos_pack_recording::inspect(&path).ok()?;
    (report.messages == frames.len() as u64)
        .then(|| std::fs::metadata(&path).map_or(0.0, |m| m.len() as f64) / elapsed)
}

fn main() {
    header(
        "7. Recording throughput: the recorder vs a bare mcap writer loop",
        "throughput, one thread, uncompressed, to the same folder",
        "1920×1080 RGB frames (6.2 MB), foxglove.RawImage",
    );
    let frames = frames(size(12, 48));
    let Ok(dir) =
        std::env::var("KAIROS_BENCH_DIR").map_or_else(|_| tempfile::tempdir(), tempfile::tempdir_in)
    else {
        return;
    };
    let mut ours = Vec::new();
    let mut bare = Vec::new();
    for repetition in 0..repetitions() {
        let pair = if repetition % 2 == 0 {
            (recorder(dir.path(), &frames), bare_loop(dir.path(), &frames))
        } else {
            let b = bare_loop(dir.path(), &frames);
            (recorder(dir.path(), &frames), b)
        };
        let (Some(o), Some(b)) = pair else {
            println!("a run failed");
            return;
        };
        ours.push(o);
        bare.push(b);
    }
    let goal = Goal::AtLeast(0.9);
    let r = Spread::of(ours.iter().zip(&bare).map(|(o, b)| o / b));
    let mut table = Table::new(&["variant", "throughput", "ratio", "goal"]);
    let mb = |v: f64| format!("{:.0} MB/s", v / 1e6);
    table.row(vec![
        "recorder component".into(),
        Spread::of(ours.iter().copied()).show(mb),
        r.show(ratio),
        format!(
            "{} {}",
            goal.show(),
            if goal.met_by(r.median) { "met" } else { "missed" }
        ),
    ]);
    table.row(vec![
        "bare mcap loop".into(),
        Spread::of(bare.iter().copied()).show(mb),
        "1.00×".into(),
        "baseline".into(),
    ]);
    table.print();
    println!(
        "\nmachine: {}\nmode: {}",
        machine(),
        if quick() { "quick" } else { "full" }
    );
}
