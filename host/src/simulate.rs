//! `kincal simulate`: an artefact and measurement sessions from a "true" arm with known errors.
//!
//! The true arm is the nominal model with its free parameters perturbed (seeded), plus any hidden
//! effects (parameter deltas the nominal model does not free, e.g. an eccentricity). Every touch
//! is found by inverse kinematics on the true arm: tip on the landmark (plus seating noise), tool
//! axis perpendicular to the base plate, tool x axis at the pillar's yaw. The forward path here
//! is deliberately independent of [`crate::model::kinematics`] (plain 4×4 homogeneous matrices),
//! so a bug there cannot hide in data made here. Touches the arm cannot reach without passing
//! a joint below the table are skipped, as an operator would.

pub mod optical;

use crate::data::{Artefact, Landmark, Measurement, Session, ARTEFACT_FORMAT, SESSION_FORMAT};
use crate::model::{ArmModel, Convention, ParamId, SUTA_JOINTS};
use crate::numerics::solver::{self, Residuals, SolverOptions, Termination};
use nalgebra::{Matrix4, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// Settings of a simulated dataset.
#[derive(Clone, Debug)]
pub struct SimulationOptions {
    /// Seed of every random choice.
    pub seed: u64,
    /// Perturbation of free angle parameters: uniform magnitude in [½x, x], random sign, degrees.
    pub perturb_deg: f64,
    /// Perturbation of free length parameters: uniform magnitude in [½x, x], random sign, mm.
    pub perturb_mm: f64,
    /// Seating noise of the tip in the pillar cup, standard deviation per axis, mm.
    pub seating_noise_mm: f64,
    /// Noise of each averaged encoder reading, standard deviation, degrees.
    pub encoder_noise_deg: f64,
    /// Repeats of every landmark per placement.
    pub repeats: u32,
    /// Hidden effects: deltas added to the true arm's parameters after the perturbation.
    pub hidden: Vec<(ParamId, f64)>,
}

impl Default for SimulationOptions {
    fn default() -> Self {
        SimulationOptions {
            seed: 1,
            perturb_deg: 2.0,
            perturb_mm: 2.0,
            seating_noise_mm: 0.1,
            encoder_noise_deg: 0.003,
            repeats: 3,
            hidden: Vec::new(),
        }
    }
}

/// Errors outside the model library and in the data, for testing the diagnosis: the
/// simulator writes them into the touches; no fitting code knows them.
#[derive(Clone, Debug, Default)]
pub struct HiddenErrors {
    /// Periodic encoder errors of the true arm beyond the library's first two harmonics.
    pub encoder_harmonics: Vec<EncoderHarmonic>,
    /// Landmarks whose certificate is wrong: (id, certified minus true position, mm).
    pub wrong_certificates: Vec<(String, [f64; 3])>,
    /// The artefact knocked during one repeat of one placement.
    pub knock: Option<Knock>,
}

/// Δθ_j = a·sin(nφ_j) + b·cos(nφ_j) on the true arm's joint `joint`, φ the raw encoder angle.
#[derive(Clone, Copy, Debug)]
pub struct EncoderHarmonic {
    /// Joint, 0-based.
    pub joint: usize,
    /// Cycles per revolution.
    pub order: u32,
    /// Sine part a, degrees.
    pub sin_deg: f64,
    /// Cosine part b, degrees.
    pub cos_deg: f64,
}

/// The artefact moved after a given touch of one repeat of one placement (and left there for
/// the rest of that repeat; the next repeat starts from the original placement, as after the
/// operator re-seats it against its stops).
#[derive(Clone, Debug)]
pub struct Knock {
    /// Placement name, e.g. `C_A`.
    pub placement: String,
    /// Repeat number (1-based).
    pub repeat: u32,
    /// Touches of the repeat made before the knock.
    pub after_touch: usize,
    /// Shift of the artefact, mm.
    pub shift_mm: [f64; 3],
    /// Rotation of the artefact about the vertical through its origin, degrees.
    pub yaw_deg: f64,
}

/// A simulated dataset: the truth and what an operator would have recorded.
#[derive(Clone, Debug)]
pub struct SimulatedData {
    /// The arm the touches were made with.
    pub truth: ArmModel,
    /// The artefact, as certified.
    pub artefact: Artefact,
    /// The artefact as it really is (differs from `artefact` only with wrong certificates).
    pub true_artefact: Artefact,
    /// Calibration sessions.
    pub calibration: Vec<Session>,
    /// Validation sessions.
    pub validation: Vec<Session>,
    /// Touches skipped as unreachable.
    pub skipped: usize,
}

/// An artefact placement in the arm's base frame.
#[derive(Clone, Debug)]
pub struct Placement {
    /// Name, e.g. `A_O`.
    pub name: String,
    /// Artefact origin in the base frame, mm.
    pub origin_mm: [f64; 3],
    /// Rotation of the artefact about the base z axis, degrees.
    pub yaw_deg: f64,
}

fn placement(name: &str, x: f64, y: f64, z: f64, yaw_deg: f64) -> Placement {
    Placement { name: name.into(), origin_mm: [x, y, z], yaw_deg }
}

/// The thesis placements: A_O at (512.5, 12.5, 0) mm and four offsets for calibration.
pub fn calibration_placements() -> Vec<Placement> {
    vec![
        placement("A_O", 512.5, 12.5, 0.0, 0.0),
        placement("C_A", 612.5, 112.5, 0.0, 10.0),
        placement("C_B", 612.5, -87.5, 0.0, -10.0),
        placement("C_C", 412.5, 112.5, 0.0, 5.0),
        placement("C_D", 412.5, -87.5, 0.0, -5.0),
    ]
}

/// Four other ground placements and one elevated by 110 mm, for validation.
pub fn validation_placements() -> Vec<Placement> {
    vec![
        placement("V_A", 662.5, 12.5, 0.0, 5.0),
        placement("V_B", 362.5, 12.5, 0.0, -5.0),
        placement("V_C", 512.5, 162.5, 0.0, 10.0),
        placement("V_D", 512.5, -137.5, 0.0, -10.0),
        placement("V_E", 512.5, 12.5, 110.0, 0.0),
    ]
}

/// The 15-pillar artefact (O, M1–M6 at 40 mm, L1–L4 at 60 mm, S1–S4 at 20 mm) with random
/// plug yaws within ±45°, the range in which the stylus can seat from this arm.
pub fn suta_artefact(rng: &mut ChaCha8Rng) -> Artefact {
    let mut landmarks = vec![("O".to_string(), [0.0, 0.0, 40.0])];
    for k in 0..6 {
        let a = (k as f64 * 60.0 + 30.0).to_radians();
        landmarks.push((format!("M{}", k + 1), [50.0 * a.cos(), 50.0 * a.sin(), 40.0]));
    }
    for (k, (x, y)) in [(70.0, 70.0), (-70.0, 70.0), (-70.0, -70.0), (70.0, -70.0)].into_iter().enumerate() {
        landmarks.push((format!("L{}", k + 1), [x, y, 60.0]));
    }
    for (k, (x, y)) in [(85.0, 0.0), (0.0, 85.0), (-85.0, 0.0), (0.0, -85.0)].into_iter().enumerate() {
        landmarks.push((format!("S{}", k + 1), [x, y, 20.0]));
    }
    let landmarks = landmarks
        .into_iter()
        .map(|(id, xyz_mm)| Landmark { id, xyz_mm, yaw_deg: (rng.random::<f64>() * 90.0 - 45.0).round() })
        .collect();
    Artefact { format: ARTEFACT_FORMAT.into(), landmarks, certificate: None }
}

/// Plain homogeneous-matrix forward kinematics of `model` (the independent path), with the
/// eccentricity and gravity-compliance effects written out again from their definitions.
/// Returns the tool frame and the frame origins after each joint.
pub fn reference_tool_frame(
    model: &ArmModel,
    enc_deg: &[f64; SUTA_JOINTS],
) -> (Matrix4<f64>, [Vector3<f64>; SUTA_JOINTS]) {
    tool_frame_with(model, &[], enc_deg)
}

/// [`reference_tool_frame`] with extra periodic encoder errors on the true arm.
fn tool_frame_with(
    model: &ArmModel,
    extra: &[EncoderHarmonic],
    enc_deg: &[f64; SUTA_JOINTS],
) -> (Matrix4<f64>, [Vector3<f64>; SUTA_JOINTS]) {
    let rigid: [f64; SUTA_JOINTS] = std::array::from_fn(|j| {
        let row = &model.joints[j];
        let phi = enc_deg[j].to_radians();
        let mut harmonics = row.eccentricity_sin_deg * phi.sin()
            + row.eccentricity_cos_deg * phi.cos()
            + row.eccentricity2_sin_deg * (2.0 * phi).sin()
            + row.eccentricity2_cos_deg * (2.0 * phi).cos()
            + row.harmonic3_sin_deg * (3.0 * phi).sin()
            + row.harmonic3_cos_deg * (3.0 * phi).cos()
            + row.harmonic4_sin_deg * (4.0 * phi).sin()
            + row.harmonic4_cos_deg * (4.0 * phi).cos();
        for h in extra.iter().filter(|h| h.joint == j) {
            let n = f64::from(h.order);
            harmonics += h.sin_deg * (n * phi).sin() + h.cos_deg * (n * phi).cos();
        }
        enc_deg[j] + row.offset_deg + harmonics
    });
    let (frames, axes) = frames_at(model, &rigid);
    let mut theta = rigid;
    if model.joints.iter().any(|j| j.compliance_deg_per_m != 0.0) {
        // Unit weights at every frame origin beyond the joint and at the tool point, pulled by -z.
        let gravity = Vector3::new(0.0, 0.0, -1.0);
        for j in 0..SUTA_JOINTS {
            let (axis_point, axis) = axes[j];
            let mut lever_mm = 0.0;
            for mass in frames[j..].iter().map(|f| f.fixed_view::<3, 1>(0, 3).into_owned()) {
                lever_mm += axis.dot(&(mass - axis_point).cross(&gravity));
            }
            theta[j] += model.joints[j].compliance_deg_per_m * lever_mm / 1000.0;
        }
    }
    let (frames, _) = frames_at(model, &theta);
    let s = 1.0 + model.scale_ppm * 1e-6;
    let mut tool = frames[SUTA_JOINTS];
    for k in 0..3 {
        tool[(k, 3)] *= s;
    }
    let origins = std::array::from_fn(|j| frames[j].fixed_view::<3, 1>(0, 3).into_owned() * s);
    (tool, origins)
}

/// Frames after each joint (and the tool frame last) for joint angles `theta_deg`, and each
/// joint's axis (point, direction), all before the length scale is applied.
/// A joint axis: a point on it and its direction.
type AxisLine = (Vector3<f64>, Vector3<f64>);

fn frames_at(
    model: &ArmModel,
    theta_deg: &[f64; SUTA_JOINTS],
) -> ([Matrix4<f64>; SUTA_JOINTS + 1], [AxisLine; SUTA_JOINTS]) {
    let rz = |t: f64| {
        Matrix4::new(t.cos(), -t.sin(), 0., 0., t.sin(), t.cos(), 0., 0., 0., 0., 1., 0., 0., 0., 0., 1.)
    };
    let rx = |t: f64| {
        Matrix4::new(1., 0., 0., 0., 0., t.cos(), -t.sin(), 0., 0., t.sin(), t.cos(), 0., 0., 0., 0., 1.)
    };
    let ry = |t: f64| {
        Matrix4::new(t.cos(), 0., t.sin(), 0., 0., 1., 0., 0., -t.sin(), 0., t.cos(), 0., 0., 0., 0., 1.)
    };
    let tr =
        |x: f64, y: f64, z: f64| Matrix4::new(1., 0., 0., x, 0., 1., 0., y, 0., 0., 1., z, 0., 0., 0., 1.);
    let axis_of =
        |m: &Matrix4<f64>| (m.fixed_view::<3, 1>(0, 3).into_owned(), m.fixed_view::<3, 1>(0, 2).into_owned());
    let mut t = Matrix4::identity();
    let mut frames = [Matrix4::identity(); SUTA_JOINTS + 1];
    let mut axes = [(Vector3::zeros(), Vector3::z()); SUTA_JOINTS];
    for (j, row) in model.joints.iter().take(SUTA_JOINTS).enumerate() {
        let theta = theta_deg[j].to_radians();
        let (alpha, beta) = (row.alpha_deg.to_radians(), row.axis_deg.to_radians());
        match model.convention {
            Convention::Classic => {
                axes[j] = axis_of(&t);
                t = t * rz(theta) * tr(0., 0., row.d_mm) * tr(row.a_mm, 0., 0.) * rx(alpha) * ry(beta);
            }
            Convention::Modified => {
                t = t * rx(alpha) * ry(beta) * tr(row.a_mm, 0., 0.);
                axes[j] = axis_of(&t);
                t = t * rz(theta) * tr(0., 0., row.d_mm);
            }
            Convention::Urdf => {
                let [x, y, z] = row.origin_xyz_mm;
                let [roll, pitch, yaw] = row.origin_rpy_deg.map(f64::to_radians);
                let turn = nalgebra::Rotation3::new(Vector3::from(row.origin_turn_deg.map(f64::to_radians)));
                t = t * tr(x, y, z) * rz(yaw) * ry(pitch) * rx(roll) * turn.to_homogeneous();
                let axis = Vector3::from(row.axis);
                axes[j] = (axis_of(&t).0, t.fixed_view::<3, 3>(0, 0) * axis);
                let turn = nalgebra::Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(axis), theta);
                t *= turn.to_homogeneous();
            }
        }
        frames[j] = t;
    }
    frames[SUTA_JOINTS] = t * tr(model.tcp_mm[0], model.tcp_mm[1], model.tcp_mm[2]);
    (frames, axes)
}

/// Inverse kinematics target: tip position and tool axes in the base frame.
struct PoseTarget<'a> {
    model: &'a ArmModel,
    extra: &'a [EncoderHarmonic],
    position_mm: Vector3<f64>,
    z_axis: Vector3<f64>,
    x_axis: Vector3<f64>,
}

/// mm per radian used to weigh orientation against position in the IK.
const IK_LEVER_MM: f64 = 300.0;

impl PoseTarget<'_> {
    fn error(&self, enc: &[f64]) -> [f64; 9] {
        let enc: [f64; SUTA_JOINTS] = std::array::from_fn(|k| enc[k]);
        let (t, _) = tool_frame_with(self.model, self.extra, &enc);
        let p = t.fixed_view::<3, 1>(0, 3).into_owned() - self.position_mm;
        let x = t.fixed_view::<3, 1>(0, 0).into_owned();
        let z = t.fixed_view::<3, 1>(0, 2).into_owned();
        let (dx, dz) = ((x - self.x_axis) * IK_LEVER_MM, (z - self.z_axis) * IK_LEVER_MM);
        [p[0], p[1], p[2], dx[0], dx[1], dx[2], dz[0], dz[1], dz[2]]
    }
}

impl Residuals for PoseTarget<'_> {
    fn len(&self) -> usize {
        9
    }
    fn evaluate(&self, x: &[f64], r: &mut [f64], jacobian: Option<&mut [f64]>) {
        r.copy_from_slice(&self.error(x));
        if let Some(j) = jacobian {
            let h = 1e-6;
            for c in 0..SUTA_JOINTS {
                let (mut xp, mut xm) = (x.to_vec(), x.to_vec());
                xp[c] += h;
                xm[c] -= h;
                let (ep, em) = (self.error(&xp), self.error(&xm));
                for i in 0..9 {
                    j[i * SUTA_JOINTS + c] = (ep[i] - em[i]) / (2.0 * h);
                }
            }
        }
    }
}

/// Encoder angles that put the true arm's tool at the target, or `None` if unreachable; the
/// first attempt starts from `first` when given (to keep a planned arm configuration).
fn solve_touch(
    truth: &ArmModel,
    target: &PoseTarget,
    first: Option<&[f64; SUTA_JOINTS]>,
    rng: &mut ChaCha8Rng,
) -> Option<[f64; SUTA_JOINTS]> {
    let options = SolverOptions {
        max_iterations: 100,
        termination: Termination::AcceptedSteps,
        ..SolverOptions::default()
    };
    for attempt in 0..25 {
        let start: Vec<f64> = match first.filter(|_| attempt == 0) {
            Some(f) => f.to_vec(),
            None => (0..SUTA_JOINTS).map(|_| rng.random::<f64>() * 360.0).collect(),
        };
        let s = solver::solve(target, &start, &[-1e4; SUTA_JOINTS], &[1e4; SUTA_JOINTS], &options);
        let err: f64 = s.residuals.iter().map(|v| v * v).sum::<f64>().sqrt();
        if err > 1e-6 {
            continue;
        }
        let enc: [f64; SUTA_JOINTS] = std::array::from_fn(|k| s.x[k].rem_euclid(360.0));
        let (_, origins) = tool_frame_with(truth, target.extra, &enc);
        if origins.iter().all(|o| o[2] > 0.0) {
            return Some(enc);
        }
    }
    None
}

/// Perturb every free parameter of `nominal` (angles by `perturb_deg`, lengths by `perturb_mm`).
pub fn perturbed_truth(nominal: &ArmModel, options: &SimulationOptions, rng: &mut ChaCha8Rng) -> ArmModel {
    let mut truth = nominal.clone();
    truth.name = format!("simulated truth (seed {})", options.seed);
    for f in &nominal.free {
        let size = match f.id.unit() {
            "deg" => options.perturb_deg,
            "mm" => options.perturb_mm,
            _ => 0.0,
        };
        let magnitude = size * (0.5 + 0.5 * rng.random::<f64>());
        let sign = if rng.random::<bool>() { 1.0 } else { -1.0 };
        let value = (nominal.get(f.id) + sign * magnitude).clamp(f.lower, f.upper);
        truth.set(f.id, value);
    }
    truth
}

/// Encoder angles (degrees) at which the true arm seats its tool on `landmark` at `place`, with
/// seating noise `noise_mm` added to the tip; `None` when unreachable.
pub fn touch_encoders(
    truth: &ArmModel,
    place: &Placement,
    landmark: &Landmark,
    noise_mm: Vector3<f64>,
    rng: &mut ChaCha8Rng,
) -> Option<[f64; SUTA_JOINTS]> {
    touch_encoders_with(truth, &[], place, landmark, noise_mm, None, rng)
}

/// As [`touch_encoders`], the inverse kinematics started from `near` (deg) first, so the arm
/// keeps that configuration where it can.
pub fn touch_encoders_from(
    truth: &ArmModel,
    place: &Placement,
    landmark: &Landmark,
    noise_mm: Vector3<f64>,
    near: &[f64; SUTA_JOINTS],
    rng: &mut ChaCha8Rng,
) -> Option<[f64; SUTA_JOINTS]> {
    touch_encoders_with(truth, &[], place, landmark, noise_mm, Some(near), rng)
}

fn touch_encoders_with(
    truth: &ArmModel,
    extra: &[EncoderHarmonic],
    place: &Placement,
    landmark: &Landmark,
    noise_mm: Vector3<f64>,
    near: Option<&[f64; SUTA_JOINTS]>,
    rng: &mut ChaCha8Rng,
) -> Option<[f64; SUTA_JOINTS]> {
    let (sy, cy) = place.yaw_deg.to_radians().sin_cos();
    let [x, y, z] = landmark.xyz_mm;
    let position_mm = Vector3::new(
        place.origin_mm[0] + cy * x - sy * y,
        place.origin_mm[1] + sy * x + cy * y,
        place.origin_mm[2] + z,
    ) + noise_mm;
    let yaw = (place.yaw_deg + landmark.yaw_deg).to_radians();
    let target = PoseTarget {
        model: truth,
        extra,
        position_mm,
        z_axis: -Vector3::z(),
        x_axis: Vector3::new(yaw.cos(), yaw.sin(), 0.0),
    };
    solve_touch(truth, &target, near, rng)
}

/// Record every landmark of `artefact` at `place` with the true arm, `repeats` times.
pub fn record_placement(
    truth: &ArmModel,
    artefact: &Artefact,
    place: &Placement,
    purpose: &str,
    options: &SimulationOptions,
    rng: &mut ChaCha8Rng,
) -> (Session, usize) {
    record_with(truth, &HiddenErrors::default(), artefact, place, purpose, options, rng)
}

fn record_with(
    truth: &ArmModel,
    errors: &HiddenErrors,
    artefact: &Artefact,
    place: &Placement,
    purpose: &str,
    options: &SimulationOptions,
    rng: &mut ChaCha8Rng,
) -> (Session, usize) {
    let seat = Normal::new(0.0, options.seating_noise_mm.max(0.0))
        .unwrap_or_else(|_| Normal::new(0.0, 0.0).expect("zero noise"));
    let enc_noise = Normal::new(0.0, options.encoder_noise_deg.max(0.0))
        .unwrap_or_else(|_| Normal::new(0.0, 0.0).expect("zero noise"));
    let mut measurements = Vec::new();
    let mut skipped = 0;
    for repeat in 1..=options.repeats {
        for (k, l) in artefact.landmarks.iter().enumerate() {
            let noise = Vector3::new(seat.sample(rng), seat.sample(rng), seat.sample(rng));
            let knocked = errors
                .knock
                .as_ref()
                .filter(|n| n.placement == place.name && n.repeat == repeat && k >= n.after_touch);
            let here = match knocked {
                Some(n) => Placement {
                    name: place.name.clone(),
                    origin_mm: std::array::from_fn(|i| place.origin_mm[i] + n.shift_mm[i]),
                    yaw_deg: place.yaw_deg + n.yaw_deg,
                },
                None => place.clone(),
            };
            let Some(enc) = touch_encoders_with(truth, &errors.encoder_harmonics, &here, l, noise, None, rng)
            else {
                skipped += 1;
                continue;
            };
            let joints_deg = enc.iter().map(|v| (v + enc_noise.sample(rng)).rem_euclid(360.0)).collect();
            measurements.push(Measurement {
                landmark: l.id.clone(),
                repeat,
                joints_deg,
                std_deg: Some(vec![options.encoder_noise_deg * 39.2; SUTA_JOINTS]),
                samples: Some(1536),
                rejected: Some(0),
                at_unix_s: None,
            });
        }
    }
    (
        Session {
            format: SESSION_FORMAT.into(),
            placement: place.name.clone(),
            purpose: purpose.into(),
            measurements,
            arm: None,
        },
        skipped,
    )
}

/// Simulate a full dataset from `nominal`: truth, artefact, calibration and validation sessions.
pub fn simulate(nominal: &ArmModel, options: &SimulationOptions) -> SimulatedData {
    simulate_with_truth(nominal, options, |truth| truth)
}

/// As [`simulate`], with `alter` applied to the perturbed truth (after the hidden effects)
/// before any touch is made.
pub fn simulate_with_truth(
    nominal: &ArmModel,
    options: &SimulationOptions,
    alter: impl FnOnce(ArmModel) -> ArmModel,
) -> SimulatedData {
    simulate_full(nominal, options, &HiddenErrors::default(), alter)
}

/// As [`simulate`], with errors outside the model library and in the data.
pub fn simulate_with_errors(
    nominal: &ArmModel,
    options: &SimulationOptions,
    errors: &HiddenErrors,
) -> SimulatedData {
    simulate_full(nominal, options, errors, |truth| truth)
}

fn simulate_full(
    nominal: &ArmModel,
    options: &SimulationOptions,
    errors: &HiddenErrors,
    alter: impl FnOnce(ArmModel) -> ArmModel,
) -> SimulatedData {
    let mut rng = ChaCha8Rng::seed_from_u64(options.seed);
    let mut truth = perturbed_truth(nominal, options, &mut rng);
    for (id, delta) in &options.hidden {
        truth.set(*id, truth.get(*id) + delta);
    }
    let truth = alter(truth);
    let artefact = suta_artefact(&mut rng);
    let mut skipped = 0;
    let mut sessions = |places: Vec<Placement>, purpose: &str| -> Vec<Session> {
        places
            .iter()
            .map(|p| {
                let (s, k) = record_with(&truth, errors, &artefact, p, purpose, options, &mut rng);
                skipped += k;
                s
            })
            .collect()
    };
    let calibration = sessions(calibration_placements(), "calibration");
    let validation = sessions(validation_placements(), "validation");
    let true_artefact = artefact.clone();
    let mut artefact = artefact;
    for (id, error) in &errors.wrong_certificates {
        if let Some(l) = artefact.landmarks.iter_mut().find(|l| &l.id == id) {
            for (x, e) in l.xyz_mm.iter_mut().zip(error) {
                *x += e;
            }
        }
    }
    SimulatedData { truth, artefact, true_artefact, calibration, validation, skipped }
}

impl SimulatedData {
    /// Write `artefact.json`, `truth.toml`, `cal/*.json` and `val/*.json` under `dir`.
    pub fn write(&self, dir: &std::path::Path) -> Result<(), crate::files::FileError> {
        let io = |path: &std::path::Path| {
            let path = path.to_owned();
            move |source| crate::files::FileError::Io { path, source }
        };
        for sub in ["cal", "val"] {
            std::fs::create_dir_all(dir.join(sub)).map_err(io(&dir.join(sub)))?;
        }
        self.artefact.save(&dir.join("artefact.json"))?;
        self.truth.save(&dir.join("truth.toml"))?;
        for (sub, sessions) in [("cal", &self.calibration), ("val", &self.validation)] {
            for s in sessions {
                s.save(&dir.join(sub).join(format!("{}.json", s.placement)))?;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::kinematics::tool_pose;

    #[test]
    fn independent_forward_path_agrees_with_the_model_kinematics() {
        let mut model = ArmModel::suta_nominal();
        model.joints[1].a_mm = 2.0;
        model.joints[4].axis_deg = 0.3;
        model.joints[2].eccentricity_sin_deg = 0.4;
        model.joints[3].eccentricity2_cos_deg = -0.2;
        model.joints[2].harmonic3_sin_deg = 0.12;
        model.joints[4].harmonic4_cos_deg = -0.05;
        model.joints[1].compliance_deg_per_m = 0.3;
        model.joints[3].compliance_deg_per_m = -0.2;
        model.tcp_mm = [1.0, -3.0, 250.0];
        model.scale_ppm = 200.0;
        for convention in [Convention::Classic, Convention::Modified] {
            model.convention = convention;
            let enc = [12.0, 250.0, 77.0, 310.0, 5.0, 200.0];
            let (t, _) = reference_tool_frame(&model, &enc);
            let p = tool_pose(&model, &enc).position_mm;
            assert!((t.fixed_view::<3, 1>(0, 3) - p).norm() < 1e-9);
        }
    }

    #[test]
    fn touches_land_on_their_landmarks() {
        let nominal = ArmModel::suta_nominal();
        let options = SimulationOptions {
            seating_noise_mm: 0.0,
            encoder_noise_deg: 0.0,
            repeats: 1,
            ..SimulationOptions::default()
        };
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let truth = perturbed_truth(&nominal, &options, &mut rng);
        let artefact = suta_artefact(&mut rng);
        let place = &calibration_placements()[0];
        let (session, skipped) =
            record_placement(&truth, &artefact, place, "calibration", &options, &mut rng);
        assert!(skipped <= 2, "{skipped} of 15 touches unreachable");
        for m in &session.measurements {
            let l = &artefact.landmarks[artefact.index_of(&m.landmark).unwrap()];
            let enc: [f64; 6] = std::array::from_fn(|k| m.joints_deg[k]);
            let (t, _) = reference_tool_frame(&truth, &enc);
            let expect =
                Vector3::new(place.origin_mm[0] + l.xyz_mm[0], place.origin_mm[1] + l.xyz_mm[1], l.xyz_mm[2]);
            assert!((t.fixed_view::<3, 1>(0, 3) - expect).norm() < 1e-5, "{}", m.landmark);
            assert!((t[(2, 2)] + 1.0).abs() < 1e-9, "tool axis must point down");
        }
    }
}
