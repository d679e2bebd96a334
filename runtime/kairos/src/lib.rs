//! The `kairos` command-line tool: the headless runtime with the built-in packs linked in.

pub mod cli;
pub mod duration;
pub mod run;

use kairos_sdk::Registry;

/// A registry holding every built-in pack.
pub fn builtin_registry() -> Registry {
    let mut registry = Registry::new();
    kairos_pack_core::register(&mut registry);
    kairos_pack_sensors::register(&mut registry);
    registry
}
