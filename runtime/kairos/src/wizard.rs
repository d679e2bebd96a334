//! `kairos new`: packs and components generated from the templates in `templates/` (embedded at build time),
//! rendered with minijinja and formatted with rustfmt. Every answer is checked before anything is written,
//! and nothing existing is overwritten without `--force`.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

use kairos_diagram::DataType;
use minijinja::{Environment, context};
use serde::Serialize;

const PACK_CARGO: &str = include_str!("../../../templates/rust/pack/Cargo.toml.j2");
const PACK_LIB: &str = include_str!("../../../templates/rust/pack/lib.rs.j2");
const PACK_README: &str = include_str!("../../../templates/rust/pack/README.md.j2");
const COMPONENT: &str = include_str!("../../../templates/rust/component.rs.j2");
const CPP_MAKEFILE: &str = include_str!("../../../templates/cpp/pack/Makefile.j2");
const CPP_README: &str = include_str!("../../../templates/cpp/pack/README.md.j2");
const CPP_PACK: &str = include_str!("../../../templates/cpp/pack/pack.cpp.j2");
const CPP_UTIL: &str = include_str!("../../../templates/cpp/pack/kairos_util.hpp.j2");
const CPP_COMPONENT: &str = include_str!("../../../templates/cpp/component.cpp.j2");
const PYTHON_MANIFEST: &str = include_str!("../../../templates/python/pack/kairos-pack.toml.j2");
const PYTHON_README: &str = include_str!("../../../templates/python/pack/README.md.j2");
const PYTHON_COMPONENT: &str = include_str!("../../../templates/python/component.py.j2");
const PYTHON_TEST: &str = include_str!("../../../templates/python/test_component.py.j2");

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

/// Asks for a component's answers one by one on `input` (a terminal, or a script's lines), checking each
/// before the next and asking again with the reason when it is refused. Lists are comma-separated; an
/// empty line takes the default shown in brackets.
pub fn ask(
    input: &mut impl std::io::BufRead,
    output: &mut impl std::io::Write,
) -> std::io::Result<(ComponentSpec, PathBuf)> {
    let mut question = |text: &str, default: &str, check: &dyn Fn(&str) -> Result<(), String>| {
        loop {
            if default.is_empty() {
                write!(output, "{text}: ")?;
            } else {
                write!(output, "{text} [{default}]: ")?;
            }
            output.flush()?;
            let mut line = String::new();
            if input.read_line(&mut line)? == 0 {
                return Err(std::io::Error::new(
                    std::io::ErrorKind::UnexpectedEof,
                    "no more answers",
                ));
            }
            let answer = match line.trim() {
                "" => default.to_owned(),
                given => given.to_owned(),
            };
            match check(&answer) {
                Ok(()) => return Ok(answer),
                Err(why) => writeln!(output, "  {why}")?,
            }
        }
    };
    let list = |text: &str| -> Vec<String> {
        text.split(',')
            .map(str::trim)
            .filter(|t| !t.is_empty())
            .map(str::to_owned)
            .collect()
    };
    let name = question("Component name", "", &|a| {
        check_name("component", a).map_err(|r| r.to_string())
    })?;
    let pack = question("Pack folder", ".", &|a| {
        let folder = Path::new(a);
        if folder.join("src/lib.rs").is_file() || folder.join("src/pack.cpp").is_file() {
            Ok(())
        } else {
            Err(format!("{a} is not a pack made by `kairos new pack`"))
        }
    })?;
    let mode = question("Mode (threaded, reactive, periodic)", "threaded", &|a| {
        ["threaded", "reactive", "periodic"]
            .contains(&a)
            .then_some(())
            .ok_or_else(|| "one of threaded, reactive, periodic".to_owned())
    })?;
    let inputs = question("Inputs, name:type, comma-separated", "", &|a| {
        list(a).iter().try_for_each(|i| {
            parse_port("input", i, true)
                .map(|_| ())
                .map_err(|r| r.to_string())
        })
    })?;
    let outputs = question("Outputs, name:type", "", &|a| {
        list(a).iter().try_for_each(|o| {
            parse_port("output", o, false)
                .map(|_| ())
                .map_err(|r| r.to_string())
        })
    })?;
    let properties = question("Properties, name:type=default", "", &|a| {
        list(a)
            .iter()
            .try_for_each(|p| property_view(p).map(|_| ()).map_err(|r| r.to_string()))
    })?;
    let actions = question("Actions, names", "", &|a| {
        list(a)
            .iter()
            .try_for_each(|n| check_name("action", n).map_err(|r| r.to_string()))
    })?;
    let spec = ComponentSpec {
        name,
        inputs: list(&inputs),
        outputs: list(&outputs),
        properties: list(&properties),
        actions: list(&actions),
        mode: match mode.as_str() {
            "reactive" => Mode::Reactive,
            "periodic" => Mode::Periodic,
            _ => Mode::Threaded,
        },
    };
    Ok((spec, PathBuf::from(pack)))
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

fn refuse(problem: impl Into<String>, suggestion: Option<String>) -> Refusal {
    Refusal {
        problem: problem.into(),
        suggestion,
    }
}

/// `smoother_2` from `Smoother-2`: a name as it could be written.
fn snake(name: &str) -> String {
    let mut out = String::new();
    for (i, c) in name.chars().enumerate() {
        if c.is_ascii_uppercase() {
            if i > 0 && !out.ends_with('_') {
                out.push('_');
            }
            out.push(c.to_ascii_lowercase());
        } else if c.is_ascii_alphanumeric() {
            out.push(c);
        } else if !out.ends_with('_') {
            out.push('_');
        }
    }
    let out = out.trim_matches('_').to_owned();
    if out.starts_with(|c: char| c.is_ascii_digit()) {
        format!("n{out}")
    } else {
        out
    }
}

/// Checks a name for a pack, component, port, property or action: lower-case letters, digits and `_`,
/// starting with a letter; a component's name (a Rust module and type) may not be a Rust keyword.
pub fn check_name(what: &str, name: &str) -> Result<(), Refusal> {
    let well_formed = name.starts_with(|c: char| c.is_ascii_lowercase())
        && name
            .chars()
            .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_');
    if !well_formed {
        let better = snake(name);
        return Err(refuse(
            format!(
                "'{name}' is not a valid {what} name (lower-case letters, digits and _, starting with a letter)"
            ),
            (!better.is_empty() && !KEYWORDS.contains(&better.as_str())).then(|| format!("try '{better}'")),
        ));
    }
    if what == "component" && KEYWORDS.contains(&name) {
        return Err(refuse(
            format!("'{name}' is a Rust keyword and cannot name a {what}"),
            Some(format!("try '{name}_'")),
        ));
    }
    Ok(())
}

/// A built-in data type (what `--input` and `--output` take: `DataType::BUILT_IN`'s names), or `any` for an
/// input when `any_allowed`.
fn parse_type(what: &str, text: &str, any_allowed: bool) -> Result<Option<DataType>, Refusal> {
    if any_allowed && text == "any" {
        return Ok(None);
    }
    if let Some(data_type) = DataType::BUILT_IN.iter().find(|t| t.name() == text) {
        return Ok(Some(data_type.clone()));
    }
    let names: Vec<&str> = DataType::BUILT_IN
        .iter()
        .map(DataType::name)
        .chain(any_allowed.then_some("any"))
        .collect();
    Err(refuse(
        format!("unknown type '{text}' for {what} (one of {})", names.join(", ")),
        kairos_diagram::did_you_mean(text, names.iter().copied()),
    ))
}

/// `name:type` into its two halves, both checked.
fn parse_port(kind: &str, text: &str, any_allowed: bool) -> Result<(String, Option<DataType>), Refusal> {
    let Some((name, type_name)) = text.split_once(':') else {
        return Err(refuse(
            format!("{kind} '{text}' has no type"),
            Some(format!("write it name:type, e.g. '{text}:f64'")),
        ));
    };
    check_name(kind, name)?;
    Ok((
        name.to_owned(),
        parse_type(&format!("{kind} '{name}'"), type_name, any_allowed)?,
    ))
}

#[derive(Debug, Clone, Serialize)]
struct PortView {
    name: String,
    #[serde(rename = "type")]
    type_expr: String,
    filter: String,
    type_name: String,
    test_payload: Option<String>,
    empty: Option<String>,
}

#[derive(Debug, Serialize)]
struct PropertyView {
    name: String,
    builder: String,
    getter: String,
    /// The same property with the Python SDK's builder.
    python: String,
}

fn type_expr(data_type: &DataType) -> String {
    let variant = match data_type {
        DataType::F64 => "F64",
        DataType::I64 => "I64",
        DataType::Bool => "Bool",
        DataType::Vector => "Vector",
        DataType::Matrix => "Matrix",
        DataType::Text => "Text",
        DataType::Bytes => "Bytes",
        DataType::Image => "Image",
        DataType::PointCloud => "PointCloud",
        DataType::Imu => "Imu",
        DataType::GnssFix => "GnssFix",
        DataType::CanFrame => "CanFrame",
        DataType::Pose => "Pose",
        // A pack-defined type travels as bytes.
        DataType::Custom(_) => return "DataType::Bytes".to_owned(),
    };
    format!("DataType::{variant}")
}

/// A value of the type for a unit test's input, for the simple types.
fn test_payload(data_type: Option<&DataType>) -> Option<String> {
    Some(
        match data_type {
            None | Some(DataType::F64) => "Payload::F64(1.5)",
            Some(DataType::I64) => "Payload::I64(3)",
            Some(DataType::Bool) => "Payload::Bool(true)",
            Some(DataType::Text) => "Payload::Text(\"hello\".into())",
            _ => return None,
        }
        .to_owned(),
    )
}

/// The type's empty value, for the simple types.
fn empty_payload(data_type: &DataType) -> Option<String> {
    Some(
        match data_type {
            DataType::F64 => "Payload::F64(0.0)",
            DataType::I64 => "Payload::I64(0)",
            DataType::Bool => "Payload::Bool(false)",
            DataType::Text => "Payload::Text(\"\".into())",
            _ => return None,
        }
        .to_owned(),
    )
}

/// What a source with this output type writes each cycle, for the simple types.
fn source_payload(data_type: &DataType) -> Option<String> {
    Some(match data_type {
        DataType::F64 => "Payload::F64(self.count as f64)".to_owned(),
        DataType::I64 => "Payload::I64(i64::try_from(self.count).unwrap_or(i64::MAX))".to_owned(),
        DataType::Bool => "Payload::Bool(self.count % 2 == 0)".to_owned(),
        DataType::Text => "Payload::Text(format!(\"sample {}\", self.count).into())".to_owned(),
        _ => return None,
    })
}

fn property_view(text: &str) -> Result<PropertyView, Refusal> {
    let Some((head, default)) = text.split_once('=') else {
        return Err(refuse(
            format!("property '{text}' has no default"),
            Some("write it name:type=default, e.g. 'gain:f64=2.0'".to_owned()),
        ));
    };
    let Some((name, kind)) = head.split_once(':') else {
        return Err(refuse(
            format!("property '{text}' has no type"),
            Some(format!("write it name:type=default, e.g. '{head}:f64={default}'")),
        ));
    };
    check_name("property", name)?;
    let malformed = |expected: &str| {
        refuse(
            format!("the default '{default}' of property '{name}' is not {expected}"),
            None,
        )
    };
    let (builder, getter) = match kind {
        "f64" => {
            let value: f64 = default.parse().map_err(|_| malformed("a number"))?;
            if !value.is_finite() {
                return Err(malformed("a finite number"));
            }
            (format!("Property::f64(\"{name}\", {value:?})"), "f64_property")
        }
        "i64" => {
            let value: i64 = default.parse().map_err(|_| malformed("a whole number"))?;
            (format!("Property::i64(\"{name}\", {value})"), "i64_property")
        }
        "bool" => {
            let value: bool = default.parse().map_err(|_| malformed("true or false"))?;
            (format!("Property::bool(\"{name}\", {value})"), "bool_property")
        }
        "text" | "path" => (
            format!("Property::{kind}(\"{name}\", {default:?})"),
            "text_property",
        ),
        other => {
            return Err(refuse(
                format!("unknown property type '{other}' for '{name}' (f64, i64, bool, text or path)"),
                kairos_diagram::did_you_mean(other, ["f64", "i64", "bool", "text", "path"]),
            ));
        }
    };
    let python = match kind {
        "bool" => format!(
            "Property.bool(\"{name}\", {})",
            if default.trim() == "true" { "True" } else { "False" }
        ),
        _ => builder.replacen("Property::", "Property.", 1),
    };
    Ok(PropertyView {
        name: name.to_owned(),
        builder,
        getter: getter.to_owned(),
        python,
    })
}

fn environment() -> Result<Environment<'static>, String> {
    let mut env = Environment::new();
    env.set_keep_trailing_newline(true);
    for (name, source) in [
        ("pack/Cargo.toml", PACK_CARGO),
        ("pack/lib.rs", PACK_LIB),
        ("pack/README.md", PACK_README),
        ("component.rs", COMPONENT),
        ("cpp/Makefile", CPP_MAKEFILE),
        ("cpp/README.md", CPP_README),
        ("cpp/pack.cpp", CPP_PACK),
        ("cpp/kairos_util.hpp", CPP_UTIL),
        ("cpp/component.cpp", CPP_COMPONENT),
        ("python/kairos-pack.toml", PYTHON_MANIFEST),
        ("python/README.md", PYTHON_README),
        ("python/component.py", PYTHON_COMPONENT),
        ("python/test_component.py", PYTHON_TEST),
    ] {
        env.add_template(name, source)
            .map_err(|e| format!("the template {name} is broken: {e}"))?;
    }
    Ok(env)
}

fn render(template: &str, values: minijinja::Value) -> Result<String, String> {
    let env = environment()?;
    env.get_template(template)
        .and_then(|t| t.render(values))
        .map_err(|e| format!("cannot render {template}: {e}"))
}

/// Where this installation's SDK is: beside the `kairos` sources it was built from.
pub fn default_sdk_path() -> PathBuf {
    let sources = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../component-sdk");
    sources.canonicalize().unwrap_or(sources)
}

fn write_new(path: &Path, text: &str, force: bool) -> Result<(), String> {
    if path.exists() && !force {
        return Err(format!("{} exists; --force overwrites it", path.display()));
    }
    std::fs::write(path, text).map_err(|e| format!("cannot write {}: {e}", path.display()))
}

/// Formats `files` with rustfmt when it is installed; says so when it is not.
fn format(files: &[PathBuf]) -> Option<String> {
    let status = std::process::Command::new("rustfmt")
        .args(["--edition", "2024"])
        .args(files)
        .status();
    match status {
        Ok(status) if status.success() => None,
        Ok(_) => Some("rustfmt refused the generated code (left as generated)".to_owned()),
        Err(_) => Some("rustfmt is not installed: the code is left as generated".to_owned()),
    }
}

/// Refuses a new pack's name that a pack of `library` (the built-in ones and those on the pack path)
/// already has: both could not be loaded together.
fn check_pack_name_free(name: &str, library: &kairos_diagram::LibraryInfo) -> Result<(), String> {
    match library.packs.get(name) {
        None => Ok(()),
        Some(pack) if pack.origin == "built-in" => {
            Err(format!("'{name}' is the name of a built-in pack; choose another"))
        }
        Some(pack) => Err(format!(
            "'{name}' is the name of a pack on the pack path ({}); choose another",
            pack.origin
        )),
    }
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
) -> Result<(PathBuf, Vec<String>), String> {
    check_name("pack", name).map_err(|r| r.to_string())?;
    check_pack_name_free(name, library)?;
    if lang != Lang::Python && !sdk.join("Cargo.toml").is_file() {
        return Err(format!(
            "no kairos-sdk at {} (it is found beside the sources kairos was built from); give --sdk PATH",
            sdk.display()
        ));
    }
    let folder = parent.join(name);
    let exists = folder.join("Cargo.toml").exists()
        || folder.join("Makefile").exists()
        || folder.join(PYTHON_MANIFEST_FILE).exists();
    if exists && !force {
        return Err(format!(
            "{} already holds a pack; --force overwrites it",
            folder.display()
        ));
    }
    let sources = if lang == Lang::Python {
        folder.clone()
    } else {
        folder.join("src")
    };
    std::fs::create_dir_all(&sources).map_err(|e| format!("cannot create {}: {e}", folder.display()))?;
    let crate_name = format!("kairos-pack-{}", name.replace('_', "-"));
    let values = context! {
        pack_name => name,
        crate_name => crate_name,
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
        write_new(&folder.join(file), &render(template, values.clone())?, force)?;
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

/// The descriptor of a C++ component as the runtime reads it from the library (the JSON of a
/// `ComponentInfo`), built with the SDK's own descriptor builder from the same answers.
fn cpp_descriptor(spec: &ComponentSpec, type_name: &str, pack_name: &str) -> Result<String, String> {
    use kairos_sdk::descriptor::{Descriptor, Property};
    let mode = match spec.mode {
        Mode::Threaded => kairos_diagram::ExecutionMode::Threaded,
        Mode::Reactive => kairos_diagram::ExecutionMode::Reactive,
        Mode::Periodic => kairos_diagram::ExecutionMode::Periodic,
    };
    let doc = format!(
        "{} (generated by kairos new: describe what it does here)",
        spec.name
    );
    let mut descriptor = Descriptor::new(type_name, pack_name, &doc).mode(mode);
    for text in &spec.inputs {
        let (name, data_type) = parse_port("input", text, true).map_err(|r| r.to_string())?;
        let filter = data_type.map_or(kairos_diagram::TypeFilter::Any, |t| {
            kairos_diagram::TypeFilter::OneOf(vec![t])
        });
        descriptor = descriptor.input(&name, filter, &name);
    }
    for text in &spec.outputs {
        let (name, data_type) = parse_port("output", text, false).map_err(|r| r.to_string())?;
        descriptor = descriptor.output(&name, data_type.unwrap_or(DataType::F64), &name);
    }
    for text in &spec.properties {
        let (head, default) = text.split_once('=').unwrap_or((text, ""));
        let (name, kind) = head.split_once(':').unwrap_or((head, "text"));
        let property = match kind {
            "f64" => Property::f64(name, default.parse().unwrap_or(0.0)),
            "i64" => Property::i64(name, default.parse().unwrap_or(0)),
            "bool" => Property::bool(name, default.parse().unwrap_or(false)),
            "path" => Property::path(name, default),
            _ => Property::text(name, default),
        };
        descriptor = descriptor.property(property.doc(name));
    }
    for action in &spec.actions {
        descriptor = descriptor.action(action, action);
    }
    let mut info = descriptor.build();
    pack_name.clone_into(&mut info.pack);
    serde_json::to_string_pretty(&info).map_err(|e| format!("cannot write the descriptor: {e}"))
}

/// The pack's name, from its `lib.rs` or `pack.cpp`.
fn pack_name(lib: &str) -> Option<String> {
    let line = lib.lines().find(|l| {
        l.starts_with("pub const PACK_NAME: &str = \"")
            || l.starts_with("constexpr const char *kPackName = \"")
    })?;
    Some(line.split('"').nth(1)?.to_owned())
}

/// Where a new component goes: the pack's index file (`lib.rs` or `pack.cpp`) and the component's file.
#[derive(Debug)]
struct Target {
    lang: Lang,
    index_path: PathBuf,
    index: String,
    pack_name: String,
    type_name: String,
    module_path: PathBuf,
    registered: bool,
}

/// Finds the pack at `pack` and checks the component's name is free in it and in the library.
fn locate(
    spec: &ComponentSpec,
    pack: &Path,
    library: &kairos_diagram::LibraryInfo,
    force: bool,
) -> Result<Target, String> {
    check_name("component", &spec.name).map_err(|r| r.to_string())?;
    if pack.join(PYTHON_MANIFEST_FILE).is_file() {
        return locate_python(spec, pack, library, force);
    }
    let cpp = pack.join("src/pack.cpp").is_file();
    let (index_path, markers) = if cpp {
        (
            pack.join("src/pack.cpp"),
            [CPP_DECLARATIONS_MARKER, CPP_COMPONENTS_MARKER],
        )
    } else {
        (pack.join("src/lib.rs"), [MODULES_MARKER, REGISTER_MARKER])
    };
    let index = std::fs::read_to_string(&index_path).map_err(|e| {
        format!(
            "{} is not a pack made by `kairos new pack` (cannot read {}: {e})",
            pack.display(),
            index_path.display()
        )
    })?;
    if markers.iter().any(|m| !index.contains(m)) {
        return Err(format!(
            "{} lacks the `kairos new` markers; add the lines '{}' and '{}'",
            index_path.display(),
            markers[0],
            markers[1]
        ));
    }
    let pack_name = pack_name(&index).ok_or_else(|| format!("{} has no pack name", index_path.display()))?;
    let type_name = format!("{pack_name}.{}", spec.name);
    if library.component(&type_name).is_some() && !force {
        return Err(format!(
            "the component library already has a type '{type_name}'; choose another name"
        ));
    }
    let module_path = pack
        .join("src")
        .join(format!("{}.{}", spec.name, if cpp { "cpp" } else { "rs" }));
    let registered = if cpp {
        index.contains(&format!(" {}_component();", spec.name))
    } else {
        index.contains(&format!("pub mod {};", spec.name))
    };
    if (registered || module_path.exists()) && !force {
        return Err(format!(
            "the pack {pack_name} already has a component '{}'; choose another name (or --force)",
            spec.name
        ));
    }
    Ok(Target {
        lang: if cpp { Lang::Cpp } else { Lang::Rust },
        index_path,
        index,
        pack_name,
        type_name,
        module_path,
        registered,
    })
}

/// [`locate`] for a Python pack: its manifest names it, and a component is a file of its own.
fn locate_python(
    spec: &ComponentSpec,
    pack: &Path,
    library: &kairos_diagram::LibraryInfo,
    force: bool,
) -> Result<Target, String> {
    let index_path = pack.join(PYTHON_MANIFEST_FILE);
    let index = std::fs::read_to_string(&index_path)
        .map_err(|e| format!("cannot read {}: {e}", index_path.display()))?;
    // `name = "..."` under [pack]: the manifest's only `name`.
    let pack_name = index
        .lines()
        .map(str::trim)
        .find_map(|line| {
            line.strip_prefix("name")?
                .trim_start()
                .strip_prefix('=')?
                .trim()
                .strip_prefix('"')?
                .split('"')
                .next()
        })
        .map(str::to_owned)
        .ok_or_else(|| {
            format!(
                "{} has no pack name (name = \"...\" under [pack])",
                index_path.display()
            )
        })?;
    let type_name = format!("{pack_name}.{}", spec.name);
    if library.component(&type_name).is_some() && !force {
        return Err(format!(
            "the component library already has a type '{type_name}'; choose another name"
        ));
    }
    let module_path = pack.join(format!("{}.py", spec.name));
    if module_path.exists() && !force {
        return Err(format!(
            "the pack {pack_name} already has a component '{}'; choose another name (or --force)",
            spec.name
        ));
    }
    Ok(Target {
        lang: Lang::Python,
        index_path,
        index,
        pack_name,
        type_name,
        module_path,
        registered: true,
    })
}

/// The checked answers, and what the templates decide from them.
#[derive(Debug)]
struct Plan {
    inputs: Vec<PortView>,
    outputs: Vec<PortView>,
    properties: Vec<PropertyView>,
    /// The first output takes the first input's payload as it is.
    pass_through: bool,
    /// The number property a number is multiplied by (the example's algorithm).
    factor: Option<String>,
    /// The expression of the first output from a number `value`.
    numeric: Option<String>,
    /// What a source writes.
    source: Option<String>,
    struct_name: String,
}

impl Plan {
    fn first_input(&self) -> Option<&PortView> {
        self.inputs.first()
    }

    fn first_output(&self) -> Option<&PortView> {
        self.outputs.first()
    }
}

/// Checks every answer (before anything is written) and works out the generated code's shape.
fn plan(spec: &ComponentSpec) -> Result<Plan, String> {
    let mut taken = BTreeSet::new();
    let mut inputs = Vec::new();
    for text in &spec.inputs {
        let (name, data_type) = parse_port("input", text, true).map_err(|r| r.to_string())?;
        if !taken.insert(name.clone()) {
            return Err(format!("two ports are named '{name}'"));
        }
        inputs.push(PortView {
            filter: data_type.as_ref().map_or_else(
                || "TypeFilter::Any".to_owned(),
                |t| format!("TypeFilter::OneOf(vec![{}])", type_expr(t)),
            ),
            type_expr: data_type.as_ref().map_or_else(String::new, type_expr),
            type_name: data_type.as_ref().map_or("any", DataType::name).to_owned(),
            test_payload: test_payload(data_type.as_ref()),
            empty: None,
            name,
        });
    }
    let mut outputs = Vec::new();
    for text in &spec.outputs {
        let (name, data_type) = parse_port("output", text, false).map_err(|r| r.to_string())?;
        let data_type = data_type.unwrap_or(DataType::F64);
        if !taken.insert(name.clone()) {
            return Err(format!("two ports are named '{name}'"));
        }
        outputs.push(PortView {
            type_expr: type_expr(&data_type),
            filter: String::new(),
            type_name: data_type.name().to_owned(),
            test_payload: None,
            empty: empty_payload(&data_type),
            name,
        });
    }
    let mut properties = Vec::new();
    let mut property_names = BTreeSet::new();
    for text in &spec.properties {
        let view = property_view(text).map_err(|r| r.to_string())?;
        if !property_names.insert(view.name.clone()) {
            return Err(format!("two properties are named '{}'", view.name));
        }
        properties.push(view);
    }
    let mut action_names = BTreeSet::new();
    for action in &spec.actions {
        check_name("action", action).map_err(|r| r.to_string())?;
        if !action_names.insert(action.clone()) {
            return Err(format!("two actions are named '{action}'"));
        }
    }
    if spec.mode == Mode::Reactive && inputs.is_empty() {
        return Err(
            "a reactive component runs when a sample arrives: give it an --input (or --mode periodic)"
                .to_owned(),
        );
    }
    let (first_input, first_output) = (inputs.first(), outputs.first());
    let same_type = matches!((first_input, first_output), (Some(i), Some(o)) if i.type_name == o.type_name);
    let numeric_in =
        first_input.is_some_and(|i| ["f64", "i64", "bool", "any"].contains(&i.type_name.as_str()));
    let f64_out = first_output.is_some_and(|o| o.type_name == "f64");
    // A number in, a number out, and a number property: the example multiplies by it.
    let factor = properties
        .iter()
        .find(|p| p.getter == "f64_property")
        .filter(|_| numeric_in && f64_out)
        .map(|p| p.name.clone());
    let pass_through = same_type && factor.is_none();
    let numeric = (!pass_through && numeric_in && f64_out).then(|| match &factor {
        Some(name) => format!("Payload::F64(value * ctx.f64_property(\"{name}\")?)"),
        None => "Payload::F64(value)".to_owned(),
    });
    let source = if first_input.is_none() {
        first_output.and_then(|o| source_payload(&DataType::from_name(&o.type_name)))
    } else {
        None
    };
    let struct_name = spec
        .name
        .split('_')
        .map(|part| {
            let mut chars = part.chars();
            chars
                .next()
                .map(|c| c.to_ascii_uppercase().to_string() + chars.as_str())
                .unwrap_or_default()
        })
        .collect();
    Ok(Plan {
        inputs,
        outputs,
        properties,
        pass_through,
        factor,
        numeric,
        source,
        struct_name,
    })
}

fn doc_line(spec: &ComponentSpec) -> String {
    format!(
        "{} (generated by kairos new: describe what it does here)",
        spec.name
    )
}

/// Writes a Rust component and registers it in the pack's `lib.rs`.
fn write_rust(
    spec: &ComponentSpec,
    target: &Target,
    plan: &Plan,
    force: bool,
) -> Result<Vec<String>, String> {
    let mut sdk_uses = vec![
        "Component",
        "ComponentInfo",
        "ComponentResult",
        "Context",
        "ExecutionMode",
        "Value",
    ];
    if !plan.outputs.is_empty() || plan.inputs.iter().any(|i| i.type_name != "any") {
        sdk_uses.push("DataType");
    }
    let todo = !plan.pass_through
        && plan.numeric.is_none()
        && plan.first_input().is_some()
        && plan.first_output().is_some_and(|o| o.empty.is_some());
    if plan.numeric.is_some() || plan.source.is_some() || todo {
        sdk_uses.push("Payload");
    }
    if !plan.inputs.is_empty() {
        sdk_uses.push("TypeFilter");
    }
    sdk_uses.sort_unstable();
    let mode = match spec.mode {
        Mode::Threaded => "Threaded",
        Mode::Reactive => "Reactive",
        Mode::Periodic => "Periodic",
    };
    let values = context! {
        name => spec.name,
        type_name => target.type_name,
        struct_name => plan.struct_name,
        category => target.pack_name,
        doc => doc_line(spec),
        mode => mode,
        inputs => plan.inputs,
        outputs => plan.outputs,
        properties => plan.properties,
        actions => spec.actions,
        first_input => plan.first_input(),
        first_output => plan.first_output(),
        pass_through => plan.pass_through,
        numeric => plan.numeric,
        source_payload => plan.source,
        sdk_uses => sdk_uses.join(", "),
        descriptor_uses => if plan.properties.is_empty() { "Descriptor" } else { "{Descriptor, Property}" },
    };
    write_new(&target.module_path, &render("component.rs", values)?, force)?;
    if !target.registered {
        let index = target
            .index
            .replacen(
                MODULES_MARKER,
                &format!("pub mod {};\n{MODULES_MARKER}", spec.name),
                1,
            )
            .replacen(
                REGISTER_MARKER,
                &format!(
                    "pack.component::<{name}::{struct_name}>({name}::descriptor());\n    {REGISTER_MARKER}",
                    name = spec.name,
                    struct_name = plan.struct_name
                ),
                1,
            );
        std::fs::write(&target.index_path, index)
            .map_err(|e| format!("cannot write {}: {e}", target.index_path.display()))?;
    }
    Ok(format(&[target.module_path.clone(), target.index_path.clone()])
        .into_iter()
        .collect())
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

fn check_python_mode(spec: &ComponentSpec, target: &Target) -> Result<(), String> {
    if target.lang == Lang::Python && spec.mode == Mode::Reactive {
        return Err(
            "a Python component runs threaded or periodic (a reactive one would run Python in its producer's thread): \
             use --mode threaded"
                .to_owned(),
        );
    }
    Ok(())
}

/// The SDK constant naming a data type in Python (`F64`, `POINT_CLOUD`, `ANY`).
fn python_type(type_name: &str) -> String {
    type_name.to_ascii_uppercase()
}

/// What a Python source writes, by type.
fn python_source(type_name: &str) -> Option<&'static str> {
    Some(match type_name {
        "f64" => "float(self.count)",
        "i64" => "self.count",
        "bool" => "self.count % 2 == 0",
        "text" => "f\"sample {self.count}\"",
        "bytes" => "bytes([self.count % 256])",
        "vector" => "[float(self.count)] * 3",
        _ => return None,
    })
}

/// Writes a Python component and its pytest test beside it: the pack reads every `.py` file, so nothing
/// else changes.
fn write_python(
    spec: &ComponentSpec,
    target: &Target,
    plan: &Plan,
    force: bool,
) -> Result<Vec<String>, String> {
    check_python_mode(spec, target)?;
    let mut imports = BTreeSet::from(["Component".to_owned(), "Descriptor".to_owned()]);
    if !plan.properties.is_empty() {
        imports.insert("Property".to_owned());
    }
    let port = |p: &PortView| {
        let py_type = python_type(&p.type_name);
        serde_json::json!({"name": p.name, "py_type": py_type})
    };
    let inputs: Vec<_> = plan.inputs.iter().map(port).collect();
    let outputs: Vec<_> = plan.outputs.iter().map(port).collect();
    for view in plan.inputs.iter().chain(&plan.outputs) {
        imports.insert(python_type(&view.type_name));
    }
    let input_type = plan.first_input().map(|i| i.type_name.as_str());
    let test_value = match input_type {
        Some("f64" | "any") => Some("1.5"),
        Some("i64") => Some("3"),
        Some("bool") => Some("True"),
        _ => None,
    };
    let factor_default = plan.factor.as_ref().and_then(|name| {
        spec.properties
            .iter()
            .find_map(|p| p.strip_prefix(&format!("{name}:f64=")))
            .and_then(|v| v.parse::<f64>().ok())
    });
    let input_value = match input_type {
        Some("i64") => 3.0,
        Some("bool") => 1.0,
        _ => 1.5,
    };
    let numeric = plan.numeric.as_ref().map(|_| match &plan.factor {
        Some(name) => format!("float(sample.data) * ctx.property(\"{name}\")"),
        None => "float(sample.data)".to_owned(),
    });
    let expected = if plan.pass_through {
        test_value.map(str::to_owned)
    } else if numeric.is_some() {
        Some(format!("{:?}", input_value * factor_default.unwrap_or(1.0)))
    } else {
        None
    };
    let source = plan
        .first_output()
        .and_then(|o| python_source(&o.type_name))
        .filter(|_| plan.first_input().is_none());
    let values = context! {
        name => spec.name,
        type_name => target.type_name,
        class_name => plan.struct_name,
        category => target.pack_name,
        doc => doc_line(spec),
        periodic => spec.mode == Mode::Periodic,
        inputs => inputs,
        outputs => outputs,
        properties => plan.properties,
        actions => spec.actions,
        first_input => plan.first_input().map(port),
        first_output => plan.first_output().map(port),
        pass_through => plan.pass_through,
        numeric => numeric,
        source => source,
        test_value => test_value,
        expected => expected,
        imports => imports.into_iter().collect::<Vec<_>>().join(", "),
    };
    write_new(
        &target.module_path,
        &render("python/component.py", values.clone())?,
        force,
    )?;
    let test_path = target
        .module_path
        .with_file_name(format!("test_{}.py", spec.name));
    write_new(&test_path, &render("python/test_component.py", values)?, force)?;
    Ok(Vec::new())
}

/// Writes a C++ component and lists it in the pack's `pack.cpp`.
fn write_cpp(spec: &ComponentSpec, target: &Target, plan: &Plan, force: bool) -> Result<Vec<String>, String> {
    let descriptor = cpp_descriptor(spec, &target.type_name, &target.pack_name)?;
    let factor_default = plan
        .factor
        .as_ref()
        .and_then(|name| {
            spec.properties
                .iter()
                .find(|p| p.starts_with(&format!("{name}:")))
        })
        .and_then(|p| p.split_once('=').map(|(_, d)| d.to_owned()))
        .unwrap_or_else(|| "1.0".to_owned());
    let source = plan
        .first_output()
        .filter(|o| plan.first_input().is_none() && ["f64", "i64", "bool"].contains(&o.type_name.as_str()))
        .map(|o| o.type_name.clone());
    let code = render(
        "cpp/component.cpp",
        context! {
            name => spec.name,
            type_name => target.type_name,
            struct_name => plan.struct_name,
            doc => doc_line(spec),
            descriptor_json => descriptor,
            mode => format!("{:?}", spec.mode).to_lowercase(),
            first_input => plan.first_input(),
            first_output => plan.first_output(),
            numeric => plan.numeric.is_some(),
            factor => plan.factor,
            factor_default => factor_default,
            source => source,
            actions => spec.actions,
        },
    )?;
    write_new(&target.module_path, &code, force)?;
    if !target.registered {
        let index = target
            .index
            .replacen(
                CPP_DECLARATIONS_MARKER,
                &format!(
                    "kairos_component_vtable {}_component();\n{CPP_DECLARATIONS_MARKER}",
                    spec.name
                ),
                1,
            )
            .replacen(
                CPP_COMPONENTS_MARKER,
                &format!("{}_component(),\n        {CPP_COMPONENTS_MARKER}", spec.name),
                1,
            );
        std::fs::write(&target.index_path, index)
            .map_err(|e| format!("cannot write {}: {e}", target.index_path.display()))?;
    }
    Ok(Vec::new())
}

/// Checks the answers for a component in the pack at `pack` as [`new_component`] would, writing nothing.
pub fn check_component(
    spec: &ComponentSpec,
    pack: &Path,
    library: &kairos_diagram::LibraryInfo,
    force: bool,
) -> Result<(), String> {
    let target = locate(spec, pack, library, force)?;
    check_python_mode(spec, &target)?;
    plan(spec).map(|_| ())
}

/// Generates a component in the pack at `pack` (Rust or C++, as the pack is) and registers it. Every answer
/// is checked before anything is written. Returns notes (rustfmt missing).
pub fn new_component(
    spec: &ComponentSpec,
    pack: &Path,
    library: &kairos_diagram::LibraryInfo,
    force: bool,
) -> Result<Vec<String>, String> {
    let target = locate(spec, pack, library, force)?;
    let plan = plan(spec)?;
    match target.lang {
        Lang::Cpp => write_cpp(spec, &target, &plan, force),
        Lang::Rust => write_rust(spec, &target, &plan, force),
        Lang::Python => write_python(spec, &target, &plan, force),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
        assert!(error.contains("built-in pack"), "{error}");
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
        assert!(error.contains("no kairos-sdk"), "{error}");
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
        assert!(error.contains("/opt/packs/libkairos_pack_filters.so"), "{error}");
    }
}
