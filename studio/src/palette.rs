//! The palette: the library's components by pack and category, filtered by a search, each dragged onto
//! the canvas to add it; and the viewer, dragged onto an output to watch it.

use std::collections::BTreeMap;

use kairos_diagram::{ComponentInfo, LibraryInfo};

use crate::canvas::{NewComponent, NewViewer};

/// Short words that are read letter by letter, written in capitals in readable names.
const ACRONYMS: [&str; 10] = [
    "csv", "gnss", "imu", "can", "dbc", "nmea", "rgb", "mcap", "ekf", "enu",
];

/// A component type's readable name: its last part, words spaced and the first capitalised, acronyms in
/// capitals (`core.moving_average` is "Moving average", `core.csv_writer` "CSV writer").
pub fn display_name(type_name: &str) -> String {
    let short = type_name.rsplit('.').next().unwrap_or(type_name);
    let words: Vec<String> = short
        .split('_')
        .filter(|w| !w.is_empty())
        .enumerate()
        .map(|(index, word)| {
            if ACRONYMS.contains(&word) {
                word.to_uppercase()
            } else if index == 0 {
                capitalised(word)
            } else {
                word.to_owned()
            }
        })
        .collect();
    words.join(" ")
}

fn capitalised(word: &str) -> String {
    let mut chars = word.chars();
    chars
        .next()
        .map_or_else(String::new, |first| first.to_uppercase().chain(chars).collect())
}

/// A group's header: the category, and the pack when it says something more ("Generators (core)",
/// "Sensors").
pub fn group_header(pack: &str, category: &str) -> String {
    if pack.eq_ignore_ascii_case(category) {
        capitalised(category)
    } else {
        format!("{} ({pack})", capitalised(category))
    }
}

/// What the palette's viewer entry says about itself, which its search matches.
const VIEWER_DOC: &str = "Drop on an output to watch its samples: images, plots, a GNSS track or a table, by the \
     output's type";

/// The components whose readable name, type or description contains `search` (any case), by pack and
/// category.
pub fn matching<'a>(
    library: &'a LibraryInfo,
    search: &str,
) -> BTreeMap<(String, String), Vec<&'a ComponentInfo>> {
    let needle = search.to_lowercase();
    let mut groups: BTreeMap<(String, String), Vec<&ComponentInfo>> = BTreeMap::new();
    for info in library.components.values() {
        let matches = needle.is_empty()
            || display_name(&info.type_name).to_lowercase().contains(&needle)
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

/// Whether the viewer entry answers `search`.
fn viewer_matches(search: &str) -> bool {
    let needle = search.to_lowercase();
    needle.is_empty() || "viewer".contains(&needle) || VIEWER_DOC.to_lowercase().contains(&needle)
}

/// The palette, with its search field.
pub fn palette_ui(ui: &mut egui::Ui, library: &LibraryInfo, search: &mut String) {
    ui.heading("Components");
    ui.add(egui::TextEdit::singleline(search).hint_text("search names and descriptions"));
    egui::ScrollArea::vertical().show(ui, |ui| {
        let groups = matching(library, search);
        let show_viewer = viewer_matches(search);
        if groups.is_empty() && !show_viewer {
            ui.weak(format!("Nothing matches \"{search}\"."));
        }
        for ((pack, category), mut entries) in groups {
            entries.sort_by_key(|info| display_name(&info.type_name));
            egui::CollapsingHeader::new(group_header(&pack, &category))
                .id_salt(("palette group", &pack, &category))
                .default_open(true)
                .show(ui, |ui| {
                    for info in entries {
                        let id = ui.make_persistent_id(("palette", &info.type_name));
                        let response = ui
                            .dnd_drag_source(id, NewComponent(info.type_name.clone()), |ui| {
                                ui.label(display_name(&info.type_name));
                            })
                            .response;
                        response.on_hover_text(format!("{}\n\n{}", info.type_name, info.doc));
                    }
                });
        }
        if show_viewer {
            egui::CollapsingHeader::new("Viewers (studio)")
                .default_open(true)
                .show(ui, |ui| {
                    let id = ui.make_persistent_id("palette viewer");
                    ui.dnd_drag_source(id, NewViewer, |ui| {
                        ui.label("Viewer");
                    })
                    .response
                    .on_hover_text(VIEWER_DOC);
                });
        }
    });
}

#[cfg(test)]
mod tests {
    use super::matching;

    #[test]
    fn names_are_readable_and_headers_not_doubled() {
        assert_eq!(super::display_name("core.moving_average"), "Moving average");
        assert_eq!(super::display_name("core.csv_writer"), "CSV writer");
        assert_eq!(super::display_name("sensors.gnss"), "GNSS");
        assert_eq!(super::group_header("sensors", "sensors"), "Sensors");
        assert_eq!(super::group_header("core", "generators"), "Generators (core)");
        // "viewer" answers the viewer alone, not every component whose description mentions one.
        assert!(super::viewer_matches("viewer"));
        assert!(!super::viewer_matches("sine"));
        let library = crate::library_from_components_json(include_str!("../tests/library.json")).unwrap();
        let by_name = matching(&library, "moving av");
        let types: Vec<&str> = by_name.values().flatten().map(|i| i.type_name.as_str()).collect();
        assert_eq!(types, ["core.moving_average"]);
    }

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
