//! Reaching a host: a session with its `kairos serve` as an operator, through the one protocol client
//! (`kairos-client`), with the host's name on every error.

use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::Context as _;
use kairos_client::{CallError, ConnectError, ConnectOptions, Connection, Fixes};
use kairos_diagram::HostSpec;
use kairos_protocol::{RequestBody, Token};

/// How long reaching a host and each of its answers may take.
pub const HOST_WAIT: Duration = Duration::from_secs(5);

/// How long a health check's answer may take: a killed host or a cut link is reported within a second.
pub const HEALTH_WAIT: Duration = Duration::from_millis(600);

/// How `kairos deploy`'s user fixes what the client refuses.
const FIXES: Fixes = Fixes {
    clear_text_opt_in: "pass --allow-clear-text-tokens",
    certificate: "add certificate: \"FILE.pem\" to its Host",
};

/// How the deploying machine reaches hosts: token files and certificates are relative to `folder` (the
/// diagram's); tokens go over plain ws:// to a host off this machine only with `clear_text_tokens`.
#[derive(Debug, Clone)]
pub struct Reach {
    folder: PathBuf,
    clear_text_tokens: bool,
}

impl Reach {
    /// Token files in `folder`.
    pub fn new(folder: &Path, clear_text_tokens: bool) -> Self {
        Reach {
            folder: folder.to_owned(),
            clear_text_tokens,
        }
    }
}

/// A connection to one host's `kairos serve`, as an operator.
pub struct Host {
    name: String,
    connection: Connection,
    /// The identity of the part this deployment gave the host, as its commit replied it.
    deployment: Option<String>,
}

impl std::fmt::Debug for Host {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Host")
            .field("name", &self.name)
            .finish_non_exhaustive()
    }
}

/// A connection error in words, with the host's name.
fn unreached(name: &str, error: &ConnectError) -> anyhow::Error {
    match error {
        ConnectError::Unreachable { .. } | ConnectError::Handshake { .. } | ConnectError::Refused(_) => {
            anyhow::anyhow!("host '{name}' {error}")
        }
        _ => anyhow::anyhow!("host '{name}': {error}"),
    }
}

/// A failed request in words, with the host's name.
fn failed(name: &str, error: &CallError) -> anyhow::Error {
    anyhow::anyhow!("host '{name}' {error}")
}

impl Host {
    /// Connects to `spec`'s endpoint and says hello with the token of its token file (relative to
    /// `folder`, the diagram's).
    pub fn reach(name: &str, spec: &HostSpec, reach: &Reach) -> anyhow::Result<Self> {
        Self::reach_within(name, spec, reach, HOST_WAIT)
    }

    /// [`Host::reach`], waiting at most `wait` for the host to accept the connection.
    pub fn reach_within(name: &str, spec: &HostSpec, reach: &Reach, wait: Duration) -> anyhow::Result<Self> {
        let folder = reach.folder.as_path();
        let token = match &spec.token_file {
            Some(file) => {
                let path = folder.join(file);
                let text = std::fs::read_to_string(&path).with_context(|| {
                    format!("host '{name}': cannot read its token file {}", path.display())
                })?;
                Some(Token::new(text.trim()))
            }
            None => None,
        };
        let options = ConnectOptions {
            token,
            certificate: spec.certificate.as_ref().map(|file| folder.join(file)),
            allow_clear_text_token: reach.clear_text_tokens,
            wait,
            ..ConnectOptions::operator(format!("kairos deploy {}", env!("CARGO_PKG_VERSION")))
        };
        let connection =
            Connection::open(&spec.endpoint, &options, FIXES).map_err(|e| unreached(name, &e))?;
        connection
            .set_read_timeout(Some(HOST_WAIT))
            .map_err(|e| failed(name, &CallError::Lost(tungstenite_io(e))))?;
        Ok(Host {
            name: name.to_owned(),
            connection,
            deployment: None,
        })
    }

    /// The host's platform, from its welcome (`linux-x86_64`).
    pub fn platform(&self) -> Option<&str> {
        self.connection.welcome().platform.as_deref()
    }

    /// Whether the host still answers, within [`HEALTH_WAIT`]: its status.
    pub fn ping(&mut self) -> anyhow::Result<serde_json::Value> {
        self.set_wait(HEALTH_WAIT)?;
        let answered = self.call(RequestBody::Status);
        self.set_wait(HOST_WAIT)?;
        answered
    }

    fn set_wait(&mut self, wait: Duration) -> anyhow::Result<()> {
        self.connection
            .set_read_timeout(Some(wait))
            .map_err(|e| failed(&self.name, &CallError::Lost(tungstenite_io(e))))
    }

    /// Sends `body` and waits for its reply; a refusal names the host and the reason (and each diagnostic).
    pub fn call(&mut self, body: RequestBody) -> anyhow::Result<serde_json::Value> {
        let id = self.send(body)?;
        self.wait(id)
    }

    /// Sends `body` without waiting; its id, for [`Host::wait`].
    pub fn send(&mut self, body: RequestBody) -> anyhow::Result<u64> {
        self.connection.send(body).map_err(|e| failed(&self.name, &e))
    }

    /// The reply to request `id`.
    pub fn wait(&mut self, id: u64) -> anyhow::Result<serde_json::Value> {
        self.connection.wait(id).map_err(|e| failed(&self.name, &e))
    }

    /// The host's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The identity of the part this deployment gave the host (`status` reports the one it runs).
    pub fn deployment(&self) -> Option<&str> {
        self.deployment.as_deref()
    }

    /// Deploys `part` (RON text) on the host, joining `network`, in one step: what it ran is replaced
    /// whether or not another host accepts its part.
    pub fn deploy(
        &mut self,
        part: String,
        network: Option<kairos_protocol::LinkNetwork>,
    ) -> anyhow::Result<()> {
        let reply = self.call(RequestBody::Deploy {
            diagram: part,
            network,
            folder: None,
        })?;
        self.deployment = reply["deployment"].as_str().map(str::to_owned);
        Ok(())
    }

    /// Commits the part the host prepared under `ticket`.
    pub fn commit(&mut self, ticket: u64) -> anyhow::Result<()> {
        let reply = self.call(RequestBody::CommitDeploy { ticket })?;
        self.deployment = reply["deployment"].as_str().map(str::to_owned);
        Ok(())
    }
}

fn tungstenite_io(error: std::io::Error) -> tungstenite::Error {
    tungstenite::Error::Io(error)
}
