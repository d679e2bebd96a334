//! Image components: colour, geometry, filters and edges. Each reads an image, keeps its timestamp,
//! and writes a new image made in the shared pixel pool (or the same buffer, changed in place, when
//! nothing else holds it).

use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{
    Component, ComponentError, ComponentInfo, ComponentResult, Context, DataType, Payload, TypeFilter,
};

use crate::image_io::{format_of, grey_view, image_of, made, transformed, view_of};
use crate::kernels::color::{self, Layout};
use crate::kernels::edges::{Canny as CannyKernel, sobel_magnitude};
use crate::kernels::filter::{self, Gaussian, Morphology as MorphologyKind, ThresholdKind};
use crate::kernels::geometry::{self, Interpolation, Orientation, Resize as ResizeKernel};

fn images() -> TypeFilter {
    TypeFilter::only(DataType::Image)
}

fn choice(ctx: &Context, name: &str) -> Result<String, ComponentError> {
    ctx.text_property(name)
}

/// A whole-number property known to lie in a small non-negative range (the descriptor's).
fn count(ctx: &Context, name: &str) -> Result<usize, ComponentError> {
    Ok(usize::try_from(ctx.i64_property(name)?.max(0)).unwrap_or(0))
}

/// `vision.convert`: between grey, RGB, BGR, RGBA and BGRA.
#[derive(Debug, Default)]
pub struct Convert;

impl Convert {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "vision.convert",
            "images",
            "Converts an image between grey, RGB, BGR, RGBA and BGRA (grey uses the BT.601 weights)",
        )
        .label("Convert colours")
        .input("in", images(), "An 8-bit image")
        .output(
            "out",
            DataType::Image,
            "The image in the chosen layout, same timestamp",
        )
        .property(
            Property::choice("to", &["gray", "rgb", "bgr", "rgba", "bgra"], "gray")
                .live()
                .doc("The layout to convert to"),
        )
        .build()
    }
}

fn layout_named(name: &str) -> Layout {
    match name {
        "rgb" => Layout::Rgb,
        "bgr" => Layout::Bgr,
        "rgba" => Layout::Rgba,
        "bgra" => Layout::Bgra,
        _ => Layout::Gray,
    }
}

impl Component for Convert {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        let image = image_of(&sample, "in")?;
        let (view, from) = view_of(image, "vision.convert")?;
        let to = layout_named(&choice(ctx, "to")?);
        if from == to {
            return ctx.forward("out", &sample);
        }
        let out = made(view.width, view.height, format_of(to), |dst| {
            color::convert(&view, from, to, dst);
            Ok(())
        })?;
        ctx.write_processed("out", &sample, Payload::Image(out))
    }
}

/// `vision.resize`: to a size or by a scale, nearest, bilinear or area.
#[derive(Debug, Default)]
pub struct Resize {
    kernel: ResizeKernel,
}

impl Resize {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "vision.resize",
            "images",
            "Resizes an image to a width and height, or by a scale when both are 0",
        )
        .label("Resize")
        .input("in", images(), "An 8-bit image")
        .output("out", DataType::Image, "The resized image, same timestamp")
        .property(
            Property::i64("width", 0)
                .int_range(0, 16384)
                .unit("px")
                .live()
                .doc("Width of the result; 0 keeps the aspect ratio from the height, or uses the scale"),
        )
        .property(
            Property::i64("height", 0)
                .int_range(0, 16384)
                .unit("px")
                .live()
                .doc("Height of the result; 0 keeps the aspect ratio from the width, or uses the scale"),
        )
        .property(
            Property::f64("scale", 0.5)
                .range(0.01, 16.0)
                .live()
                .doc("Scale applied to both sides when width and height are 0"),
        )
        .property(
            Property::choice("interpolation", &["nearest", "bilinear", "area"], "bilinear")
                .live()
                .doc("nearest: fastest; bilinear: smooth; area: the mean of the pixels covered, best to shrink"),
        )
        .build()
    }
}

impl Component for Resize {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        let image = image_of(&sample, "in")?;
        let (view, layout) = view_of(image, "vision.resize")?;
        let (width, height) = target_size(
            (view.width, view.height),
            (count(ctx, "width")?, count(ctx, "height")?),
            ctx.f64_property("scale")?,
        );
        if width == 0 || height == 0 {
            return Err(ComponentError::failed(format_args!(
                "resizing the {}×{} image gives {width}×{height}: nothing left; raise the scale or set a size",
                view.width, view.height
            )));
        }
        let interpolation = match choice(ctx, "interpolation")?.as_str() {
            "nearest" => Interpolation::Nearest,
            "area" => Interpolation::Area,
            _ => Interpolation::Bilinear,
        };
        let kernel = &mut self.kernel;
        let out = made(width, height, format_of(layout), |dst| {
            kernel
                .run(&view, (width, height), interpolation, dst)
                .map_err(ComponentError::failed)
        })?;
        ctx.write_processed("out", &sample, Payload::Image(out))
    }
}

/// The result's size: both given, one given (the other keeps the aspect ratio), or the scale.
fn target_size(
    (width, height): (usize, usize),
    (to_width, to_height): (usize, usize),
    scale: f64,
) -> (usize, usize) {
    let aspect =
        |side: usize, from: usize, to: usize| (side as f64 * to as f64 / from.max(1) as f64).round() as usize;
    match (to_width, to_height) {
        (0, 0) => (
            (width as f64 * scale).round() as usize,
            (height as f64 * scale).round() as usize,
        ),
        (0, h) => (aspect(width, height, h), h),
        (w, 0) => (w, aspect(height, width, w)),
        (w, h) => (w, h),
    }
}

/// `vision.crop`: a region of interest.
#[derive(Debug, Default)]
pub struct Crop;

impl Crop {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        let side = |name: &str, default: i64, doc: &str| {
            Property::i64(name, default)
                .int_range(0, 16384)
                .unit("px")
                .live()
                .doc(doc)
        };
        Descriptor::new(
            "vision.crop",
            "images",
            "Keeps a rectangular region of interest of an image",
        )
        .label("Crop (region of interest)")
        .input("in", images(), "An 8-bit image")
        .output("out", DataType::Image, "The region, same timestamp")
        .property(side("x", 0, "Left edge of the region"))
        .property(side("y", 0, "Top edge of the region"))
        .property(side("width", 320, "Width of the region").int_range(1, 16384))
        .property(side("height", 240, "Height of the region").int_range(1, 16384))
        .build()
    }
}

impl Component for Crop {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        let image = image_of(&sample, "in")?;
        let (view, layout) = view_of(image, "vision.crop")?;
        let (x, y) = (count(ctx, "x")?, count(ctx, "y")?);
        let (width, height) = (count(ctx, "width")?, count(ctx, "height")?);
        if width == 0 || height == 0 || x + width > view.width || y + height > view.height {
            return Err(ComponentError::failed(format_args!(
                "the region {width}×{height} at ({x}, {y}) does not fit in the {}×{} image: make it smaller or move it",
                view.width, view.height
            )));
        }
        let out = made(width, height, format_of(layout), |dst| {
            geometry::crop(&view, (x, y), (width, height), dst);
            Ok(())
        })?;
        ctx.write_processed("out", &sample, Payload::Image(out))
    }
}

/// `vision.orient`: flips and quarter turns.
#[derive(Debug, Default)]
pub struct Orient;

impl Orient {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "vision.orient",
            "images",
            "Flips an image or turns it by quarter turns",
        )
        .label("Flip / rotate")
        .input("in", images(), "An 8-bit image")
        .output("out", DataType::Image, "The turned image, same timestamp")
        .property(
            Property::choice(
                "operation",
                &[
                    "flip_horizontal",
                    "flip_vertical",
                    "rotate_90",
                    "rotate_180",
                    "rotate_270",
                ],
                "rotate_180",
            )
            .live()
            .doc("Rotations are clockwise"),
        )
        .build()
    }
}

impl Component for Orient {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        let image = image_of(&sample, "in")?;
        let (view, layout) = view_of(image, "vision.orient")?;
        let orientation = match choice(ctx, "operation")?.as_str() {
            "flip_horizontal" => Orientation::FlipHorizontal,
            "flip_vertical" => Orientation::FlipVertical,
            "rotate_90" => Orientation::Rotate90,
            "rotate_270" => Orientation::Rotate270,
            _ => Orientation::Rotate180,
        };
        let (width, height) = orientation.size(view.width, view.height);
        let out = made(width, height, format_of(layout), |dst| {
            geometry::orient(&view, orientation, dst);
            Ok(())
        })?;
        ctx.write_processed("out", &sample, Payload::Image(out))
    }
}

/// `vision.gaussian_blur`.
#[derive(Debug, Default)]
pub struct GaussianBlur;

impl GaussianBlur {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "vision.gaussian_blur",
            "image filters",
            "Smooths an image with a Gaussian kernel",
        )
        .label("Gaussian blur")
        .input("in", images(), "An 8-bit image")
        .output("out", DataType::Image, "The smoothed image, same timestamp")
        .property(
            Property::i64("size", 5)
                .int_range(1, 31)
                .unit("px")
                .live()
                .doc("Kernel width and height: an odd number"),
        )
        .property(
            Property::f64("sigma", 0.0)
                .range(0.0, 100.0)
                .unit("px")
                .live()
                .doc("Standard deviation; 0 derives it from the size as OpenCV does"),
        )
        .build()
    }
}

impl Component for GaussianBlur {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let size = count(ctx, "size")?;
        let kernel = Gaussian::new(size, ctx.f64_property("sigma")?).ok_or_else(|| {
            ComponentError::failed(format_args!(
                "the blur size must be odd (1, 3, 5 … 31), it is {size}: set it to {}",
                size | 1
            ))
        })?;
        let sample = ctx.read("in")?;
        let image = image_of(&sample, "in")?;
        let (view, layout) = view_of(image, "vision.gaussian_blur")?;
        let out = made(view.width, view.height, format_of(layout), |dst| {
            filter::gaussian_blur(&view, &kernel, dst);
            Ok(())
        })?;
        ctx.write_processed("out", &sample, Payload::Image(out))
    }
}

/// `vision.sobel`: edge strength.
#[derive(Debug, Default)]
pub struct Sobel;

impl Sobel {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "vision.sobel",
            "image filters",
            "Edge strength of a grey image: |dx| + |dy| of the 3×3 Sobel derivatives, saturated at 255",
        )
        .label("Sobel edge strength")
        .input("in", images(), "A grey image")
        .output(
            "out",
            DataType::Image,
            "The edge strength as a grey image, same timestamp",
        )
        .build()
    }
}

impl Component for Sobel {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        let view = grey_view(image_of(&sample, "in")?, "vision.sobel")?;
        let out = made(view.width, view.height, kairos_sdk::PixelFormat::Gray8, |dst| {
            sobel_magnitude(&view, dst);
            Ok(())
        })?;
        ctx.write_processed("out", &sample, Payload::Image(out))
    }
}

/// `vision.canny`: thin edges.
#[derive(Debug, Default)]
pub struct Canny {
    kernel: CannyKernel,
}

impl Canny {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "vision.canny",
            "image features",
            "Canny edges of a grey image: one-pixel-wide edges where the gradient peaks, kept by hysteresis",
        )
        .label("Canny edges")
        .input("in", images(), "A grey image")
        .output(
            "out",
            DataType::Image,
            "A grey mask: 255 on edges, 0 elsewhere; same timestamp",
        )
        .property(
            Property::f64("low", 50.0)
                .range(0.0, 2040.0)
                .live()
                .doc("Gradients above this continue an edge (|dx| + |dy| of the Sobel derivatives)"),
        )
        .property(
            Property::f64("high", 150.0)
                .range(0.0, 2040.0)
                .live()
                .doc("Gradients above this start an edge"),
        )
        .build()
    }
}

impl Component for Canny {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let (low, high) = (ctx.f64_property("low")?, ctx.f64_property("high")?);
        let sample = ctx.read("in")?;
        let view = grey_view(image_of(&sample, "in")?, "vision.canny")?;
        let kernel = &mut self.kernel;
        let out = made(view.width, view.height, kairos_sdk::PixelFormat::Gray8, |dst| {
            kernel.detect(&view, low.floor() as i32, high.floor() as i32, dst);
            Ok(())
        })?;
        ctx.write_processed("out", &sample, Payload::Image(out))
    }
}

/// `vision.threshold`.
#[derive(Debug, Default)]
pub struct Threshold;

impl Threshold {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "vision.threshold",
            "image filters",
            "Compares every byte with a level: binary masks, inverted masks, clipping",
        )
        .label("Threshold")
        .input("in", images(), "An 8-bit image (each channel is compared on its own)")
        .output("out", DataType::Image, "The thresholded image, same format and timestamp")
        .property(Property::i64("level", 128).int_range(0, 255).live().doc("Bytes above it count as above"))
        .property(Property::i64("max", 255).int_range(0, 255).live().doc("The value written for above (binary)"))
        .property(
            Property::choice("kind", &["binary", "binary_inverted", "truncate", "to_zero"], "binary")
                .live()
                .doc("binary: above becomes max, the rest 0; binary_inverted: the opposite; truncate: above becomes the level; to_zero: below becomes 0"),
        )
        .property(
            Property::bool("otsu", false)
                .live()
                .doc("Choose the level for each grey image by Otsu's method (the level is then ignored)"),
        )
        .build()
    }
}

impl Component for Threshold {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        let image = image_of(&sample, "in")?.clone();
        let (view, layout) = view_of(&image, "vision.threshold")?;
        let otsu = ctx.bool_property("otsu")?;
        if otsu && layout != Layout::Gray {
            return Err(ComponentError::failed(format_args!(
                "Otsu's level is for grey images, this one is {:?}: convert it to gray or switch otsu off",
                image.format
            )));
        }
        let level = if otsu {
            view.pixels().map_or(128, filter::otsu_level)
        } else {
            count(ctx, "level")?.min(255) as u8
        };
        let max = count(ctx, "max")?.min(255) as u8;
        let kind = match choice(ctx, "kind")?.as_str() {
            "binary_inverted" => ThresholdKind::BinaryInverted,
            "truncate" => ThresholdKind::Truncate,
            "to_zero" => ThresholdKind::ToZero,
            _ => ThresholdKind::Binary,
        };
        // Let go of the sample so the pixels can be changed in place when nothing else holds them.
        let timestamp = sample.timestamp;
        drop(sample);
        let out = transformed(image, |bytes| filter::threshold(bytes, level, max, kind))?;
        ctx.write_at("out", Payload::Image(out), timestamp)
    }
}

/// `vision.morphology`: erosion, dilation, opening, closing.
#[derive(Debug, Default)]
pub struct Morphology;

impl Morphology {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "vision.morphology",
            "image filters",
            "Erodes or dilates an image with a square, or opens (erode then dilate) or closes it",
        )
        .label("Erode / dilate")
        .input("in", images(), "An 8-bit image, usually a mask")
        .output("out", DataType::Image, "The result, same format and timestamp")
        .property(
            Property::choice("operation", &["erode", "dilate", "open", "close"], "erode")
                .live()
                .doc("open removes specks; close fills small holes"),
        )
        .property(
            Property::i64("size", 3)
                .int_range(1, 31)
                .unit("px")
                .live()
                .doc("Side of the square"),
        )
        .property(
            Property::i64("iterations", 1)
                .int_range(1, 20)
                .live()
                .doc("Times it is applied"),
        )
        .build()
    }
}

impl Component for Morphology {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        let image = image_of(&sample, "in")?;
        let (view, layout) = view_of(image, "vision.morphology")?;
        let steps: &[MorphologyKind] = match choice(ctx, "operation")?.as_str() {
            "dilate" => &[MorphologyKind::Dilate],
            "open" => &[MorphologyKind::Erode, MorphologyKind::Dilate],
            "close" => &[MorphologyKind::Dilate, MorphologyKind::Erode],
            _ => &[MorphologyKind::Erode],
        };
        let (size, iterations) = (count(ctx, "size")?, count(ctx, "iterations")?.max(1));
        let passes: Vec<MorphologyKind> = steps
            .iter()
            .flat_map(|step| std::iter::repeat_n(*step, iterations))
            .collect();
        let out = made(view.width, view.height, format_of(layout), |dst| {
            let mut scratch = Vec::new();
            for (k, pass) in passes.iter().enumerate() {
                if k == 0 {
                    filter::morphology(&view, *pass, size, dst);
                } else {
                    scratch.clear();
                    scratch.extend_from_slice(dst);
                    let previous = crate::kernels::View {
                        data: &scratch,
                        stride: view.row_bytes(),
                        ..view
                    };
                    filter::morphology(&previous, *pass, size, dst);
                }
            }
            Ok(())
        })?;
        ctx.write_processed("out", &sample, Payload::Image(out))
    }
}

/// `vision.equalize_histogram`.
#[derive(Debug, Default)]
pub struct EqualizeHistogram;

impl EqualizeHistogram {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "vision.equalize_histogram",
            "image filters",
            "Spreads a grey image's brightness over the whole range: more contrast in dull images",
        )
        .label("Equalise histogram")
        .input("in", images(), "A grey image")
        .output("out", DataType::Image, "The equalised image, same timestamp")
        .build()
    }
}

impl Component for EqualizeHistogram {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        let image = image_of(&sample, "in")?.clone();
        grey_view(&image, "vision.equalize_histogram")?;
        let timestamp = sample.timestamp;
        drop(sample);
        let out = transformed(image, filter::equalize)?;
        ctx.write_at("out", Payload::Image(out), timestamp)
    }
}

/// `vision.motion`: what changed since the previous frame.
#[derive(Debug, Default)]
pub struct Motion {
    previous: Option<kairos_sdk::Image>,
}

impl Motion {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "vision.motion",
            "image features",
            "Motion mask: where a grey frame differs from the previous one by more than a level",
        )
        .label("Motion (frame difference)")
        .input("in", images(), "Grey frames")
        .output(
            "out",
            DataType::Image,
            "A mask: 255 where the frame changed; the first frame gives an empty mask",
        )
        .property(
            Property::i64("level", 25)
                .int_range(0, 255)
                .live()
                .doc("Differences above it count as motion"),
        )
        .action("reset", "Forgets the previous frame")
        .build()
    }
}

impl Component for Motion {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        let image = image_of(&sample, "in")?;
        let view = grey_view(image, "vision.motion")?;
        let level = count(ctx, "level")?.min(255) as u8;
        let previous = self
            .previous
            .as_ref()
            .filter(|p| (p.width, p.height) == (image.width, image.height))
            .and_then(|p| grey_view(p, "vision.motion").ok());
        let out = made(view.width, view.height, kairos_sdk::PixelFormat::Gray8, |dst| {
            if let Some(before) = previous {
                for (y, out) in dst.chunks_exact_mut(view.width.max(1)).enumerate() {
                    filter::absolute_difference(view.row(y), before.row(y), out);
                }
                filter::threshold(dst, level, 255, ThresholdKind::Binary);
            } else {
                dst.fill(0);
            }
            Ok(())
        })?;
        self.previous = Some(image.clone());
        ctx.write_processed("out", &sample, Payload::Image(out))
    }

    fn action(&mut self, name: &str, _ctx: &mut Context) -> ComponentResult {
        if name == "reset" {
            self.previous = None;
        }
        Ok(())
    }
}

/// `vision.undistort`: removes lens distortion with a calibration file.
#[derive(Debug, Default)]
pub struct Undistort {
    table: Option<crate::kernels::undistort::Undistortion>,
}

impl Undistort {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "vision.undistort",
            "image filters",
            "Removes lens distortion: pinhole camera with radial and tangential distortion (OpenCV's model), from a calibration file",
        )
        .label("Undistort (lens)")
        .input("in", images(), "An 8-bit image of the size the calibration is for")
        .output("out", DataType::Image, "The image a distortion-free camera with the same intrinsics would take; same timestamp")
        .property(
            Property::path("calibration", "camera.toml")
                .doc("Calibration file (TOML): width, height, fx, fy, cx, cy, and k1, k2, k3, p1, p2"),
        )
        .build()
    }
}

impl Component for Undistort {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        let path = std::path::PathBuf::from(ctx.text_property("calibration")?);
        let calibration =
            crate::kernels::undistort::Calibration::load(&path).map_err(ComponentError::failed)?;
        self.table = Some(crate::kernels::undistort::Undistortion::new(&calibration));
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        let image = image_of(&sample, "in")?;
        let (view, layout) = view_of(image, "vision.undistort")?;
        let Some(table) = &self.table else {
            return Err(ComponentError::failed("no calibration loaded"));
        };
        let (width, height) = table.size();
        if (view.width, view.height) != (width, height) {
            return Err(ComponentError::failed(format_args!(
                "the calibration is for {width}×{height} images, this one is {}×{}: calibrate at this size, or resize the images first",
                view.width, view.height
            )));
        }
        let out = made(width, height, format_of(layout), |dst| {
            table.apply(&view, dst);
            Ok(())
        })?;
        ctx.write_processed("out", &sample, Payload::Image(out))
    }
}
