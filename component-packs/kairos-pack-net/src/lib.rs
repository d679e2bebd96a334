//! The network pack: UDP and TCP for devices and programs that speak their own protocol over the network
//! (raw bytes), and for other Kairos runtimes (whole samples with both times and their sequence number,
//! `encoding: kairos`): paper §2.3.2, RTMaps' socket components.
//!
//! | type | what it does |
//! | --- | --- |
//! | `net.udp_receiver` | one bytes sample per datagram received on an address, unicast or from a multicast group |
//! | `net.udp_sender` | sends each text or bytes sample as one datagram, unicast or to a multicast group |
//! | `net.tcp_receiver` | reads a TCP connection (as a client, or as a server of many clients): raw reads, lines or length-prefixed messages |
//! | `net.tcp_sender` | writes each sample to a TCP connection (as a client, or to every client of a server), framed the same ways |
//!
//! Every received sample is stamped on reception. Lost links are reported once and opened again every
//! second; what could not be sent or was cut off is counted in the component's status.

pub mod encoding;
pub mod framing;

pub mod tcp;
pub mod udp;

use kairos_sdk::Registry;

/// Registers the pack "net".
pub fn register(registry: &mut Registry) {
    registry
        .pack("net", env!("CARGO_PKG_VERSION"), "built-in")
        .component_described::<udp::UdpReceiver>(udp::receiver_descriptor(), udp::describe_receiver)
        .component_described::<udp::UdpSender>(udp::sender_descriptor(), udp::describe_sender)
        .component_described::<tcp::TcpReceiver>(tcp::receiver_descriptor(), tcp::describe_receiver)
        .component_described::<tcp::TcpSender>(tcp::sender_descriptor(), tcp::describe_sender);
}
