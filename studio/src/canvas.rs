//! The node editor: components as blocks with labelled, type-coloured ports, connections as curves, pan
//! and zoom, selection, moving, connecting by dragging from an output to an input, dropping components from
//! the palette. Every node, port and connection carries an accessible label (`component gain1 (core.gain)`,
//! `output sine1.out (f64)`, `connection sine1.out -> gain1.in`), so tests and screen readers find them.
//!
//! Each frame is one pass in paint order: connections, then each node with its ports, then what is being
//! dragged. Per part, `interact_*` makes its widget (area, id, accessible label), the `*_ui` method turns
//! the response into selection or edits, and a `paint_*` function of [`paint`] draws it; where things are
//! and what lies under the pointer is [`hit_test`]'s, which needs no window.

pub mod hit_test;
pub mod paint;

use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write as _;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use egui::{Color32, Pos2, Rect, Sense, Stroke, Vec2, WidgetInfo};
use kairos_diagram::{
    ComponentInfo, ComponentInstance, Connection, DataType, Diagram, ExposedKind, Exposes, InputInfo,
    LibraryInfo, PortRef, Position, ReaderPolicy, Value,
};
use kairos_protocol::LinkTelemetry;

use crate::document::Document;
use crate::monitor::{Monitor, milliseconds};
use crate::session::NodeState;
use crate::viewers::ViewerKind;
use hit_test::{Layout, NODE_WIDTH, PolicyLabel, PortSpot, Side, port_hit_rect};
pub use paint::type_color;
use paint::{ConnectionLook, NodeLook, PortLook, PortRings};

/// Below this zoom the canvas leaves out port names, type names, policies and live figures.
const DETAIL_SCALE: f32 = 0.45;
/// How long a refusal stays on the canvas.
const NOTICE_SHOWN: Duration = Duration::from_secs(4);

/// A connection, by its ends.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ConnectionRef {
    /// The output it reads.
    pub from: PortRef,
    /// The input it feeds.
    pub to: PortRef,
}

impl ConnectionRef {
    /// Whether this is `connection`.
    pub fn is(&self, connection: &Connection) -> bool {
        self.from == connection.from && self.to == connection.to
    }
}

/// A box being dragged out on the background to select what it touches (scene coordinates).
#[derive(Debug, Clone, Copy, PartialEq)]
struct RubberBand {
    /// Where the drag began.
    start: Pos2,
    /// Where the pointer is.
    end: Pos2,
    /// Whether it adds to the selection (Shift or Ctrl held when it began) rather than replacing it.
    adds: bool,
}

impl RubberBand {
    fn rect(&self) -> Rect {
        Rect::from_two_pos(self.start, self.end)
    }
}

/// A refusal shown on the canvas for a while.
#[derive(Debug, Clone)]
struct Notice {
    text: String,
    /// Where it happened (scene coordinates).
    at: Pos2,
    since: Instant,
}

/// An output the user asked to watch, with the viewer's kind.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ViewerRequest {
    /// The output.
    pub output: PortRef,
    /// How to show it.
    pub kind: ViewerKind,
}

/// What the canvas shows besides the document.
#[derive(Debug, Clone, Copy)]
pub struct Shown<'a> {
    /// The component library (ports, types, default policies).
    pub library: &'a LibraryInfo,
    /// Each component's state, as the runtime reported it.
    pub states: &'a BTreeMap<String, NodeState>,
    /// Live figures.
    pub monitor: &'a Monitor,
    /// Problems the runtime found with ports.
    pub port_problems: &'a BTreeMap<PortRef, String>,
    /// What the runtime publishes to Foxglove.
    pub foxglove: &'a kairos_protocol::FoxgloveState,
}

/// What one frame of the scene works from: the diagram as the frame began, where its parts are, and
/// what else is shown.
struct Frame<'a> {
    diagram: &'a Diagram,
    layout: &'a Layout,
    shown: &'a Shown<'a>,
    painter: &'a egui::Painter,
    /// Whether there is room for small text.
    detail: bool,
    /// A connection being dragged: the output it starts from and what that output carries.
    dragging: Option<(&'a PortRef, Option<DataType>)>,
}

/// The canvas's own state between frames.
#[derive(Debug)]
pub struct Canvas {
    scene_rect: Rect,
    /// Selected components.
    pub selected: BTreeSet<String>,
    /// The selected connection, if any.
    pub selected_connection: Option<ConnectionRef>,
    /// The output a connection is being dragged from.
    pending_link: Option<PortRef>,
    /// The diagram before nodes began to be dragged: one undoable step when the drag ends.
    drag_origin: Option<Diagram>,
    notice: Option<Notice>,
    /// A refusal for the log, until the studio takes it.
    refusal_to_log: Option<String>,
    /// Scene to screen, as of the last frame.
    to_screen: egui::emath::TSTransform,
    rubber_band: Option<RubberBand>,
    /// An output the user asked to watch, until the studio takes it.
    viewer_request: Option<ViewerRequest>,
    /// A subgraph instance double-clicked: its file, as its type names it, to open.
    subgraph_request: Option<String>,
    /// An output to publish to Foxglove (true) or no longer (false), asked in its context menu.
    foxglove_request: Option<(PortRef, bool)>,
    /// A diagram file dropped on the canvas, to open.
    file_request: Option<PathBuf>,
    /// A port to expose to diagrams using this one, or no longer, asked in its context menu.
    expose_request: Option<ExposeRequest>,
    /// The size of the canvas on the screen last frame, to keep the zoom when it changes.
    view_size: Option<Vec2>,
    /// Frames left in which a fit follows the canvas's size instead of keeping the zoom: the panels
    /// around it settle their sizes over the first frames after a fit (the studio's first frames too).
    fit_frames: u8,
    /// How many nodes lay wholly outside the canvas's view last frame: said in a corner, so that a part
    /// of the diagram out of sight (a large diagram fitted at reading size, a dock that took room) is known.
    outside_view: usize,
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
            refusal_to_log: None,
            to_screen: egui::emath::TSTransform::IDENTITY,
            rubber_band: None,
            viewer_request: None,
            subgraph_request: None,
            foxglove_request: None,
            file_request: None,
            expose_request: None,
            view_size: None,
            fit_frames: 0,
            outside_view: 0,
        }
    }
}

/// The component a recording dropped on the canvas becomes.
const PLAYER: &str = "recording.player";

/// What a file dropped on the canvas is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum DroppedFile {
    /// An MCAP file, or a rosbag2 recording's folder (its `metadata.yaml` beside its files).
    Recording,
    /// A diagram (`.ron`).
    Diagram,
    Other,
}

impl DroppedFile {
    fn of(path: &std::path::Path) -> DroppedFile {
        let extension = path.extension().and_then(|e| e.to_str()).unwrap_or("");
        if extension.eq_ignore_ascii_case("mcap") || path.join("metadata.yaml").is_file() {
            DroppedFile::Recording
        } else if extension.eq_ignore_ascii_case("ron") {
            DroppedFile::Diagram
        } else {
            DroppedFile::Other
        }
    }
}

/// The least zoom a fit goes to: below it node names are hard to read.
const READABLE_ZOOM: f32 = 0.7;

/// A palette entry being dragged onto the canvas: the component type's name.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NewComponent(pub String);

/// The palette's viewer being dragged onto an output.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NewViewer;

/// A clickable area with an accessible label (the canvas's parts are buttons to screen readers and tests).
fn interact_labelled(ui: &egui::Ui, rect: Rect, id: egui::Id, sense: Sense, label: &str) -> egui::Response {
    let response = ui.interact(rect, id, sense);
    response.widget_info(|| WidgetInfo::labeled(egui::Role::Button, true, label));
    response
}

/// A connection's label, which selects it.
fn interact_connection(ui: &egui::Ui, connection: &Connection, label: Rect) -> egui::Response {
    let id = ui.make_persistent_id(("connection", &connection.from, &connection.to));
    interact_labelled(
        ui,
        label,
        id,
        Sense::click(),
        &format!("connection {} -> {}", connection.from, connection.to),
    )
}

/// A node's box, which selects and moves it.
fn interact_node(ui: &egui::Ui, component: &ComponentInstance, rect: Rect) -> egui::Response {
    let id = ui.make_persistent_id(("node", &component.id));
    interact_labelled(
        ui,
        rect,
        id,
        Sense::click_and_drag(),
        &format!("component {} ({})", component.id, component.type_name),
    )
}

/// A port's dot: an input's takes hovers, an output's starts connections and opens viewers.
fn interact_port(ui: &egui::Ui, port: &PortRef, at: Pos2, side: Side, label: &str) -> egui::Response {
    let (salt, sense) = match side {
        Side::Input => ("input", Sense::click()),
        Side::Output => ("output", Sense::click_and_drag()),
    };
    interact_labelled(
        ui,
        port_hit_rect(at),
        ui.make_persistent_id((salt, port)),
        sense,
        label,
    )
}

/// The policy a connection reads with: its own, else its input's default.
fn policy_of(connection: &Connection, diagram: &Diagram, library: &LibraryInfo) -> Option<ReaderPolicy> {
    connection.policy.or_else(|| {
        diagram
            .component(&connection.to.component)
            .and_then(|c| library.component_of(c))
            .and_then(|i| i.input(&connection.to.port))
            .map(|i| i.default_policy)
    })
}

/// A port to expose under a name to the diagrams using this one as a subgraph, or no longer (`None`).
pub type ExposeRequest = (ExposedKind, PortRef, Option<String>);

/// A port's context-menu entry: expose it to the diagrams that use this one as a subgraph (under a free
/// name, renamed in the inspector), or no longer.
fn expose_menu(
    ui: &mut egui::Ui,
    exposes: Option<&Exposes>,
    kind: ExposedKind,
    port: &PortRef,
    request: &mut Option<ExposeRequest>,
) {
    let asked = match exposes.and_then(|e| e.name_of(kind, port)) {
        Some(name) => ui
            .button(format!("Stop exposing (as '{name}')"))
            .clicked()
            .then(|| (kind, port.clone(), None)),
        None => ui
            .button(format!("Expose as the subgraph's {}", kind.name()))
            .on_hover_text(
                "Diagrams that use this one as a component (a subgraph) see this port under a name of its \
                 own: rename it in the inspector",
            )
            .clicked()
            .then(|| {
                let name = exposes.map_or_else(|| port.port.clone(), |e| e.free_name(port));
                (kind, port.clone(), Some(name))
            }),
    };
    if asked.is_some() {
        *request = asked;
        ui.close();
    }
}

/// An input: what it accepts on hover, or the runtime's problem with it; its context menu exposes it to
/// diagrams using this one as a subgraph.
fn input_ui(
    ui: &egui::Ui,
    frame: &Frame<'_>,
    component: &str,
    spot: &PortSpot,
    input: &InputInfo,
    expose_request: &mut Option<ExposeRequest>,
) {
    let port = PortRef::new(component, &spot.name);
    let accepts = input.filter.to_string();
    let response = interact_port(
        ui,
        &port,
        spot.at,
        Side::Input,
        &format!("input {port} ({accepts})"),
    );
    let problem = frame.shown.port_problems.get(&port);
    if let Some(problem) = problem {
        response.clone().on_hover_text(problem);
    } else if response.hovered() {
        response
            .clone()
            .on_hover_text(format!("{}: {} ({accepts})", spot.name, input.doc));
    }
    let exposes = frame.diagram.exposes.as_ref();
    response.context_menu(|ui| expose_menu(ui, exposes, ExposedKind::Input, &port, expose_request));
    // While a connection is dragged, each input says whether it would take it: another component's, of
    // a type it accepts, and not fed already.
    let fit = frame.dragging.as_ref().map(|(from, data_type)| {
        from.component != component
            && data_type.as_ref().is_none_or(|t| input.filter.accepts(t))
            && !frame.diagram.connections.iter().any(|c| c.to == port)
    });
    let look = PortLook {
        name: &spot.name,
        color: paint::filter_color(&input.filter),
        rings: PortRings {
            problem: problem.is_some(),
            ..PortRings::default()
        },
        fit,
        detail: frame.detail,
        exposed: exposes.and_then(|e| e.name_of(ExposedKind::Input, &port)),
    };
    paint::paint_port(frame.painter, ui.visuals(), spot.at, Side::Input, &look);
}

/// A link between hosts in a few words: its losses in transit and the age of its last sample, or that
/// its far end is missing.
fn cross_link_figures(counts: &kairos_protocol::CrossLinkTelemetry) -> String {
    if !counts.matched {
        return "not matched".to_owned();
    }
    let age = counts
        .last_sample_age_ms
        .map_or_else(String::new, |ms| format!(" · {ms} ms ago"));
    let transit = counts.transit_p50_ns.map_or_else(String::new, |ns| {
        format!(" · {:.2} ms in transit", ns as f64 * 1e-6)
    });
    format!("{} lost{transit}{age}", counts.lost)
}

/// What hovering a connection says: its ends, its policy, its figures.
fn connection_hover(
    connection: &Connection,
    policy: Option<ReaderPolicy>,
    figures: Option<&LinkTelemetry>,
) -> String {
    let mut hover = format!(
        "{} -> {}\nreader policy: {}{}",
        connection.from,
        connection.to,
        policy.map_or("?", ReaderPolicy::name),
        if connection.policy.is_none() {
            " (the input's default)"
        } else {
            ""
        }
    );
    if let Some(t) = figures {
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
    hover
}

impl Canvas {
    /// Shows the canvas; edits go through `document`, each an undoable step.
    pub fn show(&mut self, ui: &mut egui::Ui, document: &mut Document, shown: &Shown<'_>) {
        // A primary drag on the background selects with a box; the middle or secondary button (or scrolling)
        // pans, as in most node editors.
        let scene = egui::Scene::new().zoom_range(0.2..=3.0).drag_pan_buttons(
            egui::containers::DragPanButtons::MIDDLE | egui::containers::DragPanButtons::SECONDARY,
        );
        let canvas_rect = ui.available_rect_before_wrap();
        self.keep_zoom(canvas_rect.size());
        let mut scene_rect = self.scene_rect;
        // Zoomed far out, small text is unreadable and costly: only ids, boxes, curves and losses are drawn.
        let detail = self.to_screen.scaling >= DETAIL_SCALE;
        let response = scene.show(ui, &mut scene_rect, |ui| {
            self.scene_ui(ui, document, shown, detail, canvas_rect)
        });
        self.scene_rect = scene_rect;
        self.background_ui(ui, &response.response, response.inner, document, shown.library);
        self.notice_ui(ui);
        self.outside_view_ui(ui, canvas_rect);
    }

    /// In the canvas's lower right corner, how many components are out of sight and how to reach them.
    fn outside_view_ui(&self, ui: &egui::Ui, canvas: Rect) {
        if self.outside_view == 0 {
            return;
        }
        let text = if self.outside_view == 1 {
            "1 component is outside the view: scroll or drag with the right button to pan, Ctrl+\u{2212} to zoom out"
                .to_owned()
        } else {
            format!(
                "{} components are outside the view: scroll or drag with the right button to pan, Ctrl+\u{2212} to zoom out",
                self.outside_view
            )
        };
        ui.painter().text(
            canvas.right_bottom() + Vec2::new(-8.0, -6.0),
            egui::Align2::RIGHT_BOTTOM,
            text,
            egui::FontId::proportional(12.0),
            ui.visuals().weak_text_color(),
        );
    }

    /// Everything inside the zoomable scene; returns where the pointer is, in scene coordinates.
    fn scene_ui(
        &mut self,
        ui: &mut egui::Ui,
        document: &mut Document,
        shown: &Shown<'_>,
        detail: bool,
        canvas_rect: Rect,
    ) -> Option<Pos2> {
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
        let layout = Layout::of(&diagram, shown.library);
        let visible = to_scene.map_or(canvas_rect, |t| t * canvas_rect);
        self.outside_view = diagram
            .components
            .len()
            .saturating_sub(layout.touching(visible).count());
        let pending_link = self.pending_link.clone();
        let frame = Frame {
            diagram: &diagram,
            layout: &layout,
            shown,
            painter: &painter,
            detail,
            dragging: pending_link
                .as_ref()
                .map(|from| (from, document.output_type(from, shown.library))),
        };
        // Connections under the nodes.
        for connection in &diagram.connections {
            self.connection_ui(ui, &frame, document, connection);
        }
        let mut link_released = false;
        for component in &diagram.components {
            link_released |= self.node_ui(ui, &frame, document, component);
        }
        if let Some(band) = self.rubber_band {
            paint::paint_rubber_band(&painter, ui.visuals(), band.rect());
        }
        // A connection being dragged out of an output.
        if let (Some(from), Some(to)) = (&self.pending_link, cursor)
            && let Some(start) = layout.port(from, Side::Output)
        {
            paint::paint_edge(
                &painter,
                start,
                to,
                Stroke::new(2.0, ui.visuals().selection.stroke.color),
                false,
            );
        }
        if link_released
            && let Some(from) = self.pending_link.take()
            && let Some(to) = cursor.and_then(|p| layout.input_at(p))
            && let Err(refusal) = document.connect(&from, &to, shown.library)
        {
            self.refusal_to_log = Some(refusal.0.clone());
            self.notice = Some(Notice {
                text: refusal.0,
                at: cursor.unwrap_or_default(),
                since: Instant::now(),
            });
        }
        cursor
    }

    /// One connection: selected by a click on its label, described on hover, drawn with its figures.
    fn connection_ui(
        &mut self,
        ui: &egui::Ui,
        frame: &Frame<'_>,
        document: &Document,
        connection: &Connection,
    ) {
        let (Some(from), Some(to)) = (
            frame.layout.port(&connection.from, Side::Output),
            frame.layout.port(&connection.to, Side::Input),
        ) else {
            return;
        };
        let library = frame.shown.library;
        let selected = self
            .selected_connection
            .as_ref()
            .is_some_and(|s| s.is(connection));
        let label = PolicyLabel::between(from, to, selected);
        let response = interact_connection(ui, connection, label.rect);
        if response.clicked() {
            self.selected_connection = Some(ConnectionRef {
                from: connection.from.clone(),
                to: connection.to.clone(),
            });
            self.selected.clear();
        }
        let figures = frame.shown.monitor.link(&connection.from, &connection.to);
        let policy = policy_of(connection, frame.diagram, library);
        let host_of = |id: &str| frame.diagram.component(id).and_then(|c| c.host.as_deref());
        let (from_host, to_host) = (
            host_of(&connection.from.component),
            host_of(&connection.to.component),
        );
        let crossing = frame.shown.monitor.cross_link(&connection.from, &connection.to);
        let between_hosts = (from_host != to_host).then(|| {
            let hosts = format!("{} -> {}", from_host.unwrap_or("here"), to_host.unwrap_or("here"));
            match crossing {
                Some(counts) => format!("{hosts} · {}", cross_link_figures(counts)),
                None => hosts,
            }
        });
        let look = ConnectionLook {
            color: document
                .output_type(&connection.from, library)
                .map_or(Color32::GRAY, |t| type_color(t.name())),
            selected,
            label,
            policy,
            figures: figures.map(|f| &f.latest),
            dropping: figures.is_some_and(crate::monitor::LinkHistory::dropping),
            detail: frame.detail,
            between_hosts: between_hosts.as_deref(),
        };
        paint::paint_connection(frame.painter, ui.visuals(), from, to, &look);
        if response.hovered() {
            let mut hover = connection_hover(connection, policy, look.figures);
            if let Some(counts) = crossing {
                let _ = write!(
                    hover,
                    "\nbetween hosts, over Zenoh: {} sent, {} received, {} lost in transit{}{}",
                    counts.sent,
                    counts.received,
                    counts.lost,
                    match (counts.transit_p50_ns, counts.transit_max_ns) {
                        (Some(p50), Some(max)) => format!(
                            "; in transit {:.2} ms (median), {:.2} ms at most, over the last samples",
                            p50 as f64 * 1e-6,
                            max as f64 * 1e-6
                        ),
                        _ => String::new(),
                    },
                    if counts.matched {
                        ""
                    } else {
                        "; the far end is not matched"
                    }
                );
            }
            response.on_hover_text(hover);
        }
    }

    /// One node and its ports; returns whether a connection being dragged from one of its outputs was let
    /// go this frame.
    fn node_ui(
        &mut self,
        ui: &egui::Ui,
        frame: &Frame<'_>,
        document: &mut Document,
        component: &ComponentInstance,
    ) -> bool {
        let Some(node) = frame.layout.node(&component.id) else {
            return false;
        };
        let info = frame.shown.library.component_of(component);
        let response = interact_node(ui, component, node.rect);
        self.select_or_move(ui, &response, &component.id, frame.diagram, document);
        let state = frame.shown.states.get(&component.id);
        // Under the name, what the component is in words (its type id is on hover); one placed on another
        // machine says which.
        let kind = info.map_or_else(|| component.type_name.clone(), ComponentInfo::display_name);
        let subtitle = match &component.host {
            Some(host) => format!("{kind} — on {host}"),
            None => kind,
        };
        let look = NodeLook {
            id: &component.id,
            type_name: &subtitle,
            selected: self.selected.contains(&component.id),
            state,
            figures: frame
                .shown
                .monitor
                .components
                .get(&component.id)
                .map(|f| &f.latest)
                .or_else(|| frame.shown.monitor.subgraphs.get(&component.id)),
            detail: frame.detail,
            group: frame.diagram.group_of(component),
            lost_inside: frame
                .shown
                .monitor
                .lost_inside
                .get(&component.id)
                .copied()
                .unwrap_or(0),
        };
        paint::paint_node(frame.painter, ui.visuals(), node.rect, &look);
        match (state, info) {
            (Some(NodeState::Failed(error)), _) => response.on_hover_text(format!("failed: {error}")),
            // Made only while hovered: this runs for every node each frame the canvas draws.
            (_, Some(info)) => response.on_hover_ui(|ui| {
                ui.label(format!(
                    "{} ({})\n{}",
                    info.display_name(),
                    info.type_name,
                    info.doc
                ));
            }),
            (_, None) => response.on_hover_text(format!("unknown component type {}", component.type_name)),
        };
        let Some(info) = info else { return false };
        for (spot, input) in node.inputs.iter().zip(&info.inputs) {
            input_ui(ui, frame, &component.id, spot, input, &mut self.expose_request);
        }
        let mut released = false;
        for spot in &node.outputs {
            released |= self.output_ui(ui, frame, document, &component.id, spot);
        }
        released
    }

    /// A click selects the node (Shift or Ctrl adds it to the selection); a drag moves the selection, one
    /// undoable step when it ends.
    fn select_or_move(
        &mut self,
        ui: &egui::Ui,
        response: &egui::Response,
        id: &str,
        diagram: &Diagram,
        document: &mut Document,
    ) {
        if response.double_clicked()
            && let Some(c) = diagram.component(id)
            && kairos_diagram::is_subgraph_type(&c.type_name)
        {
            self.subgraph_request = Some(c.type_name.clone());
        }
        if response.clicked() {
            if !ui.input(|i| i.modifiers.shift || i.modifiers.command) {
                self.selected.clear();
            }
            self.selected.insert(id.to_owned());
            self.selected_connection = None;
        }
        if response.drag_started() {
            self.drag_origin = Some(diagram.clone());
            if !self.selected.contains(id) {
                self.selected = BTreeSet::from([id.to_owned()]);
            }
        }
        if response.dragged() {
            let delta = response.drag_delta();
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
        if response.drag_stopped()
            && let Some(before) = self.drag_origin.take()
        {
            document.record(before);
        }
    }

    /// An output: a drag starts a connection, a viewer dropped on it or its context menu opens a viewer.
    /// Returns whether a connection dragged from it was let go.
    fn output_ui(
        &mut self,
        ui: &egui::Ui,
        frame: &Frame<'_>,
        document: &Document,
        component: &str,
        spot: &PortSpot,
    ) -> bool {
        let port = PortRef::new(component, &spot.name);
        let data_type = document.output_type(&port, frame.shown.library);
        let type_name = data_type.as_ref().map_or("?", |t| t.name()).to_owned();
        let response = interact_port(
            ui,
            &port,
            spot.at,
            Side::Output,
            &format!("output {port} ({type_name})"),
        );
        if response.drag_started() {
            self.pending_link = Some(port.clone());
        }
        let problem = frame.shown.port_problems.get(&port);
        if let Some(problem) = problem {
            response.clone().on_hover_text(problem);
        }
        let released = response.drag_stopped();
        let viewer_hover = response.dnd_hover_payload::<NewViewer>().is_some();
        if response.dnd_release_payload::<NewViewer>().is_some() {
            self.viewer_request = Some(ViewerRequest {
                output: port.clone(),
                kind: ViewerKind::for_type(&type_name),
            });
        }
        let foxglove = frame.shown.foxglove;
        // Most frames publish nothing: no name is made for the comparison then.
        let published =
            foxglove.all || (!foxglove.outputs.is_empty() && foxglove.outputs.contains(&port.to_string()));
        if published && let Some(address) = &foxglove.address {
            response
                .clone()
                .on_hover_text(format!("Published to Foxglove on {address}"));
        }
        let exposes = frame.diagram.exposes.as_ref();
        response.context_menu(|ui| {
            for kind in ViewerKind::choices(&type_name) {
                if ui.button(format!("Open a viewer ({})", kind.name())).clicked() {
                    self.viewer_request = Some(ViewerRequest {
                        output: port.clone(),
                        kind,
                    });
                    ui.close();
                }
            }
            ui.separator();
            let mut published = published;
            if ui
                .checkbox(&mut published, "Publish to Foxglove")
                .on_hover_text(
                    "Send this output live to Foxglove, in the schemas recordings use. The runtime serves \
                     it on loopback; in Foxglove, open a connection (Foxglove WebSocket) to the address shown.",
                )
                .clicked()
            {
                self.foxglove_request = Some((port.clone(), published));
                ui.close();
            }
            if published && let Some(address) = &foxglove.address {
                ui.label(egui::RichText::new(address).weak());
            }
            ui.separator();
            expose_menu(ui, exposes, ExposedKind::Output, &port, &mut self.expose_request);
        });
        let look = PortLook {
            name: &spot.name,
            color: type_color(&type_name),
            rings: PortRings {
                problem: problem.is_some(),
                viewer_hover,
                published,
            },
            fit: None,
            detail: frame.detail,
            exposed: exposes.and_then(|e| e.name_of(ExposedKind::Output, &port)),
        };
        paint::paint_port(frame.painter, ui.visuals(), spot.at, Side::Output, &look);
        released
    }

    /// The last refusal, for a few seconds, where it happened but at the size of the interface's text
    /// whatever the zoom (the scene's painter would scale it with the nodes).
    fn notice_ui(&mut self, ui: &egui::Ui) {
        let Some(notice) = &self.notice else { return };
        let shown_for = notice.since.elapsed();
        if shown_for >= NOTICE_SHOWN {
            self.notice = None;
            return;
        }
        // Above the pointer, where the port's own tooltip (below it) does not cover it.
        let at = self.to_screen * notice.at + Vec2::new(14.0, -14.0);
        egui::Area::new(egui::Id::unique("canvas refusal"))
            .order(egui::Order::Foreground)
            .pivot(egui::Align2::LEFT_BOTTOM)
            .fixed_pos(at)
            .constrain_to(ui.clip_rect())
            .interactable(false)
            .show(ui.ctx(), |ui| {
                egui::Frame::popup(ui.style())
                    .stroke(Stroke::new(1.0, paint::PROBLEM_COLOR))
                    .show(ui, |ui| {
                        ui.set_max_width(360.0);
                        ui.label(egui::RichText::new(&notice.text).color(paint::PROBLEM_COLOR));
                    });
            });
        ui.ctx()
            .request_repaint_after(NOTICE_SHOWN.saturating_sub(shown_for) + Duration::from_millis(20));
    }

    /// A refusal made since the last call, for the log.
    pub fn take_refusal(&mut self) -> Option<String> {
        self.refusal_to_log.take()
    }

    /// The background: a click clears the selection, a primary drag selects with a box, a palette entry
    /// dropped adds its component where it is let go (`cursor`, in scene coordinates).
    fn background_ui(
        &mut self,
        ui: &egui::Ui,
        background: &egui::Response,
        cursor: Option<Pos2>,
        document: &mut Document,
        library: &LibraryInfo,
    ) {
        if background.clicked() {
            self.selected.clear();
            self.selected_connection = None;
        }
        self.rubber_band_select(ui, background, document, library);
        if let Some(payload) = background.dnd_release_payload::<NewComponent>()
            && let Some(info) = library.component(&payload.0)
        {
            let at = cursor.unwrap_or_default();
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
        self.files_dropped(ui, cursor, document, library);
    }

    /// Files dropped on the canvas from the desktop: a recording (an MCAP file, a rosbag2 folder) becomes
    /// a player on it where it was let go, its topics its outputs; a diagram is opened.
    fn files_dropped(
        &mut self,
        ui: &egui::Ui,
        cursor: Option<Pos2>,
        document: &mut Document,
        library: &LibraryInfo,
    ) {
        let dropped: Vec<PathBuf> = ui.input(|i| {
            i.raw
                .dropped_files
                .iter()
                .map(|f| f.path().to_path_buf())
                .collect()
        });
        let mut at = cursor.unwrap_or_else(|| self.scene_rect.center());
        for path in dropped {
            match DroppedFile::of(&path) {
                DroppedFile::Recording => {
                    let Some(info) = library.component(PLAYER) else {
                        self.refusal_to_log = Some(format!(
                            "{} is a recording, but the runtime has no {PLAYER} to replay it",
                            path.display()
                        ));
                        continue;
                    };
                    let position = Position {
                        x: at.x - NODE_WIDTH / 2.0,
                        y: at.y - 15.0,
                    };
                    let id = document.add_component(info, library, position);
                    let before = document.diagram().clone();
                    document.edit(|diagram| {
                        if let Some(player) = diagram.component_mut(&id) {
                            player
                                .properties
                                .insert("path".to_owned(), Value::Text(path.display().to_string()));
                        }
                    });
                    // Placed and pointed at its file: one step to undo.
                    document.squash_last(&before);
                    self.selected = BTreeSet::from([id]);
                    at.y += 90.0;
                }
                DroppedFile::Diagram => self.file_request = Some(path),
                DroppedFile::Other => {
                    self.refusal_to_log = Some(format!(
                        "{} was dropped: the canvas takes diagrams (.ron) and recordings (.mcap, or a \
                         rosbag2 folder)",
                        path.display()
                    ));
                }
            }
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
            let start = to_scene * origin;
            self.rubber_band = Some(RubberBand {
                start,
                end: start,
                adds: ui.input(|i| i.modifiers.shift || i.modifiers.command),
            });
        }
        if let Some(band) = &mut self.rubber_band
            && let Some(pointer) = ui.input(|i| i.pointer.latest_pos())
        {
            band.end = to_scene * pointer;
        }
        if background.drag_stopped()
            && let Some(band) = self.rubber_band.take()
        {
            if !band.adds {
                self.selected.clear();
            }
            self.selected_connection = None;
            self.selected.extend(
                Layout::of(document.diagram(), library)
                    .touching(band.rect())
                    .map(str::to_owned),
            );
        }
    }

    /// The output the user asked to open a viewer on, with the viewer's kind, if any since the last call.
    pub fn take_viewer_request(&mut self) -> Option<ViewerRequest> {
        self.viewer_request.take()
    }

    /// The subgraph file (as its instance's type names it) the user double-clicked to go inside.
    pub fn take_subgraph_request(&mut self) -> Option<String> {
        self.subgraph_request.take()
    }

    /// An output to publish to Foxglove (true) or no longer (false), if one was asked for since the last call.
    pub fn take_foxglove_request(&mut self) -> Option<(PortRef, bool)> {
        self.foxglove_request.take()
    }

    /// A diagram file dropped on the canvas, if one was since the last call.
    pub fn take_file_request(&mut self) -> Option<PathBuf> {
        self.file_request.take()
    }

    /// A port to expose (or no longer), if one was asked for since the last call.
    pub fn take_expose_request(&mut self) -> Option<ExposeRequest> {
        self.expose_request.take()
    }

    /// Where a point of the canvas (a node's or port's accessible bounds, which are in canvas coordinates)
    /// is on the screen.
    pub fn to_screen(&self, point: Pos2) -> Pos2 {
        self.to_screen * point
    }

    /// The last refusal shown (a connection the input's filter refused), while it is shown.
    pub fn notice(&self) -> Option<&str> {
        self.notice.as_ref().map(|n| n.text.as_str())
    }

    /// When the canvas's room on the screen changes (a dock opens, the log grows, the window is resized),
    /// shows more or less of the diagram at the same zoom, its top left corner in place: the scene would
    /// otherwise squeeze the same part of the diagram into the new room and make its text unreadable.
    fn keep_zoom(&mut self, size: Vec2) {
        if self.fit_frames > 0 {
            self.fit_frames -= 1;
            self.view_size = Some(size);
            // A fit never shrinks text below reading size: a large diagram shows its top left part.
            let fitted = (size.x / self.scene_rect.width()).min(size.y / self.scene_rect.height());
            if fitted.is_finite() && fitted < READABLE_ZOOM {
                self.scene_rect = Rect::from_min_size(self.scene_rect.min, size / READABLE_ZOOM);
            }
            return;
        }
        // The first sight of the canvas with nothing to fit: at full size, where a first node dropped
        // reads as the palette does.
        if self.view_size.is_none() && size.x > 0.0 && size.y > 0.0 {
            self.scene_rect = Rect::from_min_size(self.scene_rect.min, size);
        }
        if let Some(before) = self.view_size.replace(size)
            && before != size
            && before.x > 0.0
            && before.y > 0.0
        {
            let scale = Vec2::new(size.x / before.x, size.y / before.y);
            self.scene_rect = Rect::from_min_size(self.scene_rect.min, self.scene_rect.size() * scale);
        }
    }

    /// Zooms by `factor` (above 1: in) about the middle of what is shown. Text stays crisp: the scene
    /// lays it out again at the new size rather than scaling a picture of it.
    pub fn zoom_by(&mut self, factor: f32) {
        if !(factor.is_finite() && factor > 0.0) {
            return;
        }
        let zoom = self.to_screen.scaling * factor;
        if !(0.2..=3.0).contains(&zoom) {
            return;
        }
        let center = self.scene_rect.center();
        self.scene_rect = Rect::from_center_size(center, self.scene_rect.size() / factor);
    }

    /// How many components lay wholly outside the view last frame (said in the canvas's corner).
    pub fn outside_view(&self) -> usize {
        self.outside_view
    }

    /// How many screen points one unit of the diagram takes, as of the last frame.
    pub fn zoom(&self) -> f32 {
        self.to_screen.scaling
    }

    /// Frames the whole diagram in view.
    pub fn fit(&mut self, document: &Document, library: &LibraryInfo) {
        let bounds = Layout::of(document.diagram(), library).bounds();
        if bounds.is_positive() {
            self.scene_rect = bounds.expand(60.0);
            self.fit_frames = 3;
        }
    }
}

/// How much Ctrl+wheel zooms per point scrolled: a wheel's notch (40 points) zooms 10 %, as Ctrl+= does.
/// egui's own speed (1/200) zooms 22 % a notch, too coarse to land on a readable size.
pub const WHEEL_ZOOM_SPEED: f32 = 1.0 / 400.0;

/// Makes Ctrl+wheel zoom the canvas (and plots) in fine steps.
pub fn zoom_in_fine_steps(ctx: &egui::Context) {
    if ctx.options(|o| o.input_options.scroll_zoom_speed) != WHEEL_ZOOM_SPEED {
        ctx.options_mut(|o| o.input_options.scroll_zoom_speed = WHEEL_ZOOM_SPEED);
    }
}

/// Lays out a diagram whose components all sit at one place (a file written by hand or by a script,
/// with no `position`), as Tidy layout does; whether it did. One undoable edit, which a save keeps.
pub fn lay_out_if_stacked(document: &mut Document) -> bool {
    let components = &document.diagram().components;
    let stacked = components.len() > 1 && components.iter().all(|c| c.position == components[0].position);
    if stacked {
        auto_layout(document);
    }
    stacked
}

/// Lays the diagram out in columns by depth (sources left, sinks right), one undoable edit; the columns
/// leave room for a link's figures (a link between hosts says its hosts, losses, transit and age).
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
                x: 40.0 + column as f32 * (NODE_WIDTH + 170.0),
                y: 40.0 + *row as f32 * 150.0,
            };
            *row += 1;
        }
    });
}

#[cfg(test)]
mod tests {
    use super::{Document, lay_out_if_stacked};
    use kairos_diagram::{ComponentInstance, Connection, Diagram, PortRef, Position};

    fn diagram(positions: &[(f32, f32)]) -> Diagram {
        let mut diagram = Diagram::default();
        for (index, (x, y)) in positions.iter().enumerate() {
            let mut component = ComponentInstance::new(format!("c{index}"), "core.gain");
            component.position = Position { x: *x, y: *y };
            diagram.components.push(component);
        }
        diagram.connections.push(Connection::new(
            PortRef::new("c0", "out"),
            PortRef::new("c1", "in"),
        ));
        diagram
    }

    #[test]
    fn a_diagram_with_no_positions_is_laid_out_in_columns_and_one_with_positions_is_left() {
        let mut stacked = Document::unsaved(diagram(&[(0.0, 0.0); 3]));
        assert!(lay_out_if_stacked(&mut stacked));
        let components = &stacked.diagram().components;
        assert!(
            components[1].position.x > components[0].position.x,
            "c1 after its source"
        );
        assert_ne!(components[0].position, components[2].position);
        let mut placed = Document::unsaved(diagram(&[(0.0, 0.0), (300.0, 0.0), (0.0, 200.0)]));
        assert!(!lay_out_if_stacked(&mut placed));
        assert_eq!(
            placed.diagram().components[1].position,
            Position { x: 300.0, y: 0.0 }
        );
    }
}
