//! Straight lines in an edge mask: a Hough transform over (ρ, θ), its strongest peaks, and for each the
//! stretch of the line the edges actually cover, as a segment.

/// What [`find_lines`] looks for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineSearch {
    /// Distance resolution, pixels.
    pub rho_step: f64,
    /// Angle resolution, degrees.
    pub theta_step_deg: f64,
    /// Votes a line needs (edge pixels on it).
    pub min_votes: u32,
    /// Lines closer to horizontal than this are ignored (degrees; 0 keeps every line).
    pub min_angle_deg: f64,
    /// Lines closer to vertical than this are ignored (degrees; 0 keeps every line).
    pub min_angle_from_vertical_deg: f64,
    /// Shortest segment kept, pixels.
    pub min_length: f64,
    /// Longest run without edges a segment bridges, pixels.
    pub max_gap: f64,
    /// At most this many lines, strongest first.
    pub max_lines: usize,
}

/// A segment: both ends, in pixels.
pub type Segment = [f64; 4];

/// Lines through the non-zero pixels of `mask` (`width × height`, packed), inside rows
/// `first_row..height`.
pub fn find_lines(
    mask: &[u8],
    width: usize,
    height: usize,
    first_row: usize,
    search: &LineSearch,
) -> Vec<Segment> {
    let thetas = (180.0 / search.theta_step_deg.max(0.05)).round().max(1.0) as usize;
    let rho_step = search.rho_step.max(0.1);
    let diagonal = ((width * width + height * height) as f64).sqrt();
    let rhos = (2.0 * diagonal / rho_step).ceil() as usize + 1;
    let (cosines, sines): (Vec<f64>, Vec<f64>) = (0..thetas)
        .map(|t| {
            let theta = t as f64 * std::f64::consts::PI / thetas as f64;
            (theta.cos() / rho_step, theta.sin() / rho_step)
        })
        .unzip();
    let kept: Vec<bool> = (0..thetas)
        .map(|t| {
            // θ is the normal's angle: the line itself is horizontal at θ = 90°.
            let from_horizontal = (t as f64 * 180.0 / thetas as f64 - 90.0).abs();
            from_horizontal >= search.min_angle_deg
                && 90.0 - from_horizontal >= search.min_angle_from_vertical_deg
        })
        .collect();
    let mut votes = vec![0_u32; thetas * rhos];
    let offset = diagonal / rho_step;
    for y in first_row.min(height)..height {
        for (x, on) in mask[y * width..(y + 1) * width].iter().enumerate() {
            if *on == 0 {
                continue;
            }
            for t in 0..thetas {
                if kept[t] {
                    let rho = (x as f64 * cosines[t] + y as f64 * sines[t] + offset).round() as usize;
                    votes[t * rhos + rho] += 1;
                }
            }
        }
    }
    let mut peaks: Vec<(u32, usize, usize)> = Vec::new();
    for t in 0..thetas {
        for r in 0..rhos {
            let v = votes[t * rhos + r];
            if v < search.min_votes.max(1) {
                continue;
            }
            let neighbours = [
                (t, r.wrapping_sub(1)),
                (t, r + 1),
                (t.wrapping_sub(1), r),
                (t + 1, r),
            ];
            let peak = neighbours.iter().all(|(nt, nr)| {
                *nt >= thetas || *nr >= rhos || {
                    let other = votes[nt * rhos + nr];
                    // Ties go to the earlier cell so a plateau gives one peak.
                    other < v || (other == v && (nt * rhos + nr) > t * rhos + r)
                }
            });
            if peak {
                peaks.push((v, t, r));
            }
        }
    }
    peaks.sort_by_key(|peak| std::cmp::Reverse(peak.0));
    // Edges of accepted segments are taken out, so a neighbouring peak of the same line finds too little
    // left to be a segment of its own.
    let mut remaining = mask[..width * height].to_vec();
    let mut segments = Vec::new();
    for (_, t, r) in peaks {
        if segments.len() >= search.max_lines {
            break;
        }
        let theta = t as f64 * std::f64::consts::PI / thetas as f64;
        let rho = r as f64 * rho_step - diagonal;
        if let Some(segment) = covered_segment(&remaining, width, height, first_row, theta, rho, search) {
            erase_along(&mut remaining, width, height, &segment);
            segments.push(segment);
        }
    }
    segments
}

/// Clears the pixels within two pixels of `segment`.
fn erase_along(mask: &mut [u8], width: usize, height: usize, segment: &Segment) {
    let [x0, y0, x1, y1] = *segment;
    let steps = (x1 - x0).abs().max((y1 - y0).abs()).ceil().max(1.0) as usize;
    for k in 0..=steps {
        let f = k as f64 / steps as f64;
        let (x, y) = (
            (x0 + f * (x1 - x0)).round() as i64,
            (y0 + f * (y1 - y0)).round() as i64,
        );
        for dy in -2..=2 {
            for dx in -2..=2 {
                let (px, py) = (x + dx, y + dy);
                if px >= 0 && py >= 0 && (px as usize) < width && (py as usize) < height {
                    mask[py as usize * width + px as usize] = 0;
                }
            }
        }
    }
}

/// The longest stretch of the line (θ, ρ) along which edges lie no more than `max_gap` apart.
fn covered_segment(
    mask: &[u8],
    width: usize,
    height: usize,
    first_row: usize,
    theta: f64,
    rho: f64,
    search: &LineSearch,
) -> Option<Segment> {
    let (normal_x, normal_y) = (theta.cos(), theta.sin());
    // A point on the line and its direction.
    let (x0, y0) = (rho * normal_x, rho * normal_y);
    let (dx, dy) = (-normal_y, normal_x);
    let reach = ((width * width + height * height) as f64).sqrt();
    let on_edge = |s: f64| {
        let (x, y) = (x0 + s * dx, y0 + s * dy);
        // The pixel or its neighbour across the line: edges one pixel off still count.
        [(0.0, 0.0), (normal_x, normal_y), (-normal_x, -normal_y)]
            .iter()
            .any(|(ox, oy)| {
                let (px, py) = ((x + ox).round(), (y + oy).round());
                px >= 0.0
                    && py >= first_row as f64
                    && (px as usize) < width
                    && (py as usize) < height
                    && mask[py as usize * width + px as usize] != 0
            })
    };
    let (mut best, mut start, mut last): (Option<(f64, f64)>, Option<f64>, f64) = (None, None, 0.0);
    let mut s = -reach;
    while s <= reach {
        if on_edge(s) {
            if start.is_none() || s - last > search.max_gap {
                start = Some(s);
            }
            last = s;
            if let Some(begin) = start
                && best.is_none_or(|(a, b)| last - begin > b - a)
            {
                best = Some((begin, last));
            }
        }
        s += 1.0;
    }
    let (a, b) = best?;
    (b - a >= search.min_length).then_some([x0 + a * dx, y0 + a * dy, x0 + b * dx, y0 + b * dy])
}

#[cfg(test)]
mod tests {
    use super::{LineSearch, find_lines};

    #[test]
    fn two_slanted_lines_are_found_as_segments_and_a_horizontal_one_is_ignored() {
        let (width, height) = (100, 80);
        let mut mask = vec![0_u8; width * height];
        for y in 20..80 {
            // x = y (45°) from y = 20, and x = 99 − y from y = 40.
            mask[y * width + y] = 255;
            if y >= 40 {
                mask[y * width + 99 - y] = 255;
            }
        }
        mask[50 * width..51 * width].fill(255);
        let search = LineSearch {
            rho_step: 1.0,
            theta_step_deg: 1.0,
            min_votes: 20,
            min_angle_deg: 15.0,
            min_angle_from_vertical_deg: 0.0,
            min_length: 20.0,
            max_gap: 3.0,
            max_lines: 4,
        };
        let lines = find_lines(&mask, width, height, 0, &search);
        assert_eq!(lines.len(), 2, "{lines:?}");
        let first = lines.iter().find(|l| (l[0] - l[1]).abs() < 2.0).expect("x = y");
        let top = first[1].min(first[3]);
        let bottom = first[1].max(first[3]);
        assert!(
            (top - 20.0).abs() < 2.0 && (bottom - 79.0).abs() < 2.0,
            "{first:?}"
        );
    }
}
