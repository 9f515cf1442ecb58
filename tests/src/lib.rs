//! Helpers for the end-to-end tests: an in-process fake controller.
//!
//! [`FakeController`] runs the firmware's own protocol state machine, encoder sampling and
//! windows on the host, behind a TCP server on 127.0.0.1, so host logic and the `kincal` CLI can
//! be tested fast and without QEMU. Ticks run `speedup` times faster than 768 Hz. [`corpus`] is the
//! bad-input corpus and its runner.

pub mod corpus;

use kincal_firmware::controller::{Action, Controller};
use kincal_firmware::encoders::{EncoderBus, Sampler};
use kincal_firmware::flash::RamNor;
use kincal_protocol::biss::{self, Frame};
use kincal_protocol::framing::{self, Decoder, MAX_FRAME};
use kincal_protocol::messages::{DeviceFrame, HostFrame, Request};
use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::PathBuf;
use std::process::Command;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// Encoders that report the pose last set, without noise.
#[derive(Default)]
struct PoseBus {
    counts: [u32; 6],
}

impl EncoderBus for PoseBus {
    fn transfer(&mut self, joint: usize) -> Option<Frame> {
        Some(biss::encode(self.counts[joint], false, false, 1))
    }
}

/// A controller on a background thread; stopped on drop.
pub struct FakeController {
    /// Where to connect: `tcp:127.0.0.1:PORT`.
    pub port: String,
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
        let thread = std::thread::spawn(move || serve(listener, flag, speedup));
        FakeController { port, stop, thread: Some(thread) }
    }
}

fn write_frame(stream: &mut TcpStream, frame: &DeviceFrame) {
    let mut buf = [0u8; MAX_FRAME];
    if let Ok(bytes) = framing::encode(frame, &mut buf) {
        let _ = stream.write_all(bytes);
    }
}

fn serve(listener: TcpListener, stop: Arc<AtomicBool>, speedup: u32) {
    let mut controller = Controller::new("kincal-fw fake", "host (fake)", true, RamNor::<4096>::new());
    let mut sampler = Sampler::default();
    let mut bus = PoseBus::default();
    let tick = Duration::from_secs_f64(1.0 / (768.0 * speedup.max(1) as f64));
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
                        let mut out = Vec::new();
                        let action = match decoded {
                            Ok(frame) => {
                                controller.handle(frame, &sampler.health, &mut |f| out.push(f.clone()))
                            }
                            Err(_) => {
                                controller.bad_frame(&mut |f| out.push(f.clone()));
                                Action::None
                            }
                        };
                        for f in &out {
                            write_frame(&mut stream, f);
                        }
                        match action {
                            Action::Simulate(Request::SimSetPose { counts }) => bus.counts = counts,
                            Action::Reset => {
                                let flash = controller.into_flash();
                                controller = Controller::new("kincal-fw fake", "host (fake)", true, flash);
                                sampler = Sampler::default();
                            }
                            _ => {}
                        }
                    }
                }
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {}
                Err(_) => break 'connection,
            }
            while Instant::now() >= next_tick {
                next_tick += tick;
                let sample = sampler.sample(&mut bus);
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
