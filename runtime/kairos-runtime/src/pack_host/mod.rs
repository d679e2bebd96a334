//! The host's half of the pack ABI: the loader, which checks a library entirely before calling anything
//! in it, the host functions a loaded component calls, and [`DynamicComponent`], which drives a component
//! through its pack's table. The pack's half (the C types and the shim behind `export_pack!`) is in
//! `kairos_sdk_core::abi`.

mod dynamic;
mod functions;
mod loader;

pub use dynamic::DynamicComponent;
pub use functions::HOST_API;
pub use loader::{LoadedPack, PackLoadError, load_pack};
