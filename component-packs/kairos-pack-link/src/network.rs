//! The process's Zenoh session and the link ends declared on it.
//!
//! One session per process (`kairos serve`, or the machine running `kairos deploy`), opened when a
//! diagram with links to other hosts is deployed: peer mode, listening and connecting on the endpoints
//! the hosts section gives, scouting off, so nothing is found by chance and nothing is missed silently.
//! The ends (a publisher per sending link, a subscriber per receiving one) are declared when the part is
//! deployed, before it starts, so the deployer can see every link matched before anything starts; the
//! link components take them at birth.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};
use std::time::Duration;

use anyhow::Context as _;
use kairos_diagram::Diagram;
use kairos_protocol::{LinkEnd, LinkNetwork};
use zenoh::Wait as _;
use zenoh::handlers::{FifoChannel, FifoChannelHandler, RingChannel, RingChannelHandler};
use zenoh::pubsub::{Publisher, Subscriber};
use zenoh::qos::{CongestionControl, Priority};
use zenoh::sample::Sample as ZenohSample;

use super::SENDER;

/// How long a silent link lives before Zenoh declares it dead: short, so that a cut cable or a killed
/// host is said within a second (0.5–0.7 s to notice, the last keep-alive having gone up to a quarter of
/// a lease before the cut, then up to the coordinator's 200 ms look at the statuses). Keep-alives go four
/// times per lease, every 175 ms: only a process starved of CPU for 0.7 s misses four in a row.
const LEASE_MS: u64 = 700;

/// How long a blocking put may wait for room in a link's queue before Zenoh closes the transport: a
/// lease, as a silent peer gets. A cut under a stream that fills the queue (a camera never skipping) is
/// then said as soon as one that does not, rather than when the far end's closing reaches a sender
/// whose writes are stuck.
const WAIT_BEFORE_CLOSE_MS: u64 = LEASE_MS;

/// The sending end of a link: its publisher, blocking when the consumer never skips.
pub struct SenderEnd {
    /// The publisher.
    pub publisher: Publisher<'static>,
    /// The far end, in words.
    pub peer: String,
    /// Times the receiver stopped matching, counted as Zenoh says it (a reliable link only): a sender
    /// that sees it grow knows the far end may have missed what it put since.
    pub cuts: Arc<AtomicU64>,
    /// Times the match changed either way, counted as Zenoh says it: the sender looks at once, rather
    /// than at its next status period, so a cut is said as soon as Zenoh knows it.
    pub matching_changes: Arc<AtomicU64>,
    /// Whether a receiver matches, as Zenoh last said: what the sender's status reports.
    pub matching: Arc<AtomicBool>,
    /// The sender component's status, which the matching listener sets `matched` in as Zenoh says it:
    /// the sender's own thread may be stuck in a put behind another link's full queue for as long again
    /// as the lease, and a cut is to be said on every link of the session at once.
    pub status: Arc<Mutex<Option<kairos_sdk::StatusWriter>>>,
    session: zenoh::Session,
    key: String,
}

/// The key under which a receiving end answers the newest sequence number it received.
fn newest_key(key: &str) -> String {
    format!("{key}/newest")
}

/// Where a receiving end's answer comes: the newest sequence number it received (`None`: none yet), or
/// why it did not say.
pub type Answer = std::sync::mpsc::Receiver<Result<Option<u64>, AskError>>;

/// Why a receiving end did not say what it received: the sender then counts what it missed as lost.
#[derive(Debug, thiserror::Error)]
pub enum AskError {
    /// It answered something else than a sequence number (another version?).
    #[error("an answer that is not a number")]
    NotANumber,
    /// It answered with an error, whose text Zenoh carries.
    #[error("an error: {0}")]
    Refused(String),
    /// The question could not be sent.
    #[error(transparent)]
    Query(zenoh::Error),
    /// No answer in time (the far end flapping as it comes back).
    #[error("no answer within {} ms", .0.as_millis())]
    Unanswered(Duration),
}

/// The link's session closed under a receiving end.
#[derive(Debug, thiserror::Error)]
#[error(transparent)]
pub struct Closed(zenoh::Error);

/// No sequence number received yet.
const NONE_YET: u64 = u64::MAX;

impl SenderEnd {
    /// Asks the receiving end for the newest sequence number it received, without waiting: the answer
    /// (`None`: none yet), or why there is none, comes on the channel returned; it is dropped unanswered
    /// after `wait`. (Waiting here could deadlock: the receiver's host may be blocked delivering what this
    /// host put, until this host's consumers read on.)
    pub fn ask_receiver_newest(&self, wait: Duration) -> Answer {
        let (answer, answered) = std::sync::mpsc::sync_channel(1);
        let asked = self
            .session
            .get(newest_key(&self.key))
            .timeout(wait)
            .callback({
                let answer = answer.clone();
                move |reply| {
                    let newest = match reply.result() {
                        Ok(sample) => sample
                            .payload()
                            .try_to_string()
                            .ok()
                            .and_then(|text| text.parse::<u64>().ok())
                            .map(|newest| (newest != NONE_YET).then_some(newest))
                            .ok_or(AskError::NotANumber),
                        Err(error) => Err(AskError::Refused(
                            error.payload().try_to_string().unwrap_or_default().into_owned(),
                        )),
                    };
                    let _ = answer.try_send(newest);
                }
            })
            .wait();
        if let Err(error) = asked {
            let _ = answer.try_send(Err(AskError::Query(error)));
        }
        answered
    }
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
    /// The next sample if one is queued, without waiting; `Err` once the session is closed.
    pub fn try_recv(&self) -> Result<Option<ZenohSample>, Closed> {
        match self {
            Incoming::Fifo(subscriber) => subscriber.try_recv(),
            Incoming::Ring(subscriber) => subscriber.try_recv(),
        }
        .map_err(Closed)
    }

    /// The next sample, waiting at most `wait`; `Err` once the session is closed.
    pub fn recv_timeout(&self, wait: Duration) -> Result<Option<ZenohSample>, Closed> {
        match self {
            Incoming::Fifo(subscriber) => subscriber.recv_timeout(wait),
            Incoming::Ring(subscriber) => subscriber.recv_timeout(wait),
        }
        .map_err(Closed)
    }
}

/// The receiving end of a link.
pub struct ReceiverEnd {
    /// Its queue.
    pub incoming: Incoming,
    /// The far end, in words.
    pub peer: String,
    /// The newest sequence number received ([`NONE_YET`] before any), which the sender asks for after a
    /// cut to put again what did not arrive.
    newest: Arc<AtomicU64>,
    /// Answers the sender's question (a reliable link only); dropping it undeclares it.
    _answering: Option<zenoh::query::Queryable<()>>,
}

impl ReceiverEnd {
    /// Records the newest sequence number received.
    pub fn received(&self, sequence: u64) {
        self.newest.store(sequence, Ordering::Release);
    }
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

/// This runtime's certificate chain and private key (PEM files), for listening on a `tls/` endpoint:
/// `kairos serve`'s `--tls-cert` and `--tls-key`, the same identity as its `wss://` endpoint.
static IDENTITY: Mutex<Option<(PathBuf, PathBuf)>> = Mutex::new(None);

/// Listens on `tls/` link endpoints with this certificate chain and key from now on.
pub fn set_identity(certificate: &Path, key: &Path) {
    *IDENTITY.lock().unwrap_or_else(PoisonError::into_inner) = Some((certificate.to_owned(), key.to_owned()));
}

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

/// The TLS settings of `spec`: this runtime's identity where it listens on `tls/`, and the certificates
/// to trust where it connects to one.
fn tls_settings(spec: &LinkNetwork) -> anyhow::Result<Vec<(&'static str, String)>> {
    use base64::Engine as _;
    let is_tls = |e: &&String| e.starts_with("tls/");
    let mut settings = Vec::new();
    if let Some(endpoint) = spec.listen.iter().find(is_tls) {
        let identity = IDENTITY.lock().unwrap_or_else(PoisonError::into_inner).clone();
        let Some((certificate, key)) = identity else {
            anyhow::bail!(
                "this host's link endpoint is {endpoint}, but this kairos serve has no certificate to listen \
                 with: start it with --tls-cert and --tls-key, or give the host a tcp/ zenoh endpoint"
            );
        };
        settings.push((
            "transport/link/tls/listen_certificate",
            serde_json::to_string(&certificate.display().to_string())?,
        ));
        settings.push((
            "transport/link/tls/listen_private_key",
            serde_json::to_string(&key.display().to_string())?,
        ));
    }
    if let Some(endpoint) = spec.connect.iter().find(is_tls) {
        if spec.trusted_certificates.is_empty() {
            anyhow::bail!(
                "the link endpoint {endpoint} is TLS, and no certificate to trust came with it: give that host \
                 its `certificate` in the hosts section"
            );
        }
        let bundle = spec.trusted_certificates.concat();
        settings.push((
            "transport/link/tls/root_ca_certificate_base64",
            serde_json::to_string(&base64::engine::general_purpose::STANDARD.encode(bundle))?,
        ));
    }
    Ok(settings)
}

fn open(spec: &LinkNetwork) -> anyhow::Result<zenoh::Session> {
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
        (
            "transport/link/tx/queue/congestion_control/block/wait_before_close",
            (WAIT_BEFORE_CLOSE_MS * 1000).to_string(),
        ),
    ];
    for (key, value) in settings.into_iter().chain(tls_settings(spec)?) {
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
        let bulk = component
            .properties
            .get("bulk")
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
                // Zenoh keeps a queue per priority: frames fill their own.
                .priority(if bulk { Priority::DataLow } else { Priority::Data })
                .wait()
                .map_err(|e| anyhow::anyhow!("{e}"))
                .with_context(context)?;
            let cuts = Arc::new(AtomicU64::new(0));
            let matching_changes = Arc::new(AtomicU64::new(0));
            let status: Arc<Mutex<Option<kairos_sdk::StatusWriter>>> = Arc::default();
            let matching = Arc::new(AtomicBool::new(false));
            let (counted_cuts, counted_changes, now_matching, said) = (
                Arc::clone(&cuts),
                Arc::clone(&matching_changes),
                Arc::clone(&matching),
                Arc::clone(&status),
            );
            publisher
                .matching_listener()
                .callback(move |status| {
                    if reliable && !status.matching() {
                        counted_cuts.fetch_add(1, Ordering::AcqRel);
                    }
                    counted_changes.fetch_add(1, Ordering::AcqRel);
                    now_matching.store(status.matching(), Ordering::Release);
                    if let Some(writer) = said.lock().unwrap_or_else(PoisonError::into_inner).as_ref() {
                        let mut fields = serde_json::Map::new();
                        fields.insert("matched".to_owned(), status.matching().into());
                        writer.merge(fields);
                    }
                })
                .background()
                .wait()
                .map_err(|e| anyhow::anyhow!("{e}"))
                .with_context(context)?;
            let end = Arc::new(SenderEnd {
                publisher,
                peer,
                cuts,
                matching_changes,
                matching,
                status,
                session: network.session.clone(),
                key: key.clone(),
            });
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
            let newest = Arc::new(AtomicU64::new(NONE_YET));
            let answering = if reliable {
                let answer = Arc::clone(&newest);
                Some(
                    network
                        .session
                        .declare_queryable(newest_key(&key))
                        .callback(move |query| {
                            let newest = answer.load(Ordering::Acquire).to_string();
                            let _ = query.reply(query.key_expr().clone(), newest).wait();
                        })
                        .wait()
                        .map_err(|e| anyhow::anyhow!("{e}"))
                        .with_context(context)?,
                )
            } else {
                None
            };
            let end = Arc::new(ReceiverEnd {
                incoming,
                peer,
                newest,
                _answering: answering,
            });
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
    fn a_tls_endpoint_needs_an_identity_to_listen_and_certificates_to_trust() {
        let listening = LinkNetwork {
            listen: vec!["tls/127.0.0.1:17447".to_owned()],
            ..LinkNetwork::default()
        };
        let error = tls_settings(&listening)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(
            error.contains("start it with --tls-cert and --tls-key"),
            "{error}"
        );
        let connecting = LinkNetwork {
            connect: vec!["tls/127.0.0.1:17447".to_owned()],
            ..LinkNetwork::default()
        };
        let error = tls_settings(&connecting)
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default();
        assert!(error.contains("give that host its `certificate`"), "{error}");
        let trusting = LinkNetwork {
            trusted_certificates: vec!["-----BEGIN CERTIFICATE-----\n".to_owned()],
            ..connecting
        };
        let settings = tls_settings(&trusting).unwrap_or_default();
        assert_eq!(settings.len(), 1, "{settings:?}");
        assert_eq!(settings[0].0, "transport/link/tls/root_ca_certificate_base64");
    }
}
