//! The Kairos studio: a node editor that builds, deploys, runs and watches diagrams, for people who do not
//! program. It edits the same diagram files the CLI runs and drives a runtime only through the control
//! protocol: a local `kairos serve` it starts itself, or a remote one.
//!
//! [`session`] is the state, tested without a window; [`app`] is the window around it, with one module
//! per panel (`palette`, `inspector`, `log_panel`, `menus`, `dialogs`), the [`canvas`], and [`commands`]
//! for what the panels ask.

pub mod app;
pub mod canvas;
pub mod chooser;
pub mod client;
pub mod cloud3d;
pub mod commands;
pub mod connection;
pub mod console;
pub mod dialogs;
pub mod dock;
pub mod document;
pub mod examples;
pub mod inspector;
pub mod local;
pub mod log;
pub mod log_panel;
pub mod menus;
pub mod monitor;
pub mod notices;
pub mod palette;
pub mod pending;
pub mod session;
pub mod settings;
pub mod shared;
pub mod transport;
pub mod viewers;
pub mod wizard;

pub use app::StudioApp;
pub use document::Document;
pub use session::Session;

/// The component library as `kairos components --json` prints it (packs and components as lists), as the
/// studio's model holds it (by name).
pub fn library_from_components_json(text: &str) -> Result<kairos_diagram::LibraryInfo, serde_json::Error> {
    let mut listed: serde_json::Value = serde_json::from_str(text)?;
    let mut field = |name: &str| {
        listed
            .get_mut(name)
            .map_or(serde_json::Value::Null, serde_json::Value::take)
    };
    let packs: Vec<kairos_diagram::PackInfo> = serde_json::from_value(field("packs"))?;
    let components: Vec<kairos_diagram::ComponentInfo> = serde_json::from_value(field("components"))?;
    Ok(kairos_diagram::LibraryInfo {
        packs: packs.into_iter().map(|p| (p.name.clone(), p)).collect(),
        components: components.into_iter().map(|c| (c.type_name.clone(), c)).collect(),
        custom_types: Vec::new(),
        instances: std::collections::BTreeMap::new(),
        subgraphs: std::collections::BTreeMap::new(),
    })
}
