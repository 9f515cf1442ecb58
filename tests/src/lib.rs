//! Helpers for the end-to-end tests: an in-process fake controller.
//!
//! [`FakeController`] runs the firmware's own protocol state machine, BiSS-C master reading the
//! emulated encoders, encoder sampling and windows on the host, behind a TCP server on 127.0.0.1, so host logic and the `kincal` CLI can
//! be tested fast and without QEMU. Ticks run `speedup` times faster than 768 Hz. [`corpus`] is the
//! bad-input corpus and its runner.

pub mod corpus;

pub mod doc_examples;

pub mod peers;

pub mod haptic_gen;

pub mod tracker_gen;

pub mod tracker_setup;

use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use kincal::controller::signing::StationKey;
use kincal_firmware::biss_master::BissMaster;
use kincal_firmware::controller::{Action, Controller};
use kincal_firmware::emulated_encoders::{EmulatedEncoder, EmulatedEncoders, SharedEncoders};
use kincal_firmware::encoders::Sampler;
use kincal_firmware::flash::RamNor;
use kincal_firmware::trust::{Trust, EMULATED_ARM_ID};
use kincal_protocol::framing::{self, Decoder, MAX_FRAME};
use kincal_protocol::messages::{Crash, DeviceFrame, HostFrame, Request, ResetCause, SimFaults, TICK_HZ};
use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// The fake controller's trust: the emulated arm's identity, trust on first use.
fn fake_trust() -> Trust {
    Trust::new(EMULATED_ARM_ID, None).expect("a valid identity")
}

/// The tests' station key (a fixed seed, so runs are reproducible).
pub fn station_key() -> StationKey {
    StationKey::from_seed([42; 32])
}

/// A station key file in `dir` (`station.key`, owner-only) for the CLI.
pub fn station_key_file(dir: &Path) -> PathBuf {
    let path = dir.join("station.key");
    StationKey::create(&path).expect("a new station key");
    path
}

/// `blob` signed by [`station_key`] for the emulated arm (also the fake controller's identity).
pub fn sign_blob(blob: &[u8]) -> Vec<u8> {
    station_key().sign(blob, EMULATED_ARM_ID, 1_790_000_000).expect("fits")
}

/// `model` as version `version`, signed by [`station_key`] for the emulated arm.
pub fn signed_set(model: &kincal::model::ArmModel, version: u32) -> Vec<u8> {
    sign_blob(&kincal::controller::device::parameter_blob(model, version).expect("inside the envelope"))
}

/// What happens to a request the fake controller is told to fault.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fault {
    /// Nothing: carry it out and answer.
    None,
    /// Carry it out, but the answer is lost on the way back.
    LoseReply,
    /// The request is lost on the way in: nothing happens, no answer.
    LoseRequest,
}

/// Which requests to fault, how, and how many more times.
struct FaultPlan {
    applies: fn(&Request) -> bool,
    fault: Fault,
    times: u32,
}
/// What the test does to the fake controller behind the host's back, while a CLI is connected.
#[derive(Default)]
struct Meddling {
    /// Emulated-arm requests to apply (pose, encoder faults), as if the host had sent them.
    arm: Vec<Request>,
    /// No ticks (no stream frames) until then: a stalled controller.
    stalled_until: Option<Instant>,
}

/// A controller on a background thread; stopped on drop.
pub struct FakeController {
    /// Where to connect: `tcp:127.0.0.1:PORT`.
    pub port: String,
    faults: Arc<std::sync::Mutex<FaultPlan>>,
    meddling: Arc<std::sync::Mutex<Meddling>>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Drop for FakeController {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

impl FakeController {
    /// Start a fake controller whose ticks run `speedup` × 768 Hz.
    pub fn start(speedup: u32) -> FakeController {
        let listener = TcpListener::bind("127.0.0.1:0").expect("bind");
        let port = format!("tcp:{}", listener.local_addr().expect("address"));
        listener.set_nonblocking(true).expect("nonblocking");
        let stop = Arc::new(AtomicBool::new(false));
        let flag = stop.clone();
        let faults =
            Arc::new(std::sync::Mutex::new(FaultPlan { applies: |_| false, fault: Fault::None, times: 0 }));
        let plan = faults.clone();
        let meddling = Arc::new(std::sync::Mutex::new(Meddling::default()));
        let meddle = meddling.clone();
        let thread = std::thread::spawn(move || serve(listener, flag, plan, meddle, speedup));
        FakeController { port, faults, meddling, stop, thread: Some(thread) }
    }

    /// Apply an emulated-arm request (SimSetPose, SimFaults) at the next tick, whoever is
    /// connected: e.g. unplug a joint while the CLI streams.
    pub fn meddle_arm(&self, request: Request) {
        self.meddling.lock().unwrap_or_else(|e| e.into_inner()).arm.push(request);
    }

    /// Send nothing (no ticks) for `duration`: a controller that stalls.
    pub fn stall(&self, duration: Duration) {
        self.meddling.lock().unwrap_or_else(|e| e.into_inner()).stalled_until =
            Some(Instant::now() + duration);
    }

    /// Fault the next `times` requests for which `applies` holds, in the way given.
    pub fn fault_next(&self, applies: fn(&Request) -> bool, fault: Fault, times: u32) {
        *self.faults.lock().unwrap_or_else(|e| e.into_inner()) = FaultPlan { applies, fault, times };
    }
}

fn write_frame(stream: &mut TcpStream, frame: &DeviceFrame) {
    let mut buf = [0u8; MAX_FRAME];
    if let Ok(bytes) = framing::encode(frame, &mut buf) {
        let _ = stream.write_all(bytes);
    }
}

fn serve(
    listener: TcpListener,
    stop: Arc<AtomicBool>,
    faults: Arc<std::sync::Mutex<FaultPlan>>,
    meddling: Arc<std::sync::Mutex<Meddling>>,
    speedup: u32,
) {
    let mut controller =
        Controller::new("kincal-fw fake", "host (fake)", true, fake_trust(), RamNor::<4096>::new());
    controller.set_boot(ResetCause::PowerOn, 0);
    let mut sampler = Sampler::default();
    let encoders: SharedEncoders<NoopRawMutex> =
        embassy_sync::blocking_mutex::Mutex::new(std::cell::RefCell::new(EmulatedEncoders::new()));
    let mut master = BissMaster::new(EmulatedEncoder::all(&encoders));
    let tick = Duration::from_secs_f64(1.0 / (TICK_HZ as f64 * speedup.max(1) as f64));
    while !stop.load(Ordering::SeqCst) {
        let Ok((mut stream, _)) = listener.accept() else {
            std::thread::sleep(Duration::from_millis(5));
            continue;
        };
        let _ = stream.set_nonblocking(true);
        let _ = stream.set_nodelay(true);
        let mut decoder = Decoder::new();
        let mut next_tick = Instant::now();
        'connection: while !stop.load(Ordering::SeqCst) {
            let mut buf = [0u8; 256];
            match stream.read(&mut buf) {
                Ok(0) => break 'connection,
                Ok(n) => {
                    for &b in &buf[..n] {
                        let Some(decoded) = decoder.push::<HostFrame>(b) else { continue };
                        let fault = match &decoded {
                            Ok(frame) => {
                                let mut plan = faults.lock().unwrap_or_else(|e| e.into_inner());
                                if plan.times > 0 && (plan.applies)(&frame.request) {
                                    plan.times -= 1;
                                    plan.fault
                                } else {
                                    Fault::None
                                }
                            }
                            Err(_) => Fault::None,
                        };
                        if fault == Fault::LoseRequest {
                            continue;
                        }
                        let mut out = Vec::new();
                        let action = match decoded {
                            Ok(frame) => controller.handle(frame, &sampler, &mut |f| out.push(f.clone())),
                            Err(_) => {
                                controller.bad_frame(&mut |f| out.push(f.clone()));
                                Action::None
                            }
                        };
                        if action == Action::Verify {
                            // The board checks the signature outside its shared state; here,
                            // in line: the answer comes from finishing the commit.
                            if let Some(commit) = controller.take_commit() {
                                controller.finish_commit(commit.verify(), &mut |f| out.push(f.clone()));
                            }
                        }
                        if fault != Fault::LoseReply {
                            for f in &out {
                                write_frame(&mut stream, f);
                            }
                        }
                        let restart = match action {
                            // No watchdog here, and a hang would stop this thread: the fake
                            // restarts at once, as the board does, with the cause recorded.
                            Action::Simulate(Request::SimFaults(SimFaults {
                                crash: Crash::Panic, ..
                            })) => Some(ResetCause::Panic),
                            Action::Simulate(Request::SimFaults(SimFaults {
                                crash: Crash::Hang, ..
                            })) => Some(ResetCause::Watchdog),
                            Action::Simulate(request) => {
                                encoders.lock(|e| e.borrow_mut().apply(&request));
                                if matches!(request, Request::SimSetPose(_) | Request::SimPlay(_)) {
                                    sampler.forget_positions();
                                }
                                None
                            }
                            Action::Reset => Some(ResetCause::Software),
                            Action::None | Action::Verify => None,
                        };
                        if let Some(cause) = restart {
                            let flash = controller.into_flash();
                            controller =
                                Controller::new("kincal-fw fake", "host (fake)", true, fake_trust(), flash);
                            controller.set_boot(cause, 0);
                            sampler = Sampler::default();
                        }
                    }
                }
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {}
                Err(_) => break 'connection,
            }
            let stalled_until = {
                let mut m = meddling.lock().unwrap_or_else(|e| e.into_inner());
                for request in m.arm.drain(..) {
                    encoders.lock(|e| e.borrow_mut().apply(&request));
                }
                m.stalled_until.filter(|t| Instant::now() < *t)
            };
            if let Some(until) = stalled_until {
                next_tick = until;
            }
            while Instant::now() >= next_tick {
                next_tick += tick;
                let sample = sampler.record(&embassy_futures::block_on(master.read_all()));
                let mut out = Vec::new();
                controller.on_tick(&sample, &mut |f| out.push(f.clone()));
                for f in &out {
                    write_frame(&mut stream, f);
                }
            }
            std::thread::sleep(Duration::from_micros(200));
        }
    }
}

/// The `kincal` binary of this build profile, built (or confirmed current) once per run.
pub fn kincal_bin() -> PathBuf {
    static BUILT: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    BUILT
        .get_or_init(|| {
            let exe = std::env::current_exe().unwrap();
            let dir = exe.parent().and_then(|p| p.parent()).unwrap().to_path_buf();
            let release = dir.file_name().is_some_and(|n| n == "release");
            let mut cargo = Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()));
            cargo.args(["build", "--quiet", "-p", "kincal", "--bin", "kincal"]);
            if release {
                cargo.arg("--release");
            }
            assert!(cargo.status().unwrap().success(), "building the kincal binary failed");
            dir.join("kincal")
        })
        .clone()
}

/// A TCP link whose replies arrive late and together, as over a link with Nagle's delay or a
/// USB-serial adapter's latency timer: after every write it waits `delay` before the next read,
/// so a request's answer and the frames that follow it come in one read.
pub struct Laggy {
    stream: TcpStream,
    delay: Duration,
}

impl Laggy {
    /// Connect to `tcp:HOST:PORT` with replies held back by `delay`.
    pub fn connect(port: &str, delay: Duration) -> std::io::Result<Laggy> {
        let addr = port.strip_prefix("tcp:").unwrap_or(port);
        let stream = TcpStream::connect(addr)?;
        stream.set_nodelay(true)?;
        Ok(Laggy { stream, delay })
    }
}

impl Read for Laggy {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        self.stream.read(buf)
    }
}

impl Write for Laggy {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.stream.write(buf)?;
        std::thread::sleep(self.delay);
        Ok(n)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.stream.flush()
    }
}

impl kincal::controller::link::Transport for Laggy {
    fn set_read_timeout(&mut self, timeout: Duration) -> std::io::Result<()> {
        self.stream.set_read_timeout(Some(timeout))
    }
}

/// The emulated controller's firmware image, built (or confirmed current) once per test run with
/// the workspace's `cargo build-emulated`.
pub fn emulated_firmware() -> PathBuf {
    static BUILT: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    BUILT
        .get_or_init(|| {
            let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
            let status = Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()))
                .current_dir(&root)
                .args(["build-emulated", "--quiet"])
                .status()
                .expect("cargo runs");
            assert!(
                status.success(),
                "cargo build-emulated failed (rustup target add thumbv7em-none-eabihf?)"
            );
            root.join("firmware/target/thumbv7em-none-eabihf/release/emulated")
        })
        .clone()
}
