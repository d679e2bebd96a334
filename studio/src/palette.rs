//! The palette: the library's components by pack and category, each dragged onto the canvas to add it, and
//! the viewer, dragged onto an output to watch it. A search lists what matches, best first.

use std::collections::BTreeMap;

use kairos_diagram::{ComponentInfo, LibraryInfo};

use crate::canvas::{NewComponent, NewViewer};

fn capitalised(word: &str) -> String {
    let mut chars = word.chars();
    chars
        .next()
        .map_or_else(String::new, |first| first.to_uppercase().chain(chars).collect())
}

/// A group's header: the category, and the pack when it says something more ("Generators (core)",
/// "Sensors", never "Sensors (sensors)").
pub fn group_header(pack: &str, category: &str) -> String {
    if pack.is_empty() {
        // Subgraphs read from the diagram's folder belong to no pack.
        format!("{} (beside the diagram)", capitalised(category))
    } else if pack.eq_ignore_ascii_case(category) {
        capitalised(category)
    } else {
        format!("{} ({pack})", capitalised(category))
    }
}

/// The viewer entry's name.
pub const VIEWER_NAME: &str = "Viewer";
/// The viewer entry's group.
const VIEWER_GROUP: &str = "Viewers (studio)";
/// What the viewer entry says about itself; its search matches this and its name, nothing else.
const VIEWER_DOC: &str = "Drop on an output to watch its samples: images, plots, a GNSS track or a table, by the \
     output's type";

/// What a palette entry adds.
#[derive(Debug, Clone, Copy)]
pub enum Entry<'a> {
    /// A component of this type.
    Component(&'a ComponentInfo),
    /// A viewer on an output.
    Viewer,
}

/// A palette entry that answers a search, and how well.
#[derive(Debug, Clone)]
pub struct Found<'a> {
    /// Lower is better: 0 the name begins with the search, 1 every word is in the name, 2 in the name or
    /// the type id, 3 somewhere in the description too.
    pub rank: u8,
    /// The readable name.
    pub name: String,
    /// The group it belongs to, as its header says.
    pub group: String,
    /// What it adds.
    pub entry: Entry<'a>,
}

/// How well `search` (any case, words in any order) matches an entry; `None` when some word is in
/// none of its name, type id and description.
fn rank(search: &str, name: &str, id: &str, doc: &str) -> Option<u8> {
    let search = search.trim().to_lowercase();
    let (name, id, doc) = (name.to_lowercase(), id.to_lowercase(), doc.to_lowercase());
    let words: Vec<&str> = search.split_whitespace().collect();
    if words.is_empty() {
        return Some(0);
    }
    if !words
        .iter()
        .all(|w| name.contains(w) || id.contains(w) || doc.contains(w))
    {
        return None;
    }
    Some(if name.starts_with(&search) {
        0
    } else if words.iter().all(|w| name.contains(w)) {
        1
    } else if words.iter().all(|w| name.contains(w) || id.contains(w)) {
        2
    } else {
        3
    })
}

/// The pack of the components that carry a connection between two hosts.
const LINK_PACK: &str = "link";

/// Every entry that answers `search`, best first, then by name.
pub fn search<'a>(library: &'a LibraryInfo, search: &str) -> Vec<Found<'a>> {
    let mut found: Vec<Found<'a>> = library
        .components
        .values()
        // The ends of links between hosts are placed by deploying, never by hand.
        .filter(|info| info.pack != LINK_PACK)
        .filter_map(|info| {
            let name = info.display_name();
            rank(search, &name, &info.type_name, &info.doc).map(|rank| Found {
                rank,
                group: group_header(&info.pack, &info.category),
                name,
                entry: Entry::Component(info),
            })
        })
        .collect();
    if let Some(rank) = rank(search, VIEWER_NAME, "viewer", VIEWER_DOC) {
        found.push(Found {
            rank,
            name: VIEWER_NAME.to_owned(),
            group: VIEWER_GROUP.to_owned(),
            entry: Entry::Viewer,
        });
    }
    found.sort_by(|a, b| (a.rank, &a.name).cmp(&(b.rank, &b.name)));
    found
}

/// The library's components by group header, each group by name; the viewer's group last.
fn grouped(library: &LibraryInfo) -> Vec<(String, Vec<Found<'_>>)> {
    let mut groups: BTreeMap<(String, String), Vec<Found<'_>>> = BTreeMap::new();
    for found in search(library, "") {
        let key = match found.entry {
            Entry::Component(info) => (info.pack.clone(), info.category.clone()),
            // After every pack's name.
            Entry::Viewer => ("\u{10FFFF}".to_owned(), String::new()),
        };
        groups.entry(key).or_default().push(found);
    }
    groups
        .into_values()
        .filter_map(|entries| Some((entries.first()?.group.clone(), entries)))
        .collect()
}

/// One entry, dragged from the palette.
fn entry_ui(ui: &mut egui::Ui, found: &Found<'_>) -> egui::Response {
    match found.entry {
        Entry::Component(info) => {
            let id = ui.make_persistent_id(("palette", &info.type_name));
            ui.dnd_drag_source(id, NewComponent(info.type_name.clone()), |ui| {
                ui.label(&found.name);
            })
            .response
            .on_hover_text(format!("{}\n\n{}", info.type_name, info.doc))
        }
        Entry::Viewer => {
            let id = ui.make_persistent_id("palette viewer");
            ui.dnd_drag_source(id, NewViewer, |ui| {
                ui.label(VIEWER_NAME);
            })
            .response
            .on_hover_text(VIEWER_DOC)
        }
    }
}

/// The palette, with its search field: groups while the search is empty, the matches best first while it
/// is not.
pub fn palette_ui(ui: &mut egui::Ui, library: &LibraryInfo, search_text: &mut String) {
    // The palette's width is the panel's, whatever the search shows: results never push the canvas.
    ui.set_max_width(ui.available_width());
    ui.heading("Components");
    ui.add(
        egui::TextEdit::singleline(search_text)
            .hint_text("search names, ids, descriptions")
            .desired_width(f32::INFINITY),
    )
    .on_hover_text("Drag a component onto the canvas; drag the viewer onto an output");
    egui::ScrollArea::vertical()
        .auto_shrink([false, true])
        .show(ui, |ui| {
            if search_text.trim().is_empty() {
                for (header, entries) in grouped(library) {
                    egui::CollapsingHeader::new(&header)
                        .id_salt(("palette group", &header))
                        .default_open(true)
                        .show(ui, |ui| {
                            for found in &entries {
                                entry_ui(ui, found);
                            }
                        });
                }
                return;
            }
            let found = search(library, search_text);
            if found.is_empty() {
                ui.weak(format!("Nothing matches \"{}\".", search_text.trim()));
            }
            for found in &found {
                ui.horizontal_wrapped(|ui| {
                    entry_ui(ui, found);
                    ui.weak(&found.group);
                });
            }
        });
}

#[cfg(test)]
mod tests {
    use super::{Entry, search};

    fn library() -> kairos_diagram::LibraryInfo {
        crate::library_from_components_json(include_str!("../tests/library.json")).unwrap()
    }

    fn names(library: &kairos_diagram::LibraryInfo, text: &str) -> Vec<String> {
        search(library, text).into_iter().map(|f| f.name).collect()
    }

    #[test]
    fn headers_are_not_doubled() {
        assert_eq!(super::group_header("sensors", "sensors"), "Sensors");
        assert_eq!(super::group_header("core", "generators"), "Generators (core)");
        let library = library();
        let headers: Vec<String> = super::grouped(&library).into_iter().map(|(h, _)| h).collect();
        assert!(headers.contains(&"Sensors".to_owned()), "{headers:?}");
        assert_eq!(headers.last().map(String::as_str), Some("Viewers (studio)"));
        let mut unique = headers.clone();
        unique.dedup();
        assert_eq!(unique, headers);
    }

    #[test]
    fn the_search_matches_names_ids_and_descriptions_best_first() {
        let library = library();
        // The name first, then what only the description mentions.
        let sine = names(&library, "sine");
        assert_eq!(sine.first().map(String::as_str), Some("Sine wave"), "{sine:?}");
        // Words in any order, any case.
        assert_eq!(names(&library, "WAVE sine"), ["Sine wave"]);
        // The type id.
        assert_eq!(names(&library, "core.moving_av"), ["Moving average"]);
        // The description alone.
        assert!(names(&library, "MCAP").contains(&"MCAP player".to_owned()));
        assert!(names(&library, "no such thing").is_empty());
        // Every component but the ends of links between hosts, which deploying places, and the viewer.
        let placeable = library
            .components
            .values()
            .filter(|c| c.pack != super::LINK_PACK)
            .count();
        assert_eq!(search(&library, "").len(), placeable + 1);
        assert!(names(&library, "link").iter().all(|name| !name.contains("host")));
    }

    #[test]
    fn the_viewer_answers_only_its_own_name_and_description() {
        let library = library();
        let viewer = |text: &str| {
            search(&library, text)
                .iter()
                .any(|f| matches!(f.entry, Entry::Viewer))
        };
        assert!(viewer("viewer") && viewer("watch"));
        assert!(!viewer("sine") && !viewer("lidar"));
        // Components whose descriptions mention viewers do not make the viewer answer, nor the viewer them.
        assert_eq!(names(&library, "viewer"), ["Viewer"]);
    }
}
