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
//! repeat not yet on disk and never measures one twice.

use crate::controller::link::{Link, LinkError};
use crate::data::{Artefact, Measurement, Session, SESSION_FORMAT};
use crate::files::FileError;
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
#[derive(Clone, Copy, Debug)]
pub struct Quality {
    /// Largest per-sample spread over the joints, degrees.
    pub worst_std_deg: f64,
    /// Most rejected samples of any joint.
    pub rejected: u32,
    /// The controller flagged the window (too many rejects).
    pub flagged: bool,
}

impl Quality {
    /// Whether a re-take should be offered.
    pub fn poor(&self) -> bool {
        self.flagged || self.worst_std_deg > RETAKE_STD_DEG
    }
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
    /// A window of `seconds` is being measured; the returned guard ends any display on drop.
    fn measuring(&mut self, _seconds: f64) -> Option<Box<dyn std::any::Any>> {
        None
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
        },
        quality,
    )
}

/// Load the session to resume, or start an empty one.
fn resume(plan: &Plan, artefact: &Artefact) -> Result<Session, RecordError> {
    let path = plan.session_path();
    if !path.exists() {
        return Ok(Session {
            format: SESSION_FORMAT.into(),
            placement: plan.placement.clone(),
            purpose: plan.purpose.clone(),
            measurements: Vec::new(),
        });
    }
    let session = Session::load(&path, artefact)?;
    if session.placement != plan.placement || session.purpose != plan.purpose {
        return Err(RecordError::Mismatch {
            path,
            placement: plan.placement.clone(),
            purpose: plan.purpose.clone(),
            found_placement: session.placement,
            found_purpose: session.purpose,
        });
    }
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
    let mut session = resume(plan, artefact)?;
    let mut summary = Recorded { resumed: session.measurements.len(), ..Recorded::default() };
    for repeat in 1..=plan.repeats {
        for landmark in &plan.order {
            if session.measurements.iter().any(|m| &m.landmark == landmark && m.repeat == repeat) {
                continue;
            }
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
                let (m, quality) = to_measurement(landmark, repeat, &window);
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
            session.measurements.push(measurement);
            session.save(&plan.session_path())?;
            summary.measured += 1;
        }
    }
    Ok(summary)
}

/// A scripted session (`--script FILE`): `{"steps":[{"landmark":"M1","repeat":1,
/// "pose_counts":[6 counts]}, {"landmark":"S2","skip":true}, {"stop":true}]}`. `pose_counts`
/// poses the emulated arm; steps are matched by landmark and repeat (repeat defaults to 1).
#[derive(Clone, Debug, Default, serde::Deserialize)]
pub struct Script {
    /// The steps.
    pub steps: Vec<ScriptStep>,
}

/// One step of a [`Script`].
#[derive(Clone, Debug, Default, serde::Deserialize)]
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

    fn accept(&mut self, _landmark: &str, _m: &Measurement, _q: &Quality) -> Verdict {
        Verdict::Accept
    }
}

/// A person at the keyboard: prompts on stderr, answers on stdin.
pub struct Operator;

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

    fn approach(&mut self, _link: &mut Link, landmark: &str, repeat: u32) -> Result<Step, RecordError> {
        Ok(
            match ask(&format!("attach to {landmark} (repeat {repeat}), then Enter — s to skip, q to stop: "))
                .as_str()
            {
                "s" => Step::Skip,
                "q" => Step::Stop,
                _ => Step::Measure,
            },
        )
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
        if q.poor() {
            return match ask("  the arm moved or the encoders were noisy: take it again? [Y/n/q] ").as_str() {
                "n" => Verdict::Accept,
                "q" => Verdict::Stop,
                _ => Verdict::Retake,
            };
        }
        Verdict::Accept
    }
}
