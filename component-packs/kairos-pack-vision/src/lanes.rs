//! The ego lane from an edge mask: `vision.lane_detector`.
//!
//! The camera is a pinhole looking level ahead, tilted down, at a known height above a flat road (by
//! default the `sensors` pack's simulated camera), so every image row below the horizon is one distance
//! ahead and every edge pixel one point on the road. The mask's edge chains (8-connected edge pixels)
//! are projected onto the road, one point per row. A lane's markings are parallel: the longest chain
//! that looks like one gives their shared heading and bend, the chains that come close ahead are
//! grouped by their offset from that shape, and the group nearest the vehicle on each side seeds that
//! side's boundary. Both boundaries are then followed outwards through the edge pixels near them and
//! fitted together (parallel quadratics, least squares weighted for the error growing with distance,
//! the worst-fitting points left out). The centre line is midway between them.
//!
//! Chains rather than straight segments (Hough): on a sharp bend the markings are curves in the image
//! even close ahead.

use std::sync::Arc;

use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{
    Component, ComponentError, ComponentInfo, ComponentResult, Context, DataType, Matrix, Payload, TypeFilter,
};

use crate::image_io::{grey_view, image_of};

/// How failures name the component and its input.
const WHAT: &str = "vision.lane_detector (input in)";
/// The simulated camera's downward tilt, 0.05 rad, in degrees.
const DEFAULT_TILT_DEG: f64 = 2.864_788_975_654_116;
/// How far beyond `min_range` (m) a chain must come to seed a boundary; the shape's heading is checked
/// halfway there.
const SEED_DEPTH: f64 = 8.0;
/// Steepest heading (lateral metres per metre ahead) of a lane marking relative to the vehicle.
const MAX_HEADING: f64 = 0.7;
/// A marking that, extended, passes closer to the camera than this fraction of the lane width is a ray
/// from the camera in the image (a vertical edge: a vehicle's side, a post), not a lane boundary.
const MIN_INTERCEPT: f64 = 0.15;
/// Pieces closer sideways than this fraction of the lane width belong to one marking.
const CLUSTER_GAP: f64 = 0.2;
/// Edge pixels closer than this fraction of the lane width to a fitted boundary join it when it is
/// refitted.
const REFIT_TOLERANCE: f64 = 0.1;
/// A boundary farther from the vehicle than this fraction of the lane width is not the ego lane's.
const MAX_BOUNDARY_DISTANCE: f64 = 1.0;
/// Most times a boundary is refitted with the points near it, each reaching farther along a bend.
const MAX_REFITS: usize = 12;
/// How far (m) beyond its farthest point a boundary is followed at each refit: past the gap between
/// two dashes, and little enough that the fit is not extrapolated far.
const FOLLOW_STEP: f64 = 10.0;
/// Points off a fit by more than this (pixels, across the image) may be left out of it.
const OUTLIER_PIXELS: f64 = 1.5;
/// Most times a fit is redone without the points it fits worst.
const TRIMS: usize = 3;
/// Points (image rows) a boundary needs.
const MIN_POINTS: usize = 8;
/// Spread ahead (m) a boundary's points need for a heading, and for a curvature.
const MIN_SPREAD: f64 = 1.0;
const CURVATURE_SPREAD: f64 = 8.0;
/// Chords each boundary is drawn with.
const CHORDS: usize = 16;

/// `vision.lane_detector`.
#[derive(Debug, Default)]
pub struct LaneDetector {
    /// The last centre line found: repeated, marked stale, while no boundary is seen.
    last_centre: Curve,
    frames: u64,
    both: u64,
    one: u64,
    none: u64,
}

impl LaneDetector {
    /// The descriptor.
    pub fn info() -> ComponentInfo {
        let described = Descriptor::new(
            "vision.lane_detector",
            "image features",
            "The ego lane's centre line on a flat road, in the vehicle frame, from the edge mask of a \
             forward-looking camera",
        )
        .label("Lane detector")
        .input(
            "in",
            TypeFilter::only(DataType::Image),
            "A grey edge mask (non-zero = edge), e.g. from vision.canny",
        )
        .output(
            "lane",
            DataType::Vector,
            "c0, c1, c2, found: the centre line y = c0 + c1 x + c2 x² (m; x forward, y left, from the \
             camera) and the boundaries seen (0, 1, 2); with 0, the last line found (zeros before any); \
             same timestamp",
        )
        .output(
            "offset",
            DataType::F64,
            "The vehicle's lateral position from the lane centre, m, positive left of it (−c0); only \
             while a boundary is seen",
        )
        .output(
            "lines",
            DataType::Matrix,
            "The boundaries found, drawn back into the image: rows x1, y1, x2, y2 in pixels, for \
             vision.overlay",
        );
        with_camera_properties(described)
            .property(
                Property::f64("lane_width", 3.5)
                    .range(1.0, 10.0)
                    .unit("m")
                    .live()
                    .doc("With one boundary seen, the centre is taken half a lane from it"),
            )
            .property(
                Property::f64("min_range", 4.0)
                    .range(0.5, 100.0)
                    .unit("m")
                    .live()
                    .doc("Nearest road distance used"),
            )
            .property(
                Property::f64("range", 30.0)
                    .range(2.0, 500.0)
                    .unit("m")
                    .live()
                    .doc("Farthest road distance used; rows above it are not searched"),
            )
            .property(
                Property::i64("min_length", 20)
                    .int_range(2, 10_000)
                    .unit("px")
                    .live()
                    .doc("Edge chains spanning fewer image rows are ignored (specks, horizontal edges)"),
            )
            .build()
    }
}

/// `descriptor` with the camera model's properties: the simulated camera's by default.
fn with_camera_properties(descriptor: Descriptor) -> Descriptor {
    descriptor
        .property(
            Property::f64("fov", 70.0)
                .range(10.0, 170.0)
                .unit("°")
                .live()
                .doc("Horizontal field of view"),
        )
        .property(
            Property::f64("camera_height", 1.4)
                .range(0.1, 10.0)
                .unit("m")
                .live()
                .doc("Height of the camera above the road"),
        )
        .property(
            Property::f64("tilt", DEFAULT_TILT_DEG)
                .range(-45.0, 45.0)
                .unit("°")
                .live()
                .doc("Downward tilt of the camera (the simulated camera's: 0.05 rad)"),
        )
}

impl Component for LaneDetector {
    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let settings = Settings::read(ctx)?;
        let sample = ctx.read("in")?;
        let view = grey_view(image_of(&sample, "in")?, WHAT)?;
        let packed = view.contiguous();
        let mask: &[u8] = &packed;
        let camera = Camera::new(view.width, view.height, &settings);
        let [left, right] = if view.width > 0 && mask.len() >= view.width * view.height {
            detect(mask, view.width, view.height, &camera, &settings)
        } else {
            [None, None]
        };
        let found = usize::from(left.is_some()) + usize::from(right.is_some());
        self.frames += 1;
        match found {
            0 => self.none += 1,
            1 => self.one += 1,
            _ => self.both += 1,
        }
        if let Some(centre) = centre_line(left.as_ref(), right.as_ref(), settings.lane_width) {
            self.last_centre = centre;
        }
        let Curve { a, b, c } = self.last_centre;
        let lane: Arc<[f64]> = Arc::from([a, b, c, found as f64]);
        ctx.write_processed("lane", &sample, Payload::Vector(lane))?;
        if found > 0 {
            ctx.write_processed("offset", &sample, Payload::F64(-a))?;
        }
        let seen: Vec<&Boundary> = left.iter().chain(right.iter()).collect();
        let lines = drawn(&seen, &camera, view.width, view.height);
        ctx.write_processed("lines", &sample, Payload::Matrix(Arc::new(lines)))
    }

    fn status(&self) -> Option<serde_json::Value> {
        Some(serde_json::json!({
            "kind": "lanes",
            "frames": self.frames,
            "both": self.both,
            "one": self.one,
            "none": self.none,
        }))
    }
}

/// The properties, read once per image.
#[derive(Debug, Clone, Copy)]
struct Settings {
    fov_deg: f64,
    tilt_deg: f64,
    camera_height: f64,
    lane_width: f64,
    min_range: f64,
    range: f64,
    /// Image rows an edge chain must span.
    min_length: usize,
}

impl Settings {
    fn read(ctx: &Context) -> Result<Self, ComponentError> {
        let min_range = ctx.f64_property("min_range")?;
        let range = ctx.f64_property("range")?;
        if range <= min_range {
            return Err(ComponentError::failed(format_args!(
                "vision.lane_detector: range ({range} m) must be beyond min_range ({min_range} m)"
            )));
        }
        Ok(Settings {
            fov_deg: ctx.f64_property("fov")?,
            tilt_deg: ctx.f64_property("tilt")?,
            camera_height: ctx.f64_property("camera_height")?,
            lane_width: ctx.f64_property("lane_width")?,
            min_range,
            range,
            min_length: usize::try_from(ctx.i64_property("min_length")?).unwrap_or(usize::MAX),
        })
    }
}

/// A pinhole camera looking level ahead, tilted down, above a flat road: the simulated camera's model.
/// Image positions are continuous, pixel centres at +0.5.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Camera {
    focal: f64,
    center_x: f64,
    horizon: f64,
    height: f64,
}

impl Camera {
    fn new(width: usize, height: usize, settings: &Settings) -> Self {
        let focal = 0.5 * width as f64 / (0.5 * settings.fov_deg.to_radians()).tan();
        Camera {
            focal,
            center_x: 0.5 * width as f64,
            horizon: 0.5 * height as f64 - focal * settings.tilt_deg.to_radians().tan(),
            height: settings.camera_height,
        }
    }

    /// The road point (metres ahead, metres left) seen at image position (`u`, `v`); none above the
    /// horizon.
    fn ground(&self, u: f64, v: f64) -> Option<(f64, f64)> {
        let below = v - self.horizon;
        if below.is_nan() || below <= 0.0 {
            return None;
        }
        let ahead = self.focal * self.height / below;
        Some((ahead, (self.center_x - u) * ahead / self.focal))
    }

    /// The image position (`u`, `v`) of the road point `ahead` metres ahead and `left` metres left.
    fn image(&self, ahead: f64, left: f64) -> (f64, f64) {
        (
            self.center_x - self.focal * left / ahead,
            self.horizon + self.focal * self.height / ahead,
        )
    }
}

/// y = a + b x + c x², metres.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Curve {
    a: f64,
    b: f64,
    c: f64,
}

impl Curve {
    fn at(&self, x: f64) -> f64 {
        self.a + x * (self.b + x * self.c)
    }

    fn shifted(self, by: f64) -> Curve {
        Curve {
            a: self.a + by,
            ..self
        }
    }
}

/// One side of the lane: its fit, and how far ahead the points it was fitted to reach.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Boundary {
    curve: Curve,
    nearest: f64,
    farthest: f64,
}

/// The road points of one edge chain, and where it is sideways: its offset from the lane's shape.
#[derive(Debug)]
struct Piece {
    points: Vec<(f64, f64)>,
    lateral: f64,
}

/// A boundary being followed: its curve and the points it was fitted to.
#[derive(Debug)]
struct Track {
    curve: Curve,
    points: Vec<(f64, f64)>,
}

/// The lane's left and right boundaries in `mask` (`width × height`, packed).
///
/// The markings of a lane are parallel: they share a heading and a bend, which the longest edge chain
/// that looks like a marking gives, and differ in their offsets sideways. The chains that come close
/// ahead (within [`SEED_DEPTH`] of `min_range`) and follow that shape are grouped by offset, and the
/// group nearest the vehicle on each side seeds that side's boundary. Both are then followed out to
/// `range` through the edge pixels near them and refitted.
fn detect(
    mask: &[u8],
    width: usize,
    height: usize,
    camera: &Camera,
    settings: &Settings,
) -> [Option<Boundary>; 2] {
    let (near, far) = (settings.min_range, settings.range);
    let (_, far_row) = camera.image(far, 0.0);
    // Rows farther than `range` are never searched: the road there is a few pixels wide, and the
    // horizon's clutter and the vehicles ahead are there.
    let road = Road {
        mask,
        width,
        height,
        first_row: (far_row - 0.5).ceil().clamp(0.0, height as f64) as usize,
        camera,
        near,
        far,
    };
    let lane_width = settings.lane_width;
    let seed_far = (near + SEED_DEPTH).min(far);
    let chains: Vec<Vec<(f64, f64)>> = road
        .chains(settings.min_length)
        .into_iter()
        .filter(|points| points.len() >= MIN_POINTS && spread(points).0 <= seed_far)
        .collect();
    let Some(shape) = lane_shape(&chains, 0.5 * (near + seed_far), lane_width, camera.focal) else {
        return [None, None];
    };
    let tolerance = REFIT_TOLERANCE * lane_width;
    let pieces: Vec<Piece> = chains
        .into_iter()
        .filter_map(|points| {
            let lateral = offset_from(&shape, &points, tolerance)?;
            (lateral.abs() >= MIN_INTERCEPT * lane_width).then_some(Piece { points, lateral })
        })
        .collect();
    let seed = |left_side: bool| {
        let points = nearest_marking(&pieces, left_side, CLUSTER_GAP * lane_width)?;
        let lateral = offset_from(&shape, &points, f64::INFINITY)?;
        // Seen from inside the lane, its boundaries are less than a lane's width away: a marking farther
        // is the other lane's edge, seen where the nearer marking is not (between two dashes).
        (lateral.abs() < MAX_BOUNDARY_DISTANCE * lane_width).then(|| Track {
            curve: shape.shifted(lateral),
            points,
        })
    };
    follow(&road, [seed(true), seed(false)], tolerance)
}

/// The shape (heading and bend; offset 0) a lane's markings share, from the chain with the most points
/// among those that look like a lane marking: not too steep at `reference` metres ahead, and not a ray
/// from the camera. Fitted robustly: a chain may run on into the outline of a vehicle that hides the
/// marking.
fn lane_shape(chains: &[Vec<(f64, f64)>], reference: f64, lane_width: f64, focal: f64) -> Option<Curve> {
    chains
        .iter()
        .filter_map(|points| {
            let [curve] = robust_fit([points], focal)?;
            let heading = curve.b + 2.0 * curve.c * reference;
            (heading.abs() <= MAX_HEADING && curve.a.abs() >= MIN_INTERCEPT * lane_width)
                .then_some((points.len(), curve))
        })
        .max_by_key(|(count, _)| *count)
        .map(|(_, curve)| Curve { a: 0.0, ..curve })
}

/// How far sideways `points` are from `shape`: the median of their offsets from it, if they follow it
/// (the median distance of the offsets from that is at most `tolerance`).
fn offset_from(shape: &Curve, points: &[(f64, f64)], tolerance: f64) -> Option<f64> {
    let mut offsets: Vec<f64> = points.iter().map(|(x, y)| y - shape.at(*x)).collect();
    let offset = median(&mut offsets)?;
    let mut deviations: Vec<f64> = offsets.iter().map(|o| (o - offset).abs()).collect();
    (median(&mut deviations)? <= tolerance).then_some(offset)
}

/// The median of `values` (reordered), none for none.
fn median(values: &mut [f64]) -> Option<f64> {
    values.sort_by(f64::total_cmp);
    values.get(values.len() / 2).copied()
}

/// The boundaries grown from their seeds: refitted to the edge pixels near them, each time reaching
/// [`FOLLOW_STEP`] beyond their farthest point, until nothing changes.
fn follow(road: &Road<'_>, seeds: [Option<Track>; 2], tolerance: f64) -> [Option<Boundary>; 2] {
    let mut tracks = seeds;
    for _ in 0..MAX_REFITS {
        let gathered = tracks.each_ref().map(|track| {
            track.as_ref().map(|track| {
                let reach = spread(&track.points).1 + FOLLOW_STEP;
                road.points_near(&track.curve, tolerance, reach)
            })
        });
        let unchanged = gathered
            .iter()
            .zip(&tracks)
            .all(|(points, track)| points.as_ref() == track.as_ref().map(|t| &t.points));
        if unchanged {
            break;
        }
        let fitted = refit(&gathered, road.camera.focal);
        // A side that can no longer be fitted keeps its last fit.
        for ((track, points), curve) in tracks.iter_mut().zip(gathered).zip(fitted) {
            if let (Some(track), Some(points), Some(curve)) = (track.as_mut(), points, curve) {
                *track = Track { curve, points };
            }
        }
    }
    tracks.map(|track| {
        let track = track?;
        let (nearest, farthest) = spread(&track.points);
        (farthest - nearest >= MIN_SPREAD).then_some(Boundary {
            curve: track.curve,
            nearest,
            farthest,
        })
    })
}

/// Curves through each side's points: parallel when both sides have enough, so that a side seen only
/// over a short stretch (a dash) takes its heading and bend from the other.
fn refit(sides: &[Option<Vec<(f64, f64)>>; 2], focal: f64) -> [Option<Curve>; 2] {
    let [left, right] = sides
        .each_ref()
        .map(|side| side.as_deref().filter(|p| p.len() >= MIN_POINTS));
    match (left, right) {
        (Some(left), Some(right)) => {
            robust_fit([left, right], focal).map_or([None, None], |curves| curves.map(Some))
        }
        (left, right) => [left, right].map(|side| {
            side.and_then(|points| robust_fit([points], focal))
                .map(|[curve]| curve)
        }),
    }
}

/// [`parallel_fit`] refitted without the points it fits worst: those farther off in the image than
/// [`OUTLIER_PIXELS`] and three times the typical deviation (edges of a vehicle that hides the marking,
/// a row where only one edge of the paint was near).
fn robust_fit<const N: usize>(sets: [&[(f64, f64)]; N], focal: f64) -> Option<[Curve; N]> {
    let pixels_off = |curve: &Curve, (x, y): &(f64, f64)| (y - curve.at(*x)).abs() * focal / x;
    let mut curves = parallel_fit(sets)?;
    for _ in 0..TRIMS {
        let mut deviations: Vec<f64> = sets
            .iter()
            .zip(&curves)
            .flat_map(|(points, curve)| points.iter().map(move |point| pixels_off(curve, point)))
            .collect();
        // The median absolute deviation, scaled to a standard deviation for normally spread errors.
        let typical = 1.4826 * median(&mut deviations)?;
        let limit = (3.0 * typical).max(OUTLIER_PIXELS);
        let mut fitted = curves.iter();
        let kept = sets.map(|points| {
            let curve = fitted.next();
            points
                .iter()
                .copied()
                .filter(|point| curve.is_some_and(|curve| pixels_off(curve, point) <= limit))
                .collect::<Vec<_>>()
        });
        match parallel_fit(kept.each_ref().map(Vec::as_slice)) {
            Some(better) if better != curves => curves = better,
            _ => break,
        }
    }
    Some(curves)
}

/// The edge mask and the camera that saw it, within the rows and distances searched.
#[derive(Debug, Clone, Copy)]
struct Road<'a> {
    mask: &'a [u8],
    width: usize,
    height: usize,
    first_row: usize,
    camera: &'a Camera,
    /// Distances ahead used, metres.
    near: f64,
    far: f64,
}

impl Road<'_> {
    /// The pixels of row `row`.
    fn row(&self, row: usize) -> Option<&[u8]> {
        self.mask.get(row * self.width..(row + 1) * self.width)
    }

    /// The road point at continuous image position (`u`, `v`), if within the distances searched.
    fn ground(&self, u: f64, v: f64) -> Option<(f64, f64)> {
        let (ahead, left) = self.camera.ground(u, v)?;
        (self.near..=self.far).contains(&ahead).then_some((ahead, left))
    }

    /// Whether the pixel `index` rows below the first searched row (`index = row × width + column`) is
    /// an edge.
    fn is_edge(&self, index: usize) -> bool {
        self.mask
            .get(self.first_row * self.width + index)
            .is_some_and(|pixel| *pixel != 0)
    }

    /// The edge chains (8-connected edge pixels) of the rows searched that span at least `min_rows`
    /// rows, each as road points: one per row, at the mean column of the chain's pixels in it (for both
    /// edges of a dash, its middle; for a shallow edge, the middle of its run).
    fn chains(&self, min_rows: usize) -> Vec<Vec<(f64, f64)>> {
        let width = self.width;
        let rows = self.height.saturating_sub(self.first_row);
        let mut seen = vec![false; width * rows];
        let mut chains = Vec::new();
        let mut stack = Vec::new();
        for start in 0..width * rows {
            if seen.get(start).is_none_or(|s| *s) || !self.is_edge(start) {
                continue;
            }
            let mut pixels: Vec<(usize, usize)> = Vec::new();
            stack.push(start);
            if let Some(s) = seen.get_mut(start) {
                *s = true;
            }
            while let Some(at) = stack.pop() {
                let (row, column) = (at / width, at % width);
                pixels.push((row, column));
                let neighbours = (row.saturating_sub(1)..(row + 2).min(rows)).flat_map(|r| {
                    (column.saturating_sub(1)..(column + 2).min(width)).map(move |c| r * width + c)
                });
                for next in neighbours {
                    if self.is_edge(next)
                        && let Some(s) = seen.get_mut(next)
                        && !*s
                    {
                        *s = true;
                        stack.push(next);
                    }
                }
            }
            pixels.sort_unstable();
            let spanned = pixels.last().map_or(0, |l| l.0) - pixels.first().map_or(0, |f| f.0) + 1;
            if spanned >= min_rows {
                chains.push(self.row_means(&pixels));
            }
        }
        chains
    }

    /// One road point per row of `pixels` (row below the first searched, column; sorted by row), at
    /// their mean column in it.
    fn row_means(&self, pixels: &[(usize, usize)]) -> Vec<(f64, f64)> {
        pixels
            .chunk_by(|a, b| a.0 == b.0)
            .filter_map(|in_row| {
                let row = in_row.first()?.0 + self.first_row;
                let sum: usize = in_row.iter().map(|p| p.1).sum();
                self.ground(sum as f64 / in_row.len() as f64 + 0.5, row as f64 + 0.5)
            })
            .collect()
    }

    /// Road points of the marking along `curve` up to `reach` metres ahead: in each row, the mean column
    /// of the edge pixels less than `tolerance` metres from it. This follows the marking beyond the
    /// chains it was found by (past a gap, along the next dashes) and puts both edges of a painted line
    /// together, centring on the paint.
    fn points_near(&self, curve: &Curve, tolerance: f64, reach: f64) -> Vec<(f64, f64)> {
        (self.first_row..self.height)
            .filter_map(|row| {
                let v = row as f64 + 0.5;
                let (ahead, _) = self.ground(self.camera.center_x, v)?;
                if ahead > reach {
                    return None;
                }
                let (u, _) = self.camera.image(ahead, curve.at(ahead));
                let reach = tolerance * self.camera.focal / ahead;
                // Pixel x covers u from x to x + 1: its centre is at x + 0.5.
                let first = (u - 0.5 - reach).ceil().max(0.0);
                let last = (u - 0.5 + reach).floor().min(self.width as f64 - 1.0);
                if first.is_nan() || last.is_nan() || first > last {
                    return None;
                }
                let pixels = self.row(row)?.get(first as usize..=last as usize)?;
                let (count, sum) = (first as usize..)
                    .zip(pixels)
                    .filter(|(_, on)| **on != 0)
                    .fold((0_usize, 0_usize), |(count, sum), (x, _)| (count + 1, sum + x));
                // A row more than half edges is a horizontal edge across the window (a vehicle's bumper,
                // a shadow): its mean would be wherever the window is.
                (count > 0 && 2 * count <= pixels.len() + 1)
                    .then(|| self.ground(sum as f64 / count as f64 + 0.5, v))?
            })
            .collect()
    }
}

/// The points of the marking nearest the vehicle on one side that has enough of them: pieces sorted
/// by their distance sideways, grouped while consecutive ones are less than `gap` apart.
fn nearest_marking(pieces: &[Piece], left_side: bool, gap: f64) -> Option<Vec<(f64, f64)>> {
    let mut side: Vec<&Piece> = pieces
        .iter()
        .filter(|piece| (piece.lateral > 0.0) == left_side)
        .collect();
    side.sort_by(|p, q| p.lateral.abs().total_cmp(&q.lateral.abs()));
    let mut marking: Vec<(f64, f64)> = Vec::new();
    let mut previous = f64::NEG_INFINITY;
    for piece in side {
        let distance = piece.lateral.abs();
        if distance - previous > gap {
            if marking.len() >= MIN_POINTS {
                return Some(marking);
            }
            marking.clear();
        }
        marking.extend_from_slice(&piece.points);
        previous = distance;
    }
    (marking.len() >= MIN_POINTS).then_some(marking)
}

/// The smallest and largest x of `points`.
fn spread(points: &[(f64, f64)]) -> (f64, f64) {
    points
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(low, high), (x, _)| {
            (low.min(*x), high.max(*x))
        })
}

/// Parallel curves yᵢ = aᵢ + b x + c x² through `sets` of points, least squares: lines (c = 0) unless
/// the points spread [`CURVATURE_SPREAD`] ahead; none when the sets do not determine them.
fn parallel_fit<const N: usize>(sets: [&[(f64, f64)]; N]) -> Option<[Curve; N]> {
    if sets.iter().any(|points| points.len() < MIN_POINTS) {
        return None;
    }
    let (nearest, farthest) = sets
        .iter()
        .map(|points| spread(points))
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(low, high), (near, far)| {
            (low.min(near), high.max(far))
        });
    if farthest - nearest < MIN_SPREAD {
        return None;
    }
    // Each set's offset takes up its (weighted) means, leaving b and c to fit the deviations from them.
    let means = sets.map(|points| {
        let total: f64 = points.iter().map(|(x, _)| weight(*x)).sum();
        let mean = |f: &dyn Fn(f64, f64) -> f64| {
            points.iter().map(|(x, y)| weight(*x) * f(*x, *y)).sum::<f64>() / total
        };
        (mean(&|x, _| x), mean(&|x, _| x * x), mean(&|_, y| y))
    });
    let (mut sxx, mut sxq, mut sqq, mut sxy, mut sqy) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for (points, (mean_x, mean_square, mean_y)) in sets.iter().zip(&means) {
        for (x, y) in *points {
            let (dx, dq, dy) = (x - mean_x, x * x - mean_square, y - mean_y);
            let w = weight(*x);
            sxx += w * dx * dx;
            sxq += w * dx * dq;
            sqq += w * dq * dq;
            sxy += w * dx * dy;
            sqy += w * dq * dy;
        }
    }
    let det = sxx * sqq - sxq * sxq;
    let (b, c) = if farthest - nearest >= CURVATURE_SPREAD && det > 1e-9 * sxx * sqq {
        ((sxy * sqq - sxq * sqy) / det, (sxx * sqy - sxq * sxy) / det)
    } else if sxx > 0.0 {
        (sxy / sxx, 0.0)
    } else {
        return None;
    };
    Some(means.map(|(mean_x, mean_square, mean_y)| Curve {
        a: mean_y - b * mean_x - c * mean_square,
        b,
        c,
    }))
}

/// The weight of a point `ahead` metres ahead in a fit: one pixel across the image is `ahead / focal`
/// metres there, so a point's lateral error grows with its distance, and its variance with the square.
fn weight(ahead: f64) -> f64 {
    1.0 / (ahead * ahead).max(1e-6)
}

/// The lane's centre line: midway between both boundaries, or half a lane from the one seen.
fn centre_line(left: Option<&Boundary>, right: Option<&Boundary>, lane_width: f64) -> Option<Curve> {
    match (left, right) {
        (Some(left), Some(right)) => Some(Curve {
            a: 0.5 * (left.curve.a + right.curve.a),
            b: 0.5 * (left.curve.b + right.curve.b),
            c: 0.5 * (left.curve.c + right.curve.c),
        }),
        (Some(left), None) => Some(left.curve.shifted(-0.5 * lane_width)),
        (None, Some(right)) => Some(right.curve.shifted(0.5 * lane_width)),
        (None, None) => None,
    }
}

/// The boundaries drawn into the image over the distances they were seen at, as chords in pixel
/// coordinates (x1, y1, x2, y2); chords wholly outside the image are left out.
fn drawn(boundaries: &[&Boundary], camera: &Camera, width: usize, height: usize) -> Matrix {
    let inside = |(u, v): (f64, f64)| (0.0..width as f64).contains(&u) && (0.0..height as f64).contains(&v);
    let mut values = Vec::new();
    for boundary in boundaries {
        let step = (boundary.farthest - boundary.nearest) / CHORDS as f64;
        let pixel = |k: usize| {
            let ahead = boundary.nearest + step * k as f64;
            let (u, v) = camera.image(ahead, boundary.curve.at(ahead));
            (u - 0.5, v - 0.5)
        };
        for k in 0..CHORDS {
            let (from, to) = (pixel(k), pixel(k + 1));
            if inside(from) || inside(to) {
                values.extend([from.0, from.1, to.0, to.1]);
            }
        }
    }
    Matrix {
        rows: values.len() / 4,
        cols: 4,
        values,
    }
}

#[cfg(test)]
mod tests {
    use kairos_sdk::harness::Harness;
    use kairos_sdk::{Image, Payload, PixelFormat, Timestamp};

    use super::{Camera, Curve, DEFAULT_TILT_DEG, LaneDetector, Settings};

    /// Half the width of a painted line, metres.
    const PAINT_HALF_WIDTH: f64 = 0.075;

    /// A painted line on the road: its centre at y = a + b x + c x² (metres, y left); dashed, dashes
    /// 4 m long every 12 m, the first beginning `phase` metres before the camera.
    struct Marking {
        centre: Curve,
        dashes: Option<f64>,
    }

    /// How the road is drawn: the lane's centre line in the vehicle frame, and the dashes' phase.
    #[derive(Debug, Clone, Copy)]
    struct Truth {
        offset: f64,
        heading: f64,
        bend: f64,
        phase: f64,
    }

    /// A two-lane road seen from the right lane as `truth` has it: the dashed centre line, the lane's
    /// right edge line and, left of the centre line, the other lane's edge line (each marking at
    /// y = offset + lateral + heading x + bend x²).
    fn road(truth: Truth) -> Vec<Marking> {
        [(1.75, true), (-1.75, false), (5.25, false)]
            .into_iter()
            .map(|(lateral, dashed)| Marking {
                centre: Curve {
                    a: truth.offset + lateral,
                    b: truth.heading,
                    c: truth.bend,
                },
                dashes: dashed.then_some(truth.phase),
            })
            .collect()
    }

    fn simulated_camera(width: usize, height: usize) -> Camera {
        let settings = Settings {
            fov_deg: 70.0,
            tilt_deg: DEFAULT_TILT_DEG,
            camera_height: 1.4,
            lane_width: 3.5,
            min_range: 4.0,
            range: 30.0,
            min_length: 20,
        };
        Camera::new(width, height, &settings)
    }

    /// The edge mask Canny gives of `markings` seen by the simulated camera: both sides of each painted
    /// line as thin, connected lines, dashes 4 m long every 12 m.
    fn edge_mask(width: usize, height: usize, markings: &[Marking]) -> Vec<u8> {
        let camera = simulated_camera(width, height);
        let mut mask = vec![0_u8; width * height];
        for (row, pixels) in mask.chunks_exact_mut(width).enumerate() {
            let (top, bottom) = (row as f64, row as f64 + 1.0);
            let Some((ahead, _)) = camera.ground(camera.center_x, top + 0.5) else {
                continue;
            };
            if ahead > 100.0 {
                continue;
            }
            for marking in markings {
                if marking
                    .dashes
                    .is_some_and(|phase| (ahead + phase).rem_euclid(12.0) >= 4.0)
                {
                    continue;
                }
                for side in [-PAINT_HALF_WIDTH, PAINT_HALF_WIDTH] {
                    // The columns the edge crosses between the row's top and bottom.
                    let column = |v: f64| {
                        let (ahead, _) = camera.ground(camera.center_x, v.max(camera.horizon + 0.01))?;
                        Some(camera.image(ahead, marking.centre.at(ahead) + side).0)
                    };
                    let (Some(upper), Some(lower)) = (column(top), column(bottom)) else {
                        continue;
                    };
                    let first = upper.min(lower).floor().max(0.0) as usize;
                    let last = upper.max(lower).floor().min(width as f64 - 1.0);
                    if last >= 0.0 {
                        for pixel in pixels.iter_mut().take(last as usize + 1).skip(first) {
                            *pixel = 255;
                        }
                    }
                }
            }
        }
        mask
    }

    /// `mask` with a vehicle standing `ahead` metres ahead, centred `left` metres left, 1.8 m wide and
    /// 1.5 m high, as Canny sees it from behind: the markings it hides gone, its outline drawn.
    fn with_vehicle(mut mask: Vec<u8>, width: usize, height: usize, ahead: f64, left: f64) -> Vec<u8> {
        let camera = simulated_camera(width, height);
        let (x0, bottom) = camera.image(ahead, left + 0.9);
        let (x1, _) = camera.image(ahead, left - 0.9);
        let top = bottom - camera.focal * 1.5 / ahead;
        let (x0, x1) = (x0.round() as usize, x1.round() as usize);
        let (top, bottom) = (top.round().max(0.0) as usize, bottom.round() as usize);
        for (row, pixels) in mask
            .chunks_exact_mut(width)
            .enumerate()
            .take(bottom + 1)
            .skip(top)
        {
            let outline = row == top || row == bottom;
            for (column, pixel) in pixels.iter_mut().enumerate().take(x1 + 1).skip(x0) {
                *pixel = if outline || column == x0 || column == x1 {
                    255
                } else {
                    0
                };
            }
        }
        mask
    }

    struct Detected {
        lane: Vec<f64>,
        offset: Vec<f64>,
        lines: usize,
        status: serde_json::Value,
    }

    fn detect(width: usize, height: usize, mask: Vec<u8>) -> Detected {
        let image = Image::packed(width as u32, height as u32, PixelFormat::Gray8, mask).expect("image");
        let mut harness = Harness::new(LaneDetector::info(), LaneDetector::default());
        harness.push("in", Payload::Image(image), Timestamp::from_millis(40));
        let out = harness.run().expect("runs");
        let lane = match out.samples("lane").first().map(|s| &s.payload) {
            Some(Payload::Vector(values)) => values.to_vec(),
            other => panic!("lane: {other:?}"),
        };
        let lines = match out.samples("lines").first().map(|s| &s.payload) {
            Some(Payload::Matrix(matrix)) => {
                assert_eq!(matrix.cols, 4);
                let (w, h) = (width as f64, height as f64);
                assert!(
                    matrix
                        .values
                        .chunks_exact(2)
                        .all(|p| p[0].is_finite() && p[1].is_finite()),
                    "{matrix:?}"
                );
                assert!(
                    matrix.values.chunks_exact(4).all(|s| {
                        (0.0..w).contains(&s[0]) && (0.0..h).contains(&s[1])
                            || (0.0..w).contains(&s[2]) && (0.0..h).contains(&s[3])
                    }),
                    "{matrix:?}"
                );
                matrix.rows
            }
            other => panic!("lines: {other:?}"),
        };
        assert!(
            out.samples("lane")
                .iter()
                .chain(out.samples("lines"))
                .chain(out.samples("offset"))
                .all(|s| s.timestamp == Timestamp::from_millis(40)),
            "the image's time is kept"
        );
        Detected {
            lane,
            offset: out.f64_values("offset"),
            lines,
            status: harness.status().expect("a status"),
        }
    }

    /// Checks the centre line recovered from a road drawn as `truth` has it, from `boundaries` seen.
    fn recovers(truth: Truth, boundaries: u8) {
        let (width, height) = (640, 480);
        let found = detect(width, height, edge_mask(width, height, &road(truth)));
        let [c0, c1, c2, count] = found.lane[..] else {
            panic!("{:?}", found.lane)
        };
        eprintln!("{truth:?}: c0 {c0:.4} c1 {c1:.5} c2 {c2:.6}, found {count}");
        assert!((count - f64::from(boundaries)).abs() < 0.5, "{:?}", found.lane);
        let Truth {
            offset,
            heading,
            bend,
            ..
        } = truth;
        assert!((c0 - offset).abs() < 0.05, "c0 {c0} for {offset}");
        assert!((c1 - heading).abs() < 0.01, "c1 {c1} for {heading}");
        assert!(
            c2.signum() == bend.signum() && (c2 - bend).abs() < 0.5 * bend.abs(),
            "c2 {c2} for {bend}"
        );
        assert_eq!(found.offset, [-c0], "offset = −c0");
        assert!(
            found.lines >= 4 * usize::from(boundaries),
            "each boundary is drawn"
        );
        let (both, one) = if boundaries == 2 { (1, 0) } else { (0, 1) };
        assert_eq!(
            found.status,
            serde_json::json!({"kind": "lanes", "frames": 1, "both": both, "one": one, "none": 0})
        );
    }

    #[test]
    fn the_default_camera_is_the_simulated_one() {
        let camera = simulated_camera(640, 480);
        let focal = 320.0 / 35.0_f64.to_radians().tan();
        assert!((camera.focal - focal).abs() < 1e-9);
        assert!((camera.horizon - (240.0 - focal * 0.05_f64.tan())).abs() < 1e-9);
        // 10 m ahead, 1 m to the right: the renderer's column and row.
        let (u, v) = camera.image(10.0, -1.0);
        assert!((u - (320.0 + focal / 10.0)).abs() < 1e-9);
        assert!((v - (camera.horizon + focal * 1.4 / 10.0)).abs() < 1e-9);
        let (ahead, left) = camera.ground(u, v).expect("below the horizon");
        assert!((ahead - 10.0).abs() < 1e-9 && (left + 1.0).abs() < 1e-9);
        assert_eq!(camera.ground(u, camera.horizon - 1.0), None, "above the horizon");
    }

    #[test]
    fn a_lane_bending_left_with_the_vehicle_right_of_centre_is_recovered() {
        let truth = Truth {
            offset: 0.3,
            heading: 0.03,
            bend: 0.002,
            phase: 6.0,
        };
        recovers(truth, 2);
    }

    #[test]
    fn a_lane_bending_right_with_the_vehicle_left_of_centre_is_recovered() {
        let truth = Truth {
            offset: -0.25,
            heading: -0.02,
            bend: -0.0015,
            phase: 9.0,
        };
        recovers(truth, 2);
    }

    #[test]
    fn between_two_dashes_the_other_lanes_edge_is_not_taken_for_the_lanes() {
        // No dash between 4 and 12 m: the nearest marking seen on the left is the other lane's edge.
        let truth = Truth {
            offset: 0.3,
            heading: 0.03,
            bend: 0.002,
            phase: 0.0,
        };
        recovers(truth, 1);
    }

    #[test]
    fn a_vehicle_ahead_in_the_lane_does_not_pull_the_boundaries() {
        let (width, height) = (640, 480);
        let truth = Truth {
            offset: 0.2,
            heading: -0.02,
            bend: 0.001,
            phase: 7.0,
        };
        let ahead = 14.0;
        let lane_centre = truth.offset + ahead * (truth.heading + ahead * truth.bend);
        let mask = with_vehicle(
            edge_mask(width, height, &road(truth)),
            width,
            height,
            ahead,
            lane_centre,
        );
        let found = detect(width, height, mask);
        let [c0, c1, c2, count] = found.lane[..] else {
            panic!("{:?}", found.lane)
        };
        eprintln!("{truth:?}, a vehicle {ahead} m ahead: c0 {c0:.4} c1 {c1:.5} c2 {c2:.6}, found {count}");
        assert!((count - 2.0).abs() < 0.5, "{:?}", found.lane);
        assert!((c0 - truth.offset).abs() < 0.05, "c0 {c0}");
        assert!((c1 - truth.heading).abs() < 0.01, "c1 {c1}");
    }

    #[test]
    fn a_single_boundary_gives_the_centre_half_a_lane_from_it() {
        let (width, height) = (640, 480);
        let truth = Truth {
            offset: 0.1,
            heading: 0.01,
            bend: 0.001,
            phase: 0.0,
        };
        let right_edge_only: Vec<Marking> = road(truth).into_iter().filter(|m| m.centre.a < 0.0).collect();
        let found = detect(width, height, edge_mask(width, height, &right_edge_only));
        let [c0, c1, _, count] = found.lane[..] else {
            panic!("{:?}", found.lane)
        };
        eprintln!("{truth:?}, right edge only: c0 {c0:.4} c1 {c1:.5}");
        assert!((count - 1.0).abs() < 0.5, "{:?}", found.lane);
        assert!(
            (c0 - 0.1).abs() < 0.05 && (c1 - 0.01).abs() < 0.01,
            "{:?}",
            found.lane
        );
    }

    #[test]
    fn an_empty_mask_finds_nothing_and_says_so() {
        let found = detect(640, 480, vec![0; 640 * 480]);
        assert_eq!(found.lane, [0.0, 0.0, 0.0, 0.0]);
        assert!(found.offset.is_empty(), "no offset without a boundary");
        assert_eq!(found.lines, 0);
        assert_eq!(found.status["none"], 1);
    }

    #[test]
    fn a_tiny_image_finds_nothing() {
        let found = detect(8, 8, vec![255; 64]);
        assert_eq!(found.lane.get(3), Some(&0.0));
        let found = detect(1, 1, vec![255]);
        assert_eq!(found.lane.get(3), Some(&0.0));
    }

    #[test]
    fn a_colour_image_is_refused_naming_the_input() {
        let image = Image::packed(8, 8, PixelFormat::Rgb8, vec![0_u8; 8 * 8 * 3]).expect("image");
        let mut harness = Harness::new(LaneDetector::info(), LaneDetector::default());
        harness.push("in", Payload::Image(image), Timestamp::from_millis(40));
        let error = harness.run().expect_err("a colour image").to_string();
        assert!(
            error.contains("input in") && error.contains("vision.convert"),
            "{error}"
        );
    }

    #[test]
    fn a_range_not_beyond_the_nearest_distance_is_refused() {
        let image = Image::packed(8, 8, PixelFormat::Gray8, vec![0_u8; 64]).expect("image");
        let mut harness = Harness::new(LaneDetector::info(), LaneDetector::default());
        harness.set_property("min_range", 20.0).expect("in range");
        harness.set_property("range", 10.0).expect("in range");
        harness.push("in", Payload::Image(image), Timestamp::from_millis(40));
        let error = harness.run().expect_err("an empty window").to_string();
        assert!(error.contains("min_range"), "{error}");
    }
}
