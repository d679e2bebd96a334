//! The image sequence and the image writer on real files: timing from a rate, a CSV and file names,
//! loops, every pixel format back and forth, and bad folders and CSVs.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use std::path::Path;
use std::sync::Arc;

use kairos_pack_video::files::{ImageSequence, ImageWriter, sequence_descriptor, writer_descriptor};
use kairos_sdk::harness::{Harness, HarnessOutput};
use kairos_sdk::{Image, Payload, PixelFormat, Timestamp};

/// Three 8×4 RGB images, `frame_{n}.png`, each filled with the value `40 × (n + 1)`.
fn folder_of_images(dir: &Path, names: &[&str]) {
    for (index, name) in names.iter().enumerate() {
        let value = 40 * (index as u8 + 1);
        image::RgbImage::from_pixel(8, 4, image::Rgb([value, value, value]))
            .save(dir.join(name))
            .unwrap();
    }
}

fn sequence(properties: &[(&str, kairos_sdk::Value)]) -> Harness {
    let mut harness = Harness::new(sequence_descriptor(), ImageSequence::default());
    for (name, value) in properties {
        harness.set_property(name, value.clone()).unwrap();
    }
    harness
}

fn play(mut harness: Harness, cycles: usize) -> HarnessOutput {
    let mut out = HarnessOutput::default();
    for _ in 0..cycles {
        out.extend(harness.run().unwrap());
    }
    out.extend(harness.finish().unwrap());
    out
}

fn times_ms(out: &HarnessOutput) -> Vec<i64> {
    let samples = out.samples("image");
    let first = samples[0].timestamp.0;
    samples
        .iter()
        .map(|s| (s.timestamp.0 - first) / 1_000_000)
        .collect()
}

fn first_values(out: &HarnessOutput) -> Vec<u8> {
    out.samples("image")
        .iter()
        .map(|s| match &s.payload {
            Payload::Image(image) => image.pixels[0],
            other => panic!("{other:?}"),
        })
        .collect()
}

#[test]
fn a_folder_plays_in_name_order_at_the_rate() {
    let dir = tempfile::tempdir().unwrap();
    folder_of_images(dir.path(), &["a.png", "b.png", "c.png"]);
    std::fs::write(dir.path().join("notes.txt"), "not an image").unwrap();
    let out = play(
        sequence(&[
            ("folder", dir.path().display().to_string().into()),
            ("rate", 4.0.into()),
        ]),
        6,
    );
    assert_eq!(first_values(&out), [40, 80, 120]);
    assert_eq!(times_ms(&out), [0, 250, 500]);
    let Payload::Image(image) = &out.samples("image")[0].payload else {
        panic!()
    };
    assert_eq!(
        (image.width, image.height, image.format),
        (8, 4, PixelFormat::Rgb8)
    );
}

#[test]
fn times_come_from_a_csv_or_from_the_names() {
    let dir = tempfile::tempdir().unwrap();
    folder_of_images(dir.path(), &["0001000.png", "0001040.png", "0001200.png"]);
    let out = play(
        sequence(&[
            ("folder", dir.path().display().to_string().into()),
            ("timing", "names".into()),
            ("name_unit", "ms".into()),
        ]),
        6,
    );
    assert_eq!(times_ms(&out), [0, 40, 200]);

    let csv = dir.path().join("times.csv");
    std::fs::write(
        &csv,
        "file,seconds\n0001000.png,10.0\n0001040.png,10.5\n0001200.png,12.0\n",
    )
    .unwrap();
    let out = play(
        sequence(&[
            ("folder", dir.path().display().to_string().into()),
            ("timing", "csv".into()),
            ("csv", csv.display().to_string().into()),
            ("speed", 2.0.into()),
        ]),
        6,
    );
    assert_eq!(times_ms(&out), [0, 250, 1000]);
}

#[test]
fn a_loop_starts_again_after_the_last_image() {
    let dir = tempfile::tempdir().unwrap();
    folder_of_images(dir.path(), &["a.png", "b.png"]);
    let out = play(
        sequence(&[
            ("folder", dir.path().display().to_string().into()),
            ("loop", true.into()),
        ]),
        5,
    );
    assert_eq!(first_values(&out)[..5], [40, 80, 40, 80, 40]);
}

#[test]
fn bad_folders_and_csvs_are_refused_with_the_place() {
    let dir = tempfile::tempdir().unwrap();
    let empty = play_error(&[("folder", dir.path().display().to_string().into())]);
    assert!(empty.contains("holds no image"), "{empty}");
    let missing = play_error(&[("folder", "/nonexistent/images".into())]);
    assert!(missing.contains("/nonexistent/images"), "{missing}");
    folder_of_images(dir.path(), &["a.png", "b.png"]);
    let csv = dir.path().join("times.csv");
    std::fs::write(&csv, "a.png,0\nb.png,soon\n").unwrap();
    let bad = play_error(&[
        ("folder", dir.path().display().to_string().into()),
        ("timing", "csv".into()),
        ("csv", csv.display().to_string().into()),
    ]);
    assert!(bad.contains("times.csv:2"), "{bad}");
    std::fs::write(&csv, "a.png,0\n").unwrap();
    let absent = play_error(&[
        ("folder", dir.path().display().to_string().into()),
        ("timing", "csv".into()),
        ("csv", csv.display().to_string().into()),
    ]);
    assert!(absent.contains("no time for b.png"), "{absent}");
}

fn play_error(properties: &[(&str, kairos_sdk::Value)]) -> String {
    sequence(properties).run().unwrap_err().to_string()
}

#[test]
fn the_writer_writes_every_format_and_the_files_read_back() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    for format in ["png", "jpeg"] {
        let mut harness = Harness::new(writer_descriptor(), ImageWriter::default());
        harness
            .set_property("folder", out.join(format).display().to_string())
            .unwrap();
        harness.set_property("format", format).unwrap();
        let rgb: Vec<u8> = (0..6 * 4 * 3).map(|i| (i * 3) as u8).collect();
        let bgra: Vec<u8> = (0..6 * 4 * 4).map(|i| (i * 2) as u8).collect();
        let grey: Vec<u8> = (0..6 * 4).map(|i| (i * 10) as u8).collect();
        for (index, (pixel_format, bytes)) in [
            (PixelFormat::Rgb8, rgb),
            (PixelFormat::Bgra8, bgra),
            (PixelFormat::Gray8, grey),
        ]
        .into_iter()
        .enumerate()
        {
            let image = Image::packed(6, 4, pixel_format, Arc::<[u8]>::from(bytes)).unwrap();
            harness.push("image", Payload::Image(image), Timestamp(1_000 + index as i64));
        }
        harness.finish().unwrap();
        let mut files: Vec<_> = std::fs::read_dir(out.join(format))
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        files.sort();
        assert_eq!(files.len(), 3, "{files:?}");
        let back = kairos_pack_video::files::load(&files[0]).unwrap();
        assert_eq!((back.width, back.height), (6, 4));
        if format == "png" {
            // Lossless: the RGB image comes back exactly.
            assert_eq!(&back.pixels[..6], &[0, 3, 6, 9, 12, 15]);
        }
    }
}

/// A depth camera's frame: 16-bit grey written as a 16-bit PNG and played back by the sequence whole.
#[test]
fn sixteen_bit_grey_is_written_and_played_back_whole() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("depth");
    let mut harness = Harness::new(writer_descriptor(), ImageWriter::default());
    harness.set_property("folder", out.display().to_string()).unwrap();
    // Millimetres from 0 (no return) to 65 000, across both bytes.
    let depth: Vec<u16> = (0..6 * 4).map(|i| (i * 2_826) as u16).collect();
    let bytes: Vec<u8> = depth.iter().flat_map(|v| v.to_le_bytes()).collect();
    let image = Image::packed(6, 4, PixelFormat::Gray16, Arc::<[u8]>::from(bytes.clone())).unwrap();
    harness.push("image", Payload::Image(image), Timestamp(1_000));
    harness.finish().unwrap();
    let file = std::fs::read_dir(&out).unwrap().next().unwrap().unwrap().path();
    let back = kairos_pack_video::files::load(&file).unwrap();
    assert_eq!(back.format, PixelFormat::Gray16);
    assert_eq!((back.width, back.height), (6, 4));
    assert_eq!(&back.pixels[..], &bytes[..], "every value kept");
    // Played as a camera, the folder gives the same frame.
    let played = play(
        sequence(&[("folder", kairos_sdk::Value::Text(out.display().to_string()))]),
        1,
    );
    let Payload::Image(frame) = &played.samples("image")[0].payload else {
        panic!("an image");
    };
    assert_eq!(
        (frame.format, &frame.pixels[..]),
        (PixelFormat::Gray16, &bytes[..])
    );
}

#[test]
fn a_folder_that_cannot_be_made_fails_the_writer_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("plain-file");
    std::fs::write(&file, "").unwrap();
    let mut harness = Harness::new(writer_descriptor(), ImageWriter::default());
    harness
        .set_property("folder", file.join("frames").display().to_string())
        .unwrap();
    let error = harness.run().unwrap_err().to_string();
    assert!(error.contains("plain-file"), "{error}");
}
