//! Per-tick cost, measured on the emulated Cortex-M4 (feature `tick-bench`).
//!
//! Run under `qemu-system-arm … -icount shift=0`: guest time then advances 1 ns per executed
//! instruction, so the 25 MHz CMSDK timer counts one per 40 instructions. The work per tick is
//! the firmware's own: read six BiSS-C transfers through the master, decode and check them, then
//! the controller's tick in each stream configuration the link carries (window, raw frames, pose
//! with every effect), frames going through the app's sender into the UART pipe and out of it.

use crate::mmio::{read, write, Block};
use core::cell::Cell;
use core::convert::Infallible;
use cortex_m_semihosting::{debug, hprintln};
use embedded_hal_async::spi::{ErrorType, Operation, SpiDevice};
use kincal_firmware::app::{FrameSender, TO_HOST};
use kincal_firmware::biss_master::{BissMaster, REAL_BOARD_MA_HZ, TRANSFER_BYTES};
use kincal_firmware::controller::Controller;
use kincal_firmware::emulated_encoders::EmulatedEncoders;
use kincal_firmware::encoders::Sampler;
use kincal_firmware::flash::RamNor;
use kincal_firmware::kinematics::Kinematics;
use kincal_firmware::trust::Trust;
use kincal_protocol::biss::TRANSFER_BITS;
use kincal_protocol::joints::{ALL_JOINTS, JOINTS};
use kincal_protocol::messages::{
    pack_counts, Crash, DeviceFrame, Hello, HostFrame, ParamBegin, ParamChunk, ParamCommit, PoseReport,
    RawSample, Request, SimFaults, SimSetPose, StartWindow, Stream, StreamPose, StreamRaw, PROTOCOL_VERSION,
    SCHEMA_HASH, TICK_HZ,
};
use kincal_protocol::params::{encode_blob, ArmParams, JointParams, BLOB_CRC, MAX_PARAM_BLOB};
use kincal_protocol::signed::{signing_message, SIGNATURE_BYTES};

const TIMER0: Block = Block::Timer0;

/// One encoder replaying transfers recorded from the emulated encoders, read through the
/// real BiSS-C master (its futures, decoding and checks are measured, the bus is not).
struct ReplayEncoder<'a> {
    transfers: &'a [[[u8; TRANSFER_BYTES]; 6]; 8],
    tick: &'a Cell<usize>,
    joint: usize,
}

impl ErrorType for ReplayEncoder<'_> {
    type Error = Infallible;
}

impl SpiDevice for ReplayEncoder<'_> {
    async fn transaction(&mut self, operations: &mut [Operation<'_, u8>]) -> Result<(), Infallible> {
        for op in operations {
            if let Operation::Read(buf) = op {
                buf.copy_from_slice(&self.transfers[self.tick.get() % 8][self.joint]);
            }
        }
        if self.joint == 5 {
            self.tick.set(self.tick.get() + 1);
        }
        Ok(())
    }
}

/// Cycles one DMA-driven transfer costs the real board's CPU (an encoder read on SPI1: setting up
/// two DMA streams, the completion interrupt, waking and polling the task; the same for a UART
/// write): an estimate, not measured here (QEMU has no STM32 DMA).
const DMA_TRANSFER_CYCLES: u64 = 800;
/// Cycles each encoder read costs the real board's CPU besides its transfer (`EncoderPort` in
/// the STM32 board): the 2 µs enable set-up busy-wait (336 cycles) and one timer wake for MA held
/// high through the encoder's timeout (as a DMA wake, an estimate).
const ENCODER_PORT_CYCLES: u64 = 336 + DMA_TRANSFER_CYCLES;
/// Bus time per encoder read besides the clocks, µs: the 2 µs set-up and MA held high for 40 µs.
const ENCODER_PORT_US: f64 = 42.0;
/// Core clock of the real board.
const CORE_HZ: f64 = 168e6;
/// Ticks each figure is averaged over (one second).
const TICKS: u32 = TICK_HZ;

fn timer() -> u32 {
    // TIMER0 VALUE, free running down from 0xFFFF_FFFF.
    u32::MAX - read(TIMER0, 4)
}

fn start_timer() {
    write(TIMER0, 8, u32::MAX);
    write(TIMER0, 4, u32::MAX);
    write(TIMER0, 0, 1);
}

fn params() -> ArmParams {
    let d = [47.0, 0.0, 571.0, 0.0, 371.0, 0.0];
    let alpha = [90.0, 90.0, -90.0, 90.0, 90.0, 90.0];
    let offset = [-1.6, 20.7, 201.3, 117.1, 88.7, -11.6];
    ArmParams {
        version: 1,
        modified_dh: false,
        joints: core::array::from_fn(|j| JointParams {
            offset_deg: offset[j],
            d_mm: d[j],
            alpha_deg: alpha[j],
            eccentricity_deg: [0.1, 0.05],
            eccentricity2_deg: [0.01, 0.0],
            compliance_deg_per_m: 0.05,
            ..JointParams::default()
        }),
        tcp_mm: [0.0, 0.0, 253.0],
        scale_ppm: 0.0,
    }
}

/// Measure and exit QEMU.
pub fn run() -> ! {
    start_timer();
    let trust = Trust::new("bench-arm", None).unwrap_or_else(|| panic!("a valid arm identity"));
    let mut controller = Controller::new("bench", "mps2", true, trust.clone(), RamNor::<4096>::new());
    let mut sampler = Sampler::default();
    let mut bus = EmulatedEncoders::new();
    bus.apply(&Request::SimSetPose(SimSetPose {
        counts: [100_000, 1_200_000, 2_000_000, 3_000_000, 4_000_000, 500],
    }));
    bus.apply(&Request::SimFaults(SimFaults { noise_counts: 3, ..SimFaults::default() }));
    // Frames go the app's way into TO_HOST, and leave it as the UART task takes them.
    let mut sender = FrameSender::new();
    let mut uart_chunk = [0u8; 256];
    let mut sink = |f: &DeviceFrame| {
        sender.send(f);
        while TO_HOST.try_read(&mut uart_chunk).is_ok() {}
    };
    // The set as a station signs it (signing is the host's work, not measured).
    let station = ed25519_compact::KeyPair::from_seed(ed25519_compact::Seed::new([7; 32]));
    let mut unsigned = [0u8; MAX_PARAM_BLOB];
    let m = encode_blob(&params(), &mut unsigned).unwrap_or(0);
    let mut blob = [0u8; MAX_PARAM_BLOB];
    let n = signing_message(&unsigned[..m], "bench-arm", 1_790_000_000, &station.pk, &mut blob).unwrap_or(0);
    let signature = station.sk.sign(&blob[..n], None);
    blob[n..n + SIGNATURE_BYTES].copy_from_slice(signature.as_ref());
    let n = n + SIGNATURE_BYTES;
    for request in [
        Request::Hello(Hello { version: PROTOCOL_VERSION, schema: SCHEMA_HASH }),
        Request::ParamBegin(ParamBegin { len: n as u16, crc: BLOB_CRC.checksum(&blob[..n]) }),
    ] {
        controller.handle(HostFrame { seq: 1, request }, &sampler, &mut sink);
    }
    for (k, chunk) in blob[..n].chunks(48).enumerate() {
        let data = heapless::Vec::from_slice(chunk).unwrap_or_default();
        controller.handle(
            HostFrame { seq: 2, request: Request::ParamChunk(ParamChunk { offset: (k * 48) as u16, data }) },
            &sampler,
            &mut sink,
        );
    }
    // A commit, outside any tick: the trust checks (Ed25519 verification) alone, then the
    // whole commit (the checks again, flash programming and read-back, kinematics setup).
    let start = timer();
    let admitted = trust.admit(&blob[..n], None).is_ok();
    let verify = timer().wrapping_sub(start) as u64 * 40;
    let start = timer();
    controller.handle(HostFrame { seq: 3, request: Request::ParamCommit(ParamCommit) }, &sampler, &mut sink);
    if let Some(pending) = controller.take_commit() {
        controller.finish_commit(pending.verify(), &mut sink);
    }
    let commit = timer().wrapping_sub(start) as u64 * 40;
    let committed = admitted && controller.params().is_some();
    // Transfers as the bus delivers them (generating them is the emulator's work, not measured).
    let transfers = core::array::from_fn(|_| core::array::from_fn(|j| bus.answer(j)));
    let tick = Cell::new(0);
    let mut master = BissMaster::new(core::array::from_fn(|joint| ReplayEncoder {
        transfers: &transfers,
        tick: &tick,
        joint,
    }));
    let mut read_all = || embassy_futures::block_on(master.read_all());
    let measure = |f: &mut dyn FnMut()| {
        let start = timer();
        for _ in 0..TICKS {
            f();
        }
        timer().wrapping_sub(start) as u64 * 40 / TICKS as u64
    };

    // The parts.
    let mut sample = sampler.record(&read_all());
    let decode = measure(&mut || sample = sampler.record(&read_all()));
    let mut window = kincal_firmware::window::Window::new(4096);
    let window_cost = measure(&mut || {
        let _ = window.push(&sample.counts, sample.rejected);
    });
    let raw = DeviceFrame::Stream {
        seq: 1,
        item: Stream::Raw(RawSample { tick: 1, packed: pack_counts(&sample.counts), rejected: 0 }),
    };
    let raw_frame = measure(&mut || sink(&raw));
    let pose_report = DeviceFrame::Stream {
        seq: 1,
        item: Stream::Pose(PoseReport {
            tick: 1,
            valid: true,
            fresh: ALL_JOINTS,
            stale_ticks: 0,
            position_mm: [812.5, -40.25, 301.0],
            z_axis: [0.0, 0.6, 0.8],
            x_axis: [1.0, 0.0, 0.0],
        }),
    };
    let pose_frame = measure(&mut || sink(&pose_report));
    let with_effects = Kinematics::new(&params());
    let mut plain_params = params();
    for j in plain_params.joints.iter_mut() {
        j.eccentricity_deg = [0.0; 2];
        j.eccentricity2_deg = [0.0; 2];
        j.compliance_deg_per_m = 0.0;
    }
    let plain = Kinematics::new(&plain_params);
    let mut x = 0.0f32;
    let mut k = 0u32;
    let pose_all = measure(&mut || {
        k += 4000;
        x += with_effects.tool_pose(&[k, 1_200_000, 2_000_000, 3_000_000, 4_000_000, 500]).position_mm[0];
    });
    let pose_plain = measure(&mut || {
        k += 4000;
        x += plain.tool_pose(&[k, 1_200_000, 2_000_000, 3_000_000, 4_000_000, 500]).position_mm[0];
    });
    hprintln!("tick-bench (instructions, emulated Cortex-M4, qemu -icount shift=0; checksum {})", x as i32);
    hprintln!("  read (master) + check six frames     {:6}", decode);
    hprintln!("  window accumulate                    {:6}", window_cost);
    hprintln!("  raw-sample frame into the UART pipe  {:6}", raw_frame);
    hprintln!("  pose, DH + tool only                 {:6}", pose_plain);
    hprintln!("  pose, every effect (ecc + compl.)    {:6}", pose_all);
    hprintln!("  pose frame into the UART pipe        {:6}", pose_frame);
    hprintln!(
        "  per commit ({} B signed set, {}): signature + checks {} instr. = {:.1} ms at 168 MHz; whole commit {} = {:.1} ms ({:.0} ticks)",
        n,
        if committed { "stored" } else { "REFUSED" },
        verify,
        verify as f64 / CORE_HZ * 1e3,
        commit,
        commit as f64 / CORE_HZ * 1e3,
        commit as f64 / (CORE_HZ / TICK_HZ as f64)
    );

    // Whole ticks, through the controller, in the configurations the link can carry (the
    // controller refuses stream settings above it: raw and pose both every tick need 130 %).
    let tick_cycles = CORE_HZ / TICK_HZ as f64;
    let bus_us = JOINTS as f64 * (TRANSFER_BITS as f64 / REAL_BOARD_MA_HZ as f64 * 1e6 + ENCODER_PORT_US);
    let dma = (JOINTS as u64 + 1) * DMA_TRANSFER_CYCLES + JOINTS as u64 * ENCODER_PORT_CYCLES;
    hprintln!(
        "  encoder bus busy {:.1} us per tick ({:.2} % of the tick; DMA, the CPU does not wait)",
        bus_us,
        bus_us * TICK_HZ as f64 / 1e4
    );
    hprintln!(
        "  real board (168 MHz, 1 cycle/instruction), whole tick incl. {} DMA transfers (6 encoders + 1 UART) x {} cycles and 6 encoder enables x {} cycles (estimates):",
        JOINTS + 1,
        DMA_TRANSFER_CYCLES,
        ENCODER_PORT_CYCLES
    );
    for (label, raw_on, pose_divider, window_on) in [
        ("recording (window + raw every tick)", true, 0, true),
        ("navigation (pose, every effect, every tick)", false, 1, false),
        ("busiest allowed (window + raw + pose / 2)", true, 2, true),
    ] {
        for request in [
            Request::StreamRaw(StreamRaw { on: raw_on }),
            Request::StreamPose(StreamPose { divider: pose_divider }),
            Request::StartWindow(StartWindow { ticks: if window_on { 4096 } else { 1 } }),
        ] {
            controller.handle(HostFrame { seq: 4, request }, &sampler, &mut sink);
        }
        let work = measure(&mut || {
            let s = sampler.record(&read_all());
            controller.on_tick(&s, &mut sink);
        });
        let cpu = work + dma;
        hprintln!(
            "    {:44} {:6} instr. + DMA, enables = {:6} cycles = {:5.2} % of the tick (budget 5 %); {:5.2} % if the CPU waited on the bus",
            label,
            work,
            cpu,
            cpu as f64 / tick_cycles * 100.0,
            (work as f64 + bus_us * 1e-6 * CORE_HZ) / tick_cycles * 100.0
        );
    }
    debug::exit(debug::EXIT_SUCCESS);
    loop {
        cortex_m::asm::wfi();
    }
}
