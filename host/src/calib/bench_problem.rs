//! The tracker benchmark's problem, one definition for `kincal bench`, its peers and the
//! profiling example: a 7-joint arm with 23 free parameters, 3 600 points in 5 sessions, each
//! seen from its own base, and a held-out session. The points come from kincal's own kinematics
//! with 0.02 mm noise: it measures speed only (accuracy is tested on the independent generator
//! in `tests/`).

use crate::data::tracker::TRACKER_FORMAT;
use crate::data::{Joints, Kind, Observation, Observations};
use crate::model::kinematics::tool_pose;
use crate::model::{ArmModel, Joint, ParamId};
use nalgebra::{Rotation3, Vector3};
use rand::{RngExt, SeedableRng};
use rand_distr::{Distribution, StandardNormal};
use std::path::Path;

/// Calibration sessions of the benchmark.
pub const SESSIONS: usize = 5;
/// Calibration points of the benchmark, over all sessions.
pub const POINTS: usize = 3600;
/// Noise of each measured coordinate, mm.
const NOISE_MM: f64 = 0.02;

/// The 7-joint bench arm, its 23 free parameters bounded.
pub fn arm() -> ArmModel {
    let alpha = [-90.0, 90.0, 90.0, -90.0, -90.0, 90.0, 0.0];
    let d = [360.0, 0.0, 420.0, 0.0, 400.0, 0.0, 126.0];
    let mut model = ArmModel::suta_nominal();
    model.name = "7R bench arm".into();
    model.joints = (0..7).map(|j| Joint { d_mm: d[j], alpha_deg: alpha[j], ..Joint::default() }).collect();
    model.tcp_mm = [40.0, -25.0, 120.0];
    model.free.clear();
    for j in 1..7 {
        model.free_param(ParamId::Offset(j), -5.0, 5.0);
    }
    for (j, dj) in d.iter().enumerate().take(6).skip(1) {
        model.free_param(ParamId::Length(j), dj - 10.0, dj + 10.0);
    }
    for (j, aj) in alpha.iter().enumerate().take(6) {
        model.free_param(ParamId::LinkOffset(j), -10.0, 10.0);
        model.free_param(ParamId::Twist(j), aj - 5.0, aj + 5.0);
    }
    model
}

/// The bench arm's truth: every free parameter moved by up to 0.2 from its nominal value.
pub fn truth(nominal: &ArmModel) -> ArmModel {
    let mut truth = nominal.clone();
    for (k, f) in nominal.free.iter().enumerate() {
        truth.set(f.id, nominal.get(f.id) + 0.2 * ((k as f64 * 1.7).sin()));
    }
    truth
}

/// `count` sessions of `points` random poses of `truth` (7 joints), each seen from its own base,
/// with 0.02 mm noise on each coordinate, drawn from `seed`.
pub fn sessions(truth: &ArmModel, count: usize, points: usize, seed: u64) -> Observations {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut data = Observations::new(7, Vec::new());
    for s in 0..count {
        let group = data.push_group(format!("bench_{}", s + 1), "bench.csv".into(), Kind::Tracker);
        let rotation = Rotation3::from_euler_angles(0.1, -0.05, 1.2 * s as f64).into_inner();
        let shift = Vector3::new(2500.0, -300.0 * s as f64, 400.0);
        for i in 0..points {
            let q: [f64; 7] = std::array::from_fn(|_| rng.random_range(-120.0..120.0));
            let p = rotation * tool_pose(truth, &q).position_mm + shift;
            let n = Vector3::from_fn(|_, _| {
                let z: f64 = StandardNormal.sample(&mut rng);
                NOISE_MM * z
            });
            let q = Joints::new(&q).expect("seven joints are within Joints' capacity");
            data.obs.push(Observation::point(group, q, p + n, None, Some(NOISE_MM), i + 3));
        }
    }
    data.rebuild_blocks();
    data
}

/// The bench problem: the nominal arm, 5 calibration sessions (3 600 points) and a held-out one.
pub fn problem() -> (ArmModel, Observations, Observations) {
    let nominal = arm();
    let truth = truth(&nominal);
    let cal = sessions(&truth, SESSIONS, POINTS / SESSIONS, 1);
    let mut val = sessions(&truth, 1, POINTS / SESSIONS, 2);
    val.groups[0].name = "bench_held_out".into();
    (nominal, cal, val)
}

/// Write `data`'s sessions as `kincal-tracker/1` files into `dir` (full precision), one file per
/// session named after it.
pub fn write_sessions(data: &Observations, dir: &Path) -> std::io::Result<()> {
    std::fs::create_dir_all(dir)?;
    for (g, group) in data.groups.iter().enumerate() {
        let mut text = format!("# {TRACKER_FORMAT}\n");
        let joints: Vec<String> = (1..=data.joints).map(|j| format!("q{j}_deg")).collect();
        text += &format!("{},x_mm,y_mm,z_mm,sigma_mm\n", joints.join(","));
        for p in data.obs.iter().filter(|o| o.group == g) {
            let q: Vec<String> = p.q_deg.iter().map(|v| format!("{v:?}")).collect();
            let point = p.point_mm().unwrap_or_default();
            let [x, y, z] = [point.x, point.y, point.z];
            text += &format!("{},{x:?},{y:?},{z:?},{:?}\n", q.join(","), p.sigma_mm.unwrap_or(NOISE_MM));
        }
        std::fs::write(dir.join(format!("{}.csv", group.name)), text)?;
    }
    Ok(())
}
