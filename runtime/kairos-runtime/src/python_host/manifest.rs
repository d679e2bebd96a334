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

/// Reads `folder/kairos-pack.toml`; every error names the file and, where it can, the fix.
pub fn read(folder: &Path) -> Result<PythonPackSpec, String> {
    let path = folder.join(MANIFEST);
    let text = std::fs::read_to_string(&path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    let manifest: Manifest = toml::from_str(&text).map_err(|e| format!("{}: {e}", path.display()))?;
    let name = &manifest.pack.name;
    let valid_name = name
        .chars()
        .next()
        .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
        && name.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
    if !valid_name {
        return Err(format!(
            "{}: pack name '{name}' must be letters, digits and '_', starting with a letter",
            path.display()
        ));
    }
    if semver::Version::parse(&manifest.pack.version).is_err() {
        return Err(format!(
            "{}: version '{}' is not a semantic version (write it as 1.2.3)",
            path.display(),
            manifest.pack.version
        ));
    }
    let (interpreter_named, named_by) = choose_interpreter(folder, &manifest);
    let interpreter = resolve_interpreter(folder, &interpreter_named)
        .map_err(|reason| format!("pack '{name}' ({}): {reason}; {}", path.display(), named_by.fix()))?;
    let modules = modules(folder, manifest.python.modules.as_deref())
        .map_err(|reason| format!("{}: {reason}", path.display()))?;
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
pub fn resolve_interpreter(folder: &Path, named: &str) -> Result<PathBuf, String> {
    let path = folder.join(named);
    if !named.contains('/') && !path.exists() {
        let search = std::env::var_os("PATH").unwrap_or_default();
        return std::env::split_paths(&search)
            .map(|dir| dir.join(named))
            .find(|candidate| candidate.is_file())
            .ok_or_else(|| format!("the Python interpreter '{named}' is not on the PATH"));
    }
    if path.is_dir() {
        for inside in ["bin/python3", "bin/python"] {
            if path.join(inside).is_file() {
                return Ok(path.join(inside));
            }
        }
        return Err(format!(
            "'{}' is a folder without bin/python3: not a virtual environment",
            path.display()
        ));
    }
    if !path.is_file() {
        return Err(format!(
            "the Python interpreter '{}' does not exist",
            path.display()
        ));
    }
    Ok(path)
}

fn modules(folder: &Path, listed: Option<&[String]>) -> Result<Vec<PathBuf>, String> {
    let mut files = match listed {
        Some(listed) => {
            let mut files = Vec::new();
            for name in listed {
                let file = folder.join(name);
                if !file.is_file() {
                    return Err(format!(
                        "module '{name}' listed under [python] is not in the pack's folder"
                    ));
                }
                files.push(file);
            }
            files
        }
        None => std::fs::read_dir(folder)
            .map_err(|e| format!("cannot read the pack's folder: {e}"))?
            .filter_map(Result::ok)
            .map(|entry| entry.path())
            .filter(|path| path.is_file() && path.extension().is_some_and(|e| e == "py"))
            .collect(),
    };
    files.sort();
    if files.is_empty() {
        return Err("the pack's folder holds no .py file".to_owned());
    }
    Ok(files)
}
