//! Per-tick cost, measured on the emulated Cortex-M4 (feature `tick-bench`).
//!
//! Run under `qemu-system-arm … -icount shift=0`: guest time then advances 1 ns per executed
//! instruction, so the 25 MHz CMSDK timer counts one per 40 instructions. The work per tick is
//! the firmware's own: read six emulated BiSS-C frames, decode and check them, feed a window,
//! encode a raw-sample frame and a pose frame (f32 kinematics with every effect).

use crate::bus::EmulatedBus;
use cortex_m_semihosting::{debug, hprintln};
use kincal_firmware::controller::Controller;
use kincal_firmware::encoders::Sampler;
use kincal_firmware::flash::RamNor;
use kincal_firmware::kinematics::Kinematics;
use kincal_protocol::framing::{self, MAX_FRAME};
use kincal_protocol::messages::{HostFrame, Request, PROTOCOL_VERSION, SCHEMA_HASH};
use kincal_protocol::params::{encode_blob, ArmParams, JointParams, BLOB_CRC, MAX_PARAM_BLOB};

const TIMER0: usize = 0x4000_0000;
const TICKS: u32 = 768;

fn timer() -> u32 {
    // SAFETY: TIMER0 VALUE register, free running down from 0xFFFF_FFFF.
    u32::MAX - unsafe { core::ptr::read_volatile((TIMER0 + 4) as *const u32) }
}

fn start_timer() {
    // SAFETY: TIMER0 registers.
    unsafe {
        core::ptr::write_volatile((TIMER0 + 8) as *mut u32, u32::MAX);
        core::ptr::write_volatile((TIMER0 + 4) as *mut u32, u32::MAX);
        core::ptr::write_volatile(TIMER0 as *mut u32, 1);
    }
}

fn params() -> ArmParams {
    let d = [47.0, 0.0, 571.0, 0.0, 371.0, 0.0];
    let alpha = [90.0, 90.0, -90.0, 90.0, 90.0, 90.0];
    let offset = [-1.6, 20.7, 201.3, 117.1, 88.7, -11.6];
    ArmParams {
        version: 1,
        modified_dh: false,
        joints: core::array::from_fn(|j| JointParams { offset_deg: offset[j], d_mm: d[j], alpha_deg: alpha[j], eccentricity_deg: [0.1, 0.05], eccentricity2_deg: [0.01, 0.0], compliance_deg_per_m: 0.05, ..JointParams::default() }),
        tcp_mm: [0.0, 0.0, 253.0],
        scale_ppm: 0.0,
    }
}

/// Measure and exit QEMU.
pub fn run() -> ! {
    start_timer();
    let mut controller = Controller::new("bench", "mps2", true, RamNor::<4096>::new());
    let mut sampler = Sampler::default();
    let mut bus = EmulatedBus::new();
    bus.apply(&Request::SimSetPose { counts: [100_000, 1_200_000, 2_000_000, 3_000_000, 4_000_000, 500] });
    bus.apply(&Request::SimFaults { noise_counts: 3, crc_errors_per_10k: 0, dropouts_per_10k: 0, error_bits_per_10k: 0, warnings_per_10k: 0 });
    let mut sink = |f: &kincal_protocol::messages::DeviceFrame| {
        let mut buf = [0u8; MAX_FRAME];
        let _ = framing::encode(f, &mut buf);
    };
    let health = sampler.health;
    let mut blob = [0u8; MAX_PARAM_BLOB];
    let n = encode_blob(&params(), &mut blob).unwrap_or(0);
    for request in [
        Request::Hello { version: PROTOCOL_VERSION, schema: SCHEMA_HASH },
        Request::ParamBegin { len: n as u16, crc: BLOB_CRC.checksum(&blob[..n]) },
    ] {
        controller.handle(HostFrame { seq: 1, request }, &health, &mut sink);
    }
    for (k, chunk) in blob[..n].chunks(48).enumerate() {
        let data = heapless::Vec::from_slice(chunk).unwrap_or_default();
        controller.handle(HostFrame { seq: 2, request: Request::ParamChunk { offset: (k * 48) as u16, data } }, &health, &mut sink);
    }
    for request in [Request::ParamCommit, Request::StartWindow { ticks: 4096 }, Request::StreamRaw(true), Request::StreamPose(1)] {
        controller.handle(HostFrame { seq: 3, request }, &health, &mut sink);
    }
    let start = timer();
    for _ in 0..TICKS {
        let sample = sampler.sample(&mut bus);
        controller.on_tick(&sample, &mut sink);
    }
    let full = timer().wrapping_sub(start) as u64 * 40 / TICKS as u64;
    let start = timer();
    let mut x = 0.0f32;
    let kinematics = Kinematics::new(&params());
    for k in 0..TICKS {
        x += kinematics.tool_pose(&[k * 4000, 1_200_000, 2_000_000, 3_000_000, 4_000_000, 500]).position_mm[0];
    }
    let pose = timer().wrapping_sub(start) as u64 * 40 / TICKS as u64;
    hprintln!("tick-bench: {} instructions per tick (six frames decoded, window, raw frame, pose frame); of which pose {} (checksum {})", full, pose, x as i32);
    hprintln!("tick-bench: at 768 Hz that is {:.2} % of an 84 MHz Cortex-M4 at 1 cycle/instruction, {:.2} % at 1.5", full as f64 * 768.0 / 84e6 * 100.0, full as f64 * 1.5 * 768.0 / 84e6 * 100.0);
    debug::exit(debug::EXIT_SUCCESS);
    loop {}
}
