//! The `kairos` command-line tool: the headless runtime with the built-in packs linked in. The roles live
//! in libraries of their own (`kairos-runtime` the engine, `kairos-server` the protocol server,
//! `kairos-coordinator` a diagram over hosts, `kairos-client` the protocol client, `kairos-clock-sync`
//! synchronised clocks); this crate holds the command line, `kairos run`, `kairos status` and the wizard.

pub mod cli;
pub mod duration;
pub mod packs;
pub mod run;
pub mod status;
pub mod wizard;

use std::path::{Path, PathBuf};

use kairos_runtime::PackScan;
use kairos_sdk_core::Registry;

/// A registry holding every built-in pack.
pub fn builtin_registry() -> Registry {
    let mut registry = Registry::new();
    kairos_pack_core::register(&mut registry);
    kairos_pack_sensors::register(&mut registry);
    kairos_pack_recording::register(&mut registry);
    kairos_pack_serial::register(&mut registry);
    kairos_pack_gnss::register(&mut registry);
    kairos_pack_video::register(&mut registry);
    kairos_pack_net::register(&mut registry);
    kairos_pack_lidar::register(&mut registry);
    kairos_pack_can::register(&mut registry);
    kairos_pack_vision::register(&mut registry);
    kairos_pack_fusion::register(&mut registry);
    kairos_pack_link::register(&mut registry);
    kairos_pack_ros2::register(&mut registry);
    kairos_pack_sim::register(&mut registry);
    registry
}

/// The built-in packs, then every pack found on the pack path (`pack_path` folders, `KAIROS_PACK_PATH`, and
/// a `packs/` folder beside each of `diagrams`).
pub fn registry_with_packs(pack_path: &[PathBuf], diagrams: &[&Path]) -> (Registry, PackScan) {
    let mut registry = builtin_registry();
    let mut folders = kairos_runtime::pack_path(pack_path, None);
    for diagram in diagrams {
        for folder in kairos_runtime::pack_path(&[], Some(diagram)) {
            if !folders.contains(&folder) {
                folders.push(folder);
            }
        }
    }
    let scan = kairos_runtime::load_packs(&mut registry, &folders);
    (registry, scan)
}
