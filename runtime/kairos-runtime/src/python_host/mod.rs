//! Components written in Python.
//!
//! A folder with a `kairos-pack.toml` and `.py` files is a pack. Loading it runs its interpreter once to
//! describe it (`kairos_sdk.describe`); each component instance then runs in a Python process of its own
//! (`kairos_sdk.worker`), driven over a Unix socket by a [`component::PythonComponent`] that lives in the
//! component's runtime thread like any built-in component. Why a process per instance and not an
//! interpreter embedded in the runtime: the user's own interpreter and virtual environment run it (an
//! embedded one is the version the runtime was built against), a crash or a hang ends that process and
//! fails that component alone, and no global interpreter lock is shared by unrelated components.
//! ARCHITECTURE.md and docs/python.md say more, and `docs/python.md` specifies the worker protocol.

mod component;
pub mod manifest;
mod sdk;
mod wire;
mod worker;

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::time::{Duration, Instant};

use kairos_sdk_core::{ComponentInfo, Registry};
use serde::Deserialize;

use crate::packs::RefusedLibrary;
pub use manifest::MANIFEST;

/// How long describing a pack may take (importing its modules, numpy, a model...).
const DESCRIBE_TIMEOUT: Duration = Duration::from_mins(1);

/// What `kairos_sdk.describe` answers.
#[derive(Debug, Deserialize)]
struct Described {
    /// The interpreter's own path (`sys.executable`).
    python: String,
    /// Its version.
    version: Vec<u32>,
    components: Vec<DescribedComponent>,
    errors: Vec<FileError>,
}

#[derive(Debug, Deserialize)]
struct DescribedComponent {
    #[serde(flatten)]
    info: ComponentInfo,
    python: ClassOrigin,
}

#[derive(Debug, Deserialize)]
struct ClassOrigin {
    file: PathBuf,
    class: String,
}

#[derive(Debug, Deserialize)]
struct FileError {
    file: PathBuf,
    line: Option<u32>,
    message: String,
    /// What the pack is loaded without: the file, one class of it, or one component name.
    #[serde(default = "FileError::whole_file")]
    left_out: String,
}

impl FileError {
    fn whole_file() -> String {
        "this file".to_owned()
    }
}

/// One component type of a Python pack: what its worker needs to start.
#[derive(Debug)]
pub(crate) struct ComponentSpec {
    pub pack: String,
    pub interpreter: PathBuf,
    pub sdk: PathBuf,
    pub folder: PathBuf,
    pub file: PathBuf,
    pub class: String,
}

/// Whether `folder` is a Python pack.
pub fn is_python_pack(folder: &Path) -> bool {
    folder.join(MANIFEST).is_file()
}

/// Describes the Python pack in `folder` and registers its components. A pack that cannot be described
/// at all is refused whole; a file that does not import is refused with its line, and the others load.
/// Returns the pack's name when it was registered.
pub fn load_python_pack(
    registry: &mut Registry,
    folder: &Path,
    refused: &mut Vec<RefusedLibrary>,
) -> Option<String> {
    // Absolute: the worker runs in the pack's folder and is given its files' paths.
    let folder = &std::fs::canonicalize(folder).unwrap_or_else(|_| folder.to_owned());
    let manifest_path = folder.join(MANIFEST);
    let refuse = |refused: &mut Vec<RefusedLibrary>, reason: String| {
        refused.push(RefusedLibrary {
            path: manifest_path.clone(),
            reason,
        });
    };
    let spec = match manifest::read(folder) {
        Ok(spec) => spec,
        Err(reason) => {
            refuse(refused, reason.to_string());
            return None;
        }
    };
    let name = spec.manifest.pack.name.clone();
    if registry.packs().any(|p| p.name == name) {
        refuse(refused, format!("a pack named '{name}' is already loaded"));
        return None;
    }
    let sdk = match sdk::sdk_folder() {
        Ok(sdk) => sdk,
        Err(reason) => {
            refuse(refused, reason.to_string());
            return None;
        }
    };
    let described = match describe(&spec, sdk) {
        Ok(described) => described,
        Err(reason) => {
            refuse(refused, format!("pack '{name}': {reason}"));
            return None;
        }
    };
    for error in &described.errors {
        let line = error
            .line
            .map_or_else(String::new, |line| format!("line {line}: "));
        refused.push(RefusedLibrary {
            path: error.file.clone(),
            reason: format!(
                "{line}{} (pack '{name}' loaded without {})",
                error.message, error.left_out
            ),
        });
    }
    tracing::debug!(
        "loaded Python pack {name} {} from {} with {} {}",
        spec.manifest.pack.version,
        folder.display(),
        described.python,
        described
            .version
            .iter()
            .map(u32::to_string)
            .collect::<Vec<_>>()
            .join(".")
    );
    let mut registrar = registry.pack(&name, &spec.manifest.pack.version, &folder.display().to_string());
    crate::packs::register_subgraphs(&mut registrar, &folder.join("subgraphs"));
    for component in described.components {
        let component_spec = Arc::new(ComponentSpec {
            pack: name.clone(),
            interpreter: spec.interpreter.clone(),
            sdk: sdk.to_owned(),
            folder: folder.to_owned(),
            file: component.python.file,
            class: component.python.class,
        });
        registrar.component_with(component.info, move || {
            Box::new(component::PythonComponent::new(Arc::clone(&component_spec)))
        });
    }
    Some(name)
}

/// Why a pack's files could not be described: the pack is refused with this.
#[derive(Debug, thiserror::Error)]
enum DescribeError {
    /// The interpreter would not start.
    #[error("cannot start the Python interpreter '{named}' ({}): {source}", .path.display())]
    Start {
        named: String,
        path: PathBuf,
        source: std::io::Error,
    },
    /// Without threads draining its pipes a module printing a lot would block it.
    #[error("cannot start a thread to read the interpreter's output: {0}")]
    DrainThread(#[source] std::io::Error),
    /// A module that never finishes importing would hold the runtime's start.
    #[error("importing its modules took more than {} s; the pack's code hangs at import", DESCRIBE_TIMEOUT.as_secs())]
    ImportHangs,
    /// The interpreter's process could not be waited for.
    #[error("waiting for the Python interpreter: {0}")]
    Wait(#[source] std::io::Error),
    /// It exited with an error: the last lines it wrote say why.
    #[error("the Python interpreter '{named}' could not describe it ({status}): {tail}")]
    Failed {
        named: String,
        status: std::process::ExitStatus,
        tail: String,
    },
    /// Its answer was not the description's JSON: most likely a Python too old for the SDK.
    #[error(
        "the Python interpreter '{named}' gave an unreadable description ({source}); is it Python 3.9 or newer?"
    )]
    Unreadable {
        named: String,
        source: serde_json::Error,
    },
}

/// Runs `python -m kairos_sdk.describe` on the pack's files.
fn describe(spec: &manifest::PythonPackSpec, sdk: &Path) -> Result<Described, DescribeError> {
    let interpreter = &spec.interpreter_named;
    let mut child = Command::new(&spec.interpreter)
        .args(["-m", "kairos_sdk.describe", &spec.manifest.pack.name])
        .args(&spec.modules)
        .current_dir(&spec.folder)
        .env("PYTHONPATH", sdk::python_path(sdk))
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|source| DescribeError::Start {
            named: interpreter.clone(),
            path: spec.interpreter.clone(),
            source,
        })?;
    // Read both pipes while it runs: a module printing a lot must not block on a full pipe.
    let mut stdout = child.stdout.take();
    let mut stderr = child.stderr.take();
    let drain = |name: &str, pipe: Option<Box<dyn Read + Send>>| {
        std::thread::Builder::new().name(name.to_owned()).spawn(move || {
            let mut text = String::new();
            if let Some(mut pipe) = pipe {
                let _ = pipe.read_to_string(&mut text);
            }
            text
        })
    };
    let out = drain(
        "k:describe out",
        stdout.take().map(|p| Box::new(p) as Box<dyn Read + Send>),
    );
    let err = drain(
        "k:describe err",
        stderr.take().map(|p| Box::new(p) as Box<dyn Read + Send>),
    );
    let (out, err) = match (out, err) {
        (Ok(out), Ok(err)) => (out, err),
        (Err(e), _) | (_, Err(e)) => {
            let _ = child.kill();
            let _ = child.wait();
            return Err(DescribeError::DrainThread(e));
        }
    };
    let started = Instant::now();
    let status = loop {
        match child.try_wait() {
            Ok(Some(status)) => break status,
            Ok(None) if started.elapsed() > DESCRIBE_TIMEOUT => {
                let _ = child.kill();
                let _ = child.wait();
                return Err(DescribeError::ImportHangs);
            }
            Ok(None) => std::thread::sleep(Duration::from_millis(5)),
            Err(error) => return Err(DescribeError::Wait(error)),
        }
    };
    let out = out.join().unwrap_or_default();
    let err = err.join().unwrap_or_default();
    if !status.success() {
        let tail: Vec<&str> = err
            .lines()
            .rev()
            .take(6)
            .collect::<Vec<_>>()
            .into_iter()
            .rev()
            .collect();
        return Err(DescribeError::Failed {
            named: interpreter.clone(),
            status,
            tail: tail.join(" | "),
        });
    }
    serde_json::from_str(&out).map_err(|source| DescribeError::Unreadable {
        named: interpreter.clone(),
        source,
    })
}
