//! Bilinear resizing of 8-bit images, value for value OpenCV's `INTER_LINEAR`: weights in 11-bit fixed
//! point, each computed in `f32` and rounded as OpenCV rounds them, each row first interpolated across
//! into 16-bit intermediates (the two-tap sum shifted right by 4), then down with a 16-bit high multiply
//! per row and a rounding shift of 2 (the arithmetic of OpenCV's vectorised loops; its scalar formula
//! rounds once and can differ by one level, so OpenCV's own result is the one matched). Across the
//! source's edges, the edge pixel stands for the ones beyond it.
//!
//! Interpolating across is a gather the compiler does not vectorise, so on AVX2 it is written with
//! intrinsics: one 8-byte load holds a pixel and its right neighbour (up to 4 channels), a byte shuffle
//! pairs each channel's two taps, and one multiply-add weighs them. Everything else, and every machine
//! without AVX2, takes the portable loops, which give the same values.
#![allow(
    unsafe_code,
    reason = "AVX2 intrinsics for the horizontal gather; each block says why it is sound"
)]

use multiversion::multiversion;

use super::View;

/// OpenCV's `INTER_RESIZE_COEF_BITS`: weights are parts of 2048.
const WEIGHT_ONE: f32 = 2048.0;

/// The taps and weights of one resize from one size to another, kept while the sizes stay.
#[derive(Debug)]
pub struct LinearTaps {
    sizes: [usize; 5],
    /// Per destination pixel: the byte offset of its left tap in a source row (the right tap is the
    /// next pixel, `channels` bytes on).
    across_offsets: Vec<u32>,
    /// Per destination pixel: the left tap's weight in the low 16 bits, the right's in the high 16.
    across_weights: Vec<u32>,
    /// Per destination row: the two source rows and their weights.
    down: Vec<([usize; 2], [i16; 2])>,
}

impl LinearTaps {
    /// The taps from `from` (width, height) to `to`, for pixels of `channels` bytes.
    pub fn new(from: (usize, usize), to: (usize, usize), channels: usize) -> Self {
        let mut across_offsets = Vec::with_capacity(to.0);
        let mut across_weights = Vec::with_capacity(to.0);
        for x in 0..to.0 {
            let (mut tap, mut fraction) = position(x, from.0, to.0);
            // Across, OpenCV moves a position beyond an edge onto the edge pixel, weight one.
            if tap < 0 {
                (tap, fraction) = (0, 0.0);
            }
            let last = from.0.saturating_sub(1) as i64;
            if tap >= last {
                (tap, fraction) = (last, 0.0);
            }
            let [mut left, mut right] = weights(fraction);
            if tap == last && last > 0 {
                // Every tap pair is a pixel and its right neighbour: the last pixel is the right tap of
                // the pair before it, with its weight (the same value: the left tap's weight is 0).
                (tap, left, right) = (last - 1, 0, left);
            }
            across_offsets.push((tap as usize * channels) as u32);
            across_weights.push(u32::from(left as u16) | (u32::from(right as u16) << 16));
        }
        let down = (0..to.1)
            .map(|y| {
                // Down, OpenCV clamps the rows but keeps the weights of the unclamped position.
                let (tap, fraction) = position(y, from.1, to.1);
                let clamp = |row: i64| row.clamp(0, from.1.saturating_sub(1) as i64) as usize;
                ([clamp(tap), clamp(tap + 1)], weights(fraction))
            })
            .collect();
        LinearTaps {
            sizes: [from.0, from.1, to.0, to.1, channels],
            across_offsets,
            across_weights,
            down,
        }
    }

    /// Whether these are the taps for this resize.
    pub fn fit(&self, from: (usize, usize), to: (usize, usize), channels: usize) -> bool {
        self.sizes == [from.0, from.1, to.0, to.1, channels]
    }
}

/// The source position of destination pixel `at` along an axis of `from` pixels resized to `to`: the
/// pixel left of it and the fraction of the way to the next, both as OpenCV computes them (the position
/// in `f64` rounded to `f32`, the fraction in `f32`).
fn position(at: usize, from: usize, to: usize) -> (i64, f32) {
    let scale = 1.0 / (to as f64 / from as f64);
    let exact = ((at as f64 + 0.5) * scale - 0.5) as f32;
    let tap = exact.floor();
    (tap as i64, exact - tap)
}

/// The two taps' weights for a fraction, each rounded to the nearest 1/2048 on its own (ties to even).
fn weights(fraction: f32) -> [i16; 2] {
    [
        ((1.0 - fraction) * WEIGHT_ONE).round_ties_even() as i16,
        (fraction * WEIGHT_ONE).round_ties_even() as i16,
    ]
}

/// Reusable row buffers for [`resize`].
#[derive(Debug, Default)]
pub struct LinearRows {
    /// Two source rows interpolated across, and which source row each holds.
    rows: [Vec<i16>; 2],
    held: [Option<usize>; 2],
}

/// `src` resized bilinearly into the packed `dst` with `taps` (made for `src`'s size and channels).
pub fn resize(src: &View<'_>, taps: &LinearTaps, rows: &mut LinearRows, dst: &mut [u8]) {
    let channels = src.channels;
    let row_values = taps.across_offsets.len() * channels;
    if row_values == 0 {
        return;
    }
    for buffer in &mut rows.rows {
        // Room for the vector loop's last store, which runs up to 2 values past its pixels.
        buffer.resize(row_values + 8, 0);
    }
    rows.held = [None; 2];
    for (&([top, bottom], [upper, lower]), out) in taps.down.iter().zip(dst.chunks_exact_mut(row_values)) {
        // Keep a source row already interpolated: consecutive destination rows share one.
        if rows.held[0] != Some(top) {
            if rows.held[1] == Some(top) {
                rows.rows.swap(0, 1);
                rows.held.swap(0, 1);
            } else {
                across(src.row(top), channels, taps, &mut rows.rows[0]);
                rows.held[0] = Some(top);
            }
        }
        if bottom == top {
            let [first, _] = &rows.rows;
            blend_rows(&first[..row_values], &first[..row_values], [upper, lower], out);
            continue;
        }
        if rows.held[1] != Some(bottom) {
            across(src.row(bottom), channels, taps, &mut rows.rows[1]);
            rows.held[1] = Some(bottom);
        }
        let [first, second] = &rows.rows;
        blend_rows(&first[..row_values], &second[..row_values], [upper, lower], out);
    }
}

/// One source row interpolated across into `out`: each value the two taps' weighted sum, shifted right
/// by 4 as OpenCV does before its 16-bit vertical pass.
fn across(line: &[u8], channels: usize, taps: &LinearTaps, out: &mut [i16]) {
    let mut done = 0;
    #[cfg(target_arch = "x86_64")]
    if taps.sizes[0] >= 2 && std::arch::is_x86_feature_detected!("avx2") {
        // SAFETY: AVX2 was detected on this processor just above.
        done = unsafe { across_avx2(line, channels, taps, out) };
    }
    across_portable(line, channels, taps, done, out);
}

/// [`across`] from pixel `from_pixel` on, without vector instructions: the tails and machines without AVX2.
fn across_portable(line: &[u8], channels: usize, taps: &LinearTaps, from_pixel: usize, out: &mut [i16]) {
    let pairs = taps
        .across_offsets
        .iter()
        .zip(&taps.across_weights)
        .skip(from_pixel);
    for (pixel, (&offset, &weight)) in pairs.enumerate().map(|(k, pair)| (k + from_pixel, pair)) {
        let (left, right) = (
            i32::from(weight as u16 as i16),
            i32::from((weight >> 16) as u16 as i16),
        );
        let offset = offset as usize;
        for c in 0..channels {
            let first = i32::from(line.get(offset + c).copied().unwrap_or(0));
            // With a single source pixel the right tap (weight 0) is past the row.
            let second = i32::from(line.get(offset + channels + c).copied().unwrap_or(0));
            out[pixel * channels + c] = ((first * left + second * right) >> 4) as i16;
        }
    }
}

/// Two interpolated rows blended down with weights in 1/2048: OpenCV's `VResizeLinearVec_32s8u`, a high
/// multiply of each by its weight, summed, then a rounding shift of 2.
#[multiversion(targets("x86_64+avx2+fma", "x86_64+sse4.1"))]
fn blend_rows(first: &[i16], second: &[i16], [upper, lower]: [i16; 2], out: &mut [u8]) {
    let high = |weight: i16, value: i16| ((i32::from(weight) * i32::from(value)) >> 16) as i16;
    for ((to, &a), &b) in out.iter_mut().zip(first).zip(second) {
        let value = (high(upper, a) + high(lower, b) + 2) >> 2;
        *to = value.clamp(0, 255) as u8;
    }
}

/// The pixels [`across`] takes 4 or 8 at a time with AVX2; returns how many it did (the rest, and
/// pixels of 2 channels, are left to the portable loop).
///
/// # Safety
/// The processor must have AVX2.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
#[allow(
    clippy::cast_ptr_alignment,
    reason = "every load here (`loadu`, `loadl`, a gather with scale 1) takes any address"
)]
unsafe fn across_avx2(line: &[u8], channels: usize, taps: &LinearTaps, out: &mut [i16]) -> usize {
    use std::arch::x86_64::{
        __m128i, __m256i, _mm_loadl_epi64, _mm_storeu_si128, _mm256_castsi128_si256, _mm256_castsi256_si128,
        _mm256_extracti128_si256, _mm256_i32gather_epi32, _mm256_inserti128_si256, _mm256_loadu_si256,
        _mm256_madd_epi16, _mm256_packs_epi32, _mm256_permute4x64_epi64, _mm256_permutevar8x32_epi32,
        _mm256_setr_epi8, _mm256_setr_epi32, _mm256_shuffle_epi8, _mm256_srai_epi32, _mm256_storeu_si256,
    };
    /// A shuffle index that writes a zero byte.
    const Z: i8 = -128;
    /// `packs` leaves pixels 0, 2 | 1, 3 in the 64-bit quarters; this puts them in order.
    const IN_ORDER: i32 = 0b11_01_10_00;
    let (offsets, weights) = (&taps.across_offsets[..], &taps.across_weights[..]);
    let pixels = offsets.len().min(weights.len());
    let (base, row) = (line.as_ptr(), out.as_mut_ptr());
    let mut k = 0;
    match channels {
        1 => {
            // One 4-byte gather per pixel holds both taps; each pair becomes two 16-bit values.
            let pair_taps = _mm256_setr_epi8(
                0, Z, 1, Z, 4, Z, 5, Z, 8, Z, 9, Z, 12, Z, 13, Z, 0, Z, 1, Z, 4, Z, 5, Z, 8, Z, 9, Z, 12, Z,
                13, Z,
            );
            while k + 8 <= pixels && offsets[k + 7] as usize + 4 <= line.len() && k + 8 <= out.len() {
                // SAFETY: the 8 offsets and weights at k exist (k + 8 ≤ pixels); every offset is at most
                // the last one (they rise along the row), whose 4 bytes end inside `line`; the 8 values
                // stored at k fit in `out`.
                unsafe {
                    let at = _mm256_loadu_si256(offsets.as_ptr().add(k).cast::<__m256i>());
                    let gathered = _mm256_i32gather_epi32::<1>(base.cast::<i32>(), at);
                    let both = _mm256_shuffle_epi8(gathered, pair_taps);
                    let weighed = _mm256_madd_epi16(both, _mm256_loadu_si256(weights.as_ptr().add(k).cast()));
                    let shifted = _mm256_srai_epi32::<4>(weighed);
                    let packed = _mm256_permute4x64_epi64::<IN_ORDER>(_mm256_packs_epi32(shifted, shifted));
                    _mm_storeu_si128(row.add(k).cast(), _mm256_castsi256_si128(packed));
                }
                k += 8;
            }
        }
        3 | 4 => {
            // One 8-byte load per pixel holds both taps; a pixel per 128-bit lane, each channel's two
            // taps made a pair of 16-bit values (with 3 channels the fourth pair is zero).
            let pair_taps = if channels == 3 {
                _mm256_setr_epi8(
                    0, Z, 3, Z, 1, Z, 4, Z, 2, Z, 5, Z, Z, Z, Z, Z, 0, Z, 3, Z, 1, Z, 4, Z, 2, Z, 5, Z, Z, Z,
                    Z, Z,
                )
            } else {
                _mm256_setr_epi8(
                    0, Z, 4, Z, 1, Z, 5, Z, 2, Z, 6, Z, 3, Z, 7, Z, 0, Z, 4, Z, 1, Z, 5, Z, 2, Z, 6, Z, 3, Z,
                    7, Z,
                )
            };
            // Each lane's two pixels of 4 values to 3 (2 values of padding left at the lane's end).
            let three_of_four = _mm256_setr_epi8(
                0, 1, 2, 3, 4, 5, 8, 9, 10, 11, 12, 13, Z, Z, Z, Z, 0, 1, 2, 3, 4, 5, 8, 9, 10, 11, 12, 13,
                Z, Z, Z, Z,
            );
            let lane_weights = _mm256_setr_epi32(0, 0, 0, 0, 1, 1, 1, 1);
            // The vector writes 2 values past its 4 pixels with 3 channels.
            let room = 4 * channels + if channels == 3 { 2 } else { 0 };
            while k + 4 <= pixels
                && offsets[k + 3] as usize + 8 <= line.len()
                && k * channels + room <= out.len()
            {
                // SAFETY: the 4 offsets and weights at k exist (k + 4 ≤ pixels); every offset is at most
                // the last one, whose 8 bytes end inside `line`; the stores end within `room` values
                // after k's, inside `out`.
                unsafe {
                    let load =
                        |j: usize| _mm_loadl_epi64(base.add(offsets[k + j] as usize).cast::<__m128i>());
                    let weight = |j: usize| {
                        let two = _mm_loadl_epi64(weights.as_ptr().add(k + j).cast::<__m128i>());
                        _mm256_permutevar8x32_epi32(_mm256_castsi128_si256(two), lane_weights)
                    };
                    let lanes =
                        |j: usize| _mm256_inserti128_si256::<1>(_mm256_castsi128_si256(load(j)), load(j + 1));
                    let first = _mm256_madd_epi16(_mm256_shuffle_epi8(lanes(0), pair_taps), weight(0));
                    let second = _mm256_madd_epi16(_mm256_shuffle_epi8(lanes(2), pair_taps), weight(2));
                    let packed = _mm256_permute4x64_epi64::<IN_ORDER>(_mm256_packs_epi32(
                        _mm256_srai_epi32::<4>(first),
                        _mm256_srai_epi32::<4>(second),
                    ));
                    if channels == 4 {
                        _mm256_storeu_si256(row.add(4 * k).cast(), packed);
                    } else {
                        let three = _mm256_shuffle_epi8(packed, three_of_four);
                        _mm_storeu_si128(row.add(3 * k).cast(), _mm256_castsi256_si128(three));
                        _mm_storeu_si128(row.add(3 * k + 6).cast(), _mm256_extracti128_si256::<1>(three));
                    }
                }
                k += 4;
            }
        }
        _ => {}
    }
    k
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_vector_loop_gives_the_portable_loop_s_values() {
        for channels in [1, 2, 3, 4] {
            for (from, to) in [(640, 256), (640, 480), (37, 100), (9, 5), (2, 7), (1, 4)] {
                let line: Vec<u8> = (0..from * channels).map(|i| (i * 7919 % 251) as u8).collect();
                let taps = LinearTaps::new((from, 1), (to, 1), channels);
                let mut out = vec![0; to * channels + 8];
                across(&line, channels, &taps, &mut out);
                let mut portable = vec![0; to * channels + 8];
                across_portable(&line, channels, &taps, 0, &mut portable);
                assert_eq!(
                    &out[..to * channels],
                    &portable[..to * channels],
                    "{channels} channels, {from} to {to}"
                );
            }
        }
    }

    #[test]
    fn a_uniform_image_stays_uniform_and_a_single_pixel_fills_the_result() {
        for channels in [1, 3, 4] {
            let src = vec![255_u8; 50 * 30 * channels];
            let view = View::packed(50, 30, channels, &src).expect("fits");
            for to in [(20, 12), (77, 51), (50, 30), (1, 1)] {
                let taps = LinearTaps::new((50, 30), to, channels);
                let mut dst = vec![0; to.0 * to.1 * channels];
                resize(&view, &taps, &mut LinearRows::default(), &mut dst);
                assert!(dst.iter().all(|&v| v == 255), "{channels} channels to {to:?}");
            }
            let one = vec![77_u8; channels];
            let view = View::packed(1, 1, channels, &one).expect("fits");
            let taps = LinearTaps::new((1, 1), (5, 3), channels);
            let mut dst = vec![0; 15 * channels];
            resize(&view, &taps, &mut LinearRows::default(), &mut dst);
            assert!(dst.iter().all(|&v| v == 77));
        }
    }
}
