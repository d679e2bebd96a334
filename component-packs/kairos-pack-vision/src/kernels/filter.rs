//! Neighbourhood and point filters: Gaussian blur, threshold, erosion and dilation, histogram
//! equalisation, absolute difference. Borders reflect (`gfedcb|abcdefgh|gfedcba`) as OpenCV's default
//! does, so results match it pixel for pixel where the algorithm is the same.

use multiversion::multiversion;

use super::{View, reflect_101};

/// A separable Gaussian kernel in 8-bit fixed point (its taps sum to 256).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Gaussian {
    taps: Vec<u16>,
}

impl Gaussian {
    /// The kernel of odd `size` (1 to 31) and standard deviation `sigma`; a `sigma` of 0 or less takes
    /// the one OpenCV derives from the size, `0.3 × ((size − 1) / 2 − 1) + 0.8`, and sizes 3, 5 and 7 then
    /// use OpenCV's fixed taps (1 2 1; 1 4 6 4 1; 2 7 14 18 14 7 2, over 4, 16 and 64).
    pub fn new(size: usize, sigma: f64) -> Option<Self> {
        if size.is_multiple_of(2) || !(1..=31).contains(&size) || sigma.is_nan() {
            return None;
        }
        if sigma <= 0.0 {
            match size {
                3 => {
                    return Some(Gaussian {
                        taps: vec![64, 128, 64],
                    });
                }
                5 => {
                    return Some(Gaussian {
                        taps: vec![16, 64, 96, 64, 16],
                    });
                }
                // OpenCV's fixed table for 7 (1/32, 7/64, 7/32, 9/32, …), not the sampled Gaussian.
                7 => {
                    return Some(Gaussian {
                        taps: vec![8, 28, 56, 72, 56, 28, 8],
                    });
                }
                _ => {}
            }
        }
        let sigma = if sigma > 0.0 {
            sigma
        } else {
            0.3 * ((size as f64 - 1.0) * 0.5 - 1.0) + 0.8
        };
        let half = (size / 2) as f64;
        let weights: Vec<f64> = (0..size)
            .map(|i| (-((i as f64 - half).powi(2)) / (2.0 * sigma * sigma)).exp())
            .collect();
        let total: f64 = weights.iter().sum();
        let mut taps: Vec<u16> = weights
            .iter()
            .map(|w| (w / total * 256.0).round() as u16)
            .collect();
        // Rounding may miss 256 by a little: the centre takes the difference, so flat areas stay flat.
        let sum: i32 = taps.iter().map(|t| i32::from(*t)).sum();
        let centre = &mut taps[size / 2];
        *centre = (i32::from(*centre) + 256 - sum).clamp(0, 256) as u16;
        Some(Gaussian { taps })
    }

    /// The taps, summing to 256.
    pub fn taps(&self) -> &[u16] {
        &self.taps
    }
}

/// Blurs `src` into the packed `dst` with `kernel`, horizontally and vertically.
pub fn gaussian_blur(src: &View<'_>, kernel: &Gaussian, dst: &mut [u8]) {
    let (width, height, channels) = (src.width, src.height, src.channels);
    let row_bytes = width * channels;
    if row_bytes == 0 || height == 0 {
        return;
    }
    let taps = kernel.taps();
    let radius = taps.len() / 2;
    // One vertically filtered row, with `radius` reflected pixels at each end for the horizontal pass.
    let mut column_sums = vec![0_u32; row_bytes + 2 * radius * channels];
    let binomial5 = taps == [16, 64, 96, 64, 16];
    let mut narrow = vec![0_u16; if binomial5 { column_sums.len() } else { 0 }];
    for (y, out) in dst.chunks_exact_mut(row_bytes).take(height).enumerate() {
        let rows: Vec<&[u8]> = (0..taps.len())
            .map(|k| src.row(reflect_101(y as isize + k as isize - radius as isize, height)))
            .collect();
        if binomial5 {
            // 1 4 6 4 1 twice stays within 16 bits: twice as many lanes per instruction.
            vertical_binomial5(&rows, &mut narrow[radius * channels..][..row_bytes]);
            reflect_ends(&mut narrow, width, channels, radius);
            horizontal_binomial5(&narrow, channels, out);
        } else {
            vertical_taps(&rows, taps, &mut column_sums[radius * channels..][..row_bytes]);
            reflect_ends(&mut column_sums, width, channels, radius);
            horizontal_taps(&column_sums, taps, channels, out);
        }
    }
}

/// Fills the `radius` pixels padding each end of `row` with the reflected pixels next to them.
fn reflect_ends<T: Copy>(row: &mut [T], width: usize, channels: usize, radius: usize) {
    for k in 0..radius {
        let before = reflect_101(k as isize - radius as isize, width);
        let after = reflect_101((width + k) as isize, width);
        for c in 0..channels {
            row[k * channels + c] = row[(radius + before) * channels + c];
            row[(radius + width + k) * channels + c] = row[(radius + after) * channels + c];
        }
    }
}

#[multiversion(targets("x86_64+avx2+fma", "x86_64+sse4.1"))]
fn vertical_binomial5(rows: &[&[u8]], out: &mut [u16]) {
    let n = out.len();
    let (r0, r1, r2, r3, r4) = (
        &rows[0][..n],
        &rows[1][..n],
        &rows[2][..n],
        &rows[3][..n],
        &rows[4][..n],
    );
    for i in 0..n {
        out[i] = u16::from(r0[i])
            + u16::from(r4[i])
            + 4 * (u16::from(r1[i]) + u16::from(r3[i]))
            + 6 * u16::from(r2[i]);
    }
}

#[multiversion(targets("x86_64+avx2+fma", "x86_64+sse4.1"))]
fn horizontal_binomial5(padded: &[u16], channels: usize, out: &mut [u8]) {
    match channels {
        1 => horizontal_binomial5_of::<1>(padded, out),
        3 => horizontal_binomial5_of::<3>(padded, out),
        4 => horizontal_binomial5_of::<4>(padded, out),
        _ => horizontal_binomial5_any(padded, channels, out),
    }
}

#[inline(always)]
#[allow(
    clippy::inline_always,
    reason = "inlined into its multiversioned caller, so it is compiled for that caller's target features"
)]
fn horizontal_binomial5_of<const C: usize>(padded: &[u16], out: &mut [u8]) {
    let n = out.len();
    let (p0, p1, p2, p3, p4) = (
        &padded[..n],
        &padded[C..C + n],
        &padded[2 * C..2 * C + n],
        &padded[3 * C..3 * C + n],
        &padded[4 * C..4 * C + n],
    );
    for i in 0..n {
        // The sum peaks at 16 × 16 × 255 = 65 280: it fits, and the rounding is added in 32 bits.
        let sum = p0[i] + p4[i] + 4 * (p1[i] + p3[i]) + 6 * p2[i];
        out[i] = ((u32::from(sum) + 128) >> 8) as u8;
    }
}

#[inline(always)]
#[allow(
    clippy::inline_always,
    reason = "inlined into its multiversioned caller, so it is compiled for that caller's target features"
)]
fn horizontal_binomial5_any(padded: &[u16], channels: usize, out: &mut [u8]) {
    for (i, value) in out.iter_mut().enumerate() {
        let at = |k: usize| u32::from(padded[i + k * channels]);
        let sum = at(0) + at(4) + 4 * (at(1) + at(3)) + 6 * at(2);
        *value = ((sum + 128) >> 8) as u8;
    }
}

#[multiversion(targets("x86_64+avx2+fma", "x86_64+sse4.1"))]
fn vertical_taps(rows: &[&[u8]], taps: &[u16], out: &mut [u32]) {
    let n = out.len();
    out.fill(0);
    for (row, tap) in rows.iter().zip(taps) {
        let row = &row[..n];
        let tap = u32::from(*tap);
        for i in 0..n {
            out[i] += u32::from(row[i]) * tap;
        }
    }
}

#[multiversion(targets("x86_64+avx2+fma", "x86_64+sse4.1"))]
fn horizontal_taps(padded: &[u32], taps: &[u16], channels: usize, out: &mut [u8]) {
    let n = out.len();
    let mut sums = vec![0_u32; n];
    for (k, tap) in taps.iter().enumerate() {
        let shifted = &padded[k * channels..k * channels + n];
        let tap = u32::from(*tap);
        for i in 0..n {
            sums[i] += shifted[i] * tap;
        }
    }
    for (value, sum) in out.iter_mut().zip(&sums) {
        *value = ((sum + (1 << 15)) >> 16) as u8;
    }
}

/// How [`threshold`] maps a byte against the level.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ThresholdKind {
    /// Above the level: `max`; else 0.
    Binary,
    /// Above the level: 0; else `max`.
    BinaryInverted,
    /// Above the level: the level; else unchanged.
    Truncate,
    /// Above the level: unchanged; else 0.
    ToZero,
}

/// Applies a threshold to every byte (every channel), in place.
#[multiversion(targets("x86_64+avx2+fma", "x86_64+sse4.1"))]
pub fn threshold(bytes: &mut [u8], level: u8, max: u8, kind: ThresholdKind) {
    match kind {
        ThresholdKind::Binary => bytes
            .iter_mut()
            .for_each(|b| *b = if *b > level { max } else { 0 }),
        ThresholdKind::BinaryInverted => bytes
            .iter_mut()
            .for_each(|b| *b = if *b > level { 0 } else { max }),
        ThresholdKind::Truncate => bytes.iter_mut().for_each(|b| *b = (*b).min(level)),
        ThresholdKind::ToZero => bytes
            .iter_mut()
            .for_each(|b| *b = if *b > level { *b } else { 0 }),
    }
}

/// The level that best splits a grey histogram in two (Otsu's method: most variance between classes).
pub fn otsu_level(grey: &[u8]) -> u8 {
    let histogram = histogram(grey);
    let total = grey.len() as f64;
    let weighted_total: f64 = histogram
        .iter()
        .enumerate()
        .map(|(i, n)| i as f64 * *n as f64)
        .sum();
    let (mut below, mut weighted_below) = (0.0, 0.0);
    let (mut best, mut best_variance) = (0_u8, -1.0);
    for (level, count) in histogram.iter().enumerate() {
        below += *count as f64;
        weighted_below += level as f64 * *count as f64;
        let above = total - below;
        if below == 0.0 || above <= 0.0 {
            continue;
        }
        let mean_below = weighted_below / below;
        let mean_above = (weighted_total - weighted_below) / above;
        let variance = below * above * (mean_below - mean_above).powi(2);
        if variance > best_variance {
            best_variance = variance;
            best = level as u8;
        }
    }
    best
}

/// Counts of each byte value.
pub fn histogram(bytes: &[u8]) -> [u64; 256] {
    // Four tables break the dependency between neighbouring equal bytes.
    let mut tables = [[0_u64; 256]; 4];
    let mut quads = bytes.chunks_exact(4);
    for quad in &mut quads {
        for (table, byte) in tables.iter_mut().zip(quad) {
            table[usize::from(*byte)] += 1;
        }
    }
    for byte in quads.remainder() {
        tables[0][usize::from(*byte)] += 1;
    }
    let mut counts = [0_u64; 256];
    for (i, count) in counts.iter_mut().enumerate() {
        *count = tables.iter().map(|t| t[i]).sum();
    }
    counts
}

/// Spreads a grey image's histogram over the whole range, in place (OpenCV's `equalizeHist`).
pub fn equalize(grey: &mut [u8]) {
    let histogram = histogram(grey);
    let total = grey.len() as u64;
    let Some(lowest) = histogram.iter().position(|n| *n > 0) else {
        return;
    };
    if histogram[lowest] == total {
        // One value: nothing to spread.
        return;
    }
    let scale = 255.0 / (total - histogram[lowest]) as f64;
    let mut table = [0_u8; 256];
    let mut cumulative = 0;
    for (value, count) in histogram.iter().enumerate().skip(lowest + 1) {
        cumulative += count;
        table[value] = (cumulative as f64 * scale).round().min(255.0) as u8;
    }
    for byte in grey.iter_mut() {
        *byte = table[usize::from(*byte)];
    }
}

/// Which extreme [`morphology`] keeps over each neighbourhood.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Morphology {
    /// The minimum: bright regions shrink.
    Erode,
    /// The maximum: bright regions grow.
    Dilate,
}

/// Erodes or dilates `src` with a `size × size` square into the packed `dst`; the border replicates the
/// edge pixels, which leaves edges alone as OpenCV's default does.
pub fn morphology(src: &View<'_>, operation: Morphology, size: usize, dst: &mut [u8]) {
    let (width, height, channels) = (src.width, src.height, src.channels);
    let row_bytes = width * channels;
    if row_bytes == 0 || height == 0 {
        return;
    }
    let radius = size / 2;
    let mut column = vec![0_u8; row_bytes + 2 * radius * channels];
    let dilate = operation == Morphology::Dilate;
    for (y, out) in dst.chunks_exact_mut(row_bytes).take(height).enumerate() {
        let first = y.saturating_sub(radius);
        let last = (y + radius).min(height - 1);
        let middle = &mut column[radius * channels..][..row_bytes];
        middle.copy_from_slice(src.row(first));
        for other in first + 1..=last {
            extreme_into(middle, src.row(other), dilate);
        }
        for k in 0..radius {
            for c in 0..channels {
                column[k * channels + c] = column[radius * channels + c];
                column[(radius + width + k) * channels + c] = column[(radius + width - 1) * channels + c];
            }
        }
        out.copy_from_slice(&column[..row_bytes]);
        for k in 1..=2 * radius {
            extreme_into(out, &column[k * channels..][..row_bytes], dilate);
        }
    }
}

#[multiversion(targets("x86_64+avx2+fma", "x86_64+sse4.1"))]
fn extreme_into(into: &mut [u8], other: &[u8], dilate: bool) {
    let other = &other[..into.len()];
    if dilate {
        into.iter_mut().zip(other).for_each(|(a, b)| *a = (*a).max(*b));
    } else {
        into.iter_mut().zip(other).for_each(|(a, b)| *a = (*a).min(*b));
    }
}

/// `|a − b|` for every byte, into `out`.
#[multiversion(targets("x86_64+avx2+fma", "x86_64+sse4.1"))]
pub fn absolute_difference(a: &[u8], b: &[u8], out: &mut [u8]) {
    for ((x, y), o) in a.iter().zip(b).zip(out.iter_mut()) {
        *o = x.abs_diff(*y);
    }
}

#[cfg(test)]
mod tests {
    use super::{Gaussian, Morphology, View, equalize, gaussian_blur, morphology, otsu_level};

    #[test]
    fn a_blur_keeps_flat_areas_flat_and_spreads_a_point_by_the_binomial_taps() {
        let mut image = vec![100_u8; 9 * 9];
        let view = View::packed(9, 9, 1, &image).unwrap();
        let mut out = vec![0; 81];
        gaussian_blur(&view, &Gaussian::new(5, 0.0).unwrap(), &mut out);
        assert!(out.iter().all(|v| *v == 100));
        image.fill(0);
        image[4 * 9 + 4] = 255;
        let view = View::packed(9, 9, 1, &image).unwrap();
        gaussian_blur(&view, &Gaussian::new(5, 0.0).unwrap(), &mut out);
        // The centre weighs 6 × 6 / 256 of the point: 35.9.
        assert_eq!(out[4 * 9 + 4], 36);
        assert_eq!(out[4 * 9 + 2], 6); // 6 × 1 / 256 × 255
        // Any size: the general path gives the same shape, and taps always sum to 256.
        for size in [1, 3, 7, 9, 31] {
            let kernel = Gaussian::new(size, 2.0).unwrap();
            assert_eq!(kernel.taps().iter().map(|t| u32::from(*t)).sum::<u32>(), 256);
        }
        assert!(Gaussian::new(4, 0.0).is_none() && Gaussian::new(33, 0.0).is_none());
    }

    #[test]
    fn erosion_and_dilation_shrink_and_grow_a_square() {
        let mut image = vec![0_u8; 10 * 10];
        for y in 3..7 {
            image[y * 10 + 3..y * 10 + 7].fill(255);
        }
        let view = View::packed(10, 10, 1, &image).unwrap();
        #[allow(clippy::naive_bytecount, reason = "a test: clarity over speed")]
        let count = |bytes: &[u8]| bytes.iter().filter(|b| **b == 255).count();
        let mut out = vec![0; 100];
        morphology(&view, Morphology::Erode, 3, &mut out);
        assert_eq!(count(&out), 4);
        morphology(&view, Morphology::Dilate, 3, &mut out);
        assert_eq!(count(&out), 36);
    }

    #[test]
    fn otsu_splits_two_populations_and_equalisation_spreads_a_narrow_range() {
        let mut grey: Vec<u8> = (0..1000).map(|i| if i % 2 == 0 { 40 } else { 200 }).collect();
        let level = otsu_level(&grey);
        assert!((40..200).contains(&level), "{level}");
        grey = (0..1000).map(|i| 100 + (i % 20) as u8).collect();
        equalize(&mut grey);
        assert_eq!(grey.iter().max(), Some(&255));
        assert!(*grey.iter().min().unwrap() < 20);
    }
}
