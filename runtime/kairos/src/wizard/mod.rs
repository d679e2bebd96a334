//! `kairos new`: packs and components generated from the templates in `templates/` (embedded at build time),
//! rendered with minijinja and formatted with rustfmt. Every answer is checked before anything is written,
//! and nothing existing is overwritten without `--force`.

use std::path::{Path, PathBuf};

use minijinja::context;

mod ask;
mod check;
mod plan;
mod render;
mod write;

pub use ask::ask;
pub use check::check_name;
use check::check_pack_name_free;
use plan::locate;
use render::write_new;
use write::{check_python_mode, write_cpp, write_python, write_rust};

/// Where `kairos new component` adds a module to a pack's `lib.rs`, and where it registers the component;
/// and the same two places in a C++ pack's `pack.cpp`.
const MODULES_MARKER: &str = "// kairos new: modules above this line";
const CPP_DECLARATIONS_MARKER: &str = "// kairos new: declarations above this line";
const CPP_COMPONENTS_MARKER: &str = "// kairos new: components above this line";

/// The language of a pack.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Lang {
    /// A Rust crate on the SDK.
    Rust,
    /// C++ against the C header of the pack ABI, built with make.
    Cpp,
    /// Python: `.py` files and a `kairos-pack.toml`, nothing to build (docs/python.md).
    Python,
}

impl Lang {
    /// How users name it.
    pub fn name(self) -> &'static str {
        match self {
            Lang::Rust => "Rust",
            Lang::Cpp => "C++",
            Lang::Python => "Python",
        }
    }
}

const REGISTER_MARKER: &str = "// kairos new: registrations above this line";

/// A Python pack's manifest (the runtime's `python_host::MANIFEST`).
const PYTHON_MANIFEST_FILE: &str = kairos_runtime::python_host::MANIFEST;

/// Rust's keywords (2024 edition, strict and reserved): not usable as names.
const KEYWORDS: &[&str] = &[
    "as", "async", "await", "break", "const", "continue", "crate", "dyn", "else", "enum", "extern", "false",
    "fn", "for", "gen", "if", "impl", "in", "let", "loop", "match", "mod", "move", "mut", "pub", "ref",
    "return", "self", "Self", "static", "struct", "super", "trait", "true", "type", "unsafe", "use", "where",
    "while", "abstract", "become", "box", "do", "final", "macro", "override", "priv", "try", "typeof",
    "unsized", "virtual", "yield",
];

/// How a component runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Mode {
    /// In a thread of its own, blocking on its inputs.
    Threaded,
    /// In the producer's thread when a sample arrives.
    Reactive,
    /// In a thread of its own, once per period.
    Periodic,
}

/// A component to generate.
#[derive(Debug, Clone)]
pub struct ComponentSpec {
    /// Its name in the pack (`smoother`): the module's name and the type name's second half.
    pub name: String,
    /// `name:type` for each input.
    pub inputs: Vec<String>,
    /// `name:type` for each output.
    pub outputs: Vec<String>,
    /// `name:type=default` for each property.
    pub properties: Vec<String>,
    /// Action names.
    pub actions: Vec<String>,
    /// How it runs.
    pub mode: Mode,
}

/// A refused answer: what is wrong, and what would do.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Refusal {
    /// What is wrong.
    pub problem: String,
    /// What would do, when there is a good guess.
    pub suggestion: Option<String>,
}

impl std::fmt::Display for Refusal {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.problem)?;
        if let Some(suggestion) = &self.suggestion {
            write!(f, "; {suggestion}")?;
        }
        Ok(())
    }
}

impl std::error::Error for Refusal {}

/// Why the wizard made nothing, or stopped part way: an answer refused (before anything is written), or
/// the file system or a template failing.
#[derive(Debug, thiserror::Error)]
pub enum WizardError {
    /// An answer refused, with what would do.
    #[error(transparent)]
    Refused(#[from] Refusal),
    /// A Rust or C++ pack needs the SDK's sources to build against.
    #[error("no kairos-sdk at {} (it is found beside the sources kairos was built from); give --sdk PATH", .0.display())]
    NoSdk(PathBuf),
    /// The folder already holds a pack.
    #[error("{} already holds a pack; --force overwrites it", .0.display())]
    PackExists(PathBuf),
    /// A file the wizard would write is there already.
    #[error("{} exists; --force overwrites it", .0.display())]
    FileExists(PathBuf),
    /// A folder could not be made.
    #[error("cannot create {}: {source}", .path.display())]
    Create {
        /// The folder.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// A file could not be read.
    #[error("cannot read {}: {source}", .path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// A file could not be written.
    #[error("cannot write {}: {source}", .path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// The pack's index is not one `kairos new pack` made.
    #[error("{} is not a pack made by `kairos new pack` (cannot read {}: {source})", .pack.display(), .index.display())]
    NotAPack {
        /// The pack's folder.
        pack: PathBuf,
        /// The index file looked for.
        index: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// A template carried in this binary does not parse: a defect of this build.
    #[error("the template {name} is broken: {source}")]
    Template {
        /// The template.
        name: &'static str,
        /// What minijinja said.
        source: minijinja::Error,
    },
    /// A template failed with these answers.
    #[error("cannot render {template}: {source}")]
    Render {
        /// The template.
        template: String,
        /// What minijinja said.
        source: minijinja::Error,
    },
    /// A C++ component's descriptor could not be written as JSON.
    #[error("cannot write the descriptor: {0}")]
    Descriptor(#[source] serde_json::Error),
}

fn refuse(problem: impl Into<String>, suggestion: Option<String>) -> Refusal {
    Refusal {
        problem: problem.into(),
        suggestion,
    }
}

/// Where this installation's SDK is: beside the `kairos` sources it was built from.
pub fn default_sdk_path() -> PathBuf {
    let sources = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../component-sdk");
    sources.canonicalize().unwrap_or(sources)
}

/// Generates a pack named `name` in `parent/name`, with an example component `scale`; `library` holds
/// the packs whose names are taken. Returns the pack's folder and any note (rustfmt missing).
pub fn new_pack(
    name: &str,
    parent: &Path,
    sdk: &Path,
    library: &kairos_diagram::LibraryInfo,
    lang: Lang,
    force: bool,
) -> Result<(PathBuf, Vec<String>), WizardError> {
    check_name("pack", name)?;
    check_pack_name_free(name, library)?;
    if lang != Lang::Python && !sdk.join("Cargo.toml").is_file() {
        return Err(WizardError::NoSdk(sdk.to_owned()));
    }
    let crate_name = format!("kairos-pack-{}", name.replace('_', "-"));
    // In this repository's component-packs/ folder a pack is a member of its workspace, picked up by the
    // workspace's `component-packs/*` and named as its neighbours are (the folder is the crate's name).
    let in_tree = is_workspace_pack_folder(parent);
    let folder = if in_tree {
        parent.join(&crate_name)
    } else {
        parent.join(name)
    };
    let exists = folder.join("Cargo.toml").exists()
        || folder.join("Makefile").exists()
        || folder.join(PYTHON_MANIFEST_FILE).exists();
    if exists && !force {
        return Err(WizardError::PackExists(folder));
    }
    let sources = if lang == Lang::Python {
        folder.clone()
    } else {
        folder.join("src")
    };
    std::fs::create_dir_all(&sources).map_err(|source| WizardError::Create {
        path: folder.clone(),
        source,
    })?;
    let values = context! {
        pack_name => name,
        crate_name => crate_name,
        in_tree => in_tree,
        sdk_path => sdk.display().to_string(),
        include_path => sdk.join("include").display().to_string(),
        parent => parent.display().to_string(),
    };
    let files: &[(&str, &str)] = match lang {
        Lang::Rust => &[
            ("Cargo.toml", "pack/Cargo.toml"),
            ("README.md", "pack/README.md"),
            ("src/lib.rs", "pack/lib.rs"),
        ],
        Lang::Cpp => &[
            ("Makefile", "cpp/Makefile"),
            ("README.md", "cpp/README.md"),
            ("src/pack.cpp", "cpp/pack.cpp"),
            ("src/kairos_util.hpp", "cpp/kairos_util.hpp"),
        ],
        Lang::Python => &[
            (PYTHON_MANIFEST_FILE, "python/kairos-pack.toml"),
            ("README.md", "python/README.md"),
        ],
    };
    for (file, template) in files {
        write_new(
            &folder.join(file),
            &render::render(template, values.clone())?,
            force,
        )?;
    }
    let example = ComponentSpec {
        name: "scale".to_owned(),
        inputs: vec!["in:f64".to_owned()],
        outputs: vec!["out:f64".to_owned()],
        properties: vec!["factor:f64=2.0".to_owned()],
        actions: Vec::new(),
        mode: Mode::Threaded,
    };
    let notes = new_component(&example, &folder, &kairos_diagram::LibraryInfo::default(), force)?;
    if lang != Lang::Rust {
        return Ok((folder, Vec::new()));
    }
    Ok((folder, notes))
}

/// Whether the pack in `folder` is a member of this repository's workspace (made in its `component-packs/`).
pub fn is_workspace_member(folder: &Path) -> bool {
    folder.parent().is_some_and(is_workspace_pack_folder)
}

/// Whether `parent` is the `component-packs/` folder of a workspace that takes every folder in it (this
/// repository's): a pack made there is one of the workspace's members.
fn is_workspace_pack_folder(parent: &Path) -> bool {
    let Ok(parent) = parent.canonicalize() else {
        return false;
    };
    let Some(root) = parent.parent() else {
        return false;
    };
    parent.file_name().is_some_and(|name| name == "component-packs")
        && std::fs::read_to_string(root.join("Cargo.toml"))
            .is_ok_and(|manifest| manifest.contains("\"component-packs/*\""))
}

/// The language of the pack at `pack`, as `kairos new component` finds it.
pub fn pack_lang(pack: &Path) -> Option<Lang> {
    if pack.join(PYTHON_MANIFEST_FILE).is_file() {
        Some(Lang::Python)
    } else if pack.join("src/pack.cpp").is_file() {
        Some(Lang::Cpp)
    } else if pack.join("src/lib.rs").is_file() {
        Some(Lang::Rust)
    } else {
        None
    }
}

/// Checks the answers for a component in the pack at `pack` as [`new_component`] would, writing nothing.
pub fn check_component(
    spec: &ComponentSpec,
    pack: &Path,
    library: &kairos_diagram::LibraryInfo,
    force: bool,
) -> Result<(), WizardError> {
    let target = locate(spec, pack, library, force)?;
    check_python_mode(spec, &target)?;
    plan::plan(spec)?;
    Ok(())
}

/// Generates a component in the pack at `pack` (Rust or C++, as the pack is) and registers it. Every answer
/// is checked before anything is written. Returns notes (rustfmt missing).
pub fn new_component(
    spec: &ComponentSpec,
    pack: &Path,
    library: &kairos_diagram::LibraryInfo,
    force: bool,
) -> Result<Vec<String>, WizardError> {
    let target = locate(spec, pack, library, force)?;
    let plan = plan::plan(spec)?;
    match target.lang {
        Lang::Cpp => write_cpp(spec, &target, &plan, force),
        Lang::Rust => write_rust(spec, &target, &plan, force),
        Lang::Python => write_python(spec, &target, &plan, force),
    }
}

#[cfg(test)]
mod tests {
    use super::check::{parse_type, property_view};
    use super::*;
    use kairos_diagram::DataType;

    #[test]
    fn names_are_checked_with_a_suggestion() {
        assert!(check_name("component", "smoother_2").is_ok());
        let keyword = check_name("component", "match").unwrap_err();
        assert!(keyword.problem.contains("keyword"), "{keyword}");
        let camel = check_name("component", "MySmoother").unwrap_err();
        assert_eq!(camel.suggestion.as_deref(), Some("try 'my_smoother'"));
        let typo = parse_type("input 'in'", "f46", true).unwrap_err();
        assert_eq!(typo.suggestion.as_deref(), Some("did you mean 'f64'?"));
        let default = property_view("gain:f64=two").unwrap_err();
        assert!(default.problem.contains("not a number"), "{default}");
        // Far from every kind: no guess.
        let stranger = property_view("gain:colour=red").unwrap_err();
        assert_eq!(stranger.suggestion, None, "{stranger}");
    }

    #[test]
    fn types_offered_are_the_built_in_data_types() {
        for data_type in DataType::BUILT_IN {
            assert_eq!(
                parse_type("input 'in'", data_type.name(), false),
                Ok(Some(data_type.clone()))
            );
        }
        let refused = parse_type("output 'out'", "float", false).unwrap_err();
        let listed = DataType::BUILT_IN
            .iter()
            .map(DataType::name)
            .collect::<Vec<_>>()
            .join(", ");
        assert!(refused.problem.contains(&listed), "{refused}");
    }

    #[test]
    fn a_new_pack_may_not_take_the_name_of_a_pack_the_runtime_has() {
        let mut library = crate::builtin_registry().library_info();
        let error = new_pack(
            "sensors",
            Path::new("/nowhere"),
            Path::new("/nowhere"),
            &library,
            Lang::Rust,
            false,
        )
        .unwrap_err();
        assert!(matches!(error, WizardError::Refused(_)), "{error:?}");
        assert!(error.to_string().contains("built-in pack"), "{error}");
        // `filters` is a loadable pack, not a built-in one: the name is free unless it is on the pack path.
        let error = new_pack(
            "filters",
            Path::new("/nowhere"),
            Path::new("/nowhere"),
            &library,
            Lang::Rust,
            false,
        )
        .unwrap_err();
        assert!(matches!(error, WizardError::NoSdk(_)), "{error:?}");
        library.packs.insert(
            "filters".to_owned(),
            kairos_diagram::PackInfo {
                name: "filters".to_owned(),
                version: "0.1.0".to_owned(),
                origin: "/opt/packs/libkairos_pack_filters.so".to_owned(),
            },
        );
        let error = new_pack(
            "filters",
            Path::new("/nowhere"),
            Path::new("/nowhere"),
            &library,
            Lang::Rust,
            false,
        )
        .unwrap_err();
        assert!(
            error.to_string().contains("/opt/packs/libkairos_pack_filters.so"),
            "{error}"
        );
    }

    #[test]
    fn a_pack_made_in_a_workspace_s_component_packs_is_its_member_with_its_lints() {
        let root = tempfile::tempdir().unwrap();
        std::fs::write(
            root.path().join("Cargo.toml"),
            "[workspace]\nmembers = [\"component-packs/*\"]\n",
        )
        .unwrap();
        let packs = root.path().join("component-packs");
        std::fs::create_dir(&packs).unwrap();
        let library = kairos_diagram::LibraryInfo::default();
        let sdk = default_sdk_path();
        let (folder, _) = new_pack("radar", &packs, &sdk, &library, Lang::Rust, false).unwrap();
        assert_eq!(folder, packs.join("kairos-pack-radar"));
        assert!(is_workspace_member(&folder));
        let manifest = std::fs::read_to_string(folder.join("Cargo.toml")).unwrap();
        assert!(
            manifest.contains("[lints]\nworkspace = true")
                && manifest.contains("kairos-sdk.workspace = true")
                && !manifest.contains("[workspace]"),
            "{manifest}"
        );
        // Anywhere else: a workspace of its own, with the same lints written out.
        let elsewhere = tempfile::tempdir().unwrap();
        let (folder, _) = new_pack("radar", elsewhere.path(), &sdk, &library, Lang::Rust, false).unwrap();
        assert_eq!(folder, elsewhere.path().join("radar"));
        assert!(!is_workspace_member(&folder));
        let manifest = std::fs::read_to_string(folder.join("Cargo.toml")).unwrap();
        assert!(
            manifest.contains("[workspace]")
                && manifest.contains("pedantic")
                && manifest.contains("unsafe_code"),
            "{manifest}"
        );
    }
}
