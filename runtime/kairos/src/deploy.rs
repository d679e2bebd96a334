//! `kairos deploy`: one diagram over several machines. The diagram is split by each component's `host`;
//! each part goes to its host's `kairos serve` over the control protocol, and the part without a host runs
//! here, as `kairos run` would run it. Everything starts, or nothing does: every host is reached and every
//! part accepted before anything starts, and a failure on the way names the host and its reason.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::{Context as _, bail};
use kairos_diagram::{Connection, Diagram, HostSpec, PortRef, ReaderPolicy, Value};
use kairos_protocol::{LinkList, LinkNetwork, PROTOCOL_VERSION, Reply, Request, RequestBody, Role, Token};
use kairos_sdk::Registry;
use tungstenite::{Message, WebSocket};

/// How long reaching a host and each of its answers may take.
const HOST_WAIT: Duration = Duration::from_secs(5);

/// A diagram split over its hosts.
#[derive(Debug, Default)]
pub struct Plan {
    /// The parts, by host name, and the one without a host (`None`, run by the deploying machine). Each
    /// connection between two hosts became a `link.sender` in the producer's part and a `link.receiver`
    /// in the consumer's.
    pub parts: BTreeMap<Option<String>, Diagram>,
    /// Those connections.
    pub links: Vec<CrossLink>,
    /// The packs each part needs, as loaded here: shipped to a host that lacks them.
    pub packs: BTreeMap<Option<String>, Vec<PackNeed>>,
}

/// A pack a part needs, as the deploying machine has it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PackNeed {
    /// Its name.
    pub name: String,
    /// Its version.
    pub version: String,
    /// The library it was loaded from here; `None` for a pack built into `kairos`.
    pub library: Option<PathBuf>,
}

/// The packs of `part`'s components, as `library` has them.
fn packs_needed(part: &Diagram, library: &kairos_diagram::LibraryInfo) -> Vec<PackNeed> {
    let mut needs: Vec<PackNeed> = Vec::new();
    for component in &part.components {
        let Some(pack) = library
            .components
            .get(&component.type_name)
            .and_then(|c| library.packs.get(&c.pack))
        else {
            continue;
        };
        if needs.iter().any(|n| n.name == pack.name) {
            continue;
        }
        needs.push(PackNeed {
            name: pack.name.clone(),
            version: pack.version.clone(),
            library: (pack.origin != "built-in").then(|| PathBuf::from(&pack.origin)),
        });
    }
    needs
}

/// A connection between two hosts.
#[derive(Debug, Clone)]
pub struct CrossLink {
    /// `camera.image on host 'car'`.
    pub from: String,
    /// `viewer.in on this machine`.
    pub to: String,
    /// The Zenoh key its samples travel under.
    pub key: String,
    /// The connection it carries.
    pub connection: Connection,
    /// The producer's host and the id of the `link.sender` added there.
    pub sender: (Option<String>, String),
    /// The consumer's host and the id of the `link.receiver` added there.
    pub receiver: (Option<String>, String),
}

/// Where a part runs, in words.
fn place(host: Option<&String>) -> String {
    host.map_or_else(|| "this machine".to_owned(), |h| format!("host '{h}'"))
}

/// An id for a component added to `part`, unused by the diagram and the part.
fn free_id(diagram: &Diagram, part: &Diagram, wanted: &str) -> String {
    let taken = |id: &str| diagram.component(id).is_some() || part.component(id).is_some();
    let mut id = wanted.to_owned();
    let mut suffix = 2;
    while taken(&id) {
        id = format!("{wanted}_{suffix}");
        suffix += 1;
    }
    id
}

/// Splits `diagram` by each component's `host`, links between hosts included. `deployment` tells this
/// deployment's keys from any other's on the same network.
///
/// # Errors
///
/// A connection whose ends are not both in the diagram (validation refuses those first).
pub fn split(diagram: &Diagram, registry: &Registry, deployment: &str) -> anyhow::Result<Plan> {
    let host_of: BTreeMap<&str, Option<&String>> = diagram
        .components
        .iter()
        .map(|c| (c.id.as_str(), c.host.as_ref()))
        .collect();
    let mut plan = Plan::default();
    let new_part = || Diagram {
        packs: diagram.packs.clone(),
        ..Diagram::default()
    };
    for component in &diagram.components {
        let part = plan.parts.entry(component.host.clone()).or_insert_with(new_part);
        let mut placed = component.clone();
        placed.host = None;
        part.components.push(placed);
    }
    let infos = registry.instance_infos(diagram);
    for connection in &diagram.connections {
        let (Some(&from), Some(&to)) = (
            host_of.get(connection.from.component.as_str()),
            host_of.get(connection.to.component.as_str()),
        ) else {
            bail!(
                "the connection {} -> {} names a component the diagram lacks",
                connection.from,
                connection.to
            );
        };
        if from == to {
            plan.parts
                .entry(from.cloned())
                .or_insert_with(new_part)
                .connections
                .push(connection.clone());
            continue;
        }
        // An instance's own descriptor where its ports depend on its properties, else its type's.
        let info = |id: &str| {
            infos.get(id).and_then(|r| r.as_ref().ok()).or_else(|| {
                let component = diagram.component(id)?;
                registry.component(&component.type_name).map(|r| &r.info)
            })
        };
        let data_type = info(&connection.from.component)
            .and_then(|i| i.outputs.iter().find(|o| o.name == connection.from.port))
            .map(|o| o.data_type.to_string())
            .with_context(|| {
                format!(
                    "the connection {} -> {}: no such output",
                    connection.from, connection.to
                )
            })?;
        let policy = connection.policy.or_else(|| {
            info(&connection.to.component)
                .and_then(|i| i.inputs.iter().find(|p| p.name == connection.to.port))
                .map(|p| p.default_policy)
        });
        let reliable = policy == Some(ReaderPolicy::NeverSkipping);
        let link = place_link(
            &mut plan,
            diagram,
            connection,
            (from, to),
            &data_type,
            reliable,
            deployment,
        );
        plan.links.push(link);
    }
    for part in plan.parts.values_mut() {
        if diagram
            .clock_source
            .as_ref()
            .is_some_and(|source| part.component(source).is_some())
        {
            part.clock_source.clone_from(&diagram.clock_source);
        }
        // A host needs the packs of its own part only (links are built in).
        let used: Vec<&str> = part
            .components
            .iter()
            .filter_map(|c| c.type_name.split_once('.').map(|(pack, _)| pack))
            .collect();
        part.packs.retain(|pack| used.contains(&pack.name.as_str()));
    }
    let library = registry.library_info();
    plan.packs = plan
        .parts
        .iter()
        .map(|(host, part)| (host.clone(), packs_needed(part, &library)))
        .collect();
    Ok(plan)
}

/// A link component of `type_name` carrying `key`.
fn link_component(
    type_name: &str,
    id: &str,
    key: &str,
    reliable: bool,
    peer: &str,
) -> kairos_diagram::ComponentInstance {
    let mut component = kairos_diagram::ComponentInstance::new(id, type_name);
    for (name, value) in [
        ("key", Value::Text(key.to_owned())),
        ("reliable", Value::Bool(reliable)),
        ("peer", Value::Text(peer.to_owned())),
    ] {
        component.properties.insert(name.to_owned(), value);
    }
    component
}

/// Puts the two ends of `connection`, between the hosts `from` and `to`, into their parts: a sender
/// reading the output on the producer's host (the connection's subsampling applied there, so what is
/// dropped never travels), a receiver on the consumer's whose output the consumer reads with the
/// connection's policy and buffer size.
fn place_link(
    plan: &mut Plan,
    diagram: &Diagram,
    connection: &Connection,
    (from, to): (Option<&String>, Option<&String>),
    data_type: &str,
    reliable: bool,
    deployment: &str,
) -> CrossLink {
    let new_part = || Diagram {
        packs: diagram.packs.clone(),
        ..Diagram::default()
    };
    let key = format!(
        "kairos/{deployment}/{}/{}/{}/{}",
        connection.from.component, connection.from.port, connection.to.component, connection.to.port
    );
    let from_words = format!("{} on {}", connection.from, place(from));
    let to_words = format!("{} on {}", connection.to, place(to));

    let producing = plan.parts.entry(from.cloned()).or_insert_with(new_part);
    let sender_id = free_id(
        diagram,
        producing,
        &format!("link_to_{}_{}", connection.to.component, connection.to.port),
    );
    producing.components.push(link_component(
        crate::link::SENDER,
        &sender_id,
        &key,
        reliable,
        &to_words,
    ));
    producing.connections.push(Connection {
        policy: Some(if reliable {
            ReaderPolicy::NeverSkipping
        } else {
            ReaderPolicy::Fifo
        }),
        buffer_size: connection.buffer_size,
        subsampling: connection.subsampling,
        ..Connection::new(connection.from.clone(), PortRef::new(&sender_id, "in"))
    });

    let consuming = plan.parts.entry(to.cloned()).or_insert_with(new_part);
    let receiver_id = free_id(
        diagram,
        consuming,
        &format!("link_from_{}_{}", connection.from.component, connection.from.port),
    );
    let queue = connection
        .buffer_size
        .and_then(|q| i64::try_from(q).ok())
        .unwrap_or(64);
    let mut receiver = link_component(crate::link::RECEIVER, &receiver_id, &key, reliable, &from_words);
    receiver
        .properties
        .insert("data_type".to_owned(), Value::Text(data_type.to_owned()));
    receiver.properties.insert("queue".to_owned(), Value::I64(queue));
    receiver
        .properties
        .insert("origin".to_owned(), Value::Text(connection.from.to_string()));
    consuming.components.push(receiver);
    consuming.connections.push(Connection {
        from: PortRef::new(&receiver_id, crate::link::SAMPLES_OUTPUT),
        subsampling: None,
        ..connection.clone()
    });
    CrossLink {
        from: from_words,
        to: to_words,
        key,
        connection: connection.clone(),
        sender: (from.cloned(), sender_id),
        receiver: (to.cloned(), receiver_id),
    }
}

/// Each part's link network, by host (`None`: the deploying machine).
pub type Networks = BTreeMap<Option<String>, LinkNetwork>;

/// Each part's link network: every host with links listens on its own Zenoh endpoint and connects to the
/// hosts after it, or to those before it that take TLS where it does not; this machine, when its part has
/// links, connects to them all. Whoever connects to a `tls/` endpoint trusts the certificates of the hosts
/// section (read from `folder`, the diagram's).
///
/// # Errors
///
/// A `tls/` endpoint of a host without a `certificate`, or a certificate file that cannot be read.
pub fn networks(
    diagram: &Diagram,
    plan: &Plan,
    folder: &Path,
) -> anyhow::Result<BTreeMap<Option<String>, LinkNetwork>> {
    let has_links = |part: &Diagram| part.components.iter().any(|c| crate::link::is_link(&c.type_name));
    let linked: Vec<(&String, String)> = plan
        .parts
        .iter()
        .filter(|(_, part)| has_links(part))
        .filter_map(|(host, _)| host.as_ref())
        .filter_map(|host| diagram.hosts.get(host).map(|spec| (host, spec.zenoh_endpoint())))
        .collect();
    let mut trusted = Vec::new();
    for (host, endpoint) in linked.iter().filter(|(_, e)| e.starts_with("tls/")) {
        let Some(file) = diagram
            .hosts
            .get(*host)
            .and_then(|spec| spec.certificate.as_ref())
        else {
            bail!(
                "host '{host}' takes its links over TLS ({endpoint}) but has no `certificate` to trust in the \
                 hosts section: give it the host's certificate (its kairos serve --tls-cert), or a tcp/ zenoh \
                 endpoint"
            );
        };
        let path = folder.join(file);
        let pem = std::fs::read_to_string(&path)
            .with_context(|| format!("host '{host}': cannot read its certificate {}", path.display()))?;
        if !trusted.contains(&pem) {
            trusted.push(pem);
        }
    }
    // Each pair is joined once. The side that connects chooses the transport, so a host that asked for
    // TLS is the one connected to: its samples never cross in clear because the other side listens on TCP.
    let is_tls = |index: usize| linked[index].1.starts_with("tls/");
    let mut networks = BTreeMap::new();
    for (index, (host, endpoint)) in linked.iter().enumerate() {
        let connect = (0..linked.len())
            .filter(|&other| other != index)
            .filter(|&other| match (is_tls(index), is_tls(other)) {
                (false, true) => true,
                (true, false) => false,
                _ => other > index,
            })
            .map(|other| linked[other].1.clone())
            .collect();
        networks.insert(
            Some((*host).clone()),
            LinkNetwork {
                listen: vec![endpoint.clone()],
                connect,
                trusted_certificates: trusted.clone(),
            },
        );
    }
    if plan.parts.get(&None).is_some_and(has_links) {
        networks.insert(
            None,
            LinkNetwork {
                listen: Vec::new(),
                connect: linked.iter().map(|(_, e)| e.clone()).collect(),
                trusted_certificates: trusted,
            },
        );
    }
    Ok(networks)
}

/// A name for this deployment's keys: the deploying process and the time it started.
pub fn deployment_name() -> String {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos());
    format!("{:x}{:x}", std::process::id(), nanos & 0xffff_ffff)
}

/// How the deploying machine reaches hosts: token files are relative to `folder` (the diagram's); tokens
/// go over plain ws:// to a host off this machine only with `clear_text_tokens`.
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
    socket: WebSocket<Stream>,
    /// The connection under it, for its timeouts.
    tcp: TcpStream,
    next_id: u64,
    /// The host's platform, from its welcome (`linux-x86_64`).
    platform: Option<String>,
}

/// What a host's WebSocket runs on: TCP, or TLS over TCP for a `wss://` endpoint.
enum Stream {
    Plain(TcpStream),
    Tls(Box<rustls::StreamOwned<rustls::ClientConnection, TcpStream>>),
}

impl std::io::Read for Stream {
    fn read(&mut self, buffer: &mut [u8]) -> std::io::Result<usize> {
        match self {
            Stream::Plain(stream) => stream.read(buffer),
            Stream::Tls(stream) => stream.read(buffer),
        }
    }
}

impl std::io::Write for Stream {
    fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
        match self {
            Stream::Plain(stream) => stream.write(bytes),
            Stream::Tls(stream) => stream.write(bytes),
        }
    }

    fn flush(&mut self) -> std::io::Result<()> {
        match self {
            Stream::Plain(stream) => stream.flush(),
            Stream::Tls(stream) => stream.flush(),
        }
    }
}

/// TLS over `stream` to host `name`, trusting the certificate its spec names (relative to `folder`) and
/// checking it is `server`'s.
fn tls_client(
    name: &str,
    spec: &HostSpec,
    folder: &Path,
    server: &str,
    stream: TcpStream,
) -> anyhow::Result<rustls::StreamOwned<rustls::ClientConnection, TcpStream>> {
    use rustls::pki_types::pem::PemObject as _;
    use rustls::pki_types::{CertificateDer, ServerName};
    let Some(certificate) = &spec.certificate else {
        bail!(
            "host '{name}': a wss:// endpoint needs the certificate to trust: add certificate: \"FILE.pem\" \
             to its Host (the host's certificate, or the authority that issued it)"
        );
    };
    let path = folder.join(certificate);
    let mut roots = rustls::RootCertStore::empty();
    for trusted in CertificateDer::pem_file_iter(&path).map_err(|e| {
        anyhow::anyhow!(
            "host '{name}': cannot read the certificate {}: {e}",
            path.display()
        )
    })? {
        let trusted = trusted.map_err(|e| {
            anyhow::anyhow!("host '{name}': {} is not a PEM certificate: {e}", path.display())
        })?;
        roots
            .add(trusted)
            .map_err(|e| anyhow::anyhow!("host '{name}': {}: {e}", path.display()))?;
    }
    let config = rustls::ClientConfig::builder_with_provider(std::sync::Arc::new(
        rustls::crypto::ring::default_provider(),
    ))
    .with_safe_default_protocol_versions()?
    .with_root_certificates(roots)
    .with_no_client_auth();
    let server = server.trim_start_matches('[').trim_end_matches(']');
    let server_name = ServerName::try_from(server.to_owned())
        .map_err(|e| anyhow::anyhow!("host '{name}': {server} cannot name a TLS server: {e}"))?;
    let connection = rustls::ClientConnection::new(std::sync::Arc::new(config), server_name)?;
    Ok(rustls::StreamOwned::new(connection, stream))
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
        let address = spec
            .endpoint
            .split("://")
            .nth(1)
            .and_then(|rest| rest.split('/').next())
            .unwrap_or_default()
            .to_owned();
        let secure = spec.endpoint.starts_with("wss://");
        let resolved = std::net::ToSocketAddrs::to_socket_addrs(&address.as_str())
            .ok()
            .and_then(|mut addresses| addresses.next());
        if token.is_some()
            && !secure
            && !reach.clear_text_tokens
            && resolved.is_some_and(|address| !address.ip().is_loopback())
        {
            bail!(
                "host '{name}': its token would cross the network in clear text to {} (ws://), where anyone \
                 on the path can read it and take control of that runtime; use a wss:// endpoint, or pass \
                 --allow-clear-text-tokens on a network you trust",
                spec.endpoint
            );
        }
        let stream = resolved
            .and_then(|address| TcpStream::connect_timeout(&address, wait).ok())
            .with_context(|| format!("host '{name}' is unreachable at {}", spec.endpoint))?;
        stream.set_read_timeout(Some(HOST_WAIT))?;
        let tcp = stream.try_clone()?;
        let stream = if secure {
            let host = address
                .rsplit_once(':')
                .map_or(address.as_str(), |(host, _)| host);
            Stream::Tls(Box::new(tls_client(name, spec, folder, host, stream)?))
        } else {
            Stream::Plain(stream)
        };
        let (socket, _) = tungstenite::client(spec.endpoint.as_str(), stream).map_err(|e| {
            let hint = if secure && e.to_string().contains("certificate") {
                "; is `certificate` the host's own (its --tls-cert) or the authority that issued it?"
            } else {
                ""
            };
            anyhow::anyhow!("host '{name}' at {}: {e}{hint}", spec.endpoint)
        })?;
        let mut host = Host {
            name: name.to_owned(),
            socket,
            tcp,
            next_id: 1,
            platform: None,
        };
        let welcome = host.call(RequestBody::Hello {
            protocol: PROTOCOL_VERSION,
            client: format!("kairos deploy {}", env!("CARGO_PKG_VERSION")),
            token,
            role: Some(Role::Operator),
        })?;
        host.platform = welcome["platform"].as_str().map(str::to_owned);
        Ok(host)
    }

    /// Whether the host still answers, within [`HEALTH_WAIT`]: its status.
    pub fn ping(&mut self) -> anyhow::Result<serde_json::Value> {
        self.set_wait(HEALTH_WAIT)?;
        let answered = self.call(RequestBody::Status);
        self.set_wait(HOST_WAIT)?;
        answered
    }

    fn set_wait(&mut self, wait: Duration) -> anyhow::Result<()> {
        self.tcp.set_read_timeout(Some(wait))?;
        Ok(())
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

/// Splits `diagram` over its hosts, deploys each host's part (shipping the packs it lacks), joins this
/// machine's links and waits for every link to match: this machine's part, and the hosts to watch. Token
/// files and certificates are found in `folder`; tokens go over plain `ws://` off this machine only with
/// `clear_text_tokens`. Nothing is started. Both `kairos deploy` and a server coordinating a diagram for
/// its client (the studio's Run) deploy this way.
///
/// # Errors
///
/// An unreachable host, a refused part or pack, a link that does not match: named with the reason.
pub fn deploy_everywhere(
    diagram: &Diagram,
    registry: &Registry,
    folder: &Path,
    clear_text_tokens: bool,
) -> anyhow::Result<(Diagram, Watch)> {
    let plan = split(diagram, registry, &deployment_name())?;
    let networks = networks(diagram, &plan, folder)?;
    let reach = Reach::new(folder, clear_text_tokens);
    let mut hosts = deploy_remote(diagram, &plan, &networks, &reach)?;
    let here = plan.parts.get(&None).cloned().unwrap_or_default();
    if let Some(network) = networks.get(&None) {
        crate::link::network::join(network)?;
    }
    crate::link::network::prepare(&here)?;
    wait_for_links(&plan, &mut hosts, &networks)?;
    for link in &plan.links {
        tracing::info!("linked {} -> {}", link.from, link.to);
    }
    Ok((here, Watch::new(diagram.clone(), plan, networks, reach, hosts)))
}

/// Reaches every host of `plan` and deploys each part with its link network, or fails naming the host
/// and its reason. Nothing is started.
fn deploy_remote(
    diagram: &Diagram,
    plan: &Plan,
    networks: &BTreeMap<Option<String>, LinkNetwork>,
    reach: &Reach,
) -> anyhow::Result<Vec<Host>> {
    let mut hosts = Vec::new();
    for name in plan.parts.keys().flatten() {
        let Some(spec) = diagram.hosts.get(name) else {
            bail!("no host '{name}' in the diagram's hosts");
        };
        hosts.push(Host::reach(name, spec, reach)?);
    }
    for host in &mut hosts {
        let key = Some(host.name().to_owned());
        ship_packs(host, plan.packs.get(&key).map_or(&[], Vec::as_slice))?;
    }
    for host in &mut hosts {
        let key = Some(host.name().to_owned());
        let part = plan.parts.get(&key).map(Diagram::to_ron).unwrap_or_default();
        host.call(RequestBody::Deploy {
            diagram: part,
            network: networks.get(&key).cloned(),
            folder: None,
        })?;
    }
    Ok(hosts)
}

/// Sends `host` every pack of `needs` it lacks, or fails naming the pack and the reason: another version
/// loaded there, a pack built into `kairos` missing there (another build of `kairos`), or another platform.
pub fn ship_packs(host: &mut Host, needs: &[PackNeed]) -> anyhow::Result<()> {
    if needs.is_empty() {
        return Ok(());
    }
    let library: kairos_diagram::LibraryInfo = serde_json::from_value(host.call(RequestBody::Library)?)
        .with_context(|| format!("host '{}': its component library is unreadable", host.name))?;
    for need in needs {
        let (name, version) = (&need.name, &need.version);
        if let Some(there) = library.packs.get(name) {
            if there.version == *version {
                continue;
            }
            bail!(
                "host '{}' has pack '{name}' {} (from {}), and this diagram needs {version}{}: put {version} on \
                 that host's pack path and restart its kairos serve",
                host.name,
                there.version,
                there.origin,
                need.library
                    .as_ref()
                    .map(|p| format!(" (from {} here)", p.display()))
                    .unwrap_or_default()
            );
        }
        let Some(path) = &need.library else {
            bail!(
                "host '{}' lacks pack '{name}', which is built into this kairos {}: it runs another build of \
                 kairos; install the same kairos there",
                host.name,
                env!("CARGO_PKG_VERSION")
            );
        };
        if kairos_runtime::python_host::is_python_pack(path) {
            let archive = python_pack_archive(path)
                .with_context(|| format!("pack '{name}': cannot pack its folder {}", path.display()))?;
            send_pack(host, need, kairos_protocol::PYTHON_PACK_PLATFORM, &archive)?;
            println!(
                "shipped Python pack {name} {version} to host '{}' ({} KiB)",
                host.name,
                archive.len().div_ceil(1024)
            );
            continue;
        }
        let platform = kairos_protocol::this_platform();
        if let Some(theirs) = host.platform.as_ref().filter(|p| **p != platform) {
            bail!(
                "host '{}' lacks pack '{name}' {version}, and the library here ({}) was built for {platform}, \
                 which cannot load on that host ({theirs}): build the pack for {theirs} and put it on that \
                 host's pack path",
                host.name,
                path.display()
            );
        }
        let bytes = std::fs::read(path)
            .with_context(|| format!("pack '{name}': cannot read its library {}", path.display()))?;
        send_pack(host, need, &platform, &bytes)?;
        println!(
            "shipped pack {name} {version} to host '{}' ({} KiB)",
            host.name,
            bytes.len().div_ceil(1024)
        );
    }
    Ok(())
}

/// The files of the Python pack in `folder` as a tar archive: its manifest, code and data, without what
/// belongs to this machine alone (virtual environments, `__pycache__`, hidden folders such as `.venv` or
/// `.git`). The host runs it with its own interpreter, as the manifest names it there.
fn python_pack_archive(folder: &Path) -> std::io::Result<Vec<u8>> {
    let mut archive = tar::Builder::new(Vec::new());
    archive.follow_symlinks(true);
    let mut pending = vec![PathBuf::new()];
    while let Some(relative) = pending.pop() {
        let mut entries: Vec<std::fs::DirEntry> =
            std::fs::read_dir(folder.join(&relative))?.collect::<Result<_, _>>()?;
        entries.sort_by_key(std::fs::DirEntry::file_name);
        for entry in entries {
            let name = entry.file_name();
            let inside = relative.join(&name);
            let path = entry.path();
            let hidden = name.to_string_lossy().starts_with('.');
            if path.is_dir() {
                let environment = path.join("pyvenv.cfg").is_file();
                if !hidden && !environment && name != "__pycache__" {
                    pending.push(inside);
                }
            } else if path.is_file() && !hidden {
                archive.append_path_with_name(&path, &inside)?;
            }
        }
    }
    archive.into_inner()
}

/// Sends one pack library to `host` in `install_pack` chunks.
fn send_pack(host: &mut Host, need: &PackNeed, platform: &str, bytes: &[u8]) -> anyhow::Result<()> {
    use base64::Engine as _;
    let mut offset = 0;
    // An empty library still takes one (empty) chunk, which the host then refuses as no library.
    loop {
        let end = bytes.len().min(offset + kairos_protocol::PACK_CHUNK_BYTES);
        host.call(RequestBody::InstallPack {
            name: need.name.clone(),
            version: need.version.clone(),
            platform: platform.to_owned(),
            size: bytes.len() as u64,
            offset: offset as u64,
            data: base64::engine::general_purpose::STANDARD.encode(&bytes[offset..end]),
        })
        .with_context(|| format!("shipping pack '{}' {}", need.name, need.version))?;
        offset = end;
        if offset >= bytes.len() {
            return Ok(());
        }
    }
}

/// How long the links between hosts may take to match once every part is deployed.
pub const LINK_MATCH_WAIT: Duration = Duration::from_secs(5);

/// Waits until every link of `plan` has matched (its sender sees its receiver), here and on every host;
/// a link that does not within [`LINK_MATCH_WAIT`] is an error naming both ends.
fn wait_for_links(
    plan: &Plan,
    hosts: &mut [Host],
    networks: &BTreeMap<Option<String>, LinkNetwork>,
) -> anyhow::Result<()> {
    if plan.links.is_empty() {
        return Ok(());
    }
    let deadline = std::time::Instant::now() + LINK_MATCH_WAIT;
    loop {
        let mut matched: Vec<String> = crate::link::network::ends()
            .into_iter()
            .filter(|end| end.matched && end.role == "sender")
            .map(|end| end.key)
            .collect();
        for host in hosts.iter_mut() {
            let list: LinkList = serde_json::from_value(host.call(RequestBody::Links)?)?;
            matched.extend(
                list.links
                    .into_iter()
                    .filter(|end| end.matched && end.role == "sender")
                    .map(|end| end.key),
            );
        }
        let waiting: Vec<&CrossLink> = plan.links.iter().filter(|l| !matched.contains(&l.key)).collect();
        if waiting.is_empty() {
            return Ok(());
        }
        if std::time::Instant::now() >= deadline {
            let mut why = format!(
                "{} link(s) between hosts did not match within {} s, so nothing was started:",
                waiting.len(),
                LINK_MATCH_WAIT.as_secs()
            );
            for link in waiting {
                let _ = write!(why, "\n  {} -> {}", link.from, link.to);
            }
            let _ = write!(why, "\n  the hosts' link endpoints:");
            for (host, network) in networks {
                let _ = write!(
                    why,
                    "\n    {} listens on [{}], connects to [{}]",
                    place(host.as_ref()),
                    network.listen.join(", "),
                    network.connect.join(", ")
                );
            }
            let _ = write!(
                why,
                "\n  check that each listening address is this host's and that a firewall lets the others reach it \
                 (set it with `zenoh: \"tcp/ADDRESS:PORT\"` in the hosts section)"
            );
            bail!(why);
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// Checks, before anything starts, that every host whose clock follows a master is locked to it within
/// `bound`. A host that is not is named with its state and error, and nothing starts, unless
/// `start_unlocked` (then it is only warned about, and the hosts not locked are returned in words, for the
/// recordings). A host following no master starts on its own clock, which is said.
fn check_clocks(hosts: &mut [Host], bound: Duration, start_unlocked: bool) -> anyhow::Result<Option<String>> {
    let bound_ns = i64::try_from(bound.as_nanos()).unwrap_or(i64::MAX);
    let mut unlocked = Vec::new();
    for host in hosts.iter_mut() {
        let status = host.call(RequestBody::Status)?;
        let clock = &status["clock"];
        let Some(state) = clock["state"].as_str() else {
            tracing::warn!(
                "host '{}' follows no clock master: it reaches the start instant on its own clock \
                 (`kairos serve --clock-slave-of` synchronises it)",
                host.name()
            );
            continue;
        };
        if state == "master" {
            tracing::info!("host '{}' is the clock master", host.name());
            continue;
        }
        // The master's bound where it gives one (half the exchange's round trip), else the last error.
        let error_ns = clock["error_bound_ns"]
            .as_i64()
            .or_else(|| clock["error_ns"].as_i64())
            .unwrap_or(i64::MAX);
        if state == "locked" && error_ns.abs() <= bound_ns {
            tracing::info!(
                "host '{}': clock locked, within ±{:.1} µs",
                host.name(),
                error_ns.unsigned_abs() as f64 * 1e-3
            );
        } else if state == "acquiring" {
            unlocked.push(format!(
                "host '{}': clock acquiring (no exchange with its master yet)",
                host.name()
            ));
        } else {
            unlocked.push(format!(
                "host '{}': clock {state}, error {:+.3} ms",
                host.name(),
                error_ns as f64 * 1e-6
            ));
        }
    }
    if unlocked.is_empty() {
        return Ok(None);
    }
    let list = unlocked.join("; ");
    if start_unlocked {
        tracing::warn!("starting with clocks not locked within {bound:?}, as asked: {list}");
        return Ok(Some(format!("not locked within {bound:?}: {list}")));
    }
    bail!(
        "not every host's clock is locked to its master within {bound:?}, so nothing was started: {list}; \
         wait for them to lock, raise --lock-bound, or pass --start-unlocked to start anyway"
    )
}

/// How far ahead of now the hosts are told to stop: time for every request to arrive.
pub const STOP_LEAD: Duration = Duration::from_millis(200);

/// How far ahead of now the hosts are told to start: time for every request to arrive.
pub const START_LEAD: Duration = Duration::from_millis(500);

/// Starts every host's part and, with `start_here`, this machine's, at one instant [`START_LEAD`] ahead,
/// each host waiting for it on its own clock. First every host's clock is checked ([`check_clocks`]); a
/// start forced with clocks not locked hands `start_here` (and every host) the hosts in words, for the
/// recordings.
///
/// # Errors
///
/// A clock not locked, a host refusing, or `start_here` failing: every host is stopped again. When a host
/// refuses after `start_here` succeeded, the caller stops its own part.
pub fn start_together(
    hosts: &mut [Host],
    bound: Duration,
    start_unlocked: bool,
    start_here: impl FnOnce(Option<&str>) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    use kairos_sdk::Clock as _;
    let forced = check_clocks(hosts, bound, start_unlocked)?;
    let wall = kairos_sdk::RealTimeClock::new();
    let at = wall.now().after(START_LEAD);
    let asked = start_all_at(hosts, at.as_nanos(), forced.as_deref())?;
    while wall.now() < at {
        std::thread::sleep(Duration::from_micros(200));
    }
    if let Err(error) = start_here(forced.as_deref()) {
        stop_all(hosts);
        return Err(error);
    }
    confirm_started(hosts, &asked)?;
    for host in hosts.iter() {
        tracing::info!("host '{}' started its part", host.name());
    }
    Ok(())
}

/// Asks every host to start at `at` (ns since the UNIX epoch on its clock), without waiting: each answers
/// once started. Collect the answers with [`confirm_started`].
/// `forced`: the hosts whose clocks are not locked, when the start is forced.
fn start_all_at(hosts: &mut [Host], at: i64, forced: Option<&str>) -> anyhow::Result<Vec<u64>> {
    hosts
        .iter_mut()
        .map(|host| {
            host.send(RequestBody::Start {
                at_ns: Some(at),
                forced: forced.map(str::to_owned),
                start_unlocked: false,
            })
        })
        .collect()
}

/// The hosts' answers to [`start_all_at`]; the first refusal, after stopping every host.
fn confirm_started(hosts: &mut [Host], ids: &[u64]) -> anyhow::Result<()> {
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

/// How often the deploying machine asks each host whether it is still there, and how long an answer may
/// take: a killed host or a cut link is reported within a second.
const HEALTH_PERIOD: Duration = Duration::from_millis(250);
const HEALTH_WAIT: Duration = Duration::from_millis(600);
/// How often a lost host is tried again, and how long reaching it may take then.
const RETRY_PERIOD: Duration = Duration::from_secs(1);

/// A running deployment, watched from the deploying machine: a host that stops answering is reported
/// with the links it cuts while the others keep running; when it answers again, its part is deployed and
/// started again and its links resume.
#[derive(Debug)]
pub struct Watch {
    diagram: Diagram,
    plan: Plan,
    networks: BTreeMap<Option<String>, LinkNetwork>,
    reach: Reach,
    /// The hosts answering.
    pub hosts: Vec<Host>,
    /// The hosts lost, with when to try each again.
    lost: BTreeMap<String, std::time::Instant>,
    last_check: std::time::Instant,
    /// Each answering host's last status (the result of `status`).
    statuses: BTreeMap<String, serde_json::Value>,
    /// Whether the parts run: a host that returns is started again only then.
    running: bool,
}

impl Watch {
    /// Watches `hosts`, all started.
    pub fn new(
        diagram: Diagram,
        plan: Plan,
        networks: BTreeMap<Option<String>, LinkNetwork>,
        reach: Reach,
        hosts: Vec<Host>,
    ) -> Self {
        Watch {
            diagram,
            plan,
            networks,
            reach,
            hosts,
            lost: BTreeMap::new(),
            last_check: std::time::Instant::now(),
            statuses: BTreeMap::new(),
            running: true,
        }
    }

    /// Whether the parts run (they do when a watch is made): a host that returns gets its part deployed
    /// again, and started only while they run.
    pub fn set_running(&mut self, running: bool) {
        self.running = running;
    }

    /// How the diagram was split.
    pub fn plan(&self) -> &Plan {
        &self.plan
    }

    /// Each answering host's status as of the last [`Watch::check`].
    pub fn statuses(&self) -> &BTreeMap<String, serde_json::Value> {
        &self.statuses
    }

    /// The hosts that stopped answering.
    pub fn lost(&self) -> impl Iterator<Item = &str> {
        self.lost.keys().map(String::as_str)
    }

    /// Sends `body` to host `name` and waits for its reply.
    ///
    /// # Errors
    ///
    /// The host is lost, or refuses (the reason named).
    pub fn call_on(&mut self, name: &str, body: RequestBody) -> anyhow::Result<serde_json::Value> {
        let Some(host) = self.hosts.iter_mut().find(|h| h.name() == name) else {
            bail!("host '{name}' is lost: its part is deployed again when it answers");
        };
        host.call(body)
    }

    /// Changes a property of `component` on host `name`, and in the part deployed there again if the
    /// host is lost and returns.
    ///
    /// # Errors
    ///
    /// As [`Watch::call_on`].
    pub fn set_property(
        &mut self,
        name: &str,
        component: &str,
        property: &str,
        value: &Value,
    ) -> anyhow::Result<()> {
        self.call_on(
            name,
            RequestBody::SetProperty {
                component: component.to_owned(),
                property: property.to_owned(),
                value: value.clone(),
            },
        )?;
        if let Some(instance) = self
            .plan
            .parts
            .get_mut(&Some(name.to_owned()))
            .and_then(|part| part.component_mut(component))
        {
            instance.properties.insert(property.to_owned(), value.clone());
        }
        Ok(())
    }

    /// Whether any host is part of the deployment.
    pub fn is_empty(&self) -> bool {
        self.hosts.is_empty() && self.lost.is_empty()
    }

    /// The links that cross to or from `host`, in words.
    fn links_of(&self, host: &str) -> Vec<String> {
        let words = format!("host '{host}'");
        self.plan
            .links
            .iter()
            .filter(|l| l.from.ends_with(&words) || l.to.ends_with(&words))
            .map(|l| format!("{} -> {}", l.from, l.to))
            .collect()
    }

    /// Asks each host whether it is there (at most every [`HEALTH_PERIOD`]) and tries lost ones again.
    pub fn check(&mut self) {
        if self.last_check.elapsed() < HEALTH_PERIOD {
            return;
        }
        self.last_check = std::time::Instant::now();
        let mut answering = Vec::new();
        for mut host in std::mem::take(&mut self.hosts) {
            match host.ping() {
                Ok(status) => {
                    self.statuses.insert(host.name().to_owned(), status);
                    answering.push(host);
                }
                Err(error) => {
                    self.statuses.remove(host.name());
                    let links = self.links_of(host.name());
                    let cut = if links.is_empty() {
                        String::new()
                    } else {
                        format!("; links cut: {}", links.join(", "))
                    };
                    tracing::error!(
                        "host '{}' is lost ({error:#}){cut}; the other hosts keep running, and its part is \
                         deployed again when it answers",
                        host.name()
                    );
                    self.lost
                        .insert(host.name().to_owned(), std::time::Instant::now() + RETRY_PERIOD);
                }
            }
        }
        self.hosts = answering;
        let due: Vec<String> = self
            .lost
            .iter()
            .filter(|(_, at)| **at <= std::time::Instant::now())
            .map(|(name, _)| name.clone())
            .collect();
        for name in due {
            match self.redeploy(&name) {
                Ok(host) => {
                    let again = if self.running {
                        "deployed and started again"
                    } else {
                        "deployed again"
                    };
                    tracing::info!("host '{name}' is back: its part was {again}");
                    self.lost.remove(&name);
                    self.hosts.push(host);
                }
                Err(error) => {
                    tracing::debug!("host '{name}' is still lost: {error:#}");
                    self.lost.insert(name, std::time::Instant::now() + RETRY_PERIOD);
                }
            }
        }
    }

    fn redeploy(&self, name: &str) -> anyhow::Result<Host> {
        let spec = self
            .diagram
            .hosts
            .get(name)
            .with_context(|| format!("no host '{name}'"))?;
        let mut host = Host::reach_within(name, spec, &self.reach, RETRY_PERIOD)?;
        let key = Some(name.to_owned());
        ship_packs(&mut host, self.plan.packs.get(&key).map_or(&[], Vec::as_slice))?;
        let part = self.plan.parts.get(&key).map(Diagram::to_ron).unwrap_or_default();
        host.call(RequestBody::Deploy {
            diagram: part,
            network: self.networks.get(&key).cloned(),
            folder: None,
        })?;
        if self.running {
            host.call(RequestBody::Start {
                at_ns: None,
                forced: None,
                start_unlocked: false,
            })?;
        }
        Ok(host)
    }

    /// Stops every host's part and, with `stop_here`, this machine's, all at one instant
    /// [`STOP_LEAD`] ahead, each host on its own clock, as they started.
    pub fn stop_together(&mut self, stop_here: impl FnOnce()) {
        use kairos_sdk::Clock as _;
        let wall = kairos_sdk::RealTimeClock::new();
        let at = wall.now().after(STOP_LEAD);
        let asked: Vec<anyhow::Result<u64>> = self
            .hosts
            .iter_mut()
            .map(|host| {
                host.send(RequestBody::Stop {
                    at_ns: Some(at.as_nanos()),
                })
            })
            .collect();
        while wall.now() < at {
            std::thread::sleep(Duration::from_micros(200));
        }
        stop_here();
        for (host, id) in self.hosts.iter_mut().zip(asked) {
            match id.and_then(|id| host.wait(id)) {
                Ok(_) => tracing::info!("host '{}' stopped", host.name()),
                Err(error) => tracing::warn!("{error:#}"),
            }
        }
        for name in self.lost.keys() {
            tracing::warn!("host '{name}' was lost and could not be stopped: stop it there");
        }
    }
}

/// Stops every host's part, saying which could not be stopped.
pub fn stop_all(hosts: &mut [Host]) {
    for host in hosts {
        match host.call(RequestBody::Stop { at_ns: None }) {
            Ok(_) => tracing::info!("host '{}' stopped", host.name()),
            Err(error) => tracing::warn!("{error}"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_host_that_takes_tls_is_the_one_connected_to() {
        let source = r#"Diagram(format: 1,
            hosts: {
                "a": Host(endpoint: "ws://10.0.0.1:7600", zenoh: "tcp/10.0.0.1:7447"),
                "b": Host(endpoint: "wss://10.0.0.2:7600", certificate: "b.pem"),
                "c": Host(endpoint: "ws://10.0.0.3:7600"),
            },
            components: [], connections: [])"#;
        let diagram = kairos_diagram::parse(source)
            .map(|parsed| parsed.diagram)
            .unwrap();
        let linked_part = Diagram {
            components: vec![kairos_diagram::ComponentInstance::new("out", crate::link::SENDER)],
            ..diagram.clone()
        };
        let plan = Plan {
            parts: ["a", "b", "c"]
                .into_iter()
                .map(|host| (Some(host.to_owned()), linked_part.clone()))
                .collect(),
            ..Plan::default()
        };
        let folder = tempfile::tempdir().unwrap();
        // Without the certificate to trust, b's TLS endpoint is refused with the fix.
        let error = networks(&diagram, &plan, folder.path()).unwrap_err().to_string();
        assert!(error.contains("cannot read its certificate"), "{error}");
        std::fs::write(folder.path().join("b.pem"), "PEM").unwrap();
        let networks = networks(&diagram, &plan, folder.path()).unwrap();
        let connects = |host: &str| networks[&Some(host.to_owned())].connect.clone();
        assert_eq!(networks[&Some("b".to_owned())].listen, ["tls/10.0.0.2:7447"]);
        // a and c reach b over TLS; b, taking TLS, connects to no clear-text host; a joins c once.
        assert_eq!(connects("a"), ["tls/10.0.0.2:7447", "tcp/10.0.0.3:7447"]);
        assert!(connects("b").is_empty());
        assert_eq!(connects("c"), ["tls/10.0.0.2:7447"]);
        assert_eq!(networks[&Some("c".to_owned())].trusted_certificates, ["PEM"]);
    }
}
