//! The async application both boards run: three small tasks around the [`Controller`].
//!
//! * `sample_encoders` — every tick of a 768 Hz [`Ticker`] read all six encoders and feed the
//!   controller (windows, raw and pose streams);
//! * `serve_host` — decode request frames from the host link and answer them;
//! * `send_to_host` is board code: it drains [`TO_HOST`] into the UART.
//!
//! Frames to the host are encoded whole into [`TO_HOST`]; a frame that does not fit is dropped
//! whole, so the host sees a gap in the stream sequence numbers, never a torn frame.

use crate::controller::{Action, Controller};
use crate::encoders::{EncoderBus, Sampler};
use crate::flash::NorFlash;
use core::cell::RefCell;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::pipe::Pipe;
use embassy_time::{Duration, Ticker, Timer};
use kincal_protocol::framing::{self, Decoder, MAX_FRAME};
use kincal_protocol::messages::{DeviceFrame, HostFrame, TICK_HZ};

/// Bytes buffered towards the host (≈ 0.26 s of raw stream).
pub const TO_HOST_BYTES: usize = 6144;
/// Bytes buffered from the host.
pub const FROM_HOST_BYTES: usize = 1024;

/// Encoded frames waiting for the UART.
pub static TO_HOST: Pipe<CriticalSectionRawMutex, TO_HOST_BYTES> = Pipe::new();
/// Bytes received from the host, written by the UART interrupt.
pub static FROM_HOST: Pipe<CriticalSectionRawMutex, FROM_HOST_BYTES> = Pipe::new();

/// Everything the tasks share.
pub struct Shared<F: NorFlash, B: EncoderBus> {
    /// The protocol state machine.
    pub controller: Controller<F>,
    /// Encoder reading and health counters.
    pub sampler: Sampler,
    /// The encoder bus.
    pub bus: B,
}

/// The shared state, behind a critical-section mutex.
pub type SharedCell<F, B> = Mutex<CriticalSectionRawMutex, RefCell<Option<Shared<F, B>>>>;

/// Encode `frame` into [`TO_HOST`], whole or not at all. Call with the shared state locked.
pub fn send_frame(frame: &DeviceFrame) {
    let mut buf = [0u8; MAX_FRAME];
    let Ok(bytes) = framing::encode_device_frame(frame, &mut buf) else { return };
    if TO_HOST.free_capacity() >= bytes.len() {
        // try_write stops at the ring buffer's wrap point: write the rest too. Callers hold the
        // shared critical section, so no other writer interleaves and the space stays free.
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

/// Read all encoders every tick and feed the controller.
pub async fn sample_encoders<F: NorFlash, B: EncoderBus>(shared: &SharedCell<F, B>) -> ! {
    let mut ticker = Ticker::every(Duration::from_hz(TICK_HZ as u64));
    loop {
        ticker.next().await;
        shared.lock(|cell| {
            if let Some(s) = cell.borrow_mut().as_mut() {
                let sample = s.sampler.sample(&mut s.bus);
                s.controller.on_tick(&sample, &mut send_frame);
            }
        });
    }
}

/// Answer the host. `act` carries out board actions (reset, emulated-encoder settings).
pub async fn serve_host<F: NorFlash, B: EncoderBus>(
    shared: &SharedCell<F, B>,
    mut act: impl FnMut(Action, &mut B),
) -> ! {
    let mut decoder = Decoder::new();
    let mut buf = [0u8; 64];
    loop {
        let n = FROM_HOST.read(&mut buf).await;
        for &byte in &buf[..n] {
            let Some(decoded) = decoder.push::<HostFrame>(byte) else { continue };
            let action = shared.lock(|cell| {
                let mut cell = cell.borrow_mut();
                let Some(s) = cell.as_mut() else { return Action::None };
                match decoded {
                    Ok(frame) => {
                        let health = s.sampler.health;
                        let action = s.controller.handle(frame, &health, &mut send_frame);
                        if let Action::Simulate(_) = &action {
                            act(action.clone(), &mut s.bus);
                        }
                        action
                    }
                    Err(_) => {
                        s.controller.bad_frame(&mut send_frame);
                        Action::None
                    }
                }
            });
            if action == Action::Reset {
                // Let the acknowledgement leave before the board restarts.
                while !TO_HOST.is_empty() {
                    Timer::after_millis(1).await;
                }
                Timer::after_millis(20).await;
                shared.lock(|cell| {
                    if let Some(s) = cell.borrow_mut().as_mut() {
                        act(Action::Reset, &mut s.bus);
                    }
                });
            }
        }
    }
}
