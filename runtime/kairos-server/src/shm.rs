//! Sample frames through iceoryx2 shared memory, for clients on the server's own machine.
//!
//! One publisher thread per subscribed output (named `k:shm`): at most `rate` times a second it takes the
//! output's latest sample, as the socket path does, and writes the frame (the same bytes as a binary message:
//! magic, header, payload) straight into a shared-memory sample that the client maps; nothing goes through
//! the socket or the kernel. Publishers never wait for a slow client: its oldest unread frame is dropped.
//!
//! For a client that asked for `shared_pixels`, an image whose pixels already lie in shared memory (a
//! camera's frames, `kairos_sdk_core::pixels`) is published as its header alone, naming the runtime's buffer:
//! the pixels are not copied at all. The publisher holds the sample until it publishes the next one, so
//! the buffer is not recycled while a client that keeps up is reading it.

#![allow(
    unsafe_code,
    reason = "one assume_init after every byte of a loaned sample is written"
)]

use std::mem::MaybeUninit;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use iceoryx2::prelude::*;

use super::runtime::Runtime;
use super::samples::{LatestSamples, PixelsIn};

/// Frames a client may hold unread before the oldest is dropped.
const CLIENT_FRAMES: usize = 2;

/// A number for each publication, so service names are never reused within a server.
pub fn next_publication() -> u64 {
    static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(1);
    NEXT.fetch_add(1, Ordering::Relaxed)
}

/// A publication running on its own thread; dropping it stops it.
#[derive(Debug)]
pub struct ShmPublication {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl Drop for ShmPublication {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        // Not joined: the thread wakes within one period and ends; a session must not wait for it.
        drop(self.thread.take());
    }
}

/// Copies `parts` one after the other into `target`, which they fill exactly.
fn fill(target: &mut [MaybeUninit<u8>], parts: &[&[u8]]) {
    let mut at = 0;
    for part in parts {
        if let Some(slot) = target.get_mut(at..at + part.len()) {
            slot.write_copy_of_slice(part);
        }
        at += part.len();
    }
}

/// Why an output cannot be published in shared memory: the client is told to use the socket transport.
#[derive(Debug, thiserror::Error)]
pub enum ShmError {
    /// iceoryx2 could not make its node (no `/dev/shm`, out of descriptors).
    #[error("cannot start iceoryx2: {0:?}")]
    Node(iceoryx2::node::NodeCreationFailure),
    /// The service's name is not one iceoryx2 accepts.
    #[error("bad service name {service}: {reason:?}")]
    ServiceName {
        service: String,
        reason: iceoryx2::service::service_name::ServiceNameError,
    },
    /// The service could not be opened or made (another of that name with other settings).
    #[error("cannot create the service {service}: {reason:?}")]
    Service {
        service: String,
        reason: iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenOrCreateError,
    },
    /// The publisher port could not be made.
    #[error("cannot publish on {service}: {reason:?}")]
    Publisher {
        service: String,
        reason: iceoryx2::port::publisher::PublisherCreateError,
    },
    /// The system would not give the publisher its thread.
    #[error("cannot start a publisher thread: {0}")]
    Thread(#[source] std::io::Error),
    /// The publisher thread did not say it was ready in time.
    #[error("iceoryx2 did not start in 10 s")]
    NotReady,
}

/// Starts publishing `output`'s frames on the iceoryx2 service `service`; returns when the service is
/// ready (or why it cannot be).
pub fn publish(
    runtime: Arc<Runtime>,
    output: String,
    service: String,
    rate: f64,
    max_image_width: Option<u32>,
    pixels_in: PixelsIn,
    client: String,
) -> Result<ShmPublication, ShmError> {
    let stop = Arc::new(AtomicBool::new(false));
    let stopping = Arc::clone(&stop);
    let (ready_tx, ready_rx) = mpsc::channel::<Result<(), ShmError>>();
    let thread = std::thread::Builder::new()
        .name("k:shm".to_owned())
        .spawn(move || {
            let setup = || -> Result<_, ShmError> {
                let node = NodeBuilder::new()
                    .create::<ipc::Service>()
                    .map_err(ShmError::Node)?;
                let name: ServiceName =
                    service
                        .as_str()
                        .try_into()
                        .map_err(|reason| ShmError::ServiceName {
                            service: service.clone(),
                            reason,
                        })?;
                let port_factory = node
                    .service_builder(&name)
                    .publish_subscribe::<[u8]>()
                    .subscriber_max_buffer_size(CLIENT_FRAMES)
                    .history_size(0)
                    .max_publishers(1)
                    .max_subscribers(4)
                    .open_or_create()
                    .map_err(|reason| ShmError::Service {
                        service: service.clone(),
                        reason,
                    })?;
                let publisher = port_factory
                    .publisher_builder()
                    .initial_max_slice_len(64 * 1024)
                    .allocation_strategy(AllocationStrategy::PowerOfTwo)
                    .backpressure_strategy(BackpressureStrategy::DiscardData)
                    .create()
                    .map_err(|reason| ShmError::Publisher {
                        service: service.clone(),
                        reason,
                    })?;
                Ok((node, port_factory, publisher))
            };
            let (_node, _port_factory, publisher) = match setup() {
                Ok(parts) => {
                    let _ = ready_tx.send(Ok(()));
                    parts
                }
                Err(error) => {
                    let _ = ready_tx.send(Err(error));
                    return;
                }
            };
            let period = Duration::from_secs_f64(1.0 / rate);
            let mut next = Instant::now();
            let mut latest =
                LatestSamples::new(runtime, output.clone(), format!("shared memory of {client}"));
            while !stopping.load(Ordering::Relaxed) {
                next += period;
                let now = Instant::now();
                if next > now {
                    std::thread::sleep(next - now);
                } else {
                    next = now;
                }
                let Some((sample, skipped)) = latest.next() else {
                    continue;
                };
                let (head, body) =
                    super::samples::encode_parts(&output, &sample, skipped, max_image_width, pixels_in);
                let length = head.len() + body.len();
                let mut loaned = match publisher.loan_slice_uninit(length) {
                    Ok(loaned) => loaned,
                    Err(error) => {
                        tracing::warn!("{output}: no shared memory for a {length}-byte frame: {error:?}");
                        continue;
                    }
                };
                fill(loaned.payload_mut(), &[&head, &body]);
                // SAFETY: `fill` wrote every one of the `length` bytes of the loaned slice.
                let frame = unsafe { loaned.assume_init() };
                if let Err(error) = frame.send() {
                    tracing::warn!("{output}: a shared-memory frame was not sent: {error:?}");
                }
            }
        })
        .map_err(ShmError::Thread)?;
    match ready_rx.recv_timeout(Duration::from_secs(10)) {
        Ok(Ok(())) => Ok(ShmPublication {
            stop,
            thread: Some(thread),
        }),
        Ok(Err(error)) => Err(error),
        Err(_) => Err(ShmError::NotReady),
    }
}
