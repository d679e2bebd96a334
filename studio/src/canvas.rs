//! The node editor: components as blocks with labelled, type-coloured ports, connections as curves, pan
//! and zoom, selection, moving, connecting by dragging from an output to an input, dropping components from
//! the palette. Every node, port and connection carries an accessible label (`component gain1 (core.gain)`,
//! `output sine1.out (f64)`, `connection sine1.out -> gain1.in`), so tests and screen readers find them.

use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write as _;
use std::time::{Duration, Instant};

use egui::{Align2, Color32, FontId, Pos2, Rect, Sense, Stroke, StrokeKind, Vec2, WidgetInfo};
use kairos_diagram::{ComponentInfo, Diagram, LibraryInfo, PortRef, Position};

use crate::document::Document;
use crate::monitor::{Monitor, milliseconds};

const NODE_WIDTH: f32 = 180.0;
const HEADER: f32 = 38.0;
const ROW: f32 = 20.0;
const PORT_RADIUS: f32 = 5.5;
/// Below this zoom the canvas leaves out port names, type names, policies and live figures.
const DETAIL_SCALE: f32 = 0.45;
/// The colour of lost samples.
const DROP_COLOR: Color32 = Color32::from_rgb(240, 110, 60);

/// How a component is doing, as the runtime reports it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum NodeState {
    /// Running its cycles.
    Running,
    /// Waiting (paused, idle, not started).
    Waiting(String),
    /// Its stream ended.
    Finished,
    /// Failed, with the error.
    Failed(String),
    /// The runtime refused the diagram because of this component; the problems, one per line.
    Invalid(String),
}

/// The canvas's own state between frames.
#[derive(Debug)]
pub struct Canvas {
    scene_rect: Rect,
    /// Selected components.
    pub selected: BTreeSet<String>,
    /// The selected connection, if any.
    pub selected_connection: Option<(PortRef, PortRef)>,
    pending_link: Option<PortRef>,
    drag_origin: Option<Diagram>,
    notice: Option<(String, Pos2, Instant)>,
    /// Scene to screen, as of the last frame.
    to_screen: egui::emath::TSTransform,
    /// Problems the runtime found with ports (a refused deploy), shown on them until the next deploy.
    pub port_problems: BTreeMap<PortRef, String>,
    /// A box being dragged out on the background to select what it touches (scene coordinates), and
    /// whether it adds to the selection (Shift or Ctrl held when it started).
    rubber_band: Option<(Pos2, Pos2, bool)>,
    /// An output the user asked to watch (its context menu), with its data type, until the studio takes it.
    viewer_request: Option<(PortRef, crate::viewers::ViewerKind)>,
}

impl Default for Canvas {
    fn default() -> Self {
        Canvas {
            scene_rect: Rect::from_min_size(Pos2::new(-40.0, -40.0), Vec2::new(1000.0, 700.0)),
            selected: BTreeSet::new(),
            selected_connection: None,
            pending_link: None,
            drag_origin: None,
            notice: None,
            to_screen: egui::emath::TSTransform::IDENTITY,
            port_problems: BTreeMap::new(),
            rubber_band: None,
            viewer_request: None,
        }
    }
}

/// A palette entry being dragged onto the canvas: the component type's name.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NewComponent(pub String);

/// The palette's viewer being dragged onto an output.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NewViewer;

/// Where a node's parts are, in scene coordinates.
struct Geometry {
    rect: Rect,
    inputs: Vec<(String, Pos2)>,
    outputs: Vec<(String, Pos2)>,
}

fn geometry(position: Position, info: Option<&ComponentInfo>) -> Geometry {
    let rows = info.map_or(0, |i| i.inputs.len().max(i.outputs.len()));
    let min = Pos2::new(position.x, position.y);
    let rect = Rect::from_min_size(min, Vec2::new(NODE_WIDTH, HEADER + ROW * rows as f32 + 6.0));
    let row_y = |index: usize| min.y + HEADER + ROW * (index as f32 + 0.5);
    Geometry {
        rect,
        inputs: info.map_or_else(Vec::new, |i| {
            i.inputs
                .iter()
                .enumerate()
                .map(|(n, p)| (p.name.clone(), Pos2::new(rect.left(), row_y(n))))
                .collect()
        }),
        outputs: info.map_or_else(Vec::new, |i| {
            i.outputs
                .iter()
                .enumerate()
                .map(|(n, p)| (p.name.clone(), Pos2::new(rect.right(), row_y(n))))
                .collect()
        }),
    }
}

/// A reader policy in a few letters, for connections too short for its name.
fn short_policy(policy: kairos_diagram::ReaderPolicy) -> &'static str {
    match policy {
        kairos_diagram::ReaderPolicy::Fifo => "FIFO",
        kairos_diagram::ReaderPolicy::LastOrNext => "LoN",
        kairos_diagram::ReaderPolicy::WaitForNext => "WfN",
        kairos_diagram::ReaderPolicy::Sampling => "Smp",
        kairos_diagram::ReaderPolicy::NeverSkipping => "NS",
    }
}

/// A stable colour per data type name, so a port's colour says what flows through it.
pub fn type_color(name: &str) -> Color32 {
    let hash = name.bytes().fold(2_166_136_261_u32, |h, b| {
        (h ^ u32::from(b)).wrapping_mul(16_777_619)
    });
    let hue = (hash % 360) as f32 / 360.0;
    egui::ecolor::Hsva::new(hue, 0.55, 0.85, 1.0).into()
}

fn state_color(state: Option<&NodeState>) -> Color32 {
    match state {
        Some(NodeState::Running) => Color32::from_rgb(70, 170, 90),
        Some(NodeState::Finished) => Color32::from_rgb(90, 120, 200),
        Some(NodeState::Failed(_) | NodeState::Invalid(_)) => Color32::from_rgb(210, 60, 60),
        Some(NodeState::Waiting(_)) => Color32::from_rgb(200, 170, 60),
        None => Color32::from_gray(110),
    }
}

fn edge(painter: &egui::Painter, from: Pos2, to: Pos2, stroke: Stroke) {
    let bend = ((to.x - from.x).abs() * 0.5).max(40.0);
    let shape = egui::epaint::CubicBezierShape::from_points_stroke(
        [from, from + Vec2::new(bend, 0.0), to - Vec2::new(bend, 0.0), to],
        false,
        Color32::TRANSPARENT,
        stroke,
    );
    painter.add(shape);
}

impl Canvas {
    /// Shows the canvas; edits go through `document`, each an undoable step.
    #[allow(
        clippy::too_many_lines,
        reason = "one pass over nodes, ports and edges, in paint order"
    )]
    pub fn show(
        &mut self,
        ui: &mut egui::Ui,
        document: &mut Document,
        library: &LibraryInfo,
        states: &BTreeMap<String, NodeState>,
        monitor: &Monitor,
    ) {
        // A primary drag on the background selects with a box; the middle or secondary button (or scrolling)
        // pans, as in most node editors.
        let scene = egui::Scene::new().zoom_range(0.2..=3.0).drag_pan_buttons(
            egui::containers::DragPanButtons::MIDDLE | egui::containers::DragPanButtons::SECONDARY,
        );
        let mut scene_rect = self.scene_rect;
        // Zoomed far out, small text is unreadable and costly: only ids, boxes, curves and losses are drawn.
        let detail = self.to_screen.scaling >= DETAIL_SCALE;
        let response = scene.show(ui, &mut scene_rect, |ui| {
            let painter = ui.painter().clone();
            let to_scene = ui.ctx().layer_transform_from_global(ui.layer_id());
            if let Some(to_screen) = ui.ctx().layer_transform_to_global(ui.layer_id()) {
                self.to_screen = to_screen;
            }
            let cursor = ui
                .ctx()
                .pointer_latest_pos()
                .map(|p| to_scene.map_or(p, |t| t * p));
            let diagram = document.diagram().clone();
            let geometries: BTreeMap<&str, Geometry> = diagram
                .components
                .iter()
                .map(|c| (c.id.as_str(), geometry(c.position, library.component_of(c))))
                .collect();
            let port_at = |port: &PortRef, output: bool| -> Option<Pos2> {
                let g = geometries.get(port.component.as_str())?;
                let ports = if output { &g.outputs } else { &g.inputs };
                ports.iter().find(|(name, _)| *name == port.port).map(|(_, p)| *p)
            };

            // Connections under the nodes.
            for connection in &diagram.connections {
                let (Some(from), Some(to)) =
                    (port_at(&connection.from, true), port_at(&connection.to, false))
                else {
                    continue;
                };
                let selected = self
                    .selected_connection
                    .as_ref()
                    .is_some_and(|(f, t)| f == &connection.from && t == &connection.to);
                let color = document
                    .output_type(&connection.from, library)
                    .map_or(Color32::GRAY, |t| type_color(t.name()));
                let figures = monitor.link(&connection.from, &connection.to);
                // A connection that lost samples lately turns to the warning colour and thickens.
                let dropping = figures.is_some_and(crate::monitor::LinkHistory::dropping);
                let stroke = match (dropping, selected) {
                    (true, _) => Stroke::new(4.0, DROP_COLOR),
                    (false, true) => Stroke::new(4.0, color),
                    (false, false) => Stroke::new(2.0, color),
                };
                edge(&painter, from, to, stroke);
                let policy = connection.policy.or_else(|| {
                    diagram
                        .component(&connection.to.component)
                        .and_then(|c| library.component_of(c))
                        .and_then(|i| i.input(&connection.to.port))
                        .map(|i| i.default_policy)
                });
                let middle = from + (to - from) * 0.5;
                // The policy's full name where there is room for it, its short form on short connections.
                let roomy = (to - from).length() > 130.0 || selected;
                let (text, width) = if roomy {
                    (policy.map_or("?", kairos_diagram::ReaderPolicy::name), 86.0)
                } else {
                    (policy.map_or("?", short_policy), 34.0)
                };
                let label_rect = Rect::from_center_size(middle, Vec2::new(width, 16.0));
                let label = format!("connection {} -> {}", connection.from, connection.to);
                let id = ui.make_persistent_id(("connection", &connection.from, &connection.to));
                let clicked = ui.interact(label_rect, id, Sense::click());
                clicked.widget_info(|| WidgetInfo::labeled(egui::Role::Button, true, &label));
                if clicked.clicked() {
                    self.selected_connection = Some((connection.from.clone(), connection.to.clone()));
                    self.selected.clear();
                }
                painter.rect_filled(label_rect, 4.0, ui.visuals().extreme_bg_color);
                if detail {
                    painter.text(
                        middle,
                        Align2::CENTER_CENTER,
                        text,
                        FontId::proportional(11.0),
                        color,
                    );
                }
                let hovered = clicked.hovered();
                let mut hover = String::new();
                if hovered {
                    hover = format!(
                    "{} -> {}\nreader policy: {}{}",
                    connection.from,
                    connection.to,
                    policy.map_or("?", kairos_diagram::ReaderPolicy::name),
                    if connection.policy.is_none() {
                        " (the input's default)"
                    } else {
                        ""
                    }
                    );
                }
                if let Some(figures) = figures {
                    let t = &figures.latest;
                    if detail {
                        let live = format!("{:.0} Hz · {}", t.rate_hz, milliseconds(t.latency.p50_ns));
                        painter.text(
                            label_rect.center_bottom() + Vec2::new(0.0, 2.0),
                            Align2::CENTER_TOP,
                            &live,
                            FontId::proportional(10.0),
                            ui.visuals().weak_text_color(),
                        );
                    }
                    if t.overwritten > 0 {
                        painter.text(
                            label_rect.center_bottom() + Vec2::new(0.0, 14.0),
                            Align2::CENTER_TOP,
                            format!("{} lost", t.overwritten),
                            FontId::proportional(10.5),
                            DROP_COLOR,
                        );
                    }
                    if hovered {
                        let _ = write!(
                        hover,
                        "\n{:.1} samples/s; latency p50 {}, p99 {}\nwritten {}, read {}, skipped {}, lost \
                         (overwritten unread) {}, queued {}",
                        t.rate_hz,
                        milliseconds(t.latency.p50_ns),
                        milliseconds(t.latency.p99_ns),
                        t.written,
                        t.read,
                        t.skipped,
                        t.overwritten,
                        t.queued
                    );
                    }
                }
                if hovered {
                    clicked.on_hover_text(hover);
                }
            }

            // Nodes and ports.
            let mut link_target: Option<PortRef> = None;
            let mut link_released = false;
            for component in &diagram.components {
                let Some(g) = geometries.get(component.id.as_str()) else {
                    continue;
                };
                let info = library.component_of(component);
                let node = ui.interact(
                    g.rect,
                    ui.make_persistent_id(("node", &component.id)),
                    Sense::click_and_drag(),
                );
                let label = format!("component {} ({})", component.id, component.type_name);
                node.widget_info(|| WidgetInfo::labeled(egui::Role::Button, true, &label));
                if node.clicked() {
                    if !ui.input(|i| i.modifiers.shift || i.modifiers.command) {
                        self.selected.clear();
                    }
                    self.selected.insert(component.id.clone());
                    self.selected_connection = None;
                }
                if node.drag_started() {
                    self.drag_origin = Some(diagram.clone());
                    if !self.selected.contains(&component.id) {
                        self.selected = BTreeSet::from([component.id.clone()]);
                    }
                }
                if node.dragged() {
                    let delta = node.drag_delta();
                    for id in &self.selected {
                        if let Some(c) = document.diagram().component(id) {
                            let p = c.position;
                            document.move_component(
                                id,
                                Position {
                                    x: p.x + delta.x,
                                    y: p.y + delta.y,
                                },
                            );
                        }
                    }
                }
                if node.drag_stopped()
                    && let Some(before) = self.drag_origin.take()
                {
                    document.record(before);
                }
                let selected = self.selected.contains(&component.id);
                let state = states.get(&component.id);
                let visuals = ui.visuals();
                painter.rect_filled(g.rect, 6.0, visuals.faint_bg_color);
                painter.rect_stroke(
                    g.rect,
                    6.0,
                    if selected {
                        Stroke::new(2.5, visuals.selection.stroke.color)
                    } else {
                        Stroke::new(1.0, visuals.widgets.noninteractive.bg_stroke.color)
                    },
                    StrokeKind::Inside,
                );
                let stripe = Rect::from_min_size(g.rect.min, Vec2::new(6.0, g.rect.height()));
                painter.rect_filled(stripe, 3.0, state_color(state));
                let text = visuals.text_color();
                painter.text(
                    g.rect.min + Vec2::new(12.0, 5.0),
                    Align2::LEFT_TOP,
                    &component.id,
                    FontId::proportional(14.0),
                    text,
                );
                if detail {
                    painter.text(
                        g.rect.min + Vec2::new(12.0, 22.0),
                        Align2::LEFT_TOP,
                        &component.type_name,
                        FontId::proportional(10.5),
                        visuals.weak_text_color(),
                    );
                }
                if detail && let Some(figures) = monitor.components.get(&component.id) {
                    let t = &figures.latest;
                    painter.text(
                        g.rect.right_top() + Vec2::new(-8.0, 5.0),
                        Align2::RIGHT_TOP,
                        format!("{:.0}/s · {:.0} % CPU", t.cycle_rate_hz, t.cpu_share * 100.0),
                        FontId::proportional(10.0),
                        visuals.weak_text_color(),
                    );
                }
                if let Some(NodeState::Failed(error)) = state {
                    node.clone().on_hover_text(format!("failed: {error}"));
                } else if let Some(info) = info {
                    node.clone().on_hover_text(&info.doc);
                } else {
                    node.clone()
                        .on_hover_text(format!("unknown component type {}", component.type_name));
                }
                let Some(info) = info else { continue };
                for (index, (name, at)) in g.inputs.iter().enumerate() {
                    let Some(input) = info.inputs.get(index) else {
                        continue;
                    };
                    let port = PortRef::new(&component.id, name);
                    let accepts = input.filter.to_string();
                    let hit = Rect::from_center_size(*at, Vec2::splat(PORT_RADIUS * 3.0));
                    let response = ui.interact(hit, ui.make_persistent_id(("input", &port)), Sense::click());
                    let label = format!("input {port} ({accepts})");
                    response.widget_info(|| WidgetInfo::labeled(egui::Role::Button, true, &label));
                    if let Some(problem) = self.port_problems.get(&port) {
                        let ring = Stroke::new(2.0, Color32::from_rgb(230, 90, 80));
                        painter.circle_stroke(*at, PORT_RADIUS + 3.0, ring);
                        response.on_hover_text(problem);
                    } else if response.hovered() {
                        response.on_hover_text(format!("{}: {} ({accepts})", name, input.doc));
                    }
                    let color = match &input.filter {
                        kairos_diagram::TypeFilter::OneOf(types) if types.len() == 1 => {
                            type_color(types[0].name())
                        }
                        _ => Color32::LIGHT_GRAY,
                    };
                    painter.circle_filled(*at, PORT_RADIUS, color);
                    if detail {
                        painter.text(
                            *at + Vec2::new(9.0, 0.0),
                            Align2::LEFT_CENTER,
                            name,
                            FontId::proportional(11.5),
                            text,
                        );
                    }
                    if cursor.is_some_and(|p| hit.contains(p)) {
                        link_target = Some(port);
                    }
                }
                for (name, at) in &g.outputs {
                    let port = PortRef::new(&component.id, name);
                    let data_type = document.output_type(&port, library);
                    let type_name = data_type.as_ref().map_or("?", |t| t.name()).to_owned();
                    let hit = Rect::from_center_size(*at, Vec2::splat(PORT_RADIUS * 3.0));
                    let response = ui.interact(
                        hit,
                        ui.make_persistent_id(("output", &port)),
                        Sense::click_and_drag(),
                    );
                    let label = format!("output {port} ({type_name})");
                    response.widget_info(|| WidgetInfo::labeled(egui::Role::Button, true, &label));
                    if response.drag_started() {
                        self.pending_link = Some(port.clone());
                    }
                    if let Some(problem) = self.port_problems.get(&port) {
                        let ring = Stroke::new(2.0, Color32::from_rgb(230, 90, 80));
                        painter.circle_stroke(*at, PORT_RADIUS + 3.0, ring);
                        response.clone().on_hover_text(problem);
                    }

                    if response.drag_stopped() {
                        link_released = true;
                    }
                    if response.dnd_hover_payload::<NewViewer>().is_some() {
                        let ring = Stroke::new(2.5, ui.visuals().selection.stroke.color);
                        painter.circle_stroke(*at, PORT_RADIUS + 4.0, ring);
                    }
                    if response.dnd_release_payload::<NewViewer>().is_some() {
                        self.viewer_request =
                            Some((port.clone(), crate::viewers::ViewerKind::for_type(&type_name)));
                    }
                    response.context_menu(|ui| {
                        for kind in crate::viewers::ViewerKind::choices(&type_name) {
                            if ui.button(format!("Open a viewer ({})", kind.name())).clicked() {
                                self.viewer_request = Some((port.clone(), kind));
                                ui.close();
                            }
                        }
                    });
                    painter.circle_filled(*at, PORT_RADIUS, type_color(&type_name));
                    if detail {
                        painter.text(
                            *at - Vec2::new(9.0, 0.0),
                            Align2::RIGHT_CENTER,
                            name,
                            FontId::proportional(11.5),
                            text,
                        );
                    }
                }
            }

            if let Some((start, end, _)) = self.rubber_band {
                let band = Rect::from_two_pos(start, end);
                let selection = ui.visuals().selection;
                painter.rect_filled(band, 0.0, selection.bg_fill.gamma_multiply(0.25));
                painter.rect_stroke(
                    band,
                    0.0,
                    Stroke::new(1.0, selection.stroke.color),
                    StrokeKind::Inside,
                );
            }

            // A connection being dragged out of an output.
            if let (Some(from), Some(to)) = (&self.pending_link, cursor)
                && let Some(start) = port_at(from, true)
            {
                edge(
                    &painter,
                    start,
                    to,
                    Stroke::new(2.0, ui.visuals().selection.stroke.color),
                );
            }
            if link_released
                && let Some(from) = self.pending_link.take()
                && let Some(to) = link_target
                && let Err(refusal) = document.connect(&from, &to, library)
            {
                self.notice = Some((refusal.0, cursor.unwrap_or_default(), Instant::now()));
            }
            if let Some((text, at, since)) = &self.notice {
                if since.elapsed() < Duration::from_secs(4) {
                    let rect = painter.text(
                        *at + Vec2::new(12.0, 12.0),
                        Align2::LEFT_TOP,
                        text,
                        FontId::proportional(12.0),
                        Color32::from_rgb(230, 90, 80),
                    );
                    painter.rect_stroke(
                        rect.expand(4.0),
                        4.0,
                        Stroke::new(1.0, Color32::from_rgb(230, 90, 80)),
                        StrokeKind::Outside,
                    );
                    ui.ctx().request_repaint_after(Duration::from_millis(250));
                } else {
                    self.notice = None;
                }
            }
            cursor
        });
        self.scene_rect = scene_rect;
        let background = response.response;
        if background.clicked() {
            self.selected.clear();
            self.selected_connection = None;
        }
        self.rubber_band_select(ui, &background, document, library);
        if let Some(payload) = background.dnd_release_payload::<NewComponent>()
            && let Some(info) = library.component(&payload.0)
        {
            let at = response.inner.unwrap_or_default();
            let id = document.add_component(
                info,
                library,
                Position {
                    x: at.x - NODE_WIDTH / 2.0,
                    y: at.y - 15.0,
                },
            );
            self.selected = BTreeSet::from([id]);
        }
    }

    /// Box selection: a primary drag on the background selects every node the box touches.
    fn rubber_band_select(
        &mut self,
        ui: &egui::Ui,
        background: &egui::Response,
        document: &Document,
        library: &LibraryInfo,
    ) {
        let to_scene = self.to_screen.inverse();
        if background.drag_started_by(egui::PointerButton::Primary)
            && let Some(origin) = ui.input(|i| i.pointer.press_origin())
        {
            let adds = ui.input(|i| i.modifiers.shift || i.modifiers.command);
            let start = to_scene * origin;
            self.rubber_band = Some((start, start, adds));
        }
        if let Some((start, _, adds)) = self.rubber_band
            && let Some(pointer) = ui.input(|i| i.pointer.latest_pos())
        {
            self.rubber_band = Some((start, to_scene * pointer, adds));
        }
        if background.drag_stopped()
            && let Some((start, end, adds)) = self.rubber_band.take()
        {
            let band = Rect::from_two_pos(start, end);
            if !adds {
                self.selected.clear();
            }
            self.selected_connection = None;
            for component in &document.diagram().components {
                let rect = geometry(component.position, library.component_of(component)).rect;
                if band.intersects(rect) {
                    self.selected.insert(component.id.clone());
                }
            }
        }
    }

    /// The output the user asked to open a viewer on, with the viewer's kind, if any since the last call.
    pub fn take_viewer_request(&mut self) -> Option<(PortRef, crate::viewers::ViewerKind)> {
        self.viewer_request.take()
    }

    /// Where a point of the canvas (a node's or port's accessible bounds, which are in canvas coordinates)
    /// is on the screen.
    pub fn to_screen(&self, point: Pos2) -> Pos2 {
        self.to_screen * point
    }

    /// The last refusal shown (a connection the input's filter refused), while it is shown.
    pub fn notice(&self) -> Option<&str> {
        self.notice.as_ref().map(|(text, _, _)| text.as_str())
    }

    /// Frames the whole diagram in view.
    pub fn fit(&mut self, document: &Document, library: &LibraryInfo) {
        let mut bounds = Rect::NOTHING;
        for component in &document.diagram().components {
            bounds = bounds.union(geometry(component.position, library.component_of(component)).rect);
        }
        if bounds.is_positive() {
            self.scene_rect = bounds.expand(60.0);
        }
    }
}

/// Lays the diagram out in columns by depth (sources left, sinks right), one undoable edit.
pub fn auto_layout(document: &mut Document) {
    let diagram = document.diagram().clone();
    let mut depth: BTreeMap<String, usize> = diagram.components.iter().map(|c| (c.id.clone(), 0)).collect();
    for _ in 0..diagram.components.len() {
        let mut changed = false;
        for connection in &diagram.connections {
            let from = depth.get(&connection.from.component).copied().unwrap_or(0);
            if let Some(to) = depth.get_mut(&connection.to.component)
                && *to < from + 1
                && from + 1 < diagram.components.len()
            {
                *to = from + 1;
                changed = true;
            }
        }
        if !changed {
            break;
        }
    }
    let mut rows: BTreeMap<usize, usize> = BTreeMap::new();
    document.edit(|d| {
        for component in &mut d.components {
            let column = depth.get(&component.id).copied().unwrap_or(0);
            let row = rows.entry(column).or_insert(0);
            component.position = Position {
                x: 40.0 + column as f32 * (NODE_WIDTH + 90.0),
                y: 40.0 + *row as f32 * 150.0,
            };
            *row += 1;
        }
    });
}
