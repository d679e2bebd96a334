//! Benchmark 20: the vision pack's image operations against OpenCV on the same machine, same run, same
//! images (see BENCHMARKS.md). Each Kairos figure is the time through the component in the offline
//! harness (read, kernel, new image from the pool, write; no thread hop); OpenCV's is `cv2` called from
//! Python with one thread, whose call overhead (about 1 µs) is within the noise.
//!
//! `cargo bench -p kairos-benches --bench vision` with a `python3` that has `opencv-python-headless`
//! and numpy first on PATH (`tests/run` puts one in `target/test-python/bin`).

use std::collections::BTreeMap;
use std::process::Command;
use std::time::Instant;

use kairos_pack_vision::{codecs, images};
use kairos_sdk_core::harness::Harness;
use kairos_sdk_core::{Component, ComponentInfo, Image, Payload, PixelFormat, Timestamp};

const ITERATIONS: usize = 40;
const ROUNDS: usize = 3;

/// A smooth scene with hard edges: gradients, a bright rectangle and a dark disc.
fn scene(width: usize, height: usize) -> Vec<u8> {
    let mut pixels = vec![0_u8; width * height * 3];
    for y in 0..height {
        for x in 0..width {
            let at = (y * width + x) * 3;
            let mut colour = [
                (x * 255 / width) as u8,
                (y * 255 / height) as u8,
                ((x + y) % 256) as u8,
            ];
            if (width / 4..width / 2).contains(&x) && (height / 4..height / 2).contains(&y) {
                colour = [250, 250, 250];
            }
            let (dx, dy) = (x as f64 - 0.7 * width as f64, y as f64 - 0.6 * height as f64);
            if dx.hypot(dy) < height as f64 / 6.0 {
                colour = [20, 30, 40];
            }
            pixels[at..at + 3].copy_from_slice(&colour);
        }
    }
    pixels
}

fn median_us(mut run: impl FnMut()) -> f64 {
    for _ in 0..5 {
        run();
    }
    let mut times: Vec<f64> = (0..ITERATIONS)
        .map(|_| {
            let start = Instant::now();
            run();
            start.elapsed().as_secs_f64() * 1e6
        })
        .collect();
    times.sort_by(f64::total_cmp);
    times[times.len() / 2]
}

/// The median time of one image through `component` with `properties`.
fn through(
    info: ComponentInfo,
    component: impl Component,
    properties: &[(&str, kairos_sdk_core::Value)],
    image: &Image,
) -> f64 {
    let mut harness = Harness::new(info, component);
    // A diagram's output keeps a few samples; so does this one, so pixel buffers recycle as they do there.
    harness.set_output_capacity(4);
    for (name, value) in properties {
        harness
            .set_property(name, value.clone())
            .expect("a valid property");
    }
    let mut t = 0;
    median_us(|| {
        t += 1;
        harness.push("in", Payload::Image(image.clone()), Timestamp::from_millis(t));
        let out = harness.run().expect("the component runs");
        assert!(!out.all().values().all(Vec::is_empty), "an output");
    })
}

/// Whether the operation `name` is measured: all of them, or those `KAIROS_BENCH_ONLY` names
/// (comma-separated prefixes, `canny,resize_0.4`), for working on one kernel.
fn wanted(name: &str) -> bool {
    std::env::var("KAIROS_BENCH_ONLY").map_or(true, |only| {
        only.split(',').any(|prefix| name.starts_with(prefix.trim()))
    })
}

fn ours(rgb: &Image, grey: &Image) -> BTreeMap<&'static str, f64> {
    type Measure<'a> = Box<dyn FnOnce() -> f64 + 'a>;
    let mut operations: Vec<(&'static str, Measure<'_>)> = vec![
        (
            "rgb_to_gray",
            Box::new(|| {
                through(
                    images::Convert::info(),
                    images::Convert,
                    &[("to", "gray".into())],
                    rgb,
                )
            }),
        ),
        (
            "rgb_to_bgr",
            Box::new(|| {
                through(
                    images::Convert::info(),
                    images::Convert,
                    &[("to", "bgr".into())],
                    rgb,
                )
            }),
        ),
        (
            "resize_half_bilinear",
            Box::new(|| {
                through(
                    images::Resize::info(),
                    images::Resize::default(),
                    &[("scale", 0.5.into())],
                    rgb,
                )
            }),
        ),
    ];
    for (name, scale, interpolation) in [
        ("resize_0.4_bilinear", 0.4, "bilinear"),
        ("resize_0.75_bilinear", 0.75, "bilinear"),
        ("resize_0.4_area", 0.4, "area"),
    ] {
        operations.push((
            name,
            Box::new(move || {
                through(
                    images::Resize::info(),
                    images::Resize::default(),
                    &[("scale", scale.into()), ("interpolation", interpolation.into())],
                    rgb,
                )
            }),
        ));
    }
    operations.push((
        "gaussian_blur_5x5",
        Box::new(|| through(images::GaussianBlur::info(), images::GaussianBlur, &[], rgb)),
    ));
    operations.push((
        "canny",
        Box::new(|| through(images::Canny::info(), images::Canny::default(), &[], grey)),
    ));
    // libjpeg-turbo where the system has it (the encoder `auto` picks), and the pure-Rust one.
    operations.push((
        "jpeg_encode_q90",
        Box::new(|| {
            through(
                codecs::JpegEncode::info(),
                codecs::JpegEncode::default(),
                &[("quality", 90_i64.into())],
                rgb,
            )
        }),
    ));
    operations.push((
        "jpeg_encode_q90_rust",
        Box::new(|| {
            through(
                codecs::JpegEncode::info(),
                codecs::JpegEncode::default(),
                &[("quality", 90_i64.into()), ("encoder", "rust".into())],
                rgb,
            )
        }),
    ));
    operations
        .into_iter()
        .filter(|(name, _)| wanted(name))
        .map(|(name, measure)| (name, measure()))
        .collect()
}

/// The photographs `peers/opencv/photos.py` writes (scikit-image's sample data): 640×480 and 1920×1080.
fn photographs(dir: &std::path::Path) -> Option<[Vec<u8>; 2]> {
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/peers/opencv/photos.py");
    let done = Command::new("python3").arg(script).arg(dir).output().ok()?;
    if !done.status.success() {
        eprintln!(
            "no photographs (scikit-image's sample data): {}",
            String::from_utf8_lossy(&done.stderr)
        );
        return None;
    }
    Some([
        std::fs::read(dir.join("photo640.rgb")).ok()?,
        std::fs::read(dir.join("photo1080.rgb")).ok()?,
    ])
}

fn opencv(raw: &std::path::Path, width: usize, height: usize) -> Option<BTreeMap<String, f64>> {
    let script = concat!(env!("CARGO_MANIFEST_DIR"), "/peers/opencv/ops.py");
    let output = Command::new("python3")
        .args([
            script,
            &raw.display().to_string(),
            &width.to_string(),
            &height.to_string(),
            &ITERATIONS.to_string(),
        ])
        .output()
        .ok()?;
    if !output.status.success() {
        eprintln!(
            "OpenCV side failed (is opencv-python-headless installed?): {}",
            String::from_utf8_lossy(&output.stderr)
        );
        return None;
    }
    serde_json::from_slice(&output.stdout).ok()
}

/// A 100 000-point cloud: a ground disc and scattered objects, spread as a spinning lidar's would be.
fn lidar_cloud() -> kairos_sdk_core::PointCloud {
    let mut state = 0x2545_f491_u64;
    let mut next = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state % 1_000_000) as f32 / 1_000_000.0
    };
    let points = (0..100_000)
        .map(|k| {
            let (angle, range) = (next() * std::f32::consts::TAU, 2.0 + 60.0 * next() * next());
            let z = if k % 5 == 0 {
                -1.8 + 2.0 * next()
            } else {
                -1.8 + 0.02 * next()
            };
            glam::Vec3::new(range * angle.cos(), range * angle.sin(), z)
        })
        .collect();
    kairos_sdk_core::PointCloud {
        points,
        intensity: None,
    }
}

/// Voxel downsampling of 100 000 points and one filter step, in µs and as a multiple of real time.
fn perception_figures() {
    use kairos_pack_fusion::ins::{InitialUncertainty, Ins, InsConfig};
    let cloud = lidar_cloud();
    let cloud_sample = Payload::PointCloud(std::sync::Arc::new(cloud));
    let mut voxels = Harness::new(
        kairos_pack_lidar::processing::VoxelGrid::info(),
        kairos_pack_lidar::processing::VoxelGrid,
    );
    voxels.set_property("leaf", 0.2).expect("a valid leaf");
    let mut t = 0;
    let voxel_us = median_us(|| {
        t += 1;
        voxels.push("in", cloud_sample.clone(), Timestamp::from_millis(t));
        voxels.run().expect("it runs");
    });
    let start = InitialUncertainty {
        position_m: 1.0,
        velocity_m_s: 0.5,
        tilt_rad: 0.01,
        heading_rad: 0.1,
    };
    let mut ins = Ins::new(
        InsConfig::default(),
        (glam::DVec3::ZERO, glam::DVec3::ZERO, glam::DQuat::IDENTITY),
        start,
        0.0,
    );
    let mut time = 0.0;
    let gravity = glam::DVec3::new(0.0, 0.0, 9.806_65);
    let propagate_us = median_us(|| {
        time += 0.01;
        ins.propagate(time, glam::DVec3::new(0.0, 0.0, 0.1), gravity);
    });
    let correct_us = median_us(|| {
        ins.correct_position(time, glam::DVec3::new(0.1, 0.0, 0.0), glam::DVec3::splat(0.5));
    });
    println!("\nlidar and fusion, median µs (multiple of real time: the sensor's period / the time taken)");
    println!(
        "voxel grid 0.2 m, 100 000 points: {voxel_us:>9.1} µs   {:.0}× real time at 10 Hz",
        100_000.0 / voxel_us
    );
    println!(
        "EKF step, IMU propagation:        {propagate_us:>9.1} µs   {:.0}× real time at 100 Hz",
        10_000.0 / propagate_us
    );
    println!(
        "EKF step, GNSS correction:        {correct_us:>9.1} µs   {:.0}× real time at 10 Hz",
        100_000.0 / correct_us
    );
}

fn main() {
    if std::env::var_os("KAIROS_BENCH_ONLY").is_none() {
        perception_figures();
    }
    let dir = tempfile::tempdir().expect("a temporary folder");
    println!("benchmark 20: vision operations, Kairos component vs OpenCV (one thread), median µs per image");
    // The OpenCV side reads its JPEG encoder's and the comparisons' images from raw files.
    let mut images = vec![
        ("synthetic scene", 640_usize, 480_usize, scene(640, 480)),
        ("synthetic scene", 1920, 1080, scene(1920, 1080)),
    ];
    // Kept between runs: the photographs come from a 13 MB download the first time.
    let photos = std::path::Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../target/bench-data/photos"
    ));
    let _ = std::fs::create_dir_all(photos);
    if let Some([small, large]) = photographs(photos) {
        images.push(("photograph", 640, 480, small));
        images.push(("photograph", 1920, 1080, large));
    }
    for (kind, width, height, pixels) in images {
        let raw = dir.path().join(format!("{}{width}.rgb", kind.replace(' ', "_")));
        std::fs::write(&raw, &pixels).expect("writing the image");
        let rgb =
            Image::packed(width as u32, height as u32, PixelFormat::Rgb8, pixels.clone()).expect("an image");
        // The grey input is the same for both: the BT.601 weights, which both sides use.
        let grey_pixels: Vec<u8> = pixels
            .chunks_exact(3)
            .map(|p| {
                ((u32::from(p[0]) * 9798 + u32::from(p[1]) * 19235 + u32::from(p[2]) * 3735 + 16384) >> 15)
                    as u8
            })
            .collect();
        let grey =
            Image::packed(width as u32, height as u32, PixelFormat::Gray8, grey_pixels).expect("an image");
        let mut ratios: BTreeMap<&str, Vec<(f64, f64, f64)>> = BTreeMap::new();
        for _ in 0..ROUNDS {
            let kairos = ours(&rgb, &grey);
            let Some(cv) = opencv(&raw, width, height) else {
                return;
            };
            for (name, time) in &kairos {
                // Both JPEG encoders against OpenCV's one.
                if let Some(theirs) = cv.get(name.trim_end_matches("_rust")) {
                    ratios
                        .entry(name)
                        .or_default()
                        .push((*time, *theirs, time / theirs));
                }
            }
        }
        println!(
            "\n{width}×{height} RGB, {kind}   Kairos µs   OpenCV µs   ratio (3 rounds: median [min–max])"
        );
        for (name, rounds) in ratios {
            let mut by_ratio = rounds.clone();
            by_ratio.sort_by(|a, b| a.2.total_cmp(&b.2));
            let (k, c, r) = by_ratio[by_ratio.len() / 2];
            println!(
                "{name:<22} {k:>9.1} {c:>11.1}   {r:.2}× [{:.2}–{:.2}]",
                by_ratio[0].2,
                by_ratio[by_ratio.len() - 1].2
            );
        }
    }
}
