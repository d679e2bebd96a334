//! The V4L2 camera. A missing device is tested everywhere; capture only where a camera exists (this
//! project's CI machines have none: the test says what it skipped).
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use std::path::Path;

use kairos_pack_video::camera::{V4l2Camera, descriptor};
use kairos_sdk::Payload;
use kairos_sdk::harness::Harness;

#[test]
fn a_missing_camera_is_named_with_the_cause_and_where_to_look() {
    let mut camera = Harness::new(descriptor(), V4l2Camera::default());
    camera.set_property("device", "/dev/video-none").unwrap();
    let error = camera.run().unwrap_err().to_string();
    assert!(error.contains("/dev/video-none"), "{error}");
    assert!(error.contains("kairos devices"), "{error}");
}

#[test]
fn a_camera_gives_rgb_frames_of_the_negotiated_size() {
    if !Path::new("/dev/video0").exists() {
        eprintln!("V4L2 capture NOT TESTED: no camera at /dev/video0 on this machine");
        return;
    }
    let mut camera = Harness::new(descriptor(), V4l2Camera::default());
    camera.set_property("width", 320_i64).unwrap();
    camera.set_property("height", 240_i64).unwrap();
    let mut frames = Vec::new();
    // A camera takes up to a few seconds to send its first frame; each run waits at most 50 ms.
    for _ in 0..200 {
        frames.extend(camera.run().unwrap().samples("image").iter().cloned());
        if frames.len() >= 3 {
            break;
        }
    }
    assert!(frames.len() >= 3, "no frames from /dev/video0");
    let Payload::Image(image) = &frames[0].payload else {
        panic!("not an image")
    };
    assert_eq!(image.pixels.len(), (image.width * image.height * 3) as usize);
}
