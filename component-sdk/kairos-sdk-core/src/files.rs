//! Files a component writes: never one that is there already.
//!
//! A rig's recordings and logs are its results. A run that reused a file name would destroy the last
//! run's data without a word, and a host redeployed after a restart would truncate what it wrote before.
//! Writers create their files with [`create_for`] (or [`create_beside`]): the name asked for when it is
//! free, else the first free `NAME-1.EXT`, `NAME-2.EXT`, … beside it, taken atomically (no other writer can
//! take it between the look and the creation).

use std::fs::File;
use std::io;
use std::path::{Path, PathBuf};

use crate::component::Context;

/// How many numbered names are tried before giving up.
const MOST_NUMBERED: u32 = 100_000;

/// Creates `path` (and the folders it needs), or when a file of that name exists, the first free numbered
/// name beside it: the file and the path it has. With `overwrite`, `path` is created (replacing any file
/// there) as asked.
///
/// # Errors
///
/// The folder cannot be made or written to, or every numbered name is taken.
pub fn create_beside(path: &Path, overwrite: bool) -> io::Result<(File, PathBuf)> {
    if let Some(folder) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(folder).map_err(|e| {
            io::Error::new(
                e.kind(),
                format!("cannot create the folder {}: {e}", folder.display()),
            )
        })?;
    }
    if overwrite {
        return File::create(path).map(|file| (file, path.to_owned()));
    }
    for number in 0..=MOST_NUMBERED {
        let candidate = numbered(path, number);
        match File::options().write(true).create_new(true).open(&candidate) {
            Ok(file) => return Ok((file, candidate)),
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists => {}
            Err(e) => return Err(e),
        }
    }
    Err(io::Error::new(
        io::ErrorKind::AlreadyExists,
        format!(
            "{} and {MOST_NUMBERED} numbered names beside it exist",
            path.display()
        ),
    ))
}

/// [`create_beside`] for a component's file: replacing one already there only when the component's
/// `overwrite` property says so (a component without that property never replaces), and warning, with the
/// component's id, when the file goes beside one that is kept.
///
/// # Errors
///
/// As [`create_beside`].
pub fn create_for(ctx: &Context, path: &Path) -> io::Result<(File, PathBuf)> {
    let overwrite = ctx.bool_property("overwrite").unwrap_or(false);
    let (file, created) = create_beside(path, overwrite)?;
    if created != path {
        tracing::warn!(
            "{}: {} exists and is kept: writing {} (set overwrite to replace it)",
            ctx.id(),
            path.display(),
            created.display()
        );
    }
    Ok((file, created))
}

/// `path` with `-number` before its extension; `path` itself for 0.
pub fn numbered(path: &Path, number: u32) -> PathBuf {
    if number == 0 {
        return path.to_owned();
    }
    let stem = path.file_stem().unwrap_or_default().to_string_lossy();
    let name = match path.extension() {
        Some(extension) => format!("{stem}-{number}.{}", extension.to_string_lossy()),
        None => format!("{stem}-{number}"),
    };
    path.with_file_name(name)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write as _;

    #[test]
    fn a_taken_name_is_kept_and_the_next_free_number_used() {
        let root = std::env::temp_dir().join(format!("kairos-files-{}", std::process::id()));
        // The folder is made with the first file.
        let folder = root.join("new");
        let path = folder.join("run.csv");
        let (mut first, at) = create_beside(&path, false).unwrap();
        assert_eq!(at, path);
        first.write_all(b"first").unwrap();
        let (_, second) = create_beside(&path, false).unwrap();
        assert_eq!(second, folder.join("run-1.csv"));
        let (_, third) = create_beside(&path, false).unwrap();
        assert_eq!(third, folder.join("run-2.csv"));
        assert_eq!(std::fs::read(&path).unwrap(), b"first", "never truncated");
        let (_, replaced) = create_beside(&path, true).unwrap();
        assert_eq!(replaced, path);
        assert!(std::fs::read(&path).unwrap().is_empty(), "overwritten when asked");
        assert_eq!(numbered(Path::new("a/log"), 3), Path::new("a/log-3"));
        std::fs::remove_dir_all(&root).unwrap();
    }
}
