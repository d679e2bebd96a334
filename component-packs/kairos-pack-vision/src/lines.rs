//! Lines and drawings: Hough lines from an edge mask, and overlays drawn onto a copy of an image.

use std::sync::Arc;

use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{
    Component, ComponentError, ComponentInfo, ComponentResult, Context, DataType, Matrix, Payload, Sample,
    Timestamp, TypeFilter,
};

use crate::image_io::{format_of, grey_view, image_of, made, view_of};
use crate::kernels::draw::Canvas;
use crate::kernels::hough::{LineSearch, find_lines};

/// `vision.hough_lines`.
#[derive(Debug, Default)]
pub struct HoughLines;

impl HoughLines {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        Descriptor::new(
            "vision.hough_lines",
            "image features",
            "Straight segments in an edge mask (Hough transform), e.g. lane markings after Canny",
        )
        .label("Hough lines")
        .input(
            "in",
            TypeFilter::only(DataType::Image),
            "A grey edge mask (non-zero = edge)",
        )
        .output(
            "lines",
            DataType::Matrix,
            "One row per segment: x1, y1, x2, y2 in pixels, strongest first; same timestamp",
        )
        .property(
            Property::f64("rho_step", 1.0)
                .range(0.5, 10.0)
                .unit("px")
                .doc("Distance resolution"),
        )
        .property(
            Property::f64("theta_step", 1.0)
                .range(0.1, 10.0)
                .unit("°")
                .doc("Angle resolution"),
        )
        .property(
            Property::i64("min_votes", 40)
                .int_range(1, 100_000)
                .live()
                .doc("Edge pixels a line needs"),
        )
        .property(
            Property::f64("min_length", 30.0)
                .range(1.0, 10_000.0)
                .unit("px")
                .live()
                .doc("Shortest segment kept"),
        )
        .property(
            Property::f64("max_gap", 10.0)
                .range(0.0, 1000.0)
                .unit("px")
                .live()
                .doc("Longest gap a segment bridges"),
        )
        .property(
            Property::f64("min_angle", 15.0)
                .range(0.0, 90.0)
                .unit("°")
                .live()
                .doc("Ignores lines closer to horizontal than this (lane markings are slanted)"),
        )
        .property(
            Property::f64("top", 0.5).range(0.0, 1.0).live().doc(
                "Searches from this fraction of the height down (0.5: the lower half, where the road is)",
            ),
        )
        .property(
            Property::i64("max_lines", 8)
                .int_range(1, 1000)
                .live()
                .doc("At most this many segments"),
        )
        .build()
    }
}

impl Component for HoughLines {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let search = LineSearch {
            rho_step: ctx.f64_property("rho_step")?,
            theta_step_deg: ctx.f64_property("theta_step")?,
            min_votes: u32::try_from(ctx.i64_property("min_votes")?.max(1)).unwrap_or(u32::MAX),
            min_angle_deg: ctx.f64_property("min_angle")?,
            min_angle_from_vertical_deg: 0.0,
            min_length: ctx.f64_property("min_length")?,
            max_gap: ctx.f64_property("max_gap")?,
            max_lines: usize::try_from(ctx.i64_property("max_lines")?.max(1)).unwrap_or(1),
        };
        let top = ctx.f64_property("top")?.clamp(0.0, 1.0);
        let sample = ctx.read("in")?;
        let view = grey_view(image_of(&sample, "in")?, "vision.hough_lines")?;
        let packed = view.contiguous();
        let mask: &[u8] = &packed;
        let first_row = (view.height as f64 * top) as usize;
        let segments = find_lines(mask, view.width, view.height, first_row, &search);
        let matrix = Matrix {
            rows: segments.len(),
            cols: 4,
            values: segments.concat(),
        };
        ctx.write_processed("lines", &sample, Payload::Matrix(Arc::new(matrix)))
    }
}

const COLOURS: [(&str, [u8; 3]); 8] = [
    ("red", [255, 0, 0]),
    ("green", [0, 255, 0]),
    ("blue", [0, 0, 255]),
    ("yellow", [255, 255, 0]),
    ("cyan", [0, 255, 255]),
    ("magenta", [255, 0, 255]),
    ("white", [255, 255, 255]),
    ("black", [0, 0, 0]),
];

/// `vision.overlay`.
#[derive(Debug, Default)]
pub struct Overlay {
    lines: Option<Sample>,
    boxes: Option<Sample>,
}

impl Overlay {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        let names: Vec<&str> = COLOURS.iter().map(|(name, _)| *name).collect();
        Descriptor::new(
            "vision.overlay",
            "image features",
            "Draws segments, polylines, boxes and a label onto a copy of an image, each image with the drawings of its own time",
        )
        .label("Overlay (lines, boxes, text)")
        .input("image", TypeFilter::only(DataType::Image), "The image to draw on")
        .input(
            "lines",
            TypeFilter::only(DataType::Matrix),
            "Segments and polylines: rows of x1, y1, x2, y2, … in pixels; NaN ends a row early (optional)",
        )
        .input(
            "boxes",
            TypeFilter::only(DataType::Matrix),
            "Boxes: rows of x, y, width, height in pixels (optional)",
        )
        .output("out", DataType::Image, "The image with the drawings, same timestamp")
        .property(Property::choice("color", &names, "red").live().doc("Colour of lines and boxes"))
        .property(Property::i64("thickness", 3).int_range(1, 50).unit("px").live().doc("Line width"))
        .property(Property::text("label", "").live().doc("Text written in a corner"))
        .property(
            Property::choice("label_at", &["top_left", "top_right", "bottom_left", "bottom_right"], "top_right")
                .live()
                .doc("The corner the label goes in"),
        )
        .property(Property::i64("text_scale", 2).int_range(1, 10).live().doc("Size of the label's letters"))
        .build()
    }

    /// The drawing of `input` for the image stamped `at`: samples are read until one is as recent, so
    /// each image gets the lines computed from it even though they arrive after it.
    fn drawing_for(
        held: &mut Option<Sample>,
        ctx: &mut Context,
        input: &str,
        at: Timestamp,
    ) -> Result<Option<Arc<Matrix>>, ComponentError> {
        if !ctx.is_connected(input) {
            return Ok(None);
        }
        while held.as_ref().is_none_or(|s| s.timestamp < at) {
            *held = Some(ctx.read(input)?);
        }
        match held.as_ref().map(|s| &s.payload) {
            Some(Payload::Matrix(matrix)) if matrix.cols >= 4 || matrix.rows == 0 => {
                Ok(Some(Arc::clone(matrix)))
            }
            Some(other) => Err(ComponentError::failed(format_args!(
                "input {input} expects a matrix of 4 columns, got {}",
                describe(other)
            ))),
            None => Ok(None),
        }
    }
}

fn describe(payload: &Payload) -> String {
    match payload {
        Payload::Matrix(m) => format!("a {}×{} matrix", m.rows, m.cols),
        other => other.data_type().to_string(),
    }
}

impl Component for Overlay {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("image")?;
        let lines = Self::drawing_for(&mut self.lines, ctx, "lines", sample.timestamp)?;
        let boxes = Self::drawing_for(&mut self.boxes, ctx, "boxes", sample.timestamp)?;
        let colour_name = ctx.text_property("color")?;
        let colour = COLOURS
            .iter()
            .find(|(n, _)| *n == colour_name)
            .map_or([255, 0, 0], |(_, c)| *c);
        let thickness = usize::try_from(ctx.i64_property("thickness")?).unwrap_or(1);
        let label = ctx.text_property("label")?;
        let corner = ctx.text_property("label_at")?;
        let text_scale = usize::try_from(ctx.i64_property("text_scale")?).unwrap_or(1);
        let image = image_of(&sample, "image")?;
        let (view, layout) = view_of(image, "vision.overlay")?;
        let pen = pen_for(layout, colour);
        let out = made(view.width, view.height, format_of(layout), |dst| {
            let row = view.row_bytes();
            if row > 0 {
                for (y, out) in dst.chunks_exact_mut(row).enumerate() {
                    out.copy_from_slice(view.row(y));
                }
            }
            let mut canvas = Canvas {
                width: view.width,
                height: view.height,
                channels: view.channels,
                pixels: dst,
            };
            for polyline in lines.iter().flat_map(|m| m.values.chunks_exact(m.cols.max(1))) {
                // x1, y1, x2, y2, … up to the row's end or its first NaN.
                let points: Vec<(f64, f64)> = polyline
                    .chunks_exact(2)
                    .map(|p| (p[0], p[1]))
                    .take_while(|(x, y)| !x.is_nan() && !y.is_nan())
                    .collect();
                for leg in points.windows(2) {
                    canvas.line(leg[0], leg[1], thickness, &pen);
                }
            }
            for bounds in boxes.iter().flat_map(|m| m.values.chunks_exact(m.cols.max(1))) {
                canvas.rectangle((bounds[0], bounds[1]), (bounds[2], bounds[3]), thickness, &pen);
            }
            if !label.is_empty() {
                let scale = text_scale as i64;
                let (margin, width) = (4 * scale, label.chars().count() as i64 * 6 * scale);
                let x = if corner.ends_with("right") {
                    view.width as i64 - margin - width
                } else {
                    margin
                };
                let y = if corner.starts_with("bottom") {
                    view.height as i64 - margin - 7 * scale
                } else {
                    margin
                };
                canvas.text((x.max(0), y.max(0)), &label, text_scale, &pen);
            }
            Ok(())
        })?;
        ctx.write_processed("out", &sample, Payload::Image(out))
    }
}

/// `rgb` as the bytes of one pixel in `layout` (grey: its luma; alpha: opaque).
fn pen_for(layout: crate::kernels::color::Layout, [r, g, b]: [u8; 3]) -> Vec<u8> {
    use crate::kernels::color::Layout;
    match layout {
        Layout::Gray => vec![((u32::from(r) * 299 + u32::from(g) * 587 + u32::from(b) * 114) / 1000) as u8],
        Layout::Rgb => vec![r, g, b],
        Layout::Bgr => vec![b, g, r],
        Layout::Rgba => vec![r, g, b, 255],
        Layout::Bgra => vec![b, g, r, 255],
    }
}
