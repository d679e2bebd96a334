//! The video pack: images from and to files, and camera pixel formats.
//!
//! | type | what it does |
//! | --- | --- |
//! | `video.v4l2_camera` | a camera through Video4Linux2: YUYV or MJPEG frames as RGB images |
//! | `video.image_sequence` | plays a folder of PNG/JPEG images at a fixed rate, at the times of a CSV beside them or at the times in their names |
//! | `video.image_writer` | writes one PNG or JPEG file per image |
//!
//! [`convert`] turns the frames USB cameras send (YUYV, MJPEG) into RGB images in the shared pixel pool.
//! Images are decoded and encoded by the `image` crate.

pub mod camera;
pub mod convert;
pub mod files;

use kairos_sdk::Registry;

/// Registers the pack "video".
pub fn register(registry: &mut Registry) {
    registry
        .pack("video", env!("CARGO_PKG_VERSION"), "built-in")
        .component::<camera::V4l2Camera>(camera::descriptor())
        .component::<files::ImageSequence>(files::sequence_descriptor())
        .component::<files::ImageWriter>(files::writer_descriptor());
}
