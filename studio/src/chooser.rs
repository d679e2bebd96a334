//! The studio's file chooser: one dialog for opening and saving diagrams and for path properties. It walks
//! folders, lists what can be picked, and always takes a typed name or path too (a file to be written does
//! not exist yet; a path is often quicker typed than found).

use std::path::{Path, PathBuf};

/// What the chosen file is for.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Purpose {
    /// A diagram to open: must exist.
    OpenDiagram,
    /// Where to save the diagram: `.ron` is added when no extension is typed.
    SaveDiagram,
    /// Where to write these components as a subgraph (a new file): `.ron` is added as for a diagram.
    MakeSubgraph(Vec<String>),
    /// A path property of a component.
    Property {
        /// The component's id.
        component: String,
        /// The property's name.
        property: String,
    },
}

/// Why a typed name is not a file the dialog can take; said under it.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
enum PathRefused {
    /// Nothing typed or picked.
    #[error("type a file name or pick a file")]
    Empty,
    /// A diagram to open that is not there.
    #[error("{} does not exist", .0.display())]
    Missing(PathBuf),
    /// A folder where a file to write was expected.
    #[error("{} is a folder; type a file name", .0.display())]
    Folder(PathBuf),
    /// A file in a folder that is not there.
    #[error("the folder {} does not exist", .0.display())]
    NoFolder(PathBuf),
    /// A subgraph goes into a new file: one that exists may be another diagram's.
    #[error("{} exists: a subgraph is written to a new file", .0.display())]
    SubgraphExists(PathBuf),
}

impl Purpose {
    fn title(&self) -> String {
        match self {
            Purpose::OpenDiagram => "Open a diagram".to_owned(),
            Purpose::SaveDiagram => "Save the diagram as".to_owned(),
            Purpose::MakeSubgraph(ids) => {
                format!("Write the {} selected components as a subgraph", ids.len())
            }
            Purpose::Property { component, property } => format!("Choose {property} of {component}"),
        }
    }

    fn shows(&self, path: &Path) -> bool {
        match self {
            Purpose::OpenDiagram | Purpose::SaveDiagram | Purpose::MakeSubgraph(_) => {
                path.extension().is_some_and(|e| e == "ron")
            }
            Purpose::Property { .. } => true,
        }
    }

    fn button(&self) -> &'static str {
        match self {
            Purpose::SaveDiagram => "Save",
            Purpose::MakeSubgraph(_) => "Write",
            Purpose::OpenDiagram => "Open",
            Purpose::Property { .. } => "Choose",
        }
    }
}

/// The dialog's state while it is open.
#[derive(Debug, Clone)]
pub struct FileChooser {
    /// What the file is for.
    pub purpose: Purpose,
    folder: PathBuf,
    /// The typed name: relative to the folder shown, or absolute.
    name: String,
    problem: Option<String>,
    /// An existing file the user was warned about: saving to it again replaces it.
    replace: Option<PathBuf>,
}

/// What the user did this frame.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Choice {
    /// Still choosing.
    Open,
    /// Closed without a choice.
    Cancelled,
    /// This file.
    Chosen(PathBuf),
}

impl FileChooser {
    /// Opens in the folder of `current` (a path, possibly relative to the working folder), with its file
    /// name typed in; or in the working folder.
    pub fn new(purpose: Purpose, current: &str) -> FileChooser {
        let working = std::env::current_dir().unwrap_or_default();
        let current_path = working.join(current);
        let (folder, name) = if current.is_empty() || current_path.is_dir() {
            (
                if current.is_empty() { working } else { current_path },
                String::new(),
            )
        } else {
            let folder = current_path
                .parent()
                .filter(|p| p.is_dir())
                .map_or(working, Path::to_path_buf);
            let name = current_path
                .file_name()
                .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
            (folder, name)
        };
        FileChooser {
            purpose,
            folder,
            name,
            problem: None,
            replace: None,
        }
    }

    /// The folder shown.
    pub fn folder(&self) -> &Path {
        &self.folder
    }

    /// The path the typed name stands for, as the purpose wants it.
    fn typed_path(&self) -> Result<PathBuf, PathRefused> {
        let typed = self.name.trim();
        if typed.is_empty() {
            return Err(PathRefused::Empty);
        }
        let mut path = self.folder.join(typed);
        match self.purpose {
            Purpose::OpenDiagram if !path.is_file() => Err(PathRefused::Missing(path)),
            Purpose::SaveDiagram | Purpose::MakeSubgraph(_) if path.is_dir() => {
                Err(PathRefused::Folder(path))
            }
            Purpose::SaveDiagram | Purpose::MakeSubgraph(_) => {
                if path.extension().is_none() {
                    path.set_extension("ron");
                }
                if let Some(parent) = path.parent().filter(|p| !p.is_dir()) {
                    return Err(PathRefused::NoFolder(parent.to_owned()));
                }
                // A subgraph goes into a new file: one that exists may be another diagram's.
                if matches!(self.purpose, Purpose::MakeSubgraph(_)) && path.exists() {
                    return Err(PathRefused::SubgraphExists(path));
                }
                Ok(path)
            }
            _ => Ok(path),
        }
    }

    /// Shows the dialog.
    pub fn show(&mut self, ctx: &egui::Context) -> Choice {
        let mut open = true;
        let mut choice = Choice::Open;
        egui::Window::new(self.purpose.title())
            .collapsible(false)
            .open(&mut open)
            .show(ctx, |ui| {
                ui.horizontal(|ui| {
                    if let Some(parent) = self.folder.parent()
                        && ui.button("..").on_hover_text("the folder above").clicked()
                    {
                        self.folder = parent.to_path_buf();
                    }
                    ui.label(self.folder.display().to_string());
                });
                let mut entries: Vec<(bool, PathBuf)> = std::fs::read_dir(&self.folder)
                    .map(|dir| dir.flatten().map(|e| (e.path().is_dir(), e.path())).collect())
                    .unwrap_or_default();
                entries.retain(|(is_dir, path)| {
                    let hidden = path
                        .file_name()
                        .is_some_and(|n| n.to_string_lossy().starts_with('.'));
                    !hidden && (*is_dir || self.purpose.shows(path))
                });
                entries.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)));
                egui::ScrollArea::vertical().max_height(300.0).show(ui, |ui| {
                    if entries.is_empty() {
                        ui.weak("(nothing to pick here)");
                    }
                    for (is_dir, path) in entries {
                        let name = path
                            .file_name()
                            .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
                        if is_dir {
                            if ui.button(format!("{name}/")).clicked() {
                                self.folder.clone_from(&path);
                            }
                        } else if ui.button(&name).clicked() {
                            if matches!(self.purpose, Purpose::SaveDiagram | Purpose::MakeSubgraph(_)) {
                                // Saving over a file is chosen with the Save button, not a single click.
                                self.name = name;
                            } else {
                                choice = Choice::Chosen(path);
                            }
                        }
                    }
                });
                ui.separator();
                let mut confirmed = false;
                ui.horizontal(|ui| {
                    let label = ui.label("File:");
                    let edit = ui
                        .add(egui::TextEdit::singleline(&mut self.name).desired_width(260.0))
                        .labelled_by(label.id);
                    confirmed = edit.lost_focus() && ui.input(|i| i.key_pressed(egui::Key::Enter));
                    confirmed |= ui.button(self.purpose.button()).clicked();
                });
                if confirmed {
                    match self.typed_path() {
                        Ok(path)
                            if self.purpose == Purpose::SaveDiagram
                                && path.exists()
                                && self.replace.as_ref() != Some(&path) =>
                        {
                            self.problem = Some(format!(
                                "{} exists; press {} again to replace it",
                                path.display(),
                                self.purpose.button()
                            ));
                            self.replace = Some(path);
                        }
                        Ok(path) => choice = Choice::Chosen(path),
                        Err(problem) => self.problem = Some(problem.to_string()),
                    }
                }
                if let Some(problem) = &self.problem {
                    ui.colored_label(egui::Color32::LIGHT_RED, problem);
                }
            });
        if !open {
            return Choice::Cancelled;
        }
        choice
    }
}

/// How a chosen path is written into a diagram: relative to the working folder when inside it, as the CLI
/// resolves paths from there.
pub fn as_written(path: &Path) -> String {
    let working = std::env::current_dir().unwrap_or_default();
    path.strip_prefix(&working).unwrap_or(path).display().to_string()
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "tests")]

    use super::*;

    #[test]
    fn saving_adds_the_extension_and_refuses_missing_folders() {
        let folder = std::env::temp_dir().join(format!("kairos-chooser-{}", std::process::id()));
        std::fs::create_dir_all(&folder).unwrap();
        let mut chooser = FileChooser::new(Purpose::SaveDiagram, folder.to_str().unwrap());
        assert_eq!(chooser.folder(), folder);
        chooser.name = "drive".to_owned();
        assert_eq!(chooser.typed_path().unwrap(), folder.join("drive.ron"));
        chooser.name = "missing/drive.ron".to_owned();
        assert!(matches!(chooser.typed_path(), Err(PathRefused::NoFolder(_))));
        chooser.purpose = Purpose::OpenDiagram;
        chooser.name = "nothing.ron".to_owned();
        assert!(
            chooser
                .typed_path()
                .unwrap_err()
                .to_string()
                .contains("does not exist")
        );
        std::fs::remove_dir_all(&folder).unwrap();
    }
}
