//! Finding and loading pack libraries: the pack path, what was loaded and what was refused.

use std::path::{Path, PathBuf};

use crate::pack_host::{LoadedPack, load_pack};
use crate::python_host;
use kairos_sdk_core::Registry;

/// A library on the pack path that was not loaded, and why.
#[derive(Debug, Clone, serde::Serialize)]
pub struct RefusedLibrary {
    /// The file.
    pub path: PathBuf,
    /// Why it was refused.
    pub reason: String,
}

/// What loading the pack path found.
#[derive(Debug, Default)]
pub struct PackScan {
    /// The folders searched, in order.
    pub searched: Vec<PathBuf>,
    /// Packs loaded.
    pub loaded: Vec<LoadedPack>,
    /// Libraries refused, and Python packs or files of them.
    pub refused: Vec<RefusedLibrary>,
    /// The Python packs registered, by name.
    pub python: Vec<String>,
}

/// The file name ending of shared libraries on this platform.
pub const LIBRARY_SUFFIX: &str = std::env::consts::DLL_SUFFIX;

/// The pack path: `--pack-path` folders first, then `KAIROS_PACK_PATH` (separated like `PATH`), then a
/// `packs/` folder beside the diagram when there is one.
pub fn pack_path(explicit: &[PathBuf], diagram: Option<&Path>) -> Vec<PathBuf> {
    let mut folders: Vec<PathBuf> = explicit.to_vec();
    if let Some(from_env) = std::env::var_os("KAIROS_PACK_PATH") {
        folders.extend(std::env::split_paths(&from_env).filter(|p| !p.as_os_str().is_empty()));
    }
    if let Some(beside) = diagram.and_then(Path::parent).map(|dir| dir.join("packs"))
        && beside.is_dir()
    {
        folders.push(beside);
    }
    folders
}

/// Loads every pack in `folders` and registers the good ones in `registry` after what is already there,
/// so a built-in component type is never shadowed (a clash is reported by [`Registry::duplicates`]): the
/// libraries (files ending in the platform's library suffix, in name order), then the Python packs (the
/// folder itself when it holds a `kairos-pack.toml`, and each sub-folder holding one).
pub fn load_packs(registry: &mut Registry, folders: &[PathBuf]) -> PackScan {
    let mut scan = PackScan {
        searched: folders.to_vec(),
        ..PackScan::default()
    };
    for folder in folders {
        let entries = match std::fs::read_dir(folder) {
            Ok(entries) => entries,
            Err(error) => {
                scan.refused.push(RefusedLibrary {
                    path: folder.clone(),
                    reason: format!("cannot read the folder: {error}"),
                });
                continue;
            }
        };
        let mut paths: Vec<PathBuf> = entries.filter_map(Result::ok).map(|e| e.path()).collect();
        paths.sort();
        let files = paths
            .iter()
            .filter(|p| p.is_file() && p.to_string_lossy().ends_with(LIBRARY_SUFFIX))
            .cloned();
        for file in files {
            match load_pack(&file) {
                Ok(pack) => {
                    if registry.packs().any(|p| p.name == pack.name) {
                        scan.refused.push(RefusedLibrary {
                            path: file,
                            reason: format!("a pack named '{}' is already loaded", pack.name),
                        });
                        continue;
                    }
                    tracing::debug!(
                        "loaded pack {} {} from {}",
                        pack.name,
                        pack.version,
                        file.display()
                    );
                    pack.register(registry);
                    scan.loaded.push(pack);
                }
                Err(error) => scan.refused.push(RefusedLibrary {
                    path: file,
                    reason: error.to_string(),
                }),
            }
        }
        let python_packs = std::iter::once(folder)
            .chain(paths.iter().filter(|p| p.is_dir()))
            .filter(|p| python_host::is_python_pack(p));
        for pack in python_packs {
            if let Some(name) = python_host::load_python_pack(registry, pack, &mut scan.refused) {
                scan.python.push(name);
            }
        }
    }
    scan
}

/// Ships with a pack the subgraphs in `folder` (each `NAME.ron` becomes the subgraph `pack.NAME`): the
/// `subgraphs/` folder of a Python pack, `PACK.subgraphs/` beside a pack library. A file that cannot be
/// read is left out, said in the log.
pub(crate) fn register_subgraphs(registrar: &mut kairos_sdk_core::PackRegistrar<'_>, folder: &Path) {
    let Ok(entries) = std::fs::read_dir(folder) else {
        return;
    };
    let mut files: Vec<PathBuf> = entries
        .map_while(Result::ok)
        .map(|entry| entry.path())
        .filter(|path| path.extension().is_some_and(|e| e == "ron"))
        .collect();
    files.sort();
    for file in files {
        let Some(name) = file.file_stem().and_then(|s| s.to_str()) else {
            continue;
        };
        match std::fs::read_to_string(&file) {
            Ok(text) => {
                registrar.subgraph(name, &text);
            }
            Err(error) => tracing::warn!("subgraph {} left out: {error}", file.display()),
        }
    }
}
