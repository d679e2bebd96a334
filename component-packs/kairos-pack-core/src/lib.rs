//! The core pack: generators, arithmetic and flow components, synchronisation, sinks.
//!
//! | type | what it does |
//! | --- | --- |
//! | `core.sine`, `core.square`, `core.counter`, `core.constant`, `core.random`, `core.timer` | periodic sources |
//! | `core.gain`, `core.add`, `core.moving_average`, `core.threshold` | arithmetic on numbers |
//! | `core.subsampler` | keeps one sample in N |
//! | `core.delay` | holds each sample for a while (a stand-in for a slow algorithm) |
//! | `core.synchronizer` | matches up to four streams by timestamp |
//! | `core.latency_probe` | measures how old samples are on arrival |
//! | `core.console`, `core.csv_writer` | sinks |

pub mod generators;
pub mod processing;
pub mod sinks;

use kairos_sdk::Registry;

/// The pack's name in diagrams.
pub const PACK_NAME: &str = "core";

/// Registers the core pack's components.
pub fn register(registry: &mut Registry) {
    let mut pack = registry.pack(PACK_NAME, env!("CARGO_PKG_VERSION"), "built-in");
    generators::register(&mut pack);
    processing::register(&mut pack);
    sinks::register(&mut pack);
}
