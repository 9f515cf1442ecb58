//! An OpenIGTLink client that records the TRANSFORMs a server sends, as navigation software
//! receives them: the pose's timestamp, its translation (mm) and when it arrived on this host.
//! It records kincal's own pose server (the arm's pose at the far end of the wire) as well as any
//! other server, e.g. PLUS serving an optical tracker.

use crate::igtl::{self, HeaderVersion, IgtlError};
use crate::motion::recording::Track;
use std::io::Write;
use std::net::{Shutdown, SocketAddr, TcpStream};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{SystemTime, UNIX_EPOCH};

/// What the client received.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Received {
    /// The transform's samples: its timestamps, translations and arrival times (`host_s`).
    pub track: Track,
    /// TRANSFORM messages of the name received (valid ones in `track`).
    pub transforms: u64,
    /// Of them, a matrix that is not finite (an invalid pose sent marked as such): not recorded.
    pub invalid: u64,
    /// Of them, a timestamp not after the previous one's: not recorded.
    pub unordered: u64,
    /// STATUS messages received.
    pub status: u64,
    /// Messages whose CRC did not match: not used.
    pub bad_crc: u64,
}

/// A running recording; [`Recorder::finish`] ends it and returns what arrived.
pub struct Recorder {
    socket: TcpStream,
    received: Arc<Mutex<Received>>,
    reader: Option<JoinHandle<Result<(), IgtlError>>>,
}

fn now_s() -> f64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map_or(0.0, |d| d.as_secs_f64())
}

impl Recorder {
    /// Connect to the server at `addr` and record the TRANSFORMs named `name`; `v2` first sends
    /// a header-version-2 message, as an OpenIGTLink 3 client does (a PLUS-like server then
    /// answers with version 2 and metadata).
    pub fn connect(addr: SocketAddr, name: &str, v2: bool) -> Result<Recorder, IgtlError> {
        let mut socket = TcpStream::connect(addr)?;
        socket.set_nodelay(true)?;
        if v2 {
            socket.write_all(&igtl::encode(HeaderVersion::V2, "GET_STATUS", name, 0, &[], &[], 0))?;
        }
        let received = Arc::new(Mutex::new(Received::default()));
        let (mut reader, into, name) = (socket.try_clone()?, received.clone(), name.to_string());
        let reader = std::thread::spawn(move || -> Result<(), IgtlError> {
            let mut buffered = std::io::BufReader::with_capacity(1 << 16, &mut reader);
            loop {
                let message = match igtl::read_message(&mut buffered) {
                    Ok(m) => m,
                    Err(IgtlError::Io(e)) if e.kind() == std::io::ErrorKind::UnexpectedEof => return Ok(()),
                    Err(IgtlError::Io(e)) if e.kind() == std::io::ErrorKind::NotConnected => return Ok(()),
                    Err(e) => return Err(e),
                };
                let arrived = now_s();
                let mut r = into.lock().unwrap_or_else(|e| e.into_inner());
                match (message.crc_ok, message.kind.as_str()) {
                    (false, _) => r.bad_crc += 1,
                    (true, "STATUS") => r.status += 1,
                    (true, "TRANSFORM") if message.device == name => {
                        r.transforms += 1;
                        let Some(rows) = igtl::transform_rows(&message.content) else { continue };
                        if !rows.iter().flatten().all(|v| v.is_finite()) {
                            r.invalid += 1;
                            continue;
                        }
                        let t = igtl::unix_seconds(message.timestamp);
                        if r.track.t_s.last().is_some_and(|&last| t <= last) {
                            r.unordered += 1;
                            continue;
                        }
                        r.track.t_s.push(t);
                        r.track.p.push(std::array::from_fn(|k| rows[k][3] as f64));
                        r.track.host_s.get_or_insert_with(Vec::new).push(arrived);
                    }
                    _ => {}
                }
            }
        });
        Ok(Recorder { socket, received, reader: Some(reader) })
    }

    /// Whether the connection is still open (the server has not closed it).
    pub fn is_open(&self) -> bool {
        self.reader.as_ref().is_some_and(|r| !r.is_finished())
    }

    /// Stop (if the server has not closed the connection already) and return what arrived.
    pub fn finish(mut self) -> Result<Received, IgtlError> {
        let _ = self.socket.shutdown(Shutdown::Both);
        if let Some(reader) = self.reader.take() {
            match reader.join() {
                Ok(result) => result?,
                Err(_) => return Err(IgtlError::Io(std::io::Error::other("the recording thread failed"))),
            }
        }
        let received = self.received.lock().unwrap_or_else(|e| e.into_inner());
        Ok(received.clone())
    }
}
