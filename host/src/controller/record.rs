//! `kincal record`: the guided measurement sequence of one artefact placement (thesis appendix A).
//!
//! For each landmark (artefact order, or the order given) and repeat, the [`Guide`] gets the
//! operator to the landmark ("attach to M3, then Enter") or poses the emulated arm; the
//! controller measures a window of fresh samples; the mean, spread and rejects are shown and a
//! re-take is offered when the spread or the rejects are too high. A window in which any joint
//! accepted too few samples ([`JointWindow::usable`]) is refused, never stored: the guide re-takes,
//! skips or stops. Every measured landmark is
//! written to `OUT/<placement>.json` (`suta-session/1`) atomically before the next one starts, so
//! an interrupted session loses nothing; started again, it resumes with the first landmark and
//! repeat not yet on disk and never measures one twice. Every session names the arm it was
//! recorded on (the controller's identity, firmware and board, [`ArmIdentity`]); a session is
//! resumed only on the same arm and firmware, so no file holds touches of two arms.

use crate::controller::link::{Link, LinkError};
use crate::data::{Artefact, Measurement, Session, SESSION_FORMAT};
use crate::files::FileError;
use crate::trace::ArmIdentity;
use kincal_protocol::biss::counts_to_deg;
use kincal_protocol::messages::{
    ticks_to_seconds, JointWindow, SimSetPose, StartWindow, WindowReport, WireError, MAX_WINDOW_TICKS,
};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Spread (per-sample standard deviation) above which a re-take is offered, degrees.
pub const RETAKE_STD_DEG: f64 = 0.05;

/// Why recording stopped.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// Talking to the controller failed (what was measured so far is on disk).
    #[error(transparent)]
    Link(#[from] LinkError),
    /// The session file could not be read or written.
    #[error(transparent)]
    Data(#[from] FileError),
    /// The existing session file belongs to another placement or purpose.
    #[error("{path}: holds placement {found_placement:?} ({found_purpose}), not {placement:?} ({purpose}); choose another --out")]
    Mismatch {
        /// The file.
        path: PathBuf,
        /// Placement asked for.
        placement: String,
        /// Purpose asked for.
        purpose: String,
        /// Placement in the file.
        found_placement: String,
        /// Purpose in the file.
        found_purpose: String,
    },
    /// The existing session file was recorded on another arm or firmware.
    #[error(
        "{path}: recorded on {found}, and the connected controller is {connected}: one session holds          one arm's touches; record into another --out"
    )]
    OtherArm {
        /// The file.
        path: PathBuf,
        /// The arm the file names (identity, firmware, board).
        found: String,
        /// The connected controller's.
        connected: String,
    },
    /// The existing session file names no arm, so new touches cannot be added to it.
    #[error(
        "{path}: names no arm (recorded before kincal wrote the arm's identity, or by hand): touches of          arm {connected} cannot be added to it; record into another --out"
    )]
    Unidentified {
        /// The file.
        path: PathBuf,
        /// The connected controller's arm.
        connected: String,
    },
    /// A landmark named in the order is not in the artefact.
    #[error("landmark {0:?} is not in the artefact file")]
    UnknownLandmark(String),
    /// The operator or the script stopped the session.
    #[error("stopped; {0} measurements are saved and the session resumes from there")]
    Stopped(usize),
    /// A window was refused (too few valid samples) and the guide stopped there.
    #[error("{landmark} (repeat {repeat}): {reason}; stopped, {saved} measurements are saved and the session resumes from there")]
    Refused {
        /// Landmark being measured.
        landmark: String,
        /// Its repeat.
        repeat: u32,
        /// Which joints had too few samples.
        reason: String,
        /// Measurements on disk.
        saved: usize,
    },
}

/// What to do at a landmark.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Step {
    /// Measure it.
    Measure,
    /// Skip it (unreachable).
    Skip,
    /// Stop the session here.
    Stop,
}

/// Quality of one window.
#[derive(Clone, Debug)]
pub struct Quality {
    /// Largest per-sample spread over the joints, degrees.
    pub worst_std_deg: f64,
    /// Most rejected samples of any joint.
    pub rejected: u32,
    /// The controller flagged the window (too many rejects).
    pub flagged: bool,
    /// An earlier touch of another landmark in this session with the same angles within the
    /// encoder noise, as (landmark, repeat): the arm did not move, or a bus repeats one frame.
    pub same_as: Option<(String, u32)>,
}

impl Quality {
    /// Whether a re-take should be offered.
    pub fn poor(&self) -> bool {
        self.flagged || self.worst_std_deg > RETAKE_STD_DEG || self.same_as.is_some()
    }

    /// The warning for a touch that repeats another landmark's angles, if it does.
    pub fn same_as_warning(&self, landmark: &str) -> Option<String> {
        self.same_as.as_ref().map(|(other, repeat)| {
            format!(
                "warning: {landmark} has the same six angles as {other} (repeat {repeat}) within the encoder \
                 noise: the arm did not move between them, or a bus repeats one frame"
            )
        })
    }
}

/// Encoder resolution, degrees (22-bit single-turn encoders): two touches closer than a couple
/// of counts on every joint are one reading.
const COUNT_DEG: f64 = 360.0 / (1u32 << 22) as f64;

/// Whether `a` and `b` hold the same angles within the encoder noise on every joint: within
/// three standard errors of their difference (window spread / √samples of each) plus two
/// counts of resolution.
pub fn same_angles(a: &Measurement, b: &Measurement) -> bool {
    let standard_error = |m: &Measurement, k: usize| match (&m.std_deg, m.samples) {
        (Some(std), Some(n)) if n > 0 => std.get(k).copied().unwrap_or(0.0) / (n as f64).sqrt(),
        _ => 0.0,
    };
    a.joints_deg.len() == b.joints_deg.len()
        && a.joints_deg.iter().zip(&b.joints_deg).enumerate().all(|(k, (x, y))| {
            let d = (x - y).rem_euclid(360.0);
            let tolerance = 3.0 * standard_error(a, k).hypot(standard_error(b, k)) + 2.0 * COUNT_DEG;
            d.min(360.0 - d) <= tolerance
        })
}

/// What to do with a measured window.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    /// Store it.
    Accept,
    /// Measure again.
    Retake,
    /// Stop the session (nothing more is stored).
    Stop,
}

/// Brings the arm to each landmark: a person at the keyboard, or a script.
pub trait Guide {
    /// Before measuring `landmark` (repeat `repeat`): get the arm there.
    fn approach(&mut self, link: &mut Link, landmark: &str, repeat: u32) -> Result<Step, RecordError>;
    /// After a usable window: store it, measure again, or stop.
    fn accept(&mut self, landmark: &str, measurement: &Measurement, quality: &Quality) -> Verdict;
    /// A window was refused for `reason` (a joint had too few valid samples): measure again
    /// ([`Step::Measure`]), skip the landmark or stop. By default: stop.
    fn refused(&mut self, _landmark: &str, _reason: &str) -> Step {
        Step::Stop
    }
    /// Where the sequence is, before [`Guide::approach`]: shown in the operator's prompt.
    fn progress(&mut self, _at: Progress) {}
    /// A window of `seconds` is being measured; the returned guard ends any display on drop.
    fn measuring(&mut self, _seconds: f64) -> Option<Box<dyn std::any::Any>> {
        None
    }
}

/// Where a recording is: landmark `landmark` of `landmarks`, repeat `repeat` of `repeats` (all
/// 1-based).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Progress {
    /// Landmark number in the order.
    pub landmark: usize,
    /// Landmarks in the order.
    pub landmarks: usize,
    /// Repeat number.
    pub repeat: u32,
    /// Repeats asked for.
    pub repeats: u32,
}

impl std::fmt::Display for Progress {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "landmark {} of {}, repeat {} of {}",
            self.landmark, self.landmarks, self.repeat, self.repeats
        )
    }
}

/// What one placement's recording needs.
#[derive(Clone, Debug)]
pub struct Plan {
    /// Placement name, e.g. `C_A`.
    pub placement: String,
    /// `calibration` or `validation`.
    pub purpose: String,
    /// Landmark ids in measuring order.
    pub order: Vec<String>,
    /// Repeats of the whole sequence.
    pub repeats: u32,
    /// Window length, ticks (1536 = 2 s).
    pub window_ticks: u16,
    /// Output folder.
    pub out: PathBuf,
}

impl Plan {
    /// The session file of this plan.
    pub fn session_path(&self) -> PathBuf {
        self.out.join(format!("{}.json", self.placement))
    }
}

fn next_window(link: &mut Link, timeout: Duration) -> Result<WindowReport, LinkError> {
    let deadline = Instant::now() + timeout;
    while Instant::now() < deadline {
        if let Some((_, w)) = link.next_on::<WindowReport>(Duration::from_millis(100))? {
            return Ok(w);
        }
    }
    Err(LinkError::Timeout(timeout, "measurement window"))
}

/// Measure one window of fresh samples on the controller. A window still running from an
/// earlier, interrupted session is waited for and discarded first.
pub fn measure_window(link: &mut Link, ticks: u16) -> Result<WindowReport, LinkError> {
    let longest = Duration::from_secs_f64(MAX_WINDOW_SECONDS);
    match link.call(StartWindow { ticks }) {
        Err(LinkError::Refused(_, WireError::Busy)) => {
            next_window(link, longest)?;
            link.call(StartWindow { ticks })?;
        }
        other => {
            other?;
        }
    }
    link.clear_streams();
    next_window(link, Duration::from_secs_f64(ticks_to_seconds(ticks as u32) + 3.0))
}

/// Longest window the controller runs plus margin, seconds.
pub const MAX_WINDOW_SECONDS: f64 = MAX_WINDOW_TICKS as f64 / kincal_protocol::messages::TICK_HZ as f64 + 2.0;

/// Why a window cannot be used, naming each joint with too few accepted samples; `None` when
/// every joint is usable.
pub fn refusal(w: &WindowReport) -> Option<String> {
    let starved: Vec<String> = w
        .joints
        .iter()
        .enumerate()
        .filter(|(_, j)| !JointWindow::usable(j, w.ticks))
        .map(|(k, j)| format!("joint {} accepted {} of {} samples", k + 1, j.accepted, w.ticks))
        .collect();
    (!starved.is_empty())
        .then(|| format!("window refused, too few valid encoder frames: {}", starved.join(", ")))
}

/// Turn a usable window into a session measurement and its quality (check [`refusal`] first).
pub fn to_measurement(landmark: &str, repeat: u32, w: &WindowReport) -> (Measurement, Quality) {
    let joints_deg = w.joints.iter().map(|j| counts_to_deg(j.mean_counts).rem_euclid(360.0)).collect();
    let std_deg: Vec<f64> = w.joints.iter().map(|j| counts_to_deg(j.std_counts as f64)).collect();
    let quality = Quality {
        worst_std_deg: std_deg.iter().cloned().fold(0.0, f64::max),
        rejected: w.joints.iter().map(|j| j.rejected as u32).max().unwrap_or(0),
        flagged: w.flagged,
        same_as: None,
    };
    let samples = w.joints.iter().map(|j| j.accepted as u32).min().unwrap_or(0);
    (
        Measurement {
            landmark: landmark.to_string(),
            repeat,
            joints_deg,
            std_deg: Some(std_deg),
            samples: Some(samples),
            rejected: Some(quality.rejected),
            at_unix_s: None,
        },
        quality,
    )
}

/// The identity of the arm on `link` (its controller's identity, firmware and board).
pub fn connected_arm(link: &mut Link) -> Result<ArmIdentity, LinkError> {
    let info = link.info()?;
    let text = |s: &str| Some(s.trim().to_string()).filter(|s| !s.is_empty());
    Ok(ArmIdentity { id: info.arm_id.to_string(), firmware: text(&info.firmware), board: text(&info.board) })
}

/// Load the session to resume (recorded on `arm`), or start an empty one; either names `arm`.
fn resume(plan: &Plan, artefact: &Artefact, arm: &ArmIdentity) -> Result<Session, RecordError> {
    let path = plan.session_path();
    if !path.exists() {
        return Ok(Session {
            format: SESSION_FORMAT.into(),
            placement: plan.placement.clone(),
            purpose: plan.purpose.clone(),
            measurements: Vec::new(),
            arm: Some(arm.clone()),
        });
    }
    let mut session = Session::load(&path, artefact)?;
    match &session.arm {
        Some(found) if found != arm => {
            return Err(RecordError::OtherArm { path, found: found.to_string(), connected: arm.to_string() })
        }
        None if !session.measurements.is_empty() => {
            return Err(RecordError::Unidentified { path, connected: arm.id.clone() })
        }
        _ => {}
    }
    if session.placement != plan.placement || session.purpose != plan.purpose {
        return Err(RecordError::Mismatch {
            path,
            placement: plan.placement.clone(),
            purpose: plan.purpose.clone(),
            found_placement: session.placement,
            found_purpose: session.purpose,
        });
    }
    session.arm = Some(arm.clone());
    Ok(session)
}

/// Summary of a recording.
#[derive(Clone, Debug, Default)]
pub struct Recorded {
    /// Measurements already on disk when the session started.
    pub resumed: usize,
    /// Measurements taken now.
    pub measured: usize,
    /// Landmarks skipped.
    pub skipped: usize,
    /// Re-takes.
    pub retakes: usize,
    /// The arm the session was recorded on.
    pub arm: Option<ArmIdentity>,
}

/// Run the guided sequence of `plan`, resuming what is on disk.
pub fn record(
    link: &mut Link,
    artefact: &Artefact,
    plan: &Plan,
    guide: &mut dyn Guide,
) -> Result<Recorded, RecordError> {
    if let Some(unknown) = plan.order.iter().find(|id| artefact.index_of(id).is_none()) {
        return Err(RecordError::UnknownLandmark(unknown.clone()));
    }
    std::fs::create_dir_all(&plan.out).map_err(|source| FileError::Io { path: plan.out.clone(), source })?;
    let arm = connected_arm(link)?;
    let mut session = resume(plan, artefact, &arm)?;
    let mut summary =
        Recorded { resumed: session.measurements.len(), arm: Some(arm.clone()), ..Recorded::default() };
    for repeat in 1..=plan.repeats {
        for (k, landmark) in plan.order.iter().enumerate() {
            if session.measurements.iter().any(|m| &m.landmark == landmark && m.repeat == repeat) {
                continue;
            }
            let (landmarks, repeats) = (plan.order.len(), plan.repeats);
            guide.progress(Progress { landmark: k + 1, landmarks, repeat, repeats });
            match guide.approach(link, landmark, repeat)? {
                Step::Skip => {
                    summary.skipped += 1;
                    continue;
                }
                Step::Stop => return Err(RecordError::Stopped(session.measurements.len())),
                Step::Measure => {}
            }
            let measurement = loop {
                let progress = guide.measuring(ticks_to_seconds(plan.window_ticks as u32));
                let window = measure_window(link, plan.window_ticks);
                drop(progress);
                let window = window?;
                if let Some(reason) = refusal(&window) {
                    match guide.refused(landmark, &reason) {
                        Step::Measure => {
                            summary.retakes += 1;
                            continue;
                        }
                        Step::Skip => break None,
                        Step::Stop => {
                            return Err(RecordError::Refused {
                                landmark: landmark.clone(),
                                repeat,
                                reason,
                                saved: session.measurements.len(),
                            })
                        }
                    }
                }
                let (m, mut quality) = to_measurement(landmark, repeat, &window);
                quality.same_as = session
                    .measurements
                    .iter()
                    .find(|earlier| &earlier.landmark != landmark && same_angles(earlier, &m))
                    .map(|earlier| (earlier.landmark.clone(), earlier.repeat));
                match guide.accept(landmark, &m, &quality) {
                    Verdict::Accept => break Some(m),
                    Verdict::Retake => summary.retakes += 1,
                    Verdict::Stop => return Err(RecordError::Stopped(session.measurements.len())),
                }
            };
            let Some(measurement) = measurement else {
                summary.skipped += 1;
                continue;
            };
            let at_unix_s = Some(crate::controller::traceability::unix_now());
            session.measurements.push(Measurement { at_unix_s, ..measurement });
            session.save(&plan.session_path())?;
            summary.measured += 1;
        }
    }
    Ok(summary)
}

/// A scripted session (`--script FILE`): `{"steps":[{"landmark":"M1","repeat":1,
/// "pose_counts":[6 counts]}, {"landmark":"S2","skip":true}, {"stop":true}]}`. `pose_counts`
/// poses the emulated arm; steps are matched by landmark and repeat (repeat defaults to 1).
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct Script {
    /// The steps.
    pub steps: Vec<ScriptStep>,
}

/// One step of a [`Script`].
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct ScriptStep {
    /// Landmark id.
    #[serde(default)]
    pub landmark: String,
    /// Repeat number.
    #[serde(default = "one")]
    pub repeat: u32,
    /// Emulated encoder positions for this touch.
    #[serde(default)]
    pub pose_counts: Option<[u32; 6]>,
    /// Skip this landmark.
    #[serde(default)]
    pub skip: bool,
    /// Stop the session when this landmark comes up.
    #[serde(default)]
    pub stop: bool,
}

fn one() -> u32 {
    1
}

impl Script {
    /// Read a script file.
    pub fn load(path: &Path) -> Result<Script, FileError> {
        let text = std::fs::read_to_string(path)
            .map_err(|source| FileError::Io { path: path.to_owned(), source })?;
        serde_json::from_str(&text)
            .map_err(|e| FileError::Syntax { path: path.to_owned(), message: e.to_string() })
    }
}

impl Guide for Script {
    fn approach(&mut self, link: &mut Link, landmark: &str, repeat: u32) -> Result<Step, RecordError> {
        let Some(step) = self.steps.iter().find(|s| s.landmark == landmark && s.repeat == repeat) else {
            return Ok(Step::Skip);
        };
        if step.stop {
            return Ok(Step::Stop);
        }
        if step.skip {
            return Ok(Step::Skip);
        }
        if let Some(counts) = step.pose_counts {
            link.call(SimSetPose { counts })?;
        }
        Ok(Step::Measure)
    }

    fn accept(&mut self, landmark: &str, _m: &Measurement, q: &Quality) -> Verdict {
        // A script cannot re-take: it stores the touch and says so.
        if let Some(warning) = q.same_as_warning(landmark) {
            eprintln!("{warning}; stored as scripted");
        }
        Verdict::Accept
    }
}

/// A person at the keyboard: prompts on stderr, answers on stdin.
#[derive(Default)]
pub struct Operator {
    /// Where the sequence is, for the prompt.
    at: Option<Progress>,
}

/// A progress bar that fills over the window's duration until dropped.
struct WindowBar {
    bar: indicatif::ProgressBar,
    done: std::sync::Arc<std::sync::atomic::AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl WindowBar {
    fn start(seconds: f64) -> WindowBar {
        let bar = indicatif::ProgressBar::new(100);
        if let Ok(style) = indicatif::ProgressStyle::with_template("  hold still {bar:30} {percent:>3}%") {
            bar.set_style(style);
        }
        let done = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let (b, d) = (bar.clone(), done.clone());
        let started = Instant::now();
        let thread = std::thread::spawn(move || {
            while !d.load(std::sync::atomic::Ordering::SeqCst) {
                b.set_position(
                    ((started.elapsed().as_secs_f64() / seconds.max(1e-3)) * 100.0).min(99.0) as u64
                );
                std::thread::sleep(Duration::from_millis(50));
            }
        });
        WindowBar { bar, done, thread: Some(thread) }
    }
}

impl Drop for WindowBar {
    fn drop(&mut self) {
        self.done.store(true, std::sync::atomic::Ordering::SeqCst);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        self.bar.finish_and_clear();
    }
}

/// The operator's answer, lower case; end of input (or an unreadable stdin) reads as `q`: stop,
/// everything measured is saved.
fn ask(prompt: &str) -> String {
    eprint!("{prompt}");
    let mut line = String::new();
    if std::io::stdin().read_line(&mut line).unwrap_or(0) == 0 {
        eprintln!("(end of input: stopping)");
        return "q".into();
    }
    line.trim().to_lowercase()
}

impl Guide for Operator {
    fn measuring(&mut self, seconds: f64) -> Option<Box<dyn std::any::Any>> {
        Some(Box::new(WindowBar::start(seconds)))
    }

    fn progress(&mut self, at: Progress) {
        self.at = Some(at);
    }

    fn approach(&mut self, _link: &mut Link, landmark: &str, repeat: u32) -> Result<Step, RecordError> {
        let at = self.at.map_or(format!("repeat {repeat}"), |at| at.to_string());
        Ok(match ask(&format!("[{at}] attach to {landmark}, then Enter — s to skip, q to stop: ")).as_str()
        {
            "s" => Step::Skip,
            "q" => Step::Stop,
            _ => Step::Measure,
        })
    }

    fn refused(&mut self, landmark: &str, reason: &str) -> Step {
        eprintln!("  {landmark}: {reason}");
        match ask("  check the encoder cables; Enter to measure again, s to skip, q to stop: ").as_str() {
            "s" => Step::Skip,
            "q" => Step::Stop,
            _ => Step::Measure,
        }
    }

    fn accept(&mut self, landmark: &str, m: &Measurement, q: &Quality) -> Verdict {
        let angles: Vec<String> = m.joints_deg.iter().map(|a| format!("{a:.3}")).collect();
        eprintln!(
            "  {landmark}: [{}]°  std ≤ {:.4}°  rejected {}{}",
            angles.join(", "),
            q.worst_std_deg,
            q.rejected,
            if q.flagged { "  (flagged)" } else { "" }
        );
        if let Some(warning) = q.same_as_warning(landmark) {
            eprintln!("  {warning}");
        }
        if q.poor() {
            let why = if q.same_as.is_some() {
                "move the arm to the landmark"
            } else {
                "the arm moved or the encoders were noisy"
            };
            return match ask(&format!("  {why}: take it again? [Y/n/q] ")).as_str() {
                "n" => Verdict::Accept,
                "q" => Verdict::Stop,
                _ => Verdict::Retake,
            };
        }
        Verdict::Accept
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn touch(landmark: &str, joints_deg: [f64; 6], std_deg: f64, samples: u32) -> Measurement {
        Measurement {
            landmark: landmark.into(),
            repeat: 1,
            joints_deg: joints_deg.to_vec(),
            std_deg: Some(vec![std_deg; 6]),
            samples: Some(samples),
            rejected: Some(0),
            at_unix_s: None,
        }
    }

    #[test]
    fn a_touch_with_another_landmarks_angles_is_named_within_the_encoder_noise_only() {
        let o = touch("O", [10.0, 20.0, 30.0, 40.0, 50.0, 359.9999], 0.01, 1536);
        // Standard error 0.01/√1536 ≈ 2.6e-4° per touch: 3σ of the difference ≈ 1.1e-3°.
        let same = touch("M1", [10.0005, 20.0, 30.0, 40.0, 50.0, 0.0002], 0.01, 1536);
        let moved = touch("M1", [10.01, 20.0, 30.0, 40.0, 50.0, 359.9999], 0.01, 1536);
        assert!(same_angles(&o, &same), "0.0005° and a wrap through 0° are the same reading");
        assert!(!same_angles(&o, &moved), "0.01° on one joint is a different touch");
        // Without spreads only the resolution counts.
        let bare = |j0: f64| Measurement {
            std_deg: None,
            samples: None,
            ..touch("S", [j0, 0.0, 0.0, 0.0, 0.0, 0.0], 0.0, 1)
        };
        assert!(same_angles(&bare(1.0), &bare(1.0 + COUNT_DEG)));
        assert!(!same_angles(&bare(1.0), &bare(1.0 + 5.0 * COUNT_DEG)));
        let q = Quality { worst_std_deg: 0.0, rejected: 0, flagged: false, same_as: Some(("O".into(), 1)) };
        assert!(q.poor(), "a re-take is offered");
        let warning = q.same_as_warning("M1").unwrap();
        assert!(warning.contains("M1") && warning.contains("O (repeat 1)"), "{warning}");
        let at = Progress { landmark: 2, landmarks: 15, repeat: 1, repeats: 3 };
        assert_eq!(at.to_string(), "landmark 2 of 15, repeat 1 of 3");
    }
}
