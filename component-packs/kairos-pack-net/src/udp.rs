//! `net.udp_receiver` and `net.udp_sender`: one sample per datagram.

use std::collections::BTreeMap;
use std::net::{Ipv4Addr, SocketAddr, ToSocketAddrs as _, UdpSocket};
use std::sync::Arc;
use std::time::Duration;

use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{
    Component, ComponentError, ComponentInfo, ComponentResult, Context, DataType, DescribeError, Payload,
    ReaderPolicy, TypeFilter, Value,
};
use kairos_sdk::{Throttle, WARNING_PERIOD};

use crate::encoding::{self, SampleReceiver, SampleSender};

/// How long one receive waits, so stop and control requests get through.
const RECEIVE_WAIT: Duration = Duration::from_millis(50);
/// The largest UDP payload over IPv4.
const LARGEST_DATAGRAM: usize = 65_507;

/// The descriptor of `net.udp_receiver` as listed (raw bytes).
pub fn receiver_descriptor() -> ComponentInfo {
    receiver_base()
        .output("data", DataType::Bytes, "Each datagram")
        .build()
}

/// The descriptor of one `net.udp_receiver`: a bytes output, or with encoding kairos, one of the sent type.
pub fn describe_receiver(properties: &BTreeMap<String, Value>) -> Result<ComponentInfo, DescribeError> {
    Ok(if encoding::is_kairos(properties) {
        let data_type = encoding::data_type_of(properties)?;
        receiver_base()
            .output(
                encoding::SAMPLES,
                data_type,
                "Each sample received, with both its times",
            )
            .build()
    } else {
        receiver_descriptor()
    })
}

fn receiver_base() -> Descriptor {
    Descriptor::new(
        "net.udp_receiver",
        "network",
        "Receives UDP datagrams on an address, unicast or from a multicast group: one bytes sample per \
         datagram stamped on reception, or (encoding kairos) one Kairos sample per datagram with its times",
    )
    .label("UDP receiver")
    .property(Property::text("address", "0.0.0.0:5000").doc("The local address and port to listen on"))
    .property(
        Property::text("group", "").doc("An IPv4 multicast group to join (239.1.2.3), or empty for unicast"),
    )
    .property(
        Property::text("interface", "0.0.0.0")
            .doc("The local interface's address for the multicast group (0.0.0.0: the system's choice)"),
    )
    .property(encoding::property())
    .property(encoding::data_type_property())
}

fn failed(error: impl std::fmt::Display) -> ComponentError {
    ComponentError::failed(error)
}

/// `net.udp_receiver`. See [`receiver_descriptor`].
#[derive(Debug, Default)]
pub struct UdpReceiver {
    socket: Option<UdpSocket>,
    buffer: Vec<u8>,
    datagrams: u64,
    samples: Option<SampleReceiver>,
    /// The last sender and its address in words, written once rather than for every datagram.
    peer: Option<(SocketAddr, String)>,
}

impl Component for UdpReceiver {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        let address = ctx.text_property("address")?;
        let socket = UdpSocket::bind(&address)
            .map_err(|e| failed(format_args!("cannot listen on UDP {address}: {e}")))?;
        let group = ctx.text_property("group")?;
        if !group.is_empty() {
            let group: Ipv4Addr = group
                .parse()
                .map_err(|_| failed(format_args!("group {group:?} is not an IPv4 address (239.1.2.3)")))?;
            let interface: Ipv4Addr = ctx
                .text_property("interface")?
                .parse()
                .map_err(|_| failed("interface is not an IPv4 address"))?;
            socket
                .join_multicast_v4(&group, &interface)
                .map_err(|e| failed(format_args!("cannot join the multicast group {group}: {e}")))?;
        }
        socket.set_read_timeout(Some(RECEIVE_WAIT)).map_err(failed)?;
        self.socket = Some(socket);
        self.buffer = vec![0; LARGEST_DATAGRAM + 1];
        if encoding::is_kairos(ctx.properties()) {
            self.samples = Some(SampleReceiver::of(ctx)?);
        }
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let Some(socket) = &self.socket else {
            return Err(ComponentError::Stopped);
        };
        match socket.recv_from(&mut self.buffer) {
            Ok((read, peer)) => {
                let now = ctx.now();
                let datagram = self.buffer.get(..read).unwrap_or_default();
                self.datagrams += 1;
                if let Some(samples) = &mut self.samples {
                    if self.peer.as_ref().is_none_or(|(address, _)| *address != peer) {
                        self.peer = Some((peer, peer.to_string()));
                    }
                    let name = self.peer.as_ref().map_or("", |(_, name)| name.as_str());
                    samples.take(datagram, name, ctx)?;
                } else {
                    ctx.write_at("data", Payload::Bytes(Arc::from(datagram)), now)?;
                }
            }
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) => {}
            // An ICMP error from an earlier send on this socket, and the like: the socket still works.
            Err(e) => tracing::debug!("UDP receive: {e}"),
        }
        Ok(())
    }

    fn status(&self) -> Option<serde_json::Value> {
        let status = serde_json::json!({"kind": "udp", "datagrams": self.datagrams});
        Some(encoding::status_with(status, self.samples.as_ref()))
    }

    fn property_changed(&mut self, _name: &str, _value: &Value, _ctx: &mut Context) -> ComponentResult {
        Ok(())
    }
}

/// The descriptor of `net.udp_sender` as listed (text or bytes).
pub fn sender_descriptor() -> ComponentInfo {
    sender_base(encoding::sender_accepts(&BTreeMap::new()))
}

/// The descriptor of one `net.udp_sender`: text or bytes in, or with encoding kairos, samples of any type.
pub fn describe_sender(properties: &BTreeMap<String, Value>) -> Result<ComponentInfo, DescribeError> {
    Ok(sender_base(encoding::sender_accepts(properties)))
}

fn sender_base(accepts: TypeFilter) -> ComponentInfo {
    Descriptor::new(
        "net.udp_sender",
        "network",
        "Sends each text or bytes sample as one UDP datagram to an address, unicast or multicast; or \
         (encoding kairos) each sample of any type whole, with its times and sequence number",
    )
    .label("UDP sender")
    .input_with_policy("in", accepts, ReaderPolicy::Fifo, "What to send")
    .property(
        Property::text("destination", "127.0.0.1:5000")
            .doc("Where to send: address and port (a multicast group's address sends to the group)"),
    )
    .property(
        Property::i64("ttl", 1)
            .int_range(1, 255)
            .doc("Multicast time to live: how many routers a datagram may cross"),
    )
    .property(encoding::property())
    .build()
}

/// `net.udp_sender`. See [`sender_descriptor`].
#[derive(Debug, Default)]
pub struct UdpSender {
    socket: Option<UdpSocket>,
    destination: Option<SocketAddr>,
    /// With encoding kairos: whole samples.
    samples: Option<SampleSender>,
    sent: u64,
    failed: u64,
    too_large: u64,
    warned: Throttle,
}

impl UdpSender {
    /// Logs `what` at most once a second with the counts so far (an associated function, so it can run
    /// while the frame being sent borrows the sender).
    fn warn(warned: &mut Throttle, failed: u64, too_large: u64, what: &str) {
        if warned.ready(WARNING_PERIOD) {
            tracing::warn!("{what} ({failed} not sent, {too_large} too large, in all)");
        }
    }
}

impl Component for UdpSender {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        let destination = ctx.text_property("destination")?;
        let address = destination
            .to_socket_addrs()
            .map_err(|e| failed(format_args!("cannot resolve the destination {destination}: {e}")))?
            .next()
            .ok_or_else(|| failed(format_args!("{destination} resolves to no address")))?;
        let local = if address.is_ipv4() { "0.0.0.0:0" } else { "[::]:0" };
        let socket = UdpSocket::bind(local).map_err(failed)?;
        if address.ip().is_multicast() {
            let ttl = u32::try_from(ctx.i64_property("ttl")?).unwrap_or(1);
            socket.set_multicast_ttl_v4(ttl).map_err(failed)?;
        }
        self.socket = Some(socket);
        self.destination = Some(address);
        if encoding::is_kairos(ctx.properties()) {
            self.samples = Some(SampleSender::of(ctx));
        }
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("in")?;
        let bytes = match &mut self.samples {
            Some(sender) => sender.frame(&sample, false),
            None => encoding::raw_bytes(&sample.payload)?,
        };
        if bytes.len() > LARGEST_DATAGRAM {
            self.too_large += 1;
            let size = bytes.len();
            Self::warn(
                &mut self.warned,
                self.failed,
                self.too_large,
                &format!(
                    "a sample of {size} bytes is larger than a UDP datagram can be ({LARGEST_DATAGRAM}); not sent (TCP carries any size)"
                ),
            );
        } else if let (Some(socket), Some(destination)) = (&self.socket, self.destination) {
            match socket.send_to(bytes, destination) {
                Ok(_) => self.sent += 1,
                Err(e) => {
                    self.failed += 1;
                    let what = format!("cannot send to {destination}: {e}");
                    Self::warn(&mut self.warned, self.failed, self.too_large, &what);
                }
            }
        }
        Ok(())
    }

    fn status(&self) -> Option<serde_json::Value> {
        Some(serde_json::json!({
            "kind": "udp", "sent": self.sent, "failed": self.failed, "too_large": self.too_large,
        }))
    }

    fn property_changed(&mut self, _name: &str, _value: &Value, _ctx: &mut Context) -> ComponentResult {
        Ok(())
    }
}
