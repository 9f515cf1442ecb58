//! The protocol state machine: requests in, responses and streams out. Board independent.

use crate::encoders::{Sample, Sampler};
use crate::flash::{FlashError, ParamStore};
use crate::kinematics::Kinematics;
use crate::trust::{Provenance, Trust};
use crate::window::Window;
use embedded_storage::nor_flash::NorFlash;
use kincal_protocol::joints::ALL_JOINTS;
use kincal_protocol::messages::{
    pack_counts, stream_bytes_per_s, Ack, Answer, DeviceFrame, Endpoint, GetInfo, Hello, HelloReply,
    HostFrame, Info, ParamBegin, ParamChunk, ParamCommit, ParamData, ParamRead, PoseReport, RawSample,
    Request, Reset, ResetCause, Response, SimSetPose, StartWindow, Stream, StreamPose, StreamRaw, WireError,
    LINK_BYTES_PER_S, MAX_WINDOW_TICKS, PARAM_CHUNK, PROTOCOL_VERSION, SCHEMA_HASH, TICK_HZ,
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
mod tests;
