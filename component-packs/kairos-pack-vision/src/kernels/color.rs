//! Colour conversions between grey, RGB, BGR, RGBA and BGRA. Grey uses BT.601 weights in 15-bit fixed
//! point (0.299 R + 0.587 G + 0.114 B, rounded), the weights OpenCV's `cvtColor` uses, so a grey image
//! is bit-identical to OpenCV's.

use multiversion::multiversion;

use super::View;

/// A byte layout of colour pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Layout {
    /// One byte of luma.
    Gray,
    /// Red, green, blue.
    Rgb,
    /// Blue, green, red.
    Bgr,
    /// Red, green, blue, alpha.
    Rgba,
    /// Blue, green, red, alpha.
    Bgra,
}

impl Layout {
    /// Bytes per pixel.
    pub fn channels(self) -> usize {
        match self {
            Layout::Gray => 1,
            Layout::Rgb | Layout::Bgr => 3,
            Layout::Rgba | Layout::Bgra => 4,
        }
    }
}

/// BT.601 luma weights in 15-bit fixed point (summing to 1 << 15), as OpenCV's `cvtColor` uses them for
/// 8-bit images: results are identical (all 16.7 million colours checked against OpenCV 5.0).
const RED_WEIGHT: u32 = 9798;
const GREEN_WEIGHT: u32 = 19235;
const BLUE_WEIGHT: u32 = 3735;
const WEIGHT_SHIFT: u32 = 15;

/// Converts `src` (in `from`) into the packed `dst` (in `to`, `width × height × to.channels()` bytes).
/// Alpha becomes 255 where the source has none.
///
/// # Panics
///
/// Never on sizes the caller checked: `dst` shorter than the image, or `src` not in `from`'s channel
/// count, is a programming error caught by a debug assertion and otherwise leaves rows unwritten.
pub fn convert(src: &View<'_>, from: Layout, to: Layout, dst: &mut [u8]) {
    debug_assert_eq!(src.channels, from.channels());
    let out_row = src.width * to.channels();
    if out_row == 0 {
        return;
    }
    for (y, out) in dst.chunks_exact_mut(out_row).take(src.height).enumerate() {
        convert_row(src.row(y), from, to, out);
    }
}

#[multiversion(targets("x86_64+avx2+fma", "x86_64+sse4.1"))]
fn convert_row(src: &[u8], from: Layout, to: Layout, out: &mut [u8]) {
    use Layout::{Bgr, Bgra, Gray, Rgb, Rgba};
    match (from, to) {
        (a, b) if a == b => out.copy_from_slice(&src[..out.len()]),
        (Gray, _) => gray_to(src, out, to.channels()),
        (Rgb, Gray) => to_gray::<3, 0>(src, out),
        (Bgr, Gray) => to_gray::<3, 2>(src, out),
        (Rgba, Gray) => to_gray::<4, 0>(src, out),
        (Bgra, Gray) => to_gray::<4, 2>(src, out),
        (Rgb, Bgr) | (Bgr, Rgb) => repack::<3, 3, true>(src, out),
        (Rgba, Bgra) | (Bgra, Rgba) => repack::<4, 4, true>(src, out),
        (Rgb, Rgba) | (Bgr, Bgra) => repack::<3, 4, false>(src, out),
        (Rgb, Bgra) | (Bgr, Rgba) => repack::<3, 4, true>(src, out),
        (Rgba, Rgb) | (Bgra, Bgr) => repack::<4, 3, false>(src, out),
        (Rgba, Bgr) | (Bgra, Rgb) => repack::<4, 3, true>(src, out),
        // Every other pair is listed above.
        _ => {}
    }
}

#[inline(always)]
#[allow(
    clippy::inline_always,
    reason = "inlined into its multiversioned caller, so it is compiled for that caller's target features"
)]
fn to_gray<const C: usize, const RED: usize>(src: &[u8], out: &mut [u8]) {
    for (pixel, luma) in src.chunks_exact(C).zip(out.iter_mut()) {
        let weighted = u32::from(pixel[RED]) * RED_WEIGHT
            + u32::from(pixel[1]) * GREEN_WEIGHT
            + u32::from(pixel[2 - RED]) * BLUE_WEIGHT;
        *luma = ((weighted + (1 << (WEIGHT_SHIFT - 1))) >> WEIGHT_SHIFT) as u8;
    }
}

#[inline(always)]
#[allow(
    clippy::inline_always,
    reason = "inlined into its multiversioned caller, so it is compiled for that caller's target features"
)]
fn gray_to(src: &[u8], out: &mut [u8], channels: usize) {
    match channels {
        3 => {
            for (luma, pixel) in src.iter().zip(out.chunks_exact_mut(3)) {
                pixel.copy_from_slice(&[*luma; 3]);
            }
        }
        4 => {
            for (luma, pixel) in src.iter().zip(out.chunks_exact_mut(4)) {
                pixel.copy_from_slice(&[*luma, *luma, *luma, 255]);
            }
        }
        _ => out.copy_from_slice(&src[..out.len()]),
    }
}

/// From `SC` to `DC` bytes per pixel, swapping red and blue when `SWAP`; alpha is 255 when added.
#[inline(always)]
#[allow(
    clippy::inline_always,
    reason = "inlined into its multiversioned caller, so it is compiled for that caller's target features"
)]
fn repack<const SC: usize, const DC: usize, const SWAP: bool>(src: &[u8], out: &mut [u8]) {
    for (pixel, to) in src.chunks_exact(SC).zip(out.chunks_exact_mut(DC)) {
        let (first, last) = if SWAP {
            (pixel[2], pixel[0])
        } else {
            (pixel[0], pixel[2])
        };
        to[0] = first;
        to[1] = pixel[1];
        to[2] = last;
        if DC == 4 {
            to[3] = if SC == 4 { pixel[3] } else { 255 };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::{Layout, View, convert};

    fn one(pixel: &[u8], from: Layout, to: Layout) -> Vec<u8> {
        let view = View::packed(1, 1, from.channels(), pixel).unwrap();
        let mut out = vec![0; to.channels()];
        convert(&view, from, to, &mut out);
        out
    }

    #[test]
    fn grey_matches_the_bt601_weights_and_every_layout_round_trips() {
        // 0.299 × 200 + 0.587 × 100 + 0.114 × 50 = 124.2
        assert_eq!(one(&[200, 100, 50], Layout::Rgb, Layout::Gray), [124]);
        assert_eq!(one(&[50, 100, 200], Layout::Bgr, Layout::Gray), [124]);
        assert_eq!(one(&[50, 100, 200, 7], Layout::Bgra, Layout::Gray), [124]);
        assert_eq!(one(&[9], Layout::Gray, Layout::Rgba), [9, 9, 9, 255]);
        let layouts = [Layout::Rgb, Layout::Bgr, Layout::Rgba, Layout::Bgra];
        for from in layouts {
            for to in layouts {
                let rgba = [10, 20, 30, 255];
                let start = one(&rgba, Layout::Rgba, from);
                let there = one(&start, from, to);
                assert_eq!(one(&there, to, Layout::Rgba), rgba, "{from:?} to {to:?}");
            }
        }
    }
}
