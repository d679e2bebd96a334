//! Software rendering of the camera's synthetic images, row span by row span.
//!
//! Everything is drawn as horizontal spans of one colour, and a span is filled by writing its first
//! pixel and then doubling with `copy_within` (a `memcpy` from the optimised standard library), so a
//! 640×480 frame costs a few thousand calls rather than 300 000 per-pixel writes, even in a debug build.

use std::f64::consts::{PI, TAU};

use crate::trajectory::VehicleState;
use crate::world::WorldView;

/// One RGB colour.
pub(crate) type Rgb = [u8; 3];

/// What the camera shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Pattern {
    /// A road scene seen from the simulated vehicle.
    Scene,
    /// Colour bars with a moving block, for checking a display chain.
    ColorBars,
}

impl Pattern {
    /// The names accepted by the camera's `pattern` property.
    pub const NAMES: [&'static str; 2] = ["scene", "color_bars"];

    /// The pattern with this property name.
    pub fn from_name(name: &str) -> Option<Pattern> {
        match name {
            "scene" => Some(Pattern::Scene),
            "color_bars" => Some(Pattern::ColorBars),
            _ => None,
        }
    }
}

/// What one frame depicts.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Scene<'a> {
    /// The frame's number, drawn as a bar code and in digits.
    pub frame: u32,
    /// The vehicle at the frame's time.
    pub state: VehicleState,
    /// Metres driven since the start, for scrolling the road.
    pub travelled_m: f64,
    /// A simulator's world: its road and obstacles replace the figure-eight's road and the car ahead.
    pub world: Option<&'a WorldView>,
}

/// Horizontal field of view, radians.
const FIELD_OF_VIEW: f64 = 70.0 * PI / 180.0;
/// Height of the camera above the road, metres.
const CAMERA_HEIGHT: f64 = 1.4;
/// Downward tilt of the camera, radians.
const CAMERA_TILT: f64 = 0.05;
/// Beyond this distance everything fades into the haze, metres.
const FOG_DISTANCE: f64 = 350.0;
/// Lane width, metres; the road has two lanes and the vehicle drives in the right one.
const LANE_WIDTH: f64 = 3.5;
/// Width of the painted lines, metres.
const LINE_WIDTH: f64 = 0.15;
/// Direction of the sun (radians counter-clockwise from east) and its elevation (radians).
const SUN_AZIMUTH: f64 = 2.4;
const SUN_ELEVATION: f64 = 0.16;

const SKY_TOP: Rgb = [38, 84, 170];
const SKY_HORIZON: Rgb = [168, 198, 232];
const HAZE: Rgb = [186, 200, 214];
const SUN: Rgb = [255, 244, 200];
const MOUNTAIN: Rgb = [104, 118, 146];
const GRASS: [Rgb; 2] = [[66, 138, 52], [54, 118, 42]];
const ASPHALT: [Rgb; 2] = [[92, 92, 98], [84, 84, 90]];
const PAINT: Rgb = [236, 236, 228];
const CAR_BODY: Rgb = [176, 32, 36];
const CAR_WINDOW: Rgb = [40, 44, 56];
const TAIL_LIGHT: [Rgb; 2] = [[150, 30, 30], [255, 70, 50]];
const BLACK: Rgb = [0, 0, 0];
const WHITE: Rgb = [255, 255, 255];

/// Number of cells in the frame-number bar code: a white and a black start cell, then 32 bits.
const BARCODE_CELLS: usize = 34;

/// 3×5 digit glyphs, row by row from the top, bit 14 the top-left pixel.
const DIGITS: [u16; 10] = [
    0b111_101_101_101_111,
    0b010_110_010_010_111,
    0b111_001_111_100_111,
    0b111_001_111_001_111,
    0b101_101_111_001_001,
    0b111_100_111_001_111,
    0b111_100_111_101_111,
    0b111_001_001_001_001,
    0b111_101_111_101_111,
    0b111_101_111_001_111,
];

/// The mix of `a` and `b`: `a` at `t = 0`, `b` at `t = 1`.
fn mix(a: Rgb, b: Rgb, t: f64) -> Rgb {
    let t = t.clamp(0.0, 1.0);
    let channel = |x: u8, y: u8| (f64::from(x) + (f64::from(y) - f64::from(x)) * t).round() as u8;
    let ([ar, ag, ab], [br, bg, bb]) = (a, b);
    [channel(ar, br), channel(ag, bg), channel(ab, bb)]
}

/// The second colour of a pair when `second`, else the first.
fn pick(pair: [Rgb; 2], second: bool) -> Rgb {
    let [first, other] = pair;
    if second { other } else { first }
}

/// `angle` wrapped into [−π, π).
fn wrap(angle: f64) -> f64 {
    (angle + PI).rem_euclid(TAU) - PI
}

/// Fills `span` (a whole number of pixels) with `color`.
fn fill_pixels(span: &mut [u8], color: Rgb) {
    let len = span.len() - span.len() % 3;
    let Some(first) = span.get_mut(..3) else { return };
    first.copy_from_slice(&color);
    let mut filled = 3;
    while filled < len {
        let count = filled.min(len - filled);
        span.copy_within(0..count, filled);
        filled += count;
    }
}

/// An RGB8 pixel buffer, tightly packed.
#[derive(Debug)]
pub(crate) struct Canvas<'a> {
    pixels: &'a mut [u8],
    width: usize,
    height: usize,
}

impl<'a> Canvas<'a> {
    /// A canvas over `pixels`, which must hold exactly `width * height * 3` bytes.
    pub fn new(pixels: &'a mut [u8], width: usize, height: usize) -> Option<Self> {
        (width.checked_mul(height)?.checked_mul(3)? == pixels.len()).then_some(Canvas {
            pixels,
            width,
            height,
        })
    }

    fn width(&self) -> i64 {
        self.width as i64
    }

    fn height(&self) -> i64 {
        self.height as i64
    }

    /// Fills pixels `x0..x1` of row `y`, clipped to the canvas.
    fn span(&mut self, y: i64, x0: i64, x1: i64, color: Rgb) {
        if y < 0 || y >= self.height() {
            return;
        }
        let (x0, x1) = (x0.clamp(0, self.width()), x1.clamp(0, self.width()));
        if x1 <= x0 {
            return;
        }
        let row = y as usize * self.width * 3;
        if let Some(span) = self.pixels.get_mut(row + x0 as usize * 3..row + x1 as usize * 3) {
            fill_pixels(span, color);
        }
    }

    /// Fills the rectangle `x0..x1` × `y0..y1`, clipped to the canvas.
    fn rect(&mut self, x0: i64, y0: i64, x1: i64, y1: i64, color: Rgb) {
        for y in y0.max(0)..y1.min(self.height()) {
            self.span(y, x0, x1, color);
        }
    }

    /// Fills rows `y0..y1` of column `x`, clipped to the canvas.
    fn column(&mut self, x: i64, y0: i64, y1: i64, color: Rgb) {
        if x < 0 || x >= self.width() {
            return;
        }
        for y in y0.max(0)..y1.min(self.height()) {
            let at = (y as usize * self.width + x as usize) * 3;
            if let Some(pixel) = self.pixels.get_mut(at..at + 3) {
                pixel.copy_from_slice(&color);
            }
        }
    }
}

/// The camera model for one frame: focal length and where the horizon falls.
#[derive(Debug, Clone, Copy)]
struct View {
    focal: f64,
    center_x: f64,
    horizon: f64,
}

impl View {
    fn new(canvas: &Canvas<'_>, pitch: f64) -> Self {
        let width = canvas.width as f64;
        let focal = 0.5 * width / (0.5 * FIELD_OF_VIEW).tan();
        View {
            focal,
            center_x: 0.5 * width,
            horizon: 0.5 * canvas.height as f64 + focal * (pitch - CAMERA_TILT).tan(),
        }
    }

    /// The image column of a point `right` metres right of the camera axis and `ahead` metres ahead.
    fn column(&self, right: f64, ahead: f64) -> i64 {
        (self.center_x + self.focal * right / ahead).round() as i64
    }

    /// The image row of a point `up` metres above the road and `ahead` metres ahead.
    fn row(&self, up: f64, ahead: f64) -> i64 {
        (self.horizon + self.focal * (CAMERA_HEIGHT - up) / ahead).round() as i64
    }
}

/// Draws `scene` as `pattern` into `canvas`.
pub(crate) fn render(canvas: &mut Canvas<'_>, pattern: Pattern, scene: &Scene) {
    match pattern {
        Pattern::Scene => {
            let view = View::new(canvas, scene.state.pitch);
            draw_sky(canvas, &view, scene);
            draw_ground(canvas, &view, scene);
            match scene.world {
                Some(world) => draw_obstacles(canvas, &view, world),
                None => draw_lead_car(canvas, &view, scene),
            }
        }
        Pattern::ColorBars => draw_color_bars(canvas, scene.frame),
    }
    draw_overlay(canvas, scene);
}

/// Elevation of the mountain ridge, radians, in the direction `azimuth` (periodic over a full turn).
fn ridge(azimuth: f64) -> f64 {
    let height = 0.035
        + 0.020 * (3.0 * azimuth + 1.0).sin()
        + 0.012 * (7.0 * azimuth + 2.0).sin()
        + 0.006 * (17.0 * azimuth + 0.5).sin();
    height.max(0.004)
}

fn draw_sky(canvas: &mut Canvas<'_>, view: &View, scene: &Scene) {
    let horizon_row = view.horizon.ceil() as i64;
    let sky_rows = horizon_row.clamp(0, canvas.height());
    for y in 0..sky_rows {
        let t = (y as f64 + 0.5) / view.horizon.max(1.0);
        canvas.span(y, 0, canvas.width(), mix(SKY_TOP, SKY_HORIZON, t * t));
    }

    // The sun, far away: it moves across the image only as the vehicle turns.
    let bearing = wrap(SUN_AZIMUTH - scene.state.yaw);
    if bearing.abs() < 0.5 * FIELD_OF_VIEW + 0.2 {
        let x = view.center_x - view.focal * bearing.tan();
        let y = view.horizon - view.focal * SUN_ELEVATION.tan();
        let radius = 0.03 * view.focal;
        let top = (y - radius).floor() as i64;
        for row in top..=(y + radius).ceil() as i64 {
            let dy = row as f64 + 0.5 - y;
            if dy.abs() < radius && (row as f64) < view.horizon {
                let half = (radius * radius - dy * dy).sqrt();
                canvas.span(row, (x - half).round() as i64, (x + half).round() as i64, SUN);
            }
        }
    }

    // Mountains at the horizon, fixed to the world: they slide sideways as the heading changes.
    for x in 0..canvas.width() {
        let azimuth = scene.state.yaw + ((view.center_x - x as f64 - 0.5) / view.focal).atan();
        let top = (view.horizon - view.focal * ridge(azimuth)).round() as i64;
        canvas.column(x, top, horizon_row, MOUNTAIN);
    }
}

fn draw_ground(canvas: &mut Canvas<'_>, view: &View, scene: &Scene) {
    let curvature = scene.state.curvature();
    // The vehicle weaves gently inside its lane.
    let weave = 0.25 * (0.4 * scene.state.time_s).sin();
    let width = canvas.width();
    let first = view.horizon.ceil().max(0.0) as i64;
    for y in first..canvas.height() {
        let below = y as f64 + 0.5 - view.horizon;
        if below <= 0.0 {
            continue;
        }
        let ahead = CAMERA_HEIGHT * view.focal / below;
        if ahead >= FOG_DISTANCE {
            canvas.span(y, 0, width, HAZE);
            continue;
        }
        let fog = (ahead / FOG_DISTANCE).powf(0.7);
        // Lateral position (right of the camera) of the road's centre line, and the road position of
        // this row (the same marks come closer as the vehicle drives on). On the figure-eight the
        // vehicle is in the right lane, weaving gently, and the road bends with the path's curvature.
        let (center, along, lane_width) = match scene.world {
            Some(world) => {
                // Beyond the road the view holds, grass.
                let Some((left, station)) = world.centre_line_at(ahead) else {
                    canvas.span(y, 0, width, mix(pick(GRASS, false), HAZE, fog));
                    continue;
                };
                (-left, station, world.lane_width_m)
            }
            None => (
                -0.5 * LANE_WIDTH - weave - 0.5 * curvature * ahead * ahead,
                ahead + scene.travelled_m,
                LANE_WIDTH,
            ),
        };
        let stripe = (along / 4.0).floor().rem_euclid(2.0) >= 1.0;
        let grass = mix(pick(GRASS, stripe), HAZE, fog);
        let asphalt = mix(pick(ASPHALT, stripe), HAZE, fog);
        let paint = mix(PAINT, HAZE, fog);
        let dash = if along.rem_euclid(12.0) < 4.0 {
            paint
        } else {
            asphalt
        };

        let left = center - lane_width;
        let right = center + lane_width;
        let edges = [
            (0, grass),
            (view.column(left, ahead), paint),
            (view.column(left + LINE_WIDTH, ahead), asphalt),
            (view.column(center - 0.5 * LINE_WIDTH, ahead), dash),
            (view.column(center + 0.5 * LINE_WIDTH, ahead), asphalt),
            (view.column(right - LINE_WIDTH, ahead), paint),
            (view.column(right, ahead), grass),
        ];
        let mut iter = edges.iter().peekable();
        while let Some((start, color)) = iter.next() {
            let end = iter.peek().map_or(width, |(next, _)| *next);
            canvas.span(y, *start, end, *color);
        }
    }
}

/// A car ahead in the same lane, its distance varying: something that visibly moves even at rest.
fn draw_lead_car(canvas: &mut Canvas<'_>, view: &View, scene: &Scene) {
    let t = scene.state.time_s;
    let ahead = 20.0 + 8.0 * (0.23 * t).sin();
    let weave = 0.25 * (0.4 * t).sin();
    let lateral = -weave + 0.4 * (0.17 * t).sin() - 0.5 * scene.state.curvature() * ahead * ahead;
    // Brake lights come on while the gap closes.
    let light = pick(TAIL_LIGHT, (0.23 * t).cos() < 0.0);
    draw_car(canvas, view, (lateral, 0.9), ahead, 1.5, Some(light));
}

/// A car's silhouette `ahead` metres away: body, rear window, shadow, and tail lights when given.
/// `across` is its centre's position right of the camera axis and its half width, metres.
fn draw_car(
    canvas: &mut Canvas<'_>,
    view: &View,
    across: (f64, f64),
    ahead: f64,
    height_m: f64,
    lights: Option<Rgb>,
) {
    let (lateral, half) = across;
    let (x0, x1) = (
        view.column(lateral - half, ahead),
        view.column(lateral + half, ahead),
    );
    let (bottom, top) = (view.row(0.0, ahead), view.row(height_m, ahead));
    let (width, height) = (x1 - x0, bottom - top);
    canvas.rect(x0, top, x1, bottom, CAR_BODY);
    canvas.rect(
        x0 + width / 10,
        top + height / 8,
        x1 - width / 10,
        top + height * 4 / 9,
        CAR_WINDOW,
    );
    if let Some(light) = lights {
        let (light_top, light_bottom) = (top + height * 3 / 5, top + height * 3 / 4);
        canvas.rect(x0 + width / 20, light_top, x0 + width / 4, light_bottom, light);
        canvas.rect(x1 - width / 4, light_top, x1 - width / 20, light_bottom, light);
    }
    canvas.rect(
        x0 - width / 20,
        bottom - height / 12,
        x1 + width / 20,
        bottom,
        BLACK,
    );
}

/// A simulator's obstacles, farthest first so that nearer ones hide them: each a box seen from behind
/// or the side, drawn as its silhouette.
fn draw_obstacles(canvas: &mut Canvas<'_>, view: &View, world: &WorldView) {
    let mut visible: Vec<_> = world.obstacles.iter().filter(|o| o.x > 1.0).collect();
    visible.sort_by(|a, b| b.x.total_cmp(&a.x));
    for obstacle in visible {
        // The silhouette's half width across the line of sight.
        let (sin, cos) = obstacle.yaw.sin_cos();
        let half = 0.5 * (obstacle.width * cos.abs() + obstacle.length * sin.abs());
        let near = obstacle.x - 0.5 * (obstacle.length * cos.abs() + obstacle.width * sin.abs());
        draw_car(
            canvas,
            view,
            (-obstacle.y, half),
            near.max(1.0),
            obstacle.height,
            None,
        );
    }
}

fn draw_color_bars(canvas: &mut Canvas<'_>, frame: u32) {
    const BARS: [Rgb; 8] = [
        [235, 235, 235],
        [235, 235, 16],
        [16, 235, 235],
        [16, 235, 16],
        [235, 16, 235],
        [235, 16, 16],
        [16, 16, 235],
        [16, 16, 16],
    ];
    let (width, height) = (canvas.width(), canvas.height());
    let split = height * 3 / 4;
    let mut x0 = 0;
    for (index, color) in (1_i64..).zip(BARS) {
        let x1 = width * index / 8;
        canvas.rect(x0, 0, x1, split, color);
        x0 = x1;
    }
    canvas.rect(0, split, width, height, BLACK);
    let block = (width / 16).max(1);
    let x = (i64::from(frame) * 4).rem_euclid(width);
    canvas.rect(
        x,
        split + (height - split) / 4,
        x + block,
        height - (height - split) / 4,
        WHITE,
    );
    canvas.rect(
        x - width,
        split + (height - split) / 4,
        x + block - width,
        height - (height - split) / 4,
        WHITE,
    );
}

fn draw_number(canvas: &mut Canvas<'_>, x: i64, y: i64, scale: i64, value: u64) {
    let text = value.to_string();
    let count = text.len() as i64;
    canvas.rect(x, y, x + (4 * count + 1) * scale, y + 7 * scale, BLACK);
    for (index, digit) in (0_i64..).zip(text.bytes()) {
        let Some(glyph) = DIGITS.get(usize::from(digit.wrapping_sub(b'0'))) else {
            continue;
        };
        let left = x + (1 + 4 * index) * scale;
        for bit in 0..15_i64 {
            if glyph >> (14 - bit) & 1 == 1 {
                let (row, col) = (bit / 3, bit % 3);
                let (px, py) = (left + col * scale, y + (1 + row) * scale);
                canvas.rect(px, py, px + scale, py + scale, WHITE);
            }
        }
    }
}

/// The bar code geometry for an image of this size: cell width and bar height, in pixels.
pub(crate) fn barcode_geometry(width: usize, height: usize) -> (usize, usize) {
    ((width / (BARCODE_CELLS + 6)).max(1), (height / 48).max(2))
}

/// The frame number as a bar code along the top-left edge, the frame number and speed in digits.
fn draw_overlay(canvas: &mut Canvas<'_>, scene: &Scene) {
    let (cell, bar) = barcode_geometry(canvas.width, canvas.height);
    let (cell, bar) = (cell as i64, bar as i64);
    for index in 0..BARCODE_CELLS as i64 {
        let white = match index {
            0 => true,
            1 => false,
            _ => scene.frame >> (BARCODE_CELLS as i64 - 1 - index) & 1 == 1,
        };
        canvas.rect(
            index * cell,
            0,
            (index + 1) * cell,
            bar,
            if white { WHITE } else { BLACK },
        );
    }
    let scale = (canvas.height() / 160).max(1);
    draw_number(canvas, 0, bar + scale, scale, u64::from(scene.frame));
    let speed_kmh = (scene.state.speed() * 3.6).round() as u64;
    let digits = speed_kmh.to_string().len() as i64;
    draw_number(
        canvas,
        canvas.width() - (4 * digits + 1) * scale,
        bar + scale,
        scale,
        speed_kmh,
    );
}

/// Reads the frame number from the bar code of an image drawn by [`render`]: the raw RGB8 bytes, their
/// size and the row stride; `None` when no bar code is there.
pub(crate) fn read_barcode(
    pixels: &[u8],
    width: usize,
    height: usize,
    stride: usize,
    bytes_per_pixel: usize,
) -> Option<u32> {
    let (cell, bar) = barcode_geometry(width, height);
    if width < BARCODE_CELLS * cell {
        return None;
    }
    let row = (bar / 2) * stride;
    // Green is the second byte of RGB, BGR, RGBA and BGRA; grey has a single byte.
    let channel = usize::from(bytes_per_pixel >= 3);
    let bright = |index: usize| -> Option<bool> {
        let x = index * cell + cell / 2;
        pixels
            .get(row + x * bytes_per_pixel + channel)
            .map(|value| *value >= 128)
    };
    if !bright(0)? || bright(1)? {
        return None;
    }
    let mut value = 0_u32;
    for index in 2..BARCODE_CELLS {
        value = value << 1 | u32::from(bright(index)?);
    }
    Some(value)
}
