//! The host side of the controller link: frames over a serial port, a pty or TCP.
//!
//! [`Link::open`] takes `/dev/ttyUSB0` (or any serial device or pty path) or `tcp:HOST:PORT`;
//! every command goes through the same code path. Requests carry a sequence number and wait
//! for the response with that number; stream frames that arrive meanwhile are queued for
//! [`Link::next_stream`]. Garbage on the line is skipped (and counted); a link that closes is
//! reported as such.

use kincal_protocol::framing::{self, Decoder, MAX_FRAME};
use kincal_protocol::messages::{
    DeviceFrame, HostFrame, Info, Request, Response, Stream, WireError, PARAM_CHUNK, PROTOCOL_VERSION,
    SCHEMA_HASH,
};
use kincal_protocol::params::BLOB_CRC;
use std::collections::VecDeque;
use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

/// How long a request waits for its response by default.
pub const DEFAULT_TIMEOUT: Duration = Duration::from_secs(2);

/// Why talking to the controller failed.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    /// The port could not be opened.
    #[error("cannot open {port}: {message}")]
    Open {
        /// What was asked for.
        port: String,
        /// Why.
        message: String,
    },
    /// Reading or writing failed.
    #[error("link I/O: {0}")]
    Io(#[from] std::io::Error),
    /// The other side closed the link (port unplugged, emulator stopped).
    #[error("the controller closed the link")]
    Closed,
    /// No answer in time.
    #[error("no answer from the controller within {0:?} to {1}")]
    Timeout(Duration, &'static str),
    /// Host and firmware speak different protocol versions or schemas.
    #[error("protocol mismatch: host speaks version {host_version} (schema {host_schema:08x}), controller version {device_version} (schema {device_schema:08x}); update the firmware or the host so both match")]
    VersionMismatch {
        /// Host protocol version.
        host_version: u16,
        /// Host schema hash.
        host_schema: u32,
        /// Controller protocol version.
        device_version: u16,
        /// Controller schema hash.
        device_schema: u32,
    },
    /// The controller refused the request.
    #[error("the controller refused {0}: {1:?}")]
    Refused(&'static str, WireError),
    /// The controller answered something unexpected.
    #[error("unexpected answer to {0}")]
    Unexpected(&'static str),
    /// Read-back after an upload differs from what was sent.
    #[error("parameter read-back differs at byte {0}; nothing was committed")]
    ReadBack(usize),
}

/// A byte link with a read timeout.
pub trait Transport: Read + Write + Send {
    /// Set how long a read may block.
    fn set_read_timeout(&mut self, timeout: Duration) -> std::io::Result<()>;
}

impl Transport for TcpStream {
    fn set_read_timeout(&mut self, timeout: Duration) -> std::io::Result<()> {
        TcpStream::set_read_timeout(self, Some(timeout))
    }
}

struct Serial(Box<dyn serialport::SerialPort>);

impl Read for Serial {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        self.0.read(buf)
    }
}

impl Write for Serial {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.write(buf)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.0.flush()
    }
}

impl Transport for Serial {
    fn set_read_timeout(&mut self, timeout: Duration) -> std::io::Result<()> {
        self.0.set_timeout(timeout).map_err(std::io::Error::other)
    }
}

/// Counters of what arrived on the link.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LinkStats {
    /// Frames decoded.
    pub frames: u64,
    /// Frames dropped as corrupt (bad COBS, CRC or content).
    pub bad_frames: u64,
    /// Stream frames missing, judged by their sequence numbers.
    pub stream_gaps: u64,
}

/// A connection to a controller.
pub struct Link {
    transport: Box<dyn Transport>,
    decoder: Decoder,
    seq: u16,
    streams: VecDeque<(u16, Stream)>,
    last_stream_seq: Option<u16>,
    /// What arrived so far.
    pub stats: LinkStats,
}

impl Link {
    /// Open `tcp:HOST:PORT` or a serial device / pty path (460800 baud, 8N1).
    pub fn open(port: &str) -> Result<Link, LinkError> {
        let open_error = |message: String| LinkError::Open { port: port.to_string(), message };
        let transport: Box<dyn Transport> = match port.strip_prefix("tcp:") {
            Some(addr) => {
                let stream = TcpStream::connect(addr).map_err(|e| open_error(e.to_string()))?;
                stream.set_nodelay(true).map_err(|e| open_error(e.to_string()))?;
                Box::new(stream)
            }
            None => Box::new(Serial(
                serialport::new(port, 460_800)
                    .timeout(DEFAULT_TIMEOUT)
                    .open()
                    .map_err(|e| open_error(e.to_string()))?,
            )),
        };
        Ok(Link::over(transport))
    }

    /// A link over an already open transport.
    pub fn over(transport: Box<dyn Transport>) -> Link {
        Link {
            transport,
            decoder: Decoder::new(),
            seq: 0,
            streams: VecDeque::new(),
            last_stream_seq: None,
            stats: LinkStats::default(),
        }
    }

    fn send(&mut self, request: Request) -> Result<u16, LinkError> {
        self.seq = self.seq.wrapping_add(1);
        if self.seq == u16::MAX {
            self.seq = 0; // u16::MAX is the controller's "undecodable request" answer
        }
        let mut buf = [0u8; MAX_FRAME];
        let frame = framing::encode(&HostFrame { seq: self.seq, request }, &mut buf)
            .map_err(|_| LinkError::Unexpected("encoding"))?;
        self.transport.write_all(frame)?;
        self.transport.flush()?;
        Ok(self.seq)
    }

    /// Read until one frame decodes or `deadline` passes.
    fn receive(&mut self, deadline: Instant) -> Result<Option<DeviceFrame>, LinkError> {
        let mut byte = [0u8; 512];
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Ok(None);
            }
            self.transport.set_read_timeout(left.max(Duration::from_millis(1)))?;
            let n = match self.transport.read(&mut byte) {
                Ok(0) => return Err(LinkError::Closed),
                Ok(n) => n,
                Err(e)
                    if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) =>
                {
                    continue
                }
                Err(e)
                    if e.kind() == std::io::ErrorKind::BrokenPipe
                        || e.kind() == std::io::ErrorKind::ConnectionReset =>
                {
                    return Err(LinkError::Closed)
                }
                Err(e) => return Err(e.into()),
            };
            // Stream frames are queued; the first response is returned.
            let mut frame = None;
            for &b in &byte[..n] {
                match self.decoder.push::<DeviceFrame>(b) {
                    Some(Ok(f)) => {
                        self.stats.frames += 1;
                        self.note(f, &mut frame);
                    }
                    Some(Err(_)) => self.stats.bad_frames += 1,
                    None => {}
                }
            }
            if frame.is_some() {
                return Ok(frame);
            }
        }
    }

    /// Queue stream frames; keep the first response in `response`.
    fn note(&mut self, f: DeviceFrame, response: &mut Option<DeviceFrame>) {
        match f {
            DeviceFrame::Stream { seq, item } => {
                if let Some(last) = self.last_stream_seq {
                    self.stats.stream_gaps += seq.wrapping_sub(last).wrapping_sub(1) as u64;
                }
                self.last_stream_seq = Some(seq);
                self.streams.push_back((seq, item));
            }
            r @ DeviceFrame::Response { .. } => {
                if response.is_none() {
                    *response = Some(r);
                }
            }
        }
    }

    /// Send `request` and wait for its response.
    pub fn request(
        &mut self,
        request: Request,
        what: &'static str,
        timeout: Duration,
    ) -> Result<Response, LinkError> {
        let seq = self.send(request)?;
        let deadline = Instant::now() + timeout;
        loop {
            match self.receive(deadline)? {
                None => return Err(LinkError::Timeout(timeout, what)),
                Some(DeviceFrame::Response { seq: s, response }) if s == seq => {
                    return response.map_err(|e| LinkError::Refused(what, e))
                }
                Some(_) => {} // a stale response to an earlier, timed-out request
            }
        }
    }

    /// Send a request that may safely be repeated, trying up to three times on a timeout.
    pub fn request_idempotent(
        &mut self,
        request: Request,
        what: &'static str,
    ) -> Result<Response, LinkError> {
        let mut attempt = 0;
        loop {
            attempt += 1;
            match self.request(request.clone(), what, DEFAULT_TIMEOUT) {
                Err(LinkError::Timeout(..)) if attempt < 3 => continue,
                other => return other,
            }
        }
    }

    /// Version and schema handshake; must come first.
    pub fn hello(&mut self) -> Result<(), LinkError> {
        self.hello_as(PROTOCOL_VERSION, SCHEMA_HASH)
    }

    /// Handshake announcing `version` and `schema` (tests use it to provoke a mismatch).
    pub fn hello_as(&mut self, version: u16, schema: u32) -> Result<(), LinkError> {
        match self.request_idempotent(Request::Hello { version, schema }, "hello") {
            Ok(Response::Hello { .. }) => Ok(()),
            Err(LinkError::Refused(
                _,
                WireError::VersionMismatch { version: device_version, schema: device_schema },
            )) => Err(LinkError::VersionMismatch {
                host_version: version,
                host_schema: schema,
                device_version,
                device_schema,
            }),
            Err(e) => Err(e),
            Ok(_) => Err(LinkError::Unexpected("hello")),
        }
    }

    /// Controller identity and health.
    pub fn info(&mut self) -> Result<Info, LinkError> {
        match self.request_idempotent(Request::GetInfo, "info")? {
            Response::Info(info) => Ok(info),
            _ => Err(LinkError::Unexpected("info")),
        }
    }

    /// Send a request that is answered with a plain acknowledgement.
    pub fn command(&mut self, request: Request, what: &'static str) -> Result<(), LinkError> {
        match self.request(request, what, DEFAULT_TIMEOUT)? {
            Response::Ack => Ok(()),
            _ => Err(LinkError::Unexpected(what)),
        }
    }

    /// Forget stream frames received so far. The controller answers requests in order, so after
    /// a request's response every queued frame predates that request.
    pub fn clear_streams(&mut self) {
        self.streams.clear();
    }

    /// The next streamed frame, waiting up to `timeout`.
    pub fn next_stream(&mut self, timeout: Duration) -> Result<Option<(u16, Stream)>, LinkError> {
        let deadline = Instant::now() + timeout;
        while self.streams.is_empty() {
            if self.receive(deadline)?.is_none() {
                break;
            }
        }
        Ok(self.streams.pop_front())
    }

    /// Upload a parameter blob: begin, chunks, read back and compare, commit.
    /// On any failure nothing is committed and the controller keeps its parameters.
    pub fn upload(&mut self, blob: &[u8]) -> Result<(), LinkError> {
        self.command(
            Request::ParamBegin { len: blob.len() as u16, crc: BLOB_CRC.checksum(blob) },
            "parameter upload",
        )?;
        for (k, chunk) in blob.chunks(PARAM_CHUNK).enumerate() {
            let data = heapless::Vec::from_slice(chunk).map_err(|_| LinkError::Unexpected("chunk"))?;
            self.command(Request::ParamChunk { offset: (k * PARAM_CHUNK) as u16, data }, "parameter chunk")?;
        }
        let back = self.read_params(true, blob.len())?;
        if let Some(i) = back
            .iter()
            .zip(blob)
            .position(|(a, b)| a != b)
            .or((back.len() != blob.len()).then_some(back.len()))
        {
            return Err(LinkError::ReadBack(i));
        }
        self.command(Request::ParamCommit, "parameter commit")
    }

    /// Read the pending upload (`pending`) or the stored blob, up to `limit` bytes.
    pub fn read_params(&mut self, pending: bool, limit: usize) -> Result<Vec<u8>, LinkError> {
        let mut out = Vec::new();
        while out.len() < limit {
            match self.request_idempotent(
                Request::ParamRead { offset: out.len() as u16, pending },
                "parameter read",
            )? {
                Response::ParamData { data, .. } if data.is_empty() => break,
                Response::ParamData { data, .. } => out.extend_from_slice(&data),
                _ => return Err(LinkError::Unexpected("parameter read")),
            }
        }
        Ok(out)
    }
}
