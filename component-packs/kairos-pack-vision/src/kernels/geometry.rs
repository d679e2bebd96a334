//! Geometry: resize, crop, flip and rotate. Bilinear resizing is OpenCV's fixed point ([`super::linear`]),
//! shrinking by area OpenCV's `INTER_AREA` (below), nearest and enlarging by area `fast_image_resize`'s
//! SIMD code; the rest moves whole rows or pixels.

use fast_image_resize::images::{Image as ResizeTarget, ImageRef};
use fast_image_resize::{FilterType, PixelType, ResizeAlg, ResizeOptions, Resizer};

use multiversion::multiversion;

use super::View;
use super::linear::{self, LinearRows, LinearTaps};

/// How [`Resize`] samples the source.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Interpolation {
    /// The nearest source pixel.
    Nearest,
    /// Bilinear between the four nearest pixels (OpenCV's `INTER_LINEAR`).
    Bilinear,
    /// The mean of the source pixels each destination pixel covers (OpenCV's `INTER_AREA` when
    /// shrinking): no aliasing.
    Area,
}

/// Why a resize did not happen.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("cannot resize: {0}")]
pub struct ResizeError(String);

/// A resizer that keeps its buffers from one frame to the next.
#[derive(Default)]
pub struct Resize {
    resizer: Resizer,
    packed: Vec<u8>,
    /// The area shares across and down for the last sizes shrunk by area, kept while the sizes stay.
    area: Option<AreaShares>,
    /// The bilinear taps for the last sizes resized bilinearly, and its row buffers.
    linear: Option<LinearTaps>,
    linear_rows: LinearRows,
}

/// The shares of an area shrink from one size to another, along each axis.
struct AreaShares {
    sizes: [usize; 4],
    across: Vec<Share>,
    down: Vec<Share>,
}

impl std::fmt::Debug for Resize {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Resize").finish_non_exhaustive()
    }
}

impl Resize {
    /// Resizes `src` into the packed `dst` of `width × height` pixels with the same channels.
    pub fn run(
        &mut self,
        src: &View<'_>,
        (width, height): (usize, usize),
        interpolation: Interpolation,
        dst: &mut [u8],
    ) -> Result<(), ResizeError> {
        let pixel_type = match src.channels {
            1 => PixelType::U8,
            2 => PixelType::U8x2,
            3 => PixelType::U8x3,
            4 => PixelType::U8x4,
            other => return Err(ResizeError(format!("{other} bytes per pixel are not supported"))),
        };
        if interpolation != Interpolation::Nearest && 2 * width == src.width && 2 * height == src.height {
            // Halving: bilinear sampling at the centres of the new pixels and the area mean are both the
            // mean of each 2×2 block, which a plain loop does faster than a general resampler.
            halve(src, dst);
            return Ok(());
        }
        if interpolation == Interpolation::Area
            && width <= src.width
            && height <= src.height
            && width * height > 0
        {
            let sizes = [src.width, src.height, width, height];
            let shares = match self.area.take() {
                Some(shares) if shares.sizes == sizes => shares,
                _ => AreaShares {
                    sizes,
                    across: area_shares(src.width, width),
                    down: area_shares(src.height, height),
                },
            };
            shrink_by_area(src, (&shares.across, &shares.down), dst);
            self.area = Some(shares);
            return Ok(());
        }
        if interpolation == Interpolation::Bilinear {
            let (from, to) = ((src.width, src.height), (width, height));
            let taps = match self.linear.take() {
                Some(taps) if taps.fit(from, to, src.channels) => taps,
                _ => LinearTaps::new(from, to, src.channels),
            };
            linear::resize(src, &taps, &mut self.linear_rows, dst);
            self.linear = Some(taps);
            return Ok(());
        }
        let source = if let Some(pixels) = src.pixels() {
            pixels
        } else {
            // Rows with padding between them: pack them once.
            self.packed.clear();
            for y in 0..src.height {
                self.packed.extend_from_slice(src.row(y));
            }
            &self.packed
        };
        let size = |v: usize| u32::try_from(v).map_err(|_| ResizeError(format!("{v} pixels is too large")));
        let from = ImageRef::new(size(src.width)?, size(src.height)?, source, pixel_type)
            .map_err(|e| ResizeError(e.to_string()))?;
        let mut to = ResizeTarget::from_slice_u8(size(width)?, size(height)?, dst, pixel_type)
            .map_err(|e| ResizeError(e.to_string()))?;
        let algorithm = match interpolation {
            Interpolation::Nearest => ResizeAlg::Nearest,
            // Enlarging by area (bilinear returned above).
            Interpolation::Area | Interpolation::Bilinear => ResizeAlg::Convolution(FilterType::Box),
        };
        self.resizer
            .resize(&from, &mut to, &ResizeOptions::new().resize_alg(algorithm))
            .map_err(|e| ResizeError(e.to_string()))
    }
}

/// One source pixel's share of a destination pixel, along one axis.
#[derive(Debug, Clone, Copy)]
struct Share {
    destination: usize,
    source: usize,
    weight: f32,
}

/// Along an axis of `from` pixels shrunk to `to`: each destination pixel covers `from / to` source pixels,
/// the ones at its ends in part, each weighted by how much of it is covered over the pixel's width (as
/// OpenCV's `INTER_AREA` tabulates them).
fn area_shares(from: usize, to: usize) -> Vec<Share> {
    let scale = from as f64 / to as f64;
    let mut shares = Vec::with_capacity(from + 2 * to);
    for destination in 0..to {
        let start = destination as f64 * scale;
        let end = start + scale;
        let width = scale.min(from as f64 - start);
        let last = (end.floor() as usize).min(from - 1);
        let first = (start.ceil() as usize).min(last);
        if first as f64 - start > 1e-3 {
            shares.push(Share {
                destination,
                source: first - 1,
                weight: ((first as f64 - start) / width) as f32,
            });
        }
        for source in first..last {
            shares.push(Share {
                destination,
                source,
                weight: (1.0 / width) as f32,
            });
        }
        if end - last as f64 > 1e-3 {
            let covered = (end - last as f64).min(1.0).min(width);
            shares.push(Share {
                destination,
                source: last,
                weight: (covered / width) as f32,
            });
        }
    }
    shares
}

/// `src` shrunk by area into the packed `dst` with the shares `across` and `down` ([`area_shares`]),
/// each new pixel the mean of the source area it covers, partly covered pixels in part: OpenCV's
/// `INTER_AREA`, summed in the same order in `f32`.
fn shrink_by_area(src: &View<'_>, (across, down): (&[Share], &[Share]), dst: &mut [u8]) {
    let channels = src.channels;
    let width = across.last().map_or(0, |share| share.destination + 1);
    let row_bytes = width * channels;
    let (mut row, mut sum) = (vec![0.0_f32; row_bytes], vec![0.0_f32; row_bytes]);
    let mut current: Option<usize> = None;
    let write = |at: usize, sum: &[f32], dst: &mut [u8]| {
        if let Some(out) = dst.get_mut(at * row_bytes..(at + 1) * row_bytes) {
            rounded_bytes(sum, out);
        }
    };
    // A source row that two destination rows share (the one their boundary crosses) comes twice in a
    // row in `down`: it is summed across once.
    let mut summed: Option<usize> = None;
    for vertical in down {
        if summed != Some(vertical.source) {
            row.fill(0.0);
            let line = src.row(vertical.source);
            match channels {
                1 => area_row::<1>(line, across, &mut row),
                3 => area_row::<3>(line, across, &mut row),
                4 => area_row::<4>(line, across, &mut row),
                _ => area_row_any(line, channels, across, &mut row),
            }
            summed = Some(vertical.source);
        }
        if current == Some(vertical.destination) {
            add_weighted(&row, vertical.weight, &mut sum);
        } else {
            if let Some(done) = current {
                write(done, &sum, dst);
            }
            set_weighted(&row, vertical.weight, &mut sum);
            current = Some(vertical.destination);
        }
    }
    if let Some(done) = current {
        write(done, &sum, dst);
    }
}

/// `sum += weight × row`, value by value (a multiply, then an add: the rounding OpenCV's loop has).
#[multiversion(targets("x86_64+avx2+fma", "x86_64+sse4.1"))]
fn add_weighted(row: &[f32], weight: f32, sum: &mut [f32]) {
    for (total, value) in sum.iter_mut().zip(row) {
        *total += weight * value;
    }
}

/// `sum = weight × row`.
#[multiversion(targets("x86_64+avx2+fma", "x86_64+sse4.1"))]
fn set_weighted(row: &[f32], weight: f32, sum: &mut [f32]) {
    for (total, value) in sum.iter_mut().zip(row) {
        *total = weight * value;
    }
}

/// Sums of weights that add up to one, so within 0–255 (and a hair over): each rounded to the nearest
/// byte, ties to even as OpenCV's `saturate_cast` rounds. Adding and taking away 2^23 rounds an `f32`
/// below 2^22 to the nearest integer, ties to even, in the default rounding mode, without a call to
/// `rintf` that a plain `x86_64` target makes of `round_ties_even`.
#[multiversion(targets("x86_64+avx2+fma", "x86_64+sse4.1"))]
fn rounded_bytes(sums: &[f32], out: &mut [u8]) {
    const TWO_TO_23: f32 = 8_388_608.0;
    for (to, value) in out.iter_mut().zip(sums) {
        *to = ((value.clamp(0.0, 255.0) + TWO_TO_23) - TWO_TO_23) as u8;
    }
}

/// One source row summed across into `row`, each destination pixel's shares of `C` channels.
fn area_row<const C: usize>(line: &[u8], across: &[Share], row: &mut [f32]) {
    for share in across {
        let (Some(pixel), Some(sum)) = (
            line.get(share.source * C..share.source * C + C),
            row.get_mut(share.destination * C..share.destination * C + C),
        ) else {
            continue;
        };
        for c in 0..C {
            sum[c] += f32::from(pixel[c]) * share.weight;
        }
    }
}

/// [`area_row`] for any number of channels.
fn area_row_any(line: &[u8], channels: usize, across: &[Share], row: &mut [f32]) {
    for share in across {
        for c in 0..channels {
            let value = f32::from(line[share.source * channels + c]);
            row[share.destination * channels + c] += value * share.weight;
        }
    }
}

/// `src` at half its width and height into the packed `dst`: each pixel the rounded mean of a 2×2 block.
fn halve(src: &View<'_>, dst: &mut [u8]) {
    let channels = src.channels;
    let out_row = src.width / 2 * channels;
    if out_row == 0 {
        return;
    }
    let mut pairs = vec![0_u16; src.width * channels];
    for (y, out) in dst.chunks_exact_mut(out_row).take(src.height / 2).enumerate() {
        add_rows(src.row(2 * y), src.row(2 * y + 1), &mut pairs);
        match channels {
            1 => halve_row::<1>(&pairs, out),
            3 => halve_row::<3>(&pairs, out),
            4 => halve_row::<4>(&pairs, out),
            _ => halve_row_any(&pairs, channels, out),
        }
    }
}

#[multiversion(targets("x86_64+avx2+fma", "x86_64+sse4.1"))]
fn add_rows(a: &[u8], b: &[u8], sums: &mut [u16]) {
    let n = sums.len();
    let (a, b) = (&a[..n], &b[..n]);
    for i in 0..n {
        sums[i] = u16::from(a[i]) + u16::from(b[i]);
    }
}

#[multiversion(targets("x86_64+avx2+fma", "x86_64+sse4.1"))]
fn halve_row<const C: usize>(sums: &[u16], out: &mut [u8]) {
    for (pair, to) in sums.chunks_exact(2 * C).zip(out.chunks_exact_mut(C)) {
        for c in 0..C {
            to[c] = ((pair[c] + pair[C + c] + 2) >> 2) as u8;
        }
    }
}

fn halve_row_any(sums: &[u16], channels: usize, out: &mut [u8]) {
    for (pair, to) in sums
        .chunks_exact(2 * channels)
        .zip(out.chunks_exact_mut(channels))
    {
        for c in 0..channels {
            to[c] = ((pair[c] + pair[channels + c] + 2) >> 2) as u8;
        }
    }
}

/// Copies the `width × height` region whose top-left pixel is (`x`, `y`) into the packed `dst`. The
/// region must lie inside `src`.
pub fn crop(src: &View<'_>, (x, y): (usize, usize), (width, height): (usize, usize), dst: &mut [u8]) {
    let row_bytes = width * src.channels;
    if row_bytes == 0 {
        return;
    }
    for (row, out) in dst.chunks_exact_mut(row_bytes).take(height).enumerate() {
        let line = src.row(y + row);
        if let Some(part) = line.get(x * src.channels..x * src.channels + row_bytes) {
            out.copy_from_slice(part);
        }
    }
}

/// A flip or a rotation by a quarter turn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Orientation {
    /// Mirror left–right.
    FlipHorizontal,
    /// Mirror top–bottom.
    FlipVertical,
    /// A quarter turn clockwise.
    Rotate90,
    /// A half turn.
    Rotate180,
    /// A quarter turn anticlockwise.
    Rotate270,
}

impl Orientation {
    /// The size of the result for a `width × height` source.
    pub fn size(self, width: usize, height: usize) -> (usize, usize) {
        match self {
            Orientation::Rotate90 | Orientation::Rotate270 => (height, width),
            _ => (width, height),
        }
    }
}

/// `src` flipped or rotated into the packed `dst` (of [`Orientation::size`]).
pub fn orient(src: &View<'_>, orientation: Orientation, dst: &mut [u8]) {
    let (width, height, channels) = (src.width, src.height, src.channels);
    let (out_width, _) = orientation.size(width, height);
    let out_row = out_width * channels;
    if out_row == 0 {
        return;
    }
    match orientation {
        Orientation::FlipVertical => {
            for (y, out) in dst.chunks_exact_mut(out_row).take(height).enumerate() {
                out.copy_from_slice(src.row(height - 1 - y));
            }
        }
        Orientation::FlipHorizontal | Orientation::Rotate180 => {
            for (y, out) in dst.chunks_exact_mut(out_row).take(height).enumerate() {
                let from = if orientation == Orientation::Rotate180 {
                    height - 1 - y
                } else {
                    y
                };
                mirror_row(src.row(from), channels, out);
            }
        }
        Orientation::Rotate90 | Orientation::Rotate270 => {
            // Output row r is source column c read bottom-up (clockwise) or top-down (anticlockwise).
            for (r, out) in dst.chunks_exact_mut(out_row).enumerate() {
                let column = if orientation == Orientation::Rotate90 {
                    r
                } else {
                    width - 1 - r
                };
                for (k, pixel) in out.chunks_exact_mut(channels).enumerate() {
                    let y = if orientation == Orientation::Rotate90 {
                        height - 1 - k
                    } else {
                        k
                    };
                    let from = &src.row(y)[column * channels..][..channels];
                    pixel.copy_from_slice(from);
                }
            }
        }
    }
}

fn mirror_row(row: &[u8], channels: usize, out: &mut [u8]) {
    for (pixel, to) in row
        .chunks_exact(channels)
        .rev()
        .zip(out.chunks_exact_mut(channels))
    {
        to.copy_from_slice(pixel);
    }
}

#[cfg(test)]
mod tests {
    use super::{Interpolation, Orientation, Resize, View, crop, orient};

    #[test]
    fn rotations_move_a_corner_where_expected_and_four_quarter_turns_come_back() {
        // 3 × 2 grey: 1 2 3 / 4 5 6.
        let pixels = [1, 2, 3, 4, 5, 6];
        let view = View::packed(3, 2, 1, &pixels).unwrap();
        let turned = |o: Orientation| {
            let mut out = vec![0; 6];
            orient(&view, o, &mut out);
            out
        };
        assert_eq!(turned(Orientation::Rotate90), [4, 1, 5, 2, 6, 3]);
        assert_eq!(turned(Orientation::Rotate270), [3, 6, 2, 5, 1, 4]);
        assert_eq!(turned(Orientation::Rotate180), [6, 5, 4, 3, 2, 1]);
        assert_eq!(turned(Orientation::FlipHorizontal), [3, 2, 1, 6, 5, 4]);
        assert_eq!(turned(Orientation::FlipVertical), [4, 5, 6, 1, 2, 3]);
        let mut out = vec![0; 2];
        crop(&view, (1, 0), (1, 2), &mut out);
        assert_eq!(out, [2, 5]);
    }

    #[test]
    fn halving_averages_and_every_interpolation_keeps_a_flat_image_flat() {
        let pixels: Vec<u8> = (0..16 * 16 * 3)
            .map(|i| if (i / 3) % 2 == 0 { 0 } else { 200 })
            .collect();
        let view = View::packed(16, 16, 3, &pixels).unwrap();
        let mut out = vec![0; 8 * 8 * 3];
        Resize::default()
            .run(&view, (8, 8), Interpolation::Area, &mut out)
            .unwrap();
        assert!(out.iter().all(|v| *v == 100), "{out:?}");
        let flat = vec![77_u8; 10 * 10];
        let view = View::packed(10, 10, 1, &flat).unwrap();
        for interpolation in [
            Interpolation::Nearest,
            Interpolation::Bilinear,
            Interpolation::Area,
        ] {
            let mut out = vec![0; 23 * 7];
            Resize::default()
                .run(&view, (23, 7), interpolation, &mut out)
                .unwrap();
            assert!(out.iter().all(|v| *v == 77), "{interpolation:?}");
        }
    }
}
