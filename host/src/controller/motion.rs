//! The emulated arm in motion: send a trajectory to the emulated controller and start it, stream
//! the moving pose over OpenIGTLink and record it as a client receives it, and the demo's
//! dynamic validation against a simulated optical tracker of known latency.

use crate::controller::igtl_client::{Received, Recorder};
use crate::controller::igtl_server::{PoseServer, ServerError, ServerOptions, DEFAULT_NAME};
use crate::controller::link::{Link, LinkError};
use crate::controller::pose_stream::{stream_poses, Flow, StreamCount, TimedPose};
use crate::igtl::IgtlError;
use crate::model::ArmModel;
use crate::motion::recording::{track_csv, Track};
use crate::motion::trajectory::Trajectory;
use crate::motion::truth::{against_truth, TruthRow};
use crate::motion::{analyze, Dynamic, DynamicError};
use crate::simulate::optical::{record, MovingArm, OpticalOptions, OpticalSample};
use kincal_protocol::messages::{SimPlay, SimWaypoint, TICK_HZ};
use kincal_protocol::trajectory::duration_ticks;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Ticks between the start request and the trajectory's start (0.5 s): time for the request to
/// arrive on a slow link, so the start tick is still ahead when it does.
pub const LEAD_TICKS: u32 = 384;
/// Ticks streamed after the trajectory's end (at rest).
const TAIL_TICKS: u64 = 192;

/// Send `trajectory` to the emulated controller on `link` and start it [`LEAD_TICKS`] from now;
/// with `repeat` it starts again at its end. Returns the controller tick of the trajectory's
/// time 0: the sample of tick `k` is the trajectory at `k − start`.
pub fn play(link: &mut Link, trajectory: &Trajectory, repeat: bool) -> Result<u32, LinkError> {
    for (index, waypoint) in trajectory.waypoints.iter().enumerate() {
        link.call_retrying(SimWaypoint { index: index as u8, waypoint: *waypoint })?;
    }
    let start_tick = link.info()?.ticks.wrapping_add(LEAD_TICKS);
    link.call_retrying(SimPlay { waypoints: trajectory.waypoints.len() as u8, start_tick, repeat })?;
    Ok(start_tick)
}

/// Why the arm's motion could not be recorded or validated.
#[derive(Debug, thiserror::Error)]
pub enum MotionError {
    /// Talking to the controller failed.
    #[error(transparent)]
    Link(#[from] LinkError),
    /// The OpenIGTLink server did not start.
    #[error(transparent)]
    Server(#[from] ServerError),
    /// The OpenIGTLink client failed.
    #[error("OpenIGTLink client: {0}")]
    Client(#[from] IgtlError),
    /// The dynamic validation refused the recordings, which are kept in the files named.
    #[error("{source} (the recordings are kept: {} and {})", arm_csv.display(), tracker_csv.display())]
    Analysis {
        /// The OpenIGTLink client's recording.
        arm_csv: PathBuf,
        /// The simulated tracker's recording.
        tracker_csv: PathBuf,
        /// Why the validation refused them.
        source: DynamicError,
    },
    /// Writing the recordings or the report failed.
    #[error(transparent)]
    Output(#[from] crate::store::OutputError),
    /// The stream did not cover the trajectory in time.
    #[error("{0}")]
    Stream(String),
}

/// The arm's motion as the host streamed it and as an OpenIGTLink client received it.
pub struct MotionRecording {
    /// The trajectory played.
    pub trajectory: Trajectory,
    /// The controller tick of its time 0.
    pub start_tick: u32,
    /// Every pose the host streamed (stamped with the controller's sample instant).
    pub poses: Vec<TimedPose>,
    /// What the controller link delivered.
    pub stream: StreamCount,
    /// What the OpenIGTLink client received.
    pub received: Received,
    /// The OpenIGTLink server's address.
    pub server: std::net::SocketAddr,
}

impl MotionRecording {
    /// The controller's tick on the host's clock, fitted to the stream's stamps: host time of
    /// tick 0 (s) and ticks per second.
    pub fn tick_clock(&self) -> (f64, f64) {
        let n = self.poses.len() as f64;
        let (t0, k0) = (self.poses[0].t_s, self.poses[0].tick as f64);
        let (mut sk, mut st, mut skk, mut skt) = (0.0, 0.0, 0.0, 0.0);
        for p in &self.poses {
            let (k, t) = (p.tick as f64 - k0, p.t_s - t0);
            sk += k;
            st += t;
            skk += k * k;
            skt += k * t;
        }
        let seconds_per_tick = (n * skt - sk * st) / (n * skk - sk * sk);
        let at_first = (st - seconds_per_tick * sk) / n;
        (t0 + at_first - k0 * seconds_per_tick, 1.0 / seconds_per_tick)
    }

    /// The arm moving as the emulated encoders moved it, with the true arm `truth`.
    pub fn moving_arm<'a>(&'a self, truth: &'a ArmModel) -> MovingArm<'a> {
        let (anchor_s, tick_hz) = self.tick_clock();
        MovingArm {
            truth,
            waypoints: &self.trajectory.waypoints,
            repeat: false,
            start_tick: self.start_tick,
            anchor_s,
            tick_hz,
        }
    }

    /// The largest difference between a transform the client received and the host's pose of
    /// the same instant, µm (None when none matched).
    pub fn received_vs_streamed_um(&self) -> Option<f64> {
        let stamps: Vec<f64> =
            self.poses.iter().map(|p| crate::igtl::unix_seconds(crate::igtl::timestamp(p.t_s))).collect();
        let mut worst: Option<f64> = None;
        for (t, q) in self.received.track.t_s.iter().zip(&self.received.track.p) {
            let i = stamps.partition_point(|&s| s < t - 2e-6);
            let Some(pose) = self.poses.get(i).filter(|_| (stamps[i] - t).abs() <= 2e-6) else { continue };
            let p = pose.report.position_mm;
            let d = (0..3).map(|k| (q[k] - p[k] as f64).powi(2)).sum::<f64>().sqrt() * 1000.0;
            worst = Some(worst.map_or(d, |w| w.max(d)));
        }
        worst
    }

    /// Valid poses the host streamed while the client was connected that the client did not
    /// receive.
    pub fn lost_by_client(&self) -> usize {
        let t = &self.received.track.t_s;
        let (Some(&first), Some(&last)) = (t.first(), t.last()) else { return 0 };
        let streamed = self
            .poses
            .iter()
            .filter(|p| p.report.valid)
            .map(|p| crate::igtl::unix_seconds(crate::igtl::timestamp(p.t_s)))
            .filter(|s| (first - 1e-6..=last + 1e-6).contains(s))
            .count();
        streamed.saturating_sub(t.len())
    }
}

/// Play `trajectory` on the emulated controller on `link`, stream the pose until it has ended,
/// serve it over OpenIGTLink on `listen` (e.g. `127.0.0.1:0`) and record it with a client.
pub fn record_motion(
    link: &mut Link,
    trajectory: &Trajectory,
    listen: &str,
    progress: &mut dyn FnMut(&str),
) -> Result<MotionRecording, MotionError> {
    let server = PoseServer::start(listen, ServerOptions::default())?;
    let addr = server.local_addr();
    let client = Recorder::connect(addr, DEFAULT_NAME, false)?;
    let deadline = Instant::now() + Duration::from_secs(10);
    while server.clients().is_empty() {
        if Instant::now() > deadline {
            return Err(MotionError::Stream("the OpenIGTLink client did not connect within 10 s".into()));
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    let start_tick = play(link, trajectory, false)?;
    let end_tick = start_tick as u64 + duration_ticks(&trajectory.waypoints) as u64 + TAIL_TICKS;
    let wall = Duration::from_secs_f64(
        2.0 * (end_tick - start_tick as u64 + LEAD_TICKS as u64) as f64 / TICK_HZ as f64 + 10.0,
    );
    progress(&format!(
        "the emulated arm follows {} waypoints over {:.1} s; its pose is served over OpenIGTLink on {addr} and recorded by a client",
        trajectory.waypoints.len(),
        trajectory.duration_s()
    ));
    let started = Instant::now();
    let mut poses: Vec<TimedPose> = Vec::new();
    let last_tick = std::cell::Cell::new(0u64);
    let stream = stream_poses(
        link,
        |p| {
            server.publish(p);
            last_tick.set(p.tick);
            poses.push(*p);
        },
        |_, _| {
            Ok(if last_tick.get() >= end_tick || started.elapsed() > wall { Flow::Stop } else { Flow::Go })
        },
    )?;
    let last_tick = last_tick.get();
    drop(server); // the client sees the connection close
    let received = client.finish()?;
    if last_tick < end_tick {
        return Err(MotionError::Stream(format!(
            "the stream reached controller tick {last_tick} in {:.0} s, short of the trajectory's end at tick {end_tick}",
            started.elapsed().as_secs_f64()
        )));
    }
    // Ticks are counted from the controller's start; the stream's 16-bit ticks are extended
    // from the same count, so the trajectory's start is on the same scale.
    Ok(MotionRecording { trajectory: trajectory.clone(), start_tick, poses, stream, received, server: addr })
}

/// The simulated optical tracker's recording of the moving arm `arm` over the recording.
pub fn tracker_track(samples: &[OpticalSample]) -> Track {
    Track {
        t_s: samples.iter().map(|s| s.t_s).collect(),
        host_s: Some(samples.iter().map(|s| s.host_s).collect()),
        p: samples.iter().map(|s| s.p).collect(),
        gaps: 0,
        unordered: 0,
    }
}

/// The demo's dynamic validation: what was measured, the truth beside it, where it was written.
pub struct MotionReport {
    /// The validation of the OpenIGTLink client's recording against the simulated tracker.
    pub dynamic: Dynamic,
    /// The true error by category.
    pub truth: Vec<TruthRow>,
    /// The simulated tracker's settings (the true latency, clock, noise, flex).
    pub tracker: OpticalOptions,
    /// Valid poses the host streamed.
    pub streamed_valid: usize,
    /// Transforms the OpenIGTLink client received.
    pub received: usize,
    /// Valid poses the client did not receive.
    pub lost_by_client: usize,
    /// Largest difference between a received transform and the host's pose, µm.
    pub received_vs_streamed_um: Option<f64>,
    /// What the controller link delivered.
    pub stream: StreamCount,
    /// The recordings (`arm.csv`, `tracker.csv`) and the report folder.
    pub arm_csv: PathBuf,
    /// The simulated tracker's recording.
    pub tracker_csv: PathBuf,
    /// The dynamic validation folder.
    pub report_dir: PathBuf,
}

/// A comfortable pose of the SUTA at the centre of the demo's motion, encoder angles (°).
pub const DEMO_CENTER_DEG: [f64; 6] = [20.0, 100.0, 40.0, 10.0, 70.0, 5.0];

/// Move the emulated arm (whose true geometry is `truth`) along the demo trajectory, serve its
/// pose over OpenIGTLink and record it as a client receives it, watch the true tool with the
/// simulated optical `tracker`, and validate the received pose against it: the recordings go to
/// `out/motion/`, the report to `out/dynamic/`.
pub fn motion_demo(
    link: &mut Link,
    truth: &ArmModel,
    tracker: &OpticalOptions,
    out: &Path,
    progress: &mut dyn FnMut(&str),
) -> Result<MotionReport, MotionError> {
    let trajectory = Trajectory::demo(DEMO_CENTER_DEG);
    let rec = record_motion(link, &trajectory, "127.0.0.1:0", progress)?;
    let arm = rec.moving_arm(truth);
    let t = &rec.received.track.t_s;
    if t.len() < 2 {
        let r = &rec.received;
        return Err(MotionError::Stream(format!(
            "the OpenIGTLink client recorded {} poses: {} TRANSFORM messages ({} invalid, {} out of order), {} STATUS, {} bad CRC; the host streamed {} poses ({} valid) over controller ticks {}–{}",
            t.len(),
            r.transforms,
            r.invalid,
            r.unordered,
            r.status,
            r.bad_crc,
            rec.poses.len(),
            rec.poses.iter().filter(|p| p.report.valid).count(),
            rec.poses.first().map_or(0, |p| p.tick),
            rec.poses.last().map_or(0, |p| p.tick),
        )));
    }
    let samples = record(&arm, t[0] + 0.2, t[t.len() - 1] - 0.2, tracker);
    let tracker_rec = tracker_track(&samples);
    progress(&format!(
        "a simulated optical tracker watched the true tool: {} samples at {} Hz, latency {} ms, noise {} mm, clock {:+} s and {:+} ppm",
        samples.len(),
        tracker.rate_hz,
        tracker.latency_ms,
        tracker.noise_mm,
        tracker.clock_offset_s,
        tracker.drift_ppm
    ));
    // The recordings are kept before they are analysed: what was measured is never lost, and
    // `kincal dynamic` can be run on them again.
    let folder = out.join("motion");
    let files = |e: std::io::Error| crate::store::OutputError::Io { path: folder.clone(), source: e };
    std::fs::create_dir_all(&folder).map_err(files)?;
    let (arm_csv, tracker_csv) = (folder.join("arm.csv"), folder.join("tracker.csv"));
    crate::files::write_atomic(&arm_csv, track_csv(&rec.received.track).as_bytes()).map_err(files)?;
    crate::files::write_atomic(&tracker_csv, track_csv(&tracker_rec).as_bytes()).map_err(files)?;
    let dynamic = analyze(&rec.received.track, &tracker_rec).map_err(|e| MotionError::Analysis {
        arm_csv: arm_csv.clone(),
        tracker_csv: tracker_csv.clone(),
        source: e,
    })?;
    let received = crate::motion::align::Path::new(&rec.received.track.t_s, &rec.received.track.p);
    let truth_rows = against_truth(&dynamic, &|k| {
        let at = samples[k].taken_s;
        received.at(at).map(|reported| (arm.true_point(at, tracker.flex_mm_per_m_s2), reported))
    });
    let report_dir = out.join("dynamic");
    crate::store::write_dynamic(&dynamic, Some(&truth_rows), &report_dir, &arm_csv, &tracker_csv)?;
    Ok(MotionReport {
        truth: truth_rows,
        tracker: tracker.clone(),
        streamed_valid: rec.poses.iter().filter(|p| p.report.valid).count(),
        received: rec.received.track.len(),
        lost_by_client: rec.lost_by_client(),
        received_vs_streamed_um: rec.received_vs_streamed_um(),
        stream: rec.stream,
        arm_csv,
        tracker_csv,
        report_dir,
        dynamic,
    })
}
