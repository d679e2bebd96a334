//! Where the canvas's parts are, in scene coordinates, and what lies under a point or inside a box: pure
//! functions over the diagram and the library, which the canvas's interaction uses and unit tests call.

use std::collections::BTreeMap;

use egui::{Pos2, Rect, Vec2};
use kairos_diagram::{ComponentInfo, Diagram, LibraryInfo, PortRef, Position};

/// A node's width.
pub const NODE_WIDTH: f32 = 180.0;
/// The height of a node's title (its id and type).
const HEADER: f32 = 38.0;
/// The height of one row of ports.
const ROW: f32 = 20.0;
/// A port's radius as drawn.
pub const PORT_RADIUS: f32 = 5.5;
/// A connection longer than this shows its policy's full name.
const ROOMY_CONNECTION: f32 = 130.0;

/// Which side of a node a port is on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Side {
    /// An input, on the left.
    Input,
    /// An output, on the right.
    Output,
}

/// One port of a node, and where it is.
#[derive(Debug, Clone, PartialEq)]
pub struct PortSpot {
    /// The port's name.
    pub name: String,
    /// Its centre.
    pub at: Pos2,
}

/// Where a node's parts are.
#[derive(Debug, Clone, PartialEq)]
pub struct Geometry {
    /// The node's box.
    pub rect: Rect,
    /// Its inputs, in the order the component declares them.
    pub inputs: Vec<PortSpot>,
    /// Its outputs, likewise.
    pub outputs: Vec<PortSpot>,
}

/// A node at `position` of a component described by `info` (none: an unknown type, a box with no ports).
pub fn geometry(position: Position, info: Option<&ComponentInfo>) -> Geometry {
    let rows = info.map_or(0, |i| i.inputs.len().max(i.outputs.len()));
    let min = Pos2::new(position.x, position.y);
    let rect = Rect::from_min_size(min, Vec2::new(NODE_WIDTH, HEADER + ROW * rows as f32 + 6.0));
    let row_y = |index: usize| min.y + HEADER + ROW * (index as f32 + 0.5);
    let spots = |names: Vec<&str>, x: f32| -> Vec<PortSpot> {
        names
            .into_iter()
            .enumerate()
            .map(|(n, name)| PortSpot {
                name: name.to_owned(),
                at: Pos2::new(x, row_y(n)),
            })
            .collect()
    };
    Geometry {
        rect,
        inputs: spots(
            info.map_or_else(Vec::new, |i| i.inputs.iter().map(|p| p.name.as_str()).collect()),
            rect.left(),
        ),
        outputs: spots(
            info.map_or_else(Vec::new, |i| i.outputs.iter().map(|p| p.name.as_str()).collect()),
            rect.right(),
        ),
    }
}

/// The area of a port that reacts to the pointer: larger than the dot, so it is easy to hit.
pub fn port_hit_rect(at: Pos2) -> Rect {
    Rect::from_center_size(at, Vec2::splat(PORT_RADIUS * 3.0))
}

/// Where the label of a connection from `from` to `to` sits, and whether it has room for the policy's full
/// name (a long or selected connection) rather than its short form.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PolicyLabel {
    /// The label's box, centred on the curve's middle.
    pub rect: Rect,
    /// Whether the full name is shown.
    pub full_name: bool,
}

impl PolicyLabel {
    /// The label of a connection between these points.
    pub fn between(from: Pos2, to: Pos2, selected: bool) -> PolicyLabel {
        let full_name = (to - from).length() > ROOMY_CONNECTION || selected;
        let width = if full_name { 86.0 } else { 34.0 };
        PolicyLabel {
            rect: Rect::from_center_size(from + (to - from) * 0.5, Vec2::new(width, 16.0)),
            full_name,
        }
    }
}

/// Every node of a diagram laid out, by component id.
#[derive(Debug, Clone, Default)]
pub struct Layout {
    nodes: BTreeMap<String, Geometry>,
}

impl Layout {
    /// The nodes of `diagram`, ports as `library` describes them.
    pub fn of(diagram: &Diagram, library: &LibraryInfo) -> Layout {
        Layout {
            nodes: diagram
                .components
                .iter()
                .map(|c| (c.id.clone(), geometry(c.position, library.component_of(c))))
                .collect(),
        }
    }

    /// A component's node.
    pub fn node(&self, id: &str) -> Option<&Geometry> {
        self.nodes.get(id)
    }

    /// Where a port is.
    pub fn port(&self, port: &PortRef, side: Side) -> Option<Pos2> {
        let node = self.nodes.get(&port.component)?;
        let spots = match side {
            Side::Input => &node.inputs,
            Side::Output => &node.outputs,
        };
        spots.iter().find(|s| s.name == port.port).map(|s| s.at)
    }

    /// The input whose reacting area holds `point`, if any: where a connection being dragged would end.
    pub fn input_at(&self, point: Pos2) -> Option<PortRef> {
        self.nodes.iter().find_map(|(id, node)| {
            node.inputs
                .iter()
                .find(|s| port_hit_rect(s.at).contains(point))
                .map(|s| PortRef::new(id, &s.name))
        })
    }

    /// The components whose nodes `band` touches, by id.
    pub fn touching(&self, band: Rect) -> impl Iterator<Item = &str> {
        self.nodes
            .iter()
            .filter(move |(_, node)| band.intersects(node.rect))
            .map(|(id, _)| id.as_str())
    }

    /// The box around every node; nothing when there are none.
    pub fn bounds(&self) -> Rect {
        self.nodes
            .values()
            .fold(Rect::NOTHING, |bounds, node| bounds.union(node.rect))
    }
}

#[cfg(test)]
#[allow(
    clippy::float_cmp,
    reason = "positions are sums of the same constants, exact in f32"
)]
mod tests {
    use egui::{Pos2, Rect};
    use kairos_diagram::{Diagram, LibraryInfo, PortRef};

    use super::{Layout, NODE_WIDTH, PolicyLabel, Side};

    fn library() -> LibraryInfo {
        crate::library_from_components_json(include_str!("../../tests/library.json")).unwrap()
    }

    fn diagram() -> Diagram {
        kairos_diagram::parse(
            "Diagram(format: 1, packs: [Pack(name: \"core\", version: \"^0.1\")], components: [\
             Component(id: \"sine1\", type: \"core.sine\", position: (x: 0.0, y: 0.0)), \
             Component(id: \"add1\", type: \"core.add\", position: (x: 400.0, y: 100.0))], connections: [])",
        )
        .unwrap()
        .diagram
    }

    #[test]
    fn ports_sit_on_the_nodes_edges_one_row_each() {
        let layout = Layout::of(&diagram(), &library());
        let out = layout.port(&PortRef::new("sine1", "out"), Side::Output).unwrap();
        assert_eq!(out.x, NODE_WIDTH);
        let a = layout.port(&PortRef::new("add1", "a"), Side::Input).unwrap();
        let b = layout.port(&PortRef::new("add1", "b"), Side::Input).unwrap();
        assert_eq!((a.x, b.x), (400.0, 400.0));
        assert!(b.y > a.y, "b is the row under a");
        assert_eq!(layout.port(&PortRef::new("add1", "a"), Side::Output), None);
        assert_eq!(layout.port(&PortRef::new("add1", "c"), Side::Input), None);
    }

    #[test]
    fn the_input_under_the_pointer_is_found_near_its_dot() {
        let layout = Layout::of(&diagram(), &library());
        let b = layout.port(&PortRef::new("add1", "b"), Side::Input).unwrap();
        assert_eq!(
            layout.input_at(b + egui::vec2(4.0, -4.0)),
            Some(PortRef::new("add1", "b"))
        );
        assert_eq!(layout.input_at(b + egui::vec2(40.0, 0.0)), None);
        let out = layout.port(&PortRef::new("sine1", "out"), Side::Output).unwrap();
        assert_eq!(layout.input_at(out), None, "an output is no target");
    }

    #[test]
    fn a_box_selects_the_nodes_it_touches() {
        let layout = Layout::of(&diagram(), &library());
        let band = Rect::from_two_pos(Pos2::new(-10.0, -10.0), Pos2::new(20.0, 20.0));
        assert_eq!(layout.touching(band).collect::<Vec<_>>(), ["sine1"]);
        let wide = Rect::from_two_pos(Pos2::new(-10.0, -10.0), Pos2::new(420.0, 120.0));
        assert_eq!(layout.touching(wide).collect::<Vec<_>>(), ["add1", "sine1"]);
        assert!(layout.bounds().contains(Pos2::new(500.0, 110.0)));
    }

    #[test]
    fn short_connections_get_the_short_policy_name_unless_selected() {
        let (from, to) = (Pos2::new(0.0, 0.0), Pos2::new(100.0, 0.0));
        let short = PolicyLabel::between(from, to, false);
        assert!(!short.full_name);
        assert_eq!(short.rect.center(), Pos2::new(50.0, 0.0));
        assert!(PolicyLabel::between(from, to, true).full_name);
        assert!(PolicyLabel::between(from, Pos2::new(300.0, 0.0), false).full_name);
    }
}
