//! Rendering and writing: the embedded templates through minijinja, files written without overwriting,
//! Rust formatted with rustfmt.

use std::path::{Path, PathBuf};

use minijinja::Environment;

use super::WizardError;

pub(super) const PACK_CARGO: &str = include_str!("../../../../templates/rust/pack/Cargo.toml.j2");
pub(super) const PACK_LIB: &str = include_str!("../../../../templates/rust/pack/lib.rs.j2");
pub(super) const PACK_README: &str = include_str!("../../../../templates/rust/pack/README.md.j2");
pub(super) const COMPONENT: &str = include_str!("../../../../templates/rust/component.rs.j2");
pub(super) const CPP_MAKEFILE: &str = include_str!("../../../../templates/cpp/pack/Makefile.j2");
pub(super) const CPP_README: &str = include_str!("../../../../templates/cpp/pack/README.md.j2");
pub(super) const CPP_PACK: &str = include_str!("../../../../templates/cpp/pack/pack.cpp.j2");
pub(super) const CPP_UTIL: &str = include_str!("../../../../templates/cpp/pack/kairos_util.hpp.j2");
pub(super) const CPP_COMPONENT: &str = include_str!("../../../../templates/cpp/component.cpp.j2");
pub(super) const PYTHON_MANIFEST: &str =
    include_str!("../../../../templates/python/pack/kairos-pack.toml.j2");
pub(super) const PYTHON_README: &str = include_str!("../../../../templates/python/pack/README.md.j2");
pub(super) const PYTHON_COMPONENT: &str = include_str!("../../../../templates/python/component.py.j2");
pub(super) const PYTHON_TEST: &str = include_str!("../../../../templates/python/test_component.py.j2");

pub(super) fn environment() -> Result<Environment<'static>, WizardError> {
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
            .map_err(|source| WizardError::Template { name, source })?;
    }
    Ok(env)
}

pub(super) fn render(template: &str, values: minijinja::Value) -> Result<String, WizardError> {
    let env = environment()?;
    env.get_template(template)
        .and_then(|t| t.render(values))
        .map_err(|source| WizardError::Render {
            template: template.to_owned(),
            source,
        })
}

pub(super) fn write_new(path: &Path, text: &str, force: bool) -> Result<(), WizardError> {
    if path.exists() && !force {
        return Err(WizardError::FileExists(path.to_owned()));
    }
    std::fs::write(path, text).map_err(|source| WizardError::Write {
        path: path.to_owned(),
        source,
    })
}

/// Formats `files` with rustfmt when it is installed; says so when it is not.
pub(super) fn format(files: &[PathBuf]) -> Option<String> {
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
