//! The simulated world's road: straights and curves joined by clothoids, with two lanes, sampled
//! finely enough that looking up where a vehicle stands on it costs a short search.
//!
//! A road is written as segments separated by `;` (or new lines), each one of:
//!
//! ```text
//! straight LENGTH          metres
//! left RADIUS ANGLE        a curve to the left: radius in metres, angle turned in degrees
//! right RADIUS ANGLE
//! ```
//!
//! Between segments of different curvature the curvature changes linearly over `transition` metres
//! (a clothoid, as roads are built), centred on the join, so the heading turned by each curve is the
//! one written and steering never has to jump. The road starts at the world's origin heading east and
//! goes on straight for [`RUN_OUT_M`] after its last segment. It is flat.

use std::f64::consts::PI;
use std::fmt::Write as _;

/// Spacing of the road's samples, metres.
pub const STEP_M: f64 = 0.5;
/// The straight added after the last segment, metres.
pub const RUN_OUT_M: f64 = 500.0;

/// The road the simulator drives when none is written: about 1.6 km of straights and curves of 150 to
/// 300 m radius, both ways.
pub const DEFAULT_ROAD: &str = "straight 80; left 200 45; straight 60; right 150 70; straight 40; \
                                left 250 60; right 180 50; straight 100; left 150 90; straight 120; \
                                right 300 40; straight 200";

/// One segment as written.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    /// Length along the road, metres.
    pub length_m: f64,
    /// Curvature, 1/m, positive to the left.
    pub curvature: f64,
}

/// A sample of the road's centre line.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RoadSample {
    /// Metres from the road's start.
    pub station_m: f64,
    /// East, metres.
    pub x: f64,
    /// North, metres.
    pub y: f64,
    /// Direction, radians counter-clockwise from east.
    pub heading: f64,
    /// Curvature, 1/m, positive to the left.
    pub curvature: f64,
}

/// Where a point is relative to the road.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Located {
    /// Metres along the road of the nearest centre-line point.
    pub station_m: f64,
    /// Metres left of the centre line (negative: right).
    pub lateral_m: f64,
    /// The road's direction there, radians counter-clockwise from east.
    pub heading: f64,
    /// The road's curvature there, 1/m.
    pub curvature: f64,
    /// Index of the sample before the point, a hint for the next look-up.
    pub index: usize,
}

/// A road, sampled every [`STEP_M`].
#[derive(Debug, Clone, PartialEq)]
pub struct Road {
    samples: Vec<RoadSample>,
}

/// Why a road description does not read: the segment (1-based) and its text, and what was expected.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RoadError {
    /// A segment lacks a number.
    #[error("segment {index} ('{part}'): the {what} is missing")]
    Missing {
        /// Which segment, from 1.
        index: usize,
        /// Its text.
        part: String,
        /// The number missing.
        what: &'static str,
    },
    /// A number that is not positive and finite.
    #[error("segment {index} ('{part}'): the {what} '{word}' is not a positive number")]
    NotPositive {
        /// Which segment, from 1.
        index: usize,
        /// Its text.
        part: String,
        /// The number expected.
        what: &'static str,
        /// What was written.
        word: String,
    },
    /// A first word that is no kind of segment.
    #[error(
        "segment {index} ('{part}') is not 'straight LENGTH', 'left RADIUS ANGLE' or 'right RADIUS ANGLE'"
    )]
    UnknownKind {
        /// Which segment, from 1.
        index: usize,
        /// Its text.
        part: String,
    },
    /// Words beyond the segment's numbers.
    #[error("segment {index} ('{part}') has more than {expected} words")]
    TooManyWords {
        /// Which segment, from 1.
        index: usize,
        /// Its text.
        part: String,
        /// How many its kind takes.
        expected: usize,
    },
    /// Nothing to drive on.
    #[error("the road has no segment: write e.g. 'straight 100; left 200 45'")]
    Empty,
}

/// Parses a road description (see the module's documentation).
///
/// # Errors
///
/// A segment that does not read, with its number and what was expected.
pub fn parse_segments(text: &str) -> Result<Vec<Segment>, RoadError> {
    let mut segments = Vec::new();
    for (index, part) in text
        .split([';', '\n'])
        .map(str::trim)
        .filter(|p| !p.is_empty())
        .enumerate()
    {
        let words: Vec<&str> = part.split_whitespace().collect();
        let number = |at: usize, what: &'static str| -> Result<f64, RoadError> {
            let word = words.get(at).ok_or_else(|| RoadError::Missing {
                index: index + 1,
                part: part.to_owned(),
                what,
            })?;
            word.parse::<f64>()
                .ok()
                .filter(|v| v.is_finite() && *v > 0.0)
                .ok_or_else(|| RoadError::NotPositive {
                    index: index + 1,
                    part: part.to_owned(),
                    what,
                    word: (*word).to_owned(),
                })
        };
        let (length_m, curvature, expected) = match words.first().copied() {
            Some("straight") => (number(1, "length")?, 0.0, 2),
            Some(side @ ("left" | "right")) => {
                let radius = number(1, "radius")?;
                let angle = number(2, "angle")?;
                let sign = if side == "left" { 1.0 } else { -1.0 };
                (radius * angle * PI / 180.0, sign / radius, 3)
            }
            _ => {
                return Err(RoadError::UnknownKind {
                    index: index + 1,
                    part: part.to_owned(),
                });
            }
        };
        if words.len() > expected {
            return Err(RoadError::TooManyWords {
                index: index + 1,
                part: part.to_owned(),
                expected,
            });
        }
        segments.push(Segment { length_m, curvature });
    }
    if segments.is_empty() {
        return Err(RoadError::Empty);
    }
    Ok(segments)
}

/// The curvature at `station`: each segment's own, ramping linearly over `transition` metres centred on
/// each join.
fn curvature_at(segments: &[Segment], transition: f64, station: f64) -> f64 {
    let mut start = 0.0;
    let mut before = 0.0;
    let half = 0.5 * transition;
    for (index, segment) in segments.iter().enumerate() {
        let end = start + segment.length_m;
        let next = segments.get(index + 1);
        let after = next.map_or(0.0, |s| s.curvature);
        // A join's ramp is no longer than half of either neighbour, so ramps never overlap, and is
        // centred on the join, so each segment keeps the heading it turns.
        let ramp_in = match index.checked_sub(1).and_then(|i| segments.get(i)) {
            Some(previous) => half.min(0.5 * segment.length_m).min(0.5 * previous.length_m),
            None => 0.0,
        };
        let ramp_out = next.map_or(0.0, |next| {
            half.min(0.5 * segment.length_m).min(0.5 * next.length_m)
        });
        if station < end || index + 1 == segments.len() {
            if station < start + ramp_in && ramp_in > 0.0 {
                let t = (station - start + ramp_in) / (2.0 * ramp_in);
                return before + (segment.curvature - before) * t.clamp(0.0, 1.0);
            }
            if station > end - ramp_out && ramp_out > 0.0 {
                let t = (station - end + ramp_out) / (2.0 * ramp_out);
                return segment.curvature + (after - segment.curvature) * t.clamp(0.0, 1.0);
            }
            return segment.curvature;
        }
        before = segment.curvature;
        start = end;
    }
    0.0
}

impl Road {
    /// The road of `segments`, with clothoid transitions `transition_m` long.
    pub fn new(segments: &[Segment], transition_m: f64) -> Road {
        let mut all = segments.to_vec();
        all.push(Segment {
            length_m: RUN_OUT_M,
            curvature: 0.0,
        });
        let total: f64 = all.iter().map(|s| s.length_m).sum();
        let count = (total / STEP_M).ceil() as usize;
        let mut samples = Vec::with_capacity(count + 1);
        let (mut x, mut y, mut heading) = (0.0_f64, 0.0_f64, 0.0_f64);
        let transition = transition_m.max(0.0);
        for index in 0..=count {
            let station = index as f64 * STEP_M;
            samples.push(RoadSample {
                station_m: station,
                x,
                y,
                heading,
                curvature: curvature_at(&all, transition, station),
            });
            // Midpoint rule on the heading, which the curvature drives.
            let middle = curvature_at(&all, transition, station + 0.5 * STEP_M);
            let heading_middle = heading + middle * 0.5 * STEP_M;
            x += heading_middle.cos() * STEP_M;
            y += heading_middle.sin() * STEP_M;
            heading += middle * STEP_M;
        }
        Road { samples }
    }

    /// Parses and builds a road.
    ///
    /// # Errors
    ///
    /// The description does not read (see [`parse_segments`]).
    pub fn parse(text: &str, transition_m: f64) -> Result<Road, RoadError> {
        Ok(Road::new(&parse_segments(text)?, transition_m))
    }

    /// The samples, every [`STEP_M`] from the start.
    pub fn samples(&self) -> &[RoadSample] {
        &self.samples
    }

    /// The road's length, metres, run-out included.
    pub fn length_m(&self) -> f64 {
        self.samples.last().map_or(0.0, |s| s.station_m)
    }

    /// The centre line at `station_m` (clamped to the road), interpolated between samples.
    pub fn at(&self, station_m: f64) -> RoadSample {
        let last = self.samples.len().saturating_sub(1);
        let position = (station_m / STEP_M).clamp(0.0, last as f64);
        let index = (position.floor() as usize).min(last.saturating_sub(1));
        let (Some(a), Some(b)) = (self.samples.get(index), self.samples.get(index + 1)) else {
            return self.samples.first().copied().unwrap_or(RoadSample {
                station_m: 0.0,
                x: 0.0,
                y: 0.0,
                heading: 0.0,
                curvature: 0.0,
            });
        };
        let t = position - index as f64;
        RoadSample {
            station_m: a.station_m + (b.station_m - a.station_m) * t,
            x: a.x + (b.x - a.x) * t,
            y: a.y + (b.y - a.y) * t,
            heading: a.heading + (b.heading - a.heading) * t,
            curvature: a.curvature + (b.curvature - a.curvature) * t,
        }
    }

    /// Where `(x, y)` is relative to the road, searching near the sample `hint` (the last look-up's
    /// index): a vehicle moves less than a few metres between look-ups. `None` when the point is beyond
    /// either end.
    pub fn locate(&self, x: f64, y: f64, hint: usize) -> Option<Located> {
        let from = hint.saturating_sub(40);
        let to = (hint + 200).min(self.samples.len().saturating_sub(1));
        let distance = |s: &RoadSample| (s.x - x).powi(2) + (s.y - y).powi(2);
        let nearest = (from..=to)
            .filter_map(|i| Some((i, distance(self.samples.get(i)?))))
            .min_by(|a, b| a.1.total_cmp(&b.1))?
            .0;
        // The segment through the nearest sample on the side the point is on.
        let sample = self.samples.get(nearest)?;
        let along = (x - sample.x) * sample.heading.cos() + (y - sample.y) * sample.heading.sin();
        let index = if along < 0.0 {
            nearest.checked_sub(1)?
        } else {
            nearest
        };
        let (start, end) = (self.samples.get(index)?, self.samples.get(index + 1)?);
        let (dx, dy) = (end.x - start.x, end.y - start.y);
        let length_sq = (dx * dx + dy * dy).max(f64::EPSILON);
        let share = (((x - start.x) * dx + (y - start.y) * dy) / length_sq).clamp(0.0, 1.0);
        let (foot_x, foot_y) = (start.x + dx * share, start.y + dy * share);
        let cross = dx * (y - foot_y) - dy * (x - foot_x);
        let lateral = (x - foot_x).hypot(y - foot_y).copysign(cross);
        let between = |from: f64, to: f64| from + (to - from) * share;
        Some(Located {
            station_m: between(start.station_m, end.station_m),
            lateral_m: lateral,
            heading: between(start.heading, end.heading),
            curvature: between(start.curvature, end.curvature),
            index,
        })
    }

    /// A one-line summary for logs: length and the tightest radius.
    pub fn summary(&self) -> String {
        let tightest = self.samples.iter().map(|s| s.curvature.abs()).fold(0.0, f64::max);
        let mut text = format!("{:.0} m", self.length_m() - RUN_OUT_M);
        if tightest > 0.0 {
            let _ = write!(text, ", tightest radius {:.0} m", 1.0 / tightest);
        }
        text
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn segments_read_and_bad_ones_are_named() {
        let segments = parse_segments("straight 100; left 200 90\nright 50 45").expect("reads");
        assert_eq!(segments.len(), 3);
        assert!((segments[1].length_m - 100.0 * PI).abs() < 1e-9);
        assert!((segments[1].curvature - 0.005).abs() < 1e-12);
        assert!((segments[2].curvature + 0.02).abs() < 1e-12);
        for (text, expected) in [
            ("", "no segment"),
            ("straight", "segment 1 ('straight'): the length is missing"),
            (
                "straight 10; left 20",
                "segment 2 ('left 20'): the angle is missing",
            ),
            ("straight -5", "not a positive number"),
            ("curve 10 20", "is not 'straight LENGTH'"),
            ("straight 10 20", "more than 2 words"),
        ] {
            let error = parse_segments(text).expect_err(text);
            assert!(error.to_string().contains(expected), "{text}: {error}");
        }
    }

    #[test]
    fn a_curve_turns_by_its_angle_and_transitions_keep_it() {
        // A quarter circle of radius 100 between straights, with 30 m clothoids.
        let road = Road::parse("straight 100; left 100 90; straight 100", 30.0).expect("road");
        let end = road.at(100.0 + 50.0 * PI + 100.0);
        assert!((end.heading - 0.5 * PI).abs() < 1e-3, "heading {}", end.heading);
        // Curvature is continuous: no step between samples larger than a ramp's.
        for pair in road.samples().windows(2) {
            let step = (pair[1].curvature - pair[0].curvature).abs();
            assert!(step <= 0.01 / 30.0 * STEP_M + 1e-12, "curvature step {step}");
        }
        // Without transitions, the exact circle: its end is (100 + R, R).
        let sharp = Road::parse("straight 100; left 100 90", 0.0).expect("road");
        let corner = sharp.at(100.0 + 50.0 * PI);
        assert!(
            (corner.x - 200.0).abs() < 0.05 && (corner.y - 100.0).abs() < 0.05,
            "{corner:?}"
        );
    }

    #[test]
    fn points_are_located_left_and_right_of_the_centre_line() {
        let road = Road::parse(DEFAULT_ROAD, 30.0).expect("road");
        let mut hint = 0;
        for station in [10.0, 150.3, 333.3, 777.7, 1200.0] {
            let centre = road.at(station);
            for lateral in [-1.75, 0.0, 2.5] {
                let x = centre.x - centre.heading.sin() * lateral;
                let y = centre.y + centre.heading.cos() * lateral;
                let located = road
                    .locate(x, y, hint.max((station / STEP_M) as usize - 10))
                    .expect("on road");
                assert!(
                    (located.station_m - station).abs() < 0.02,
                    "{station}: {located:?}"
                );
                assert!(
                    (located.lateral_m - lateral).abs() < 0.01,
                    "{station} {lateral}: {located:?}"
                );
                hint = located.index;
            }
        }
        assert!(
            road.summary().contains("tightest radius 150 m"),
            "{}",
            road.summary()
        );
    }
}
