//! `kairos packs`, and the note printed when a diagram needs a pack that was not found.

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::Context as _;
use kairos_diagram::{Diagnostic, DiagnosticCode};
use kairos_runtime::PackScan;
use kairos_sdk_core::Registry;

/// Prints every pack with its version, origin and components, the refused libraries and the clashes.
pub fn list(registry: &Registry, scan: &PackScan, json: bool) -> anyhow::Result<()> {
    let library = registry.library_info();
    let components_of = |pack: &str| -> Vec<String> {
        library
            .components
            .values()
            .filter(|c| c.pack == pack)
            .map(|c| c.type_name.clone())
            .collect()
    };
    if json {
        let packs: Vec<_> = library
            .packs
            .values()
            .map(|p| {
                serde_json::json!({
                    "name": p.name, "version": p.version, "origin": p.origin, "components": components_of(&p.name),
                })
            })
            .collect();
        let duplicates: Vec<_> = registry
            .duplicates()
            .iter()
            .map(|d| serde_json::json!({"type_name": d.type_name, "kept_from": d.kept_from, "refused_from": d.refused_from}))
            .collect();
        let mut refused: Vec<_> = scan
            .refused
            .iter()
            .map(|r| serde_json::json!({"path": r.path, "reason": r.reason}))
            .collect();
        refused.extend(
            registry
                .refused()
                .iter()
                .map(|r| serde_json::json!({"path": r.origin, "type_name": r.type_name, "reason": r.reason})),
        );
        let document = serde_json::json!({
            "searched": scan.searched, "packs": packs, "refused": refused, "duplicates": duplicates,
        });
        println!(
            "{}",
            serde_json::to_string_pretty(&document).context("encoding the pack list as JSON")?
        );
        return Ok(());
    }
    let mut out = String::new();
    for pack in library.packs.values() {
        let _ = writeln!(out, "{} {}  ({})", pack.name, pack.version, pack.origin);
        for component in components_of(&pack.name) {
            let _ = writeln!(out, "    {component}");
        }
    }
    let searched: Vec<String> = scan.searched.iter().map(|p| p.display().to_string()).collect();
    let _ = writeln!(
        out,
        "\npack path: {}",
        if searched.is_empty() {
            "(empty: use --pack-path DIR or KAIROS_PACK_PATH)".to_owned()
        } else {
            searched.join(", ")
        }
    );
    for refused in &scan.refused {
        let _ = writeln!(out, "refused: {}: {}", refused.path.display(), refused.reason);
    }
    for refused in registry.refused() {
        let _ = writeln!(out, "refused: {}: {}", refused.origin, refused.reason);
    }
    for duplicate in registry.duplicates() {
        let _ = writeln!(
            out,
            "clash: '{}' is offered by '{}' and '{}'; '{}' is used",
            duplicate.type_name, duplicate.kept_from, duplicate.refused_from, duplicate.kept_from
        );
    }
    print!("{out}");
    Ok(())
}

/// Gives a missing pack that lies on the pack path but was refused the reason, in place of a guess at
/// another pack's name: `pack 'py_vision' is not in the component library` is then followed by why.
pub fn say_refused(diagnostics: &mut [Diagnostic], refused: &[kairos_runtime::RefusedLibrary]) {
    for diagnostic in diagnostics.iter_mut() {
        let Some(name) = diagnostic.missing_pack_name().map(str::to_owned) else {
            continue;
        };
        let named = format!("pack '{name}'");
        if let Some(library) = refused
            .iter()
            .find(|r| r.reason.contains(&named) || r.path.file_name().is_some_and(|f| *f == *name))
        {
            let path = library.path.display().to_string();
            let place = if library.reason.contains(&path) {
                "on the pack path".to_owned()
            } else {
                format!("at {path}")
            };
            diagnostic.suggestion = Some(format!("it is {place} but was refused: {}", library.reason));
        }
    }
}

/// After diagnostics about missing or mismatched packs, says where packs were looked for.
pub fn explain_missing(diagnostics: &[Diagnostic], searched: &[PathBuf]) {
    let about_packs = diagnostics.iter().any(|d| {
        matches!(
            d.code,
            DiagnosticCode::MissingPack | DiagnosticCode::PackVersionMismatch
        )
    });
    if about_packs {
        let folders: Vec<String> = searched.iter().map(|p| p.display().to_string()).collect();
        eprintln!(
            "note: packs were looked for among the built-in packs{}",
            if folders.is_empty() {
                " only (no pack path: use --pack-path DIR or KAIROS_PACK_PATH)".to_owned()
            } else {
                format!(" and in {}", folders.join(", "))
            }
        );
    }
}
