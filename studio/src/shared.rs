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

/// How often the reader looks for new frames.
const POLL: Duration = Duration::from_millis(3);

/// Opens the services (output → service name), reports whether it could as a
/// [`ClientEvent::SharedMemory`], then forwards every frame as a [`ClientEvent::Sample`] until `stop` is set
/// or the studio goes.
pub fn read_frames(services: &BTreeMap<String, String>, stop: &AtomicBool, events: &EventSender) {
    let opened = (|| -> Result<_, String> {
        let node = NodeBuilder::new()
            .create::<ipc::Service>()
            .map_err(|e| format!("cannot start iceoryx2: {e:?}"))?;
        let mut subscribers = Vec::new();
        for (output, service) in services {
            let name: ServiceName = service
                .as_str()
                .try_into()
                .map_err(|e| format!("bad service name {service}: {e:?}"))?;
            let port_factory = node
                .service_builder(&name)
                .publish_subscribe::<[u8]>()
                .open()
                .map_err(|e| format!("cannot open {service} for {output}: {e:?}"))?;
            let subscriber = port_factory
                .subscriber_builder()
                .create()
                .map_err(|e| format!("cannot subscribe to {service}: {e:?}"))?;
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
    while !stop.load(Ordering::Relaxed) {
        for (_, subscriber) in &subscribers {
            while let Ok(Some(sample)) = subscriber.receive() {
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
        std::thread::sleep(POLL);
    }
}
