//! Messages between host and controller.
//!
//! The host sends [`HostFrame`]s (a request with its sequence number); the controller answers
//! each with a [`DeviceFrame::Response`] carrying the same sequence number, and sends streamed
//! data as [`DeviceFrame::Stream`] with its own wrapping counter so the host sees any loss.
//! On connect the host sends [`Request::Hello`] with [`PROTOCOL_VERSION`] and [`SCHEMA_HASH`];
//! a controller with another version or schema answers [`WireError::VersionMismatch`] and the
//! host reports both sides' versions.

use crate::joints::JOINTS;
use postcard_schema::Schema;
use serde::{Deserialize, Serialize};

/// Protocol version; bump on any incompatible change.
pub const PROTOCOL_VERSION: u16 = 5;
/// Largest parameter chunk carried by one message, bytes.
pub const PARAM_CHUNK: usize = 48;
/// Encoder sampling rate of the controller (one tick), Hz.
pub const TICK_HZ: u32 = 768;
/// Longest measurement window, ticks ([`Request::StartWindow`]).
pub const MAX_WINDOW_TICKS: u16 = 4096;
/// Rejected samples per thousand above which the controller flags a window.
pub const MAX_REJECT_PER_1000: u32 = 20;
/// Accepted samples per thousand below which a joint's window mean is not used at all.
pub const MIN_ACCEPTED_PER_1000: u32 = 500;

/// Baud rate of the host link (UART, 8N1: 10 bits on the line per byte).
pub const LINK_BAUD: u32 = 460_800;
/// Bytes per second the host link carries.
pub const LINK_BYTES_PER_S: u32 = LINK_BAUD / 10;
/// Longest raw-sample stream frame on the wire (delimiter included), bytes.
pub const RAW_FRAME_MAX_BYTES: u32 = 30;
/// Longest pose stream frame on the wire (delimiter included), bytes.
pub const POSE_FRAME_MAX_BYTES: u32 = 53;

/// Bytes per second the per-tick streams need: the raw stream if `raw`, and one pose frame every
/// `pose_divider` ticks (0: no pose stream). The controller refuses settings above
/// [`LINK_BYTES_PER_S`] rather than drop frames.
pub fn stream_bytes_per_s(raw: bool, pose_divider: u16) -> u32 {
    let raw_bytes = if raw { TICK_HZ * RAW_FRAME_MAX_BYTES } else { 0 };
    let pose_bytes = match pose_divider {
        0 => 0,
        d => TICK_HZ * POSE_FRAME_MAX_BYTES / d as u32,
    };
    raw_bytes + pose_bytes
}

/// Seconds of `ticks` controller ticks.
pub fn ticks_to_seconds(ticks: u32) -> f64 {
    ticks as f64 / TICK_HZ as f64
}

/// Hash of the wire types' structure (type, field and variant names, and how each is encoded:
/// postcard-schema's FNV-1a over the schema of [`HostFrame`] and [`DeviceFrame`]). Any change to
/// what crosses the wire changes it; comments and formatting do not.
pub const SCHEMA_HASH: u32 = {
    let h = postcard_schema::key::hash::fnv1a64::hash_ty_path::<(HostFrame, DeviceFrame)>("kincal");
    u32::from_le_bytes([h[0] ^ h[4], h[1] ^ h[5], h[2] ^ h[6], h[3] ^ h[7]])
};

/// A request from the host, numbered so its response can be matched.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Schema)]
pub struct HostFrame {
    /// Sequence number chosen by the host, echoed in the response.
    pub seq: u16,
    /// The request.
    pub request: Request,
}

/// What the host can ask: one variant per endpoint, each wrapping the request type of the same
/// name, whose [`Endpoint::Response`] names the answer's type.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Schema)]
pub enum Request {
    /// Version and schema check; must come first.
    Hello(Hello),
    /// Firmware identity, stored parameters and encoder health.
    GetInfo(GetInfo),
    /// Measure a window of fresh samples.
    StartWindow(StartWindow),
    /// Stream every raw sample, or stop.
    StreamRaw(StreamRaw),
    /// Stream the calibrated tool pose, or stop.
    StreamPose(StreamPose),
    /// Start a parameter upload.
    ParamBegin(ParamBegin),
    /// One chunk of the upload.
    ParamChunk(ParamChunk),
    /// Read back part of the pending upload or of the stored blob.
    ParamRead(ParamRead),
    /// Check the pending upload and store it (power-loss safe).
    ParamCommit(ParamCommit),
    /// Restart the controller.
    Reset(Reset),
    /// Emulated board only: pose the emulated encoders.
    SimSetPose(SimSetPose),
    /// Emulated board only: noise and faults of the emulated encoder bus.
    SimFaults(SimFaults),
    /// Emulated board only: one waypoint of the trajectory the emulated arm will follow.
    SimWaypoint(SimWaypoint),
    /// Emulated board only: follow the stored waypoints from a given tick, or stop.
    SimPlay(SimPlay),
}

/// Version and schema check; must come first. Answer: [`HelloReply`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct Hello {
    /// The host's [`PROTOCOL_VERSION`].
    pub version: u16,
    /// The host's [`SCHEMA_HASH`].
    pub schema: u32,
}

/// Firmware identity, stored parameters and encoder health. Answer: [`Info`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct GetInfo;

/// Average the next `ticks` fresh samples (1536 = 2 s at 768 Hz) and stream a
/// [`WindowReport`]. Answer: [`Ack`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct StartWindow {
    /// Samples to average (1..=[`MAX_WINDOW_TICKS`]).
    pub ticks: u16,
}

/// Stream every raw sample ([`RawSample`]) or stop. Answer: [`Ack`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct StreamRaw {
    /// Stream (true) or stop (false).
    pub on: bool,
}

/// Stream the calibrated tool pose ([`PoseReport`]) every `divider` ticks. Answer: [`Ack`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct StreamPose {
    /// Ticks between poses (0 stops).
    pub divider: u16,
}

/// Start a parameter upload of `len` bytes whose CRC-32 is `crc`. Answer: [`Ack`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct ParamBegin {
    /// Blob length, bytes.
    pub len: u16,
    /// CRC-32 (ISO-HDLC) of the blob.
    pub crc: u32,
}

/// One chunk of the upload. Answer: [`Ack`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Schema)]
pub struct ParamChunk {
    /// Offset of the chunk in the blob.
    pub offset: u16,
    /// Bytes.
    pub data: heapless::Vec<u8, PARAM_CHUNK>,
}

/// Read back part of the pending upload (before commit) or of the stored blob.
/// Answer: [`ParamData`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct ParamRead {
    /// Offset, bytes.
    pub offset: u16,
    /// Read the pending upload (true) or the stored parameters (false).
    pub pending: bool,
}

/// Check the pending upload and make it the stored parameters (power-loss safe).
/// Answer: [`Ack`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct ParamCommit;

/// Restart the controller (after the answer has left). Answer: [`Ack`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct Reset;

/// Emulated board only: set the joint positions the emulated encoders report. Answer: [`Ack`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct SimSetPose {
    /// Position of each encoder, counts.
    pub counts: [u32; JOINTS],
}

/// Emulated board only: noise and faults of the emulated encoder bus (default: a clean bus).
/// Answer: [`Ack`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct SimFaults {
    /// Standard deviation of position noise, counts.
    pub noise_counts: u16,
    /// Frames per 10 000 sent with a corrupted CRC.
    pub crc_errors_per_10k: u16,
    /// Frames per 10 000 with no answer.
    pub dropouts_per_10k: u16,
    /// Frames per 10 000 with the error bit set.
    pub error_bits_per_10k: u16,
    /// Frames per 10 000 with the warning bit set.
    pub warnings_per_10k: u16,
    /// Bit j set: joint j + 1's encoder is unplugged (its SLO line floats and the pull-up reads
    /// it high: no encoder answers).
    pub unplugged: u8,
    /// A firmware fault to inject now, to test that the watchdog and the panic handler reset
    /// the controller.
    pub crash: Crash,
}

/// Emulated board only: store waypoint `index` of the trajectory the emulated arm follows
/// ([`crate::trajectory`]). Answer: [`Ack`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct SimWaypoint {
    /// Position in the trajectory (0..[`crate::trajectory::MAX_WAYPOINTS`]).
    pub index: u8,
    /// The waypoint.
    pub waypoint: crate::trajectory::Waypoint,
}

/// Emulated board only: the emulated arm follows waypoints `0..waypoints` ([`SimWaypoint`])
/// from controller tick `start_tick` on ([`Info::ticks`] counts the same ticks); before it, it
/// holds the first waypoint. `waypoints` 0 stops the motion where the arm is; [`SimSetPose`]
/// stops it too. Answer: [`Ack`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct SimPlay {
    /// Waypoints to follow (0: stop).
    pub waypoints: u8,
    /// Controller tick at which the trajectory's time 0 falls.
    pub start_tick: u32,
    /// Start again at the end (the first and last waypoints should be the same pose).
    pub repeat: bool,
}

/// A firmware fault the emulated controller injects on request ([`SimFaults::crash`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum Crash {
    /// No fault.
    #[default]
    None,
    /// Panic in the task serving the host.
    Panic,
    /// The sampling task hangs (spins inside an encoder read, as on a dead DMA or clock).
    Hang,
}

/// A frame from the controller.
// A response can carry an `Info` (see [`Response`]); the frame lives on the stack only while it
// is encoded or decoded, and no_std without alloc cannot box it.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Schema)]
pub enum DeviceFrame {
    /// The answer to the request with sequence number `seq`.
    Response {
        /// The request's sequence number.
        seq: u16,
        /// The answer.
        response: Result<Response, WireError>,
    },
    /// Streamed data; `seq` counts stream frames (wrapping) so gaps show.
    Stream {
        /// Stream frame counter.
        seq: u16,
        /// The data.
        item: Stream,
    },
}

/// Successful answers, one variant per answer type.
// `Info` (~340 bytes with the signer's key and the set's trace) is the large one; no_std without
// alloc cannot box it, and an answer lives on the stack only while it is encoded.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Schema)]
pub enum Response {
    /// Answer to [`Hello`].
    Hello(HelloReply),
    /// Answer to [`GetInfo`].
    Info(Info),
    /// The request was carried out.
    Ack,
    /// Answer to [`ParamRead`].
    ParamData(ParamData),
}

/// The controller's side of the handshake.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct HelloReply {
    /// Controller's protocol version.
    pub version: u16,
    /// Controller's schema hash.
    pub schema: u32,
}

/// The request was carried out (the answer of most endpoints).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Ack;

/// Part of a parameter blob.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Schema)]
pub struct ParamData {
    /// Offset of the bytes.
    pub offset: u16,
    /// Bytes (empty past the end).
    pub data: heapless::Vec<u8, PARAM_CHUNK>,
}

/// Errors that cross the wire.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, Schema)]
pub enum WireError {
    /// Version or schema differ; the controller's are given.
    VersionMismatch {
        /// Controller's protocol version.
        version: u16,
        /// Controller's schema hash.
        schema: u32,
    },
    /// The request frame could not be decoded.
    BadFrame,
    /// A window is already being measured.
    Busy,
    /// The request needs [`Request::Hello`] first.
    NoHello,
    /// Window length out of range (1..=4096 ticks).
    BadWindowLength,
    /// Upload larger than the parameter area.
    ParamTooLarge,
    /// Chunk outside the announced upload, or out of order.
    ParamOffset,
    /// No upload in progress.
    NoUpload,
    /// Upload incomplete at commit.
    ParamIncomplete,
    /// Upload's CRC or content invalid at commit; nothing was stored.
    ParamInvalid,
    /// A value of the uploaded set is outside the physical envelope; nothing was stored.
    ParamEnvelope(crate::params::EnvelopeViolation),
    /// Writing flash failed; the previous parameters are still active.
    FlashWrite,
    /// The parameter flash needs a sector erased first, which the controller does only while
    /// nothing samples; nothing was stored. Stop the streams and windows and commit again.
    FlashBusy,
    /// Only the emulated board supports this request.
    NotSupported,
    /// The set's signature, key or arm identity is refused; nothing was stored.
    ParamSignature(crate::signed::SignatureRefusal),
    /// A signature did not verify less than a second ago: commits wait (each check costs the
    /// controller's CPU); the upload is kept, commit again after the time given.
    ParamBackoff {
        /// Time until commits are taken again, ms.
        retry_after_ms: u32,
    },
    /// The set's version is not higher than the stored one's (no rollback); nothing was stored.
    ParamRollback {
        /// Version of the stored set.
        stored: u32,
        /// Version of the refused set.
        offered: u32,
    },
    /// The streams asked for need more than the host link carries; the settings are unchanged.
    LinkTooSlow {
        /// Bytes per second the asked-for streams need.
        needed_bytes_per_s: u32,
        /// Bytes per second the link carries.
        link_bytes_per_s: u32,
    },
}

/// Controller identity and health.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Schema)]
pub struct Info {
    /// Firmware name and version.
    pub firmware: heapless::String<24>,
    /// Board name.
    pub board: heapless::String<24>,
    /// Version number of the stored parameters (0: none stored).
    pub param_version: u32,
    /// CRC-32 of the stored parameter set (0: none).
    pub param_crc: u32,
    /// This controller's arm identity (signed sets must name it).
    pub arm_id: crate::signed::ArmId,
    /// Which keys the controller trusts.
    pub trust: crate::signed::TrustMode,
    /// Public key of the stored set's signer (all zero: none stored).
    pub param_signer: [u8; crate::signed::PUBLIC_KEY_BYTES],
    /// When the stored set was signed, Unix seconds (0: none stored).
    pub param_signed_at_unix_s: u64,
    /// Ticks since boot.
    pub ticks: u32,
    /// Ticks whose encoder read started more than one tick period late since boot (the
    /// sampling instant was missed).
    pub late_ticks: u32,
    /// Per-joint encoder health since boot.
    pub encoders: [EncoderHealth; JOINTS],
    /// Why the controller last started.
    pub reset_cause: ResetCause,
    /// The brown-out reset threshold the board is set to, millivolts (0: the board has none to
    /// report, e.g. the emulated board). Flash is programmed 32 bits at a time, which needs
    /// at least 2700 mV.
    pub brownout_mv: u16,
    /// Where the stored set comes from: its RUN's hash, validation date and validity (all zero:
    /// none stored, or a set that carries no trace). Added in protocol version 5.
    pub param_trace: crate::signed::SetTrace,
}

impl Info {
    /// The `Info` with every field at its longest encoding: the longest response the controller
    /// sends, for the frame budget ([`crate::framing::MAX_FRAME`]).
    pub fn largest() -> Info {
        fn full<const N: usize>() -> heapless::String<N> {
            let mut text = heapless::String::new();
            while text.push('z').is_ok() {}
            text
        }
        let health = EncoderHealth {
            accepted: u32::MAX,
            crc_errors: u32::MAX,
            error_bits: u32::MAX,
            warnings: u32::MAX,
            dropouts: u32::MAX,
            frame_errors: u32::MAX,
            jumps: u32::MAX,
        };
        Info {
            firmware: full(),
            board: full(),
            param_version: u32::MAX,
            param_crc: u32::MAX,
            arm_id: full(),
            trust: crate::signed::TrustMode::FirstUse,
            param_signer: [0xFF; crate::signed::PUBLIC_KEY_BYTES],
            param_signed_at_unix_s: u64::MAX,
            ticks: u32::MAX,
            late_ticks: u32::MAX,
            encoders: [health; JOINTS],
            reset_cause: ResetCause::Unknown,
            brownout_mv: u16::MAX,
            param_trace: crate::signed::SetTrace {
                run_sha256: [0xFF; 32],
                validated_at_unix_s: u64::MAX,
                valid_until_unix_s: u64::MAX,
            },
        }
    }
}

/// Why the controller last started (reported by [`Info::reset_cause`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub enum ResetCause {
    /// Power was switched on.
    PowerOn,
    /// The watchdog reset a controller whose sampling loop had stopped.
    Watchdog,
    /// The firmware panicked (recorded by the panic handler, which then resets).
    Panic,
    /// A processor fault (HardFault: bad memory access, stack overflow), recorded, then reset.
    Fault,
    /// A reset request ([`Request::Reset`]) or a debugger.
    Software,
    /// The supply fell below the brown-out level.
    BrownOut,
    /// The reset pin was pulled low.
    Pin,
    /// None of the above could be told (no cause recorded).
    #[default]
    Unknown,
}

/// Encoder frame counters of one joint.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct EncoderHealth {
    /// Frames accepted.
    pub accepted: u32,
    /// Frames rejected for a bad CRC.
    pub crc_errors: u32,
    /// Frames rejected for the error bit.
    pub error_bits: u32,
    /// Frames accepted with the warning bit.
    pub warnings: u32,
    /// Frames with no answer (the line stayed high, or low: no encoder or a dead line).
    pub dropouts: u32,
    /// Frames that answered but break the frame format (ACK too early or too long, CDS,
    /// the timeout bits after the CRC).
    pub frame_errors: u32,
    /// Frames with a valid CRC whose count jumped farther from the last good one than the arm
    /// can move in the time between them (rejected like a CRC error).
    pub jumps: u32,
}

/// What the controller streams.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Schema)]
pub enum Stream {
    /// One tick's raw positions.
    Raw(RawSample),
    /// A finished measurement window.
    Window(WindowReport),
    /// Calibrated tool pose.
    Pose(PoseReport),
}

/// Raw positions of one tick: six 22-bit counts packed into 17 bytes (see [`pack_counts`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Schema)]
pub struct RawSample {
    /// Tick number (wrapping).
    pub tick: u16,
    /// Six 22-bit positions, packed big-endian.
    pub packed: [u8; 17],
    /// Bit j set: joint j's frame was rejected this tick (its count repeats the last good one).
    pub rejected: u8,
}

/// A finished measurement window.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Schema)]
pub struct WindowReport {
    /// Ticks requested.
    pub ticks: u16,
    /// Per joint statistics.
    pub joints: [JointWindow; JOINTS],
    /// Some joint had more rejected samples than allowed; do not use the means.
    pub flagged: bool,
}

/// Window statistics of one joint.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, Schema)]
pub struct JointWindow {
    /// Wrap-safe mean position, counts in [0, 2²²), with sub-count resolution.
    pub mean_counts: f64,
    /// Standard deviation, counts.
    pub std_counts: f32,
    /// Smallest sample, counts relative to the mean (≤ 0).
    pub min_counts: i32,
    /// Largest sample, counts relative to the mean (≥ 0).
    pub max_counts: i32,
    /// Samples accepted.
    pub accepted: u16,
    /// Samples rejected.
    pub rejected: u16,
}

/// Calibrated tool pose computed on the controller.
///
/// A pose is valid only when every joint's frame of this very tick was accepted: a joint whose
/// frame was rejected (or that was never read since boot) would put its last good count, or 0,
/// into a plausible but wrong position. An invalid pose carries NaN in the position and the
/// axes, so it cannot be used as one by mistake; [`PoseReport::fresh`] tells which joints
/// failed.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, Schema)]
pub struct PoseReport {
    /// Tick number (wrapping).
    pub tick: u16,
    /// Every joint's count is fresh this tick and the pose was computed from them.
    pub valid: bool,
    /// Bit j set: joint j + 1's frame of this tick was accepted ([`ALL_JOINTS`](crate::joints::ALL_JOINTS) when valid).
    pub fresh: u8,
    /// Ticks since the stalest joint's last accepted frame (0 when valid; `u16::MAX`: some
    /// joint was never read since boot, or longer ago than that).
    pub stale_ticks: u16,
    /// Tool point, mm (NaN when not valid).
    pub position_mm: [f32; 3],
    /// Tool z axis (unit; NaN when not valid).
    pub z_axis: [f32; 3],
    /// Tool x axis (unit; NaN when not valid).
    pub x_axis: [f32; 3],
}

impl PoseReport {
    /// Joint numbers (1-based, base to tip) whose count was not fresh this tick.
    pub fn stale_joints(&self) -> impl Iterator<Item = usize> + '_ {
        (0..JOINTS).filter(|j| self.fresh & (1 << j) == 0).map(|j| j + 1)
    }
}

/// A request type and the type of its answer, as postcard-rpc's endpoints: the controller can
/// only answer a request with its endpoint's response type, and the host gets that type back.
pub trait Endpoint: Into<Request> {
    /// The answer's type.
    type Response: Answer;
    /// The request's name in messages.
    const NAME: &'static str;
}

/// A type a [`Response`] can carry.
pub trait Answer: Sized {
    /// Put it on the wire.
    fn into_response(self) -> Response;
    /// Take it off the wire; `None` when the response holds another type.
    fn from_response(response: Response) -> Option<Self>;
}

macro_rules! answers {
    ($($ty:ty => $variant:ident),* $(,)?) => {$(
        impl Answer for $ty {
            fn into_response(self) -> Response {
                Response::$variant(self)
            }
            fn from_response(response: Response) -> Option<Self> {
                match response {
                    Response::$variant(inner) => Some(inner),
                    _ => None,
                }
            }
        }
    )*};
}
answers!(HelloReply => Hello, Info => Info, ParamData => ParamData);

impl Answer for Ack {
    fn into_response(self) -> Response {
        Response::Ack
    }
    fn from_response(response: Response) -> Option<Self> {
        matches!(response, Response::Ack).then_some(Ack)
    }
}

macro_rules! endpoints {
    ($($request:ident => $answer:ty, $name:literal;)*) => {$(
        impl From<$request> for Request {
            fn from(request: $request) -> Request {
                Request::$request(request)
            }
        }
        impl Endpoint for $request {
            type Response = $answer;
            const NAME: &'static str = $name;
        }
    )*};
}
endpoints! {
    Hello => HelloReply, "hello";
    GetInfo => Info, "info";
    StartWindow => Ack, "measurement window";
    StreamRaw => Ack, "raw stream";
    StreamPose => Ack, "pose stream";
    ParamBegin => Ack, "parameter upload";
    ParamChunk => Ack, "parameter chunk";
    ParamRead => ParamData, "parameter read";
    ParamCommit => Ack, "parameter commit";
    Reset => Ack, "reset";
    SimSetPose => Ack, "emulated pose";
    SimFaults => Ack, "emulated encoder faults";
    SimWaypoint => Ack, "emulated trajectory waypoint";
    SimPlay => Ack, "emulated trajectory start";
}

/// A stream topic: one of the items the controller streams, with its own type.
pub trait Topic: Sized {
    /// The topic's name in messages.
    const NAME: &'static str;
    /// Take it out of a stream frame; `None` for another topic.
    fn from_stream(item: Stream) -> Option<Self>;
}

macro_rules! topics {
    ($($ty:ty => $variant:ident, $name:literal;)*) => {$(
        impl Topic for $ty {
            const NAME: &'static str = $name;
            fn from_stream(item: Stream) -> Option<Self> {
                match item {
                    Stream::$variant(inner) => Some(inner),
                    _ => None,
                }
            }
        }
    )*};
}
topics! {
    RawSample => Raw, "raw samples";
    WindowReport => Window, "measurement windows";
    PoseReport => Pose, "tool poses";
}

impl JointWindow {
    /// Whether enough samples were accepted (at least [`MIN_ACCEPTED_PER_1000`]‰ of `ticks`, and
    /// at least one) for the mean to be used.
    pub fn usable(&self, ticks: u16) -> bool {
        self.accepted > 0 && self.accepted as u32 * 1000 >= MIN_ACCEPTED_PER_1000 * ticks as u32
    }
}

impl core::fmt::Display for WireError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            WireError::VersionMismatch { version, schema } => {
                write!(f, "protocol mismatch (controller version {version}, schema {schema:08x})")
            }
            WireError::BadFrame => f.write_str("the request frame did not decode"),
            WireError::Busy => f.write_str("a window is already being measured"),
            WireError::NoHello => f.write_str("no handshake yet"),
            WireError::BadWindowLength => write!(f, "window length outside 1..={MAX_WINDOW_TICKS} ticks"),
            WireError::ParamTooLarge => f.write_str("parameter set larger than the parameter area"),
            WireError::ParamOffset => f.write_str("parameter chunk out of order"),
            WireError::NoUpload => f.write_str("no parameter upload in progress"),
            WireError::ParamIncomplete => f.write_str("parameter upload incomplete"),
            WireError::ParamInvalid => {
                f.write_str("parameter set damaged (CRC or format); nothing was stored")
            }
            WireError::ParamEnvelope(v) => write!(f, "{v}; nothing was stored"),
            WireError::FlashWrite => f.write_str("writing flash failed; the previous parameters are active"),
            WireError::FlashBusy => f.write_str(
                "the parameter flash must erase a sector first, which the controller does only while \
                 nothing samples; nothing was stored: stop the streams and windows and commit again",
            ),
            WireError::NotSupported => f.write_str("only the emulated controller supports this"),
            WireError::ParamSignature(r) => write!(f, "{r}; nothing was stored"),
            WireError::ParamBackoff { retry_after_ms } => write!(
                f,
                "a parameter set's signature did not verify less than a second ago; commits wait: \
                 nothing was stored, commit again in {retry_after_ms} ms"
            ),
            WireError::ParamRollback { stored, offered } => write!(
                f,
                "parameter version {offered} is not higher than the stored version {stored} (no rollback); \
                 nothing was stored: to put older values back, upload them as version {} or later",
                stored.saturating_add(1)
            ),
            WireError::LinkTooSlow { needed_bytes_per_s, link_bytes_per_s } => write!(
                f,
                "these streams need {needed_bytes_per_s} B/s and the link carries {link_bytes_per_s} B/s \
                 (raw samples every tick and the pose every tick do not fit together: stream the pose \
                 every 2nd tick or stop the raw stream)"
            ),
        }
    }
}

/// Pack six 22-bit counts into 17 bytes (132 bits, big-endian, last 4 bits zero).
pub fn pack_counts(counts: &[u32; JOINTS]) -> [u8; 17] {
    let mut out = [0u8; 17];
    // Bits not yet written sit at the bottom of `pending` (never more than 7 + 22 of them).
    let (mut pending, mut pending_bits, mut at) = (0u32, 0u32, 0usize);
    for &c in counts {
        pending = (pending << 22) | (c & 0x3F_FFFF);
        pending_bits += 22;
        while pending_bits >= 8 {
            pending_bits -= 8;
            if let Some(byte) = out.get_mut(at) {
                *byte = (pending >> pending_bits) as u8;
            }
            at += 1;
        }
    }
    if let Some(byte) = out.get_mut(at) {
        *byte = (pending << (8 - pending_bits)) as u8;
    }
    out
}

/// Unpack what [`pack_counts`] packed.
pub fn unpack_counts(packed: &[u8; 17]) -> [u32; JOINTS] {
    let mut out = [0u32; JOINTS];
    let mut bit = 0usize;
    for c in out.iter_mut() {
        for _ in 0..22 {
            *c = (*c << 1) | ((packed[bit / 8] >> (7 - bit % 8)) & 1) as u32;
            bit += 1;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_pack_and_unpack() {
        let counts = [0, 1, 0x3F_FFFF, 0x2A_AAAA, 0x15_5555, 123_456];
        assert_eq!(unpack_counts(&pack_counts(&counts)), counts);
    }

    /// The layout bit by bit, as documented: joint 1's most significant bit first.
    #[test]
    fn counts_are_packed_big_endian_bit_by_bit() {
        let counts = [0x3F_FFFF, 0, 0x2A_AAAA, 1, 0x20_0000, 0x12_3456];
        let mut expected = [0u8; 17];
        for (bit, value) in counts.iter().flat_map(|c| (0..22).rev().map(move |k| (c >> k) & 1)).enumerate() {
            expected[bit / 8] |= (value as u8) << (7 - bit % 8);
        }
        assert_eq!(pack_counts(&counts), expected);
        assert_eq!(pack_counts(&counts.map(|c| c | 0xFFC0_0000)), expected, "bits above 22 are ignored");
    }

    /// Each endpoint's answer type comes back only from its own kind of response.
    #[test]
    fn answers_are_taken_only_from_their_own_response() {
        fn name<E: Endpoint>(_: &E) -> &'static str {
            E::NAME
        }
        let reply = HelloReply { version: 1, schema: 2 };
        assert_eq!(<Hello as Endpoint>::Response::from_response(reply.into_response()), Some(reply));
        assert_eq!(<GetInfo as Endpoint>::Response::from_response(Response::Ack), None);
        assert_eq!(<ParamCommit as Endpoint>::Response::from_response(Response::Ack), Some(Ack));
        assert_eq!(<ParamRead as Endpoint>::Response::from_response(Response::Ack), None);
        assert_eq!(Request::from(StreamRaw { on: true }), Request::StreamRaw(StreamRaw { on: true }));
        assert_eq!(name(&StartWindow { ticks: 1 }), "measurement window");
    }

    /// The hash follows the structure, not the text: a renamed field or a changed type changes
    /// it, a different comment does not.
    #[test]
    fn schema_hash_follows_the_structure() {
        use postcard_schema::key::hash::fnv1a64::hash_ty_path;
        #[allow(dead_code)]
        mod documented {
            /// One comment.
            #[derive(postcard_schema::Schema)]
            pub struct Window {
                /// Ticks.
                pub ticks: u16,
            }
        }
        #[allow(dead_code)]
        mod other_comment {
            #[derive(postcard_schema::Schema)]
            pub struct Window {
                // Another comment, no doc.
                pub ticks: u16,
            }
        }
        #[allow(dead_code)]
        mod renamed {
            #[derive(postcard_schema::Schema)]
            pub struct Window {
                pub samples: u16,
            }
        }
        #[allow(dead_code)]
        mod widened {
            #[derive(postcard_schema::Schema)]
            pub struct Window {
                pub ticks: u32,
            }
        }
        let base = hash_ty_path::<documented::Window>("t");
        assert_eq!(base, hash_ty_path::<other_comment::Window>("t"));
        assert_ne!(base, hash_ty_path::<renamed::Window>("t"));
        assert_ne!(base, hash_ty_path::<widened::Window>("t"));
        assert_ne!(SCHEMA_HASH, 0);
    }
}
