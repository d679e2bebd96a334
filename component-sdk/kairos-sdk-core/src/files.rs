//! Files a component writes: never one that is there already.
//!
//! A rig's recordings and logs are its results. A run that reused a file name would destroy the last
//! run's data without a word, and a host redeployed after a restart would truncate what it wrote before.
//! Writers create their files with [`create_beside`]: the name asked for when it is free, else the first
//! free `NAME-1.EXT`, `NAME-2.EXT`, … beside it, taken atomically (no other writer can take it between the
//! look and the creation).

use std::fs::File;
use std::io;
use std::path::{Path, PathBuf};

/// How many numbered names are tried before giving up.
const MOST_NUMBERED: u32 = 100_000;

/// Creates `path`, or when a file of that name exists, the first free numbered name beside it: the file
/// and the path it has. With `overwrite`, `path` is created (replacing any file there) as asked.
///
/// # Errors
///
/// The folder is missing or not writable, or every numbered name is taken.
pub fn create_beside(path: &Path, overwrite: bool) -> io::Result<(File, PathBuf)> {
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
        let folder = std::env::temp_dir().join(format!("kairos-files-{}", std::process::id()));
        std::fs::create_dir_all(&folder).unwrap();
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
        std::fs::remove_dir_all(&folder).unwrap();
    }
}
