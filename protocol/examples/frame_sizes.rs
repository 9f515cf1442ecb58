//! Prints the encoded size of each frame type (COBS, CRC and delimiter included), worst case.
use kincal_protocol::framing::{encode, MAX_FRAME};
use kincal_protocol::joints::{ALL_JOINTS, JOINTS};
use kincal_protocol::messages::*;

fn size<T: serde::Serialize>(m: &T) -> usize {
    let mut out = [0u8; MAX_FRAME];
    match encode(m, &mut out) {
        Ok(f) => f.len(),
        Err(e) => panic!("a frame does not encode: {e:?}"),
    }
}

fn main() {
    let stream = |item| DeviceFrame::Stream { seq: u16::MAX, item };
    let joint = JointWindow {
        mean_counts: 4_194_303.999,
        std_counts: 123.4,
        min_counts: -100_000,
        max_counts: 100_000,
        accepted: 4096,
        rejected: 4096,
    };
    let info = Info::largest();
    let rows = [
        (
            "raw sample (stream)",
            size(&stream(Stream::Raw(RawSample { tick: u16::MAX, packed: [0xFF; 17], rejected: 0x3F }))),
        ),
        (
            "pose (stream)",
            size(&stream(Stream::Pose(PoseReport {
                tick: u16::MAX,
                valid: true,
                fresh: ALL_JOINTS,
                stale_ticks: u16::MAX,
                position_mm: [1e3; 3],
                z_axis: [1.0; 3],
                x_axis: [1.0; 3],
            }))),
        ),
        (
            "window (stream)",
            size(&stream(Stream::Window(WindowReport {
                ticks: 4096,
                joints: [joint; JOINTS],
                flagged: true,
            }))),
        ),
        (
            "info (response)",
            size(&DeviceFrame::Response { seq: u16::MAX, response: Ok(Response::Info(info)) }),
        ),
        (
            "parameter chunk (request)",
            size(&HostFrame {
                seq: u16::MAX,
                request: Request::ParamChunk(ParamChunk {
                    offset: 1000,
                    data: heapless::Vec::from_slice(&[0xFF; PARAM_CHUNK]).unwrap_or_default(),
                }),
            }),
        ),
    ];
    for (name, n) in rows {
        println!("{name:<28} {n:4} B");
    }
    let raw = rows[0].1;
    let pose = rows[1].1;
    for (what, bytes_per_s) in [
        ("raw stream every tick", raw * TICK_HZ as usize),
        ("pose stream every tick", pose * TICK_HZ as usize),
        ("raw + pose every 2nd tick", (raw + pose / 2) * TICK_HZ as usize),
    ] {
        println!(
            "{what:<28} {bytes_per_s} B/s = {:.0} % of the {LINK_BAUD}-baud link ({LINK_BYTES_PER_S} B/s)",
            bytes_per_s as f64 / LINK_BYTES_PER_S as f64 * 100.0
        );
    }
}
