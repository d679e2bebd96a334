//! Byte links a component reads: a serial port, a UDP socket, a TCP connection, or a file. Each read waits a
//! short while at most, so the component stays responsive to stop, pause and property changes; a link
//! that drops (a serial adapter unplugged, a TCP peer gone) is reopened once a second.

use std::fs::File;
use std::io::{BufRead as _, BufReader, ErrorKind, Read as _};
use std::net::{TcpStream, ToSocketAddrs as _, UdpSocket};
use std::time::{Duration, Instant};

/// How long one read waits for bytes.
pub const READ_WAIT: Duration = Duration::from_millis(50);
/// How long after a failure a link is opened again.
pub const REOPEN_AFTER: Duration = Duration::from_secs(1);

/// The settings of a serial port.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SerialSettings {
    /// The device (`/dev/ttyUSB0`).
    pub device: String,
    /// Bits per second.
    pub baud: u32,
    /// `none`, `even` or `odd`.
    pub parity: String,
    /// 1 or 2.
    pub stop_bits: u8,
    /// `none`, `software` (XON/XOFF) or `hardware` (RTS/CTS).
    pub flow_control: String,
}

/// Why a link could not be opened: a serial port, a UDP address to listen on, a TCP server to reach.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    /// The port is missing, taken, or refuses its settings.
    #[error("cannot open the serial port {device}: {source}")]
    Serial {
        device: String,
        source: serialport::Error,
    },
    /// The address is in use or not this machine's.
    #[error("cannot listen on UDP {address}: {source}")]
    UdpBind { address: String, source: std::io::Error },
    /// The socket's read timeout could not be set.
    #[error("UDP {address}: {source}")]
    UdpConfigure { address: String, source: std::io::Error },
    /// The server's name did not resolve.
    #[error("cannot resolve {address}: {source}")]
    Resolve { address: String, source: std::io::Error },
    /// The name resolved to nothing to connect to.
    #[error("{address} resolves to no address")]
    NoAddress { address: String },
    /// Nobody listens there, or it did not answer within a second.
    #[error("cannot connect to TCP {address}: {source}")]
    TcpConnect { address: String, source: std::io::Error },
    /// The stream's read timeout could not be set.
    #[error("TCP {address}: {source}")]
    TcpConfigure { address: String, source: std::io::Error },
}

/// Why a file of lines could not be read for replay.
#[derive(Debug, thiserror::Error)]
pub enum FileError {
    /// Missing, or not readable by this user.
    #[error("cannot open {path}: {source}")]
    Open { path: String, source: std::io::Error },
    /// It went wrong part way.
    #[error("cannot read {path}: {source}")]
    Read { path: String, source: std::io::Error },
}

impl SerialSettings {
    /// Opens the port, with reads that wait [`READ_WAIT`] at most.
    ///
    /// # Errors
    ///
    /// The port cannot be opened or configured; the message names it and the cause.
    pub fn open(&self) -> Result<Box<dyn serialport::SerialPort>, LinkError> {
        let parity = match self.parity.as_str() {
            "even" => serialport::Parity::Even,
            "odd" => serialport::Parity::Odd,
            _ => serialport::Parity::None,
        };
        let stop_bits = if self.stop_bits == 2 {
            serialport::StopBits::Two
        } else {
            serialport::StopBits::One
        };
        let flow_control = match self.flow_control.as_str() {
            "software" => serialport::FlowControl::Software,
            "hardware" => serialport::FlowControl::Hardware,
            _ => serialport::FlowControl::None,
        };
        serialport::new(&self.device, self.baud)
            .data_bits(serialport::DataBits::Eight)
            .parity(parity)
            .stop_bits(stop_bits)
            .flow_control(flow_control)
            .timeout(READ_WAIT)
            .open()
            .map_err(|source| LinkError::Serial {
                device: self.device.clone(),
                source,
            })
    }
}

/// An open byte stream.
#[derive(Debug)]
enum Link {
    Serial(Box<dyn serialport::SerialPort>),
    Udp(UdpSocket),
    Tcp(TcpStream),
}

/// What a source is asked to read.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Endpoint {
    /// A serial port.
    Serial(SerialSettings),
    /// Datagrams received on this local address (`0.0.0.0:10110`).
    Udp(String),
    /// A TCP server to connect to (`192.168.1.20:10110`).
    Tcp(String),
}

impl Endpoint {
    fn describe(&self) -> String {
        match self {
            Endpoint::Serial(settings) => format!("serial port {}", settings.device),
            Endpoint::Udp(address) => format!("UDP {address}"),
            Endpoint::Tcp(address) => format!("TCP {address}"),
        }
    }

    fn open(&self) -> Result<Link, LinkError> {
        match self {
            Endpoint::Serial(settings) => settings.open().map(Link::Serial),
            Endpoint::Udp(address) => {
                let socket = UdpSocket::bind(address).map_err(|source| LinkError::UdpBind {
                    address: address.clone(),
                    source,
                })?;
                socket
                    .set_read_timeout(Some(READ_WAIT))
                    .map_err(|source| LinkError::UdpConfigure {
                        address: address.clone(),
                        source,
                    })?;
                Ok(Link::Udp(socket))
            }
            Endpoint::Tcp(address) => {
                let target = address
                    .to_socket_addrs()
                    .map_err(|source| LinkError::Resolve {
                        address: address.clone(),
                        source,
                    })?
                    .next()
                    .ok_or_else(|| LinkError::NoAddress {
                        address: address.clone(),
                    })?;
                let stream =
                    TcpStream::connect_timeout(&target, Duration::from_secs(1)).map_err(|source| {
                        LinkError::TcpConnect {
                            address: address.clone(),
                            source,
                        }
                    })?;
                stream
                    .set_read_timeout(Some(READ_WAIT))
                    .map_err(|source| LinkError::TcpConfigure {
                        address: address.clone(),
                        source,
                    })?;
                Ok(Link::Tcp(stream))
            }
        }
    }
}

/// Cuts a byte stream into lines: a line ends at `\n` (a `\r` before it is dropped); a line longer
/// than the longest expected is dropped whole and counted.
#[derive(Debug)]
pub struct LineSplitter {
    longest: usize,
    partial: Vec<u8>,
    overlong: bool,
    /// Lines dropped for being too long.
    pub dropped_overlong: u64,
}

impl LineSplitter {
    /// A splitter that drops lines longer than `longest` bytes.
    pub fn new(longest: usize) -> Self {
        LineSplitter {
            longest,
            partial: Vec::new(),
            overlong: false,
            dropped_overlong: 0,
        }
    }

    /// Feeds `bytes`; calls `on_line` with every complete line.
    pub fn feed(&mut self, bytes: &[u8], mut on_line: impl FnMut(&[u8])) {
        for &byte in bytes {
            if byte == b'\n' {
                if self.overlong {
                    self.dropped_overlong += 1;
                } else {
                    let line = self.partial.strip_suffix(b"\r").unwrap_or(&self.partial);
                    if !line.is_empty() {
                        on_line(line);
                    }
                }
                self.partial.clear();
                self.overlong = false;
            } else if self.partial.len() > self.longest {
                self.overlong = true;
            } else {
                self.partial.push(byte);
            }
        }
    }

    /// Ends the stream: a last line without its line ending counts as a line; returns it.
    pub fn finish(&mut self) -> Option<Vec<u8>> {
        let line = std::mem::take(&mut self.partial);
        let overlong = std::mem::take(&mut self.overlong);
        (!line.is_empty() && !overlong).then_some(line)
    }
}

/// A live source of lines: a serial port, UDP or TCP, reopened after a failure.
#[derive(Debug)]
pub struct LiveSource {
    endpoint: Endpoint,
    link: Option<Link>,
    /// When opening last failed, and why.
    failed: Option<(Instant, String)>,
    splitter: LineSplitter,
    buffer: Vec<u8>,
}

/// What one wait on a live source gave.
#[derive(Debug, Default)]
pub struct Received {
    /// Complete lines.
    pub lines: Vec<Vec<u8>>,
    /// A failure to report (once per outage): the link could not be opened or went away.
    pub problem: Option<String>,
    /// The link came back after a failure.
    pub recovered: bool,
}

impl LiveSource {
    /// A source for `endpoint` whose lines are at most `longest` bytes, opened at the first read.
    pub fn new(endpoint: Endpoint, longest: usize) -> Self {
        LiveSource {
            endpoint,
            link: None,
            failed: None,
            splitter: LineSplitter::new(longest),
            buffer: vec![0; 64 * 1024],
        }
    }

    /// Opens the link now: an error names the device or address and the cause.
    ///
    /// # Errors
    ///
    /// The device cannot be opened or the address not bound or reached.
    pub fn open_now(&mut self) -> Result<(), LinkError> {
        self.link = Some(self.endpoint.open()?);
        Ok(())
    }

    /// Lines dropped for being longer than a sentence can be.
    pub fn dropped_overlong(&self) -> u64 {
        self.splitter.dropped_overlong
    }

    /// Waits [`READ_WAIT`] at most for bytes and returns the complete lines they end.
    pub fn receive(&mut self) -> Received {
        let (mut bytes, mut received) = self.receive_bytes();
        if received.problem.is_some() && self.link.is_none() {
            // The link went: a line it cut is not joined to what comes after it.
            self.splitter = LineSplitter {
                dropped_overlong: self.splitter.dropped_overlong,
                ..LineSplitter::new(self.splitter.longest)
            };
        }
        // A datagram is whole: its last line needs no line ending.
        if matches!(self.link, Some(Link::Udp(_))) && !bytes.is_empty() && bytes.last() != Some(&b'\n') {
            bytes.push(b'\n');
        }
        self.splitter
            .feed(&bytes, |line| received.lines.push(line.to_vec()));
        received
    }

    /// Waits [`READ_WAIT`] at most for bytes and returns them as read (a datagram whole).
    pub fn receive_bytes(&mut self) -> (Vec<u8>, Received) {
        let mut received = Received::default();
        if self.link.is_none() {
            if let Some((at, _)) = &self.failed
                && at.elapsed() < REOPEN_AFTER
            {
                std::thread::sleep(READ_WAIT);
                return (Vec::new(), received);
            }
            match self.endpoint.open() {
                Ok(link) => {
                    self.link = Some(link);
                    received.recovered = self.failed.take().is_some();
                }
                Err(reason) => {
                    let reason = reason.to_string();
                    let first = self.failed.is_none();
                    self.failed = Some((Instant::now(), reason.clone()));
                    if first {
                        received.problem = Some(reason);
                    }
                    return (Vec::new(), received);
                }
            }
        }
        let result = match &mut self.link {
            Some(Link::Serial(port)) => port.read(&mut self.buffer),
            Some(Link::Tcp(stream)) => match stream.read(&mut self.buffer) {
                Ok(0) => Err(std::io::Error::new(
                    ErrorKind::UnexpectedEof,
                    "the peer closed the connection",
                )),
                other => other,
            },
            Some(Link::Udp(socket)) => socket.recv(&mut self.buffer),
            None => return (Vec::new(), received),
        };
        match result {
            Ok(read) => return (self.buffer.get(..read).unwrap_or_default().to_vec(), received),
            Err(e)
                if matches!(
                    e.kind(),
                    ErrorKind::TimedOut | ErrorKind::WouldBlock | ErrorKind::Interrupted
                ) => {}
            Err(e) => {
                let reason = format!(
                    "{} went away: {e}; opening it again every second",
                    self.endpoint.describe()
                );
                self.link = None;
                self.failed = Some((Instant::now(), reason.clone()));
                received.problem = Some(reason);
            }
        }
        (Vec::new(), received)
    }
}

/// The lines of a file, for replay, and how many were dropped for being longer than a sentence can be.
///
/// # Errors
///
/// The file cannot be read; the message names it and the cause.
pub fn file_lines(path: &str, longest: usize) -> Result<(Vec<Vec<u8>>, u64), FileError> {
    let file = File::open(path).map_err(|source| FileError::Open {
        path: path.to_owned(),
        source,
    })?;
    let mut splitter = LineSplitter::new(longest);
    let mut lines = Vec::new();
    let mut reader = BufReader::new(file);
    loop {
        let chunk = reader.fill_buf().map_err(|source| FileError::Read {
            path: path.to_owned(),
            source,
        })?;
        if chunk.is_empty() {
            break;
        }
        let length = chunk.len();
        splitter.feed(chunk, |line| lines.push(line.to_vec()));
        reader.consume(length);
    }
    lines.extend(splitter.finish());
    Ok((lines, splitter.dropped_overlong))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_split_across_reads_join_and_overlong_ones_are_dropped_whole() {
        let mut splitter = LineSplitter::new(256);
        let mut lines = Vec::new();
        splitter.feed(b"$GPGGA,1\r\n$GPR", |l| lines.push(l.to_vec()));
        splitter.feed(b"MC,2\r\n", |l| lines.push(l.to_vec()));
        splitter.feed(&[b'x'; 600], |l| lines.push(l.to_vec()));
        splitter.feed(b"\n$GPVTG,3\n", |l| lines.push(l.to_vec()));
        assert_eq!(
            lines,
            vec![b"$GPGGA,1".to_vec(), b"$GPRMC,2".to_vec(), b"$GPVTG,3".to_vec()]
        );
        assert_eq!(splitter.dropped_overlong, 1);
    }
}
