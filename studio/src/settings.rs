//! What the studio remembers between launches, in `$XDG_CONFIG_HOME/kairos` (or `~/.config/kairos`): the
//! recent files and, for each remote runtime connected to lately, its address, token file and the
//! certificate trusted for it, never a token or a key. Reading and writing
//! return their errors, which the studio shows in its log.

use std::path::{Path, PathBuf};

/// How many recent files are remembered.
const RECENT_FILES: usize = 10;
const RECENT_FILE_NAME: &str = "studio-recent.txt";
/// The last remote runtime alone, as studios before per-address memory wrote it (address, token file).
const REMOTE_FILE_NAME: &str = "studio-remote.txt";
/// The remote runtimes connected to, the latest first: one per line, address, token file and certificate
/// separated by tabs.
const REMOTES_FILE_NAME: &str = "studio-remotes.txt";
/// How many remote runtimes are remembered.
const REMOTES: usize = 10;

/// A remote runtime as the connect dialog asks for it: its address, the file holding its token, and the
/// certificate to trust for a `wss://` address.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RemoteAddress {
    /// `ws://HOST:PORT` or `wss://HOST:PORT`.
    pub url: String,
    /// The file holding its token; empty when it needs none.
    pub token_file: String,
    /// The PEM file of the certificate to trust (the runtime's own, or its authority's); empty: the one
    /// given with `--certificate`, if any.
    pub certificate: String,
}

impl Default for RemoteAddress {
    fn default() -> Self {
        RemoteAddress {
            url: "ws://HOST:7400".to_owned(),
            token_file: String::new(),
            certificate: String::new(),
        }
    }
}

impl RemoteAddress {
    fn line(&self) -> String {
        format!("{}\t{}\t{}", self.url, self.token_file, self.certificate)
    }

    fn of_line(line: &str) -> Option<RemoteAddress> {
        let mut fields = line.split('\t');
        let url = fields.next().filter(|url| !url.is_empty())?.to_owned();
        Some(RemoteAddress {
            url,
            token_file: fields.next().unwrap_or_default().to_owned(),
            certificate: fields.next().unwrap_or_default().to_owned(),
        })
    }
}

/// The remembered settings and where they live.
#[derive(Debug, Clone, Default)]
pub struct Settings {
    folder: Option<PathBuf>,
    /// Recent diagram files, the latest first.
    pub recent: Vec<PathBuf>,
}

/// Where the studio keeps what it remembers: `$XDG_CONFIG_HOME/kairos` or `~/.config/kairos`.
pub fn default_folder() -> Option<PathBuf> {
    let base = std::env::var_os("XDG_CONFIG_HOME")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".config")))?;
    Some(base.join("kairos"))
}

/// Why what the studio remembers could not be read or written: it starts without it, and says so.
#[derive(Debug, thiserror::Error)]
pub enum SettingsError {
    /// A file there that cannot be read.
    #[error("cannot read {}: {source}", .path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// The settings' folder could not be made.
    #[error("cannot create {}: {source}", .path.display())]
    Create {
        /// The folder.
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
}

/// Why a token file named for a runtime cannot be used.
#[derive(Debug, thiserror::Error)]
#[error("cannot read the token file {}: {source}", .path.display())]
pub struct TokenFileError {
    /// The file.
    pub path: PathBuf,
    /// What the system said.
    pub source: std::io::Error,
}

/// The text of `file`, `None` when it does not exist yet.
fn read_if_any(file: &Path) -> Result<Option<String>, SettingsError> {
    match std::fs::read_to_string(file) {
        Ok(text) => Ok(Some(text)),
        Err(error) if error.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(source) => Err(SettingsError::Read {
            path: file.to_owned(),
            source,
        }),
    }
}

impl Settings {
    /// The settings kept in `folder` (none: nothing is remembered), with an error when what is there cannot
    /// be read (the settings then start empty).
    pub fn load(folder: Option<PathBuf>) -> (Settings, Option<String>) {
        let mut settings = Settings {
            folder,
            recent: Vec::new(),
        };
        let Some(folder) = &settings.folder else {
            return (settings, None);
        };
        match read_if_any(&folder.join(RECENT_FILE_NAME)) {
            Ok(text) => {
                settings.recent = text
                    .unwrap_or_default()
                    .lines()
                    .filter(|l| !l.is_empty())
                    .map(PathBuf::from)
                    .collect();
                (settings, None)
            }
            Err(error) => (settings, Some(format!("recent files: {error}"))),
        }
    }

    /// The folder the settings live in.
    pub fn folder(&self) -> Option<&Path> {
        self.folder.as_deref()
    }

    fn write(&self, name: &str, text: &str) -> Result<(), SettingsError> {
        let Some(folder) = &self.folder else {
            return Ok(());
        };
        std::fs::create_dir_all(folder).map_err(|source| SettingsError::Create {
            path: folder.clone(),
            source,
        })?;
        let file = folder.join(name);
        std::fs::write(&file, text).map_err(|source| SettingsError::Write { path: file, source })
    }

    /// Puts `path` first among the recent files and writes them.
    pub fn remember_recent(&mut self, path: PathBuf) -> Result<(), SettingsError> {
        self.recent.retain(|p| p != &path);
        self.recent.insert(0, path);
        self.recent.truncate(RECENT_FILES);
        let lines: Vec<String> = self.recent.iter().map(|p| p.display().to_string()).collect();
        self.write(RECENT_FILE_NAME, &lines.join("\n"))
    }

    /// The remote runtimes connected to, the latest first (none yet: empty).
    pub fn remembered_remotes(&self) -> Result<Vec<RemoteAddress>, SettingsError> {
        let Some(folder) = &self.folder else {
            return Ok(Vec::new());
        };
        if let Some(text) = read_if_any(&folder.join(REMOTES_FILE_NAME))? {
            return Ok(text.lines().filter_map(RemoteAddress::of_line).collect());
        }
        // Written by an earlier studio: the last runtime alone, its address and token file on two lines.
        let Some(text) = read_if_any(&folder.join(REMOTE_FILE_NAME))? else {
            return Ok(Vec::new());
        };
        let mut lines = text.lines();
        Ok(lines
            .next()
            .filter(|url| !url.is_empty())
            .map(|url| RemoteAddress {
                url: url.to_owned(),
                token_file: lines.next().unwrap_or_default().to_owned(),
                certificate: String::new(),
            })
            .into_iter()
            .collect())
    }

    /// The last remote runtime connected to; the connect dialog's default address when none was.
    pub fn remembered_remote(&self) -> Result<RemoteAddress, SettingsError> {
        Ok(self.remembered_remotes()?.into_iter().next().unwrap_or_default())
    }

    /// Remembers `remote` first among the remote runtimes (its address, token file and certificate; the
    /// token and any key are never written).
    pub fn remember_remote(&self, remote: &RemoteAddress) -> Result<(), SettingsError> {
        let mut remotes = self.remembered_remotes().unwrap_or_default();
        remotes.retain(|known| known.url != remote.url);
        remotes.insert(0, remote.clone());
        remotes.truncate(REMOTES);
        let lines: Vec<String> = remotes.iter().map(RemoteAddress::line).collect();
        self.write(REMOTES_FILE_NAME, &(lines.join("\n") + "\n"))
    }
}

/// Reads a token from the first line of `file`.
pub fn read_token(file: &Path) -> Result<kairos_protocol::Token, TokenFileError> {
    std::fs::read_to_string(file)
        .map(|text| kairos_protocol::Token::new(text.lines().next().unwrap_or_default().trim()))
        .map_err(|source| TokenFileError {
            path: file.to_owned(),
            source,
        })
}

#[cfg(test)]
mod tests {
    use super::{RemoteAddress, Settings};

    #[test]
    fn recent_files_and_the_remote_are_written_and_read_back() {
        let dir = tempfile::tempdir().unwrap();
        let (mut settings, error) = Settings::load(Some(dir.path().to_owned()));
        assert_eq!(error, None, "a folder with nothing yet is no error");
        for name in ["a.ron", "b.ron", "a.ron"] {
            settings.remember_recent(name.into()).unwrap();
        }
        let remote = RemoteAddress {
            url: "ws://robot:7400".to_owned(),
            token_file: "/home/me/robot.token".to_owned(),
            certificate: String::new(),
        };
        settings.remember_remote(&remote).unwrap();
        let (again, error) = Settings::load(Some(dir.path().to_owned()));
        assert_eq!(error, None);
        assert_eq!(again.recent, [std::path::PathBuf::from("a.ron"), "b.ron".into()]);
        assert_eq!(again.remembered_remote().unwrap(), remote);
    }

    #[test]
    fn each_remote_keeps_its_own_token_file_and_certificate_the_latest_first() {
        let dir = tempfile::tempdir().unwrap();
        // What an earlier studio remembered: the last address and its token file, on two lines.
        std::fs::write(
            dir.path().join("studio-remote.txt"),
            "ws://old:7400\n/home/me/old.token\n",
        )
        .unwrap();
        let (settings, _) = Settings::load(Some(dir.path().to_owned()));
        let old = settings.remembered_remote().unwrap();
        assert_eq!(
            (old.url.as_str(), old.token_file.as_str()),
            ("ws://old:7400", "/home/me/old.token")
        );
        let car = RemoteAddress {
            url: "wss://10.0.0.2:7400".to_owned(),
            token_file: "/home/me/car.token".to_owned(),
            certificate: "/home/me/car.pem".to_owned(),
        };
        let roadside = RemoteAddress {
            url: "wss://10.0.0.3:7400".to_owned(),
            token_file: "/home/me/roadside.token".to_owned(),
            certificate: "/home/me/ca.pem".to_owned(),
        };
        for remote in [&car, &roadside, &car] {
            settings.remember_remote(remote).unwrap();
        }
        let (again, _) = Settings::load(Some(dir.path().to_owned()));
        assert_eq!(again.remembered_remotes().unwrap(), [car, roadside, old]);
    }

    #[test]
    fn a_folder_that_cannot_be_written_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        // A file where the folder should be: nothing can be created under it.
        let blocked = dir.path().join("blocked");
        std::fs::write(&blocked, "").unwrap();
        let (mut settings, _) = Settings::load(Some(blocked.join("kairos")));
        let error = settings.remember_recent("a.ron".into()).unwrap_err();
        assert!(matches!(error, super::SettingsError::Create { .. }), "{error}");
        assert!(error.to_string().contains("cannot create"), "{error}");
        assert!(settings.remember_remote(&RemoteAddress::default()).is_err());
    }
}
