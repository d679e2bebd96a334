//! A Python pack's manifest, `kairos-pack.toml`, and the interpreter it names.

use std::path::{Path, PathBuf};

use serde::Deserialize;

/// The manifest's file name: a folder on the pack path holding it is a Python pack.
pub const MANIFEST: &str = "kairos-pack.toml";

/// The interpreter used when the manifest names none, `KAIROS_PYTHON` is not set and the pack has no
/// `.venv`.
const DEFAULT_INTERPRETER: &str = "python3";

/// A virtual environment in the pack's folder, used when nothing else names an interpreter.
const PACK_VENV: &str = ".venv";

/// What `kairos-pack.toml` says.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// `[pack]`.
    pub pack: PackSection,
    /// `[python]`, optional.
    #[serde(default)]
    pub python: PythonSection,
}

/// `[pack]`: the pack's name and version.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PackSection {
    /// The pack's name: its components are `NAME.component`.
    pub name: String,
    /// Its semantic version.
    pub version: String,
    /// One line about the pack.
    #[serde(default)]
    pub description: String,
}

/// `[python]`: which interpreter runs the pack and which files it loads.
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PythonSection {
    /// A command on the `PATH` (`python3.12`), a path to an interpreter, or a virtual environment's folder;
    /// relative paths are from the pack's folder.
    pub interpreter: Option<String>,
    /// The files holding components; by default every `.py` file of the pack's folder.
    pub modules: Option<Vec<String>>,
}

/// A manifest read and checked, with the interpreter and files it resolves to.
#[derive(Debug, Clone)]
pub struct PythonPackSpec {
    /// The pack's folder.
    pub folder: PathBuf,
    /// The manifest.
    pub manifest: Manifest,
    /// The interpreter as written (`python3`, `.venv`), for messages.
    pub interpreter_named: String,
    /// The interpreter to run.
    pub interpreter: PathBuf,
    /// The component files, in name order.
    pub modules: Vec<PathBuf>,
}

/// Why a Python pack's manifest refuses the pack; each names the manifest and, where it can, the fix.
#[derive(Debug, thiserror::Error)]
pub enum ManifestError {
    /// The file could not be read.
    #[error("cannot read {}: {source}", .path.display())]
    Read { path: PathBuf, source: std::io::Error },
    /// Not TOML, or not the manifest's sections and keys.
    #[error("{}: {source}", .path.display())]
    Toml { path: PathBuf, source: toml::de::Error },
    /// The name becomes the first half of every component's type, so it must be an identifier.
    #[error("{}: pack name '{name}' must be letters, digits and '_', starting with a letter", .path.display())]
    BadName { path: PathBuf, name: String },
    /// The version is compared when packs are shipped and listed.
    #[error("{}: version '{version}' is not a semantic version (write it as 1.2.3)", .path.display())]
    BadVersion { path: PathBuf, version: String },
    /// The interpreter cannot be found; `fix` says what to change, after where its name came from.
    #[error("pack '{pack}' ({}): {reason}; {fix}", .path.display())]
    Interpreter {
        pack: String,
        path: PathBuf,
        reason: InterpreterError,
        fix: &'static str,
    },
    /// The component files cannot be found.
    #[error("{}: {reason}", .path.display())]
    Modules { path: PathBuf, reason: ModulesError },
}

/// Why an interpreter's name stands for no interpreter.
#[derive(Debug, thiserror::Error)]
pub enum InterpreterError {
    /// A bare command searched on the `PATH`, not found there.
    #[error("the Python interpreter '{0}' is not on the PATH")]
    NotOnPath(String),
    /// A folder named as a virtual environment that has no interpreter.
    #[error("'{}' is a folder without bin/python3: not a virtual environment", .0.display())]
    NotAVirtualEnvironment(PathBuf),
    /// A path to nothing.
    #[error("the Python interpreter '{}' does not exist", .0.display())]
    Missing(PathBuf),
}

/// Why a pack's component files cannot be listed.
#[derive(Debug, thiserror::Error)]
pub enum ModulesError {
    /// A file `modules` lists is not there.
    #[error("module '{0}' listed under [python] is not in the pack's folder")]
    NotInFolder(String),
    /// The folder could not be listed.
    #[error("cannot read the pack's folder: {0}")]
    Folder(#[source] std::io::Error),
    /// A pack with no component file offers nothing; most likely the wrong folder.
    #[error("the pack's folder holds no .py file")]
    NoPythonFile,
}

/// Reads `folder/kairos-pack.toml`; every error names the file and, where it can, the fix.
pub fn read(folder: &Path) -> Result<PythonPackSpec, ManifestError> {
    let path = folder.join(MANIFEST);
    let text = match std::fs::read_to_string(&path) {
        Ok(text) => text,
        Err(source) => return Err(ManifestError::Read { path, source }),
    };
    let manifest: Manifest = match toml::from_str(&text) {
        Ok(manifest) => manifest,
        Err(source) => return Err(ManifestError::Toml { path, source }),
    };
    let name = &manifest.pack.name;
    let valid_name = name
        .chars()
        .next()
        .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
        && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
    if !valid_name {
        let name = name.clone();
        return Err(ManifestError::BadName { path, name });
    }
    if semver::Version::parse(&manifest.pack.version).is_err() {
        let version = manifest.pack.version.clone();
        return Err(ManifestError::BadVersion { path, version });
    }
    let (interpreter_named, named_by) = choose_interpreter(folder, &manifest);
    let interpreter = match resolve_interpreter(folder, &interpreter_named) {
        Ok(interpreter) => interpreter,
        Err(reason) => {
            let pack = name.clone();
            let fix = named_by.fix();
            return Err(ManifestError::Interpreter {
                pack,
                path,
                reason,
                fix,
            });
        }
    };
    let modules = match modules(folder, manifest.python.modules.as_deref()) {
        Ok(modules) => modules,
        Err(reason) => return Err(ManifestError::Modules { path, reason }),
    };
    Ok(PythonPackSpec {
        folder: folder.to_owned(),
        manifest,
        interpreter_named,
        interpreter,
        modules,
    })
}

/// Where the interpreter's name came from: the error that cannot start it says what to change.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum NamedBy {
    Manifest,
    Environment,
    PackVenv,
    Default,
}

impl NamedBy {
    fn fix(self) -> &'static str {
        match self {
            NamedBy::Manifest => "correct `interpreter` under [python] in kairos-pack.toml",
            NamedBy::Environment => {
                "it was named by the environment variable KAIROS_PYTHON: correct or unset it, or set \
                 `interpreter` under [python] in kairos-pack.toml"
            }
            NamedBy::PackVenv => {
                "the pack's .venv folder is used when nothing names an interpreter: \
                 make it again (python3 -m venv .venv) or set `interpreter` under [python]"
            }
            NamedBy::Default => {
                "install python3, or set `interpreter` under [python] in kairos-pack.toml to your Python \
                 or virtual environment"
            }
        }
    }
}

/// The interpreter a pack runs on, first found: the manifest's `interpreter`, `$KAIROS_PYTHON`, a virtual
/// environment with an interpreter in the pack's `.venv` folder (where the wizard tells to make one), then
/// `python3`.
fn choose_interpreter(folder: &Path, manifest: &Manifest) -> (String, NamedBy) {
    if let Some(named) = &manifest.python.interpreter {
        return (named.clone(), NamedBy::Manifest);
    }
    if let Some(named) = std::env::var("KAIROS_PYTHON").ok().filter(|v| !v.is_empty()) {
        return (named, NamedBy::Environment);
    }
    // Only one with an interpreter: a `.venv` made on another machine and copied here, or half made, is
    // passed over rather than refusing the pack.
    let venv = folder.join(PACK_VENV);
    if venv.join("bin/python3").is_file() || venv.join("bin/python").is_file() {
        return (PACK_VENV.to_owned(), NamedBy::PackVenv);
    }
    (DEFAULT_INTERPRETER.to_owned(), NamedBy::Default)
}

/// The interpreter `named` stands for: a path from the pack's folder when one is there or `named` has a
/// `/` (a virtual environment's folder gives its `bin/python3`), else a command searched on the `PATH`.
pub fn resolve_interpreter(folder: &Path, named: &str) -> Result<PathBuf, InterpreterError> {
    let path = folder.join(named);
    if !named.contains('/') && !path.exists() {
        let search = std::env::var_os("PATH").unwrap_or_default();
        return std::env::split_paths(&search)
            .map(|dir| dir.join(named))
            .find(|candidate| candidate.is_file())
            .ok_or_else(|| InterpreterError::NotOnPath(named.to_owned()));
    }
    if path.is_dir() {
        for inside in ["bin/python3", "bin/python"] {
            if path.join(inside).is_file() {
                return Ok(path.join(inside));
            }
        }
        return Err(InterpreterError::NotAVirtualEnvironment(path));
    }
    if !path.is_file() {
        return Err(InterpreterError::Missing(path));
    }
    Ok(path)
}

/// Whether a file of a pack's folder is one of its modules: a `.py` file other than pytest's (`test_*.py`,
/// `*_test.py`, `conftest.py`, which the wizard writes beside the components). Tests are not imported into
/// the runtime: they need pytest, and a test's own imports must not refuse a component.
pub fn is_component_module(name: &std::ffi::OsStr) -> bool {
    let name = name.to_string_lossy();
    name.strip_suffix(".py")
        .is_some_and(|stem| !(stem.starts_with("test_") || stem.ends_with("_test") || stem == "conftest"))
}

fn modules(folder: &Path, listed: Option<&[String]>) -> Result<Vec<PathBuf>, ModulesError> {
    let mut files = match listed {
        Some(listed) => {
            let mut files = Vec::new();
            for name in listed {
                let file = folder.join(name);
                if !file.is_file() {
                    return Err(ModulesError::NotInFolder(name.clone()));
                }
                files.push(file);
            }
            files
        }
        None => std::fs::read_dir(folder)
            .map_err(ModulesError::Folder)?
            .filter_map(Result::ok)
            .map(|entry| entry.path())
            .filter(|path| path.is_file() && path.file_name().is_some_and(is_component_module))
            .collect(),
    };
    files.sort();
    if files.is_empty() {
        return Err(ModulesError::NoPythonFile);
    }
    Ok(files)
}
