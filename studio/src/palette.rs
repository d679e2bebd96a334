//! The palette: the library's components by pack and category, filtered by a search, each dragged onto
//! the canvas to add it; and the viewer, dragged onto an output to watch it.

use std::collections::BTreeMap;

use kairos_diagram::{ComponentInfo, LibraryInfo};

use crate::canvas::{NewComponent, NewViewer};

/// The components whose type or description contains `search` (any case), by pack and category.
pub fn matching<'a>(
    library: &'a LibraryInfo,
    search: &str,
) -> BTreeMap<(String, String), Vec<&'a ComponentInfo>> {
    let needle = search.to_lowercase();
    let mut groups: BTreeMap<(String, String), Vec<&ComponentInfo>> = BTreeMap::new();
    for info in library.components.values() {
        let matches = needle.is_empty()
            || info.type_name.to_lowercase().contains(&needle)
            || info.doc.to_lowercase().contains(&needle);
        if matches {
            groups
                .entry((info.pack.clone(), info.category.clone()))
                .or_default()
                .push(info);
        }
    }
    groups
}

/// The palette, with its search field.
pub fn palette_ui(ui: &mut egui::Ui, library: &LibraryInfo, search: &mut String) {
    ui.heading("Components");
    ui.add(egui::TextEdit::singleline(search).hint_text("search"));
    egui::ScrollArea::vertical().show(ui, |ui| {
        for ((pack, category), entries) in matching(library, search) {
            egui::CollapsingHeader::new(format!("{pack} / {category}"))
                .default_open(true)
                .show(ui, |ui| {
                    for info in entries {
                        let id = ui.make_persistent_id(("palette", &info.type_name));
                        let response = ui
                            .dnd_drag_source(id, NewComponent(info.type_name.clone()), |ui| {
                                ui.label(&info.type_name);
                            })
                            .response;
                        response.on_hover_text(&info.doc);
                    }
                });
        }
        egui::CollapsingHeader::new("studio / viewers")
            .default_open(true)
            .show(ui, |ui| {
                let id = ui.make_persistent_id("palette viewer");
                ui.dnd_drag_source(id, NewViewer, |ui| {
                    ui.label("viewer");
                })
                .response
                .on_hover_text(
                    "Drop on an output to watch its samples: images, plots, a GNSS track or a table, \
                     by the output's type",
                );
            });
    });
}

#[cfg(test)]
mod tests {
    use super::matching;

    #[test]
    fn the_search_matches_types_and_descriptions_in_any_case() {
        let library = crate::library_from_components_json(include_str!("../tests/library.json")).unwrap();
        let found = matching(&library, "LIDAR");
        let types: Vec<&str> = found.values().flatten().map(|i| i.type_name.as_str()).collect();
        assert_eq!(types, ["sensors.lidar"]);
        assert!(matching(&library, "").values().flatten().count() == library.components.len());
        assert!(matching(&library, "no such thing").is_empty());
    }
}
