//! The vision pack: the image blocks a perception prototype is assembled from.
//!
//! | type | what it does |
//! | --- | --- |
//! | `vision.convert` | grey, RGB, BGR, RGBA, BGRA, either way |
//! | `vision.resize` | to a size or by a scale: nearest, bilinear, area |
//! | `vision.crop` | a region of interest |
//! | `vision.orient` | flips and quarter turns |
//! | `vision.gaussian_blur` | Gaussian smoothing, any odd size |
//! | `vision.sobel` | edge strength |
//! | `vision.canny` | thin edges with hysteresis |
//! | `vision.threshold` | binary, inverted, truncate, to-zero; Otsu's level |
//! | `vision.morphology` | erode, dilate, open, close |
//! | `vision.equalize_histogram` | contrast spread over the whole range |
//! | `vision.motion` | frame difference as a motion mask |
//! | `vision.undistort` | lens distortion removed, from a calibration file |
//! | `vision.jpeg_encode` / `vision.jpeg_decode` | JPEG bytes and back |
//! | `vision.from_yuv` / `vision.to_yuv` | raw YUYV and NV12 frames and back |
//! | `vision.hough_lines` | straight segments in an edge mask |
//! | `vision.lane_detector` | the ego lane's centre line, in the vehicle frame, from an edge mask |
//! | `vision.overlay` | segments, boxes and a label drawn onto a copy |
//!
//! [`kernels`] holds the algorithms as pure functions on byte rows; the components take images apart
//! with [`image_io`] and put the results in the shared pixel pool.

pub mod codecs;
pub mod image_io;
pub mod images;
pub mod kernels;
pub mod lanes;
pub mod lines;

use kairos_sdk::Registry;

/// Registers the pack "vision".
pub fn register(registry: &mut Registry) {
    registry
        .pack("vision", env!("CARGO_PKG_VERSION"), "built-in")
        .subgraph("edges", include_str!("../subgraphs/edges.ron"))
        .component::<images::Convert>(images::Convert::info())
        .component::<images::Resize>(images::Resize::info())
        .component::<images::Crop>(images::Crop::info())
        .component::<images::Orient>(images::Orient::info())
        .component::<images::GaussianBlur>(images::GaussianBlur::info())
        .component::<images::Sobel>(images::Sobel::info())
        .component::<images::Canny>(images::Canny::info())
        .component::<images::Threshold>(images::Threshold::info())
        .component::<images::Morphology>(images::Morphology::info())
        .component::<images::EqualizeHistogram>(images::EqualizeHistogram::info())
        .component::<images::Motion>(images::Motion::info())
        .component::<images::Undistort>(images::Undistort::info())
        .component::<codecs::JpegEncode>(codecs::JpegEncode::info())
        .component::<codecs::JpegDecode>(codecs::JpegDecode::info())
        .component::<codecs::FromYuv>(codecs::FromYuv::info())
        .component::<codecs::ToYuv>(codecs::ToYuv::info())
        .component::<lines::HoughLines>(lines::HoughLines::info())
        .component::<lanes::LaneDetector>(lanes::LaneDetector::info())
        .component::<lines::Overlay>(lines::Overlay::info());
}
