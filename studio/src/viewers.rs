//! Data viewers: floating windows that show the samples of one output as they arrive. The kind follows the
//! output's data type: images as GPU textures, numbers, vectors, IMU and poses as plots against time, GNSS
//! fixes as a track on a local metric plane, anything else as a table of the latest samples. Viewers get
//! samples as protocol frames (header and bytes) and do not care how they travelled.

use std::collections::{BTreeMap, VecDeque};

use std::sync::Arc;

use egui::{Color32, ColorImage, RichText, TextureHandle, TextureOptions, Vec2};
use egui_plot::{Legend, Line, Plot, PlotPoints, Points};
use kairos_protocol::frame::SampleHeader;

use crate::cloud3d::{CloudCallback, ColorBy, GpuCloud, OrbitCamera};

/// The most points a series keeps (at 30 Hz, more than five minutes to scroll back through).
const SERIES_POINTS: usize = 10_000;
/// The most rows a table keeps.
const TABLE_ROWS: usize = 200;
/// The time window a live plot follows unless the user changes it, in seconds.
const LIVE_WINDOW_S: f64 = 10.0;
/// Colours of a plot's series, in order, so that the legend above the plot can name them.
const SERIES_COLORS: [Color32; 8] = [
    Color32::from_rgb(100, 170, 255),
    Color32::from_rgb(255, 150, 80),
    Color32::from_rgb(120, 210, 120),
    Color32::from_rgb(240, 100, 110),
    Color32::from_rgb(190, 140, 255),
    Color32::from_rgb(230, 210, 90),
    Color32::from_rgb(90, 210, 210),
    Color32::from_rgb(200, 200, 200),
];
/// A timestamp this far before the previous one means time went back (nanoseconds).
const TIME_JUMP_NS: i64 = 500_000_000;
/// Mean Earth radius (IUGG), for the local projection of GNSS fixes.
const EARTH_RADIUS_M: f64 = 6_371_008.8;

/// How a viewer shows its samples.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ViewerKind {
    /// An image.
    Image,
    /// Numbers against time.
    Plot,
    /// GNSS fixes on a plane.
    Track,
    /// Point clouds in 3D.
    Cloud,
    /// Poses in 3D: the path so far and where the body points now.
    Trajectory,
    /// The latest samples as text.
    Table,
}

impl ViewerKind {
    /// The viewer a data type gets.
    pub fn for_type(data_type: &str) -> ViewerKind {
        match data_type {
            "image" => ViewerKind::Image,
            "f64" | "i64" | "bool" | "vector" | "imu" => ViewerKind::Plot,
            "pose" => ViewerKind::Trajectory,
            "gnss_fix" => ViewerKind::Track,
            "point_cloud" => ViewerKind::Cloud,
            _ => ViewerKind::Table,
        }
    }

    /// Whether outputs of `data_type` can be drawn over this viewer's: more fixes on a GNSS track,
    /// boxes (a matrix of rows min x, y, z, max x, y, z) in a point cloud.
    pub fn overlays(self, data_type: &str) -> bool {
        matches!(
            (self, data_type),
            (ViewerKind::Track, "gnss_fix") | (ViewerKind::Cloud, "matrix")
        )
    }

    /// The viewers that can show a data type, the usual one first.
    pub fn choices(data_type: &str) -> Vec<ViewerKind> {
        let usual = ViewerKind::for_type(data_type);
        let mut choices = vec![usual];
        if data_type == "pose" {
            choices.push(ViewerKind::Plot);
        }
        if usual != ViewerKind::Table {
            choices.push(ViewerKind::Table);
        }
        choices
    }

    /// The name a diagram file saves it under.
    pub fn key(self) -> &'static str {
        match self {
            ViewerKind::Image => "image",
            ViewerKind::Plot => "plot",
            ViewerKind::Track => "track",
            ViewerKind::Cloud => "cloud",
            ViewerKind::Trajectory => "trajectory",
            ViewerKind::Table => "table",
        }
    }

    /// The kind a diagram file names; `None` for a name this studio does not know.
    pub fn from_key(key: &str) -> Option<ViewerKind> {
        [
            ViewerKind::Image,
            ViewerKind::Plot,
            ViewerKind::Track,
            ViewerKind::Cloud,
            ViewerKind::Trajectory,
            ViewerKind::Table,
        ]
        .into_iter()
        .find(|kind| kind.key() == key)
    }

    /// What the viewer is called in menus and titles.
    pub fn name(self) -> &'static str {
        match self {
            ViewerKind::Image => "image",
            ViewerKind::Plot => "plot",
            ViewerKind::Track => "GNSS track",
            ViewerKind::Cloud => "3D point cloud",
            ViewerKind::Trajectory => "3D poses",
            ViewerKind::Table => "latest samples",
        }
    }
}

/// The latest image and what is needed to read its pixels back.
struct Frame {
    texture: TextureHandle,
    /// The same pixels the texture was made from (shared, not copied), for the value under the pointer.
    pixels: Arc<ColorImage>,
    original_width: Option<u32>,
}

/// One open viewer.
#[allow(clippy::struct_excessive_bools, reason = "independent switches of one window")]
pub struct Viewer {
    id: u64,
    /// The output it shows (`camera.image`).
    pub output: String,
    /// How it shows it.
    pub kind: ViewerKind,
    open: bool,
    docked: bool,
    paused: bool,
    /// Samples received, and samples the runtime did not send (rate limit, slow link).
    pub received: u64,
    /// Samples skipped on the way, as the frames reported.
    pub skipped: u64,
    first_timestamp_ns: Option<i64>,
    last: Option<SampleHeader>,
    pending_image: Option<(ColorImage, Option<u32>)>,
    frame: Option<Frame>,
    zoom: f32,
    /// Whether the zoom follows the viewer's width.
    fit: bool,
    /// Plot series: name and (seconds since the first sample, value) points.
    series: Vec<(String, VecDeque<[f64; 2]>)>,
    track: Vec<[f64; 2]>,
    origin: Option<(f64, f64)>,
    /// Outputs drawn over the main one: more GNSS tracks on a track, boxes in a 3D view.
    pub also: Vec<String>,
    /// The tracks of the outputs in `also`, on the main track's plane.
    more_tracks: Vec<(String, Vec<[f64; 2]>)>,
    /// A 3D viewer's cloud as received, before boxes are drawn into it (shared with `cloud` when there
    /// are none, so an ordinary cloud is never copied).
    received_cloud: Arc<GpuCloud>,
    /// Boxes (min x, y, z, max x, y, z) from each output in `also`.
    boxes: Vec<(String, Vec<[f32; 6]>)>,
    generation: u64,
    rows: VecDeque<(u64, i64, i64, String)>,
    cloud: Arc<GpuCloud>,
    /// A pose viewer's positions so far.
    path: VecDeque<glam::Vec3>,
    camera: OrbitCamera,
    color_by: ColorBy,
    point_size: f32,
    /// The seconds a live plot shows.
    window_s: f64,
}

impl std::fmt::Debug for Viewer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Viewer")
            .field("output", &self.output)
            .field("kind", &self.kind)
            .field("received", &self.received)
            .finish_non_exhaustive()
    }
}

/// Turns frame pixels into an image for the GPU; `None` for a layout that does not add up. The format is
/// looked at once per image and each row converted by a loop of its own (a 1920×1080 frame in a few
/// milliseconds).
fn color_image(layout: &kairos_protocol::frame::ImageLayout, bytes: &[u8]) -> Option<ColorImage> {
    let (width, height, stride) = (
        layout.width as usize,
        layout.height as usize,
        layout.stride as usize,
    );
    let per_pixel = match layout.format.as_str() {
        "gray8" => 1,
        "gray16" => 2,
        "rgb8" | "bgr8" => 3,
        "rgba8" | "bgra8" => 4,
        _ => return None,
    };
    if width == 0
        || height == 0
        || stride < width * per_pixel
        || bytes.len() < stride * (height - 1) + width * per_pixel
    {
        return None;
    }
    if layout.format == "gray16" {
        return gray16_image(width, height, stride, bytes);
    }
    let convert: fn(&[u8]) -> Color32 = match layout.format.as_str() {
        "gray8" => |p| Color32::from_gray(p[0]),
        "rgb8" => |p| Color32::from_rgb(p[0], p[1], p[2]),
        "bgr8" => |p| Color32::from_rgb(p[2], p[1], p[0]),
        "rgba8" => |p| Color32::from_rgba_unmultiplied(p[0], p[1], p[2], p[3]),
        _ => |p| Color32::from_rgba_unmultiplied(p[2], p[1], p[0], p[3]),
    };
    let mut pixels = Vec::with_capacity(width * height);
    for row in 0..height {
        let line = bytes.get(row * stride..row * stride + width * per_pixel)?;
        pixels.extend(line.chunks_exact(per_pixel).map(convert));
    }
    Some(ColorImage::new([width, height], pixels))
}

/// A 16-bit grey frame (a depth camera's millimetres, a thermal camera's counts) stretched over the grey
/// scale from its least to its greatest value, 0 left black: such frames use a small part of the 16 bits,
/// and shown by their high byte they would be black.
fn gray16_image(width: usize, height: usize, stride: usize, bytes: &[u8]) -> Option<ColorImage> {
    let rows = || (0..height).filter_map(move |row| bytes.get(row * stride..row * stride + width * 2));
    let values = || rows().flat_map(|line| line.chunks_exact(2).map(|p| u16::from_le_bytes([p[0], p[1]])));
    let (low, high) = values()
        .filter(|v| *v != 0)
        .fold((u16::MAX, 0), |(low, high), v| (low.min(v), high.max(v)));
    let span = u32::from(high.saturating_sub(low)).max(1);
    let pixels: Vec<Color32> = values()
        .map(|v| {
            if v == 0 {
                return Color32::BLACK;
            }
            let level = (u32::from(v.saturating_sub(low)) * 255 + span / 2) / span;
            Color32::from_gray(u8::try_from(level.min(255)).unwrap_or(255))
        })
        .collect();
    (pixels.len() == width * height).then(|| ColorImage::new([width, height], pixels))
}

/// A point-cloud frame's points (x, y, z and, with `intensity`, a fourth f32 each, little-endian) for the
/// GPU.
fn cloud_of(intensity: bool, payload: &[u8], generation: u64) -> GpuCloud {
    let stride = if intensity { 16 } else { 12 };
    let mut points = Vec::with_capacity(payload.len() / stride);
    let (mut low, mut high) = (f32::INFINITY, f32::NEG_INFINITY);
    for chunk in payload.chunks_exact(stride) {
        let value = |at: usize| {
            chunk
                .get(at..at + 4)
                .and_then(|b| b.try_into().ok())
                .map_or(0.0, f32::from_le_bytes)
        };
        let point = [
            value(0),
            value(4),
            value(8),
            if intensity { value(12) } else { 0.5 },
        ];
        low = low.min(point[2]);
        high = high.max(point[2]);
        points.push(point);
    }
    GpuCloud {
        generation,
        points,
        z_range: if low <= high { (low, high) } else { (0.0, 1.0) },
    }
}

/// A pose viewer's points: the path so far (intensity 0.3), and the body's axes now, a metre and a half long
/// (forward 1.0, left 0.7, up 0.5 in intensity, so colouring by intensity tells them apart).
fn pose_cloud(path: &VecDeque<glam::Vec3>, orientation: glam::Quat, generation: u64) -> GpuCloud {
    let mut points: Vec<[f32; 4]> = path.iter().map(|p| [p.x, p.y, p.z, 0.3]).collect();
    if let Some(now) = path.back() {
        for (axis, intensity) in [(glam::Vec3::X, 1.0), (glam::Vec3::Y, 0.7), (glam::Vec3::Z, 0.5)] {
            let direction = orientation * axis;
            for step in 0..=30 {
                let p = *now + direction * (step as f32 * 0.05);
                points.push([p.x, p.y, p.z, intensity]);
            }
        }
    }
    let (low, high) = points
        .iter()
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(l, h), p| {
            (l.min(p[2]), h.max(p[2]))
        });
    GpuCloud {
        generation,
        points,
        z_range: if low <= high { (low, high) } else { (0.0, 1.0) },
    }
}

/// A time in nanoseconds since the UNIX epoch as the time of day in UTC, to the millisecond.
fn time_of_day(nanos: i64) -> String {
    let millis = nanos.div_euclid(1_000_000).rem_euclid(86_400_000);
    format!(
        "{:02}:{:02}:{:02}.{:03}",
        millis / 3_600_000,
        millis / 60_000 % 60,
        millis / 1000 % 60,
        millis % 1000
    )
}

/// The numbers a plot draws from a sample's JSON value, with their series names.
fn plotted(data_type: &str, value: &serde_json::Value) -> Vec<(String, f64)> {
    let xyz = |prefix: &str, v: Option<&serde_json::Value>| -> Vec<(String, f64)> {
        v.and_then(serde_json::Value::as_array)
            .map(|a| {
                a.iter()
                    .zip(["x", "y", "z"])
                    .filter_map(|(n, axis)| Some((format!("{prefix}.{axis}"), n.as_f64()?)))
                    .collect()
            })
            .unwrap_or_default()
    };
    match data_type {
        "f64" | "i64" => value
            .as_f64()
            .map(|v| vec![("value".to_owned(), v)])
            .unwrap_or_default(),
        "bool" => value
            .as_bool()
            .map(|v| vec![("value".to_owned(), f64::from(u8::from(v)))])
            .unwrap_or_default(),
        "vector" => value
            .as_array()
            .map(|a| {
                a.iter()
                    .take(16)
                    .enumerate()
                    .filter_map(|(i, n)| Some((format!("[{i}]"), n.as_f64()?)))
                    .collect()
            })
            .unwrap_or_default(),
        "imu" => {
            let mut values = xyz("angular_velocity", value.get("angular_velocity"));
            values.extend(xyz("linear_acceleration", value.get("linear_acceleration")));
            values
        }
        "pose" => xyz("position", value.get("position")),
        _ => Vec::new(),
    }
}

impl Viewer {
    fn new(id: u64, output: String, kind: ViewerKind) -> Viewer {
        Viewer {
            id,
            output,
            kind,
            open: true,
            docked: true,
            paused: false,
            received: 0,
            skipped: 0,
            first_timestamp_ns: None,
            last: None,
            pending_image: None,
            frame: None,
            zoom: 1.0,
            fit: true,
            series: Vec::new(),
            track: Vec::new(),
            origin: None,
            also: Vec::new(),
            more_tracks: Vec::new(),
            received_cloud: Arc::new(GpuCloud::default()),
            boxes: Vec::new(),
            generation: 0,
            rows: VecDeque::new(),
            cloud: Arc::new(GpuCloud::default()),
            path: VecDeque::new(),
            camera: OrbitCamera::default(),
            color_by: ColorBy::Height,
            point_size: 2.0,
            window_s: LIVE_WINDOW_S,
        }
    }

    /// The seconds a live plot shows.
    pub fn window_s(&self) -> f64 {
        self.window_s
    }

    /// How many points the 3D view shows.
    pub fn cloud_points(&self) -> usize {
        self.cloud.points.len()
    }

    /// The plot's series: name and point count.
    pub fn series(&self) -> Vec<(&str, usize)> {
        self.series
            .iter()
            .map(|(name, points)| (name.as_str(), points.len()))
            .collect()
    }

    /// The size of the image shown, once one arrived.
    pub fn texture_size(&self) -> Option<[usize; 2]> {
        self.frame.as_ref().map(|f| f.texture.size())
    }

    /// The track's points so far (metres east and north of the first fix).
    pub fn track(&self) -> &[[f64; 2]] {
        &self.track
    }

    /// The table's rows, newest first: the sample's text.
    pub fn rows(&self) -> impl Iterator<Item = &str> {
        self.rows.iter().map(|(_, _, _, text)| text.as_str())
    }

    fn receive(&mut self, header: &SampleHeader, payload: &[u8]) {
        self.received += 1;
        self.skipped += header.skipped;
        if self.paused {
            return;
        }
        // Time going back (a replay that loops or seeks back) starts the plot afresh.
        if let Some(last) = &self.last
            && header.timestamp_ns < last.timestamp_ns - TIME_JUMP_NS
        {
            self.first_timestamp_ns = None;
            self.series.clear();
        }
        let value = header.value.clone().unwrap_or(serde_json::Value::Null);
        match self.kind {
            ViewerKind::Image => {
                if let Some(layout) = &header.image
                    && let Some(image) = color_image(layout, payload)
                {
                    self.pending_image = Some((image, layout.original_width));
                }
            }
            ViewerKind::Plot => self.plot_sample(header, &value),
            ViewerKind::Track => {
                if let Some(point) = self.track_point(&value) {
                    push_bounded(&mut self.track, point);
                }
            }
            ViewerKind::Cloud => {
                self.generation += 1;
                self.received_cloud = Arc::new(cloud_of(header.intensity, payload, self.generation));
                self.rebuild_cloud();
            }
            ViewerKind::Trajectory => self.pose_sample(&value),
            ViewerKind::Table => self.table_sample(header, &value, payload),
        }
        self.last = Some(header.clone());
    }

    fn plot_sample(&mut self, header: &SampleHeader, value: &serde_json::Value) {
        let first = *self.first_timestamp_ns.get_or_insert(header.timestamp_ns);
        let seconds = (header.timestamp_ns - first) as f64 / 1e9;
        for (name, y) in plotted(&header.data_type, value) {
            let index = self
                .series
                .iter()
                .position(|(n, _)| *n == name)
                .unwrap_or_else(|| {
                    self.series.push((name, VecDeque::new()));
                    self.series.len() - 1
                });
            if let Some((_, points)) = self.series.get_mut(index) {
                if points.len() == SERIES_POINTS {
                    points.pop_front();
                }
                points.push_back([seconds, y]);
            }
        }
    }

    /// A fix as metres east and north of the first fix any track received.
    fn track_point(&mut self, value: &serde_json::Value) -> Option<[f64; 2]> {
        let lat = value.get("latitude_deg").and_then(serde_json::Value::as_f64)?;
        let lon = value.get("longitude_deg").and_then(serde_json::Value::as_f64)?;
        // Equirectangular around the first fix: metres east and north, exact enough over the
        // few kilometres a test drive covers.
        let (lat0, lon0) = *self.origin.get_or_insert((lat, lon));
        let east = EARTH_RADIUS_M * (lon - lon0).to_radians() * lat0.to_radians().cos();
        let north = EARTH_RADIUS_M * (lat - lat0).to_radians();
        Some([east, north])
    }

    /// A sample of an output drawn over the main one.
    fn receive_overlay(&mut self, header: &SampleHeader, value: &serde_json::Value) {
        if self.paused {
            return;
        }
        match self.kind {
            ViewerKind::Track => {
                if let Some(point) = self.track_point(value) {
                    let index = entry_of(&mut self.more_tracks, &header.output);
                    push_bounded(&mut self.more_tracks[index].1, point);
                }
            }
            ViewerKind::Cloud => {
                let index = entry_of(&mut self.boxes, &header.output);
                self.boxes[index].1 = boxes_of(value);
                self.rebuild_cloud();
            }
            _ => {}
        }
    }

    /// The cloud to draw: the received points, and the edges of every box as points of the marker
    /// colour (intensity −1).
    fn rebuild_cloud(&mut self) {
        if self.boxes.iter().all(|(_, boxes)| boxes.is_empty()) {
            self.cloud = Arc::clone(&self.received_cloud);
            return;
        }
        self.generation += 1;
        let mut points = self.received_cloud.points.clone();
        for b in self.boxes.iter().flat_map(|(_, boxes)| boxes) {
            box_edges(b, &mut points);
        }
        self.cloud = Arc::new(GpuCloud {
            generation: self.generation,
            points,
            z_range: self.received_cloud.z_range,
        });
    }

    fn pose_sample(&mut self, value: &serde_json::Value) {
        let numbers = |v: Option<&serde_json::Value>| -> Vec<f32> {
            #[allow(
                clippy::cast_possible_truncation,
                reason = "metres and unit quaternions, shown on screen"
            )]
            v.and_then(serde_json::Value::as_array)
                .map(|a| {
                    a.iter()
                        .filter_map(serde_json::Value::as_f64)
                        .map(|x| x as f32)
                        .collect()
                })
                .unwrap_or_default()
        };
        let (position, rotation) = (numbers(value.get("position")), numbers(value.get("orientation")));
        let (&[x, y, z], &[qx, qy, qz, qw]) = (position.as_slice(), rotation.as_slice()) else {
            return;
        };
        if self.path.len() == SERIES_POINTS {
            self.path.pop_front();
        }
        self.path.push_back(glam::Vec3::new(x, y, z));
        let orientation = glam::Quat::from_xyzw(qx, qy, qz, qw);
        self.cloud = Arc::new(pose_cloud(&self.path, orientation, self.received));
    }

    fn table_sample(&mut self, header: &SampleHeader, value: &serde_json::Value, payload: &[u8]) {
        let text = table_text(&header.data_type, value, payload.len());
        if self.rows.len() == TABLE_ROWS {
            self.rows.pop_back();
        }
        self.rows.push_front((
            header.sequence,
            header.timestamp_ns,
            header.time_of_issue_ns - header.timestamp_ns,
            text,
        ));
    }

    fn title(&self) -> String {
        let mut outputs = self.output.clone();
        for over in &self.also {
            outputs.push_str(" + ");
            outputs.push_str(over);
        }
        format!("{outputs} — {}", self.kind.name())
    }

    /// Whether it sits in the dock beside the canvas (or floats in a window).
    pub fn is_docked(&self) -> bool {
        self.docked
    }

    /// Draws the viewer; returns an output (of `choices`: output and type) the user chose to draw over it.
    fn contents(&mut self, ui: &mut egui::Ui, choices: &[(String, String)]) -> Option<(String, String)> {
        let chosen = self.status(ui, choices);
        match self.kind {
            ViewerKind::Image => self.image(ui),
            ViewerKind::Plot => self.plot(ui),
            ViewerKind::Track => self.track_view(ui),
            ViewerKind::Cloud | ViewerKind::Trajectory => self.cloud_view(ui),
            ViewerKind::Table => self.table(ui),
        }
        chosen
    }

    fn cloud_view(&mut self, ui: &mut egui::Ui) {
        ui.horizontal(|ui| {
            egui::ComboBox::new(("colour", self.id), "colour")
                .selected_text(match self.color_by {
                    ColorBy::Height => "by height",
                    ColorBy::Intensity => "by intensity",
                })
                .show_ui(ui, |ui| {
                    ui.selectable_value(&mut self.color_by, ColorBy::Height, "by height");
                    ui.selectable_value(&mut self.color_by, ColorBy::Intensity, "by intensity");
                });
            ui.add(egui::Slider::new(&mut self.point_size, 1.0..=6.0).text("point size"));
            if ui.button("Reset view").clicked() {
                self.camera = OrbitCamera::default();
            }
        });
        if !crate::cloud3d::available() {
            ui.colored_label(
                Color32::LIGHT_RED,
                "the 3D view needs the GPU renderer (wgpu), which this window does not have",
            );
            return;
        }
        let size = Vec2::new(ui.available_width(), (ui.available_height() - 4.0).max(160.0));
        let (rect, response) = ui.allocate_exact_size(size, egui::Sense::click_and_drag());
        self.camera.handle(&response, ui);
        ui.painter().rect_filled(rect, 0.0, Color32::from_gray(12));
        crate::cloud3d::paint(
            ui,
            rect,
            CloudCallback {
                viewer: self.id,
                cloud: Arc::clone(&self.cloud),
                view_projection: self.camera.view_projection(rect.width() / rect.height().max(1.0)),
                point_size: self.point_size,
                color_by: self.color_by,
                rect_size: rect.size(),
            },
        );
        ui.weak(format!(
            "{} points · drag to turn, right-drag to pan, scroll to zoom",
            self.cloud.points.len()
        ));
    }

    fn status(&mut self, ui: &mut egui::Ui, choices: &[(String, String)]) -> Option<(String, String)> {
        let mut chosen = None;
        ui.horizontal(|ui| {
            let fitting: Vec<&(String, String)> = choices
                .iter()
                .filter(|(output, data_type)| {
                    self.kind.overlays(data_type) && *output != self.output && !self.also.contains(output)
                })
                .collect();
            if !fitting.is_empty() {
                ui.menu_button("Draw over", |ui| {
                    for (output, data_type) in fitting {
                        if ui.button(output).clicked() {
                            chosen = Some((output.clone(), data_type.clone()));
                            ui.close();
                        }
                    }
                })
                .response
                .on_hover_text(match self.kind {
                    ViewerKind::Track => "another GNSS output's track, on the same map",
                    _ => "boxes (min x, y, z, max x, y, z) from a matrix output, in the marker colour",
                });
            }
            let label = if self.paused { "Resume" } else { "Pause" };
            if ui.button(label).clicked() {
                self.paused = !self.paused;
            }
            ui.label(format!("{} received", self.received));
            if self.skipped > 0 {
                ui.weak(format!("{} not sent (rate limit)", self.skipped))
                    .on_hover_text("the viewer gets at most 30 samples a second, always the latest");
            }
            if let Some(last) = &self.last {
                ui.weak(format!(
                    "#{} · latency {}",
                    last.sequence,
                    crate::monitor::milliseconds(last.time_of_issue_ns - last.timestamp_ns)
                ));
            }
        });
        chosen
    }

    fn image(&mut self, ui: &mut egui::Ui) {
        if let Some((image, original_width)) = self.pending_image.take() {
            let image = Arc::new(image);
            if let Some(frame) = &mut self.frame {
                frame.texture.set(Arc::clone(&image), TextureOptions::NEAREST);
                frame.pixels = image;
                frame.original_width = original_width;
            } else {
                let texture = ui.ctx().load_texture(
                    format!("viewer {}", self.id),
                    Arc::clone(&image),
                    TextureOptions::NEAREST,
                );
                self.frame = Some(Frame {
                    texture,
                    pixels: image,
                    original_width,
                });
            }
        }
        ui.horizontal(|ui| {
            let slider = egui::Slider::new(&mut self.zoom, 0.1..=8.0)
                .logarithmic(true)
                .text("zoom");
            if ui.add(slider).changed() {
                self.fit = false;
            }
            ui.checkbox(&mut self.fit, "fit")
                .on_hover_text("scale the image to the viewer's room");
        });
        if self.fit
            && let Some(frame) = &self.frame
        {
            let size = frame.texture.size_vec2();
            let room = ui.available_size();
            self.zoom = (room.x / size.x).min(room.y.max(60.0) / size.y).clamp(0.1, 8.0);
        }
        let Some(frame) = &self.frame else {
            ui.weak("waiting for an image…");
            return;
        };
        let size = frame.texture.size_vec2();
        egui::ScrollArea::both()
            .max_height(ui.available_height().max(100.0))
            .show(ui, |ui| {
                let response = ui.add(
                    egui::Image::new((frame.texture.id(), size * self.zoom)).sense(egui::Sense::hover()),
                );
                // The sample's time (UTC) and latency over the image's corner.
                if let Some(last) = &self.last {
                    let text = format!(
                        "{} UTC · latency {}",
                        time_of_day(last.timestamp_ns),
                        crate::monitor::milliseconds(last.time_of_issue_ns - last.timestamp_ns)
                    );
                    let painter = ui.painter_at(response.rect);
                    let at = response.rect.left_bottom() + Vec2::new(6.0, -6.0);
                    let galley = painter.layout_no_wrap(text, egui::FontId::monospace(12.0), Color32::WHITE);
                    let back = egui::Rect::from_min_size(
                        at - Vec2::new(3.0, galley.size().y + 2.0),
                        galley.size() + Vec2::new(6.0, 4.0),
                    );
                    painter.rect_filled(back, 3.0, Color32::from_black_alpha(170));
                    painter.galley(at - Vec2::new(0.0, galley.size().y), galley, Color32::WHITE);
                }
                if let Some(pointer) = response.hover_pos() {
                    let at = (pointer - response.rect.min) / self.zoom;
                    let (x, y) = (at.x as usize, at.y as usize);
                    let [w, h] = frame.pixels.size;
                    if x < w
                        && y < h
                        && let Some(pixel) = frame.pixels.pixels.get(y * w + x)
                    {
                        response.on_hover_text(format!(
                            "x {x}, y {y}: r {} g {} b {} a {}",
                            pixel.r(),
                            pixel.g(),
                            pixel.b(),
                            pixel.a()
                        ));
                    }
                }
            });
        let [w, h] = frame.texture.size();
        let scaled = frame
            .original_width
            .map_or_else(String::new, |o| format!(" (sent scaled down from {o} px wide)"));
        ui.weak(format!("{w}×{h}{scaled}"));
    }

    fn plot(&mut self, ui: &mut egui::Ui) {
        let latest = self
            .series
            .iter()
            .filter_map(|(_, points)| points.back().map(|p| p[0]))
            .fold(f64::NEG_INFINITY, f64::max);
        ui.horizontal_wrapped(|ui| {
            ui.add(
                egui::DragValue::new(&mut self.window_s)
                    .range(1.0..=600.0)
                    .speed(0.5)
                    .suffix(" s"),
            )
            .on_hover_text(
                "how many seconds the live plot shows; pause to scroll back through all that was kept",
            );
            ui.weak("window");
            ui.separator();
            // The legend above the plot, never over the data.
            for (index, (name, _)) in self.series.iter().enumerate() {
                ui.label(RichText::new(name).color(series_color(index)).strong());
            }
        });
        // The plot takes the room its window or dock area has.
        let height = (ui.available_height() - 4.0).max(120.0);
        let mut plot = Plot::new(("plot", self.id))
            .height(height)
            .x_axis_label("time (s)")
            .x_axis_formatter(|mark, _| format!("{:.1}", mark.value).trim_end_matches(".0").to_owned())
            .y_axis_min_width(48.0);
        let window = self.window_s;
        if !self.paused && latest.is_finite() {
            // Live: follow the last seconds; paused: pan and zoom freely through what was kept.
            plot = plot
                .include_x(latest - window)
                .include_x(latest)
                .auto_bounds(egui::Vec2b::new(false, true))
                .allow_drag(false)
                .allow_zoom(false)
                .allow_scroll(false);
        }
        let series = &self.series;
        let live = !self.paused;
        plot.show(ui, |plot_ui| {
            if live && latest.is_finite() {
                plot_ui.set_plot_bounds_x(latest - window..=latest);
            }
            for (index, (name, points)) in series.iter().enumerate() {
                // Only what the window shows, live: the rest is kept for scrolling back when paused.
                let points: PlotPoints<'_> = points
                    .iter()
                    .filter(|p| !live || p[0] >= latest - window)
                    .copied()
                    .collect();
                plot_ui.line(Line::new(name.clone(), points).color(series_color(index)));
            }
        });
    }

    fn track_view(&self, ui: &mut egui::Ui) {
        Plot::new(("track", self.id))
            .legend(Legend::default())
            .data_aspect(1.0)
            // Room for the origin's line under it.
            .height((ui.available_height() - 24.0).max(120.0))
            .x_axis_label("east, m")
            .y_axis_label("north, m")
            .show(ui, |plot_ui| {
                let points: PlotPoints<'_> = self.track.iter().copied().collect();
                plot_ui.line(Line::new(self.output.as_str(), points));
                for (index, (output, track)) in self.more_tracks.iter().enumerate() {
                    let points: PlotPoints<'_> = track.iter().copied().collect();
                    plot_ui.line(Line::new(output.as_str(), points).color(series_color(index + 1)));
                }
                if let Some(last) = self.track.last() {
                    plot_ui.points(
                        Points::new("now", vec![*last])
                            .radius(5.0)
                            .color(Color32::LIGHT_RED),
                    );
                }
            });
        if let (Some((lat, lon)), Some(last)) = (self.origin, &self.last)
            && let Some(value) = &last.value
        {
            ui.weak(format!(
                "origin {lat:.6}°, {lon:.6}° · status {}",
                value
                    .get("status")
                    .and_then(serde_json::Value::as_str)
                    .unwrap_or("?")
            ));
        }
    }

    fn table(&self, ui: &mut egui::Ui) {
        egui::ScrollArea::vertical()
            .max_height(ui.available_height().max(100.0))
            .show(ui, |ui| {
                egui::Grid::new(("table", self.id))
                    .striped(true)
                    .max_col_width(ui.available_width() * 0.6)
                    .show(ui, |ui| {
                        ui.strong("#");
                        ui.strong("timestamp (s)");
                        ui.strong("latency");
                        ui.strong("value");
                        ui.end_row();
                        for (sequence, timestamp, latency, text) in &self.rows {
                            ui.label(sequence.to_string());
                            ui.label(format!("{:.3}", *timestamp as f64 / 1e9));
                            ui.label(crate::monitor::milliseconds(*latency));
                            // Long values are cut at the dock's edge (the whole text on hover), so the table
                            // never widens the dock over the canvas.
                            ui.add(egui::Label::new(RichText::new(text).monospace()).truncate())
                                .on_hover_text(text);
                            ui.end_row();
                        }
                    });
            });
    }
}

/// The colour of a plot's series by its place.
/// The index of `name`'s entry in `list`, added empty when missing.
fn entry_of<T: Default>(list: &mut Vec<(String, T)>, name: &str) -> usize {
    list.iter().position(|(n, _)| n == name).unwrap_or_else(|| {
        list.push((name.to_owned(), T::default()));
        list.len() - 1
    })
}

fn push_bounded(track: &mut Vec<[f64; 2]>, point: [f64; 2]) {
    if track.len() == SERIES_POINTS {
        track.remove(0);
    }
    track.push(point);
}

/// Boxes from a matrix sample's value: rows of min x, y, z, max x, y, z.
fn boxes_of(value: &serde_json::Value) -> Vec<[f32; 6]> {
    let cols = value.get("cols").and_then(serde_json::Value::as_u64).unwrap_or(0);
    let Some(values) = value.get("values").and_then(serde_json::Value::as_array) else {
        return Vec::new();
    };
    if cols < 6 {
        return Vec::new();
    }
    let numbers: Vec<f32> = values
        .iter()
        .map(|v| v.as_f64().unwrap_or(f64::NAN) as f32)
        .collect();
    numbers
        .chunks_exact(cols as usize)
        .filter_map(|row| row.get(..6).and_then(|r| <[f32; 6]>::try_from(r).ok()))
        .filter(|b| b.iter().all(|v| v.is_finite()))
        .collect()
}

/// The twelve edges of a box as points 5 cm apart, in the marker colour (intensity −1).
fn box_edges(b: &[f32; 6], points: &mut Vec<[f32; 4]>) {
    let corner = |i: usize| {
        [
            if i & 1 == 0 { b[0] } else { b[3] },
            if i & 2 == 0 { b[1] } else { b[4] },
            if i & 4 == 0 { b[2] } else { b[5] },
        ]
    };
    for (a, z) in [
        (0, 1),
        (2, 3),
        (4, 5),
        (6, 7),
        (0, 2),
        (1, 3),
        (4, 6),
        (5, 7),
        (0, 4),
        (1, 5),
        (2, 6),
        (3, 7),
    ] {
        let (p, q) = (corner(a), corner(z));
        let length = ((q[0] - p[0]).powi(2) + (q[1] - p[1]).powi(2) + (q[2] - p[2]).powi(2)).sqrt();
        let steps = ((length / 0.05).ceil() as usize).clamp(1, 2000);
        for k in 0..=steps {
            let t = k as f32 / steps as f32;
            points.push([
                p[0] + (q[0] - p[0]) * t,
                p[1] + (q[1] - p[1]) * t,
                p[2] + (q[2] - p[2]) * t,
                -1.0,
            ]);
        }
    }
}

fn series_color(index: usize) -> Color32 {
    SERIES_COLORS[index % SERIES_COLORS.len()]
}

/// The dock's way of drawing viewers: a tab per viewer, closable, with Float for the one in front.
struct DockedViewers<'a> {
    list: &'a mut [Viewer],
    choices: &'a [(String, String)],
    /// An output the user chose to draw over a viewer (its index).
    chosen: Option<(usize, (String, String))>,
}

impl DockedViewers<'_> {
    fn viewer(&mut self, id: u64) -> Option<&mut Viewer> {
        self.list.iter_mut().find(|v| v.id == id)
    }
}

impl egui_tiles::Behavior<u64> for DockedViewers<'_> {
    fn pane_ui(
        &mut self,
        ui: &mut egui::Ui,
        _tile: egui_tiles::TileId,
        id: &mut u64,
    ) -> egui_tiles::UiResponse {
        let choices = self.choices;
        if let Some(index) = self.list.iter().position(|v| v.id == *id) {
            let room = ui.max_rect().shrink(4.0);
            let mut inner = ui.new_child(
                egui::UiBuilder::new()
                    .max_rect(room)
                    .id_salt(("docked viewer", *id)),
            );
            // A viewer never draws over its neighbours, whatever its area's size.
            inner.set_clip_rect(room.intersect(ui.clip_rect()));
            if let Some(choice) = self.list[index].contents(&mut inner, choices) {
                self.chosen = Some((index, choice));
            }
        }
        egui_tiles::UiResponse::None
    }

    fn tab_title_for_pane(&mut self, id: &u64) -> egui::WidgetText {
        self.list
            .iter()
            .find(|v| v.id == *id)
            .map_or_else(String::new, Viewer::title)
            .into()
    }

    fn is_tab_closable(&self, _tiles: &egui_tiles::Tiles<u64>, _tile: egui_tiles::TileId) -> bool {
        true
    }

    fn on_tab_close(&mut self, tiles: &mut egui_tiles::Tiles<u64>, tile: egui_tiles::TileId) -> bool {
        if let Some(&id) = tiles.get_pane(&tile)
            && let Some(viewer) = self.viewer(id)
        {
            viewer.open = false;
        }
        true
    }

    fn top_bar_right_ui(
        &mut self,
        tiles: &egui_tiles::Tiles<u64>,
        ui: &mut egui::Ui,
        _tile: egui_tiles::TileId,
        tabs: &egui_tiles::Tabs,
        _scroll_offset: &mut f32,
    ) {
        let Some(&id) = tabs.active.and_then(|active| tiles.get_pane(&active)) else {
            return;
        };
        if ui
            .small_button("Float")
            .on_hover_text("show it in a window of its own; drag a tab to move a viewer in the dock")
            .clicked()
            && let Some(viewer) = self.viewer(id)
        {
            viewer.docked = false;
        }
    }

    fn simplification_options(&self) -> egui_tiles::SimplificationOptions {
        crate::dock::SIMPLIFICATION
    }

    fn min_size(&self) -> f32 {
        80.0
    }
}

/// Every open viewer.
#[derive(Debug, Default)]
pub struct Viewers {
    /// The viewers, in the order they were opened.
    pub list: Vec<Viewer>,
    next_id: u64,
    changed: bool,
    /// Closed 3D viewers whose GPU buffers are still to be freed.
    closed_on_gpu: Vec<u64>,
    /// Where the docked viewers are in the dock.
    dock: crate::dock::Dock,
}

impl Viewers {
    /// Opens the usual viewer of `output` (`component.port`) for its `data_type`.
    pub fn open(&mut self, output: String, data_type: &str) {
        self.open_kind(output, ViewerKind::for_type(data_type));
    }

    /// Opens a viewer of this kind on `output`.
    pub fn open_kind(&mut self, output: String, kind: ViewerKind) {
        self.next_id += 1;
        self.list.push(Viewer::new(self.next_id, output, kind));
        self.changed = true;
    }

    /// The open viewers as a diagram saves them, in their order, the docked ones with their place in
    /// the dock.
    pub fn specs(&mut self) -> Vec<kairos_diagram::ViewerSpec> {
        self.dock.sync(&self.docked_ids());
        let areas = self.dock.areas();
        let place = |id: u64| {
            areas
                .iter()
                .enumerate()
                .find(|(_, area)| area.viewers.contains(&id))
                .map(|(index, area)| (index as u32, area.share))
        };
        self.list
            .iter()
            .filter(|v| v.open)
            .map(|v| {
                let place = if v.docked { place(v.id) } else { None };
                kairos_diagram::ViewerSpec {
                    output: v.output.clone(),
                    kind: v.kind.key().to_owned(),
                    docked: v.docked,
                    also: v.also.clone(),
                    area: place.map(|(area, _)| area),
                    share: place.map(|(_, share)| share),
                }
            })
            .collect()
    }

    /// The open docked viewers' ids, in the order they were opened.
    fn docked_ids(&self) -> Vec<u64> {
        self.list
            .iter()
            .filter(|v| v.open && v.docked)
            .map(|v| v.id)
            .collect()
    }

    /// Replaces the open viewers by those a diagram saved; returns the kinds it did not know (shown as
    /// tables).
    pub fn restore(&mut self, specs: &[kairos_diagram::ViewerSpec]) -> Vec<String> {
        for viewer in &mut self.list {
            viewer.open = false;
        }
        self.forget_closed();
        let mut unknown = Vec::new();
        // Numbered areas in the order of their numbers, then one for each docked viewer without one.
        let mut areas: BTreeMap<(bool, u32), crate::dock::Area> = BTreeMap::new();
        for (order, spec) in specs.iter().enumerate() {
            let kind = ViewerKind::from_key(&spec.kind).unwrap_or_else(|| {
                unknown.push(spec.kind.clone());
                ViewerKind::Table
            });
            self.open_kind(spec.output.clone(), kind);
            let id = self.next_id;
            if let Some(viewer) = self.list.last_mut() {
                viewer.docked = spec.docked;
                viewer.also.clone_from(&spec.also);
            }
            if spec.docked {
                let key = spec.area.map_or((true, order as u32), |area| (false, area));
                let area = areas.entry(key).or_insert_with(|| crate::dock::Area {
                    viewers: Vec::new(),
                    share: spec.share.unwrap_or(1.0),
                });
                area.viewers.push(id);
            }
        }
        self.dock.restore(areas.into_values().collect());
        self.changed = true;
        unknown
    }

    /// Whether a viewer of this kind already shows `output`.
    pub fn shows(&self, output: &str, kind: ViewerKind) -> bool {
        self.list
            .iter()
            .any(|v| v.open && v.output == output && v.kind == kind)
    }

    /// The outputs the viewers show, each once.
    pub fn outputs(&self) -> Vec<String> {
        let mut outputs: Vec<String> = self
            .list
            .iter()
            .flat_map(|v| std::iter::once(&v.output).chain(&v.also))
            .cloned()
            .collect();
        outputs.sort();
        outputs.dedup();
        outputs
    }

    /// Whether the set of outputs changed since the last call (a viewer opened or closed).
    pub fn take_changed(&mut self) -> bool {
        std::mem::take(&mut self.changed)
    }

    /// Hands a sample to every viewer of its output.
    pub fn receive(&mut self, header: &SampleHeader, payload: &[u8]) {
        for viewer in &mut self.list {
            if viewer.output == header.output {
                viewer.receive(header, payload);
            } else if viewer.also.contains(&header.output) {
                let value = header.value.clone().unwrap_or(serde_json::Value::Null);
                viewer.receive_overlay(header, &value);
            }
        }
    }

    /// Draws `output` over the viewer `index` shows, when its type fits that viewer (see
    /// [`ViewerKind::overlays`]); returns whether it does.
    pub fn add_overlay(&mut self, index: usize, output: String, data_type: &str) -> bool {
        let Some(viewer) = self.list.get_mut(index) else {
            return false;
        };
        if !viewer.kind.overlays(data_type) || viewer.output == output || viewer.also.contains(&output) {
            return false;
        }
        viewer.also.push(output);
        self.changed = true;
        true
    }

    /// Whether any viewer is docked (the studio then shows the dock).
    pub fn any_docked(&self) -> bool {
        self.list.iter().any(|v| v.docked)
    }

    /// The docked viewers in their areas, each area with a tab for each of its viewers (drag one to
    /// move it), buttons to float the viewer in front or close it, and borders to resize by.
    pub fn show_docked(&mut self, ui: &mut egui::Ui, choices: &[(String, String)]) {
        self.dock.sync(&self.docked_ids());
        let mut behavior = DockedViewers {
            list: &mut self.list,
            choices,
            chosen: None,
        };
        self.dock.show(ui, &mut behavior);
        if let Some((index, (output, data_type))) = behavior.chosen {
            self.add_overlay(index, output, &data_type);
        }
        self.forget_closed();
    }

    /// Brings the docked viewer of this kind on `output` to the front of its area (a tab behind another
    /// draws nothing).
    pub fn bring_to_front(&mut self, output: &str, kind: ViewerKind) {
        self.dock.sync(&self.docked_ids());
        if let Some(viewer) = self
            .list
            .iter()
            .find(|v| v.open && v.output == output && v.kind == kind)
        {
            self.dock.bring_to_front(viewer.id);
        }
    }

    /// The docked viewers drawn (each area's tab in front), as their outputs.
    pub fn docked_in_front(&self) -> Vec<String> {
        self.dock
            .in_front()
            .into_iter()
            .filter_map(|id| self.list.iter().find(|v| v.id == id))
            .map(|v| format!("{} {}", v.output, v.kind.key()))
            .collect()
    }

    /// The layout of the dock: each area's viewers (outputs) and share of the height, top to bottom.
    pub fn dock_areas(&mut self) -> Vec<(Vec<String>, f32)> {
        self.dock.sync(&self.docked_ids());
        let output = |id: u64| {
            self.list
                .iter()
                .find(|v| v.id == id)
                .map(|v| v.output.clone())
                .unwrap_or_default()
        };
        self.dock
            .areas()
            .into_iter()
            .map(|area| (area.viewers.into_iter().map(output).collect(), area.share))
            .collect()
    }

    /// The floating viewers, each in a window of its own.
    pub fn show_floating(&mut self, ctx: &egui::Context, choices: &[(String, String)]) {
        let screen = ctx.content_rect();
        let mut chosen = None;
        for (index, viewer) in self.list.iter_mut().enumerate().filter(|(_, v)| !v.docked) {
            let mut open = viewer.open;
            let step = (index % 8) as f32 * 32.0;
            let at = egui::pos2(screen.center().x - 240.0 + step, screen.top() + 80.0 + step);
            let mut dock = false;
            egui::Window::new(viewer.title())
                .id(egui::Id::unique(("viewer", viewer.id)))
                .open(&mut open)
                .default_pos(at)
                .default_size(Vec2::new(480.0, 360.0))
                .resizable(true)
                .show(ctx, |ui| {
                    dock = ui
                        .button("Dock")
                        .on_hover_text("put it back beside the canvas")
                        .clicked();
                    if let Some(choice) = viewer.contents(ui, choices) {
                        chosen = Some((index, choice));
                    }
                });
            viewer.open = open;
            if dock {
                viewer.docked = true;
            }
        }
        if let Some((index, (output, data_type))) = chosen {
            self.add_overlay(index, output, &data_type);
        }
        self.forget_closed();
    }

    /// The 3D viewers closed since the last call, whose GPU buffers the renderer is to free.
    pub fn take_closed_on_gpu(&mut self) -> Vec<u64> {
        std::mem::take(&mut self.closed_on_gpu)
    }

    fn forget_closed(&mut self) {
        let before = self.list.len();
        self.closed_on_gpu.extend(
            self.list
                .iter()
                .filter(|v| !v.open && matches!(v.kind, ViewerKind::Cloud | ViewerKind::Trajectory))
                .map(|v| v.id),
        );
        self.list.retain(|v| v.open);
        if self.list.len() != before {
            self.changed = true;
        }
    }
}

/// A sample as a table row reads it: text as it is (a decoded CAN frame's `Engine: Speed = 2000 rpm`), a
/// CAN frame as candump writes it, other small payloads as `name = value` fields, large ones by their size.
fn table_text(data_type: &str, value: &serde_json::Value, payload_len: usize) -> String {
    match value {
        serde_json::Value::Null => format!("{payload_len} bytes"),
        // A structured value carried as text (a ROS message Kairos has no type for) reads as its fields.
        serde_json::Value::String(text) if text.starts_with('{') => {
            match serde_json::from_str::<serde_json::Value>(text) {
                Ok(object @ serde_json::Value::Object(_)) => fields_text(&object),
                _ => text.clone(),
            }
        }
        serde_json::Value::String(text) => text.clone(),
        frame if data_type == "can_frame" => {
            let id = frame["id"].as_u64().unwrap_or(0);
            let extended = frame["extended"].as_bool().unwrap_or(false);
            let data: Vec<String> = frame["data"]
                .as_array()
                .map(|bytes| {
                    bytes
                        .iter()
                        .map(|b| format!("{:02X}", b.as_u64().unwrap_or(0)))
                        .collect()
                })
                .unwrap_or_default();
            let id = if extended {
                format!("{id:08X}")
            } else {
                format!("{id:03X}")
            };
            if frame["remote"].as_bool().unwrap_or(false) {
                return format!("{id} [{}] remote request", frame["length"].as_u64().unwrap_or(0));
            }
            let fd = if frame["fd"].as_bool().unwrap_or(false) {
                " (FD)"
            } else {
                ""
            };
            format!("{id} [{}] {}{fd}", data.len(), data.join(" "))
        }
        other => fields_text(other),
    }
}

/// How many values of a list a table cell shows before it says how many there are.
const LISTED_VALUES: usize = 8;

/// A structured value as `name = value` fields joined with `; `: what a person reads, rather than
/// JSON's braces and quotes.
fn fields_text(value: &serde_json::Value) -> String {
    let mut fields = Vec::new();
    flatten_fields("", value, &mut fields);
    fields
        .into_iter()
        .map(|(name, text)| {
            if name.is_empty() {
                text
            } else {
                format!("{name} = {text}")
            }
        })
        .collect::<Vec<_>>()
        .join("; ")
}

/// A structured value's fields as (name, value in words), nested names joined with dots
/// (`position.x`); a value that is not an object is one field with an empty name. The table viewer and
/// the inspector's status read values alike.
pub(crate) fn flatten_fields(prefix: &str, value: &serde_json::Value, into: &mut Vec<(String, String)>) {
    match value {
        serde_json::Value::Object(fields) if !fields.is_empty() => {
            for (name, field) in fields {
                let path = if prefix.is_empty() {
                    name.clone()
                } else {
                    format!("{prefix}.{name}")
                };
                flatten_fields(&path, field, into);
            }
        }
        leaf => into.push((prefix.to_owned(), scalar_text(leaf))),
    }
}

/// One value of a field: text without quotes, a list as its first values and its length.
fn scalar_text(value: &serde_json::Value) -> String {
    match value {
        serde_json::Value::Null => "none".to_owned(),
        serde_json::Value::String(text) => text.clone(),
        serde_json::Value::Array(items) => {
            let shown: Vec<String> = items.iter().take(LISTED_VALUES).map(scalar_text).collect();
            if items.len() > LISTED_VALUES {
                format!("[{}, … ({} values)]", shown.join(", "), items.len())
            } else {
                format!("[{}]", shown.join(", "))
            }
        }
        serde_json::Value::Object(fields) if fields.is_empty() => "{}".to_owned(),
        serde_json::Value::Object(_) => format!("({})", fields_text(value)),
        serde_json::Value::Number(number) => match number.as_f64() {
            Some(real) if number.is_f64() => real_text(real),
            _ => number.to_string(),
        },
        serde_json::Value::Bool(flag) => flag.to_string(),
    }
}

/// A real number to nine significant digits (a latitude to about a centimetre), without trailing zeros:
/// `150.418698` rather than `150.418697990603`.
fn real_text(value: f64) -> String {
    if !value.is_finite() || value == 0.0 {
        return value.to_string();
    }
    let magnitude = value.abs().log10().floor() as i32;
    let decimals = usize::try_from((8 - magnitude).clamp(0, 15)).unwrap_or(0);
    let text = format!("{value:.decimals$}");
    if text.contains('.') {
        text.trim_end_matches('0').trim_end_matches('.').to_owned()
    } else {
        text
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_rows_read_text_as_text_and_can_frames_as_candump_does() {
        let line = serde_json::json!("Engine: Speed = 2000 rpm; Temperature = 85 degC");
        assert_eq!(
            table_text("text", &line, 0),
            "Engine: Speed = 2000 rpm; Temperature = 85 degC"
        );
        let frame = serde_json::json!({"id": 256, "extended": false, "fd": false, "data": [64, 31, 236]});
        assert_eq!(table_text("can_frame", &frame, 0), "100 [3] 40 1F EC");
        let extended = serde_json::json!({"id": 0x18FF_0001_u32, "extended": true, "fd": false, "data": []});
        assert_eq!(table_text("can_frame", &extended, 0), "18FF0001 [0] ");
        let remote = serde_json::json!({"id": 291, "extended": false, "fd": false, "data": [], "remote": true, "length": 4});
        assert_eq!(table_text("can_frame", &remote, 0), "123 [4] remote request");
        assert_eq!(table_text("f64", &serde_json::json!(0.5), 0), "0.5");
        // A ROS message carried as JSON text reads as its fields; text that only looks like JSON stays.
        let message = serde_json::json!(r#"{"header": {"frame_id": "room"}, "temperature": 21.5}"#);
        assert_eq!(
            table_text("text", &message, 0),
            "header.frame_id = room; temperature = 21.5"
        );
        assert_eq!(
            table_text("text", &serde_json::json!("{not json"), 0),
            "{not json"
        );
        // Structured values read as fields, nested ones with dotted names, lists cut short.
        let fix =
            serde_json::json!({"latitude": 48.85, "longitude": 2.35, "quality": "rtk fixed", "hdop": null});
        assert_eq!(
            table_text("gnss_fix", &fix, 0),
            "hdop = none; latitude = 48.85; longitude = 2.35; quality = rtk fixed"
        );
        let pose = serde_json::json!({"position": {"x": 1.5, "y": -2}, "frame": "map"});
        assert_eq!(
            table_text("pose", &pose, 0),
            "frame = map; position.x = 1.5; position.y = -2"
        );
        let noisy = serde_json::json!({"altitude_m": 150.418_697_990_603, "latitude": 48.716_700_123_4, "tiny": 0.000_012_345_678_91});
        assert_eq!(
            table_text("gnss_fix", &noisy, 0),
            "altitude_m = 150.418698; latitude = 48.7167001; tiny = 0.0000123456789"
        );
        let long: Vec<u32> = (0..20).collect();
        assert_eq!(
            table_text("vector", &serde_json::json!(long), 0),
            "[0, 1, 2, 3, 4, 5, 6, 7, … (20 values)]"
        );
        assert_eq!(
            table_text("vector", &serde_json::json!([{"a": 1}, [2, 3]]), 0),
            "[(a = 1), [2, 3]]"
        );
        assert_eq!(
            table_text("image", &serde_json::Value::Null, 921_600),
            "921600 bytes"
        );
    }

    #[test]
    fn images_of_every_format_become_rgba() {
        let layout = |format: &str, stride| kairos_protocol::frame::ImageLayout {
            width: 2,
            height: 1,
            format: format.to_owned(),
            stride,
            original_width: None,
            shared: None,
        };
        let bgr = color_image(&layout("bgr8", 6), &[1, 2, 3, 4, 5, 6]);
        assert_eq!(
            bgr.map(|i| i.pixels),
            Some(vec![Color32::from_rgb(3, 2, 1), Color32::from_rgb(6, 5, 4)])
        );
        assert!(
            color_image(&layout("rgb8", 6), &[1, 2, 3]).is_none(),
            "too few bytes"
        );
        assert!(
            color_image(&layout("yuv", 6), &[0; 6]).is_none(),
            "unknown format"
        );
        // A depth frame of 1000 and 3000 mm: stretched from least to greatest, not its high byte.
        let depth = color_image(&layout("gray16", 4), &[0xE8, 0x03, 0xB8, 0x0B]);
        assert_eq!(
            depth.map(|i| i.pixels),
            Some(vec![Color32::from_gray(0), Color32::from_gray(255)])
        );
        // No return (0) stays black beside a single value.
        let sparse = color_image(&layout("gray16", 4), &[0, 0, 0x10, 0x00]);
        assert_eq!(
            sparse.map(|i| i.pixels),
            Some(vec![Color32::BLACK, Color32::from_gray(0)])
        );
    }

    fn header(output: &str, data_type: &str, value: serde_json::Value) -> SampleHeader {
        SampleHeader {
            output: output.to_owned(),
            data_type: data_type.to_owned(),
            timestamp_ns: 1,
            time_of_issue_ns: 1,
            sequence: 0,
            skipped: 0,
            value: Some(value),
            image: None,
            intensity: false,
        }
    }

    #[test]
    fn a_second_gnss_output_is_drawn_as_a_track_of_its_own_on_the_same_map() {
        let mut viewers = Viewers::default();
        viewers.open("gnss.fix".to_owned(), "gnss_fix");
        assert!(
            !viewers.add_overlay(0, "camera.image".to_owned(), "image"),
            "only fixes go on a track"
        );
        assert!(viewers.add_overlay(0, "ekf.fix".to_owned(), "gnss_fix"));
        assert!(!viewers.add_overlay(0, "ekf.fix".to_owned(), "gnss_fix"), "once");
        assert_eq!(
            viewers.outputs(),
            ["ekf.fix", "gnss.fix"],
            "both are subscribed to"
        );
        let fix = |lat: f64| serde_json::json!({"latitude_deg": lat, "longitude_deg": 2.0});
        viewers.receive(&header("gnss.fix", "gnss_fix", fix(48.0)), &[]);
        viewers.receive(&header("ekf.fix", "gnss_fix", fix(48.0001)), &[]);
        let viewer = &viewers.list[0];
        assert_eq!(viewer.track().len(), 1);
        assert_eq!(viewer.more_tracks.len(), 1);
        let north = viewer.more_tracks[0].1[0][1];
        assert!((north - 11.1).abs() < 0.1, "on the first track's plane: {north}");
    }

    #[test]
    fn boxes_from_a_matrix_are_drawn_into_the_cloud_in_the_marker_colour() {
        let mut viewers = Viewers::default();
        viewers.open("lidar.points".to_owned(), "point_cloud");
        assert!(viewers.add_overlay(0, "clusters.boxes".to_owned(), "matrix"));
        let point: Vec<u8> = [1.0_f32, 2.0, 3.0].iter().flat_map(|v| v.to_le_bytes()).collect();
        let mut cloud = header("lidar.points", "point_cloud", serde_json::Value::Null);
        cloud.value = None;
        viewers.receive(&cloud, &point);
        let boxes = serde_json::json!({"rows": 1, "cols": 6, "values": [0.0, 0.0, 0.0, 1.0, 1.0, 1.0]});
        viewers.receive(&header("clusters.boxes", "matrix", boxes), &[]);
        let drawn = &viewers.list[0].cloud.points;
        let first = drawn[0].map(|v| (v * 10.0).round() as i32);
        assert_eq!(first, [10, 20, 30, 5], "the cloud's own point first");
        let markers = drawn.iter().filter(|p| p[3] < 0.0).count();
        assert_eq!(markers, 12 * 21, "twelve edges of 1 m, a point every 5 cm");
        // A new cloud keeps the boxes until new boxes come.
        viewers.receive(&cloud, &point);
        assert_eq!(viewers.list[0].cloud.points.len(), 1 + 12 * 21);
        assert!(boxes_of(&serde_json::json!({"rows": 1, "cols": 4, "values": [0, 0, 1, 1]})).is_empty());
    }

    #[test]
    fn imu_samples_plot_six_series() {
        let value = serde_json::json!({
            "angular_velocity": [0.1, 0.2, 0.3],
            "linear_acceleration": [1.0, 2.0, 9.8],
            "orientation": null
        });
        let plotted = plotted("imu", &value);
        assert_eq!(plotted.len(), 6);
        assert_eq!(plotted[5], ("linear_acceleration.z".to_owned(), 9.8));
    }
}
