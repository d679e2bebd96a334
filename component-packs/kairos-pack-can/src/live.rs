//! `can.socketcan_reader` and `can.socketcan_writer`: a live bus through Linux SocketCAN, classic CAN or
//! CAN FD, on the `socketcan` crate.

use std::io::ErrorKind;
use std::path::Path;
use std::time::Duration;

use kairos_sdk::descriptor::{Descriptor, Property};
use kairos_sdk::{
    CanFrame, Component, ComponentError, ComponentInfo, ComponentResult, Context, DataType, Payload,
    ReaderPolicy, TypeFilter, Value,
};
use kairos_sdk::{DeviceKind, Throttle};
use socketcan::{
    CanAnyFrame, CanDataFrame, CanErrorFrame, CanFdFrame, CanFdSocket, CanFilter, CanFrame as BusFrame,
    CanRemoteFrame, CanSocket, EmbeddedFrame, ExtendedId, Frame as _, Id, Socket, SocketOptions, StandardId,
};

/// How long one read waits, so stop and control requests get through.
const READ_WAIT: Duration = Duration::from_millis(50);

fn failed(error: impl std::fmt::Display) -> ComponentError {
    ComponentError::failed(error)
}

/// Why the `filters` property cannot be read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0:?} is not a hexadecimal identifier")]
pub struct FilterError(String);

/// Why a bus could not be opened: the system, the interface, or its configuration.
#[derive(Debug, thiserror::Error)]
enum OpenError {
    /// The kernel has no SocketCAN: the fix is a module, not the diagram.
    #[error(
        "cannot open CAN interface '{interface}': this system has no SocketCAN ({source}); load the \
             kernel's can and can_raw modules (modprobe can_raw)"
    )]
    NoSocketCan {
        interface: String,
        source: std::io::Error,
    },
    /// No such interface: the fix is its name, or a virtual bus.
    #[error(
        "no CAN interface '{interface}' ({source}); `kairos devices` lists those present; a virtual bus: \
             ip link add dev vcan0 type vcan && ip link set up vcan0"
    )]
    NoInterface {
        interface: String,
        source: std::io::Error,
    },
    /// Any other refusal to open it (permissions, a busy device).
    #[error("cannot open CAN interface '{interface}': {source}")]
    Open {
        interface: String,
        source: std::io::Error,
    },
    /// Opened, but its filters or timeouts could not be set.
    #[error("cannot configure CAN interface '{interface}': {source}")]
    Configure {
        interface: String,
        source: std::io::Error,
    },
}

/// Why a frame was not sent: counted, and said once a second.
#[derive(Debug, thiserror::Error)]
enum SendError {
    /// An identifier beyond its width.
    #[error("{id:#x} is not a valid {} identifier", if *.extended { "29-bit" } else { "11-bit" })]
    BadId { id: u32, extended: bool },
    /// A remote request longer than the bus allows.
    #[error("a remote request the bus cannot carry")]
    RemoteTooLong,
    /// FD data on a socket opened for classic frames.
    #[error("a CAN FD frame on a classic socket: set 'fd' to send it")]
    FdOnClassic,
    /// More data than the frame kind holds.
    #[error("a frame the bus cannot carry")]
    TooLong,
    /// `ENOBUFS`: frames wait for an acknowledgement that does not come.
    #[error("the interface's transmit queue is full (the bus is saturated, or nobody acknowledges)")]
    QueueFull,
    /// What the kernel said otherwise.
    #[error(transparent)]
    Io(std::io::Error),
}

/// Parses `filters`: comma-separated `ID` (that identifier alone) or `ID:MASK` (the identifiers whose
/// masked bits equal ID's), hexadecimal with or without `0x`. Empty: every frame.
pub fn parse_filters(text: &str) -> Result<Vec<(u32, u32)>, FilterError> {
    let hex = |part: &str| {
        let digits = part.trim().trim_start_matches("0x").trim_start_matches("0X");
        u32::from_str_radix(digits, 16).map_err(|_| FilterError(part.trim().to_owned()))
    };
    text.split(',')
        .filter(|part| !part.trim().is_empty())
        .map(|part| match part.split_once(':') {
            Some((id, mask)) => Ok((hex(id)?, hex(mask)?)),
            // One identifier: every one of its bits must match (an extended one's 29).
            None => hex(part).map(|id| (id, if id > 0x7FF { 0x1FFF_FFFF } else { 0x7FF })),
        })
        .collect()
}

/// Why an interface cannot be opened, in words that say what to do.
fn open_error(interface: &str, source: std::io::Error) -> OpenError {
    let interface = interface.to_owned();
    if !Path::new("/proc/net/can").exists() {
        return OpenError::NoSocketCan { interface, source };
    }
    if source.raw_os_error() == Some(libc_enodev()) || source.kind() == ErrorKind::NotFound {
        return OpenError::NoInterface { interface, source };
    }
    OpenError::Open { interface, source }
}

/// `ENODEV`, the error for a network interface that does not exist.
const fn libc_enodev() -> i32 {
    19
}

/// `ENOBUFS`: the interface's transmit queue is full.
const ENOBUFS: i32 = 105;

/// An open bus: classic frames only, or classic and FD.
#[derive(Debug)]
enum Bus {
    Classic(CanSocket),
    Fd(CanFdSocket),
}

/// What one read gave.
#[derive(Debug)]
enum Received {
    Frame(CanFrame),
    Remote(CanFrame),
    Error(String),
    /// More data than a frame holds: cannot come from the kernel, counted if it ever does.
    Oversized,
}

impl Bus {
    fn open(interface: &str, fd: bool, filters: &[(u32, u32)]) -> Result<Self, OpenError> {
        let bus = if fd {
            CanFdSocket::open(interface).map(Bus::Fd)
        } else {
            CanSocket::open(interface).map(Bus::Classic)
        }
        .map_err(|e| open_error(interface, e))?;
        let filters: Vec<CanFilter> = filters
            .iter()
            .map(|(id, mask)| CanFilter::new(*id, *mask))
            .collect();
        let configured = match &bus {
            Bus::Classic(socket) => Self::configure(socket, &filters),
            Bus::Fd(socket) => Self::configure(socket, &filters),
        };
        configured.map_err(|source| OpenError::Configure {
            interface: interface.to_owned(),
            source,
        })?;
        Ok(bus)
    }

    fn configure<S: Socket + SocketOptions>(socket: &S, filters: &[CanFilter]) -> std::io::Result<()> {
        if !filters.is_empty() {
            socket.set_filters(filters)?;
        }
        // Error frames are counted and reported, never mistaken for data.
        socket.set_error_filter_accept_all()?;
        socket.set_read_timeout(READ_WAIT)
    }

    fn read(&self) -> std::io::Result<Received> {
        Ok(match self {
            Bus::Classic(socket) => match socket.read_frame()? {
                BusFrame::Data(frame) => converted(frame.raw_id(), frame.is_extended(), frame.data(), false),
                BusFrame::Remote(frame) => remote(frame.raw_id(), frame.is_extended(), frame.dlc()),
                BusFrame::Error(frame) => Received::Error(error_text(frame)),
            },
            Bus::Fd(socket) => match socket.read_frame()? {
                CanAnyFrame::Normal(frame) => {
                    converted(frame.raw_id(), frame.is_extended(), frame.data(), false)
                }
                CanAnyFrame::Fd(frame) => converted(frame.raw_id(), frame.is_extended(), frame.data(), true),
                CanAnyFrame::Remote(frame) => remote(frame.raw_id(), frame.is_extended(), frame.dlc()),
                CanAnyFrame::Error(frame) => Received::Error(error_text(frame)),
            },
        })
    }

    fn write(&self, frame: &CanFrame) -> Result<(), SendError> {
        let id: Id = if frame.extended {
            ExtendedId::new(frame.id).map(Id::Extended)
        } else {
            u16::try_from(frame.id)
                .ok()
                .and_then(StandardId::new)
                .map(Id::Standard)
        }
        .ok_or(SendError::BadId {
            id: frame.id,
            extended: frame.extended,
        })?;
        let remote =
            || CanRemoteFrame::new_remote(id, usize::from(frame.length())).ok_or(SendError::RemoteTooLong);
        let written = match self {
            Bus::Classic(socket) if frame.remote => socket.write_frame(&remote()?),
            Bus::Fd(socket) if frame.remote => socket.write_frame(&remote()?),
            Bus::Classic(socket) => {
                if frame.fd || frame.data().len() > 8 {
                    return Err(SendError::FdOnClassic);
                }
                let data = CanDataFrame::new(id, frame.data()).ok_or(SendError::TooLong)?;
                socket.write_frame(&data)
            }
            Bus::Fd(socket) if frame.fd || frame.data().len() > 8 => {
                let data = CanFdFrame::new(id, frame.data()).ok_or(SendError::TooLong)?;
                socket.write_frame(&data)
            }
            Bus::Fd(socket) => {
                let data = CanDataFrame::new(id, frame.data()).ok_or(SendError::TooLong)?;
                socket.write_frame(&data)
            }
        };
        written.map_err(|e| {
            if e.raw_os_error() == Some(ENOBUFS) {
                SendError::QueueFull
            } else {
                SendError::Io(e)
            }
        })
    }
}

/// A received remote request as a sample's frame.
fn remote(id: u32, extended: bool, length: usize) -> Received {
    u8::try_from(length)
        .ok()
        .and_then(|length| CanFrame::remote_request(id, extended, length))
        .map_or(Received::Oversized, Received::Remote)
}

/// A received data frame as a sample's frame.
fn converted(id: u32, extended: bool, data: &[u8], fd: bool) -> Received {
    match CanFrame::new(id, extended, data) {
        Some(mut frame) => {
            frame.fd |= fd;
            Received::Frame(frame)
        }
        None => Received::Oversized,
    }
}

fn error_text(frame: CanErrorFrame) -> String {
    socketcan::CanError::from(frame).to_string()
}

fn interface_property() -> Property {
    Property::text("interface", "can0")
        .doc("The SocketCAN interface (can0, vcan0); `kairos devices` lists them")
        .device(DeviceKind::Can)
}

fn fd_property() -> Property {
    Property::bool("fd", false)
        .doc("CAN FD: frames of up to 64 bytes (the interface must be configured for FD)")
}

/// The descriptor of `can.socketcan_reader`.
pub fn reader_descriptor() -> ComponentInfo {
    Descriptor::new(
        "can.socketcan_reader",
        "CAN",
        "Reads a live CAN bus through SocketCAN: one frame sample per data frame, stamped on reception; \
         error frames counted and reported",
    )
    .label("CAN bus reader (SocketCAN)")
    .output("frame", DataType::CanFrame, "Each data frame received")
    .property(interface_property())
    .property(fd_property())
    .property(Property::text("filters", "").doc(
        "Only these frames (the kernel filters them): comma-separated hexadecimal IDs, or ID:MASK pairs \
         (100, 18FF0000:1FFF0000); empty: every frame",
    ))
    .build()
}

/// `can.socketcan_reader`. See [`reader_descriptor`].
#[derive(Debug, Default)]
pub struct SocketCanReader {
    bus: Option<Bus>,
    interface: String,
    frames: u64,
    /// Of the frames, remote requests.
    remote: u64,
    oversized: u64,
    errors: u64,
    last_error: String,
    warnings: Throttle,
}

impl Component for SocketCanReader {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        self.interface = ctx.text_property("interface")?;
        let filters = parse_filters(&ctx.text_property("filters")?)
            .map_err(|e| failed(format_args!("filters: {e}")))?;
        self.bus = Some(Bus::open(&self.interface, ctx.bool_property("fd")?, &filters).map_err(failed)?);
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let Some(bus) = &self.bus else {
            return Err(ComponentError::Stopped);
        };
        match bus.read() {
            Ok(Received::Frame(frame)) => {
                self.frames += 1;
                let now = ctx.now();
                ctx.write_at("frame", Payload::CanFrame(frame), now)?;
            }
            Ok(Received::Remote(frame)) => {
                self.frames += 1;
                self.remote += 1;
                let now = ctx.now();
                ctx.write_at("frame", Payload::CanFrame(frame), now)?;
            }
            Ok(Received::Oversized) => self.oversized += 1,
            Ok(Received::Error(what)) => {
                self.errors += 1;
                let (interface, count) = (&self.interface, self.errors);
                self.warnings
                    .warn(|| format!("{interface}: error frame: {what} ({count} in all)"));
                self.last_error = what;
            }
            Err(e)
                if matches!(
                    e.kind(),
                    ErrorKind::WouldBlock | ErrorKind::TimedOut | ErrorKind::Interrupted
                ) => {}
            Err(e) => {
                // The interface went down, or away: say so once a second and keep trying.
                let interface = &self.interface;
                self.warnings.warn(|| format!("{interface}: {e}; reading again"));
                ctx.sleep(READ_WAIT)?;
            }
        }
        Ok(())
    }

    fn status(&self) -> Option<serde_json::Value> {
        Some(serde_json::json!({
            "kind": "can", "interface": self.interface, "frames": self.frames, "remote_frames": self.remote,
            "oversized": self.oversized, "error_frames": self.errors, "last_error": self.last_error,
        }))
    }

    fn property_changed(&mut self, _name: &str, _value: &Value, _ctx: &mut Context) -> ComponentResult {
        Ok(())
    }
}

/// The descriptor of `can.socketcan_writer`.
pub fn writer_descriptor() -> ComponentInfo {
    Descriptor::new(
        "can.socketcan_writer",
        "CAN",
        "Sends each frame sample on a live CAN bus through SocketCAN",
    )
    .label("CAN bus writer (SocketCAN)")
    .input_with_policy(
        "frame",
        TypeFilter::OneOf(vec![DataType::CanFrame]),
        ReaderPolicy::Fifo,
        "The frames to send",
    )
    .property(interface_property())
    .property(fd_property())
    .build()
}

/// `can.socketcan_writer`. See [`writer_descriptor`].
#[derive(Debug, Default)]
pub struct SocketCanWriter {
    bus: Option<Bus>,
    interface: String,
    sent: u64,
    not_sent: u64,
    warnings: Throttle,
}

impl Component for SocketCanWriter {
    fn birth(&mut self, ctx: &mut Context) -> ComponentResult {
        self.interface = ctx.text_property("interface")?;
        self.bus = Some(Bus::open(&self.interface, ctx.bool_property("fd")?, &[]).map_err(failed)?);
        Ok(())
    }

    fn core(&mut self, ctx: &mut Context) -> ComponentResult {
        let sample = ctx.read("frame")?;
        let Payload::CanFrame(frame) = &sample.payload else {
            return Err(failed(format_args!(
                "expected a CAN frame, got {}",
                sample.payload.data_type()
            )));
        };
        let Some(bus) = &self.bus else {
            return Err(ComponentError::Stopped);
        };
        match bus.write(frame) {
            Ok(()) => self.sent += 1,
            Err(why) => {
                self.not_sent += 1;
                let (interface, count) = (&self.interface, self.not_sent);
                self.warnings
                    .warn(|| format!("{interface}: frame not sent: {why} ({count} in all)"));
            }
        }
        Ok(())
    }

    fn status(&self) -> Option<serde_json::Value> {
        Some(serde_json::json!({
            "kind": "can", "interface": self.interface, "sent": self.sent, "not_sent": self.not_sent,
        }))
    }

    fn property_changed(&mut self, _name: &str, _value: &Value, _ctx: &mut Context) -> ComponentResult {
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::parse_filters;

    #[test]
    fn filters_are_identifiers_or_identifier_mask_pairs_in_hexadecimal() {
        assert_eq!(parse_filters(""), Ok(vec![]));
        assert_eq!(
            parse_filters("100, 0x18FF0000:1FFF0000"),
            Ok(vec![(0x100, 0x7FF), (0x18FF_0000, 0x1FFF_0000)])
        );
        assert_eq!(parse_filters("18FEF100"), Ok(vec![(0x18FE_F100, 0x1FFF_FFFF)]));
        assert!(parse_filters("12G").unwrap_err().to_string().contains("\"12G\""));
    }
}
