//! Sobel gradients and Canny edges on grey images. The Canny detector follows the classic recipe with
//! OpenCV's choices (3×3 Sobel with replicated borders, L1 gradient magnitude, non-maximum suppression
//! in four directions, hysteresis between two thresholds), so its edges match OpenCV's `Canny` with
//! `L2gradient = false`.

use multiversion::multiversion;

use super::View;

/// The 3×3 Sobel derivatives of one row `y` of a grey image: `dx` and `dy`, `width` values each.
/// Borders replicate the edge pixels.
fn sobel_row(grey: &View<'_>, y: usize, dx: &mut [i16], dy: &mut [i16], sums: &mut [i16], diffs: &mut [i16]) {
    let width = grey.width;
    let above = grey.row(y.saturating_sub(1));
    let here = grey.row(y);
    let below = grey.row((y + 1).min(grey.height - 1));
    // Vertical pass into the padded rows (one pixel each side), then the horizontal pass.
    vertical_sobel(above, here, below, &mut sums[1..=width], &mut diffs[1..=width]);
    sums[0] = sums[1];
    sums[width + 1] = sums[width];
    diffs[0] = diffs[1];
    diffs[width + 1] = diffs[width];
    horizontal_sobel(sums, diffs, dx, dy);
}

#[multiversion(targets("x86_64+avx2+fma", "x86_64+sse4.1"))]
fn vertical_sobel(above: &[u8], here: &[u8], below: &[u8], sums: &mut [i16], diffs: &mut [i16]) {
    let n = sums.len();
    let (above, here, below, diffs) = (&above[..n], &here[..n], &below[..n], &mut diffs[..n]);
    for i in 0..n {
        let (a, h, b) = (i16::from(above[i]), i16::from(here[i]), i16::from(below[i]));
        sums[i] = a + 2 * h + b;
        diffs[i] = b - a;
    }
}

#[multiversion(targets("x86_64+avx2+fma", "x86_64+sse4.1"))]
fn horizontal_sobel(sums: &[i16], diffs: &[i16], dx: &mut [i16], dy: &mut [i16]) {
    let n = dx.len();
    let (left_s, right_s) = (&sums[..n], &sums[2..n + 2]);
    let (left_d, mid_d, right_d) = (&diffs[..n], &diffs[1..=n], &diffs[2..n + 2]);
    let dy = &mut dy[..n];
    for i in 0..n {
        dx[i] = right_s[i] - left_s[i];
        dy[i] = left_d[i] + 2 * mid_d[i] + right_d[i];
    }
}

/// `|dx| + |dy|`, saturated to a byte: the Sobel edge strength of a grey image into the packed `dst`.
pub fn sobel_magnitude(grey: &View<'_>, dst: &mut [u8]) {
    let width = grey.width;
    if width == 0 || grey.height == 0 {
        return;
    }
    let (mut dx, mut dy) = (vec![0_i16; width], vec![0_i16; width]);
    let (mut sums, mut diffs) = (vec![0_i16; width + 2], vec![0_i16; width + 2]);
    for (y, out) in dst.chunks_exact_mut(width).take(grey.height).enumerate() {
        sobel_row(grey, y, &mut dx, &mut dy, &mut sums, &mut diffs);
        magnitude_bytes(&dx, &dy, out);
    }
}

#[multiversion(targets("x86_64+avx2+fma", "x86_64+sse4.1"))]
fn magnitude_bytes(dx: &[i16], dy: &[i16], out: &mut [u8]) {
    for ((x, y), o) in dx.iter().zip(dy).zip(out.iter_mut()) {
        *o = (x.unsigned_abs() + y.unsigned_abs()).min(255) as u8;
    }
}

#[multiversion(targets("x86_64+avx2+fma", "x86_64+sse4.1"))]
fn magnitude_l1(dx: &[i16], dy: &[i16], out: &mut [i32]) {
    let n = dx.len();
    let (dy, out) = (&dy[..n], &mut out[..n]);
    for i in 0..n {
        out[i] = i32::from(dx[i]).abs() + i32::from(dy[i]).abs();
    }
}

/// Not an edge.
const NONE: u8 = 1;
/// Above the low threshold and a local maximum: an edge if it touches a strong one.
const CANDIDATE: u8 = 0;
/// An edge.
const EDGE: u8 = 2;

/// Reused buffers of the Canny detector, so a stream of frames allocates once.
#[derive(Debug, Default)]
pub struct Canny {
    map: Vec<u8>,
    magnitudes: Vec<i32>,
    gradients: Vec<i16>,
    scratch: Vec<i16>,
    stack: Vec<usize>,
}

impl Canny {
    /// Edges of `grey` into the packed `dst` (255 on an edge, 0 elsewhere): gradients above `high`
    /// start edges, those above `low` continue them.
    pub fn detect(&mut self, grey: &View<'_>, low: i32, high: i32, dst: &mut [u8]) {
        let (width, height) = (grey.width, grey.height);
        if width == 0 || height == 0 {
            return;
        }
        let (low, high) = (low.min(high), high.max(low));
        // The map has a one-pixel frame of NONE so neighbours need no bounds checks.
        let map_width = width + 2;
        self.map.clear();
        self.map.resize(map_width * (height + 2), NONE);
        // Three rows of magnitudes (above, here, below), each padded by one zero at each end.
        self.magnitudes.clear();
        self.magnitudes.resize(3 * map_width, 0);
        // dx and dy of the rows held: two rows, since suppression looks at the row below's magnitude.
        self.gradients.clear();
        self.gradients.resize(4 * width, 0);
        self.scratch.clear();
        self.scratch.resize(2 * (width + 2), 0);
        self.stack.clear();

        let (x_gradients, y_gradients) = self.gradients.split_at_mut(2 * width);
        let (sums, diffs) = self.scratch.split_at_mut(width + 2);
        let magnitude_row = |slot: usize| slot * map_width + 1;
        // Row 0 into slot 1 ("here" of the first step); slot 0 ("above") stays zero.
        sobel_row(
            grey,
            0,
            &mut x_gradients[..width],
            &mut y_gradients[..width],
            sums,
            diffs,
        );
        magnitude_l1(
            &x_gradients[..width],
            &y_gradients[..width],
            &mut self.magnitudes[magnitude_row(1)..][..width],
        );
        for y in 0..height {
            let here = y % 2;
            let next = 1 - here;
            let (below_slot, here_slot, above_slot) = ((y + 2) % 3, (y + 1) % 3, y % 3);
            if y + 1 < height {
                sobel_row(
                    grey,
                    y + 1,
                    &mut x_gradients[next * width..][..width],
                    &mut y_gradients[next * width..][..width],
                    sums,
                    diffs,
                );
                magnitude_l1(
                    &x_gradients[next * width..][..width],
                    &y_gradients[next * width..][..width],
                    &mut self.magnitudes[magnitude_row(below_slot)..][..width],
                );
            } else {
                self.magnitudes[magnitude_row(below_slot)..][..width].fill(0);
            }
            let rows = Rows {
                above: &self.magnitudes[above_slot * map_width..][..map_width],
                here: &self.magnitudes[here_slot * map_width..][..map_width],
                below: &self.magnitudes[below_slot * map_width..][..map_width],
            };
            let map_row = (y + 1) * map_width;
            suppress_row(
                &rows,
                &x_gradients[here * width..][..width],
                &y_gradients[here * width..][..width],
                (low, high),
                &mut self.map[map_row..map_row + map_width],
                map_row,
                &mut self.stack,
            );
        }
        self.hysteresis(map_width);
        for (y, out) in dst.chunks_exact_mut(width).take(height).enumerate() {
            let row = &self.map[(y + 1) * map_width + 1..][..width];
            edge_bytes(row, out);
        }
    }

    fn hysteresis(&mut self, map_width: usize) {
        let map = &mut self.map;
        while let Some(at) = self.stack.pop() {
            for neighbour in [
                at - map_width - 1,
                at - map_width,
                at - map_width + 1,
                at - 1,
                at + 1,
                at + map_width - 1,
                at + map_width,
                at + map_width + 1,
            ] {
                if map[neighbour] == CANDIDATE {
                    map[neighbour] = EDGE;
                    self.stack.push(neighbour);
                }
            }
        }
    }
}

struct Rows<'a> {
    above: &'a [i32],
    here: &'a [i32],
    below: &'a [i32],
}

/// tan(22.5°) in 15-bit fixed point.
const TAN_22_5: i32 = 13_573;

/// Non-maximum suppression of one row: marks local maxima above `low` as candidates, those above
/// `high` as edges (pushed to start hysteresis).
fn suppress_row(
    rows: &Rows<'_>,
    dx: &[i16],
    dy: &[i16],
    (low, high): (i32, i32),
    map: &mut [u8],
    map_offset: usize,
    stack: &mut Vec<usize>,
) {
    let width = dx.len().min(dy.len());
    let map = &mut map[..width + 2];
    classify_row(
        rows.above,
        rows.here,
        rows.below,
        &dx[..width],
        &dy[..width],
        [low, high],
        &mut map[1..=width],
    );
    // The strong ones start hysteresis; on a photograph most 16-pixel runs have none.
    for (chunk, codes) in map[1..=width].chunks(16).enumerate() {
        if codes.iter().fold(0, |any, &code| any | u8::from(code == EDGE)) != 0 {
            for (x, &code) in codes.iter().enumerate() {
                if code == EDGE {
                    stack.push(map_offset + 1 + chunk * 16 + x);
                }
            }
        }
    }
}

/// `when_set` where `mask` is all ones, `otherwise` where it is zero.
#[inline]
fn pick(mask: i32, when_set: i32, otherwise: i32) -> i32 {
    otherwise ^ ((when_set ^ otherwise) & mask)
}

/// The suppression's codes of one row (`NONE`, `CANDIDATE`, `EDGE`), without a branch: on a photograph
/// the directions change from pixel to pixel and the magnitudes cross the low threshold as often, so
/// branches would be mispredicted about half the time; as selects the loop vectorises. The arithmetic
/// fits in i32: a 3×3 Sobel component is at most 1020, so |dy| << 15 and |dx| << 16 stay below 2^27.
#[multiversion(targets("x86_64+avx2+fma", "x86_64+sse4.1"))]
fn classify_row(
    above: &[i32],
    here: &[i32],
    below: &[i32],
    dx: &[i16],
    dy: &[i16],
    [low, high]: [i32; 2],
    codes: &mut [u8],
) {
    let width = codes.len().min(dx.len()).min(dy.len());
    let (above, here, below) = (&above[..width + 2], &here[..width + 2], &below[..width + 2]);
    for x in 0..width {
        let m = here[x + 1];
        let (gx, gy) = (i32::from(dx[x]), i32::from(dy[x]));
        let (ax, ay) = (gx.abs(), gy.abs() << 15);
        let tan_22 = ax * TAN_22_5;
        let horizontal = ay < tan_22;
        let vertical = ay > tan_22 + (ax << 16);
        // Every neighbour is loaded and the two wanted picked by masks, not by choosing addresses: a
        // chosen address makes the compiler load lane by lane.
        let (above_left, above_middle, above_right) = (above[x], above[x + 1], above[x + 2]);
        let (left, right) = (here[x], here[x + 2]);
        let (below_left, below_middle, below_right) = (below[x], below[x + 1], below[x + 2]);
        // Diagonal: the neighbours on the line the gradient's signs give.
        let agree = mask((gx ^ gy) >= 0);
        let diagonal_above = pick(agree, above_left, above_right);
        let diagonal_below = pick(agree, below_right, below_left);
        let (horizontal_mask, vertical_mask) = (mask(horizontal), mask(vertical));
        let first = pick(
            horizontal_mask,
            left,
            pick(vertical_mask, above_middle, diagonal_above),
        );
        let second = pick(
            horizontal_mask,
            right,
            pick(vertical_mask, below_middle, diagonal_below),
        );
        // Diagonally the second neighbour must be strictly smaller too.
        let strict = 1 & !horizontal_mask & !vertical_mask;
        let maximum = mask(m > low) & mask(m > first) & mask(m >= second + strict);
        let code = pick(
            maximum,
            pick(mask(m > high), i32::from(EDGE), i32::from(CANDIDATE)),
            i32::from(NONE),
        );
        codes[x] = code.to_le_bytes()[0];
    }
}

/// All ones where `condition` holds, zero where not.
#[inline]
fn mask(condition: bool) -> i32 {
    -i32::from(condition)
}

#[multiversion(targets("x86_64+avx2+fma", "x86_64+sse4.1"))]
fn edge_bytes(map: &[u8], out: &mut [u8]) {
    for (m, o) in map.iter().zip(out.iter_mut()) {
        *o = if *m == EDGE { 255 } else { 0 };
    }
}

#[cfg(test)]
mod tests {
    use super::{Canny, View, sobel_magnitude};

    /// A dark image with a bright square from (8, 8) to (23, 23).
    fn square() -> Vec<u8> {
        let mut grey = vec![20_u8; 32 * 32];
        for y in 8..24 {
            grey[y * 32 + 8..y * 32 + 24].fill(220);
        }
        grey
    }

    #[test]
    fn canny_draws_the_outline_of_a_square_one_pixel_wide() {
        let grey = square();
        let view = View::packed(32, 32, 1, &grey).unwrap();
        let mut edges = vec![0; 32 * 32];
        Canny::default().detect(&view, 50, 150, &mut edges);
        let on = |x: usize, y: usize| edges[y * 32 + x] == 255;
        // Each side of the square is an edge along its whole length, and the inside and outside are not.
        for t in 10..22 {
            assert!(on(t, 7) || on(t, 8), "top at {t}");
            assert!(on(7, t) || on(8, t), "left at {t}");
        }
        assert!(!on(16, 16) && !on(2, 2) && !on(16, 3));
        // Thin: no row of the left side is more than one pixel thick.
        for y in 10..22 {
            let thick = (5..12).filter(|x| on(*x, y)).count();
            assert_eq!(thick, 1, "row {y}");
        }
        #[allow(clippy::naive_bytecount, reason = "a test: clarity over speed")]
        let total = edges.iter().filter(|e| **e == 255).count();
        assert!((56..=72).contains(&total), "{total}");
    }

    #[test]
    fn a_flat_image_has_no_edges_and_the_sobel_strength_peaks_on_the_border() {
        let flat = vec![90_u8; 16 * 16];
        let view = View::packed(16, 16, 1, &flat).unwrap();
        let mut edges = vec![7; 16 * 16];
        Canny::default().detect(&view, 10, 30, &mut edges);
        assert!(edges.iter().all(|e| *e == 0));
        let grey = square();
        let view = View::packed(32, 32, 1, &grey).unwrap();
        let mut strength = vec![0; 32 * 32];
        sobel_magnitude(&view, &mut strength);
        assert_eq!(strength[16 * 32 + 16], 0);
        assert_eq!(strength[16 * 32 + 8], 255);
    }
}
