//! The protocol state machine: requests in, responses and streams out. Board independent.

use crate::encoders::{Sample, Sampler};
use crate::flash::{FlashError, ParamStore};
use crate::kinematics::Kinematics;
use crate::trust::{Provenance, Trust};
use crate::window::Window;
use embedded_storage::nor_flash::NorFlash;
use kincal_protocol::messages::{
    pack_counts, stream_bytes_per_s, Ack, Answer, DeviceFrame, Endpoint, GetInfo, Hello, HelloReply,
    HostFrame, Info, ParamBegin, ParamChunk, ParamCommit, ParamData, ParamRead, PoseReport, RawSample,
    Request, Reset, ResetCause, Response, SimSetPose, StartWindow, Stream, StreamPose, StreamRaw, WireError,
    ALL_JOINTS, LINK_BYTES_PER_S, MAX_WINDOW_TICKS, PARAM_CHUNK, PROTOCOL_VERSION, SCHEMA_HASH, TICK_HZ,
};
use kincal_protocol::params::{ArmParams, BLOB_CRC, MAX_PARAM_BLOB};
use kincal_protocol::signed::{SetTrace, SignatureRefusal};

/// What the board must do after a request.
#[derive(Clone, Debug, PartialEq)]
pub enum Action {
    /// Nothing more.
    None,
    /// Restart the controller (after the response has been sent).
    Reset,
    /// Emulated board: apply this simulation request (already acknowledged).
    Simulate(Request),
    /// A commit passed the cheap checks: take it ([`Controller::take_commit`]), check its
    /// signature with the shared state unlocked ([`PendingCommit::verify`]), then hand the
    /// result to [`Controller::finish_commit`], which answers.
    Verify,
}

/// Commits are refused for this many ticks (1 s) after a set whose signature did not verify:
/// each check costs 10.6 ms of the real board's CPU, so sets with made-up signatures sent
/// back to back could otherwise keep the controller verifying.
pub const SIGNATURE_BACKOFF_TICKS: u32 = TICK_HZ;

/// A commit whose set passed the cheap checks (complete, upload CRC, no back-off): it owns the
/// set and what it is checked against, so the signature is verified without the controller.
pub struct PendingCommit {
    frame: HostFrame,
    upload: Upload,
    trust: Trust,
    stored: Option<(ArmParams, Provenance)>,
}

impl PendingCommit {
    /// Verify the set (signature, key, arm, version, envelope): the slow part of a commit.
    pub fn verify(self) -> VerifiedCommit {
        let set = &self.upload.buf[..self.upload.len];
        let admitted = self.trust.admit(set, self.stored.as_ref().map(|(p, v)| (p, v)));
        VerifiedCommit { pending: self, admitted }
    }
}

/// A commit after its signature check, for [`Controller::finish_commit`].
pub struct VerifiedCommit {
    pending: PendingCommit,
    admitted: Result<(ArmParams, Provenance), WireError>,
}

/// What a request leads to: an answer now, or a commit whose signature is checked first.
#[allow(clippy::large_enum_variant, reason = "returned once per request, never stored")]
enum Reply {
    Now(Result<Response, WireError>, Action),
    Verify,
}

struct Upload {
    len: usize,
    crc: u32,
    received: usize,
    buf: [u8; MAX_PARAM_BLOB],
}

/// Controller state.
pub struct Controller<F: NorFlash> {
    firmware: &'static str,
    board: &'static str,
    simulated: bool,
    hello: bool,
    window: Option<Window>,
    raw: bool,
    pose_divider: u16,
    tick: u32,
    stream_seq: u16,
    upload: Option<Upload>,
    /// The commit request whose upload awaits its signature check ([`Action::Verify`]).
    verifying: Option<HostFrame>,
    /// The last request carried out and its answer: the host repeats a request with the same
    /// sequence number when the answer was lost, and gets this answer again instead of the
    /// request being carried out twice.
    last: Option<(HostFrame, Result<Response, WireError>)>,
    store: ParamStore<F>,
    trust: Trust,
    params: Option<ActiveSet>,
    reset_cause: ResetCause,
    brownout_mv: u16,
    /// Tick of the last signature that did not verify (commits wait [`SIGNATURE_BACKOFF_TICKS`]).
    signature_failed_at: Option<u32>,
}

/// The stored set in use: its parameters, who signed it and its precomputed kinematics.
struct ActiveSet {
    params: ArmParams,
    provenance: Provenance,
    kinematics: Kinematics,
}

impl ActiveSet {
    fn new((params, provenance): (ArmParams, Provenance)) -> Self {
        ActiveSet { params, provenance, kinematics: Kinematics::new(&params) }
    }
}

impl<F: NorFlash> Controller<F> {
    /// A controller on `flash`; loads the stored parameters if they are valid and pass `trust`.
    /// `simulated`: the board accepts the emulated-encoder requests.
    pub fn new(firmware: &'static str, board: &'static str, simulated: bool, trust: Trust, flash: F) -> Self {
        let mut store = ParamStore::mount(flash);
        let mut buf = [0u8; MAX_PARAM_BLOB];
        let params = store.load(&mut buf).and_then(|set| trust.load(set)).map(ActiveSet::new);
        Controller {
            firmware,
            board,
            simulated,
            hello: false,
            window: None,
            raw: false,
            pose_divider: 0,
            tick: 0,
            stream_seq: 0,
            upload: None,
            verifying: None,
            last: None,
            store,
            trust,
            params,
            reset_cause: ResetCause::Unknown,
            brownout_mv: 0,
            signature_failed_at: None,
        }
    }

    /// What the board found at start: why it reset and its brown-out threshold (mV, 0: none to
    /// report), for [`Info`].
    pub fn set_boot(&mut self, reset_cause: ResetCause, brownout_mv: u16) {
        self.reset_cause = reset_cause;
        self.brownout_mv = brownout_mv;
    }

    /// Give the flash back (a reboot keeps what is stored, nothing else).
    pub fn into_flash(self) -> F {
        self.store.into_flash()
    }

    /// The active parameters.
    pub fn params(&self) -> Option<&ArmParams> {
        self.params.as_ref().map(|p| &p.params)
    }

    /// Who signed the active parameters, and when.
    pub fn provenance(&self) -> Option<&Provenance> {
        self.params.as_ref().map(|p| &p.provenance)
    }

    fn stream(&mut self, item: Stream, emit: &mut impl FnMut(&DeviceFrame)) {
        emit(&DeviceFrame::Stream { seq: self.stream_seq, item });
        self.stream_seq = self.stream_seq.wrapping_add(1);
    }

    /// Process one tick's sample.
    pub fn on_tick(&mut self, sample: &Sample, emit: &mut impl FnMut(&DeviceFrame)) {
        self.tick = self.tick.wrapping_add(1);
        let tick = self.tick as u16;
        if let Some(report) = self.window.as_mut().and_then(|w| w.push(&sample.counts, sample.rejected)) {
            self.window = None;
            self.stream(Stream::Window(report), emit);
        }
        if self.raw {
            self.stream(
                Stream::Raw(RawSample {
                    tick,
                    packed: pack_counts(&sample.counts),
                    rejected: sample.rejected,
                }),
                emit,
            );
        }
        if self.pose_divider > 0 && self.tick.is_multiple_of(self.pose_divider as u32) {
            if let Some(active) = &self.params {
                self.stream(Stream::Pose(pose_report(tick, &active.kinematics, sample)), emit);
            }
        }
    }

    /// Answer one request; `sampler`'s counters go into the answer to [`GetInfo`].
    pub fn handle(
        &mut self,
        frame: HostFrame,
        sampler: &Sampler,
        emit: &mut impl FnMut(&DeviceFrame),
    ) -> Action {
        if let Some((done, response)) = &self.last {
            if *done == frame {
                emit(&DeviceFrame::Response { seq: frame.seq, response: response.clone() });
                return Action::None;
            }
        }
        match self.respond(frame.request.clone(), sampler) {
            Reply::Now(response, action) => {
                self.answer(frame, response, emit);
                action
            }
            Reply::Verify => {
                self.verifying = Some(frame);
                Action::Verify
            }
        }
    }

    /// The commit [`Action::Verify`] announced, with its own copy of what it is checked
    /// against; the board verifies it without holding the shared state.
    pub fn take_commit(&mut self) -> Option<PendingCommit> {
        let frame = self.verifying.take()?;
        let upload = self.upload.take()?;
        let stored = self.params.as_ref().map(|a| (a.params, a.provenance));
        Some(PendingCommit { frame, upload, trust: self.trust.clone(), stored })
    }

    /// Send the answer to `frame` and keep it for a repeat.
    fn answer(
        &mut self,
        frame: HostFrame,
        response: Result<Response, WireError>,
        emit: &mut impl FnMut(&DeviceFrame),
    ) {
        let seq = frame.seq;
        // A handshake starts a new session: nothing before it is repeated.
        let hello = matches!(frame.request, Request::Hello(_));
        self.last = (!hello).then(|| (frame, response.clone()));
        emit(&DeviceFrame::Response { seq, response });
    }

    /// Store a verified commit and answer it. A signature that did not verify starts the
    /// back-off; a set stored meanwhile is not rolled back.
    pub fn finish_commit(&mut self, verified: VerifiedCommit, emit: &mut impl FnMut(&DeviceFrame)) {
        let VerifiedCommit { pending, admitted } = verified;
        if admitted == Err(WireError::ParamSignature(SignatureRefusal::BadSignature)) {
            self.signature_failed_at = Some(self.tick);
        }
        let result = admitted.and_then(|admitted| self.commit(&pending, admitted));
        self.answer(pending.frame, typed::<ParamCommit>(result), emit);
    }

    /// Answer a frame that could not be decoded.
    pub fn bad_frame(&mut self, emit: &mut impl FnMut(&DeviceFrame)) {
        emit(&DeviceFrame::Response { seq: u16::MAX, response: Err(WireError::BadFrame) });
    }

    fn respond(&mut self, request: Request, sampler: &Sampler) -> Reply {
        let none = |answer| Reply::Now(answer, Action::None);
        if let Request::Hello(hello) = request {
            return none(typed::<Hello>(self.handshake(hello)));
        }
        if !self.hello {
            return none(Err(WireError::NoHello));
        }
        match request {
            Request::Hello(_) => none(Err(WireError::BadFrame)),
            Request::GetInfo(GetInfo) => none(typed::<GetInfo>(Ok(self.info(sampler)))),
            Request::StartWindow(r) => none(typed::<StartWindow>(self.start_window(r))),
            Request::StreamRaw(StreamRaw { on }) => {
                none(typed::<StreamRaw>(self.set_streams(on, self.pose_divider)))
            }
            Request::StreamPose(StreamPose { divider }) => {
                none(typed::<StreamPose>(self.set_streams(self.raw, divider)))
            }
            Request::ParamBegin(r) => none(typed::<ParamBegin>(self.param_begin(r))),
            Request::ParamChunk(r) => none(typed::<ParamChunk>(self.param_chunk(r))),
            Request::ParamRead(r) => none(typed::<ParamRead>(self.param_read(r))),
            Request::ParamCommit(ParamCommit) => match self.param_commit() {
                Ok(()) => Reply::Verify,
                Err(e) => none(Err(e)),
            },
            Request::Reset(Reset) => Reply::Now(typed::<Reset>(Ok(Ack)), Action::Reset),
            Request::SimSetPose(_)
            | Request::SimFaults(_)
            | Request::SimWaypoint(_)
            | Request::SimPlay(_) => {
                if self.simulated {
                    Reply::Now(typed::<SimSetPose>(Ok(Ack)), Action::Simulate(request))
                } else {
                    none(Err(WireError::NotSupported))
                }
            }
        }
    }

    /// A window or a stream uses this tick's samples.
    fn sampling_in_use(&self) -> bool {
        self.raw || self.pose_divider > 0 || self.window.is_some()
    }

    /// Whether [`Controller::maintain_flash`] has work now: the parameter log's spare sector
    /// needs erasing and nothing samples.
    pub fn flash_maintenance_due(&self) -> bool {
        self.store.spare_needs_erase() && !self.sampling_in_use()
    }

    /// Erase the parameter log's spare sector if that is due (slow: 1–2 s on the real board,
    /// without sampling). Boards call it at start and when idle, after the answers went out.
    pub fn maintain_flash(&mut self) {
        if self.flash_maintenance_due() {
            // A failed erase is tried again next time; a commit that needs it says so.
            let _ = self.store.erase_spare();
        }
    }

    /// Switch the per-tick streams, if the link carries them: frames the link cannot carry would
    /// be dropped, so such settings are refused and the present ones kept.
    fn set_streams(&mut self, raw: bool, pose_divider: u16) -> Result<Ack, WireError> {
        let needed_bytes_per_s = stream_bytes_per_s(raw, pose_divider);
        if needed_bytes_per_s > LINK_BYTES_PER_S {
            return Err(WireError::LinkTooSlow { needed_bytes_per_s, link_bytes_per_s: LINK_BYTES_PER_S });
        }
        self.raw = raw;
        self.pose_divider = pose_divider;
        Ok(Ack)
    }

    fn handshake(&mut self, Hello { version, schema }: Hello) -> Result<HelloReply, WireError> {
        self.hello = version == PROTOCOL_VERSION && schema == SCHEMA_HASH;
        if !self.hello {
            return Err(WireError::VersionMismatch { version: PROTOCOL_VERSION, schema: SCHEMA_HASH });
        }
        Ok(HelloReply { version: PROTOCOL_VERSION, schema: SCHEMA_HASH })
    }

    fn info(&self, sampler: &Sampler) -> Info {
        Info {
            firmware: heapless::String::try_from(self.firmware).unwrap_or_default(),
            board: heapless::String::try_from(self.board).unwrap_or_default(),
            param_version: self.params().map_or(0, |p| p.version),
            param_crc: self.params.as_ref().and(self.store.active()).map_or(0, |s| s.crc),
            arm_id: self.trust.arm_id().clone(),
            trust: self.trust.mode(),
            param_signer: self.provenance().map_or([0; 32], |p| p.signer),
            param_signed_at_unix_s: self.provenance().map_or(0, |p| p.signed_at_unix_s),
            ticks: self.tick,
            late_ticks: sampler.late_ticks,
            encoders: sampler.health,
            reset_cause: self.reset_cause,
            brownout_mv: self.brownout_mv,
            param_trace: self.provenance().map_or(SetTrace::default(), |p| p.trace),
        }
    }

    fn start_window(&mut self, StartWindow { ticks }: StartWindow) -> Result<Ack, WireError> {
        if self.window.is_some() {
            return Err(WireError::Busy);
        }
        if ticks == 0 || ticks > MAX_WINDOW_TICKS {
            return Err(WireError::BadWindowLength);
        }
        self.window = Some(Window::new(ticks));
        Ok(Ack)
    }

    fn param_begin(&mut self, ParamBegin { len, crc }: ParamBegin) -> Result<Ack, WireError> {
        if len as usize > MAX_PARAM_BLOB || len == 0 {
            return Err(WireError::ParamTooLarge);
        }
        self.upload = Some(Upload { len: len as usize, crc, received: 0, buf: [0; MAX_PARAM_BLOB] });
        Ok(Ack)
    }

    fn param_chunk(&mut self, ParamChunk { offset, data }: ParamChunk) -> Result<Ack, WireError> {
        let u = self.upload.as_mut().ok_or(WireError::NoUpload)?;
        let offset = offset as usize;
        if offset != u.received || offset + data.len() > u.len {
            return Err(WireError::ParamOffset);
        }
        u.buf[offset..offset + data.len()].copy_from_slice(&data);
        u.received += data.len();
        Ok(Ack)
    }

    fn param_read(&mut self, ParamRead { offset, pending }: ParamRead) -> Result<ParamData, WireError> {
        let mut stored = [0u8; MAX_PARAM_BLOB];
        let bytes: &[u8] = if pending {
            let u = self.upload.as_ref().ok_or(WireError::NoUpload)?;
            &u.buf[..u.received]
        } else if self.params.is_some() {
            self.store.load(&mut stored).unwrap_or(&[])
        } else {
            // A stored set the controller does not use (unsigned, another arm, a key no longer
            // trusted) is not its parameters: nothing is shown, as `info` shows none.
            &[]
        };
        let from = (offset as usize).min(bytes.len());
        let to = (from + PARAM_CHUNK).min(bytes.len());
        Ok(ParamData { offset, data: heapless::Vec::from_slice(&bytes[from..to]).unwrap_or_default() })
    }

    /// The cheap checks of a commit; the upload stays for [`Controller::take_commit`].
    fn param_commit(&mut self) -> Result<(), WireError> {
        if let Some(at) = self.signature_failed_at {
            let waited = self.tick.wrapping_sub(at);
            if waited < SIGNATURE_BACKOFF_TICKS {
                let retry_after_ms = ((SIGNATURE_BACKOFF_TICKS - waited) * 1000).div_ceil(TICK_HZ);
                return Err(WireError::ParamBackoff { retry_after_ms });
            }
        }
        let u = self.upload.as_ref().ok_or(WireError::NoUpload)?;
        if u.received != u.len {
            return Err(WireError::ParamIncomplete);
        }
        if BLOB_CRC.checksum(&u.buf[..u.len]) != u.crc {
            self.upload = None;
            return Err(WireError::ParamInvalid);
        }
        Ok(())
    }

    /// Store a set [`Trust::admit`] admitted (signed by a trusted key for this arm, newer than
    /// the stored set, inside the physical envelope) and make it active.
    fn commit(
        &mut self,
        pending: &PendingCommit,
        admitted: (ArmParams, Provenance),
    ) -> Result<Ack, WireError> {
        if let Some(active) = &self.params {
            // Checked against the set active when the commit began; a newer one stored since
            // is not rolled back.
            if pending.stored.as_ref().map(|(p, _)| p.version) != Some(active.params.version) {
                return Err(WireError::ParamRollback {
                    stored: active.params.version,
                    offered: admitted.0.version,
                });
            }
        }
        // Erasing stops the CPU on the real board: never while something samples.
        self.store.store(&pending.upload.buf[..pending.upload.len], !self.sampling_in_use()).map_err(
            |e| match e {
                FlashError::SpareNotErased => WireError::FlashBusy,
                _ => WireError::FlashWrite,
            },
        )?;
        self.params = Some(ActiveSet::new(admitted));
        Ok(Ack)
    }
}

/// The pose of this tick's sample: computed only when every joint's frame of this tick was
/// accepted; otherwise invalid (NaN, never a position from stale counts) naming the joints.
fn pose_report(tick: u16, kinematics: &Kinematics, sample: &Sample) -> PoseReport {
    let fresh = ALL_JOINTS & !sample.rejected;
    if fresh != ALL_JOINTS {
        let nan = [f32::NAN; 3];
        return PoseReport {
            tick,
            valid: false,
            fresh,
            stale_ticks: sample.stale_ticks,
            position_mm: nan,
            z_axis: nan,
            x_axis: nan,
        };
    }
    let pose = kinematics.tool_pose(&sample.counts);
    PoseReport {
        tick,
        valid: true,
        fresh,
        stale_ticks: 0,
        position_mm: pose.position_mm,
        z_axis: pose.z_axis,
        x_axis: pose.x_axis,
    }
}

/// Put endpoint `E`'s answer on the wire: each handler returns its endpoint's response type, so
/// a request cannot be answered with another request's kind of answer.
fn typed<E: Endpoint>(answer: Result<E::Response, WireError>) -> Result<Response, WireError> {
    answer.map(Answer::into_response)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::flash::RamNor;
    use kincal_protocol::params::encode_blob;
    use kincal_protocol::signed::{signing_message, traced_signing_message, TrustMode};

    type Ctl = Controller<RamNor<4096>>;

    const ARM: &str = "arm-1";

    /// A controller for arm [`ARM`] trusting the first key it sees.
    fn controller(flash: RamNor<4096>) -> Ctl {
        Ctl::new("fw", "test", false, Trust::new(ARM, None).unwrap(), flash)
    }

    /// The station key made from `seed`.
    fn station(seed: u8) -> ed25519_compact::KeyPair {
        ed25519_compact::KeyPair::from_seed(ed25519_compact::Seed::new([seed; 32]))
    }

    /// `params` signed by `key` for `arm` at `time`, laid out as the protocol says.
    fn signed_for(params: &ArmParams, key: &ed25519_compact::KeyPair, arm: &str, time: u64) -> Vec<u8> {
        let mut blob = [0u8; MAX_PARAM_BLOB];
        let n = encode_blob(params, &mut blob).unwrap();
        let mut out = [0u8; MAX_PARAM_BLOB];
        let m = signing_message(&blob[..n], arm, time, &key.pk, &mut out).unwrap();
        let mut set = out[..m].to_vec();
        set.extend_from_slice(key.sk.sign(&set, None).as_ref());
        set
    }

    /// `params` signed by station 1 for [`ARM`].
    fn signed(params: &ArmParams) -> Vec<u8> {
        signed_for(params, &station(1), ARM, 1_790_000_000)
    }

    /// Send `request` as frame `seq`; the answer.
    fn ask_as(c: &mut Ctl, seq: u16, request: Request) -> Result<Response, WireError> {
        let mut out = Vec::new();
        if c.handle(HostFrame { seq, request }, &Sampler::default(), &mut |f| out.push(f.clone()))
            == Action::Verify
        {
            let commit = c.take_commit().expect("the announced commit");
            c.finish_commit(commit.verify(), &mut |f| out.push(f.clone()));
        }
        match out.pop() {
            Some(DeviceFrame::Response { seq: s, response }) if s == seq => response,
            other => panic!("unexpected {other:?}"),
        }
    }

    /// Send `request` with a fresh sequence number, as the host does.
    fn ask(c: &mut Ctl, request: Request) -> Result<Response, WireError> {
        static SEQ: std::sync::atomic::AtomicU16 = std::sync::atomic::AtomicU16::new(1);
        ask_as(c, SEQ.fetch_add(1, std::sync::atomic::Ordering::Relaxed), request)
    }

    fn hello(c: &mut Ctl) {
        assert!(ask(c, Request::Hello(Hello { version: PROTOCOL_VERSION, schema: SCHEMA_HASH })).is_ok());
    }

    #[test]
    fn requests_need_a_matching_hello() {
        let mut c = controller(RamNor::new());
        assert_eq!(ask(&mut c, Request::GetInfo(GetInfo)), Err(WireError::NoHello));
        assert_eq!(
            ask(&mut c, Request::Hello(Hello { version: 99, schema: SCHEMA_HASH })),
            Err(WireError::VersionMismatch { version: PROTOCOL_VERSION, schema: SCHEMA_HASH })
        );
        assert_eq!(
            ask(&mut c, Request::Hello(Hello { version: PROTOCOL_VERSION, schema: 1 })),
            Err(WireError::VersionMismatch { version: PROTOCOL_VERSION, schema: SCHEMA_HASH })
        );
        hello(&mut c);
        assert!(matches!(ask(&mut c, Request::GetInfo(GetInfo)), Ok(Response::Info(_))));
        assert_eq!(
            ask(&mut c, Request::SimSetPose(SimSetPose { counts: [0; 6] })),
            Err(WireError::NotSupported)
        );
    }

    #[test]
    fn streams_the_link_cannot_carry_are_refused_and_the_settings_kept() {
        let mut c = controller(RamNor::new());
        hello(&mut c);
        assert_eq!(ask(&mut c, Request::StreamRaw(StreamRaw { on: true })), Ok(Response::Ack));
        let refused = ask(&mut c, Request::StreamPose(StreamPose { divider: 1 }));
        assert_eq!(
            refused,
            Err(WireError::LinkTooSlow { needed_bytes_per_s: 768 * (30 + 53), link_bytes_per_s: 46_080 })
        );
        assert_eq!(ask(&mut c, Request::StreamPose(StreamPose { divider: 2 })), Ok(Response::Ack));
        let mut frames = Vec::new();
        let sample = Sample { counts: [1000; 6], rejected: 0, stale_ticks: 0 };
        for _ in 0..4 {
            c.on_tick(&sample, &mut |f| frames.push(f.clone()));
        }
        // No parameters stored: raw frames only, every tick; the raw stream stayed on.
        assert_eq!(frames.len(), 4);
        assert_eq!(ask(&mut c, Request::StreamRaw(StreamRaw { on: false })), Ok(Response::Ack));
        assert_eq!(ask(&mut c, Request::StreamPose(StreamPose { divider: 1 })), Ok(Response::Ack));
        assert_eq!(
            ask(&mut c, Request::StreamRaw(StreamRaw { on: true })),
            Err(WireError::LinkTooSlow { needed_bytes_per_s: 768 * (30 + 53), link_bytes_per_s: 46_080 })
        );
    }

    #[test]
    fn a_window_takes_only_samples_after_the_request() {
        let mut c = controller(RamNor::new());
        hello(&mut c);
        let mut frames = Vec::new();
        let stale = Sample { counts: [4_000_000; 6], rejected: 0, stale_ticks: 0 };
        for _ in 0..10 {
            c.on_tick(&stale, &mut |f| frames.push(f.clone()));
        }
        assert_eq!(ask(&mut c, Request::StartWindow(StartWindow { ticks: 3 })), Ok(Response::Ack));
        assert_eq!(ask(&mut c, Request::StartWindow(StartWindow { ticks: 3 })), Err(WireError::Busy));
        let fresh = Sample { counts: [1000; 6], rejected: 0, stale_ticks: 0 };
        for _ in 0..3 {
            c.on_tick(&fresh, &mut |f| frames.push(f.clone()));
        }
        let Some(DeviceFrame::Stream { item: Stream::Window(w), .. }) = frames.last() else {
            panic!("{frames:?}")
        };
        assert_eq!(w.joints[0].mean_counts, 1000.0);
        assert_eq!(w.joints[0].accepted, 3);
    }

    #[test]
    fn upload_is_checked_committed_and_survives_a_reboot() {
        let mut c = controller(RamNor::new());
        hello(&mut c);
        let params = ArmParams { version: 42, tcp_mm: [0.0, 0.0, 253.0], ..ArmParams::default() };
        let blob = signed(&params);
        let n = blob.len();
        let crc = BLOB_CRC.checksum(&blob[..n]);
        assert_eq!(ask(&mut c, Request::ParamCommit(ParamCommit)), Err(WireError::NoUpload));
        assert_eq!(
            ask(&mut c, Request::ParamBegin(ParamBegin { len: n as u16, crc: crc ^ 1 })),
            Ok(Response::Ack)
        );
        for (k, chunk) in blob[..n].chunks(PARAM_CHUNK).enumerate() {
            assert_eq!(
                ask(
                    &mut c,
                    Request::ParamChunk(ParamChunk {
                        offset: (k * PARAM_CHUNK) as u16,
                        data: heapless::Vec::from_slice(chunk).unwrap()
                    })
                ),
                Ok(Response::Ack)
            );
        }
        assert_eq!(
            ask(&mut c, Request::ParamCommit(ParamCommit)),
            Err(WireError::ParamInvalid),
            "wrong upload CRC"
        );
        assert!(c.params().is_none());
        assert_eq!(ask(&mut c, Request::ParamBegin(ParamBegin { len: n as u16, crc })), Ok(Response::Ack));
        assert_eq!(
            ask(&mut c, Request::ParamChunk(ParamChunk { offset: 48, data: heapless::Vec::new() })),
            Err(WireError::ParamOffset)
        );
        for (k, chunk) in blob[..n].chunks(PARAM_CHUNK).enumerate() {
            ask(
                &mut c,
                Request::ParamChunk(ParamChunk {
                    offset: (k * PARAM_CHUNK) as u16,
                    data: heapless::Vec::from_slice(chunk).unwrap(),
                }),
            )
            .unwrap();
        }
        let Ok(Response::ParamData(ParamData { data, .. })) =
            ask(&mut c, Request::ParamRead(ParamRead { offset: 0, pending: true }))
        else {
            panic!()
        };
        assert_eq!(&data[..], &blob[..PARAM_CHUNK.min(n)]);
        assert_eq!(ask(&mut c, Request::ParamCommit(ParamCommit)), Ok(Response::Ack));
        assert_eq!(c.params().map(|p| p.version), Some(42));
        let rebooted = controller(c.store.into_flash());
        assert_eq!(rebooted.params().map(|p| p.version), Some(42));
    }

    fn upload(c: &mut Ctl, params: &ArmParams) -> Result<Response, WireError> {
        upload_set(c, &signed(params))
    }

    /// Upload `set` (any bytes) and commit it.
    fn upload_set(c: &mut Ctl, blob: &[u8]) -> Result<Response, WireError> {
        let n = blob.len();
        ask(c, Request::ParamBegin(ParamBegin { len: n as u16, crc: BLOB_CRC.checksum(&blob[..n]) }))?;
        for (k, chunk) in blob[..n].chunks(PARAM_CHUNK).enumerate() {
            let data = heapless::Vec::from_slice(chunk).unwrap();
            ask(c, Request::ParamChunk(ParamChunk { offset: (k * PARAM_CHUNK) as u16, data }))?;
        }
        ask(c, Request::ParamCommit(ParamCommit))
    }

    /// A pose is streamed as valid only when every joint's frame of this tick was accepted;
    /// otherwise within that same tick it is invalid, carries no position and names the joints.
    #[test]
    fn a_pose_with_a_rejected_or_never_read_joint_is_invalid_the_same_tick() {
        let mut c = controller(RamNor::new());
        hello(&mut c);
        let params = ArmParams { version: 4, tcp_mm: [0.0, 0.0, 253.0], ..ArmParams::default() };
        assert_eq!(upload(&mut c, &params), Ok(Response::Ack));
        assert_eq!(ask(&mut c, Request::StreamPose(StreamPose { divider: 1 })), Ok(Response::Ack));
        let mut sampler = Sampler::default();
        let mut poses = Vec::new();
        let mut tick = |c: &mut Ctl,
                        readings: [Result<kincal_protocol::biss::Reading, crate::biss_master::ReadError>;
                            6]| {
            let sample = sampler.record(&readings);
            c.on_tick(&sample, &mut |f| {
                if let DeviceFrame::Stream { item: Stream::Pose(p), .. } = f {
                    poses.push(*p)
                }
            });
        };
        use crate::biss_master::ReadError;
        use kincal_protocol::biss::{BissError, Reading};
        let good = Ok(Reading { position_counts: 1000, warning: false });
        let lost = Err(ReadError::Frame(BissError::LineHigh));
        // Joint 3 never read since boot.
        tick(&mut c, [good, good, lost, good, good, good]);
        tick(&mut c, [good; 6]);
        tick(&mut c, [good, good, good, good, lost, lost]);
        tick(&mut c, [good, good, good, good, good, lost]);
        tick(&mut c, [good; 6]);
        let summary: Vec<_> = poses.iter().map(|p| (p.valid, p.fresh, p.stale_ticks)).collect();
        assert_eq!(
            summary,
            [
                (false, 0b11_1011, u16::MAX),
                (true, 0x3F, 0),
                (false, 0b00_1111, 1),
                (false, 0b01_1111, 2),
                (true, 0x3F, 0)
            ]
        );
        for p in &poses {
            let finite = p.position_mm.iter().chain(&p.z_axis).chain(&p.x_axis).all(|v| v.is_finite());
            assert_eq!(finite, p.valid, "{p:?}: a position only when valid");
        }
        assert_eq!(poses[2].stale_joints().collect::<Vec<_>>(), [5, 6]);
    }

    /// While a stream runs, a commit that would need a sector erased is refused (the erase
    /// would stop sampling on the real board); once idle the controller erases and commits pass.
    #[test]
    fn commits_while_sampling_never_erase_and_say_so() {
        let mut c = controller(RamNor::new());
        hello(&mut c);
        assert!(!c.flash_maintenance_due(), "a blank device has nothing to erase");
        assert_eq!(ask(&mut c, Request::StreamRaw(StreamRaw { on: true })), Ok(Response::Ack));
        let set = |version| ArmParams { version, tcp_mm: [0.0, 0.0, 253.0], ..ArmParams::default() };
        let mut version = 1;
        let refused = loop {
            match upload(&mut c, &set(version)) {
                Ok(_) => version += 1,
                Err(e) => break e,
            }
            assert!(version < 100, "never needed an erase");
        };
        assert_eq!(refused, WireError::FlashBusy);
        assert_eq!(c.params().map(|p| p.version), Some(version - 1), "the stored set stays active");
        assert!(!c.flash_maintenance_due(), "not while the stream runs");
        c.maintain_flash();
        assert_eq!(upload(&mut c, &set(version)), Err(WireError::FlashBusy), "nothing erased while sampling");
        assert_eq!(ask(&mut c, Request::StreamRaw(StreamRaw { on: false })), Ok(Response::Ack));
        assert!(c.flash_maintenance_due());
        c.maintain_flash();
        assert!(!c.flash_maintenance_due());
        assert_eq!(upload(&mut c, &set(version)), Ok(Response::Ack));
        let flash = c.into_flash();
        assert_eq!(flash.erases, 1);
        let rebooted = controller(flash);
        assert_eq!(rebooted.params().map(|p| p.version), Some(version));
    }

    #[test]
    fn sets_outside_the_envelope_are_refused_with_the_reason_and_not_stored() {
        use kincal_protocol::params::ParamField;
        let mut c = controller(RamNor::new());
        hello(&mut c);
        let good = ArmParams { version: 3, tcp_mm: [0.0, 0.0, 253.0], ..ArmParams::default() };
        assert_eq!(upload(&mut c, &good), Ok(Response::Ack));
        let mut far = good;
        far.version = 77;
        far.joints[1].a_mm = 1e6;
        let Err(WireError::ParamEnvelope(v)) = upload(&mut c, &far) else { panic!("accepted a = 1e6 mm") };
        assert_eq!((v.field, v.joint, v.value), (ParamField::AMm, 2, 1e6));
        let mut zero = good;
        zero.version = 0;
        assert!(matches!(upload(&mut c, &zero), Err(WireError::ParamEnvelope(_))));
        // A version no later set could exceed (no rollback) is refused, not stored.
        let mut last = good;
        last.version = u32::MAX;
        let Err(WireError::ParamEnvelope(v)) = upload(&mut c, &last) else {
            panic!("stored version u32::MAX")
        };
        assert_eq!((v.field, v.value, v.limit), (ParamField::Version, u32::MAX as f64, 2_147_483_648.0));
        assert_eq!(c.params(), Some(&good), "the previous set stays active");
    }

    /// A request repeated with its sequence number (its answer was lost) is answered again, not
    /// carried out twice; the same request with a new number is carried out.
    #[test]
    fn a_repeated_request_is_answered_again_not_carried_out_twice() {
        let mut c = controller(RamNor::new());
        hello(&mut c);
        let params = ArmParams { version: 9, tcp_mm: [0.0, 0.0, 253.0], ..ArmParams::default() };
        let blob = signed(&params);
        let n = blob.len();
        let begin = Request::ParamBegin(ParamBegin { len: n as u16, crc: BLOB_CRC.checksum(&blob[..n]) });
        assert_eq!(ask_as(&mut c, 100, begin), Ok(Response::Ack));
        let chunk = Request::ParamChunk(ParamChunk {
            offset: 0,
            data: heapless::Vec::from_slice(&blob[..PARAM_CHUNK]).unwrap(),
        });
        assert_eq!(ask_as(&mut c, 101, chunk.clone()), Ok(Response::Ack));
        assert_eq!(ask_as(&mut c, 101, chunk.clone()), Ok(Response::Ack), "the repeat gets the answer");
        assert_eq!(ask_as(&mut c, 102, chunk), Err(WireError::ParamOffset), "a new request is carried out");
        let Ok(Response::ParamData(ParamData { data, .. })) =
            ask(&mut c, Request::ParamRead(ParamRead { offset: 0, pending: true }))
        else {
            panic!()
        };
        assert_eq!(data.len(), PARAM_CHUNK, "the chunk was taken once");
    }

    /// Let the back-off after a failed signature pass (one second of ticks).
    fn wait_out_backoff(c: &mut Ctl) {
        let idle = Sample { counts: [0; 6], rejected: 0, stale_ticks: 0 };
        for _ in 0..SIGNATURE_BACKOFF_TICKS {
            c.on_tick(&idle, &mut |_| {});
        }
    }

    /// After a signature that does not verify, commits are refused for a second with the time
    /// to wait, before any signature is checked again (a flood of made-up signatures cannot keep
    /// the CPU verifying); the upload is kept, and the same commit passes once the time is out.
    #[test]
    fn after_a_bad_signature_commits_wait_a_second() {
        let mut c = controller(RamNor::new());
        hello(&mut c);
        assert_eq!(upload_set(&mut c, &signed(&set(1))), Ok(Response::Ack));
        let mut forged = signed(&set(2));
        let last = forged.len() - 1;
        forged[last] ^= 0x40;
        let bad = Err(WireError::ParamSignature(SignatureRefusal::BadSignature));
        assert_eq!(upload_set(&mut c, &forged), bad);
        let idle = Sample { counts: [0; 6], rejected: 0, stale_ticks: 0 };
        for _ in 0..SIGNATURE_BACKOFF_TICKS / 2 {
            c.on_tick(&idle, &mut |_| {});
        }
        // Half a second later: refused without a check, also for a good set.
        assert_eq!(upload_set(&mut c, &forged), Err(WireError::ParamBackoff { retry_after_ms: 500 }));
        assert_eq!(
            upload_set(&mut c, &signed(&set(2))),
            Err(WireError::ParamBackoff { retry_after_ms: 500 })
        );
        for _ in 0..SIGNATURE_BACKOFF_TICKS / 2 - 1 {
            c.on_tick(&idle, &mut |_| {});
        }
        assert_eq!(
            ask(&mut c, Request::ParamCommit(ParamCommit)),
            Err(WireError::ParamBackoff { retry_after_ms: 2 })
        );
        c.on_tick(&idle, &mut |_| {});
        assert_eq!(
            ask(&mut c, Request::ParamCommit(ParamCommit)),
            Ok(Response::Ack),
            "the kept upload is committed"
        );
        assert_eq!(c.params(), Some(&set(2)));
        // Cheap refusals (an untrusted key: no signature check) start no back-off.
        let stranger = signed_for(&set(3), &station(2), ARM, 5);
        assert_eq!(
            upload_set(&mut c, &stranger),
            Err(WireError::ParamSignature(SignatureRefusal::UntrustedKey))
        );
        assert_eq!(upload_set(&mut c, &signed(&set(3))), Ok(Response::Ack));
    }

    /// The signature check runs on the commit's own copy of the set, without the controller:
    /// ticks go on (here nine, the real board's 10.6 ms) and stream poses from the active set
    /// while a commit is being verified; the new set is used from the tick after it is stored.
    #[test]
    fn ticks_go_on_while_a_commit_is_verified() {
        let mut c = controller(RamNor::new());
        hello(&mut c);
        assert_eq!(upload_set(&mut c, &signed(&set(1))), Ok(Response::Ack));
        assert_eq!(ask(&mut c, Request::StreamPose(StreamPose { divider: 1 })), Ok(Response::Ack));
        let mut newer = set(2);
        newer.tcp_mm = [0.0, 0.0, 300.0];
        let blob = signed(&newer);
        ask(
            &mut c,
            Request::ParamBegin(ParamBegin { len: blob.len() as u16, crc: BLOB_CRC.checksum(&blob) }),
        )
        .unwrap();
        for (k, chunk) in blob.chunks(PARAM_CHUNK).enumerate() {
            let data = heapless::Vec::from_slice(chunk).unwrap();
            ask(&mut c, Request::ParamChunk(ParamChunk { offset: (k * PARAM_CHUNK) as u16, data })).unwrap();
        }
        let mut frames = Vec::new();
        let frame = HostFrame { seq: 9_000, request: Request::ParamCommit(ParamCommit) };
        assert_eq!(c.handle(frame, &Sampler::default(), &mut |f| frames.push(f.clone())), Action::Verify);
        let commit = c.take_commit().expect("the commit handed out for its signature check");
        assert!(frames.is_empty(), "answered before the signature was checked");
        let sample = Sample { counts: [1000; 6], rejected: 0, stale_ticks: 0 };
        let mut poses = Vec::new();
        let mut tick = |c: &mut Ctl| {
            c.on_tick(&sample, &mut |f| {
                if let DeviceFrame::Stream { item: Stream::Pose(p), .. } = f {
                    poses.push(*p)
                }
            })
        };
        let verified = std::thread::scope(|scope| {
            let verifying = scope.spawn(|| commit.verify());
            for _ in 0..9 {
                tick(&mut c);
            }
            verifying.join().unwrap()
        });
        assert_eq!(c.params(), Some(&set(1)), "the active set until the new one is stored");
        c.finish_commit(verified, &mut |f| frames.push(f.clone()));
        assert_eq!(frames, [DeviceFrame::Response { seq: 9_000, response: Ok(Response::Ack) }]);
        tick(&mut c);
        assert_eq!(poses.len(), 10);
        assert!(poses.iter().all(|p| p.valid));
        let lengths: Vec<f32> =
            poses.iter().map(|p| p.position_mm.iter().map(|v| v * v).sum::<f32>().sqrt()).collect();
        assert!(lengths[..9].iter().all(|l| *l == lengths[0]), "{lengths:?}");
        assert!(
            (lengths[9] - lengths[0]).abs() > 10.0,
            "the new tool length is used after the commit: {lengths:?}"
        );
        assert_eq!(c.params(), Some(&newer));
    }

    fn set(version: u32) -> ArmParams {
        ArmParams { version, tcp_mm: [0.0, 0.0, 253.0], ..ArmParams::default() }
    }

    /// Unsigned, untrusted, tampered, replayed and other-arm sets are refused with the reason;
    /// the stored set and its provenance stay.
    #[test]
    fn only_newer_sets_signed_by_the_trusted_key_for_this_arm_are_stored() {
        let mut c = controller(RamNor::new());
        hello(&mut c);
        let mut blob = [0u8; MAX_PARAM_BLOB];
        let n = encode_blob(&set(1), &mut blob).unwrap();
        let unsigned = upload_set(&mut c, &blob[..n]);
        assert_eq!(unsigned, Err(WireError::ParamSignature(SignatureRefusal::Unsigned)));
        assert_eq!(c.params(), None, "an unsigned set is not stored, not even the first");
        let first = signed(&set(2));
        assert_eq!(upload_set(&mut c, &first), Ok(Response::Ack), "trust on first use");
        let pinned = *c.provenance().unwrap();
        assert_eq!(pinned.signer, *station(1).pk);
        let refusals = [
            (
                signed_for(&set(3), &station(2), ARM, 5),
                WireError::ParamSignature(SignatureRefusal::UntrustedKey),
            ),
            (
                signed_for(&set(3), &station(1), "arm-2", 5),
                WireError::ParamSignature(SignatureRefusal::WrongArm),
            ),
            (first.clone(), WireError::ParamRollback { stored: 2, offered: 2 }),
            (signed(&set(1)), WireError::ParamRollback { stored: 2, offered: 1 }),
        ];
        for (k, (bad, refusal)) in refusals.into_iter().enumerate() {
            assert_eq!(upload_set(&mut c, &bad), Err(refusal), "case {k}");
        }
        let good = signed(&set(3));
        for at in 0..good.len() {
            // Every byte flipped after signing: refused (most as a bad signature, the magic and
            // padding as unsigned, the key as untrusted).
            let mut bad = good.clone();
            bad[at] ^= 0x01;
            assert!(matches!(upload_set(&mut c, &bad), Err(WireError::ParamSignature(_))), "byte {at}");
            wait_out_backoff(&mut c);
        }
        assert_eq!(c.params(), Some(&set(2)));
        assert_eq!(c.provenance(), Some(&pinned));
        let info = c.info(&Sampler::default());
        assert_eq!((info.arm_id.as_str(), info.trust, info.param_version), (ARM, TrustMode::FirstUse, 2));
        assert_eq!((info.param_signer, info.param_signed_at_unix_s), (*station(1).pk, 1_790_000_000));
        assert_eq!(upload_set(&mut c, &good), Ok(Response::Ack));
        // The pin is the stored set: it survives a reboot.
        let mut rebooted = controller(c.into_flash());
        hello(&mut rebooted);
        assert_eq!(rebooted.params(), Some(&set(3)));
        assert_eq!(
            upload_set(&mut rebooted, &signed_for(&set(4), &station(2), ARM, 5)),
            Err(WireError::ParamSignature(SignatureRefusal::UntrustedKey))
        );
    }

    /// A traced set (`KSG2`) is stored like any other; `info` reports its trace, and it
    /// survives a reboot. Every byte of the trace is covered by the signature. A `KSG1` set
    /// after it reports no trace.
    #[test]
    fn a_traced_set_reports_its_run_and_validity_and_its_trace_is_signed() {
        let trace = SetTrace {
            run_sha256: core::array::from_fn(|k| k as u8),
            validated_at_unix_s: 1_789_000_000,
            valid_until_unix_s: 1_800_000_000,
        };
        let traced = |params: &ArmParams| {
            let mut blob = [0u8; MAX_PARAM_BLOB];
            let n = encode_blob(params, &mut blob).unwrap();
            let mut out = [0u8; MAX_PARAM_BLOB];
            let m = traced_signing_message(&blob[..n], &trace, ARM, 1_790_000_000, &station(1).pk, &mut out)
                .unwrap();
            let mut set = out[..m].to_vec();
            set.extend_from_slice(station(1).sk.sign(&set, None).as_ref());
            (set, n)
        };
        let mut c = controller(RamNor::new());
        hello(&mut c);
        let (first, blob_len) = traced(&set(1));
        for at in blob_len..blob_len + kincal_protocol::signed::TRACE_BYTES {
            let mut bad = first.clone();
            bad[at] ^= 0x01;
            assert_eq!(
                upload_set(&mut c, &bad),
                Err(WireError::ParamSignature(SignatureRefusal::BadSignature)),
                "trace byte {}",
                at - blob_len
            );
            wait_out_backoff(&mut c);
        }
        assert_eq!(c.params(), None);
        assert_eq!(upload_set(&mut c, &first), Ok(Response::Ack));
        assert_eq!(c.info(&Sampler::default()).param_trace, trace);
        let mut rebooted = controller(c.into_flash());
        hello(&mut rebooted);
        assert_eq!(rebooted.info(&Sampler::default()).param_trace, trace, "kept over a reboot");
        assert_eq!(upload_set(&mut rebooted, &signed(&set(2))), Ok(Response::Ack));
        assert!(rebooted.info(&Sampler::default()).param_trace.is_none(), "a KSG1 set carries none");
    }

    /// With a key built in, only that key is trusted, also for the first set; a stored set
    /// signed by another key is not used after a re-flash with a new key.
    #[test]
    fn a_build_time_key_is_the_only_one_trusted() {
        let built_in = Trust::new(ARM, Some(*station(3).pk)).unwrap();
        let mut c = Ctl::new("fw", "test", false, built_in.clone(), RamNor::new());
        hello(&mut c);
        assert_eq!(
            upload_set(&mut c, &signed(&set(1))),
            Err(WireError::ParamSignature(SignatureRefusal::UntrustedKey))
        );
        assert_eq!(upload_set(&mut c, &signed_for(&set(1), &station(3), ARM, 9)), Ok(Response::Ack));
        assert_eq!(c.info(&Sampler::default()).trust, TrustMode::BuildKey);
        let other_key = Trust::new(ARM, Some(*station(4).pk)).unwrap();
        let reflashed = Ctl::new("fw", "test", false, other_key, c.into_flash());
        assert_eq!(reflashed.params(), None);
        let back = Ctl::new("fw", "test", false, built_in, reflashed.into_flash());
        assert_eq!(back.params(), Some(&set(1)));
    }

    /// What `kincal params` reads is what runs: a stored set the controller does not use (another
    /// key built in now) is not shown as its parameters.
    #[test]
    fn the_stored_set_read_back_is_the_one_in_use() {
        let built_in = Trust::new(ARM, Some(*station(3).pk)).unwrap();
        let mut c = Ctl::new("fw", "test", false, built_in, RamNor::new());
        hello(&mut c);
        let set = signed_for(&set(1), &station(3), ARM, 9);
        assert_eq!(upload_set(&mut c, &set), Ok(Response::Ack));
        let read = |c: &mut Ctl| match ask(c, Request::ParamRead(ParamRead { offset: 0, pending: false })) {
            Ok(Response::ParamData(ParamData { data, .. })) => data.to_vec(),
            other => panic!("{other:?}"),
        };
        assert_eq!(read(&mut c), set[..PARAM_CHUNK]);
        let other_key = Trust::new(ARM, Some(*station(4).pk)).unwrap();
        let mut reflashed = Ctl::new("fw", "test", false, other_key, c.into_flash());
        hello(&mut reflashed);
        assert_eq!(reflashed.params(), None);
        assert_eq!(read(&mut reflashed), Vec::<u8>::new(), "a set not in use was read back as stored");
    }

    /// A power cut after every flash operation of a signed commit: after the reboot the
    /// controller uses the old signed set or the new one (with its provenance), and the pinned key
    /// is still the only one trusted. Once inside a sector, once where the log moves back to the
    /// first sector and erases it (on 2 KiB sectors a 658-byte set fills one in 3 commits).
    #[test]
    fn a_power_cut_at_every_step_of_a_signed_commit_keeps_the_old_or_the_new_set() {
        for earlier in [1, 5] {
            let old_version = 4 + earlier;
            let old_set = signed_for(&set(old_version), &station(1), ARM, 100);
            let new_set = signed_for(&set(old_version + 1), &station(1), ARM, 200);
            // (version, time signed) as the rebooted controller reports them.
            let (old, new) = ((Some(old_version), Some(100)), (Some(old_version + 1), Some(200)));
            let mut seen = [false; 2];
            let mut erased_at_commit = false;
            for budget in 0..400 {
                let mut c = controller(RamNor::new());
                hello(&mut c);
                for version in 4..old_version {
                    assert_eq!(upload_set(&mut c, &signed(&set(version))), Ok(Response::Ack));
                }
                assert_eq!(upload_set(&mut c, &old_set), Ok(Response::Ack));
                let mut flash = c.into_flash();
                let erases_before = flash.erases;
                flash.power_budget = Some(budget);
                let mut c = controller(flash);
                hello(&mut c);
                let finished = upload_set(&mut c, &new_set).is_ok();
                let mut flash = c.into_flash();
                erased_at_commit |= flash.erases > erases_before;
                flash.power_budget = None;
                let mut rebooted = controller(flash);
                let got =
                    (rebooted.params().map(|p| p.version), rebooted.provenance().map(|p| p.signed_at_unix_s));
                assert!(got == old || got == new, "{earlier} earlier, budget {budget}: {got:?}");
                assert!(!finished || got == new, "budget {budget}: a finished commit must be active");
                seen[(got == new) as usize] = true;
                hello(&mut rebooted);
                assert_eq!(
                    upload_set(&mut rebooted, &signed_for(&set(99), &station(2), ARM, 5)),
                    Err(WireError::ParamSignature(SignatureRefusal::UntrustedKey)),
                    "{earlier} earlier, budget {budget}: the pin survives"
                );
                if finished {
                    assert!(budget > 0);
                    break;
                }
            }
            assert_eq!(seen, [true, true], "cuts before and after the commit word were tried");
            assert_eq!(erased_at_commit, earlier == 5, "{earlier} earlier: the commit erased a sector");
        }
    }
}
