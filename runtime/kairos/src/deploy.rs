//! `kairos deploy`: one diagram over several machines. The diagram is split by each component's `host`;
//! each part goes to its host's `kairos serve` over the control protocol, and the part without a host runs
//! here, as `kairos run` would run it. Everything starts, or nothing does: every host is reached and every
//! part accepted before anything starts, and a failure on the way names the host and its reason.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::net::TcpStream;
use std::path::Path;
use std::time::Duration;

use anyhow::{Context as _, bail};
use kairos_diagram::{Diagram, HostSpec};
use kairos_protocol::{PROTOCOL_VERSION, Reply, Request, RequestBody, Role, Token};
use tungstenite::stream::MaybeTlsStream;
use tungstenite::{Message, WebSocket};

/// How long reaching a host and each of its answers may take.
const HOST_WAIT: Duration = Duration::from_secs(5);

/// The parts of `diagram`: by host name, and the one without a host (`None`). Connections must stay
/// within a part: one between hosts is refused with both ends named.
pub fn split(diagram: &Diagram) -> anyhow::Result<BTreeMap<Option<String>, Diagram>> {
    let host_of: BTreeMap<&str, Option<&String>> = diagram
        .components
        .iter()
        .map(|c| (c.id.as_str(), c.host.as_ref()))
        .collect();
    let mut parts: BTreeMap<Option<String>, Diagram> = BTreeMap::new();
    for component in &diagram.components {
        let part = parts.entry(component.host.clone()).or_insert_with(|| Diagram {
            packs: diagram.packs.clone(),
            ..Diagram::default()
        });
        let mut placed = component.clone();
        placed.host = None;
        part.components.push(placed);
    }
    for connection in &diagram.connections {
        let from = host_of.get(connection.from.component.as_str()).copied().flatten();
        let to = host_of.get(connection.to.component.as_str()).copied().flatten();
        if from != to {
            let name = |host: Option<&String>| {
                host.map_or_else(|| "this machine".to_owned(), |h| format!("host '{h}'"))
            };
            bail!(
                "the connection {} -> {} crosses from {} to {}: links between hosts are not part of this version; \
                 place both ends on one host",
                connection.from,
                connection.to,
                name(from),
                name(to)
            );
        }
        if let Some(part) = parts.get_mut(&from.cloned()) {
            part.connections.push(connection.clone());
        }
    }
    for part in parts.values_mut() {
        if diagram
            .clock_source
            .as_ref()
            .is_some_and(|source| part.component(source).is_some())
        {
            part.clock_source.clone_from(&diagram.clock_source);
        }
        // A host needs the packs of its own part only.
        let used: Vec<&str> = part
            .components
            .iter()
            .filter_map(|c| c.type_name.split_once('.').map(|(pack, _)| pack))
            .collect();
        part.packs.retain(|pack| used.contains(&pack.name.as_str()));
    }
    Ok(parts)
}

/// A connection to one host's `kairos serve`, as an operator.
pub struct Host {
    name: String,
    socket: WebSocket<MaybeTlsStream<TcpStream>>,
    next_id: u64,
}

impl std::fmt::Debug for Host {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Host")
            .field("name", &self.name)
            .finish_non_exhaustive()
    }
}

impl Host {
    /// Connects to `spec`'s endpoint and says hello with the token of its token file (relative to
    /// `folder`, the diagram's).
    pub fn reach(name: &str, spec: &HostSpec, folder: &Path) -> anyhow::Result<Self> {
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
        let address = spec
            .endpoint
            .split("://")
            .nth(1)
            .and_then(|rest| rest.split('/').next())
            .unwrap_or_default()
            .to_owned();
        if spec.endpoint.starts_with("wss://") {
            bail!("host '{name}': wss:// endpoints are not part of this version; use ws://");
        }
        let stream = std::net::ToSocketAddrs::to_socket_addrs(&address.as_str())
            .ok()
            .and_then(|mut addresses| addresses.next())
            .and_then(|address| TcpStream::connect_timeout(&address, HOST_WAIT).ok())
            .with_context(|| format!("host '{name}' is unreachable at {}", spec.endpoint))?;
        stream.set_read_timeout(Some(HOST_WAIT))?;
        let (socket, _) = tungstenite::client(spec.endpoint.as_str(), MaybeTlsStream::Plain(stream))
            .map_err(|e| anyhow::anyhow!("host '{name}' at {}: {e}", spec.endpoint))?;
        let mut host = Host {
            name: name.to_owned(),
            socket,
            next_id: 1,
        };
        host.call(RequestBody::Hello {
            protocol: PROTOCOL_VERSION,
            client: format!("kairos deploy {}", env!("CARGO_PKG_VERSION")),
            token,
            role: Some(Role::Operator),
        })?;
        Ok(host)
    }

    /// Sends `body` and waits for its reply; a refusal names the host and the reason (and each diagnostic).
    pub fn call(&mut self, body: RequestBody) -> anyhow::Result<serde_json::Value> {
        let id = self.send(body)?;
        self.wait(id)
    }

    /// Sends `body` without waiting; its id, for [`Host::wait`].
    pub fn send(&mut self, body: RequestBody) -> anyhow::Result<u64> {
        let id = self.next_id;
        self.next_id += 1;
        let text = serde_json::to_string(&Request { id, body })?;
        self.socket
            .send(Message::text(text))
            .map_err(|e| anyhow::anyhow!("host '{}': {e}", self.name))?;
        Ok(id)
    }

    /// The reply to request `id`.
    pub fn wait(&mut self, id: u64) -> anyhow::Result<serde_json::Value> {
        loop {
            let message = self
                .socket
                .read()
                .map_err(|e| anyhow::anyhow!("host '{}' stopped answering: {e}", self.name))?;
            let Message::Text(text) = message else { continue };
            let Ok(value) = serde_json::from_str::<serde_json::Value>(text.as_str()) else {
                continue;
            };
            if value["type"] != "reply" || value["id"] != id {
                continue;
            }
            let reply: Reply = serde_json::from_value(value)?;
            if let Some(error) = reply.error.filter(|_| !reply.ok) {
                let mut why = format!("host '{}' refused: {}", self.name, error.message);
                for diagnostic in &error.diagnostics {
                    let _ = write!(why, "\n  {diagnostic}");
                }
                bail!(why);
            }
            return Ok(reply.result.unwrap_or_default());
        }
    }

    /// The host's name.
    pub fn name(&self) -> &str {
        &self.name
    }
}

/// Reaches every host of `parts` and deploys each part, or fails naming the host and its reason. Nothing
/// is started.
pub fn deploy_remote(
    diagram: &Diagram,
    parts: &BTreeMap<Option<String>, Diagram>,
    folder: &Path,
) -> anyhow::Result<Vec<Host>> {
    let mut hosts = Vec::new();
    for name in parts.keys().flatten() {
        let Some(spec) = diagram.hosts.get(name) else {
            bail!("no host '{name}' in the diagram's hosts");
        };
        hosts.push(Host::reach(name, spec, folder)?);
    }
    for host in &mut hosts {
        let part = parts
            .get(&Some(host.name().to_owned()))
            .map(Diagram::to_ron)
            .unwrap_or_default();
        host.call(RequestBody::Deploy { diagram: part })?;
    }
    Ok(hosts)
}

/// How far ahead of now the hosts are told to start: time for every request to arrive.
pub const START_LEAD: Duration = Duration::from_millis(500);

/// Asks every host to start at `at` (ns since the UNIX epoch on its clock), without waiting: each answers
/// once started. Collect the answers with [`confirm_started`].
pub fn start_all_at(hosts: &mut [Host], at: i64) -> anyhow::Result<Vec<u64>> {
    hosts
        .iter_mut()
        .map(|host| host.send(RequestBody::Start { at_ns: Some(at) }))
        .collect()
}

/// The hosts' answers to [`start_all_at`]; the first refusal, after stopping every host.
pub fn confirm_started(hosts: &mut [Host], ids: &[u64]) -> anyhow::Result<()> {
    let mut refused = None;
    for (host, id) in hosts.iter_mut().zip(ids) {
        if let Err(error) = host.wait(*id) {
            refused.get_or_insert(error);
        }
    }
    match refused {
        None => Ok(()),
        Some(error) => {
            stop_all(hosts);
            Err(error)
        }
    }
}

/// Stops every host's part, saying which could not be stopped.
pub fn stop_all(hosts: &mut [Host]) {
    for host in hosts {
        match host.call(RequestBody::Stop) {
            Ok(_) => tracing::info!("host '{}' stopped", host.name()),
            Err(error) => tracing::warn!("{error}"),
        }
    }
}
