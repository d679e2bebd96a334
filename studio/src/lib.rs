//! The Kairos studio: a node editor that builds, deploys, runs and watches diagrams, for people who do not
//! program. It edits the same diagram files the CLI runs and drives a runtime only through the control
//! protocol: a local `kairos serve` it starts itself, or a remote one.

pub mod app;
pub mod canvas;
pub mod chooser;
pub mod client;
pub mod cloud3d;
pub mod document;
pub mod local;
pub mod monitor;
pub mod shared;
pub mod transport;
pub mod viewers;
pub mod wizard;

pub use app::StudioApp;
pub use document::Document;
