//! Sample frames from iceoryx2 shared memory: what a runtime on this machine publishes for the studio's
//! viewers instead of sending it through the socket. The frames are the protocol's own bytes, so the
//! viewers cannot tell the two paths apart.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::Sender;
use std::time::Duration;

use iceoryx2::prelude::*;

use crate::client::ClientEvent;

/// How often the reader looks for new frames.
const POLL: Duration = Duration::from_millis(3);

/// Opens the services (output → service name), reports on `ready` whether it could, then forwards every
/// frame as a [`ClientEvent::Sample`] until `stop` is set or the studio goes.
pub fn read_frames(
    services: &BTreeMap<String, String>,
    stop: &AtomicBool,
    ready: &Sender<Result<(), String>>,
    events: &Sender<ClientEvent>,
    wake: &dyn Fn(),
) {
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
            let _ = ready.send(Ok(()));
            parts
        }
        Err(error) => {
            let _ = ready.send(Err(error));
            return;
        }
    };
    while !stop.load(Ordering::Relaxed) {
        let mut any = false;
        for (_, subscriber) in &subscribers {
            while let Ok(Some(sample)) = subscriber.receive() {
                // A frame that does not decode is skipped, as on the socket.
                if let Ok((header, payload)) = kairos_protocol::frame::decode(sample.payload()) {
                    if events
                        .send(ClientEvent::Sample(header, payload.to_vec()))
                        .is_err()
                    {
                        return;
                    }
                    any = true;
                }
            }
        }
        if any {
            wake();
        }
        std::thread::sleep(POLL);
    }
}
