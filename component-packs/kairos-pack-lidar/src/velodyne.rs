//! `lidar.velodyne`: a Velodyne VLP-16, VLP-32C or HDL-32E, live over UDP or replayed from a pcap capture.

use std::net::UdpSocket;
use std::path::Path;
use std::sync::Arc;
use std::time::Duration;

use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{
    Component, ComponentError, ComponentInfo, ComponentResult, Context, DataType, Payload, PointCloud,
    Timestamp, Value,
};
use kairos_sdk::{Throttle, WARNING_PERIOD};

use crate::packets::{Decoder, Model};
use crate::pcap::Capture;

/// How long one receive waits, so stop and control requests get through.
const RECEIVE_WAIT: Duration = Duration::from_millis(50);

/// The descriptor of `lidar.velodyne`.
pub fn descriptor() -> ComponentInfo {
    Descriptor::new(
        "lidar.velodyne",
        "lidar",
        "Velodyne lidar (VLP-16, VLP-32C, HDL-32E): data packets from UDP or a pcap capture, one point \
         cloud per revolution (x forward, y left, z up, metres; intensity from the reflectivity)",
    )
    .label("Velodyne lidar")
    .output("points", DataType::PointCloud, "A revolution's points")
    .property(
        Property::choice("model", &["auto", "VLP-16", "VLP-32C", "HDL-32E"], "auto").doc(
            "The sensor; auto reads it from each packet's product id (set it for a sensor whose packets do \
             not say)",
        ),
    )
    .property(Property::choice("source", &["udp", "pcap"], "udp").doc("Live packets, or a capture"))
    .property(
        Property::text("address", "0.0.0.0:2368")
            .doc("UDP: where to listen (the sensor sends its data packets to port 2368)"),
    )
    .property(Property::path("path", "").doc("pcap: the capture file"))
    .property(
        Property::i64("port", 2368)
            .int_range(1, 65_535)
            .doc("pcap: the destination port of the data packets in the capture"),
    )
    .property(
        Property::choice("replay", &["timing", "fast"], "timing")
            .doc("pcap: at the capture's timing, or as fast as the readers take the clouds"),
    )
    .property(Property::bool("loop", false).doc("pcap: start again at the end"))
    .build()
}

enum Input {
    Udp(UdpSocket, Vec<u8>),
    Pcap {
        path: String,
        capture: Capture,
        port: u16,
        at_timing: bool,
        looping: bool,
        /// The first packet's capture time and the clock time it was replayed at.
        anchor: Option<(i64, Timestamp)>,
        /// A packet whose wait a control request interrupted.
        pending: Option<crate::pcap::Datagram>,
    },
}

/// `lidar.velodyne`. See [`descriptor`].
#[derive(Default)]
pub struct Velodyne {
    input: Option<Input>,
    decoder: Decoder,
    packets: u64,
    bad_packets: u64,
    revolutions: u64,
    last_problem: String,
    warned: Throttle,
}

impl std::fmt::Debug for Velodyne {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Velodyne")
            .field("packets", &self.packets)
            .field("revolutions", &self.revolutions)
            .finish_non_exhaustive()
    }
}

fn failed(error: impl std::fmt::Display) -> ComponentError {
    ComponentError::failed(error)
}

impl Velodyne {
    fn open(ctx: &Context) -> Result<Input, ComponentError> {
        if ctx.text_property("source")? == "pcap" {
            let path = ctx.text_property("path")?;
            if path.is_empty() {
                return Err(failed(
                    "source is pcap but no path is given: set the property path",
                ));
            }
            let capture = Capture::open(Path::new(&path)).map_err(failed)?;
            return Ok(Input::Pcap {
                path,
                capture,
                port: u16::try_from(ctx.i64_property("port")?).unwrap_or(2368),
                at_timing: ctx.text_property("replay")? == "timing",
                looping: ctx.bool_property("loop")?,
                anchor: None,
                pending: None,
            });
        }
        let address = ctx.text_property("address")?;
        let socket = UdpSocket::bind(&address)
            .map_err(|e| failed(format_args!("cannot listen on UDP {address}: {e}")))?;
        socket.set_read_timeout(Some(RECEIVE_WAIT)).map_err(failed)?;
        Ok(Input::Udp(socket, vec![0; 65_536]))
    }

    /// Decodes one packet, writing the revolutions it completes stamped `at`.
    fn packet(&mut self, ctx: &mut Context, payload: &[u8], at: Timestamp) -> ComponentResult {
        let mut clouds = Vec::new();
        match self.decoder.packet(payload, |cloud| clouds.push(cloud)) {
            Ok(()) => self.packets += 1,
            Err(error) => {
                self.bad_packets += 1;
                self.last_problem = error.to_string();
                if self.warned.ready(WARNING_PERIOD) {
                    tracing::warn!(
                        "{} packet(s) refused in all (last: {})",
                        self.bad_packets,
                        self.last_problem
                    );
                }
            }
        }
        for cloud in clouds {
            self.write(ctx, cloud, at)?;
        }
        Ok(())
    }

    fn write(&mut self, ctx: &mut Context, cloud: PointCloud, at: Timestamp) -> ComponentResult {
        self.revolutions += 1;
        ctx.write_at("points", Payload::PointCloud(Arc::new(cloud)), at)
    }
}

impl Component for Velodyne {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        self.decoder = match Model::named(&ctx.text_property("model")?) {
            Some(model) => Decoder::for_model(model),
            None => Decoder::new(),
        };
        self.input = Some(Self::open(ctx)?);
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let mut received: Option<(Vec<u8>, Timestamp)> = None;
        let mut ended = false;
        match &mut self.input {
            Some(Input::Udp(socket, buffer)) => match socket.recv(buffer) {
                Ok(read) => received = Some((buffer.get(..read).unwrap_or_default().to_vec(), ctx.now())),
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) => {}
                Err(e) => tracing::debug!("UDP receive: {e}"),
            },
            Some(Input::Pcap {
                path,
                capture,
                port,
                at_timing,
                looping,
                anchor,
                pending,
            }) => {
                let next = match pending.take() {
                    Some(datagram) => Some(datagram),
                    None => loop {
                        match capture.next_datagram() {
                            Some(datagram) if datagram.port == *port => break Some(datagram),
                            Some(_) => {}
                            None => {
                                if let Some(why) = capture.cut_short.take() {
                                    tracing::warn!("{path}: {why}");
                                }
                                if !*looping {
                                    break None;
                                }
                                *capture = Capture::open(Path::new(path.as_str())).map_err(failed)?;
                                *anchor = None;
                            }
                        }
                    },
                };
                match next {
                    Some(datagram) => {
                        let now = ctx.now();
                        let (first, at) = *anchor.get_or_insert((datagram.time_ns, now));
                        let due = if *at_timing {
                            Timestamp(at.0 + (datagram.time_ns - first).max(0))
                        } else {
                            now
                        };
                        if *at_timing && let Err(interrupted) = ctx.wait_until(due) {
                            // A control request first; this packet waits for its time again next call.
                            *pending = Some(datagram);
                            return Err(interrupted);
                        }
                        received = Some((datagram.payload, due));
                    }
                    None => ended = true,
                }
            }
            None => return Err(ComponentError::Stopped),
        }
        if let Some((payload, at)) = received {
            self.packet(ctx, &payload, at)?;
        }
        if ended {
            if let Some(cloud) = self.decoder.finish() {
                let now = ctx.now();
                self.write(ctx, cloud, now)?;
            }
            return Err(ComponentError::EndOfStream);
        }
        Ok(())
    }

    fn death(&mut self, _ctx: &mut Context) -> ComponentResult {
        self.input = None;
        Ok(())
    }

    fn status(&self) -> Option<serde_json::Value> {
        Some(serde_json::json!({
            "kind": "lidar", "model": self.decoder.model().map(Model::name),
            "packets": self.packets, "bad_packets": self.bad_packets, "revolutions": self.revolutions,
        }))
    }

    fn property_changed(&mut self, _name: &str, _value: &Value, _ctx: &mut Context) -> ComponentResult {
        Ok(())
    }
}
