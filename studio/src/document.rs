//! The diagram being edited: its file, whether it changed, and the undo history. Every edit goes through
//! here, so every edit can be undone and the file written is always the canonical text the CLI runs.

use std::path::{Path, PathBuf};

use kairos_diagram::{
    ComponentInfo, ComponentInstance, Connection, DataType, Diagram, ExposedKind, LibraryInfo,
    PackRequirement, PortRef, Position, TypeFilter,
};

/// How many edits can be undone.
const HISTORY: usize = 200;

/// A diagram with its file and history.
#[derive(Debug, Clone, Default)]
pub struct Document {
    diagram: Diagram,
    path: Option<PathBuf>,
    /// The diagram as it was last read or written: unchanged means nothing to save.
    saved: Diagram,
    undo: Vec<Diagram>,
    redo: Vec<Diagram>,
}

/// Why a connection is not made.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Refusal(pub String);

/// Why a diagram file could not be opened or saved.
#[derive(Debug, thiserror::Error)]
pub enum DocumentError {
    /// Not readable, or not a valid diagram: every problem rendered with its line and column.
    #[error("{}", .0.render())]
    Load(#[from] kairos_diagram::LoadError),
    /// Never saved: Save would not know where.
    #[error("the diagram has no file yet: use Save as")]
    NoFile,
    /// The file could not be written.
    #[error("cannot write {}: {source}", .path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
}

/// Why a component cannot take a new name: nothing changes.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RenameError {
    /// Ids are letters, digits, `_` and `-`.
    #[error("\"{to}\" cannot name a component: use letters, digits, _ and - (for example {from}_2)")]
    NotAnId {
        /// The name asked for.
        to: String,
        /// The component's name now.
        from: String,
    },
    /// Another component has it.
    #[error("there is already a component named {0}: choose another name")]
    Taken(String),
    /// No component has the old name.
    #[error("no component named {0}")]
    NoComponent(String),
}

impl Document {
    /// Opens a diagram file; syntax errors are returned rendered, with their line and column.
    pub fn open(path: &Path) -> Result<Document, DocumentError> {
        let (_, parsed) = kairos_diagram::load(path)?;
        Ok(Document {
            saved: parsed.diagram.clone(),
            diagram: parsed.diagram,
            path: Some(path.to_owned()),
            undo: Vec::new(),
            redo: Vec::new(),
        })
    }

    /// A diagram made for the user (a replay of a recording) and not yet saved: it has changes to save.
    pub fn unsaved(diagram: Diagram) -> Document {
        Document {
            diagram,
            ..Document::default()
        }
    }

    /// The diagram.
    pub fn diagram(&self) -> &Diagram {
        &self.diagram
    }

    /// The file, once saved or opened.
    pub fn path(&self) -> Option<&Path> {
        self.path.as_deref()
    }

    /// Whether there are edits a save would write (what is asked before they are discarded). Viewers
    /// opened or closed are not edits: a save writes them, but nothing asks for one.
    pub fn is_dirty(&self) -> bool {
        // Field by field, with no copy: the window's title asks every frame. Every field is named, so a
        // field added to `Diagram` must be placed here.
        let Diagram {
            format,
            packs,
            components,
            connections,
            clock_source,
            hosts,
            viewers: _,
            sequential,
            groups,
            exposes,
        } = &self.diagram;
        let saved = &self.saved;
        *format != saved.format
            || *packs != saved.packs
            || *components != saved.components
            || *connections != saved.connections
            || *clock_source != saved.clock_source
            || *hosts != saved.hosts
            || *sequential != saved.sequential
            || *groups != saved.groups
            || *exposes != saved.exposes
    }

    /// Writes the diagram (canonical text) to its file. With no change since it was opened, the file is left
    /// as it is, byte for byte.
    pub fn save(&mut self) -> Result<(), DocumentError> {
        let Some(path) = self.path.clone() else {
            return Err(DocumentError::NoFile);
        };
        if self.diagram == self.saved && path.exists() {
            return Ok(());
        }
        self.save_as(&path)
    }

    /// Writes the diagram to `path`, which becomes its file.
    pub fn save_as(&mut self, path: &Path) -> Result<(), DocumentError> {
        kairos_diagram::save(path, &self.diagram).map_err(|source| DocumentError::Write {
            path: path.to_owned(),
            source,
        })?;
        self.path = Some(path.to_owned());
        self.saved = self.diagram.clone();
        Ok(())
    }

    /// Applies `edit` as one undoable step.
    pub fn edit<R>(&mut self, edit: impl FnOnce(&mut Diagram) -> R) -> R {
        let before = self.diagram.clone();
        let result = edit(&mut self.diagram);
        if self.diagram != before {
            self.undo.push(before);
            if self.undo.len() > HISTORY {
                self.undo.remove(0);
            }
            self.redo.clear();
        }
        result
    }

    /// Makes the last two edits one undoable step: `before` is the diagram between them.
    pub fn squash_last(&mut self, before: &Diagram) {
        if self.undo.last() == Some(before) {
            self.undo.pop();
        }
    }

    /// Makes the change from `before` to now one undoable step (for a drag applied frame by frame).
    pub fn record(&mut self, before: Diagram) {
        if before != self.diagram {
            self.undo.push(before);
            if self.undo.len() > HISTORY {
                self.undo.remove(0);
            }
            self.redo.clear();
        }
    }

    /// Undoes the last edit; `false` when there is none. The viewers stay as they are: opening one is
    /// not an edit.
    pub fn undo(&mut self) -> bool {
        let Some(mut previous) = self.undo.pop() else {
            return false;
        };
        previous.viewers.clone_from(&self.diagram.viewers);
        self.redo.push(std::mem::replace(&mut self.diagram, previous));
        true
    }

    /// Redoes the last undone edit; `false` when there is none.
    pub fn redo(&mut self) -> bool {
        let Some(mut next) = self.redo.pop() else {
            return false;
        };
        next.viewers.clone_from(&self.diagram.viewers);
        self.undo.push(std::mem::replace(&mut self.diagram, next));
        true
    }

    /// Keeps the open viewers in the diagram, to be saved with it: a change to save, but no edit to undo.
    pub fn set_viewers(&mut self, viewers: Vec<kairos_diagram::ViewerSpec>) {
        self.diagram.viewers = viewers;
    }

    /// Adds a component of `info`'s type at `position`, with a fresh id, and lists its pack. Returns the id.
    pub fn add_component(
        &mut self,
        info: &ComponentInfo,
        library: &LibraryInfo,
        position: Position,
    ) -> String {
        // `core.sine` → `sine1`; a subgraph's file `lane_pipeline.ron` → `lane_pipeline1`.
        let name = if kairos_diagram::is_subgraph_type(&info.type_name) {
            info.type_name.trim_end_matches(".ron").rsplit('/').next()
        } else {
            info.type_name.rsplit('.').next()
        };
        let base = name
            .filter(|n| kairos_diagram::is_valid_id(n))
            .unwrap_or("component")
            .to_owned();
        let id = fresh_id(&self.diagram, &base);
        let pack = library.packs.get(&info.pack).map(|p| PackRequirement {
            name: p.name.clone(),
            version: caret(&p.version),
        });
        self.edit(|diagram| {
            let mut instance = ComponentInstance::new(id.clone(), info.type_name.clone());
            instance.position = position;
            diagram.components.push(instance);
            if let Some(pack) = pack
                && !diagram.packs.iter().any(|p| p.name == pack.name)
            {
                diagram.packs.push(pack);
            }
        });
        id
    }

    /// Removes components and every connection touching them.
    pub fn remove_components(&mut self, ids: &[String]) {
        self.edit(|diagram| {
            diagram.components.retain(|c| !ids.contains(&c.id));
            diagram
                .connections
                .retain(|c| !ids.contains(&c.from.component) && !ids.contains(&c.to.component));
            if diagram
                .clock_source
                .as_ref()
                .is_some_and(|source| ids.contains(source))
            {
                diagram.clock_source = None;
            }
            if let Some(exposes) = &mut diagram.exposes {
                exposes.forget_components(ids);
            }
        });
    }

    /// Renames a component, its connections following; one undoable edit. Refused, with the reason and the
    /// fix, when the name is not a valid id or another component has it.
    pub fn rename_component(&mut self, from: &str, to: &str) -> Result<(), RenameError> {
        let to = to.trim();
        if to == from {
            return Ok(());
        }
        if !kairos_diagram::is_valid_id(to) {
            return Err(RenameError::NotAnId {
                to: to.to_owned(),
                from: from.to_owned(),
            });
        }
        if self.diagram.component(to).is_some() {
            return Err(RenameError::Taken(to.to_owned()));
        }
        if self.diagram.component(from).is_none() {
            return Err(RenameError::NoComponent(from.to_owned()));
        }
        self.edit(|diagram| {
            if let Some(component) = diagram.component_mut(from) {
                to.clone_into(&mut component.id);
            }
            for connection in &mut diagram.connections {
                for end in [&mut connection.from, &mut connection.to] {
                    if end.component == from {
                        to.clone_into(&mut end.component);
                    }
                }
            }
            if diagram.clock_source.as_deref() == Some(from) {
                diagram.clock_source = Some(to.to_owned());
            }
            if let Some(exposes) = &mut diagram.exposes {
                exposes.rename_component(from, to);
            }
        });
        Ok(())
    }

    /// Exposes an inner port or property under `name` to the diagrams that use this one as a subgraph,
    /// or stops exposing it (`None`); one undoable edit. Exposing the first makes the diagram a subgraph;
    /// nothing exposed, it is a plain diagram again.
    pub fn set_exposed(
        &mut self,
        kind: ExposedKind,
        inner: &PortRef,
        name: Option<&str>,
    ) -> Result<(), kairos_diagram::ExposeError> {
        let mut exposes = self.diagram.exposes.clone().unwrap_or_default();
        exposes.set(kind, inner, name)?;
        self.edit(|diagram| diagram.exposes = (!exposes.is_empty()).then_some(exposes));
        Ok(())
    }

    /// Removes one connection.
    pub fn remove_connection(&mut self, from: &PortRef, to: &PortRef) {
        self.edit(|diagram| diagram.connections.retain(|c| !(&c.from == from && &c.to == to)));
    }

    /// Moves a component (not an undo step of its own per frame: call [`Document::edit`] around a whole drag
    /// to make it one).
    pub fn move_component(&mut self, id: &str, position: Position) {
        if let Some(component) = self.diagram.component_mut(id) {
            component.position = position;
        }
    }

    /// Connects `from` (an output) to `to` (an input) when the input's type filter accepts the output's type
    /// and the input is free; otherwise says why not.
    pub fn connect(&mut self, from: &PortRef, to: &PortRef, library: &LibraryInfo) -> Result<(), Refusal> {
        let output_type = self.output_type(from, library);
        let Some(input) = self
            .diagram
            .component(&to.component)
            .and_then(|c| library.component_of(c))
            .and_then(|info| info.input(&to.port))
        else {
            return Err(Refusal(format!("{to} is not an input")));
        };
        if from.component == to.component {
            return Err(Refusal(format!(
                "{} cannot feed itself: connect it to another component",
                from.component
            )));
        }
        if let Some(data_type) = &output_type
            && !input.filter.accepts(data_type)
        {
            return Err(Refusal(format!(
                "{to} needs {}, and {from} gives {}",
                filter_in_words(&input.filter),
                type_in_words(data_type)
            )));
        }
        if let Some(existing) = self.diagram.connections.iter().find(|c| &c.to == to) {
            return Err(Refusal(format!(
                "{to} is already fed by {}: an input takes one connection (delete that one first)",
                existing.from
            )));
        }
        self.edit(|diagram| {
            diagram
                .connections
                .push(Connection::new(from.clone(), to.clone()));
        });
        Ok(())
    }

    /// The type an output carries, following pass-through outputs to what feeds them.
    pub fn output_type(&self, port: &PortRef, library: &LibraryInfo) -> Option<DataType> {
        kairos_diagram::output_type(&self.diagram, port, |c| library.component_of(c))
    }
}

/// A type as people who do not program say it ("a number", "an image").
pub fn type_in_words(data_type: &DataType) -> String {
    match data_type {
        DataType::F64 => "a number",
        DataType::I64 => "a whole number",
        DataType::Bool => "a yes/no value",
        DataType::Vector => "a list of numbers",
        DataType::Matrix => "a table of numbers",
        DataType::Text => "text",
        DataType::Bytes => "raw bytes",
        DataType::Image => "an image",
        DataType::PointCloud => "a point cloud",
        DataType::Imu => "IMU readings",
        DataType::GnssFix => "a GNSS position",
        DataType::CanFrame => "a CAN frame",
        DataType::Pose => "a pose",
        DataType::Custom(name) => return format!("a {name}"),
    }
    .to_owned()
}

/// What an input takes, in words ("a number or a whole number", "anything").
pub fn filter_in_words(filter: &TypeFilter) -> String {
    match filter {
        TypeFilter::Any => "anything".to_owned(),
        TypeFilter::OneOf(types) => {
            let words: Vec<String> = types.iter().map(type_in_words).collect();
            match words.split_last() {
                None => "nothing".to_owned(),
                Some((last, [])) => last.clone(),
                Some((last, rest)) => format!("{} or {last}", rest.join(", ")),
            }
        }
    }
}

/// The runtime's diagnostics about `text` (a deployed diagram), by the component they concern: a
/// component's own problems, and a connection's problems on the component it feeds. Problems outside any
/// component (the format, the pack list) are left out; the log shows every one.
pub fn diagnostics_by_component(
    text: &str,
    diagnostics: &[kairos_diagram::Diagnostic],
) -> std::collections::BTreeMap<String, Vec<String>> {
    let mut found: std::collections::BTreeMap<String, Vec<String>> = std::collections::BTreeMap::new();
    let Ok(parsed) = kairos_diagram::parse(text) else {
        return found;
    };
    let map = &parsed.source_map;
    for diagnostic in diagnostics {
        let Some(offset) = diagnostic.location.map(|l| l.offset) else {
            continue;
        };
        let in_connection = map
            .connections
            .iter()
            .zip(&parsed.diagram.connections)
            .rfind(|(at, _)| at.connection.offset <= offset)
            .map(|(_, c)| c.to.component.clone());
        let in_component = map
            .components
            .iter()
            .zip(&parsed.diagram.components)
            .rfind(|(at, _)| at.component.offset <= offset)
            .map(|(_, c)| c.id.clone());
        let first_connection = map
            .connections
            .first()
            .map_or(usize::MAX, |c| c.connection.offset);
        let concerned = if offset >= first_connection {
            in_connection
        } else {
            in_component
        };
        if let Some(id) = concerned {
            found.entry(id).or_default().push(diagnostic.message.clone());
        }
    }
    found
}

/// The runtime's diagnostics about `text` that concern connections, by the port at fault: the output when
/// the diagnostic points at the `from` end, otherwise the input.
pub fn diagnostics_by_port(
    text: &str,
    diagnostics: &[kairos_diagram::Diagnostic],
) -> std::collections::BTreeMap<PortRef, Vec<String>> {
    let mut found: std::collections::BTreeMap<PortRef, Vec<String>> = std::collections::BTreeMap::new();
    let Ok(parsed) = kairos_diagram::parse(text) else {
        return found;
    };
    for diagnostic in diagnostics {
        let Some(offset) = diagnostic.location.map(|l| l.offset) else {
            continue;
        };
        let Some((at, connection)) = parsed
            .source_map
            .connections
            .iter()
            .zip(&parsed.diagram.connections)
            .rfind(|(at, _)| at.connection.offset <= offset)
        else {
            continue;
        };
        let on_from = (at.from.offset..at.from.offset + at.from.len).contains(&offset);
        let port = if on_from { &connection.from } else { &connection.to };
        found
            .entry(port.clone())
            .or_default()
            .push(diagnostic.message.clone());
    }
    found
}

/// `base1`, `base2`, ...: the first id not taken in `diagram`.
pub fn fresh_id(diagram: &Diagram, base: &str) -> String {
    (1..=diagram.components.len() + 1)
        .map(|n| format!("{base}{n}"))
        .find(|id| diagram.component(id).is_none())
        .unwrap_or_else(|| base.to_owned())
}

/// `^0.1` for `0.1.3`, `^1` for `1.2.0`: what a new diagram asks of a pack it uses.
fn caret(version: &str) -> String {
    let mut parts = version.split('.');
    match (parts.next(), parts.next()) {
        (Some("0"), Some(minor)) => format!("^0.{minor}"),
        (Some(major), _) => format!("^{major}"),
        _ => "*".to_owned(),
    }
}

#[cfg(test)]
mod tests {
    use kairos_diagram::{LibraryInfo, PortRef, Position};

    use super::Document;

    /// The built-in library as `kairos components --json` prints it (and the protocol's `library` sends).
    fn library() -> LibraryInfo {
        crate::library_from_components_json(include_str!("../tests/library.json")).unwrap()
    }

    #[test]
    fn edits_undo_and_redo_and_saving_twice_writes_the_same_bytes() {
        let library = library();
        let mut document = Document::default();
        let sine = document.add_component(
            library.component("core.sine").unwrap(),
            &library,
            Position { x: 0.0, y: 0.0 },
        );
        let console = document.add_component(
            library.component("core.console").unwrap(),
            &library,
            Position { x: 200.0, y: 0.0 },
        );
        assert_eq!((sine.as_str(), console.as_str()), ("sine1", "console1"));
        document
            .connect(
                &PortRef::new("sine1", "out"),
                &PortRef::new("console1", "in"),
                &library,
            )
            .unwrap();
        assert_eq!(document.diagram().connections.len(), 1);
        assert_eq!(document.diagram().packs[0].name, "core");
        assert!(document.undo());
        assert!(document.diagram().connections.is_empty());
        assert!(document.redo());
        assert_eq!(document.diagram().connections.len(), 1);

        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("d.ron");
        document.save_as(&path).unwrap();
        let first = std::fs::read(&path).unwrap();
        let mut reopened = Document::open(&path).unwrap();
        assert!(!reopened.is_dirty());
        reopened.save().unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), first);
    }

    #[test]
    fn the_clock_source_follows_a_rename_goes_with_its_component_and_is_saved() {
        let library = library();
        let mut document = Document::default();
        let gnss = document.add_component(
            library.component("gnss.nmea").unwrap(),
            &library,
            Position { x: 0.0, y: 0.0 },
        );
        document.edit(|diagram| diagram.clock_source = Some(gnss.clone()));
        document.rename_component(&gnss, "receiver").unwrap();
        assert_eq!(document.diagram().clock_source.as_deref(), Some("receiver"));
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("d.ron");
        document.save_as(&path).unwrap();
        assert!(
            std::fs::read_to_string(&path)
                .unwrap()
                .contains("clock_source: \"receiver\"")
        );
        document.remove_components(&["receiver".to_owned()]);
        assert_eq!(document.diagram().clock_source, None);
        assert!(document.undo());
        assert_eq!(document.diagram().clock_source.as_deref(), Some("receiver"));
    }

    #[test]
    fn diagnostics_land_on_the_components_they_concern() {
        let text = "Diagram(\n    format: 1,\n    components: [\n        Component(id: \"a\", type: \"core.sine\", properties: {\"rate\": \"fast\"}),\n        Component(id: \"b\", type: \"core.nothing\"),\n    ],\n    connections: [\n        Connection(from: \"a.out\", to: \"b.in\"),\n    ],\n)\n";
        let library = library();
        let parsed = kairos_diagram::parse(text).unwrap();
        let diagnostics = parsed.validate(&library);
        let by_component = super::diagnostics_by_component(text, &diagnostics);
        assert!(
            by_component["a"].iter().any(|m| m.contains("rate")),
            "{by_component:?}"
        );
        assert!(
            by_component["b"].iter().any(|m| m.contains("core.nothing")),
            "{by_component:?}"
        );
    }

    #[test]
    fn a_refused_connection_is_marked_on_its_ports() {
        let text = "Diagram(\n    format: 1,\n    components: [\n        Component(id: \"cam\", type: \"sensors.camera\"),\n        Component(id: \"g\", type: \"core.gain\"),\n    ],\n    connections: [\n        Connection(from: \"cam.image\", to: \"g.in\"),\n        Connection(from: \"cam.nothing\", to: \"g.in\"),\n    ],\n)\n";
        let parsed = kairos_diagram::parse(text).unwrap();
        let diagnostics = parsed.validate(&library());
        let by_port = super::diagnostics_by_port(text, &diagnostics);
        assert!(
            by_port[&PortRef::new("cam", "nothing")]
                .iter()
                .any(|m| m.contains("nothing")),
            "{by_port:?}"
        );
        assert!(by_port.contains_key(&PortRef::new("g", "in")), "{by_port:?}");
    }

    #[test]
    fn a_connection_the_input_refuses_is_not_made_and_says_why() {
        let library = library();
        let mut document = Document::default();
        document.add_component(
            library.component("sensors.camera").unwrap(),
            &library,
            Position::default(),
        );
        document.add_component(
            library.component("core.gain").unwrap(),
            &library,
            Position::default(),
        );
        let refusal = document
            .connect(
                &PortRef::new("camera1", "image"),
                &PortRef::new("gain1", "in"),
                &library,
            )
            .unwrap_err();
        assert!(
            refusal.0.contains("needs a number") && refusal.0.contains("camera1.image gives an image"),
            "{}",
            refusal.0
        );
        assert!(document.diagram().connections.is_empty());
    }
}
