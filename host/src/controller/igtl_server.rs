//! An OpenIGTLink server for the calibrated pose: what 3D Slicer (OpenIGTLinkIF, SlicerIGT),
//! PLUS and other navigation software connect to.
//!
//! Every pose the controller streams goes to every client as a TRANSFORM named in PLUS's
//! convention (`ToolToArmBase` by default: the tool frame in the arm's base frame, mm), stamped
//! with the instant the controller sampled it ([`crate::controller::pose_stream`]), not when the
//! host received it. A client that sends `STT_TDATA` (the protocol's way to ask for a rate)
//! gets TDATA messages no closer than the interval it asked for instead, until `STP_TDATA`;
//! `GET_TRANS` returns the latest valid pose, `GET_STATUS` a STATUS.
//!
//! Header versions as PLUS negotiates them: a client gets header version 1 (what the OpenIGTLink
//! library 1.x and every older client reads) until it sends a message with header version 2;
//! from then on its messages have version 2 and carry `TransformStatus` metadata (`OK`).
//!
//! An invalid pose (a joint's encoder frame not accepted that tick) is never sent as a valid
//! transform. As PLUS with its default `SendValidTransformsOnly="true"`, no TRANSFORM (or TDATA)
//! goes out for it: Slicer keeps showing the last valid pose and SlicerIGT's Watchdog, which
//! judges a transform by the time since its last update, flags it. A STATUS message named like
//! the transform says why when the pose turns invalid and every second while it stays so (code
//! 18, hardware failure; sub-code: bit j set when joint j + 1 was not read; message: which joints
//! and since when), and a STATUS OK when it is valid again. With
//! [`ServerOptions::send_invalid`] (PLUS's `SendValidTransformsOnly="false"`) header-version-2
//! clients also get a TRANSFORM for every invalid tick, its matrix NaN and its metadata
//! `TransformStatus` = `INVALID`; header-version-1 clients never do, as they could not tell.
//!
//! Each client has its own queue and writer thread: a client that reads slowly or not at all
//! loses its oldest frames (counted and logged; once the socket buffers, kept small by
//! [`SEND_BUFFER_BYTES`], and [`QUEUE_FRAMES`] are full) and never delays
//! [`PoseServer::publish`], the controller link or the other clients. A client that leaves is logged; the stream goes on.

use crate::controller::pose_stream::TimedPose;
use crate::igtl::{self, HeaderVersion, Incoming};
use std::collections::VecDeque;
use std::fmt;
use std::io::Write;
use std::net::{Shutdown, SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{channel, Receiver, Sender};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::Duration;

/// Frames queued per client before its oldest are dropped (0.5 s at 768 Hz); the kernel's
/// socket buffers hold more before the queue starts to fill.
pub const QUEUE_FRAMES: usize = 384;
/// Kernel send buffer of a client's socket, bytes (Linux doubles it): with the client's receive
/// buffer, what a client that stops reading holds before its queue starts dropping (about 2 s at
/// 768 Hz); a reading client on any network is not slowed by it.
pub const SEND_BUFFER_BYTES: usize = 32 * 1024;
/// While the pose stays invalid, its STATUS message is repeated this often, s.
pub const INVALID_STATUS_EVERY_S: f64 = 1.0;
/// The transform name used unless another is given (PLUS's `FromToTo` convention).
pub const DEFAULT_NAME: &str = "ToolToArmBase";

/// How the server names and sends the pose.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ServerOptions {
    /// Transform name, PLUS's convention `FromToTo` (e.g. `ToolToArmBase`).
    pub name: String,
    /// Also send invalid poses to header-version-2 clients, marked `TransformStatus` =
    /// `INVALID` with a NaN matrix.
    pub send_invalid: bool,
}

impl Default for ServerOptions {
    fn default() -> Self {
        ServerOptions { name: DEFAULT_NAME.into(), send_invalid: false }
    }
}

/// Why the server could not start.
#[derive(Debug, thiserror::Error)]
pub enum ServerError {
    /// The name cannot be a transform name.
    #[error("transform name `{0}`: expected PLUS's FromToTo form (e.g. ToolToArmBase): 1 to 20 ASCII letters and digits with `To` between two names")]
    Name(String),
    /// The address could not be bound.
    #[error("cannot listen on {addr}: {source}")]
    Bind {
        /// The address.
        addr: String,
        /// Why.
        source: std::io::Error,
    },
}

/// Whether `name` is a transform name in PLUS's convention: `From` `To` `To`, ASCII letters and
/// digits, each part starting with a capital, at most 20 bytes (a device name's room).
pub fn plus_name(name: &str) -> bool {
    igtl::valid_name(name)
        && name.bytes().all(|b| b.is_ascii_alphanumeric())
        && name.match_indices("To").any(|(at, _)| {
            let (from, to) = (&name[..at], &name[at + 2..]);
            from.starts_with(|c: char| c.is_ascii_uppercase())
                && to.starts_with(|c: char| c.is_ascii_uppercase())
        })
}

/// Something that happened to a client.
#[derive(Clone, Debug, PartialEq)]
pub enum ServerEvent {
    /// A client connected.
    Joined {
        /// Its address.
        peer: SocketAddr,
    },
    /// A client went away; the stream goes on for the others.
    Left {
        /// Its address.
        peer: SocketAddr,
        /// Why (closed, reset, …).
        why: String,
        /// Messages it was sent.
        sent: u64,
        /// Messages dropped because it did not read them in time.
        dropped: u64,
    },
    /// A client does not keep up: its oldest frames are being dropped.
    Slow {
        /// Its address.
        peer: SocketAddr,
    },
    /// A client's request or message, as the server took it.
    Note {
        /// Its address.
        peer: SocketAddr,
        /// What.
        text: String,
    },
}

impl fmt::Display for ServerEvent {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ServerEvent::Joined { peer } => write!(f, "OpenIGTLink client {peer} connected"),
            ServerEvent::Left { peer, why, sent, dropped } => write!(
                f,
                "OpenIGTLink client {peer} left ({why}) after {sent} messages, {dropped} dropped as it did not read them in time; the stream goes on"
            ),
            ServerEvent::Slow { peer } => {
                write!(f, "OpenIGTLink client {peer} does not keep up: its oldest frames are dropped")
            }
            ServerEvent::Note { peer, text } => write!(f, "OpenIGTLink client {peer}: {text}"),
        }
    }
}

/// What one client receives.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Feed {
    /// A TRANSFORM every tick.
    Transform,
    /// TDATA no closer than this many ms (`STT_TDATA`).
    Tdata(u32),
}

/// A client's queue and state, under its lock.
struct ClientState {
    queue: VecDeque<Arc<Vec<u8>>>,
    version: HeaderVersion,
    feed: Feed,
    last_tdata_s: f64,
    /// Validity of the last pose reported by STATUS, and when.
    last_status: Option<(bool, f64)>,
    /// Dropping frames now (a [`ServerEvent::Slow`] was sent for this episode).
    slow: bool,
}

struct Client {
    peer: SocketAddr,
    socket: TcpStream,
    state: Mutex<ClientState>,
    ready: Condvar,
    gone: AtomicBool,
    sent: AtomicU64,
    dropped: AtomicU64,
}

impl Client {
    fn lock(&self) -> MutexGuard<'_, ClientState> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Queue `message`, dropping the oldest when full.
    fn push(&self, state: &mut ClientState, message: Arc<Vec<u8>>, events: &Sender<ServerEvent>) {
        if state.queue.len() >= QUEUE_FRAMES {
            state.queue.pop_front();
            self.dropped.fetch_add(1, Ordering::Relaxed);
            if !state.slow {
                state.slow = true;
                let _ = events.send(ServerEvent::Slow { peer: self.peer });
            }
        } else if state.queue.is_empty() {
            state.slow = false;
        }
        state.queue.push_back(message);
        self.ready.notify_one();
    }
}

struct Shared {
    options: ServerOptions,
    clients: Mutex<Vec<Arc<Client>>>,
    /// The latest valid pose's TRANSFORM content and stamp, for `GET_TRANS`.
    latest: Mutex<Option<([u8; igtl::TRANSFORM_BYTES], u64)>>,
    stop: AtomicBool,
    events: Sender<ServerEvent>,
}

/// Per-client statistics.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ClientStats {
    /// Address.
    pub peer: SocketAddr,
    /// Messages sent.
    pub sent: u64,
    /// Messages dropped (the client did not read them in time).
    pub dropped: u64,
}

/// The running server; stops (and disconnects its clients) when dropped.
pub struct PoseServer {
    addr: SocketAddr,
    shared: Arc<Shared>,
    events: Mutex<Receiver<ServerEvent>>,
    acceptor: Option<std::thread::JoinHandle<()>>,
}

impl PoseServer {
    /// Listen on `addr` (`127.0.0.1:18944`; port 0 picks a free one).
    pub fn start(addr: &str, options: ServerOptions) -> Result<PoseServer, ServerError> {
        if !plus_name(&options.name) {
            return Err(ServerError::Name(options.name));
        }
        let bind = |source| ServerError::Bind { addr: addr.to_string(), source };
        let listener = TcpListener::bind(addr).map_err(bind)?;
        let local = listener.local_addr().map_err(bind)?;
        listener.set_nonblocking(true).map_err(bind)?;
        let (events, receiver) = channel();
        let shared = Arc::new(Shared {
            options,
            clients: Mutex::new(Vec::new()),
            latest: Mutex::new(None),
            stop: AtomicBool::new(false),
            events,
        });
        let accepting = shared.clone();
        let acceptor = std::thread::spawn(move || accept(listener, accepting));
        Ok(PoseServer { addr: local, shared, events: Mutex::new(receiver), acceptor: Some(acceptor) })
    }

    /// The address it listens on.
    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    /// Events since the last call (clients joining, leaving, not keeping up).
    pub fn events(&self) -> Vec<ServerEvent> {
        let receiver = self.events.lock().unwrap_or_else(|e| e.into_inner());
        receiver.try_iter().collect()
    }

    /// The clients connected now.
    pub fn clients(&self) -> Vec<ClientStats> {
        let clients = self.shared.clients.lock().unwrap_or_else(|e| e.into_inner());
        clients
            .iter()
            .map(|c| ClientStats {
                peer: c.peer,
                sent: c.sent.load(Ordering::Relaxed),
                dropped: c.dropped.load(Ordering::Relaxed),
            })
            .collect()
    }

    /// Send `pose` to every client (queued; never waits for one).
    pub fn publish(&self, pose: &TimedPose) {
        let shared = &self.shared;
        let name = shared.options.name.as_str();
        let stamp = igtl::timestamp(pose.t_s);
        let rows = pose.rows();
        let valid = pose.report.valid;
        let content = igtl::transform_content(&rows);
        if valid {
            *shared.latest.lock().unwrap_or_else(|e| e.into_inner()) = Some((content, stamp));
        }
        let mut cache = Encoded::default();
        let clients: Vec<Arc<Client>> = {
            let mut clients = shared.clients.lock().unwrap_or_else(|e| e.into_inner());
            clients.retain(|c| !c.gone.load(Ordering::SeqCst));
            clients.clone()
        };
        for client in clients {
            let mut state = client.lock();
            let version = state.version;
            let status_due = match state.last_status {
                None => !valid,
                Some((was_valid, at)) => {
                    was_valid != valid || (!valid && pose.t_s - at >= INVALID_STATUS_EVERY_S)
                }
            };
            if status_due {
                let message = cache.status(version, name, stamp, pose);
                state.last_status = Some((valid, pose.t_s));
                client.push(&mut state, message, &shared.events);
            }
            let message = match (state.feed, valid) {
                (Feed::Transform, true) => Some(cache.transform(version, name, stamp, &content, "OK")),
                (Feed::Transform, false) if shared.options.send_invalid && version == HeaderVersion::V2 => {
                    Some(cache.transform(version, name, stamp, &content, "INVALID"))
                }
                (Feed::Tdata(resolution_ms), true)
                    if (pose.t_s - state.last_tdata_s) * 1000.0 >= resolution_ms as f64 =>
                {
                    state.last_tdata_s = pose.t_s;
                    Some(cache.tdata(version, name, stamp, &rows))
                }
                _ => None,
            };
            if let Some(message) = message {
                client.push(&mut state, message, &shared.events);
            }
        }
    }
}

impl Drop for PoseServer {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::SeqCst);
        if let Some(acceptor) = self.acceptor.take() {
            let _ = acceptor.join();
        }
        let clients = self.shared.clients.lock().unwrap_or_else(|e| e.into_inner());
        for c in clients.iter() {
            c.gone.store(true, Ordering::SeqCst);
            let _ = c.socket.shutdown(Shutdown::Both);
            c.ready.notify_all();
        }
    }
}

/// The messages of one pose, encoded once per header version and shared by the clients.
#[derive(Default)]
struct Encoded {
    transform: [Option<Arc<Vec<u8>>>; 2],
    status: [Option<Arc<Vec<u8>>>; 2],
    tdata: [Option<Arc<Vec<u8>>>; 2],
}

impl Encoded {
    fn transform(
        &mut self,
        v: HeaderVersion,
        name: &str,
        stamp: u64,
        content: &[u8],
        status: &str,
    ) -> Arc<Vec<u8>> {
        self.transform[v as usize - 1]
            .get_or_insert_with(|| {
                Arc::new(igtl::encode(
                    v,
                    "TRANSFORM",
                    name,
                    stamp,
                    content,
                    &[("TransformStatus", status)],
                    0,
                ))
            })
            .clone()
    }

    fn status(&mut self, v: HeaderVersion, name: &str, stamp: u64, pose: &TimedPose) -> Arc<Vec<u8>> {
        self.status[v as usize - 1]
            .get_or_insert_with(|| {
                let content = if pose.report.valid {
                    igtl::status_content(igtl::status::OK, 0, "OK", "pose valid")
                } else {
                    let stale = !pose.report.fresh & kincal_protocol::joints::ALL_JOINTS;
                    igtl::status_content(
                        igtl::status::HARDWARE_FAILURE,
                        stale as i64,
                        "POSE INVALID",
                        &invalid_text(pose),
                    )
                };
                Arc::new(igtl::encode(v, "STATUS", name, stamp, &content, &[], 0))
            })
            .clone()
    }

    fn tdata(&mut self, v: HeaderVersion, name: &str, stamp: u64, rows: &[[f32; 4]; 3]) -> Arc<Vec<u8>> {
        self.tdata[v as usize - 1]
            .get_or_insert_with(|| {
                let element = igtl::tdata_element(name, rows);
                Arc::new(igtl::encode(v, "TDATA", name, stamp, &element, &[("TransformStatus", "OK")], 0))
            })
            .clone()
    }
}

/// "joint 3 not read (last good 5 ticks ago); no pose".
fn invalid_text(pose: &TimedPose) -> String {
    let joints: Vec<String> = pose.report.stale_joints().map(|j| j.to_string()).collect();
    let age = match pose.report.stale_ticks {
        u16::MAX => "never read since the controller started".to_string(),
        t => format!("last good {t} ticks ago"),
    };
    format!(
        "joint{} {} not read at controller tick {} ({age}); no pose",
        if joints.len() == 1 { "" } else { "s" },
        joints.join(", "),
        pose.tick
    )
}

fn accept(listener: TcpListener, shared: Arc<Shared>) {
    while !shared.stop.load(Ordering::SeqCst) {
        let (socket, peer) = match listener.accept() {
            Ok(s) => s,
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                std::thread::sleep(Duration::from_millis(20));
                continue;
            }
            Err(_) => continue,
        };
        let clones = (socket.try_clone(), socket.try_clone());
        let (Ok(reader), Ok(writer)) = clones else { continue };
        let _ = socket.set_nonblocking(false);
        let _ = socket.set_nodelay(true);
        let _ = socket2::SockRef::from(&socket).set_send_buffer_size(SEND_BUFFER_BYTES);
        let client = Arc::new(Client {
            peer,
            socket,
            state: Mutex::new(ClientState {
                queue: VecDeque::with_capacity(QUEUE_FRAMES),
                version: HeaderVersion::V1,
                feed: Feed::Transform,
                last_tdata_s: f64::NEG_INFINITY,
                last_status: None,
                slow: false,
            }),
            ready: Condvar::new(),
            gone: AtomicBool::new(false),
            sent: AtomicU64::new(0),
            dropped: AtomicU64::new(0),
        });
        let _ = shared.events.send(ServerEvent::Joined { peer });
        shared.clients.lock().unwrap_or_else(|e| e.into_inner()).push(client.clone());
        let (c, s) = (client.clone(), shared.clone());
        std::thread::spawn(move || write_to(c, writer, s));
        let s = shared.clone();
        std::thread::spawn(move || read_from(client, reader, s));
    }
}

/// Mark `client` gone (once) and say why.
fn leave(client: &Client, shared: &Shared, why: String) {
    if !client.gone.swap(true, Ordering::SeqCst) {
        let _ = client.socket.shutdown(Shutdown::Both);
        client.ready.notify_all();
        let _ = shared.events.send(ServerEvent::Left {
            peer: client.peer,
            why,
            sent: client.sent.load(Ordering::Relaxed),
            dropped: client.dropped.load(Ordering::Relaxed),
        });
    }
}

/// The client's writer: sends what is queued, blocking only itself.
fn write_to(client: Arc<Client>, mut socket: TcpStream, shared: Arc<Shared>) {
    let mut batch: Vec<Arc<Vec<u8>>> = Vec::new();
    let mut bytes = Vec::new();
    loop {
        {
            let mut state = client.lock();
            while state.queue.is_empty() && !client.gone.load(Ordering::SeqCst) {
                state = client
                    .ready
                    .wait_timeout(state, Duration::from_millis(200))
                    .unwrap_or_else(|e| e.into_inner())
                    .0;
            }
            if client.gone.load(Ordering::SeqCst) {
                return;
            }
            batch.extend(state.queue.drain(..));
        }
        bytes.clear();
        for message in batch.drain(..) {
            bytes.extend_from_slice(&message);
        }
        match socket.write_all(&bytes) {
            Ok(()) => {
                client.sent.fetch_add(count_messages(&bytes), Ordering::Relaxed);
            }
            Err(e) => return leave(&client, &shared, e.to_string()),
        }
    }
}

/// How many messages a run of whole messages holds (each header gives its body size).
fn count_messages(bytes: &[u8]) -> u64 {
    let (mut at, mut n) = (0usize, 0u64);
    while at + igtl::HEADER_BYTES <= bytes.len() {
        let size = u64::from_be_bytes(bytes[at + 42..at + 50].try_into().unwrap_or([0; 8]));
        at += igtl::HEADER_BYTES + size as usize;
        n += 1;
    }
    n
}

/// The client's reader: queries, rate requests and the header version it speaks.
fn read_from(client: Arc<Client>, mut socket: TcpStream, shared: Arc<Shared>) {
    let note = |text: String| {
        let _ = shared.events.send(ServerEvent::Note { peer: client.peer, text });
    };
    let mut ignored: Vec<String> = Vec::new();
    loop {
        let message = match igtl::read_message(&mut socket) {
            Ok(m) => m,
            Err(igtl::IgtlError::Io(e)) => {
                let why = match e.kind() {
                    std::io::ErrorKind::UnexpectedEof => "closed the connection".to_string(),
                    _ => e.to_string(),
                };
                return leave(&client, &shared, why);
            }
            Err(e) => return leave(&client, &shared, format!("sent something that is not OpenIGTLink: {e}")),
        };
        if !message.crc_ok {
            note(format!("a {} message with a bad CRC was ignored", message.kind));
            continue;
        }
        let mut state = client.lock();
        if message.version >= 2 && state.version == HeaderVersion::V1 {
            state.version = HeaderVersion::V2;
            note("speaks header version 2: its messages carry TransformStatus metadata from now on".into());
        }
        let version = state.version;
        let reply = |kind: &str, content: &[u8]| {
            Arc::new(igtl::encode(version, kind, &message.device, 0, content, &[], 0))
        };
        match message.kind.as_str() {
            "GET_STATUS" => {
                let content = igtl::status_content(igtl::status::OK, 0, "OK", "kincal pose server");
                client.push(&mut state, reply("STATUS", &content), &shared.events);
            }
            "STT_TDATA" => {
                let ms = rate_request(&message);
                state.feed = Feed::Tdata(ms);
                state.last_tdata_s = f64::NEG_INFINITY;
                client.push(&mut state, reply("RTS_TDATA", &[0]), &shared.events);
                drop(state);
                note(format!("asked for tracking data every {ms} ms or more (TDATA instead of TRANSFORM)"));
            }
            "STP_TDATA" => {
                state.feed = Feed::Transform;
                client.push(&mut state, reply("RTS_TDATA", &[0]), &shared.events);
                drop(state);
                note("stopped tracking data: back to a TRANSFORM every tick".into());
            }
            "GET_TRANS" | "GET_TRANSFORM" => {
                let latest = *shared.latest.lock().unwrap_or_else(|e| e.into_inner());
                let name = shared.options.name.as_str();
                let answer = match latest {
                    Some((content, stamp)) if message.device.is_empty() || message.device == name => {
                        igtl::encode(
                            version,
                            "TRANSFORM",
                            name,
                            stamp,
                            &content,
                            &[("TransformStatus", "OK")],
                            0,
                        )
                    }
                    // No valid pose (yet): a TRANSFORM without body, as the query page says.
                    _ => igtl::encode(HeaderVersion::V1, "TRANSFORM", &message.device, 0, &[], &[], 0),
                };
                client.push(&mut state, Arc::new(answer), &shared.events);
            }
            kind => {
                if !ignored.iter().any(|k| k == kind) {
                    ignored.push(kind.to_string());
                    drop(state);
                    note(format!("sent {kind}, which this server does not take; ignored"));
                }
            }
        }
    }
}

/// The interval an `STT_TDATA` asks for, ms (0: every tick).
fn rate_request(message: &Incoming) -> u32 {
    message.content.get(..4).map_or(0, |b| u32::from_be_bytes([b[0], b[1], b[2], b[3]]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use kincal_protocol::messages::PoseReport;
    use std::io::Read;

    fn pose(tick: u64, valid: bool) -> TimedPose {
        let nan = [f32::NAN; 3];
        let report = PoseReport {
            tick: tick as u16,
            valid,
            fresh: if valid { 0x3F } else { 0x3B },
            stale_ticks: if valid { 0 } else { 3 },
            position_mm: if valid { [100.0 + tick as f32, 2.5, -3.25] } else { nan },
            z_axis: if valid { [0.0, 0.0, 1.0] } else { nan },
            x_axis: if valid { [1.0, 0.0, 0.0] } else { nan },
        };
        TimedPose { seq: tick as u16, tick, t_s: 1_790_000_000.0 + tick as f64 / 768.0, host_s: 0.0, report }
    }

    fn connect(server: &PoseServer) -> TcpStream {
        let s = TcpStream::connect(server.local_addr()).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
        s
    }

    /// Wait until the server has `n` clients.
    fn wait_clients(server: &PoseServer, n: usize) {
        for _ in 0..500 {
            if server.clients().len() == n {
                return;
            }
            std::thread::sleep(Duration::from_millis(2));
        }
        panic!("{} clients, expected {n}", server.clients().len());
    }

    fn read_n(s: &mut TcpStream, n: usize) -> Vec<Incoming> {
        (0..n).map(|_| igtl::read_message(s).unwrap()).collect()
    }

    /// Valid poses go out as TRANSFORM stamped with the sample instant; an invalid one as no
    /// transform but a STATUS naming the joint, then STATUS OK; a header-2 client gets
    /// TransformStatus metadata, and with `send_invalid` the invalid ticks marked INVALID.
    #[test]
    fn invalid_poses_are_never_sent_as_valid_transforms() {
        let server =
            PoseServer::start("127.0.0.1:0", ServerOptions { send_invalid: true, ..Default::default() })
                .unwrap();
        let mut v1 = connect(&server);
        let mut v2 = connect(&server);
        wait_clients(&server, 2);
        v2.write_all(&igtl::encode(HeaderVersion::V2, "GET_STATUS", "", 0, &[], &[], 0)).unwrap();
        let status = igtl::read_message(&mut v2).unwrap();
        assert_eq!((status.kind.as_str(), status.version), ("STATUS", 2));
        for (tick, valid) in [(1, true), (2, false), (3, false), (4, true)] {
            server.publish(&pose(tick, valid));
        }
        let got = read_n(&mut v1, 4);
        let kinds: Vec<&str> = got.iter().map(|m| m.kind.as_str()).collect();
        assert_eq!(kinds, ["TRANSFORM", "STATUS", "STATUS", "TRANSFORM"]);
        assert!(got.iter().all(|m| m.crc_ok && m.version == 1 && m.device == DEFAULT_NAME));
        let rows = igtl::transform_rows(&got[0].content).unwrap();
        assert_eq!(rows[0][3], 101.0);
        assert!((igtl::unix_seconds(got[0].timestamp) - pose(1, true).t_s).abs() < 1e-6);
        let (code, sub, _, text) = igtl::status_fields(&got[1].content).unwrap();
        assert_eq!((code, sub), (igtl::status::HARDWARE_FAILURE, 0b100));
        assert!(text.contains("joint 3 not read at controller tick 2"), "{text}");
        assert_eq!(igtl::status_fields(&got[2].content).unwrap().0, igtl::status::OK);
        let got = read_n(&mut v2, 6);
        let kinds: Vec<&str> = got.iter().map(|m| m.kind.as_str()).collect();
        assert_eq!(kinds, ["TRANSFORM", "STATUS", "TRANSFORM", "TRANSFORM", "STATUS", "TRANSFORM"]);
        let status_of =
            |m: &Incoming| m.metadata.iter().find(|(k, _)| k == "TransformStatus").map(|(_, v)| v.clone());
        assert_eq!(status_of(&got[0]).as_deref(), Some("OK"));
        assert_eq!(status_of(&got[2]).as_deref(), Some("INVALID"));
        assert!(igtl::transform_rows(&got[2].content).unwrap().iter().flatten().all(|v| v.is_nan()));
    }

    /// A client that never reads loses its oldest frames and delays no one; one that reads keeps
    /// up with the controller's rate and gets every frame; one that asks for 50 ms gets TDATA no
    /// closer than that; one that leaves is logged.
    #[test]
    fn a_stalled_client_drops_frames_and_delays_no_one() {
        let server = PoseServer::start("127.0.0.1:0", ServerOptions::default()).unwrap();
        let stalled = connect(&server);
        let mut reader = connect(&server);
        let mut rate = connect(&server);
        let leaver = connect(&server);
        wait_clients(&server, 4);
        let mut ask = 50u32.to_be_bytes().to_vec();
        ask.extend_from_slice(&[0u8; 32]);
        rate.write_all(&igtl::encode(HeaderVersion::V1, "STT_TDATA", "ToolToArmBase", 0, &ask, &[], 0))
            .unwrap();
        assert_eq!(igtl::read_message(&mut rate).unwrap().kind, "RTS_TDATA");
        drop(leaver);
        // Ten seconds of the controller's frames, published faster than its rate.
        let n = 7_680u64;
        // What the reading client has read: the publisher keeps at most half a queue ahead of
        // it, so a reader starved by a loaded machine still keeps up (a client that reads must
        // get every frame; one that never reads must lose its oldest).
        let read = Arc::new(AtomicU64::new(0));
        let collect = std::thread::spawn({
            let read = Arc::clone(&read);
            move || {
                let mut buffered = std::io::BufReader::new(&mut reader);
                (0..n)
                    .map(|_| {
                        let m = igtl::read_message(&mut buffered).unwrap();
                        read.fetch_add(1, Ordering::SeqCst);
                        m
                    })
                    .collect::<Vec<_>>()
            }
        });
        let tdata = std::thread::spawn(move || {
            let mut got = Vec::new();
            while let Ok(m) = igtl::read_message(&mut rate) {
                got.push(m);
                if got.len() == 50 {
                    break;
                }
            }
            got
        });
        // The time spent inside `publish` (a stalled client must delay no one), and the whole
        // stream's: the reading client must keep up with the controller, its 7 680 frames read
        // in less than their 10 s.
        let real_time = Duration::from_secs_f64(n as f64 / 768.0);
        let mut publishing = Duration::ZERO;
        let streaming = std::time::Instant::now();
        for tick in 1..=n {
            while tick > read.load(Ordering::SeqCst) + QUEUE_FRAMES as u64 / 2 {
                assert!(
                    !collect.is_finished() && streaming.elapsed() < real_time,
                    "the reading client stopped, or fell behind the controller's rate, at frame {tick}"
                );
                std::thread::sleep(Duration::from_millis(1));
            }
            let started = std::time::Instant::now();
            server.publish(&pose(tick, true));
            publishing += started.elapsed();
            if tick % 8 == 0 {
                std::thread::sleep(Duration::from_millis(1));
            }
        }
        let got = collect.join().unwrap();
        let streamed = streaming.elapsed();
        assert!(streamed < real_time, "the reading client took {streamed:?} for {real_time:?} of frames");
        let ticks: Vec<u64> =
            got.iter().map(|m| igtl::transform_rows(&m.content).unwrap()[0][3] as u64 - 100).collect();
        assert_eq!(ticks, (1..=n).collect::<Vec<_>>(), "the reading client gets every frame in order");
        let tdata = tdata.join().unwrap();
        let times: Vec<f64> = tdata.iter().map(|m| igtl::unix_seconds(m.timestamp)).collect();
        assert!(tdata.iter().all(|m| m.kind == "TDATA" && m.content.len() == igtl::TDATA_ELEMENT_BYTES));
        assert!(times.windows(2).all(|w| w[1] - w[0] >= 0.050 - 1e-6 && w[1] - w[0] < 0.052), "{times:?}");
        let stats = server.clients();
        let stalled_stats = stats.iter().find(|c| c.peer == stalled.local_addr().unwrap()).unwrap();
        assert!(stalled_stats.dropped > 0, "{stats:?}");
        let events = server.events();
        assert!(events.iter().any(|e| matches!(e, ServerEvent::Slow { .. })), "{events:?}");
        assert!(
            events.iter().any(|e| matches!(e, ServerEvent::Left { why, .. } if why.contains("closed"))),
            "{events:?}"
        );
        assert!(publishing < Duration::from_secs(2), "publishing took {publishing:?}");
        let mut buf = [0u8; 1];
        drop(server);
        let mut stalled = stalled;
        stalled.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
        while stalled.read(&mut buf).map(|n| n > 0).unwrap_or(false) {}
    }

    #[test]
    fn transform_names_follow_plus() {
        for good in ["ToolToArmBase", "StylusTipToReference", "ProbeToTracker"] {
            assert!(plus_name(good), "{good}");
        }
        for bad in
            ["toolToBase", "Tool", "ToolTo", "ToArm", "Tool To Base", "ToolToArmBaseToSomethingLong", ""]
        {
            assert!(!plus_name(bad), "{bad}");
        }
    }
}
