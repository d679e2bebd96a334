//! How the canvas draws: connections as curves with their policy and live figures, nodes with their state
//! stripe and figures, ports as type-coloured dots, the selection box, a refusal notice. Painting decides
//! nothing: what to draw comes in as arguments.

use egui::{Align2, Color32, FontId, Painter, Pos2, Rect, Stroke, StrokeKind, Vec2};
use kairos_diagram::{ReaderPolicy, TypeFilter};
use kairos_protocol::{ComponentTelemetry, LinkTelemetry};

use super::hit_test::{PORT_RADIUS, PolicyLabel};
use crate::monitor::milliseconds;
use crate::session::NodeState;

/// The colour of lost samples.
pub const DROP_COLOR: Color32 = Color32::from_rgb(240, 110, 60);
/// The colour of a problem the runtime found with a port.
pub const PROBLEM_COLOR: Color32 = Color32::from_rgb(230, 90, 80);
/// The ring of an input that would take the connection being dragged.
const FIT_COLOR: Color32 = Color32::from_rgb(110, 210, 120);
/// The ring of an output published to Foxglove.
/// The mark of a port exposed to the diagrams that use this one as a subgraph.
const EXPOSED_COLOR: Color32 = Color32::from_rgb(90, 200, 210);
const PUBLISHED_COLOR: Color32 = Color32::from_rgb(160, 120, 255);

/// A reader policy in a few letters, for connections too short for its name.
pub fn short_policy(policy: ReaderPolicy) -> &'static str {
    match policy {
        ReaderPolicy::Fifo => "FIFO",
        ReaderPolicy::LastOrNext => "LoN",
        ReaderPolicy::WaitForNext => "WfN",
        ReaderPolicy::Sampling => "Smp",
        ReaderPolicy::NeverSkipping => "NS",
    }
}

/// Text on the canvas, laid out at the size it has on the screen: the scene scales what is painted in it,
/// and text laid out at its unzoomed size would be a magnified (blurred) or shrunken picture of its glyphs.
/// The galley is laid out at `font`'s size times the zoom, then scaled back into scene units, so the
/// scene's own scaling brings it to exactly the size its glyphs were drawn at. Returns where it is, in
/// scene units.
pub fn crisp_text(
    painter: &Painter,
    pos: Pos2,
    anchor: Align2,
    text: impl ToString,
    font: FontId,
    color: Color32,
) -> Rect {
    let zoom = painter
        .ctx()
        .layer_transform_to_global(painter.layer_id())
        .map_or(1.0, |to_screen| to_screen.scaling);
    // In quarter points, so a zoom lays glyphs out at few distinct sizes (each one fills the font atlas);
    // the scale below makes up the difference.
    let size = (font.size * zoom * 4.0).round() / 4.0;
    if !(zoom.is_finite() && zoom > 0.0 && size > 0.0) || (size - font.size).abs() < 1e-3 {
        return painter.text(pos, anchor, text, font, color);
    }
    let scale = font.size / size;
    let galley = painter.layout_no_wrap(text.to_string(), FontId::new(size, font.family), color);
    let rect = anchor.anchor_size(pos, galley.size() * scale);
    let mut shape = egui::epaint::TextShape::new(rect.min, galley, color);
    // Scaled about its own corner, which stays where the anchor put it.
    shape.transform(egui::emath::TSTransform::new(
        rect.min.to_vec2() * (1.0 - scale),
        scale,
    ));
    painter.add(shape);
    rect
}

/// A stable colour per data type name, so a port's colour says what flows through it.
pub fn type_color(name: &str) -> Color32 {
    let hash = name.bytes().fold(2_166_136_261_u32, |h, b| {
        (h ^ u32::from(b)).wrapping_mul(16_777_619)
    });
    let hue = (hash % 360) as f32 / 360.0;
    egui::ecolor::Hsva::new(hue, 0.55, 0.85, 1.0).into()
}

/// An input's colour: its type's when it accepts one type only.
pub fn filter_color(filter: &TypeFilter) -> Color32 {
    match filter {
        TypeFilter::OneOf(types) => match types.as_slice() {
            [only] => type_color(only.name()),
            _ => Color32::LIGHT_GRAY,
        },
        TypeFilter::Any => Color32::LIGHT_GRAY,
    }
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

/// A connection's curve from an output to an input; dashed for one between two hosts.
pub fn paint_edge(painter: &Painter, from: Pos2, to: Pos2, stroke: Stroke, dashed: bool) {
    let bend = ((to.x - from.x).abs() * 0.5).max(40.0);
    let shape = egui::epaint::CubicBezierShape::from_points_stroke(
        [from, from + Vec2::new(bend, 0.0), to - Vec2::new(bend, 0.0), to],
        false,
        Color32::TRANSPARENT,
        stroke,
    );
    if dashed {
        let points = shape.flatten(Some(0.5));
        painter.extend(egui::Shape::dashed_line(&points, stroke, 8.0, 5.0));
    } else {
        painter.add(shape);
    }
}

/// How a connection looks this frame.
#[derive(Debug, Clone, Copy)]
pub struct ConnectionLook<'a> {
    /// Its data type's colour.
    pub color: Color32,
    /// Whether it is selected.
    pub selected: bool,
    /// Its label's place and form.
    pub label: PolicyLabel,
    /// Its policy (the connection's own or the input's default), if known.
    pub policy: Option<ReaderPolicy>,
    /// Its latest figures, when the diagram runs.
    pub figures: Option<&'a LinkTelemetry>,
    /// Whether it lost samples lately.
    pub dropping: bool,
    /// Whether there is room for small text (zoomed in enough).
    pub detail: bool,
    /// The hosts it crosses between (`car -> roadside`; `here` for the deploying machine), when they differ.
    pub between_hosts: Option<&'a str>,
}

/// A connection: its curve, its policy's label, its rate, latency and losses.
pub fn paint_connection(
    painter: &Painter,
    visuals: &egui::Visuals,
    from: Pos2,
    to: Pos2,
    look: &ConnectionLook<'_>,
) {
    // A connection that lost samples lately turns to the warning colour and thickens.
    let stroke = match (look.dropping, look.selected) {
        (true, _) => Stroke::new(4.0, DROP_COLOR),
        (false, true) => Stroke::new(4.0, look.color),
        (false, false) => Stroke::new(2.0, look.color),
    };
    paint_edge(painter, from, to, stroke, look.between_hosts.is_some());
    let label = look.label.rect;
    if let Some(hosts) = look.between_hosts.filter(|_| look.detail) {
        crisp_text(
            painter,
            label.center_top() - Vec2::new(0.0, 2.0),
            Align2::CENTER_BOTTOM,
            hosts,
            FontId::proportional(10.0),
            visuals.weak_text_color(),
        );
    }
    painter.rect_filled(label, 4.0, visuals.extreme_bg_color);
    if look.detail {
        // The policy's full name where there is room for it, its short form on short connections.
        let text = match (look.policy, look.label.full_name) {
            (None, _) => "?",
            (Some(policy), true) => policy.name(),
            (Some(policy), false) => short_policy(policy),
        };
        crisp_text(
            painter,
            label.center(),
            Align2::CENTER_CENTER,
            text,
            FontId::proportional(11.0),
            look.color,
        );
    }
    let Some(figures) = look.figures else { return };
    if look.detail {
        let live = format!(
            "{:.0} Hz · {}",
            figures.rate_hz,
            milliseconds(figures.latency.p50_ns)
        );
        crisp_text(
            painter,
            label.center_bottom() + Vec2::new(0.0, 2.0),
            Align2::CENTER_TOP,
            &live,
            FontId::proportional(10.0),
            visuals.weak_text_color(),
        );
    }
    if figures.overwritten > 0 {
        crisp_text(
            painter,
            label.center_bottom() + Vec2::new(0.0, 14.0),
            Align2::CENTER_TOP,
            format!("{} lost", figures.overwritten),
            FontId::proportional(10.5),
            DROP_COLOR,
        );
    }
}

/// How a node looks this frame.
#[derive(Debug, Clone, Copy)]
pub struct NodeLook<'a> {
    /// The component's id.
    pub id: &'a str,
    /// Its type's name.
    pub type_name: &'a str,
    /// Whether it is selected.
    pub selected: bool,
    /// Its state, when the runtime reported one.
    pub state: Option<&'a NodeState>,
    /// Its latest figures, when the diagram runs.
    pub figures: Option<&'a ComponentTelemetry>,
    /// Whether there is room for small text.
    pub detail: bool,
    /// The execution group it runs in, when it shares a thread.
    pub group: Option<&'a str>,
    /// Samples lost on the links inside it (a subgraph instance), so far.
    pub lost_inside: u64,
}

/// A node's box, state stripe, id, type and figures (its ports are painted on their own); a member of an
/// execution group is ringed in the group's colour, its name on a tab above.
pub fn paint_node(painter: &Painter, visuals: &egui::Visuals, rect: Rect, look: &NodeLook<'_>) {
    if let Some(group) = look.group {
        let color = type_color(group);
        painter.rect_stroke(
            rect.expand(3.0),
            8.0,
            Stroke::new(2.0, color),
            StrokeKind::Outside,
        );
        if look.detail {
            crisp_text(
                painter,
                rect.right_top() + Vec2::new(-8.0, -4.0),
                Align2::RIGHT_BOTTOM,
                group,
                FontId::proportional(10.0),
                color,
            );
        }
    }
    painter.rect_filled(rect, 6.0, visuals.faint_bg_color);
    painter.rect_stroke(
        rect,
        6.0,
        if look.selected {
            Stroke::new(2.5, visuals.selection.stroke.color)
        } else {
            Stroke::new(1.0, visuals.widgets.noninteractive.bg_stroke.color)
        },
        StrokeKind::Inside,
    );
    let stripe = Rect::from_min_size(rect.min, Vec2::new(6.0, rect.height()));
    painter.rect_filled(stripe, 3.0, state_color(look.state));
    crisp_text(
        painter,
        rect.min + Vec2::new(12.0, 5.0),
        Align2::LEFT_TOP,
        look.id,
        FontId::proportional(14.0),
        visuals.text_color(),
    );
    if !look.detail {
        return;
    }
    crisp_text(
        painter,
        rect.min + Vec2::new(12.0, 22.0),
        Align2::LEFT_TOP,
        look.type_name,
        FontId::proportional(10.5),
        visuals.weak_text_color(),
    );
    if let Some(figures) = look.figures {
        crisp_text(
            painter,
            rect.right_top() + Vec2::new(-8.0, 5.0),
            Align2::RIGHT_TOP,
            if look.lost_inside > 0 {
                format!(
                    "{:.0}/s · {:.0} % CPU · {} lost inside",
                    figures.cycle_rate_hz,
                    figures.cpu_share * 100.0,
                    look.lost_inside
                )
            } else {
                format!(
                    "{:.0}/s · {:.0} % CPU",
                    figures.cycle_rate_hz,
                    figures.cpu_share * 100.0
                )
            },
            FontId::proportional(10.0),
            visuals.weak_text_color(),
        );
    }
}

/// How a port looks this frame.
#[derive(Debug, Clone, Copy)]
pub struct PortLook<'a> {
    /// Its name.
    pub name: &'a str,
    /// Its dot's colour.
    pub color: Color32,
    /// The rings around its dot.
    pub rings: PortRings,
    /// While a connection is dragged: whether this input would take it (highlighted) or not (dimmed).
    pub fit: Option<bool>,
    /// Whether there is room for its name.
    pub detail: bool,
    /// The name it is exposed under to diagrams using this one as a subgraph, if it is.
    pub exposed: Option<&'a str>,
}

/// What a port's rings say.
#[derive(Debug, Clone, Copy, Default)]
pub struct PortRings {
    /// The runtime found a problem with it.
    pub problem: bool,
    /// A viewer being dragged from the palette hovers it.
    pub viewer_hover: bool,
    /// The output is published live to Foxglove.
    pub published: bool,
}

/// A port's dot, its name inside the node (right of an input, left of an output) and its rings.
pub fn paint_port(
    painter: &Painter,
    visuals: &egui::Visuals,
    at: Pos2,
    side: super::hit_test::Side,
    look: &PortLook<'_>,
) {
    if look.rings.problem {
        painter.circle_stroke(at, PORT_RADIUS + 3.0, Stroke::new(2.0, PROBLEM_COLOR));
    }
    if look.rings.published {
        painter.circle_stroke(at, PORT_RADIUS + 5.5, Stroke::new(1.5, PUBLISHED_COLOR));
    }
    if look.rings.viewer_hover {
        painter.circle_stroke(
            at,
            PORT_RADIUS + 4.0,
            Stroke::new(2.5, visuals.selection.stroke.color),
        );
    }
    let color = match look.fit {
        Some(true) => {
            painter.circle_stroke(at, PORT_RADIUS + 4.0, Stroke::new(2.5, FIT_COLOR));
            look.color
        }
        Some(false) => look.color.gamma_multiply(0.25),
        None => look.color,
    };
    painter.circle_filled(at, PORT_RADIUS, color);
    if let Some(exposed) = look.exposed {
        paint_exposed(painter, at, side, exposed, look.detail);
    }
    if look.detail {
        let (offset, align) = match side {
            super::hit_test::Side::Input => (Vec2::new(9.0, 0.0), Align2::LEFT_CENTER),
            super::hit_test::Side::Output => (Vec2::new(-9.0, 0.0), Align2::RIGHT_CENTER),
        };
        crisp_text(
            painter,
            at + offset,
            align,
            look.name,
            FontId::proportional(11.5),
            if look.fit == Some(false) {
                visuals.weak_text_color().gamma_multiply(0.5)
            } else {
                visuals.text_color()
            },
        );
    }
}

/// An exposed port's mark outside its node: an arrow into an input from the left, out of an output to
/// the right, with the name diagrams using this one see.
fn paint_exposed(painter: &Painter, at: Pos2, side: super::hit_test::Side, name: &str, detail: bool) {
    let (tip, direction, align) = match side {
        super::hit_test::Side::Input => (at - Vec2::new(PORT_RADIUS + 3.0, 0.0), -1.0, Align2::RIGHT_CENTER),
        super::hit_test::Side::Output => (at + Vec2::new(PORT_RADIUS + 14.0, 0.0), 1.0, Align2::LEFT_CENTER),
    };
    // A triangle pointing right: into the input, out of the output.
    let back = tip - Vec2::new(9.0, 0.0);
    painter.add(egui::Shape::convex_polygon(
        vec![tip, back + Vec2::new(0.0, -5.0), back + Vec2::new(0.0, 5.0)],
        EXPOSED_COLOR,
        Stroke::NONE,
    ));
    if detail {
        let label_at = match side {
            super::hit_test::Side::Input => back,
            super::hit_test::Side::Output => tip,
        } + Vec2::new(3.0 * direction, 0.0);
        crisp_text(
            painter,
            label_at,
            align,
            name,
            FontId::proportional(11.0),
            EXPOSED_COLOR,
        );
    }
}

/// The selection box being dragged out.
pub fn paint_rubber_band(painter: &Painter, visuals: &egui::Visuals, band: Rect) {
    let selection = visuals.selection;
    painter.rect_filled(band, 0.0, selection.bg_fill.gamma_multiply(0.25));
    painter.rect_stroke(
        band,
        0.0,
        Stroke::new(1.0, selection.stroke.color),
        StrokeKind::Inside,
    );
}
