//! Broken diagrams and the diagnostics they must produce.
//!
//! Each `corpus/broken/NAME.ron` sits beside `NAME.expected`, which holds one diagnostic a line as
//! `Diagnostic`'s `Display` writes it. Run with `KAIROS_BLESS=1` to rewrite the expected files after a
//! deliberate change, then review the diff.

mod common;

use std::path::{Path, PathBuf};

use kairos_diagram::{Diagnostic, parse};

fn diagnostics(source: &str) -> Vec<Diagnostic> {
    match parse(source) {
        Ok(parsed) => parsed.validate(&common::library()),
        Err(diagnostics) => diagnostics,
    }
}

fn corpus() -> Vec<PathBuf> {
    let directory = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/corpus/broken");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&directory)
        .expect("the corpus directory is readable")
        .map(|entry| entry.expect("a corpus entry is readable").path())
        .filter(|path| path.extension().is_some_and(|e| e == "ron"))
        .collect();
    files.sort();
    files
}

#[test]
fn every_broken_diagram_gives_its_expected_diagnostics() {
    let bless = std::env::var_os("KAIROS_BLESS").is_some();
    let files = corpus();
    assert!(files.len() >= 15, "the corpus has only {} files", files.len());
    let mut mismatches = Vec::new();
    for path in &files {
        let source = std::fs::read_to_string(path).unwrap();
        let found = diagnostics(&source);
        assert!(!found.is_empty(), "{} produced no diagnostic", path.display());
        let lines: Vec<String> = found.iter().map(ToString::to_string).collect();
        let actual = lines.join("\n") + "\n";
        let expected_path = path.with_extension("expected");
        if bless {
            std::fs::write(&expected_path, &actual).unwrap();
            continue;
        }
        let expected = std::fs::read_to_string(&expected_path).unwrap_or_default();
        if actual != expected {
            mismatches.push(format!(
                "{}:\n--- expected\n{expected}--- actual\n{actual}",
                path.display()
            ));
        }
        // Rendering must cope with every location the reader and validator produce.
        let name = path.file_name().unwrap().to_string_lossy();
        for diagnostic in &found {
            let rendered = diagnostic.render(&name, &source);
            if let Some(location) = diagnostic.location {
                assert!(
                    rendered.contains(&format!("--> {name}:{location}\n")),
                    "{rendered}"
                );
                assert!(rendered.contains('^'), "{rendered}");
            }
        }
    }
    assert!(mismatches.is_empty(), "{}", mismatches.join("\n"));
}

#[test]
fn a_rendered_diagnostic_shows_the_line_the_caret_and_the_help() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/corpus/broken/unknown_property.ron");
    let source = std::fs::read_to_string(path).unwrap();
    let found = diagnostics(&source);
    let first = found.first().unwrap().render("unknown_property.ron", &source);
    assert_eq!(
        first,
        "error: unknown property 'frequncy' on 'sine1'\n  \
         --> unknown_property.ron:12:17\n   \
         |\n\
         12 |                 \"frequncy\": 2.0,\n   \
         |                 ^^^^^^^^^^\n   \
         = help: did you mean 'frequency'?\n"
    );
}

#[test]
fn notes_point_at_the_other_half_of_a_duplicate() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/corpus/broken/input_fed_twice.ron");
    let source = std::fs::read_to_string(path).unwrap();
    let found = diagnostics(&source);
    let fed_twice = found
        .iter()
        .find(|d| d.code == kairos_diagram::DiagnosticCode::InputFedTwice)
        .unwrap();
    let rendered = fed_twice.render("f.ron", &source);
    assert!(
        rendered.contains("note: the connection from 'sine1.out' is here\n"),
        "{rendered}"
    );
    assert_eq!(fed_twice.notes.len(), 1);
}
