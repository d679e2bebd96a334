//! Sample frames from iceoryx2 shared memory: what a runtime on this machine publishes for the studio's
//! viewers instead of sending it through the socket. The frames are the protocol's own bytes, so the
//! viewers cannot tell the two paths apart. A frame may name the runtime's pixel buffer instead of
//! carrying the pixels (`shared_pixels`): they are copied out of that buffer here, so the viewers still
//! get the same bytes.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use iceoryx2::prelude::*;
use kairos_protocol::LogLevel;
use kairos_protocol::shared_pixels::{PixelsReference, SharedPixelsError, SharedPixelsReader};

use crate::client::{ClientEvent, EventSender, studio_record};

/// Copies the pixels of frames that name a buffer of the runtime instead of carrying them.
#[derive(Default)]
struct PixelsFromRuntime {
    reader: SharedPixelsReader,
    /// Frames whose buffer was recycled before they were read, in all.
    replaced: u64,
    /// Whether a buffer that cannot be mapped was reported (once is enough: the next ones fail alike).
    reported_unreachable: bool,
}

impl PixelsFromRuntime {
    /// The pixels, or `None` (the frame is skipped, as a frame lost on the way would be) with the reason
    /// in the studio's log: once for a buffer that cannot be mapped, at 1, 2, 4, 8 ... for frames the
    /// runtime recycled before they were read.
    fn read(&mut self, reference: &PixelsReference, events: &EventSender) -> Option<Vec<u8>> {
        let error = match self.reader.read(reference) {
            Ok(bytes) => return Some(bytes),
            Err(error) => error,
        };
        let (level, message) = match error {
            SharedPixelsError::Replaced => {
                self.replaced += 1;
                if !self.replaced.is_power_of_two() {
                    return None;
                }
                (
                    LogLevel::Debug,
                    format!(
                        "viewer: {} image frames were recycled by the runtime before they could be read",
                        self.replaced
                    ),
                )
            }
            error => {
                if std::mem::replace(&mut self.reported_unreachable, true) {
                    return None;
                }
                (LogLevel::Warn, format!("viewer: {error}"))
            }
        };
        // A studio that is gone needs no message; the frame loop ends at its next send.
        events.send(ClientEvent::Log(studio_record(level, message)));
        None
    }
}

/// Why frames cannot come through shared memory: the viewers use the socket instead. Cloned with the
/// event that carries it.
#[derive(Debug, Clone, thiserror::Error)]
pub enum SharedMemoryError {
    /// iceoryx2 could not make its node (no `/dev/shm`, no permission).
    #[error("cannot start iceoryx2: {0:?}")]
    Node(iceoryx2::node::NodeCreationFailure),
    /// A service name the runtime gave that iceoryx2 refuses.
    #[error("bad service name {service}: {reason:?}")]
    ServiceName {
        /// The service.
        service: String,
        /// What iceoryx2 said.
        reason: iceoryx2::service::service_name::ServiceNameError,
    },
    /// The runtime's service is not there (a runtime on another machine, or gone).
    #[error("cannot open {service} for {output}: {reason:?}")]
    Open {
        /// The service.
        service: String,
        /// The output it carries.
        output: String,
        /// What iceoryx2 said.
        reason: iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenError,
    },
    /// The subscriber port could not be made.
    #[error("cannot subscribe to {service}: {reason:?}")]
    Subscribe {
        /// The service.
        service: String,
        /// What iceoryx2 said.
        reason: iceoryx2::port::subscriber::SubscriberCreateError,
    },
    /// The reader's thread could not be started.
    #[error("cannot start the shared-memory reader's thread: {0}")]
    Thread(std::sync::Arc<std::io::Error>),
}

/// How often the reader looks for new frames.
const POLL: Duration = Duration::from_millis(3);
/// How often it looks once none has come for [`IDLE_AFTER`] (the diagram stopped or paused, a slow
/// source): a look every 3 ms costs about a point of a core with nothing to read.
const IDLE_POLL: Duration = Duration::from_millis(50);
const IDLE_AFTER: Duration = Duration::from_secs(1);

/// Opens the services (output → service name), reports whether it could as a
/// [`ClientEvent::SharedMemory`], then forwards every frame as a [`ClientEvent::Sample`] until `stop` is set
/// or the studio goes.
pub fn read_frames(services: &BTreeMap<String, String>, stop: &AtomicBool, events: &EventSender) {
    let opened = (|| -> Result<_, SharedMemoryError> {
        let node = NodeBuilder::new()
            .create::<ipc::Service>()
            .map_err(SharedMemoryError::Node)?;
        let mut subscribers = Vec::new();
        for (output, service) in services {
            let name: ServiceName =
                service
                    .as_str()
                    .try_into()
                    .map_err(|reason| SharedMemoryError::ServiceName {
                        service: service.clone(),
                        reason,
                    })?;
            let port_factory = node
                .service_builder(&name)
                .publish_subscribe::<[u8]>()
                .open()
                .map_err(|reason| SharedMemoryError::Open {
                    service: service.clone(),
                    output: output.clone(),
                    reason,
                })?;
            let subscriber = port_factory.subscriber_builder().create().map_err(|reason| {
                SharedMemoryError::Subscribe {
                    service: service.clone(),
                    reason,
                }
            })?;
            subscribers.push((port_factory, subscriber));
        }
        Ok((node, subscribers))
    })();
    let (_node, subscribers) = match opened {
        Ok(parts) => {
            if !events.send(ClientEvent::SharedMemory(Ok(()))) {
                return;
            }
            parts
        }
        Err(error) => {
            events.send(ClientEvent::SharedMemory(Err(error)));
            return;
        }
    };
    let mut pixels = PixelsFromRuntime::default();
    let mut last_frame = std::time::Instant::now();
    while !stop.load(Ordering::Relaxed) {
        for (_, subscriber) in &subscribers {
            while let Ok(Some(sample)) = subscriber.receive() {
                last_frame = std::time::Instant::now();
                // A frame that does not decode is skipped, as on the socket.
                let Ok((mut header, payload)) = kairos_protocol::frame::decode(sample.payload()) else {
                    continue;
                };
                let payload = match header.image.as_mut().and_then(|layout| layout.shared.take()) {
                    Some(reference) => match pixels.read(&reference, events) {
                        Some(bytes) => bytes,
                        None => continue,
                    },
                    None => payload.to_vec(),
                };
                if !events.send(ClientEvent::Sample(header, payload)) {
                    return;
                }
            }
        }
        std::thread::sleep(if last_frame.elapsed() < IDLE_AFTER {
            POLL
        } else {
            IDLE_POLL
        });
    }
}
