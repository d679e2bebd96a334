//! The example diagrams offered on an empty canvas: the `.ron` files of the repository's `examples/`
//! folder and its subfolders (grouped by subfolder), each with the first sentence of its leading comment
//! as its description.

use std::path::{Path, PathBuf};

/// One example diagram.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Example {
    /// Its file.
    pub path: PathBuf,
    /// Its file name without `.ron` (`fusion`).
    pub name: String,
    /// The subfolder it is in, `/`-separated (`vision`), empty at the top.
    pub group: String,
    /// What it shows, in one line.
    pub description: String,
}

/// Where the examples are: `KAIROS_EXAMPLES` if set; else `examples/` in the working folder; else the
/// repository's `examples/` beside a `target/<profile>/` the studio runs from (as `cargo run` and the
/// README's first command start it).
pub fn folder() -> Option<PathBuf> {
    if let Some(folder) = std::env::var_os("KAIROS_EXAMPLES") {
        return Some(folder.into());
    }
    let here = Path::new("examples");
    if here.is_dir() {
        return Some(here.to_owned());
    }
    let binary = std::env::current_exe().ok()?;
    binary
        .ancestors()
        .skip(1)
        .take(4)
        .map(|folder| folder.join("examples"))
        .find(|candidate| candidate.join("hello.ron").is_file())
}

/// How deep subfolders are searched: `examples/vision/lanes.ron` is one level down.
const DEPTH: usize = 3;

/// The examples in `folder` and its subfolders: the top's first, then each group's, by name.
pub fn in_folder(folder: &Path) -> Vec<Example> {
    let mut examples = Vec::new();
    collect(folder, "", DEPTH, &mut examples);
    examples.sort_by(|a, b| {
        (!a.group.is_empty(), &a.group, &a.name).cmp(&(!b.group.is_empty(), &b.group, &b.name))
    });
    examples
}

fn collect(folder: &Path, group: &str, depth: usize, examples: &mut Vec<Example>) {
    let Ok(entries) = std::fs::read_dir(folder) else {
        return;
    };
    for path in entries.map_while(Result::ok).map(|entry| entry.path()) {
        let Some(file_name) = path.file_name().map(|n| n.to_string_lossy().into_owned()) else {
            continue;
        };
        if path.is_dir() {
            if depth > 0 && !file_name.starts_with('.') {
                let inner = if group.is_empty() {
                    file_name
                } else {
                    format!("{group}/{file_name}")
                };
                collect(&path, &inner, depth - 1, examples);
            }
        } else if path.extension().is_some_and(|e| e == "ron") {
            examples.push(Example {
                name: path
                    .file_stem()
                    .map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_default(),
                group: group.to_owned(),
                description: std::fs::read_to_string(&path)
                    .ok()
                    .and_then(|text| description(&text))
                    .unwrap_or_default(),
                path,
            });
        }
    }
}

/// The longest description kept, in characters: one line in the examples menu.
const DESCRIPTION_CHARS: usize = 140;

/// What a diagram file says it shows: the first sentence of its leading `//` comment, which may run over
/// several lines (a diagram has no description field of its own, and its comment is where the examples
/// say what they are).
pub fn description(text: &str) -> Option<String> {
    let comment: Vec<&str> = text
        .lines()
        .map(str::trim_start)
        .map_while(|line| line.strip_prefix("//"))
        .map(str::trim)
        .take_while(|line| !line.is_empty())
        .collect();
    // The arrow that descriptions of pipelines use, in characters the studio's font has.
    let comment = comment.join(" ").replace('→', "->");
    // A sentence ends at a full stop followed by a space or the end (not `fusion.ron`'s dot).
    let end = comment
        .match_indices(". ")
        .map(|(at, _)| at + 1)
        .next()
        .unwrap_or(comment.len());
    let sentence = comment[..end].trim();
    if sentence.is_empty() {
        return None;
    }
    Some(if sentence.chars().count() > DESCRIPTION_CHARS {
        let cut: String = sentence.chars().take(DESCRIPTION_CHARS - 3).collect();
        format!("{}...", cut.trim_end())
    } else {
        sentence.to_owned()
    })
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    #[test]
    fn the_repositorys_examples_are_found_with_their_descriptions() {
        let folder = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples");
        let examples = super::in_folder(&folder);
        let hello = examples.iter().find(|e| e.name == "hello").unwrap();
        assert_eq!(
            hello.description,
            "Hello, Kairos: a sine wave, amplified, printed on the console."
        );
        assert!(examples.iter().all(|e| !e.description.is_empty()), "{examples:?}");
        // A first sentence that runs over two lines is taken whole, and only the first.
        let sensors = examples.iter().find(|e| e.name == "sensors").unwrap();
        assert!(sensors.description.ends_with("open a viewer."), "{sensors:?}");
        // The showcases in subfolders too, after the top's, grouped by folder.
        let lanes = examples.iter().position(|e| e.name == "lanes").unwrap();
        assert_eq!(examples[lanes].group, "vision");
        assert!(
            examples.iter().any(|e| e.group == "python" && e.name == "edges"),
            "{examples:?}"
        );
        assert!(
            examples
                .iter()
                .any(|e| e.group == "lidar" && e.name == "obstacles")
        );
        let first_grouped = examples.iter().position(|e| !e.group.is_empty()).unwrap();
        assert!(examples[first_grouped..].iter().all(|e| !e.group.is_empty()));
        assert!(examples[..first_grouped].iter().any(|e| e.name == "hello"));
    }

    #[test]
    fn a_description_is_the_leading_comments_first_sentence() {
        let description = |text: &str| super::description(text);
        assert_eq!(
            description("// Replay into fusion.ron.\n// Record first.\nDiagram()").as_deref(),
            Some("Replay into fusion.ron.")
        );
        assert_eq!(
            description("  // No full stop\n//\n// Another paragraph.").as_deref(),
            Some("No full stop")
        );
        assert_eq!(description("Diagram(format: 1)"), None);
        assert_eq!(description("//\nDiagram()"), None);
        let long = format!("// {}", "word ".repeat(60));
        assert!(description(&long).unwrap().ends_with("..."));
    }
}
