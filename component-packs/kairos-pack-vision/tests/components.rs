//! The vision components through the offline harness: a lane-marking chain on a drawn road, and each
//! bad input refused with its reason.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use kairos_pack_vision::{codecs, images, lines};
use kairos_sdk::harness::{Harness, HarnessError};
use kairos_sdk::{Component, ComponentInfo, Image, Payload, PixelFormat, Sample, Timestamp};

/// Runs one component on `image` with `properties`; its first output's sample, or the failure in words.
fn through(
    info: ComponentInfo,
    component: impl Component,
    properties: &[(&str, kairos_sdk::Value)],
    input: &str,
    payload: Payload,
) -> Result<Sample, HarnessError> {
    let output = info.outputs[0].name.clone();
    let mut harness = Harness::new(info, component);
    for (name, value) in properties {
        harness.set_property(name, value.clone())?;
    }
    harness.push(input, payload, Timestamp::from_millis(40));
    let out = harness.run()?;
    Ok(out
        .samples(&output)
        .first()
        .cloned()
        .expect("the component wrote its output"))
}

fn image(sample: &Sample) -> &Image {
    match &sample.payload {
        Payload::Image(image) => image,
        other => panic!("not an image: {other:?}"),
    }
}

/// A 320×240 road: dark grey, two bright slanted markings converging upwards, sky above.
fn road() -> Image {
    let (w, h) = (320_usize, 240_usize);
    let mut pixels = vec![0_u8; w * h * 3];
    for y in 0..h {
        for x in 0..w {
            let at = (y * w + x) * 3;
            let colour = if y < h / 2 {
                [90, 140, 220]
            } else {
                let t = (y - h / 2) as f64 / (h / 2) as f64;
                let left = 150.0 - 120.0 * t;
                let right = 170.0 + 120.0 * t;
                let on = |edge: f64| (x as f64 - edge).abs() < 2.0 + 3.0 * t;
                if on(left) || on(right) {
                    [240, 240, 240]
                } else {
                    [80, 80, 84]
                }
            };
            pixels[at..at + 3].copy_from_slice(&colour);
        }
    }
    Image::packed(w as u32, h as u32, PixelFormat::Rgb8, pixels).unwrap()
}

#[test]
fn a_lane_chain_finds_both_markings_and_draws_them() {
    let grey = through(
        images::Convert::info(),
        images::Convert,
        &[],
        "in",
        Payload::Image(road()),
    )
    .unwrap();
    assert_eq!(image(&grey).format, PixelFormat::Gray8);
    assert_eq!(
        grey.timestamp,
        Timestamp::from_millis(40),
        "the camera's time is kept"
    );
    let blurred = through(
        images::GaussianBlur::info(),
        images::GaussianBlur,
        &[],
        "in",
        grey.payload.clone(),
    )
    .unwrap();
    let edges = through(
        images::Canny::info(),
        images::Canny::default(),
        &[],
        "in",
        blurred.payload,
    )
    .unwrap();
    let found = through(
        lines::HoughLines::info(),
        lines::HoughLines,
        &[("min_votes", 30_i64.into()), ("min_length", 40.0.into())],
        "in",
        edges.payload,
    )
    .unwrap();
    let Payload::Matrix(segments) = &found.payload else {
        panic!("{:?}", found.payload)
    };
    assert!(segments.rows >= 2, "{segments:?}");
    // One segment leans each way: the left marking goes up to the right, the right one up to the left.
    let slopes: Vec<f64> = segments
        .values
        .chunks_exact(4)
        .map(|s| (s[2] - s[0]) / (s[3] - s[1]))
        .collect();
    assert!(
        slopes.iter().any(|s| *s < -0.5) && slopes.iter().any(|s| *s > 0.5),
        "{slopes:?}"
    );

    let mut overlay = Harness::new(lines::Overlay::info(), lines::Overlay::default());
    // The harness delivers one sample at a time and does not block, and every input counts as
    // connected: the drawings go first here, where in a running diagram the overlay waits for them.
    overlay.push("lines", found.payload.clone(), Timestamp::from_millis(40));
    let no_boxes = kairos_sdk::Matrix {
        rows: 0,
        cols: 4,
        values: Vec::new(),
    };
    overlay.push(
        "boxes",
        Payload::Matrix(no_boxes.into()),
        Timestamp::from_millis(40),
    );
    overlay.push("image", Payload::Image(road()), Timestamp::from_millis(40));
    let drawn = overlay.run().unwrap();
    let drawn = image(&drawn.samples("out")[0]).clone();
    let reds = drawn.pixels.chunks_exact(3).filter(|p| p == &[255, 0, 0]).count();
    assert!(reds > 200, "{reds} red pixels");
    assert!(
        road().pixels.chunks_exact(3).all(|p| p != [255, 0, 0]),
        "the input is left unchanged"
    );
}

#[test]
fn a_polyline_is_drawn_leg_by_leg_up_to_its_first_nan() {
    // A polyline: an L from (10, 10) down to (10, 100) and across to (100, 100); NaN ends the row.
    let mut overlay = Harness::new(lines::Overlay::info(), lines::Overlay::default());
    let polyline = kairos_sdk::Matrix {
        rows: 1,
        cols: 8,
        values: vec![10.0, 10.0, 10.0, 100.0, 100.0, 100.0, f64::NAN, 0.0],
    };
    overlay.push(
        "lines",
        Payload::Matrix(polyline.into()),
        Timestamp::from_millis(40),
    );
    let no_boxes = kairos_sdk::Matrix {
        rows: 0,
        cols: 4,
        values: Vec::new(),
    };
    overlay.push(
        "boxes",
        Payload::Matrix(no_boxes.into()),
        Timestamp::from_millis(40),
    );
    overlay.push("image", Payload::Image(road()), Timestamp::from_millis(40));
    let drawn = overlay.run().unwrap();
    let drawn = image(&drawn.samples("out")[0]).clone();
    let red = |x: usize, y: usize| drawn.pixels[(y * 320 + x) * 3..][..3] == [255, 0, 0];
    assert!(
        red(10, 50) && red(50, 100) && !red(50, 50),
        "both legs, nothing across"
    );
}

#[test]
fn images_of_the_wrong_format_are_failed_with_the_reason_and_the_fix() {
    let error = through(
        images::Canny::info(),
        images::Canny::default(),
        &[],
        "in",
        Payload::Image(road()),
    )
    .unwrap_err()
    .to_string();
    assert!(
        error.contains("grey images") && error.contains("Rgb8") && error.contains("vision.convert"),
        "{error}"
    );
    let deep = Image::packed(4, 4, PixelFormat::Gray16, vec![0_u8; 32]).unwrap();
    let error = through(
        images::Resize::info(),
        images::Resize::default(),
        &[],
        "in",
        Payload::Image(deep),
    )
    .unwrap_err()
    .to_string();
    assert!(error.contains("8-bit") && error.contains("Gray16"), "{error}");
    let error = through(
        images::Convert::info(),
        images::Convert,
        &[],
        "in",
        Payload::F64(1.0),
    )
    .unwrap_err()
    .to_string();
    assert!(error.contains("expects an image"), "{error}");
    let error = through(
        codecs::JpegDecode::info(),
        codecs::JpegDecode,
        &[],
        "in",
        Payload::Bytes(b"GIF89a".as_slice().into()),
    )
    .unwrap_err()
    .to_string();
    assert!(error.contains("not a readable JPEG"), "{error}");
}

#[test]
fn zero_sized_and_outside_regions_and_even_blur_sizes_are_refused() {
    // A zero-sized region is refused as a property value, before anything runs.
    let error = through(
        images::Crop::info(),
        images::Crop,
        &[("width", 0_i64.into())],
        "in",
        Payload::Image(road()),
    )
    .unwrap_err()
    .to_string();
    assert!(error.contains("width"), "{error}");
    let error = through(
        images::Crop::info(),
        images::Crop,
        &[("x", 300_i64.into()), ("width", 100_i64.into())],
        "in",
        Payload::Image(road()),
    )
    .unwrap_err()
    .to_string();
    assert!(error.contains("does not fit in the 320×240 image"), "{error}");
    let error = through(
        images::GaussianBlur::info(),
        images::GaussianBlur,
        &[("size", 4_i64.into())],
        "in",
        Payload::Image(road()),
    )
    .unwrap_err()
    .to_string();
    assert!(
        error.contains("must be odd") && error.contains("set it to 5"),
        "{error}"
    );
    let error = through(
        images::Resize::info(),
        images::Resize::default(),
        &[("scale", 0.001.into())],
        "in",
        Payload::Image(road()),
    )
    .unwrap_err()
    .to_string();
    assert!(error.contains("scale"), "{error}");
}

#[test]
fn geometry_and_codecs_keep_sizes_and_content() {
    let crop = through(
        images::Crop::info(),
        images::Crop,
        &[
            ("x", 10_i64.into()),
            ("y", 20_i64.into()),
            ("width", 30_i64.into()),
            ("height", 40_i64.into()),
        ],
        "in",
        Payload::Image(road()),
    )
    .unwrap();
    assert_eq!((image(&crop).width, image(&crop).height), (30, 40));
    let turned = through(
        images::Orient::info(),
        images::Orient,
        &[("operation", "rotate_90".into())],
        "in",
        crop.payload,
    )
    .unwrap();
    assert_eq!((image(&turned).width, image(&turned).height), (40, 30));
    let half = through(
        images::Resize::info(),
        images::Resize::default(),
        &[],
        "in",
        Payload::Image(road()),
    )
    .unwrap();
    assert_eq!((image(&half).width, image(&half).height), (160, 120));
    let jpeg = through(
        codecs::JpegEncode::info(),
        codecs::JpegEncode::default(),
        &[],
        "in",
        Payload::Image(road()),
    )
    .unwrap();
    let Payload::Bytes(bytes) = &jpeg.payload else {
        panic!()
    };
    assert!(bytes.starts_with(&[0xFF, 0xD8]) && bytes.len() < 320 * 240 * 3 / 4);
    let back = through(
        codecs::JpegDecode::info(),
        codecs::JpegDecode,
        &[],
        "in",
        jpeg.payload,
    )
    .unwrap();
    let back = image(&back);
    assert_eq!(
        (back.width, back.height, back.format),
        (320, 240, PixelFormat::Rgb8)
    );
    // The sky survives compression within a few levels.
    let sky = &back.pixels[(10 * 320 + 10) * 3..][..3];
    assert!(
        sky.iter().zip([90, 140, 220]).all(|(a, b)| a.abs_diff(b) < 8),
        "{sky:?}"
    );
}

#[test]
fn a_threshold_on_pixels_held_once_works_in_place_and_motion_shows_what_moved() {
    let grey = Image::packed(8, 1, PixelFormat::Gray8, vec![0, 50, 100, 150, 200, 250, 10, 130]).unwrap();
    let out = through(
        images::Threshold::info(),
        images::Threshold,
        &[("level", 120_i64.into())],
        "in",
        Payload::Image(grey),
    )
    .unwrap();
    assert_eq!(&image(&out).pixels[..], [0, 0, 0, 255, 255, 255, 0, 255]);

    let mut motion = Harness::new(images::Motion::info(), images::Motion::default());
    let frame = |bright: usize| {
        let mut pixels = vec![0_u8; 16];
        pixels[bright] = 200;
        Payload::Image(Image::packed(4, 4, PixelFormat::Gray8, pixels).unwrap())
    };
    motion.push("in", frame(0), Timestamp::from_millis(0));
    motion.push("in", frame(5), Timestamp::from_millis(33));
    let masks = motion.run().unwrap();
    let masks = masks.samples("out");
    assert!(
        image(&masks[0]).pixels.iter().all(|p| *p == 0),
        "nothing before the first frame"
    );
    let moved: Vec<usize> = image(&masks[1])
        .pixels
        .iter()
        .enumerate()
        .filter(|(_, p)| **p == 255)
        .map(|(i, _)| i)
        .collect();
    assert_eq!(moved, [0, 5]);
}

#[test]
fn undistortion_refuses_a_bad_calibration_file_and_an_image_of_another_size() {
    let dir = tempfile::tempdir().unwrap();
    let calibration = dir.path().join("camera.toml");
    std::fs::write(
        &calibration,
        "width = 320\nheight = 240\nfx = 250.0\nfy = 250.0\ncx = 160.0\ncy = 120.0\nk1 = -0.2\n",
    )
    .unwrap();
    let path = calibration.display().to_string();
    let out = through(
        images::Undistort::info(),
        images::Undistort::default(),
        &[("calibration", path.clone().into())],
        "in",
        Payload::Image(road()),
    )
    .unwrap();
    assert_eq!((image(&out).width, image(&out).height), (320, 240));
    let small = Image::packed(160, 120, PixelFormat::Rgb8, vec![0_u8; 160 * 120 * 3]).unwrap();
    let error = through(
        images::Undistort::info(),
        images::Undistort::default(),
        &[("calibration", path.into())],
        "in",
        Payload::Image(small),
    )
    .unwrap_err()
    .to_string();
    assert!(
        error.contains("for 320×240 images, this one is 160×120"),
        "{error}"
    );
    std::fs::write(
        &calibration,
        "width = 320\nheight = 240\nfx = 0.0\nfy = 250.0\ncx = 160.0\ncy = 120.0\n",
    )
    .unwrap();
    let error = through(
        images::Undistort::info(),
        images::Undistort::default(),
        &[("calibration", calibration.display().to_string().into())],
        "in",
        Payload::Image(road()),
    )
    .unwrap_err()
    .to_string();
    assert!(
        error.contains("camera.toml:3:6") && error.contains("must be positive"),
        "{error}"
    );
}

#[test]
fn yuv_frames_convert_both_ways_and_a_short_frame_is_refused_with_the_sizes() {
    for format in ["yuyv", "nv12"] {
        let frame = through(
            codecs::ToYuv::info(),
            codecs::ToYuv::default(),
            &[("format", format.into())],
            "in",
            Payload::Image(road()),
        )
        .unwrap();
        let Payload::Bytes(bytes) = &frame.payload else {
            panic!()
        };
        let expected = if format == "nv12" {
            320 * 240 * 3 / 2
        } else {
            320 * 240 * 2
        };
        assert_eq!(bytes.len(), expected, "{format}");
        let sizes: [(&str, kairos_sdk::Value); 3] = [
            ("format", format.into()),
            ("width", 320_i64.into()),
            ("height", 240_i64.into()),
        ];
        let back = through(
            codecs::FromYuv::info(),
            codecs::FromYuv,
            &sizes,
            "in",
            frame.payload.clone(),
        )
        .unwrap();
        let back = image(&back);
        // The sky, away from any edge, comes back within a few levels.
        let sky = &back.pixels[(10 * 320 + 10) * 3..][..3];
        assert!(
            sky.iter().zip([90, 140, 220]).all(|(a, b)| a.abs_diff(b) <= 3),
            "{format}: {sky:?}"
        );
    }
    let sizes: [(&str, kairos_sdk::Value); 3] = [
        ("format", "nv12".into()),
        ("width", 320_i64.into()),
        ("height", 240_i64.into()),
    ];
    let error = through(
        codecs::FromYuv::info(),
        codecs::FromYuv,
        &sizes,
        "in",
        Payload::Bytes(vec![0_u8; 1000].into()),
    )
    .unwrap_err()
    .to_string();
    assert!(error.contains("needs 115200 bytes, this one has 1000"), "{error}");
    let odd = Image::packed(3, 2, PixelFormat::Rgb8, vec![0_u8; 18]).unwrap();
    let error = through(
        codecs::ToYuv::info(),
        codecs::ToYuv::default(),
        &[],
        "in",
        Payload::Image(odd),
    )
    .unwrap_err()
    .to_string();
    assert!(error.contains("even sides"), "{error}");
}
