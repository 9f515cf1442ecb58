//! OpenIGTLink clients no one here wrote, for the tests: pyigtl (`tests/peers/pyigtl_record.py`
//! decodes with pyigtl) and the OpenIGTLink C++ library (`tests/peers/igtl_receive.cxx`,
//! compiled here against Debian's `libopenigtlink-dev`). Both are installed by
//! `scripts/setup.sh`; a missing one fails the test with what to install, never skips it.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::thread::JoinHandle;

fn peers_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("peers")
}

/// Panic with the install step when `what` is missing.
fn missing(what: &str) -> ! {
    panic!("{what} is missing: run scripts/setup.sh (it installs libopenigtlink-dev, g++ and pyigtl)")
}

/// The C++ receive client, compiled once per test run into `out_dir`.
pub fn cpp_client(out_dir: &Path) -> PathBuf {
    static BUILT: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    BUILT
        .get_or_init(|| {
            if !Path::new("/usr/include/openigtlink/igtlTransformMessage.h").exists() {
                missing("the OpenIGTLink C++ library (Debian libopenigtlink-dev)");
            }
            let exe = out_dir.join("igtl_receive");
            let status = Command::new("g++")
                .args(["-O2", "-I/usr/include/openigtlink"])
                .arg(peers_dir().join("igtl_receive.cxx"))
                .args(["-lOpenIGTLink", "-o"])
                .arg(&exe)
                .status()
                .unwrap_or_else(|_| missing("g++"));
            assert!(status.success(), "compiling tests/peers/igtl_receive.cxx against libOpenIGTLink failed");
            exe
        })
        .clone()
}

/// Fail unless Python can import pyigtl.
pub fn require_pyigtl() {
    let ok = Command::new("python3").args(["-c", "import pyigtl"]).status().is_ok_and(|s| s.success());
    if !ok {
        missing("pyigtl (pip install pyigtl)");
    }
}

/// A client process whose standard output is read as it comes, so that it never blocks on a
/// full pipe while the test waits (a blocked client would stop reading the server).
pub struct Peer {
    child: Child,
    output: JoinHandle<String>,
}

impl Peer {
    /// Start `cmd`; `what` names it when it cannot start.
    pub fn start(cmd: &mut Command, what: &str) -> Peer {
        let mut child = cmd
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .unwrap_or_else(|e| panic!("{what}: {e}"));
        let mut stdout = child.stdout.take().expect("stdout is piped");
        let output = std::thread::spawn(move || {
            let mut text = String::new();
            let _ = stdout.read_to_string(&mut text);
            text
        });
        Peer { child, output }
    }

    /// Wait for it to end: its exit status and all it printed.
    pub fn finish(mut self) -> (ExitStatus, String) {
        let status = self.child.wait().expect("the peer is waited for");
        (status, self.output.join().unwrap_or_default())
    }
}

/// Start the C++ client on `addr` (`HOST:PORT`), asking for TDATA every `tdata_ms` if given.
pub fn spawn_cpp(exe: &Path, addr: std::net::SocketAddr, tdata_ms: Option<u32>) -> Peer {
    let mut cmd = Command::new(exe);
    cmd.arg(addr.ip().to_string()).arg(addr.port().to_string());
    if let Some(ms) = tdata_ms {
        cmd.arg(ms.to_string());
    }
    Peer::start(&mut cmd, "the C++ client starts")
}

/// Start the pyigtl recorder on `addr`, writing `csv`; `v2`: it first sends a header-2 message.
pub fn spawn_pyigtl(addr: std::net::SocketAddr, csv: &Path, v2: bool) -> Peer {
    let mut cmd = Command::new("python3");
    cmd.arg(peers_dir().join("pyigtl_record.py"))
        .arg(addr.ip().to_string())
        .arg(addr.port().to_string())
        .arg(csv);
    if v2 {
        cmd.arg("--v2");
    }
    Peer::start(&mut cmd, "python3 starts")
}

/// One message as a peer received it.
#[derive(Clone, Debug, PartialEq)]
pub struct Received {
    /// Message type.
    pub kind: String,
    /// Device name.
    pub device: String,
    /// Timestamp, s since 1970.
    pub t_s: f64,
    /// The peer's CRC check passed.
    pub crc_ok: bool,
    /// Header version (pyigtl only; 0 when not known).
    pub version: u16,
    /// `TransformStatus` metadata (pyigtl only).
    pub status: String,
    /// Matrix values R11 R21 R31 R12 … TX TY TZ (TRANSFORM, and the TDATA element's).
    pub matrix: Vec<f64>,
    /// STATUS code and sub-code (C++ only).
    pub code: Option<(i64, i64)>,
}

/// The messages the C++ client printed.
pub fn parse_cpp(stdout: &str) -> Vec<Received> {
    let mut out = Vec::new();
    for line in stdout.lines() {
        let f: Vec<&str> = line.split(' ').collect();
        if f.len() < 5 || !matches!(f[0], "TRANSFORM" | "STATUS" | "TDATA" | "RTS_TDATA") {
            continue;
        }
        let num = |s: &str| s.parse::<f64>().unwrap_or(f64::NAN);
        let t_s = num(f[2]) + num(f[3]) * 1e-9;
        let mut r = Received {
            kind: f[0].to_string(),
            device: f[1].to_string(),
            t_s,
            crc_ok: f[4] == "1",
            version: 0,
            status: String::new(),
            matrix: Vec::new(),
            code: None,
        };
        match f[0] {
            "TRANSFORM" => r.matrix = f[5..].iter().map(|s| num(s)).collect(),
            "TDATA" if f.len() >= 19 => r.matrix = f[7..19].iter().map(|s| num(s)).collect(),
            "STATUS" => r.code = Some((num(f[5]) as i64, num(f[6]) as i64)),
            _ => {}
        }
        out.push(r);
    }
    out
}

/// The messages the pyigtl recorder wrote.
pub fn parse_pyigtl(csv: &str) -> Vec<Received> {
    csv.lines()
        .skip(1)
        .map(|line| {
            let f: Vec<&str> = line.split(',').collect();
            Received {
                kind: f[0].to_string(),
                device: f[1].to_string(),
                t_s: f[2].parse().unwrap_or(f64::NAN),
                crc_ok: f[4] == "1",
                version: f[3].parse().unwrap_or(0),
                status: f[5].to_string(),
                matrix: f[6..].iter().map(|s| s.parse().unwrap_or(f64::NAN)).collect(),
                code: None,
            }
        })
        .collect()
}
