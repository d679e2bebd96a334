//! Every character the studio writes on the screen is one its fonts can draw: a glyph the fonts lack
//! shows as an empty box ("→" did, in the inspector).
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "a failed unwrap is a failed test"
)]

use std::collections::BTreeSet;
use std::path::Path;

/// The characters beyond ASCII inside string literals of `source` (comments and doc comments left out).
fn literal_characters(source: &str, found: &mut BTreeSet<char>) {
    for line in source.lines() {
        let code = line.trim_start();
        if code.starts_with("//") {
            continue;
        }
        // Text between quotes on the line (good enough for the studio's literals, which do not span
        // lines with non-ASCII characters).
        let mut inside = false;
        let mut previous = ' ';
        for c in line.chars() {
            if c == '"' && previous != '\\' {
                inside = !inside;
            } else if inside && !c.is_ascii() {
                found.insert(c);
            }
            previous = c;
        }
    }
}

fn sources(folder: &Path, out: &mut Vec<(String, String)>) {
    for entry in std::fs::read_dir(folder).unwrap().map_while(Result::ok) {
        let path = entry.path();
        if path.is_dir() {
            sources(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push((
                path.display().to_string(),
                std::fs::read_to_string(&path).unwrap(),
            ));
        }
    }
}

#[test]
fn every_character_in_the_interface_has_a_glyph() {
    let mut files = Vec::new();
    sources(&Path::new(env!("CARGO_MANIFEST_DIR")).join("src"), &mut files);
    let ctx = egui::Context::default();
    ctx.run_ui(egui::RawInput::default(), |_| {})
        .textures_delta
        .clear();
    let mut missing = Vec::new();
    for (file, source) in &files {
        let mut found = BTreeSet::new();
        literal_characters(source, &mut found);
        for c in found {
            let drawn = ctx.fonts_mut(|fonts| {
                fonts.has_glyph(&egui::FontId::proportional(14.0), c)
                    && fonts.has_glyph(&egui::FontId::monospace(14.0), c)
            });
            if !drawn {
                missing.push(format!("{c:?} (U+{:04X}) in {file}", c as u32));
            }
        }
    }
    assert!(missing.is_empty(), "no glyph for: {missing:#?}");
}

/// The characters of the text the studio shows but does not write itself: the library's names,
/// descriptions and units (palette, inspector), and what the built-in components print and log
/// ("latency=3.0µs" in the Console tab).
#[test]
fn every_character_the_library_and_the_runtime_send_has_a_glyph() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut found = BTreeSet::new();
    let library = std::fs::read_to_string(root.join("tests/library.json")).unwrap();
    found.extend(library.chars().filter(|c| !c.is_ascii()));
    let mut files = Vec::new();
    sources(&root.join("../component-packs"), &mut files);
    sources(&root.join("../runtime"), &mut files);
    for (_, source) in &files {
        literal_characters(source, &mut found);
    }
    let ctx = egui::Context::default();
    ctx.run_ui(egui::RawInput::default(), |_| {})
        .textures_delta
        .clear();
    let missing: Vec<String> = found
        .into_iter()
        .filter(|&c| {
            !ctx.fonts_mut(|fonts| {
                fonts.has_glyph(&egui::FontId::proportional(14.0), c)
                    && fonts.has_glyph(&egui::FontId::monospace(14.0), c)
            })
        })
        .map(|c| format!("{c:?} (U+{:04X})", c as u32))
        .collect();
    assert!(missing.is_empty(), "no glyph for: {missing:#?}");
}
