//! The async application both boards run: three small tasks around the [`Controller`].
//!
//! * `sample_encoders` — every tick of a 768 Hz [`Ticker`] read all six encoders through the
//!   BiSS-C master and feed the controller (windows, raw and pose streams);
//! * `serve_host` — decode request frames from the host link and answer them;
//! * `send_to_host` is board code: it drains [`TO_HOST`] into the UART.
//!
//! Frames to the host are encoded whole into [`TO_HOST`]; a frame that does not fit is dropped
//! whole, so the host sees a gap in the stream sequence numbers, never a torn frame.

use crate::biss_master::BissMaster;
use crate::controller::{Action, Controller};
use crate::encoders::Sampler;
use core::cell::RefCell;
use embassy_sync::blocking_mutex::raw::{CriticalSectionRawMutex, ThreadModeRawMutex};
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::pipe::Pipe;
use embassy_time::{Duration, Instant, Ticker, Timer};
use embedded_hal_async::spi::SpiDevice;
use embedded_storage::nor_flash::NorFlash;
use kincal_protocol::framing::{self, Decoder, MAX_FRAME};
use kincal_protocol::messages::{Crash, DeviceFrame, HostFrame, Request, SimFaults, TICK_HZ};

/// Bytes buffered towards the host (≈ 0.26 s of raw stream).
pub const TO_HOST_BYTES: usize = 6144;
/// Bytes buffered from the host.
pub const FROM_HOST_BYTES: usize = 1024;

/// Encoded frames waiting for the UART (tasks only: a thread-mode lock, interrupts stay on).
pub static TO_HOST: Pipe<ThreadModeRawMutex, TO_HOST_BYTES> = Pipe::new();
/// Bytes received from the host; the emulated board's UART interrupt writes them, so this one
/// is a critical section, held only to copy a few bytes.
pub static FROM_HOST: Pipe<CriticalSectionRawMutex, FROM_HOST_BYTES> = Pipe::new();

/// Everything the tasks share.
pub struct Shared<F: NorFlash> {
    /// The protocol state machine.
    pub controller: Controller<F>,
    /// Encoder health counters and last good positions.
    pub sampler: Sampler,
    /// Encodes frames into [`TO_HOST`].
    pub to_host: FrameSender,
}

impl<F: NorFlash> Shared<F> {
    /// The shared state around `controller`.
    pub fn new(controller: Controller<F>) -> Self {
        Shared { controller, sampler: Sampler::default(), to_host: FrameSender::new() }
    }
}

/// The shared state. Only tasks (thread mode) lock it, so holding it never masks interrupts;
/// the encoder bus transfers happen outside it. Boards create it at start (in a `StaticCell`,
/// so it takes no initialised-data flash) and hand it to the tasks.
pub type SharedCell<F> = Mutex<ThreadModeRawMutex, RefCell<Shared<F>>>;

/// Encodes frames for the host into [`TO_HOST`] through one buffer kept between frames (a
/// fresh zeroed buffer per frame cost about 300 instructions, a tenth of a tick's work).
pub struct FrameSender {
    buf: [u8; MAX_FRAME],
}

impl Default for FrameSender {
    fn default() -> Self {
        Self::new()
    }
}

impl FrameSender {
    /// A sender with its buffer.
    pub const fn new() -> Self {
        FrameSender { buf: [0; MAX_FRAME] }
    }

    /// Encode `frame` into [`TO_HOST`], whole or not at all. Call with the shared state locked.
    pub fn send(&mut self, frame: &DeviceFrame) {
        let Ok(bytes) = framing::encode_device_frame(frame, &mut self.buf) else { return };
        if TO_HOST.free_capacity() >= bytes.len() {
            // try_write stops at the ring buffer's wrap point: write the rest too. Only tasks
            // write and they do not interleave inside this function, so the space stays free.
            let mut rest = bytes;
            while !rest.is_empty() {
                match TO_HOST.try_write(rest) {
                    Ok(n) => rest = &rest[n..],
                    Err(_) => break,
                }
            }
        }
        // Otherwise the frame is dropped whole; the host sees the gap in the stream counter.
    }
}

/// Every tick: read all encoders through `master` (awaiting the bus, nothing locked), feed
/// the controller, then feed the watchdog (`feed_watchdog`): only a sampling loop that
/// completes its ticks keeps the controller from being reset.
pub async fn sample_encoders<F: NorFlash, D: SpiDevice>(
    shared: &SharedCell<F>,
    mut master: BissMaster<D>,
    mut feed_watchdog: impl FnMut(),
) -> ! {
    let period = Duration::from_hz(TICK_HZ as u64);
    let mut ticker = Ticker::every(period);
    let mut due = Instant::now() + period;
    loop {
        ticker.next().await;
        let late = Instant::now() > due + period;
        due += period;
        let readings = master.read_all().await;
        shared.lock(|cell| {
            let s = &mut *cell.borrow_mut();
            s.sampler.late_ticks += late as u32;
            let sample = s.sampler.record(&readings);
            let to_host = &mut s.to_host;
            s.controller.on_tick(&sample, &mut |frame| to_host.send(frame));
        });
        feed_watchdog();
    }
}

/// Answer the host. `act` carries out board actions (reset, emulated-encoder settings).
pub async fn serve_host<F: NorFlash>(shared: &SharedCell<F>, mut act: impl FnMut(Action)) -> ! {
    let mut decoder = Decoder::new();
    let mut buf = [0u8; 64];
    loop {
        let n = FROM_HOST.read(&mut buf).await;
        for &byte in &buf[..n] {
            let Some(decoded) = decoder.push::<HostFrame>(byte) else { continue };
            let action = shared.lock(|cell| {
                let s = &mut *cell.borrow_mut();
                let to_host = &mut s.to_host;
                let mut send = |frame: &DeviceFrame| to_host.send(frame);
                match decoded {
                    Ok(frame) => s.controller.handle(frame, &s.sampler, &mut send),
                    Err(_) => {
                        s.controller.bad_frame(&mut send);
                        Action::None
                    }
                }
            });
            match action {
                Action::None => {}
                Action::Verify => verify_and_commit(shared),
                Action::Simulate(request) => {
                    let moved = matches!(request, Request::SimSetPose(_) | Request::SimPlay(_));
                    if let Request::SimFaults(SimFaults { crash: Crash::Panic | Crash::Hang, .. }) = request {
                        // Let the acknowledgement leave before the board fails on purpose.
                        answers_sent().await;
                    }
                    act(Action::Simulate(request));
                    if moved {
                        // The emulated arm jumped to the new pose (or to a trajectory's start):
                        // not a fault of its encoders.
                        shared.lock(|cell| cell.borrow_mut().sampler.forget_positions());
                    }
                }
                Action::Reset => {
                    // Let the acknowledgement leave before the board restarts.
                    answers_sent().await;
                    act(Action::Reset);
                }
            }
        }
        if shared.lock(|cell| cell.borrow().controller.flash_maintenance_due()) {
            // The erase stops the real board's CPU for 1–2 s: after the answers are out, and only
            // while nothing samples (checked again under the lock).
            answers_sent().await;
            shared.lock(|cell| cell.borrow_mut().controller.maintain_flash());
        }
    }
}

/// Check the announced commit's signature (10.6 ms on the real board) on the commit's own copy
/// of the set, with the shared state unlocked; lock only to store it and answer. Not async: the
/// 1.7 KiB commit lives on the stack for this call, not in the task's state.
fn verify_and_commit<F: NorFlash>(shared: &SharedCell<F>) {
    let Some(commit) = shared.lock(|cell| cell.borrow_mut().controller.take_commit()) else { return };
    let verified = commit.verify();
    shared.lock(|cell| {
        let s = &mut *cell.borrow_mut();
        let to_host = &mut s.to_host;
        s.controller.finish_commit(verified, &mut |frame| to_host.send(frame));
    });
}

/// Wait until everything queued for the host has left (the UART's last DMA chunk included).
async fn answers_sent() {
    while !TO_HOST.is_empty() {
        Timer::after_millis(1).await;
    }
    Timer::after_millis(20).await;
}
