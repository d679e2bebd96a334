//! The process's Zenoh session and the link ends declared on it.
//!
//! One session per process (`kairos serve`, or the machine running `kairos deploy`), opened when a
//! diagram with links to other hosts is deployed: peer mode, listening and connecting on the endpoints
//! the hosts section gives, scouting off, so nothing is found by chance and nothing is missed silently.
//! The ends (a publisher per sending link, a subscriber per receiving one) are declared when the part is
//! deployed, before it starts, so the deployer can see every link matched before anything starts; the
//! link components take them at birth.

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use anyhow::Context as _;
use kairos_diagram::Diagram;
use kairos_protocol::{LinkEnd, LinkNetwork};
use zenoh::Wait as _;
use zenoh::handlers::{FifoChannel, FifoChannelHandler, RingChannel, RingChannelHandler};
use zenoh::pubsub::{Publisher, Subscriber};
use zenoh::qos::CongestionControl;
use zenoh::sample::Sample as ZenohSample;

use super::SENDER;

/// How long a silent link lives before Zenoh declares it dead: short, so a cut cable or a killed host is
/// noticed within about a second (keep-alives go four times per lease).
const LEASE_MS: u64 = 1000;

/// The sending end of a link: its publisher, blocking when the consumer never skips.
pub struct SenderEnd {
    /// The publisher.
    pub publisher: Publisher<'static>,
    /// The far end, in words.
    pub peer: String,
}

/// What a receiving end queues: a bounded FIFO that blocks the link when full (a consumer that never
/// skips), or a ring that drops the oldest (any other).
pub enum Incoming {
    /// Blocking.
    Fifo(Subscriber<FifoChannelHandler<ZenohSample>>),
    /// Dropping the oldest.
    Ring(Subscriber<RingChannelHandler<ZenohSample>>),
}

impl std::fmt::Debug for Incoming {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Incoming::Fifo(_) => "Incoming::Fifo",
            Incoming::Ring(_) => "Incoming::Ring",
        })
    }
}

impl Incoming {
    /// The next sample, waiting at most `wait`; `Err` once the session is closed.
    pub fn recv_timeout(&self, wait: Duration) -> Result<Option<ZenohSample>, String> {
        match self {
            Incoming::Fifo(subscriber) => subscriber.recv_timeout(wait),
            Incoming::Ring(subscriber) => subscriber.recv_timeout(wait),
        }
        .map_err(|e| e.to_string())
    }
}

/// The receiving end of a link.
pub struct ReceiverEnd {
    /// Its queue.
    pub incoming: Incoming,
    /// The far end, in words.
    pub peer: String,
}

impl std::fmt::Debug for SenderEnd {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SenderEnd")
            .field("key", &self.publisher.key_expr().as_str())
            .field("peer", &self.peer)
            .finish_non_exhaustive()
    }
}

impl std::fmt::Debug for ReceiverEnd {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ReceiverEnd")
            .field("peer", &self.peer)
            .finish_non_exhaustive()
    }
}

struct Network {
    spec: LinkNetwork,
    session: zenoh::Session,
    /// By key.
    senders: BTreeMap<String, (String, Arc<SenderEnd>)>,
    receivers: BTreeMap<String, (String, Arc<ReceiverEnd>)>,
}

static NETWORK: Mutex<Option<Network>> = Mutex::new(None);

fn network() -> MutexGuard<'static, Option<Network>> {
    NETWORK.lock().unwrap_or_else(PoisonError::into_inner)
}

/// Joins the network `spec` describes: keeps the session when it is already that one, else closes the
/// old one (and its ends) and opens a new one.
///
/// # Errors
///
/// An endpoint Zenoh does not accept, or one it cannot listen on, named with the fix.
pub fn join(spec: &LinkNetwork) -> anyhow::Result<()> {
    let mut slot = network();
    if slot.as_ref().is_some_and(|n| n.spec == *spec) {
        return Ok(());
    }
    if let Some(old) = slot.take() {
        let _ = old.session.close().wait();
    }
    let session = open(spec)?;
    *slot = Some(Network {
        spec: spec.clone(),
        session,
        senders: BTreeMap::new(),
        receivers: BTreeMap::new(),
    });
    Ok(())
}

/// Closes the session, if one is open.
pub fn leave() {
    if let Some(old) = network().take() {
        let _ = old.session.close().wait();
    }
}

fn open(spec: &LinkNetwork) -> anyhow::Result<zenoh::Session> {
    if let Some(secure) = spec
        .listen
        .iter()
        .chain(&spec.connect)
        .find(|e| e.starts_with("tls/"))
    {
        anyhow::bail!(
            "the link endpoint {secure}: Zenoh's TLS transport is not built into this kairos; use tcp/ (the \
             control protocol can be TLS with wss://, the links' samples then cross in clear)"
        );
    }
    let mut config = zenoh::Config::default();
    let settings = [
        ("mode", "\"peer\"".to_owned()),
        ("scouting/multicast/enabled", "false".to_owned()),
        ("scouting/gossip/enabled", "false".to_owned()),
        ("listen/endpoints", serde_json::to_string(&spec.listen)?),
        ("connect/endpoints", serde_json::to_string(&spec.connect)?),
        // Hosts come up in any order: keep trying an absent peer in the background.
        ("connect/exit_on_failure", "false".to_owned()),
        (
            "connect/retry",
            "{period_init_ms: 100, period_max_ms: 1000, period_increase_factor: 2}".to_owned(),
        ),
        ("transport/link/tx/lease", LEASE_MS.to_string()),
    ];
    for (key, value) in settings {
        config
            .insert_json5(key, &value)
            .map_err(|e| anyhow::anyhow!("the links' Zenoh setting {key} = {value}: {e}"))?;
    }
    zenoh::open(config).wait().map_err(|e| {
        anyhow::anyhow!(
            "cannot open the links' Zenoh session listening on {}: {e}; is another process using that port? \
             Give the host another with `zenoh: \"tcp/ADDRESS:PORT\"` in the hosts section",
            spec.listen.join(", ")
        )
    })
}

/// Declares the ends of `diagram`'s link components (dropping those of an earlier diagram), so that they
/// match before the diagram starts.
///
/// # Errors
///
/// No network joined while the diagram has links, or a key Zenoh refuses.
pub fn prepare(diagram: &Diagram) -> anyhow::Result<()> {
    let mut slot = network();
    let links: Vec<_> = diagram
        .components
        .iter()
        .filter(|c| super::is_link(&c.type_name))
        .collect();
    let Some(network) = slot.as_mut() else {
        if let Some(first) = links.first() {
            anyhow::bail!(
                "'{}' links this part to another host, but no link network is set: parts with links are \
                 deployed by `kairos deploy`, which tells each host where the others are",
                first.id
            );
        }
        return Ok(());
    };
    network.senders.clear();
    network.receivers.clear();
    for component in links {
        let text = |name: &str| {
            component
                .properties
                .get(name)
                .and_then(kairos_diagram::Value::as_text)
                .unwrap_or_default()
                .to_owned()
        };
        let reliable = component
            .properties
            .get("reliable")
            .and_then(kairos_diagram::Value::as_bool)
            .unwrap_or(false);
        let key = text("key");
        let peer = text("peer");
        let context = || format!("link '{}' (key {key})", component.id);
        if component.type_name == SENDER {
            // Over TCP every link is reliable in transit; what the consumer's policy decides is whether
            // a full queue blocks the producer or drops the sample.
            let publisher = network
                .session
                .declare_publisher(key.clone())
                .congestion_control(if reliable {
                    CongestionControl::Block
                } else {
                    CongestionControl::Drop
                })
                .wait()
                .map_err(|e| anyhow::anyhow!("{e}"))
                .with_context(context)?;
            let end = Arc::new(SenderEnd { publisher, peer });
            network.senders.insert(key, (component.id.clone(), end));
        } else {
            let capacity = component
                .properties
                .get("queue")
                .and_then(kairos_diagram::Value::as_i64)
                .and_then(|q| usize::try_from(q).ok())
                .unwrap_or(64)
                .max(1);
            let subscriber = network.session.declare_subscriber(key.clone());
            let incoming = if reliable {
                Incoming::Fifo(
                    subscriber
                        .with(FifoChannel::new(capacity))
                        .wait()
                        .map_err(|e| anyhow::anyhow!("{e}"))
                        .with_context(context)?,
                )
            } else {
                Incoming::Ring(
                    subscriber
                        .with(RingChannel::new(capacity))
                        .wait()
                        .map_err(|e| anyhow::anyhow!("{e}"))
                        .with_context(context)?,
                )
            };
            let end = Arc::new(ReceiverEnd { incoming, peer });
            network.receivers.insert(key, (component.id.clone(), end));
        }
    }
    Ok(())
}

/// The session, for measuring links against Zenoh alone in the same configuration.
pub fn session() -> Option<zenoh::Session> {
    network().as_ref().map(|n| n.session.clone())
}

/// The declared sending end under `key`.
pub fn sender(key: &str) -> Option<Arc<SenderEnd>> {
    network().as_ref()?.senders.get(key).map(|(_, end)| end.clone())
}

/// The declared receiving end under `key`.
pub fn receiver(key: &str) -> Option<Arc<ReceiverEnd>> {
    network().as_ref()?.receivers.get(key).map(|(_, end)| end.clone())
}

/// Whether a receiver matches the sending end `end`.
pub fn matched(end: &SenderEnd) -> bool {
    end.publisher
        .matching_status()
        .wait()
        .is_ok_and(|status| status.matching())
}

/// Every declared end, for `links` and the deployer's wait for matching. A receiver counts as matched
/// here: only its sender can tell.
pub fn ends() -> Vec<LinkEnd> {
    let slot = network();
    let Some(network) = slot.as_ref() else {
        return Vec::new();
    };
    let senders = network.senders.iter().map(|(key, (component, end))| LinkEnd {
        component: component.clone(),
        key: key.clone(),
        role: "sender".to_owned(),
        peer: end.peer.clone(),
        matched: matched(end),
    });
    let receivers = network.receivers.iter().map(|(key, (component, end))| LinkEnd {
        component: component.clone(),
        key: key.clone(),
        role: "receiver".to_owned(),
        peer: end.peer.clone(),
        matched: true,
    });
    senders.chain(receivers).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_tls_link_endpoint_is_refused_with_the_reason_until_zenoh_tls_is_built_in() {
        let spec = LinkNetwork {
            listen: vec!["tls/127.0.0.1:17447".to_owned()],
            connect: Vec::new(),
        };
        let error = open(&spec).err().map(|e| e.to_string()).unwrap_or_default();
        assert!(error.contains("TLS transport is not built"), "{error}");
    }
}
