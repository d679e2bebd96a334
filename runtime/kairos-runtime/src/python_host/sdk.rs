//! The Python SDK the runtime carries: written once into a cache folder and put first on every worker's
//! `PYTHONPATH`, so a component always speaks the worker protocol of the runtime that runs it, whatever
//! the user's environment has installed.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// The package's files, as they are in `component-sdk/python/kairos_sdk`.
const FILES: [(&str, &str); 8] = [
    (
        "__init__.py",
        include_str!("../../../../component-sdk/python/kairos_sdk/__init__.py"),
    ),
    (
        "types.py",
        include_str!("../../../../component-sdk/python/kairos_sdk/types.py"),
    ),
    (
        "descriptor.py",
        include_str!("../../../../component-sdk/python/kairos_sdk/descriptor.py"),
    ),
    (
        "component.py",
        include_str!("../../../../component-sdk/python/kairos_sdk/component.py"),
    ),
    (
        "wire.py",
        include_str!("../../../../component-sdk/python/kairos_sdk/wire.py"),
    ),
    (
        "worker.py",
        include_str!("../../../../component-sdk/python/kairos_sdk/worker.py"),
    ),
    (
        "describe.py",
        include_str!("../../../../component-sdk/python/kairos_sdk/describe.py"),
    ),
    (
        "harness.py",
        include_str!("../../../../component-sdk/python/kairos_sdk/harness.py"),
    ),
];

/// Why the Python SDK could not be written where workers import it from (a full or read-only cache).
#[derive(Debug, Clone, thiserror::Error)]
#[error("cannot write the Python SDK into {}{}", .folder.display(), .cause.as_ref().map(|e| format!(": {e}")).unwrap_or_default())]
pub struct SdkUnwritable {
    folder: PathBuf,
    /// Shared: the first failure is kept and given to every pack that asks afterwards.
    cause: Option<std::sync::Arc<std::io::Error>>,
}

impl SdkUnwritable {
    fn at(folder: &Path) -> impl FnOnce(std::io::Error) -> SdkUnwritable + '_ {
        move |error| SdkUnwritable {
            folder: folder.to_owned(),
            cause: Some(std::sync::Arc::new(error)),
        }
    }
}

/// The folder to put on `PYTHONPATH` (it holds `kairos_sdk/`), written on first use.
pub fn sdk_folder() -> Result<&'static Path, SdkUnwritable> {
    static FOLDER: OnceLock<Result<PathBuf, SdkUnwritable>> = OnceLock::new();
    FOLDER
        .get_or_init(write_once)
        .as_ref()
        .map(PathBuf::as_path)
        .map_err(Clone::clone)
}

fn write_once() -> Result<PathBuf, SdkUnwritable> {
    // The folder is named by the contents, so two runtimes of different versions never share one.
    let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
    for (name, text) in FILES {
        for byte in name.bytes().chain(text.bytes()) {
            hash = (hash ^ u64::from(byte)).wrapping_mul(0x0100_0000_01b3);
        }
    }
    let base = std::env::var_os("XDG_CACHE_HOME")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|home| PathBuf::from(home).join(".cache")))
        .unwrap_or_else(std::env::temp_dir)
        .join("kairos")
        .join("python-sdk");
    let folder = base.join(format!("{hash:016x}"));
    if folder.join("kairos_sdk").join("__init__.py").is_file() {
        return Ok(folder);
    }
    // Written beside, then renamed into place: a runtime starting meanwhile never sees half a package.
    let partial = base.join(format!("{hash:016x}.{}", std::process::id()));
    let package = partial.join("kairos_sdk");
    std::fs::create_dir_all(&package).map_err(SdkUnwritable::at(&package))?;
    for (name, text) in FILES {
        std::fs::write(package.join(name), text).map_err(SdkUnwritable::at(&package))?;
    }
    if std::fs::rename(&partial, &folder).is_err() {
        // Another runtime put it there first.
        let _ = std::fs::remove_dir_all(&partial);
    }
    if folder.join("kairos_sdk").join("__init__.py").is_file() {
        Ok(folder)
    } else {
        Err(SdkUnwritable { folder, cause: None })
    }
}

/// `PYTHONPATH` for a worker: the SDK first, then whatever the user had.
pub fn python_path(sdk: &Path) -> std::ffi::OsString {
    let mut paths = vec![sdk.to_owned()];
    if let Some(existing) = std::env::var_os("PYTHONPATH") {
        paths.extend(std::env::split_paths(&existing));
    }
    std::env::join_paths(paths).unwrap_or_else(|_| sdk.as_os_str().to_owned())
}
