//! What the user asks of the studio through menus, shortcuts, the inspector and dialogs. Panels push
//! commands while they draw; the app carries them out once the frame's panels are drawn, so no panel
//! changes state that another panel of the same frame has already shown.

use std::path::PathBuf;

use kairos_diagram::{PortRef, Value};
use kairos_protocol::RequestBody;

use crate::session::ReaderSettings;
use crate::settings::RemoteAddress;

/// What to do once unsaved changes are saved or discarded.
#[derive(Debug, Clone, PartialEq)]
pub enum AfterDiscard {
    /// Start a new, empty diagram.
    New,
    /// Open this file.
    Open(PathBuf),
    /// Open this subgraph file, the open diagram going on the breadcrumb.
    Inside(PathBuf),
    /// Open the breadcrumb's diagram at this depth, dropping those after it.
    Back(usize),
    /// Close the studio.
    Quit,
    /// Open this diagram, not yet saved (a replay of a recording just made).
    Unsaved(Box<kairos_diagram::Diagram>),
}

/// One thing the user asked for.
#[derive(Debug, Clone, PartialEq)]
pub enum Command {
    /// A new diagram (asking first about unsaved changes).
    NewDiagram,
    /// The file chooser, to open a diagram.
    OpenDiagram,
    /// Open this file (asking first about unsaved changes).
    OpenFile(PathBuf),
    /// Go inside a subgraph: open its file (asking first about unsaved changes), the diagram using it
    /// kept in the breadcrumb to come back to.
    OpenSubgraph(PathBuf),
    /// Back out of a subgraph to the diagram at this depth of the breadcrumb.
    BackTo(usize),
    /// Save the diagram (asking for a file when it has none).
    Save,
    /// The file chooser, to save the diagram under another name.
    SaveAs,
    /// Close the studio (asking first about unsaved changes).
    Quit,
    /// Save, then do this if the save succeeded.
    SaveThen(AfterDiscard),
    /// Do this, dropping unsaved changes.
    Discard(AfterDiscard),
    /// Open the "New component…" dialog.
    NewComponentDialog,
    /// Open the connect dialog, filled with the last remote runtime.
    ConnectDialog,
    /// Connect to this remote runtime, and remember it.
    Connect(RemoteAddress),
    /// Go back to the local runtime.
    UseLocalRuntime,
    /// Undo the last edit.
    Undo,
    /// Redo the last undone edit.
    Redo,
    /// Copy the selected components.
    Copy,
    /// Paste the copied components, beside the originals.
    Paste,
    /// Copy and paste the selected components.
    Duplicate,
    /// Delete the selected components or connection.
    Delete,
    /// Lay the diagram out in columns.
    TidyLayout,
    /// Ask where to write the selected components as a subgraph.
    MakeSubgraphDialog,
    /// Deploy the diagram and start it.
    Run,
    /// Start the deployed diagram although some hosts' clocks are not locked.
    StartUnlocked,
    /// How close to their master hosts' clocks must be for the next starts.
    SetLockBound(std::time::Duration),
    /// Send this request to the runtime (pause, resume, stop, the transport strip's controls).
    Request(RequestBody),
    /// Replay what this recorder wrote last (`file`, as it named it) in a new diagram: a player on the
    /// file, with the open viewers of what it recorded on the player's outputs.
    Replay {
        /// The recorder's id.
        recorder: String,
        /// Its last file.
        file: String,
    },
    /// Set a component's property.
    SetProperty {
        /// The component's id.
        component: String,
        /// The property's name.
        property: String,
        /// Its new value.
        value: Value,
    },
    /// A value typed into a property's field was refused or clamped: say why there and in the log.
    FieldRefused {
        /// The component's id.
        component: String,
        /// The property's name.
        property: String,
        /// Why, in words.
        why: String,
    },
    /// Rename a component (its connections follow).
    Rename {
        /// Its id now.
        from: String,
        /// The new id.
        to: String,
    },
    /// Frame the whole diagram in the canvas.
    FitDiagram,
    /// Zoom the canvas by this factor about its centre (above 1: in).
    Zoom(f32),
    /// Change how a connection reads.
    SetReader {
        /// The output it reads.
        from: PortRef,
        /// The input it feeds.
        to: PortRef,
        /// The new settings.
        settings: ReaderSettings,
    },
    /// Ask the runtime for the devices of its machine again.
    RefreshDevices,
    /// Ask the runtime for the topics of the ROS 2 graph reached through `router` in `domain`.
    RefreshRos2Topics {
        /// The Zenoh endpoint the component reaches ROS 2 through.
        router: String,
        /// Its ROS 2 domain.
        domain: i64,
    },
    /// Make the runtime clock follow a component (a GNSS receiver), or no component.
    SetClockSource(Option<String>),
    /// Run these components in an execution group, or each in a thread of its own (`None`).
    SetGroup {
        /// The components' ids.
        components: Vec<String>,
        /// The group's name.
        group: Option<String>,
    },
    /// Expose an inner port or property to the diagrams using this one as a subgraph, under `name`, or
    /// stop exposing it (`None`).
    SetExposed {
        /// An input, an output or a property.
        kind: kairos_diagram::ExposedKind,
        /// `component.port` or `component.property`.
        inner: PortRef,
        /// The name outside.
        name: Option<String>,
    },
    /// Run the whole diagram in one thread (sequential), or not.
    SetSequential(bool),
    /// Open the usual viewer of `output` for its type (an output inside a subgraph, named flat).
    OpenViewer {
        /// `component.port`.
        output: String,
        /// Its type's name.
        data_type: String,
    },
    /// Trigger a component's action.
    TriggerAction {
        /// The component's id.
        component: String,
        /// The action's name.
        action: String,
    },
    /// The file chooser, for a path property.
    ChoosePath {
        /// The component's id.
        component: String,
        /// The property's name.
        property: String,
        /// The path typed so far.
        current: String,
    },
}
