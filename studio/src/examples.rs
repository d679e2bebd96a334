//! The example diagrams offered on an empty canvas: the `.ron` files of the repository's `examples/`
//! folder, each with the first line of its leading comment as its description.

use std::path::{Path, PathBuf};

/// One example diagram.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Example {
    /// Its file.
    pub path: PathBuf,
    /// Its file name without `.ron` (`fusion`).
    pub name: String,
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

/// The examples in `folder`, by name.
pub fn in_folder(folder: &Path) -> Vec<Example> {
    let Ok(entries) = std::fs::read_dir(folder) else {
        return Vec::new();
    };
    let mut examples: Vec<Example> = entries
        .map_while(Result::ok)
        .map(|entry| entry.path())
        .filter(|path| path.extension().is_some_and(|e| e == "ron"))
        .map(|path| Example {
            name: path
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default(),
            description: std::fs::read_to_string(&path)
                .ok()
                .and_then(|text| first_comment(&text))
                .unwrap_or_default(),
            path,
        })
        .collect();
    examples.sort_by(|a, b| a.name.cmp(&b.name));
    examples
}

/// The first line of a file's leading `//` comment.
fn first_comment(text: &str) -> Option<String> {
    let line = text.lines().next()?.trim_start().strip_prefix("//")?.trim();
    (!line.is_empty()).then(|| line.to_owned())
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
    }
}
