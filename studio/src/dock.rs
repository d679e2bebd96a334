//! The dock beside the canvas: the docked viewers in areas stacked top to bottom, each area holding one
//! viewer or several as tabs. Areas resize by dragging the border between them; a viewer moves by
//! dragging its tab onto another area (to share it), onto an area's edge (to split it) or out of one.
//!
//! The layout is a tile tree whose panes are viewer ids. A diagram saves it as each viewer's area
//! number and the area's share of the height: a split across (areas side by side) reopens stacked,
//! which keeps the saved form two plain numbers per viewer.

use egui_tiles::{Behavior, Container, SimplificationOptions, Tile, TileId, Tiles, Tree};

/// How the tree is tidied after each edit: every viewer keeps a tab (its title, its handle to drag),
/// and a tab dropped on a tab area joins it rather than nesting in it.
pub const SIMPLIFICATION: SimplificationOptions = SimplificationOptions {
    prune_empty_tabs: true,
    prune_single_child_tabs: true,
    prune_empty_containers: true,
    prune_single_child_containers: true,
    all_panes_must_have_tabs: true,
    join_nested_linear_containers: true,
    flatten_tabs_in_tabs: true,
};

/// One area of the dock as a diagram saves it: its viewers (tabs, in order) and its share of the height.
#[derive(Debug, Clone, PartialEq)]
pub struct Area {
    pub viewers: Vec<u64>,
    pub share: f32,
}

/// The docked viewers' layout.
#[derive(Debug)]
pub struct Dock {
    tree: Tree<u64>,
}

impl Default for Dock {
    fn default() -> Self {
        Dock {
            tree: Tree::empty(egui::Id::unique("viewer dock")),
        }
    }
}

impl Dock {
    /// Makes the dock hold exactly `shown` (viewer ids): those gone leave their areas, and each new one
    /// opens in an area of its own at the bottom.
    pub fn sync(&mut self, shown: &[u64]) {
        let gone: Vec<TileId> = self
            .tree
            .tiles
            .iter()
            .filter_map(|(tile, content)| match content {
                Tile::Pane(viewer) if !shown.contains(viewer) => Some(*tile),
                _ => None,
            })
            .collect();
        for tile in gone {
            self.tree.remove_recursively(tile);
        }
        for &viewer in shown {
            if self.tree.tiles.find_pane(&viewer).is_none() {
                self.add_area(vec![viewer], 1.0);
            }
        }
        self.tree.simplify(&SIMPLIFICATION);
    }

    /// Appends an area holding `viewers` as tabs at the bottom of the dock.
    fn add_area(&mut self, viewers: Vec<u64>, share: f32) {
        let panes: Vec<TileId> = viewers
            .into_iter()
            .map(|v| self.tree.tiles.insert_pane(v))
            .collect();
        let area = self.tree.tiles.insert_tab_tile(panes);
        let column = match self.tree.root() {
            Some(root) if is_column(&self.tree.tiles, root) => root,
            Some(root) => {
                let column = self.tree.tiles.insert_vertical_tile(vec![root]);
                self.tree.root = Some(column);
                column
            }
            None => {
                let column = self.tree.tiles.insert_vertical_tile(Vec::new());
                self.tree.root = Some(column);
                column
            }
        };
        if let Some(Tile::Container(Container::Linear(linear))) = self.tree.tiles.get_mut(column) {
            linear.add_child(area);
            linear.shares.set_share(area, share);
        }
    }

    /// Replaces the layout by `areas` (top to bottom), as a diagram saved them.
    pub fn restore(&mut self, areas: Vec<Area>) {
        self.tree = Tree::empty(egui::Id::unique("viewer dock"));
        for area in areas {
            self.add_area(area.viewers, area.share);
        }
        self.tree.simplify(&SIMPLIFICATION);
    }

    /// The areas top to bottom (an area beside another counts after it), with their shares of the
    /// height, rounded so that a saved diagram does not change with a pixel of resizing.
    pub fn areas(&self) -> Vec<Area> {
        let mut areas = Vec::new();
        let Some(root) = self.tree.root() else {
            return areas;
        };
        if let Some(Tile::Container(Container::Linear(column))) = self.tree.tiles.get(root)
            && is_column(&self.tree.tiles, root)
        {
            for &child in &column.children {
                let before = areas.len();
                collect_areas(&self.tree.tiles, child, &mut areas);
                let inside = (areas.len() - before).max(1) as f32;
                let share = column.shares[child] / inside;
                for area in &mut areas[before..] {
                    area.share = (share * 100.0).round() / 100.0;
                }
            }
        } else {
            collect_areas(&self.tree.tiles, root, &mut areas);
        }
        areas
    }

    /// Draws the dock in `ui`'s room.
    pub fn show(&mut self, ui: &mut egui::Ui, behavior: &mut dyn Behavior<u64>) {
        self.tree.ui(behavior, ui);
    }

    /// Brings `viewer`'s tab to the front of its area.
    pub fn bring_to_front(&mut self, viewer: u64) {
        if let Some(pane) = self.tree.tiles.find_pane(&viewer) {
            self.tree.make_active(|tile, _| tile == pane);
        }
    }

    /// The viewers whose tabs are in front (those being drawn).
    pub fn in_front(&self) -> Vec<u64> {
        self.tree
            .active_tiles()
            .into_iter()
            .filter_map(|tile| self.tree.tiles.get_pane(&tile).copied())
            .collect()
    }
}

fn is_column(tiles: &Tiles<u64>, tile: TileId) -> bool {
    matches!(
        tiles.get(tile),
        Some(Tile::Container(Container::Linear(linear))) if linear.dir == egui_tiles::LinearDir::Vertical
    )
}

/// The tab areas under `tile`, depth first (each with share 1 until its caller knows better).
fn collect_areas(tiles: &Tiles<u64>, tile: TileId, areas: &mut Vec<Area>) {
    match tiles.get(tile) {
        Some(Tile::Pane(viewer)) => areas.push(Area {
            viewers: vec![*viewer],
            share: 1.0,
        }),
        Some(Tile::Container(Container::Tabs(tabs))) => {
            let viewers: Vec<u64> = tabs
                .children
                .iter()
                .filter_map(|child| tiles.get_pane(child).copied())
                .collect();
            if !viewers.is_empty() {
                areas.push(Area { viewers, share: 1.0 });
            }
            // Tabs holding containers (not made by the dock, but possible by dragging) count after.
            for &child in &tabs.children {
                if matches!(tiles.get(child), Some(Tile::Container(_))) {
                    collect_areas(tiles, child, areas);
                }
            }
        }
        Some(Tile::Container(container)) => {
            for &child in container.children() {
                collect_areas(tiles, child, areas);
            }
        }
        None => {}
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn new_viewers_open_in_areas_of_their_own_at_the_bottom_and_closed_ones_leave() {
        let mut dock = Dock::default();
        dock.sync(&[1, 2, 3]);
        let ids: Vec<Vec<u64>> = dock.areas().into_iter().map(|a| a.viewers).collect();
        assert_eq!(ids, [vec![1], vec![2], vec![3]]);
        dock.sync(&[1, 3, 4]);
        let ids: Vec<Vec<u64>> = dock.areas().into_iter().map(|a| a.viewers).collect();
        assert_eq!(ids, [vec![1], vec![3], vec![4]]);
        dock.sync(&[]);
        assert!(dock.areas().is_empty());
    }

    #[test]
    fn a_saved_layout_comes_back_with_its_tabs_and_shares() {
        let mut dock = Dock::default();
        let saved = vec![
            Area {
                viewers: vec![7, 9],
                share: 1.5,
            },
            Area {
                viewers: vec![8],
                share: 0.5,
            },
        ];
        dock.restore(saved.clone());
        assert_eq!(dock.areas(), saved);
        // Syncing the same viewers changes nothing; a new one gets an area below.
        dock.sync(&[7, 8, 9]);
        assert_eq!(dock.areas(), saved);
        dock.sync(&[7, 8, 9, 10]);
        assert_eq!(dock.areas().len(), 3);
        assert_eq!(dock.areas()[2].viewers, [10]);
    }

    #[test]
    fn the_tab_in_front_is_the_one_drawn() {
        let mut dock = Dock::default();
        dock.restore(vec![Area {
            viewers: vec![1, 2],
            share: 1.0,
        }]);
        dock.bring_to_front(2);
        assert_eq!(dock.in_front(), [2]);
        dock.bring_to_front(1);
        assert_eq!(dock.in_front(), [1]);
    }
}
