//! Controller commands: info, params, upload, stream, record, check.

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand};
use kincal::controller::signing::{fingerprint, utc, StationKey};
use kincal::data::Artefact;
use kincal::model::ArmModel;
use std::path::PathBuf;

#[derive(Args)]
pub struct PortArgs {
    /// Serial device or pty path (/dev/ttyUSB0, /dev/pts/3) or tcp:HOST:PORT.
    #[arg(long)]
    port: String,
}

#[derive(Args)]
pub struct UploadArgs {
    #[command(flatten)]
    port: PortArgs,
    /// The calibrated model (RUN/model.toml).
    model: PathBuf,
    /// The station key that signs the set (`kincal key new`); the controller stores only signed
    /// sets.
    #[arg(long)]
    key: Option<PathBuf>,
    /// Version number of the new set; must be higher than the stored one (default: the stored
    /// version + 1). Older values go back only as a new, higher version.
    #[arg(long)]
    version: Option<u32>,
    /// The arm a model that names none (a nominal, simulated or hand-written model) is for; it
    /// must be the connected controller's. Without it such a model is not uploaded. A model that
    /// names its arm (`[arm] id`, as a calibrated RUN/model.toml does) goes only to that arm.
    #[arg(long = "for-arm", alias = "arm", value_name = "ID")]
    for_arm: Option<String>,
    /// Days the calibration stays valid, counted from its validation (the RUN's date); the
    /// host warns at every connect once they have passed, and `kincal check` re-validates.
    /// Default: no validity period.
    #[arg(long, value_name = "DAYS")]
    valid_days: Option<u32>,
    /// Upload a model with a free parameter on its bound (a value the data pushed there, not a
    /// result: `kincal calibrate` warns of it). Without it such a model is not uploaded.
    #[arg(long)]
    allow_on_bound: bool,
}

#[derive(Subcommand)]
pub enum KeyCommand {
    /// Make a new station key: FILE (secret, owner-only, never printed) and FILE.pub.
    New(KeyNewArgs),
}

#[derive(Args)]
pub struct KeyNewArgs {
    /// The new key file (never replaced).
    #[arg(long)]
    out: PathBuf,
}

pub fn cmd_key_new(a: &KeyNewArgs) -> Result<()> {
    let key = StationKey::create(&a.out)?;
    println!("station key written to {} (owner-only; keep it secret, it is not printed)", a.out.display());
    println!("fingerprint  {}", fingerprint(&key.public_key()));
    println!(
        "public key   {} (also in {}; build it into a real controller with KINCAL_TRUSTED_KEY=… cargo build-stm32)",
        key.public_key_hex(),
        kincal::controller::signing::public_key_path(&a.out).display()
    );
    Ok(())
}

/// Read a station key, printing its warnings.
fn load_key(path: &std::path::Path) -> Result<StationKey> {
    let loaded = StationKey::load(path)?;
    for w in &loaded.warnings {
        eprintln!("{w}");
    }
    Ok(loaded.key)
}

#[derive(Args)]
pub struct StreamArgs {
    #[command(flatten)]
    port: PortArgs,
    /// Stream raw joint angles (default).
    #[arg(long, conflicts_with = "pose")]
    raw: bool,
    /// Stream the calibrated tool pose computed on the controller.
    #[arg(long)]
    pose: bool,
    /// Also write every sample to this CSV file (a new file: an existing one is never replaced;
    /// written as `.NAME.partial` and renamed when the stream stops, Ctrl-C included).
    #[arg(long)]
    csv: Option<PathBuf>,
    /// Stop after this many seconds (default: until Ctrl-C).
    #[arg(long)]
    seconds: Option<f64>,
    /// Also serve the pose to navigation software over OpenIGTLink on [HOST:]PORT (default
    /// 18944 on localhost; 0.0.0.0:18944 for every interface): a TRANSFORM every tick, stamped
    /// with the controller's sample instant.
    #[arg(long, requires = "pose", num_args = 0..=1, default_missing_value = "18944", value_name = "[HOST:]PORT", value_parser = igtl_address)]
    igtl: Option<String>,
    /// Name of the OpenIGTLink transform, PLUS's FromToTo convention.
    #[arg(long, requires = "igtl", default_value = kincal::controller::igtl_server::DEFAULT_NAME)]
    igtl_name: String,
    /// Also send invalid poses to clients that speak header version 2, as TRANSFORMs marked
    /// TransformStatus=INVALID with a NaN matrix (PLUS's SendValidTransformsOnly="false"); by
    /// default an invalid pose sends no transform, only a STATUS message.
    #[arg(long, requires = "igtl")]
    igtl_send_invalid: bool,
}

/// `--igtl` as an address to listen on: a port alone means localhost.
pub fn igtl_address(text: &str) -> Result<String, String> {
    let text = text.trim();
    let addr = if text.parse::<u16>().is_ok() { format!("127.0.0.1:{text}") } else { text.to_string() };
    use std::net::ToSocketAddrs;
    match addr.to_socket_addrs().map(|mut a| a.next()) {
        Ok(Some(_)) => Ok(addr),
        _ => Err(format!("expected PORT or HOST:PORT (e.g. 18944 or 0.0.0.0:18944), found `{text}`")),
    }
}

#[derive(Args)]
pub struct RecordArgs {
    #[command(flatten)]
    touches: TouchArgs,
    /// calibration or validation.
    #[arg(long, default_value = "calibration")]
    purpose: String,
    /// Output folder; the session is OUT/<placement>.json.
    #[arg(long)]
    out: PathBuf,
    /// Repeats of the sequence.
    #[arg(long, default_value_t = 3)]
    repeats: u32,
}

/// What a recording of touches needs, for `record` and `check`.
#[derive(Args)]
pub struct TouchArgs {
    #[command(flatten)]
    port: PortArgs,
    /// Artefact file.
    #[arg(long)]
    artefact: PathBuf,
    /// Placement name, e.g. C_A.
    #[arg(long)]
    placement: String,
    /// Landmark order, comma separated (default: the artefact file's).
    #[arg(long, value_delimiter = ',')]
    order: Vec<String>,
    /// Window per touch, ticks (1536 = 2 s).
    #[arg(long, default_value_t = 1536)]
    window_ticks: u16,
    /// Non-interactive: steps from a JSON script (landmarks, emulated poses, skips;
    /// `kincal emulated-arm script` writes one for the emulated arm).
    #[arg(long)]
    script: Option<PathBuf>,
}

impl TouchArgs {
    /// The artefact and the plan of a recording for `purpose`, `repeats` times, into `out`.
    fn plan(
        &self,
        purpose: &str,
        repeats: u32,
        out: &std::path::Path,
    ) -> Result<(Artefact, kincal::controller::record::Plan)> {
        let artefact = Artefact::load(&self.artefact)?;
        let order = if self.order.is_empty() {
            artefact.landmarks.iter().map(|l| l.id.clone()).collect()
        } else {
            self.order.clone()
        };
        let plan = kincal::controller::record::Plan {
            placement: self.placement.clone(),
            purpose: purpose.into(),
            order,
            repeats,
            window_ticks: self.window_ticks,
            out: out.to_path_buf(),
        };
        Ok((artefact, plan))
    }

    /// Run `f` with the guide of the recording: the script's steps, or the operator at the
    /// keyboard.
    fn guided<R>(
        &self,
        f: impl FnOnce(&mut dyn kincal::controller::record::Guide) -> Result<R>,
    ) -> Result<R> {
        match &self.script {
            Some(path) => f(&mut kincal::controller::record::Script::load(path)?),
            None => f(&mut kincal::controller::record::Operator::default()),
        }
    }
}

/// Open and greet the controller on `port`; warns when the stored calibration's validity has
/// passed.
pub fn connect(port: &PortArgs) -> Result<kincal::controller::link::Link> {
    let mut link = kincal::controller::link::Link::open(&port.port)?;
    link.hello().with_context(|| format!("handshake with the controller on {}", port.port))?;
    let info = link.info()?;
    if let Some(warning) = kincal::controller::traceability::expiry_warning(
        &info.arm_id,
        info.param_version,
        &info.param_trace,
        kincal::controller::traceability::unix_now(),
    ) {
        eprintln!("{warning}");
    }
    Ok(link)
}

/// The stored set's trace, one line each, labelled for `info`'s layout.
fn print_trace(trace: &kincal_protocol::signed::SetTrace, labelled: impl Fn(&str, &str)) {
    for (label, text) in
        kincal::controller::traceability::trace_lines(trace, kincal::controller::traceability::unix_now())
    {
        labelled(label, &text);
    }
}

pub fn cmd_info(a: &PortArgs) -> Result<()> {
    let mut link = connect(a)?;
    let info = link.info()?;
    println!("firmware   {} on {}", info.firmware, info.board);
    println!(
        "protocol   version {} schema {:08x}: matches this host",
        kincal_protocol::messages::PROTOCOL_VERSION,
        kincal_protocol::messages::SCHEMA_HASH
    );
    let trust = match (info.trust, info.param_version) {
        (kincal_protocol::signed::TrustMode::BuildKey, _) => "the station key built into the firmware",
        (kincal_protocol::signed::TrustMode::FirstUse, 0) => {
            "on first use: the first signed set stored pins its key"
        }
        (kincal_protocol::signed::TrustMode::FirstUse, _) => {
            "on first use: the signer of the stored set only"
        }
    };
    println!("arm        {} (signed sets must name it)", info.arm_id);
    println!("trust      {trust}");
    if info.param_version == 0 {
        println!("parameters none stored");
    } else {
        println!("parameters version {} (CRC-32 {:08x})", info.param_version, info.param_crc);
        println!("signed by  {} at {}", fingerprint(&info.param_signer), utc(info.param_signed_at_unix_s));
        print_trace(&info.param_trace, |label, text| println!("{label:<10} {text}"));
    }
    println!("reset      {}", reset_cause_text(info.reset_cause));
    match info.brownout_mv {
        0 => {}
        mv if mv < 2700 => println!(
            "brown-out  reset below {:.1} V: too low for programming flash (needs 2.7 V); set BOR level 3 in the option bytes (README, bring-up)",
            mv as f64 / 1000.0
        ),
        mv => println!("brown-out  reset below {:.1} V", mv as f64 / 1000.0),
    }
    println!("late ticks {} (encoder reads started over a tick late)", info.late_ticks);
    println!(
        "uptime     {} ticks ({:.1} s)",
        info.ticks,
        kincal_protocol::messages::ticks_to_seconds(info.ticks)
    );
    println!("joint  accepted  crc-errors  error-bits  warnings  dropouts  frame-errors  jumps");
    for (j, h) in info.encoders.iter().enumerate() {
        println!(
            "{:>5}  {:>8}  {:>10}  {:>10}  {:>8}  {:>8}  {:>12}  {:>5}",
            j + 1,
            h.accepted,
            h.crc_errors,
            h.error_bits,
            h.warnings,
            h.dropouts,
            h.frame_errors,
            h.jumps
        );
    }
    Ok(())
}

fn reset_cause_text(cause: kincal_protocol::messages::ResetCause) -> &'static str {
    use kincal_protocol::messages::ResetCause;
    match cause {
        ResetCause::PowerOn => "power-on",
        ResetCause::Watchdog => {
            "WATCHDOG: the sampling loop stopped and the watchdog restarted the controller"
        }
        ResetCause::Panic => "PANIC: the firmware panicked and restarted the controller",
        ResetCause::Fault => "FAULT: a processor fault (HardFault) restarted the controller",
        ResetCause::Software => "software (a reset request or the debugger)",
        ResetCause::BrownOut => "BROWN-OUT: the supply fell below the brown-out level",
        ResetCause::Pin => "reset pin",
        ResetCause::Unknown => "unknown (no cause recorded)",
    }
}

/// Time without a stream frame after which `kincal stream` raises an alarm: 16 ticks (21 ms);
/// a stream that stops is reported, never waited on silently.
pub const STREAM_GAP_ALARM_TICKS: u32 = 16;

/// Watches a pose stream for invalid poses and reports each change (which joints, since when).
#[derive(Default)]
struct PoseWatch {
    /// Fresh-joint mask of the invalid poses being reported (None: valid).
    invalid: Option<u8>,
    /// Invalid poses received.
    invalid_poses: u64,
    /// Joints seen stale in any pose (bit j: joint j + 1).
    stale_seen: u8,
}

impl PoseWatch {
    fn see(&mut self, p: &kincal_protocol::messages::PoseReport) {
        if p.valid {
            if self.invalid.take().is_some() {
                println!("tick {}: pose valid again", p.tick);
            }
            return;
        }
        self.invalid_poses += 1;
        self.stale_seen |= !p.fresh & kincal_protocol::joints::ALL_JOINTS;
        if self.invalid != Some(p.fresh) {
            self.invalid = Some(p.fresh);
            println!("tick {}: pose INVALID: {}", p.tick, stale_text(p));
        }
    }
}

/// "joint 3 not read this tick (last good 5 ticks ago)", naming every stale joint.
fn stale_text(p: &kincal_protocol::messages::PoseReport) -> String {
    let joints: Vec<String> = p.stale_joints().map(|j| j.to_string()).collect();
    let age = match p.stale_ticks {
        u16::MAX => "never read since boot".to_string(),
        t => format!("last good {t} ticks ago"),
    };
    format!(
        "joint{} {} not read this tick ({age}); no position",
        if joints.len() == 1 { "" } else { "s" },
        joints.join(", ")
    )
}

/// Joint numbers of a mask (bit j: joint j + 1), space separated (for CSV cells).
fn joint_list(mask: u8) -> String {
    let joints: Vec<String> = (0..kincal_protocol::joints::JOINTS)
        .filter(|j| mask & (1 << j) != 0)
        .map(|j| (j + 1).to_string())
        .collect();
    joints.join(" ")
}

pub fn cmd_params(a: &PortArgs) -> Result<()> {
    let mut link = connect(a)?;
    let blob = link.read_params(false, kincal_protocol::params::MAX_PARAM_BLOB)?;
    if blob.is_empty() {
        println!("no parameters stored");
        return Ok(());
    }
    let Some(signed) = kincal::controller::signing::provenance(&blob) else {
        bail!("the stored parameter set is not signed; this controller does not use it");
    };
    let params = kincal_protocol::params::decode_blob(&signed.blob)
        .map_err(|e| anyhow::anyhow!("the stored parameter blob does not decode: {e:?}"))?;
    eprintln!(
        "version {} for arm {}, signed by {} at {}; signature {}",
        params.version,
        signed.arm_id,
        fingerprint(&signed.signer),
        utc(signed.signed_at_unix_s),
        if signed.signature_valid { "valid (checked here too)" } else { "INVALID (checked here)" }
    );
    print_trace(&signed.trace.unwrap_or_default(), |label, text| eprintln!("{label} {text}"));
    println!("{}", serde_json::to_string_pretty(&params)?);
    if !signed.signature_valid {
        bail!("the stored set's signature does not verify on this host");
    }
    Ok(())
}

pub fn cmd_upload(a: &UploadArgs) -> Result<()> {
    let model = ArmModel::load(&a.model)?;
    let beyond = kincal::model::effects::beyond_controller(&model);
    if !beyond.is_empty() {
        let names: Vec<String> = beyond.iter().map(|p| p.to_string()).collect();
        bail!(
            "{}: the controller cannot evaluate {} (harmonics above the second); nothing was uploaded",
            a.model.display(),
            names.join(", ")
        );
    }
    let on_bounds = kincal::calib::run::parameters_on_bounds(&model);
    if !on_bounds.is_empty() && !a.allow_on_bound {
        bail!(
            "{}: {}: the data pushed {} there, so {} not a result (an effect the model lacks may have leaked \
             in: `kincal diagnose RUN` names it; or widen the bounds in the model's [free] table and calibrate \
             again); pass --allow-on-bound to upload it anyway; nothing was uploaded",
            a.model.display(),
            on_bounds.join(", "),
            if on_bounds.len() == 1 { "it" } else { "them" },
            if on_bounds.len() == 1 { "its value is" } else { "their values are" }
        );
    }
    let Some(key_path) = &a.key else {
        bail!(
            "the controller stores only signed parameter sets: pass --key STATION.key (make one with `kincal key new --out station.key`); nothing was uploaded"
        );
    };
    let key = load_key(key_path)?;
    // Checked before connecting: a bad model never reaches the controller.
    kincal::controller::device::parameter_blob(&model, a.version.unwrap_or(1))
        .with_context(|| format!("{}: parameters", a.model.display()))?;
    use kincal::controller::traceability::{check_upload_arm, unix_now, upload_trace};
    let origin = kincal::trace::run_origin(&a.model)?;
    let trace = upload_trace(&a.model, origin.as_ref(), a.valid_days, unix_now())?;
    let mut link = connect(&a.port)?;
    let started = std::time::Instant::now();
    let info = link.info()?;
    let before = kincal::controller::link::HeldParams { version: info.param_version, crc: info.param_crc };
    check_upload_arm(&a.model, model.arm.as_ref(), a.for_arm.as_deref(), &info.arm_id)?;
    let version = kincal::controller::device::next_version(info.param_version, a.version)
        .map_err(|e| anyhow::anyhow!("{e}; nothing was uploaded"))?;
    let blob = kincal::controller::device::traced_parameter_set(&model, version, &info.arm_id, &key, &trace)
        .with_context(|| format!("{}: parameters version {version}", a.model.display()))?;
    let uploaded = match link.upload(&blob) {
        Ok(u) => u,
        Err(
            e @ kincal::controller::link::LinkError::CommitUnconfirmed {
                after: kincal::controller::link::AfterFailure::Unknown,
                ..
            },
        ) => {
            // Committed or not, nobody knows: neither success (0) nor "not committed" (1).
            eprintln!("error: upload failed: {e}");
            std::process::exit(UPLOAD_UNKNOWN);
        }
        Err(e @ kincal::controller::link::LinkError::CommitUnconfirmed { .. }) => bail!("upload failed: {e}"),
        // The controller's own verdict (signature, identity, version, envelope): the same set
        // would be refused again.
        Err(e @ kincal::controller::link::LinkError::Refused(..)) => {
            bail!("upload refused: {e}. The controller keeps {before}")
        }
        Err(e) => {
            bail!("upload failed: {e}. Nothing was committed: the controller keeps {before}; run the upload again")
        }
    };
    if uploaded.commit_reply_lost {
        eprintln!(
            "the first commit request went unanswered; asked again, the controller confirms the new set"
        );
    }
    let elapsed = started.elapsed().as_secs_f64();
    let signed = format!("signed by {} for arm {}", fingerprint(&key.public_key()), info.arm_id);
    match &origin {
        Some(o) => println!(
            "from RUN {}: sha256:{}, validated {}{}",
            o.run.display(),
            kincal::trace::hex(&o.sha256),
            utc(o.validated_at_unix_s),
            if o.date_from_file_time {
                " (summary.json's modification time: this RUN records no validation date)"
            } else {
                ""
            }
        ),
        None => println!("not from a RUN: the set carries no RUN hash or validation date"),
    }
    if trace.valid_until_unix_s != 0 {
        println!("valid until {}", utc(trace.valid_until_unix_s));
    }
    if let Some(o) = &origin {
        let arm = kincal::controller::record::connected_arm(&mut link)
            .unwrap_or_else(|_| kincal::trace::ArmIdentity::of(&info.arm_id));
        let recorded = kincal::controller::traceability::upload_record(&arm, &blob)
            .map(|record| kincal::trace::record_upload(&o.run, &record));
        match recorded {
            Some(Ok(())) => println!(
                "recorded in {} (`kincal certificate {}` shows it)",
                o.run.join(kincal::trace::UPLOADS_FILE).display(),
                o.run.display()
            ),
            Some(Err(e)) => {
                eprintln!("warning: the set is stored, but recording the upload in the RUN failed: {e}")
            }
            None => eprintln!(
                "warning: the set is stored, but its record could not be read back from the signed set"
            ),
        }
    }
    // The commit is confirmed: what follows only reports, and its failure changes nothing stored.
    match link.held_params() {
        Ok(now) => println!(
            "uploaded {} bytes ({signed}) in {elapsed:.2} s; the controller now holds {now}, previously {before}",
            blob.len()
        ),
        Err(e) => {
            println!(
                "uploaded {} bytes ({signed}) in {elapsed:.2} s; the controller confirmed the commit of \
                 parameters version {version}, previously {before}",
                blob.len()
            );
            eprintln!(
                "warning: the commit was confirmed, but reading back what the controller holds failed \
                 ({e}); check with `kincal info`"
            );
        }
    }
    Ok(())
}

/// Exit status of `kincal upload` when the commit was sent, its answer lost, and the controller
/// could not be asked what it holds: the new set may or may not be stored (0: committed, 1: not).
pub const UPLOAD_UNKNOWN: i32 = 3;

pub fn cmd_stream(a: &StreamArgs) -> Result<()> {
    use kincal_protocol::messages::{Stream, StreamPose, StreamRaw};
    use std::time::{Duration, Instant};
    if let Some(path) = &a.csv {
        CsvRecording::refuse_existing(path)?;
    }
    let mut link = connect(&a.port)?;
    let info = link.info()?;
    if a.pose && info.param_version == 0 {
        bail!(
            "the controller on {} holds no parameters: no pose to stream (kincal upload first)",
            a.port.port
        );
    }
    let server = match &a.igtl {
        Some(addr) => {
            let options = kincal::controller::igtl_server::ServerOptions {
                name: a.igtl_name.clone(),
                send_invalid: a.igtl_send_invalid,
            };
            let server = kincal::controller::igtl_server::PoseServer::start(addr, options)?;
            println!(
                "OpenIGTLink server on {}: TRANSFORM {} (tool in the arm's base frame, mm) every tick, stamped with the controller's sample instant; in Slicer: OpenIGTLinkIF, a client connector to this host and port",
                server.local_addr(),
                a.igtl_name
            );
            Some(server)
        }
        None => None,
    };
    let mut clock = kincal::controller::pose_stream::PoseClock::new(info.ticks);
    catch_ctrl_c();
    let mut csv = match &a.csv {
        Some(path) => Some(CsvRecording::create(path)?),
        None => None,
    };
    use std::io::Write;
    if let Some(w) = csv.as_mut().map(|c| &mut c.writer) {
        writeln!(
            w,
            "{}",
            if a.pose {
                "seq,tick,valid,stale_joints,stale_ticks,x_mm,y_mm,z_mm,zx,zy,zz,xx,xy,xz,t_s,host_s"
            } else {
                "seq,tick,j1_deg,j2_deg,j3_deg,j4_deg,j5_deg,j6_deg,rejected"
            }
        )?;
    }
    if a.pose {
        link.call(StreamPose { divider: 1 })?;
    } else {
        link.call(StreamRaw { on: true })?;
    }
    let gap_alarm =
        Duration::from_secs_f64(kincal_protocol::messages::ticks_to_seconds(STREAM_GAP_ALARM_TICKS));
    let started = Instant::now();
    let (mut frames, mut alarms) = (0u64, 0u64);
    let mut last_report = started;
    let mut last_frame = Instant::now();
    let mut in_gap = false;
    let mut lost_seen = 0u64;
    let mut watch = PoseWatch::default();
    let mut latest = String::new();
    while !INTERRUPTED.load(std::sync::atomic::Ordering::SeqCst)
        && a.seconds.is_none_or(|s| started.elapsed().as_secs_f64() < s)
    {
        let Some((seq, item)) = link.next_stream(Duration::from_millis(5))? else {
            if !in_gap && last_frame.elapsed() > gap_alarm {
                in_gap = true;
                alarms += 1;
                println!(
                    "ALARM: no stream frame for over {} ticks ({:.0} ms): the controller or the link stopped; no position until it resumes",
                    STREAM_GAP_ALARM_TICKS,
                    last_frame.elapsed().as_secs_f64() * 1e3
                );
            }
            continue;
        };
        if in_gap {
            in_gap = false;
            println!("stream resumed after {:.0} ms", last_frame.elapsed().as_secs_f64() * 1e3);
        }
        last_frame = Instant::now();
        if link.stats.stream_gaps > lost_seen {
            alarms += 1;
            println!("ALARM: {} stream frames lost before frame {seq}", link.stats.stream_gaps - lost_seen);
            lost_seen = link.stats.stream_gaps;
        }
        frames += 1;
        let timed = match &item {
            Stream::Pose(p) => Some(clock.time(seq, *p, Instant::now())),
            _ => None,
        };
        if let (Some(server), Some(pose)) = (&server, &timed) {
            server.publish(pose);
        }
        for event in server.iter().flat_map(|s| s.events()) {
            println!("{event}");
        }
        match &item {
            Stream::Pose(p) => {
                watch.see(p);
                latest = if p.valid {
                    format!("pose {:.3} {:.3} {:.3} mm", p.position_mm[0], p.position_mm[1], p.position_mm[2])
                } else {
                    format!("pose INVALID ({})", stale_text(p))
                };
            }
            Stream::Raw(r) if r.rejected != 0 => {
                latest = format!("rejected joints {}", joint_list(r.rejected))
            }
            _ => latest.clear(),
        }
        if let Some(w) = csv.as_mut().map(|c| &mut c.writer) {
            match item {
                Stream::Raw(r) => {
                    // A rejected joint's count is its last good one: left empty, never written
                    // as this tick's angle.
                    let deg = kincal_protocol::messages::unpack_counts(&r.packed)
                        .map(|c| kincal_protocol::biss::counts_to_deg(c as f64));
                    let cells: Vec<String> = (0..kincal_protocol::joints::JOINTS)
                        .map(|j| if r.rejected & (1 << j) != 0 { String::new() } else { deg[j].to_string() })
                        .collect();
                    writeln!(w, "{seq},{},{},{}", r.tick, cells.join(","), r.rejected)?;
                }
                Stream::Pose(p) => {
                    let (tick, t_s, host_s) = timed.map_or((0, 0.0, 0.0), |t| (t.tick, t.t_s, t.host_s));
                    if p.valid {
                        let [x, y, z] = p.position_mm;
                        let ([zx, zy, zz], [xx, xy, xz]) = (p.z_axis, p.x_axis);
                        writeln!(w, "{seq},{tick},1,,0,{x},{y},{z},{zx},{zy},{zz},{xx},{xy},{xz},{t_s:.6},{host_s:.6}")?
                    } else {
                        let stale = joint_list(!p.fresh & kincal_protocol::joints::ALL_JOINTS);
                        writeln!(w, "{seq},{tick},0,{stale},{},,,,,,,,,,{t_s:.6},{host_s:.6}", p.stale_ticks)?
                    }
                }
                Stream::Window(_) => {}
            }
        }
        if last_report.elapsed().as_secs_f64() >= 1.0 {
            last_report = Instant::now();
            let clients = server.as_ref().map_or(String::new(), |s| {
                let c = s.clients();
                let dropped: u64 = c.iter().map(|c| c.dropped).sum();
                format!("; {} OpenIGTLink clients, {dropped} messages dropped for slow readers", c.len())
            });
            eprintln!(
                "{:.0} frames/s, {} lost, {} corrupt{}{}{clients}",
                frames as f64 / started.elapsed().as_secs_f64(),
                link.stats.stream_gaps,
                link.stats.bad_frames,
                if latest.is_empty() { "" } else { "; " },
                latest
            );
        }
    }
    let _ = link.call(StreamRaw { on: false });
    let _ = link.call(StreamPose { divider: 0 });
    if let Some(c) = csv {
        c.finish()?;
    }
    println!(
        "{frames} frames in {:.1} s ({:.1} Hz), {} lost, {} corrupt, {alarms} alarms",
        started.elapsed().as_secs_f64(),
        frames as f64 / started.elapsed().as_secs_f64(),
        link.stats.stream_gaps,
        link.stats.bad_frames
    );
    if watch.invalid_poses > 0 {
        println!(
            "{} poses INVALID (joints {} not read; the CSV marks them valid = 0 with no position)",
            watch.invalid_poses,
            joint_list(watch.stale_seen)
        );
    }
    Ok(())
}

/// A CSV file being written during a stream: a new file only, written under a temporary name
/// beside it and renamed by [`CsvRecording::finish`] (or when dropped after an error, so what
/// was recorded is kept).
struct CsvRecording {
    writer: std::io::BufWriter<std::fs::File>,
    partial: PathBuf,
    path: PathBuf,
}

impl CsvRecording {
    /// Refuse a path that exists (checked before connecting, so nothing is created on a refusal).
    fn refuse_existing(path: &std::path::Path) -> Result<()> {
        if path.exists() {
            anyhow::bail!(
                "{} exists; kincal never replaces a file with a stream recording: choose a new name or remove it",
                path.display()
            );
        }
        Ok(())
    }

    fn create(path: &std::path::Path) -> Result<CsvRecording> {
        Self::refuse_existing(path)?;
        let name = path.file_name().with_context(|| format!("{} is not a file name", path.display()))?;
        let partial = path.with_file_name(format!(".{}.partial", name.to_string_lossy()));
        let file = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&partial)
            .with_context(|| format!("creating {}", partial.display()))?;
        Ok(CsvRecording { writer: std::io::BufWriter::new(file), partial, path: path.to_path_buf() })
    }

    /// Flush and give the file its name (never over a file that appeared meanwhile).
    fn finish(mut self) -> Result<()> {
        self.keep()
    }

    fn keep(&mut self) -> Result<()> {
        use std::io::Write;
        self.writer.flush().with_context(|| format!("writing {}", self.partial.display()))?;
        std::fs::hard_link(&self.partial, &self.path).with_context(|| {
            format!("naming the recording {} (kept as {})", self.path.display(), self.partial.display())
        })?;
        std::fs::remove_file(&self.partial)
            .with_context(|| format!("removing {}", self.partial.display()))?;
        Ok(())
    }
}

impl Drop for CsvRecording {
    fn drop(&mut self) {
        if self.partial.exists() {
            if let Err(e) = self.keep() {
                eprintln!("{e:#}");
            }
        }
    }
}

/// Set by Ctrl-C while streaming.
pub static INTERRUPTED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

extern "C" fn on_sigint(_: libc::c_int) {
    INTERRUPTED.store(true, std::sync::atomic::Ordering::SeqCst);
}

/// Make Ctrl-C stop a stream cleanly instead of killing the process.
pub fn catch_ctrl_c() {
    #[cfg(unix)]
    // SAFETY: the handler only stores to an atomic flag (async-signal-safe).
    unsafe {
        libc::signal(libc::SIGINT, on_sigint as *const () as libc::sighandler_t);
    }
}

pub fn cmd_record(a: &RecordArgs) -> Result<()> {
    let (artefact, plan) = a.touches.plan(&a.purpose, a.repeats, &a.out)?;
    let mut link = connect(&a.touches.port)?;
    let done = a
        .touches
        .guided(|guide| Ok(kincal::controller::record::record(&mut link, &artefact, &plan, guide)?))?;
    println!(
        "{}: {} measured now, {} resumed from disk, {} skipped, {} re-taken → {}{}",
        plan.placement,
        done.measured,
        done.resumed,
        done.skipped,
        done.retakes,
        plan.session_path().display(),
        done.arm.map_or(String::new(), |arm| format!(" (recorded on arm {arm})"))
    );
    Ok(())
}

#[derive(Args)]
pub struct CheckArgs {
    #[command(flatten)]
    touches: TouchArgs,
    /// A new folder for the check: its session OUT/<placement>.json and its result OUT/check.json
    /// (a check measures afresh: an earlier check is never judged again or replaced).
    #[arg(long)]
    out: PathBuf,
    /// Repeats of the sequence (at least 2: the repeats give the floor the error is judged
    /// against).
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(2..=20))]
    repeats: u32,
}

/// Exit status of `kincal check` when the arm does not hold its calibration.
pub const CHECK_DOES_NOT_HOLD: i32 = 2;
/// Exit status of `kincal check` when the touches decide neither way.
pub const CHECK_CANNOT_TELL: i32 = 3;

pub fn cmd_check(a: &CheckArgs) -> Result<()> {
    use kincal::controller::check::{check, Verdict};
    let (artefact, plan) = a.touches.plan(kincal::data::Purpose::Validation.as_str(), a.repeats, &a.out)?;
    let mut link = connect(&a.touches.port)?;
    let result = a.touches.guided(|guide| Ok(check(&mut link, &artefact, &plan, guide)?))?;
    println!("arm        {}", result.arm);
    println!("parameters version {} signed by {}", result.param_version, result.signer);
    print_trace(&result.trace, |label, text| println!("{label:<10} {text}"));
    println!(
        "check      {} touches at {}, {} distances → {}",
        result.touches,
        a.touches.placement,
        result.distances,
        a.out.join("check.json").display()
    );
    println!("{}: {}", result.verdict.to_string().to_uppercase(), result.sentence());
    match result.verdict {
        Verdict::Holds => Ok(()),
        Verdict::DoesNotHold => std::process::exit(CHECK_DOES_NOT_HOLD),
        Verdict::CannotTell => std::process::exit(CHECK_CANNOT_TELL),
    }
}
