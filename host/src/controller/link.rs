//! The host side of the controller link: frames over a serial port, a pty or TCP.
//!
//! [`Link::open`] takes `/dev/ttyUSB0` (or any serial device or pty path) or `tcp:HOST:PORT`;
//! every command goes through the same code path. Requests carry a sequence number and wait
//! for the response with that number; stream frames that arrive meanwhile are queued for
//! [`Link::next_stream`]. Every request frame starts with a 0x00 delimiter, so line noise before
//! it ends as a bad frame of its own instead of swallowing the request. A request whose answer
//! does not come is repeated with the same sequence number ([`Link::call_retrying`]); the
//! controller answers a repeat without carrying the request out twice, so any request may be
//! repeated, not only idempotent ones. Garbage on the line is
//! skipped (and counted); a link that closes is reported as such. When the answer to a parameter
//! commit is lost, the host asks the controller what it holds before saying anything.

use kincal_protocol::framing::{self, Decoder, MAX_FRAME};
use kincal_protocol::messages::{
    Ack, Answer, DeviceFrame, Endpoint, GetInfo, Hello, HelloReply, HostFrame, Info, ParamBegin, ParamChunk,
    ParamCommit, ParamData, ParamRead, Request, Response, Stream, Topic, WireError, PARAM_CHUNK,
    PROTOCOL_VERSION, SCHEMA_HASH,
};
use kincal_protocol::params::BLOB_CRC;
use std::collections::VecDeque;
use std::fmt;
use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

/// How long a request waits for its response by default.
pub const DEFAULT_TIMEOUT: Duration = Duration::from_secs(2);
/// How long a parameter commit may take (flash programming on the controller).
pub const COMMIT_TIMEOUT: Duration = Duration::from_secs(3);

/// The parameter set a controller reports holding.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HeldParams {
    /// Version (0: none stored).
    pub version: u32,
    /// CRC-32 of the stored blob.
    pub crc: u32,
}

impl fmt::Display for HeldParams {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.version == 0 {
            f.write_str("no parameters")
        } else {
            write!(f, "parameters version {} (CRC-32 {:08x})", self.version, self.crc)
        }
    }
}

/// What the controller holds after a failed commit, as read back from it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AfterFailure {
    /// It answered: it holds this set (the previous one; the new one would have been success).
    Holds(HeldParams),
    /// It could not be asked.
    Unknown,
}

impl fmt::Display for AfterFailure {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            AfterFailure::Holds(held) => write!(f, "asked afterwards, the controller holds {held}"),
            AfterFailure::Unknown => f.write_str(
                "the controller could not be asked what it holds now: check with `kincal info` before using it",
            ),
        }
    }
}

/// How an upload ended when it succeeded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Uploaded {
    /// The first commit request went unanswered (it or its answer was lost); a repeat of it
    /// (answered without committing twice) or asking what the controller holds confirmed the
    /// new set.
    pub commit_reply_lost: bool,
}

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
    #[error("the controller refused {0}: {1}")]
    Refused(&'static str, WireError),
    /// The commit was sent but not confirmed; the controller's state was read back.
    #[error("the parameter commit was not confirmed ({cause}); {after}")]
    CommitUnconfirmed {
        /// Why the commit's answer did not arrive.
        cause: Box<LinkError>,
        /// What the controller holds, asked afterwards.
        after: AfterFailure,
    },
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

/// A response as queued: its sequence number, the answer, and how many stream frames had been
/// queued before it arrived.
struct Queued {
    seq: u16,
    response: Result<Response, WireError>,
    streams_before: u64,
}

/// A connection to a controller.
pub struct Link {
    transport: Box<dyn Transport>,
    decoder: Decoder,
    seq: u16,
    /// Stream frames with their arrival number.
    streams: VecDeque<(u64, u16, Stream)>,
    /// Stream frames queued so far (arrival numbers count up from 0).
    streams_arrived: u64,
    answers: VecDeque<Queued>,
    /// Stream frames that had arrived when the last returned response arrived.
    before_last_response: u64,
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
                serialport::new(port, kincal_protocol::messages::LINK_BAUD)
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
            streams_arrived: 0,
            answers: VecDeque::new(),
            before_last_response: 0,
            last_stream_seq: None,
            stats: LinkStats::default(),
        }
    }

    /// The next request's sequence number.
    fn next_seq(&mut self) -> u16 {
        self.seq = self.seq.wrapping_add(1);
        if self.seq == u16::MAX {
            self.seq = 0; // u16::MAX is the controller's "undecodable request" answer
        }
        self.seq
    }

    /// Send `request` as frame `seq`.
    fn send(&mut self, seq: u16, request: Request) -> Result<(), LinkError> {
        let mut buf = [0u8; MAX_FRAME + 1];
        let (delimiter, rest) = buf.split_at_mut(1);
        delimiter[0] = 0;
        let Ok(rest) = <&mut [u8; MAX_FRAME]>::try_from(rest) else {
            return Err(LinkError::Unexpected("encoding"));
        };
        let n = framing::encode(&HostFrame { seq, request }, rest)
            .map_err(|_| LinkError::Unexpected("encoding"))?
            .len();
        // The leading delimiter ends any noise the controller received before this frame.
        self.transport.write_all(&buf[..1 + n])?;
        self.transport.flush()?;
        Ok(())
    }

    /// Read once (waiting until `deadline` at most) and queue every frame that decoded.
    /// Returns false when the deadline passed with nothing read.
    fn pump(&mut self, deadline: Instant) -> Result<bool, LinkError> {
        let mut bytes = [0u8; 512];
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return Ok(false);
        }
        self.transport.set_read_timeout(left.max(Duration::from_millis(1)))?;
        let n = match self.transport.read(&mut bytes) {
            Ok(0) => return Err(LinkError::Closed),
            Ok(n) => n,
            // A read interrupted by a signal (Ctrl-C ending a stream) read nothing: the caller
            // checks its flag and reads again.
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock
                        | std::io::ErrorKind::TimedOut
                        | std::io::ErrorKind::Interrupted
                ) =>
            {
                return Ok(true)
            }
            Err(e)
                if e.kind() == std::io::ErrorKind::BrokenPipe
                    || e.kind() == std::io::ErrorKind::ConnectionReset =>
            {
                return Err(LinkError::Closed)
            }
            Err(e) => return Err(e.into()),
        };
        for &b in &bytes[..n] {
            match self.decoder.push::<DeviceFrame>(b) {
                Some(Ok(f)) => {
                    self.stats.frames += 1;
                    self.note(f);
                }
                Some(Err(_)) => self.stats.bad_frames += 1,
                None => {}
            }
        }
        Ok(true)
    }

    /// Queue a decoded frame, in arrival order.
    fn note(&mut self, f: DeviceFrame) {
        match f {
            DeviceFrame::Stream { seq, item } => {
                if let Some(last) = self.last_stream_seq {
                    self.stats.stream_gaps += seq.wrapping_sub(last).wrapping_sub(1) as u64;
                }
                self.last_stream_seq = Some(seq);
                self.streams.push_back((self.streams_arrived, seq, item));
                self.streams_arrived += 1;
            }
            DeviceFrame::Response { seq, response } => {
                self.answers.push_back(Queued { seq, response, streams_before: self.streams_arrived })
            }
        }
    }

    /// Send `request` up to `attempts` times, each waiting `timeout` for its answer. Repeats
    /// carry the same sequence number: a controller that carried the request out and whose
    /// answer was lost answers again without doing it twice, so any request may be repeated.
    /// Returns the answer and the attempts it took.
    fn request(
        &mut self,
        request: Request,
        what: &'static str,
        timeout: Duration,
        attempts: u32,
    ) -> Result<(Response, u32), LinkError> {
        let seq = self.next_seq();
        for attempt in 1..=attempts.max(1) {
            self.send(seq, request.clone())?;
            let deadline = Instant::now() + timeout;
            loop {
                // Answers to other sequence numbers are stale (their requests timed out): dropped.
                if let Some(answer) = self.answers.iter().position(|a| a.seq == seq) {
                    let answer =
                        self.answers.drain(..=answer).next_back().ok_or(LinkError::Unexpected(what))?;
                    self.before_last_response = answer.streams_before;
                    return match answer.response {
                        Ok(response) => Ok((response, attempt)),
                        Err(e) => Err(LinkError::Refused(what, e)),
                    };
                }
                self.answers.clear();
                if !self.pump(deadline)? {
                    break;
                }
            }
        }
        Err(LinkError::Timeout(timeout, what))
    }

    /// Send `request` (up to `attempts` times) and wait up to `timeout` each time for its
    /// endpoint's answer; returns it with the attempts it took.
    fn call_attempts<E: Endpoint>(
        &mut self,
        request: E,
        timeout: Duration,
        attempts: u32,
    ) -> Result<(E::Response, u32), LinkError> {
        let (response, attempt) = self.request(request.into(), E::NAME, timeout, attempts)?;
        let answer = E::Response::from_response(response).ok_or(LinkError::Unexpected(E::NAME))?;
        Ok((answer, attempt))
    }

    /// Send `request` once and wait up to `timeout` for its endpoint's answer.
    pub fn call_within<E: Endpoint>(
        &mut self,
        request: E,
        timeout: Duration,
    ) -> Result<E::Response, LinkError> {
        Ok(self.call_attempts(request, timeout, 1)?.0)
    }

    /// Send `request` once and wait for its endpoint's answer ([`DEFAULT_TIMEOUT`]).
    pub fn call<E: Endpoint>(&mut self, request: E) -> Result<E::Response, LinkError> {
        self.call_within(request, DEFAULT_TIMEOUT)
    }

    /// [`Link::call`], repeated (same sequence number) up to three times when no answer comes.
    pub fn call_retrying<E: Endpoint>(&mut self, request: E) -> Result<E::Response, LinkError> {
        Ok(self.call_attempts(request, DEFAULT_TIMEOUT, 3)?.0)
    }

    /// Version and schema handshake; must come first.
    pub fn hello(&mut self) -> Result<(), LinkError> {
        self.hello_as(PROTOCOL_VERSION, SCHEMA_HASH)
    }

    /// Handshake announcing `version` and `schema` (tests use it to provoke a mismatch).
    pub fn hello_as(&mut self, version: u16, schema: u32) -> Result<(), LinkError> {
        match self.call_retrying(Hello { version, schema }) {
            Ok(HelloReply { .. }) => Ok(()),
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
        }
    }

    /// Controller identity and health.
    pub fn info(&mut self) -> Result<Info, LinkError> {
        self.call_retrying(GetInfo)
    }

    /// Forget the stream frames that arrived before the response to the last request. The
    /// controller sends frames in order, so those predate the request; frames that arrived with
    /// or after its response (a short window's report can come in the same read) are kept.
    pub fn clear_streams(&mut self) {
        let mark = self.before_last_response;
        self.streams.retain(|(arrival, _, _)| *arrival >= mark);
    }

    /// The next item of topic `T`, waiting up to `timeout`; frames of other topics that arrive
    /// first are dropped.
    pub fn next_on<T: Topic>(&mut self, timeout: Duration) -> Result<Option<(u16, T)>, LinkError> {
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.next_stream(left)? {
                None => return Ok(None),
                Some((seq, item)) => {
                    if let Some(item) = T::from_stream(item) {
                        return Ok(Some((seq, item)));
                    }
                }
            }
        }
    }

    /// The next streamed frame, waiting up to `timeout`.
    pub fn next_stream(&mut self, timeout: Duration) -> Result<Option<(u16, Stream)>, LinkError> {
        let deadline = Instant::now() + timeout;
        while self.streams.is_empty() {
            if !self.pump(deadline)? {
                break;
            }
        }
        Ok(self.streams.pop_front().map(|(_, seq, item)| (seq, item)))
    }

    /// The parameter set the controller reports holding.
    pub fn held_params(&mut self) -> Result<HeldParams, LinkError> {
        let info = self.info()?;
        Ok(HeldParams { version: info.param_version, crc: info.param_crc })
    }

    /// Upload a parameter blob as it is (no envelope check here: see
    /// [`crate::controller::device::parameter_blob`]): begin, chunks, read back and compare, commit.
    /// Before the commit, any failure leaves the controller's parameters as they were. When the
    /// commit's answer does not arrive, the controller is asked what it holds: the new set
    /// (success, [`Uploaded::commit_reply_lost`]) or not ([`LinkError::CommitUnconfirmed`]).
    pub fn upload(&mut self, blob: &[u8]) -> Result<Uploaded, LinkError> {
        self.call_retrying(ParamBegin { len: blob.len() as u16, crc: BLOB_CRC.checksum(blob) })?;
        for (k, chunk) in blob.chunks(PARAM_CHUNK).enumerate() {
            let data = heapless::Vec::from_slice(chunk).map_err(|_| LinkError::Unexpected("chunk"))?;
            self.call_retrying(ParamChunk { offset: (k * PARAM_CHUNK) as u16, data })?;
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
        let cause = match self.call_attempts(ParamCommit, COMMIT_TIMEOUT, 2) {
            Ok((Ack, attempts)) => return Ok(Uploaded { commit_reply_lost: attempts > 1 }),
            Err(e @ LinkError::Refused(..)) => return Err(e),
            Err(e) => e,
        };
        // The commit may or may not have happened: ask before saying anything.
        let crc = BLOB_CRC.checksum(blob);
        match self.held_params() {
            Ok(held) if held.crc == crc && held.version != 0 => Ok(Uploaded { commit_reply_lost: true }),
            Ok(held) => {
                Err(LinkError::CommitUnconfirmed { cause: Box::new(cause), after: AfterFailure::Holds(held) })
            }
            Err(_) => {
                Err(LinkError::CommitUnconfirmed { cause: Box::new(cause), after: AfterFailure::Unknown })
            }
        }
    }

    /// Read the pending upload (`pending`) or the stored blob, up to `limit` bytes.
    pub fn read_params(&mut self, pending: bool, limit: usize) -> Result<Vec<u8>, LinkError> {
        let mut out = Vec::new();
        while out.len() < limit {
            let ParamData { data, .. } =
                self.call_retrying(ParamRead { offset: out.len() as u16, pending })?;
            if data.is_empty() {
                break;
            }
            out.extend_from_slice(&data);
        }
        Ok(out)
    }
}
