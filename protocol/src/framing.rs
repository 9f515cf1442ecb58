//! Frames on the byte link: COBS( postcard(message) ‖ CRC-16 ) followed by a 0x00 delimiter.
//!
//! The decoder collects bytes up to each delimiter, undoes COBS, checks the CRC over the
//! postcard bytes and only then decodes, so trailing garbage or a flipped bit is a typed error,
//! never a wrong message. After any error it simply starts again at the next delimiter.

use serde::{de::DeserializeOwned, Serialize};

/// Largest encoded message (postcard bytes, before CRC and COBS).
pub const MAX_MESSAGE: usize = 448;
/// Largest frame on the wire: COBS overhead, CRC and delimiter included.
pub const MAX_FRAME: usize = MAX_MESSAGE + 2 + MAX_MESSAGE / 254 + 2 + 1;

/// Table of the frame CRC (CRC-16/IBM-3740, "CCITT-FALSE": polynomial 0x1021, not reflected,
/// initial value 0xFFFF, no final XOR), one entry per byte value.
const CRC16_TABLE: [u16; 256] = {
    let mut table = [0u16; 256];
    let mut i = 0;
    while i < 256 {
        let mut c = (i as u16) << 8;
        let mut k = 0;
        while k < 8 {
            c = if c & 0x8000 != 0 { (c << 1) ^ 0x1021 } else { c << 1 };
            k += 1;
        }
        table[i] = c;
        i += 1;
    }
    table
};

/// Initial value of the frame CRC.
const FRAME_CRC_INIT: u16 = 0xFFFF;

/// The frame CRC with one more byte.
#[inline(always)]
fn frame_crc_step(crc: u16, byte: u8) -> u16 {
    (crc << 8) ^ CRC16_TABLE[((crc >> 8) as u8 ^ byte) as usize]
}

/// CRC-16 over the postcard bytes of a frame (CRC-16/IBM-3740, "CCITT-FALSE"; a test holds it
/// to the `crc` crate's definition). Own table, so the stream frames can update it byte by byte.
pub fn frame_crc(bytes: &[u8]) -> u16 {
    bytes.iter().fold(FRAME_CRC_INIT, |crc, &b| frame_crc_step(crc, b))
}

/// Why a frame was not turned into a message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameError {
    /// The message does not fit [`MAX_MESSAGE`].
    TooLong,
    /// COBS decoding failed.
    Cobs,
    /// Shorter than a CRC.
    TooShort,
    /// CRC mismatch.
    Crc,
    /// CRC fine but the bytes are not a message of the expected type.
    Decode,
}

/// Encode `message` into `out`; returns the frame (delimiter included).
pub fn encode<'a, T: Serialize>(message: &T, out: &'a mut [u8; MAX_FRAME]) -> Result<&'a [u8], FrameError> {
    let mut raw = [0u8; MAX_MESSAGE + 2];
    let used = postcard::to_slice(message, &mut raw[..MAX_MESSAGE]).map_err(|_| FrameError::TooLong)?.len();
    let crc = frame_crc(&raw[..used]);
    raw[used..used + 2].copy_from_slice(&crc.to_le_bytes());
    let n = if used + 2 < 254 {
        cobs_short(&raw[..used + 2], out)
    } else {
        cobs::encode(&raw[..used + 2], &mut out[..MAX_FRAME - 1])
    };
    out[n] = 0;
    Ok(&out[..n + 1])
}

/// A short stream frame written byte by byte in postcard's layout (variant indices and
/// integers as varints, arrays and `u8` as raw bytes, `f32` as 4 little-endian bytes) straight
/// into its wire form: the CRC is updated and COBS applied as each byte arrives, so nothing is
/// copied or scanned twice. The controller sends up to 768 stream frames per second; serde and
/// a second pass cost it several times more. Tests hold each fast path to [`encode`].
struct StreamFrame<'a> {
    out: &'a mut [u8; MAX_FRAME],
    /// Where the current COBS block's code byte goes.
    code_at: usize,
    /// Bytes of `out` written (code byte places included).
    len: usize,
    crc: u16,
}

impl<'a> StreamFrame<'a> {
    /// `DeviceFrame::Stream { seq, item: <variant> }` so far.
    #[inline(always)]
    fn new(seq: u16, variant: u8, out: &'a mut [u8; MAX_FRAME]) -> Self {
        let mut frame = StreamFrame { out, code_at: 0, len: 1, crc: FRAME_CRC_INIT };
        frame.byte(1); // DeviceFrame::Stream
        frame.varint(seq);
        frame.byte(variant);
        frame
    }

    /// Put one COBS-encoded byte. Stream frames are far shorter than 254 bytes, so no block
    /// needs splitting (and `out` has room: a test compares every field at its largest).
    #[inline(always)]
    fn cobs(&mut self, byte: u8) {
        if byte == 0 {
            self.set(self.code_at, (self.len - self.code_at) as u8);
            self.code_at = self.len;
        } else {
            self.set(self.len, byte);
        }
        self.len += 1;
    }

    #[inline(always)]
    fn set(&mut self, at: usize, byte: u8) {
        if let Some(slot) = self.out.get_mut(at) {
            *slot = byte;
        }
    }

    #[inline(always)]
    fn byte(&mut self, byte: u8) {
        self.crc = frame_crc_step(self.crc, byte);
        self.cobs(byte);
    }

    #[inline(always)]
    fn bytes(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.byte(b);
        }
    }

    fn varint(&mut self, mut v: u16) {
        while v >= 0x80 {
            self.byte((v as u8 & 0x7F) | 0x80);
            v >>= 7;
        }
        self.byte(v as u8);
    }

    #[inline(always)]
    fn floats(&mut self, values: &[f32; 3]) {
        for v in values {
            self.bytes(&v.to_le_bytes());
        }
    }

    /// Append the CRC, close the last COBS block and add the delimiter.
    fn seal(mut self) -> &'a [u8] {
        let crc = self.crc;
        for b in crc.to_le_bytes() {
            self.cobs(b);
        }
        self.set(self.code_at, (self.len - self.code_at) as u8);
        self.set(self.len, 0);
        let end = (self.len + 1).min(MAX_FRAME);
        &self.out[..end]
    }
}

/// Encode `DeviceFrame::Stream { seq, item: Stream::Raw(sample) }` without serde.
pub fn encode_raw_sample<'a>(
    seq: u16,
    sample: &crate::messages::RawSample,
    out: &'a mut [u8; MAX_FRAME],
) -> &'a [u8] {
    let mut frame = StreamFrame::new(seq, 0, out); // Stream::Raw
    frame.varint(sample.tick);
    frame.bytes(&sample.packed);
    frame.byte(sample.rejected);
    frame.seal()
}

/// Encode `DeviceFrame::Stream { seq, item: Stream::Pose(pose) }` without serde.
pub fn encode_pose_report<'a>(
    seq: u16,
    pose: &crate::messages::PoseReport,
    out: &'a mut [u8; MAX_FRAME],
) -> &'a [u8] {
    let mut frame = StreamFrame::new(seq, 2, out); // Stream::Pose
    frame.varint(pose.tick);
    frame.byte(pose.valid as u8);
    frame.byte(pose.fresh);
    frame.varint(pose.stale_ticks);
    frame.floats(&pose.position_mm);
    frame.floats(&pose.z_axis);
    frame.floats(&pose.x_axis);
    frame.seal()
}

/// COBS in one pass for inputs shorter than 254 bytes (no 0xFF blocks needed).
fn cobs_short(src: &[u8], dst: &mut [u8]) -> usize {
    let (mut code_at, mut code, mut w) = (0usize, 1u8, 1usize);
    for &b in src {
        if b == 0 {
            dst[code_at] = code;
            code_at = w;
            code = 1;
        } else {
            dst[w] = b;
            code += 1;
        }
        w += 1;
    }
    dst[code_at] = code;
    w
}

/// Encode a frame from the controller: the two per-tick streams by [`encode_raw_sample`] and
/// [`encode_pose_report`], the rest by [`encode`].
pub fn encode_device_frame<'a>(
    frame: &crate::messages::DeviceFrame,
    out: &'a mut [u8; MAX_FRAME],
) -> Result<&'a [u8], FrameError> {
    use crate::messages::{DeviceFrame, Stream};
    match frame {
        DeviceFrame::Stream { seq, item: Stream::Raw(sample) } => Ok(encode_raw_sample(*seq, sample, out)),
        DeviceFrame::Stream { seq, item: Stream::Pose(pose) } => Ok(encode_pose_report(*seq, pose, out)),
        other => encode(other, out),
    }
}

/// Decode one frame's bytes (without the delimiter) into a message.
pub fn decode<T: DeserializeOwned>(frame: &mut [u8]) -> Result<T, FrameError> {
    let n = cobs::decode_in_place(frame).map_err(|_| FrameError::Cobs)?;
    if n < 2 {
        return Err(FrameError::TooShort);
    }
    let (body, crc) = frame[..n].split_at(n - 2);
    if frame_crc(body) != u16::from_le_bytes([crc[0], crc[1]]) {
        return Err(FrameError::Crc);
    }
    postcard::from_bytes(body).map_err(|_| FrameError::Decode)
}

/// Accumulates bytes from the link and yields complete frames.
pub struct Decoder {
    buf: [u8; MAX_FRAME],
    len: usize,
    overflow: bool,
}

impl Default for Decoder {
    fn default() -> Self {
        Decoder { buf: [0; MAX_FRAME], len: 0, overflow: false }
    }
}

impl Decoder {
    /// An empty decoder.
    pub fn new() -> Self {
        Self::default()
    }

    /// Feed one byte; at a delimiter returns the decoded message or why it failed.
    /// Empty frames (two delimiters in a row) are skipped.
    pub fn push<T: DeserializeOwned>(&mut self, byte: u8) -> Option<Result<T, FrameError>> {
        if byte != 0 {
            if self.len < MAX_FRAME {
                self.buf[self.len] = byte;
                self.len += 1;
            } else {
                self.overflow = true;
            }
            return None;
        }
        let (len, overflow) = (self.len, self.overflow);
        self.len = 0;
        self.overflow = false;
        if overflow {
            return Some(Err(FrameError::TooLong));
        }
        if len == 0 {
            return None;
        }
        Some(decode(&mut self.buf[..len]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::joints::{ALL_JOINTS, JOINTS};
    use crate::messages::*;
    use rand::{RngExt, SeedableRng};

    fn samples() -> Vec<DeviceFrame> {
        let window = JointWindow {
            mean_counts: 4_194_303.75,
            std_counts: 1.5,
            min_counts: -3,
            max_counts: 4,
            accepted: 1530,
            rejected: 6,
        };
        let health = EncoderHealth {
            accepted: 10,
            crc_errors: 1,
            error_bits: 2,
            warnings: 3,
            dropouts: 4,
            frame_errors: 5,
            jumps: 6,
        };
        let info = Info {
            firmware: heapless::String::try_from("kincal-fw 0.1.0").unwrap(),
            board: heapless::String::try_from("mps2-an386").unwrap(),
            param_version: 3,
            param_crc: 0xDEAD_BEEF,
            arm_id: heapless::String::try_from("arm-1").unwrap(),
            trust: crate::signed::TrustMode::BuildKey,
            param_signer: [0x5A; 32],
            param_signed_at_unix_s: 1_790_000_000,
            ticks: 99,
            late_ticks: 2,
            encoders: [health; JOINTS],
            reset_cause: ResetCause::Watchdog,
            brownout_mv: 2700,
            param_trace: crate::signed::SetTrace {
                run_sha256: [0xA5; 32],
                validated_at_unix_s: 1_789_000_000,
                valid_until_unix_s: 1_820_000_000,
            },
        };
        let chunk = heapless::Vec::from_slice(&[1, 2, 0, 0, 255]).unwrap();
        let responses = [
            Ok(Response::Hello(HelloReply { version: PROTOCOL_VERSION, schema: SCHEMA_HASH })),
            Ok(Response::Info(info)),
            Ok(Response::Ack),
            Ok(Response::ParamData(ParamData { offset: 48, data: chunk })),
            Err(WireError::VersionMismatch { version: 9, schema: 1 }),
            Err(WireError::ParamInvalid),
        ];
        let mut out: Vec<DeviceFrame> = responses
            .into_iter()
            .enumerate()
            .map(|(i, response)| DeviceFrame::Response { seq: i as u16, response })
            .collect();
        let streams = [
            Stream::Raw(RawSample {
                tick: 65535,
                packed: pack_counts(&[0, 1, 2, 0x3F_FFFF, 5, 6]),
                rejected: 0b10_0001,
            }),
            Stream::Window(WindowReport { ticks: 1536, joints: [window; JOINTS], flagged: true }),
            Stream::Pose(PoseReport {
                tick: 7,
                valid: true,
                fresh: ALL_JOINTS,
                stale_ticks: 0,
                position_mm: [512.5, 12.5, 40.0],
                z_axis: [0.0, 0.0, -1.0],
                x_axis: [1.0, 0.0, 0.0],
            }),
        ];
        out.extend(
            streams.into_iter().enumerate().map(|(i, item)| DeviceFrame::Stream { seq: i as u16, item }),
        );
        out
    }

    fn requests() -> Vec<HostFrame> {
        let chunk = heapless::Vec::from_slice(&[0u8; PARAM_CHUNK]).unwrap();
        [
            Request::Hello(Hello { version: PROTOCOL_VERSION, schema: SCHEMA_HASH }),
            Request::GetInfo(GetInfo),
            Request::StartWindow(StartWindow { ticks: 1536 }),
            Request::StreamRaw(StreamRaw { on: true }),
            Request::StreamPose(StreamPose { divider: 8 }),
            Request::ParamBegin(ParamBegin { len: 500, crc: 7 }),
            Request::ParamChunk(ParamChunk { offset: 96, data: chunk }),
            Request::ParamRead(ParamRead { offset: 0, pending: true }),
            Request::ParamCommit(ParamCommit),
            Request::Reset(Reset),
            Request::SimSetPose(SimSetPose { counts: [1, 2, 3, 4, 5, 0x3F_FFFF] }),
            Request::SimFaults(SimFaults {
                noise_counts: 3,
                crc_errors_per_10k: 100,
                dropouts_per_10k: 5,
                error_bits_per_10k: 1,
                warnings_per_10k: 2,
                unplugged: 0b100,
                crash: Crash::Hang,
            }),
        ]
        .into_iter()
        .enumerate()
        .map(|(i, request)| HostFrame { seq: i as u16, request })
        .collect()
    }

    fn round_trip<T: Serialize + DeserializeOwned + PartialEq + core::fmt::Debug>(m: &T) -> usize {
        let mut out = [0u8; MAX_FRAME];
        let frame = encode(m, &mut out).unwrap().to_vec();
        assert_eq!(frame.iter().filter(|b| **b == 0).count(), 1, "only the delimiter is zero");
        let mut d = Decoder::new();
        let mut got = None;
        for &b in &frame {
            if let Some(r) = d.push::<T>(b) {
                got = Some(r.unwrap());
            }
        }
        assert_eq!(got.as_ref(), Some(m));
        frame.len()
    }

    #[test]
    fn every_message_round_trips() {
        for m in samples() {
            round_trip(&m);
        }
        for m in requests() {
            round_trip(&m);
        }
    }

    #[test]
    fn the_raw_sample_fast_path_matches_the_generic_encoder() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        for _ in 0..20_000 {
            let seq: u16 = rng.random();
            let sample = RawSample {
                tick: rng.random(),
                packed: core::array::from_fn(|_| rng.random()),
                rejected: rng.random_range(0..64),
            };
            let (mut a, mut b) = ([0u8; MAX_FRAME], [0u8; MAX_FRAME]);
            let generic = encode(&DeviceFrame::Stream { seq, item: Stream::Raw(sample) }, &mut a).unwrap();
            assert_eq!(encode_raw_sample(seq, &sample, &mut b), generic);
        }
    }

    #[test]
    fn the_frame_crc_is_crc16_ibm_3740() {
        let reference = crc::Crc::<u16>::new(&crc::CRC_16_IBM_3740);
        assert_eq!(frame_crc(b"123456789"), 0x29B1);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        for len in 0..300 {
            let bytes: Vec<u8> = (0..len).map(|_| rng.random()).collect();
            assert_eq!(frame_crc(&bytes), reference.checksum(&bytes), "{len} bytes");
        }
    }

    /// The stream frames' byte counts the link budget uses are the longest the encoders give.
    #[test]
    fn stream_frames_are_never_longer_than_the_link_budget_assumes() {
        let mut buf = [0u8; MAX_FRAME];
        let raw = RawSample { tick: u16::MAX, packed: [0xFF; 17], rejected: 0xFF };
        assert_eq!(encode_raw_sample(u16::MAX, &raw, &mut buf).len() as u32, RAW_FRAME_MAX_BYTES);
        let big = [f32::from_bits(0xFFFF_FFFF); 3];
        let pose = PoseReport {
            tick: u16::MAX,
            valid: true,
            fresh: 0xFF,
            stale_ticks: u16::MAX,
            position_mm: big,
            z_axis: big,
            x_axis: big,
        };
        assert_eq!(encode_pose_report(u16::MAX, &pose, &mut buf).len() as u32, POSE_FRAME_MAX_BYTES);
        // Zeros make COBS blocks but never more bytes than a frame without zeros.
        let zero = RawSample { tick: 0, packed: [0; 17], rejected: 0 };
        assert!(encode_raw_sample(0, &zero, &mut buf).len() as u32 <= RAW_FRAME_MAX_BYTES);
    }

    #[test]
    fn the_pose_fast_path_matches_the_generic_encoder() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        let mut float = || match rng.random_range(0..4) {
            0 => 0.0,
            1 => f32::from_bits(rng.random()),
            _ => rng.random_range(-2000.0..2000.0),
        };
        for k in 0..20_000u32 {
            let seq = (k as u16).wrapping_mul(40_503);
            let pose = PoseReport {
                tick: (k as u16).wrapping_mul(7919),
                valid: k % 2 == 0,
                fresh: k as u8,
                stale_ticks: (k as u16).wrapping_mul(331),
                position_mm: core::array::from_fn(|_| float()),
                z_axis: core::array::from_fn(|_| float()),
                x_axis: core::array::from_fn(|_| float()),
            };
            let (mut a, mut b) = ([0u8; MAX_FRAME], [0u8; MAX_FRAME]);
            let generic = encode(&DeviceFrame::Stream { seq, item: Stream::Pose(pose) }, &mut a).unwrap();
            assert_eq!(encode_pose_report(seq, &pose, &mut b), generic);
        }
    }

    #[test]
    fn the_largest_info_response_encodes() {
        let info = Info::largest();
        round_trip(&DeviceFrame::Response { seq: u16::MAX, response: Ok(Response::Info(info)) });
    }

    #[test]
    fn a_raw_sample_frame_fits_32_bytes() {
        let raw = DeviceFrame::Stream {
            seq: 65535,
            item: Stream::Raw(RawSample { tick: 65535, packed: [0xFF; 17], rejected: 0x3F }),
        };
        let n = round_trip(&raw);
        assert!(n <= 32, "raw sample frame is {n} bytes");
    }

    /// Random, truncated, bit-flipped and concatenated frames: no panic, every corrupted frame is
    /// an error or (rarely, for random bytes) a valid message, and the frame after it decodes.
    #[test]
    fn decoder_survives_a_million_mutated_frames_and_resyncs() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let messages = samples();
        let encoded: Vec<Vec<u8>> = messages
            .iter()
            .map(|m| {
                let mut out = [0u8; MAX_FRAME];
                encode(m, &mut out).unwrap().to_vec()
            })
            .collect();
        let mut decoder = Decoder::new();
        let (mut errors, mut resynced) = (0u64, 0u64);
        for round in 0..1_000_000u32 {
            let k = rng.random_range(0..encoded.len());
            let mut bad = encoded[k].clone();
            match round % 4 {
                0 => {
                    let i = rng.random_range(0..bad.len() - 1);
                    bad[i] ^= 1 << rng.random_range(0..8u32);
                }
                1 => bad.truncate(rng.random_range(0..bad.len())),
                2 => bad = (0..rng.random_range(1..80)).map(|_| rng.random::<u8>()).collect(),
                _ => {
                    let extra: Vec<u8> =
                        (0..rng.random_range(0..300)).map(|_| rng.random_range(1..=255u8)).collect();
                    bad.splice(0..0, extra);
                }
            }
            for &b in &bad {
                if let Some(Err(_)) = decoder.push::<DeviceFrame>(b) {
                    errors += 1;
                }
            }
            // A delimiter ends whatever the garbage was; the next good frame must decode.
            let _ = decoder.push::<DeviceFrame>(0);
            let good = &encoded[(k + 1) % encoded.len()];
            let mut got = None;
            for &b in good {
                if let Some(r) = decoder.push::<DeviceFrame>(b) {
                    got = Some(r);
                }
            }
            assert_eq!(got, Some(Ok(messages[(k + 1) % messages.len()].clone())), "round {round}");
            resynced += 1;
        }
        assert_eq!(resynced, 1_000_000);
        assert!(errors > 500_000, "corruptions must be caught: {errors}");
    }
}
