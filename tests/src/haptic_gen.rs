//! An independent PHANToM + optical tracker generator for the haptic calibration tests.
//!
//! Written from the workspace-calibration paper (eqs. 7–10) and shared/notes/references.md, and
//! sharing no code with `kincal::haptic`: its own 3×3 matrix arithmetic, forward kinematics,
//! sensor models and their inverses, quaternion conversion, noise and CSV writer. It writes the
//! `haptic-recording/1` folder `kincal haptic calibrate` reads and returns the truth it used.
//!
//! What it models: Omni or Premium 1.5 with l1 ≠ l2; joint encoders with gain/offset errors (a
//! poor reset pose); linear or potentiometer-like quadratic gimbal sensors; asymmetric roll stops;
//! a 1 kHz device stream with timestamp jitter; a 60–240 Hz tracker, late by a delay, with
//! position and rotation noise, timestamp jitter, occlusion gaps and wild samples; landmark
//! targets T1 (first link) and T2 (turret, above, below or beside the central joint); driver
//! conventions (θ3 absolute or relative to θ2, per-joint sign, degrees, permuted columns) both as
//! recorded and as declared in `recording.json`.

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::fmt::Write as _;
use std::path::Path;

type M3 = [[f64; 3]; 3];
type V3 = [f64; 3];

fn mul(a: &M3, b: &M3) -> M3 {
    let mut c = [[0.0; 3]; 3];
    for (i, row) in c.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    c
}

fn apply(a: &M3, v: &V3) -> V3 {
    [0, 1, 2].map(|i| a[i][0] * v[0] + a[i][1] * v[1] + a[i][2] * v[2])
}

fn transpose(a: &M3) -> M3 {
    [0, 1, 2].map(|i| [a[0][i], a[1][i], a[2][i]])
}

fn add(a: &V3, b: &V3) -> V3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

fn sub(a: &V3, b: &V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn norm(a: &V3) -> f64 {
    (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt()
}

/// Rotation by the rotation vector `w` (axis · angle, radians), Rodrigues.
fn rotvec(w: &V3) -> M3 {
    let a = norm(w);
    if a < 1e-15 {
        return [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    }
    let k = [w[0] / a, w[1] / a, w[2] / a];
    let (s, c) = a.sin_cos();
    let t = 1.0 - c;
    [
        [c + k[0] * k[0] * t, k[0] * k[1] * t - k[2] * s, k[0] * k[2] * t + k[1] * s],
        [k[1] * k[0] * t + k[2] * s, c + k[1] * k[1] * t, k[1] * k[2] * t - k[0] * s],
        [k[2] * k[0] * t - k[1] * s, k[2] * k[1] * t + k[0] * s, c + k[2] * k[2] * t],
    ]
}

/// Unit quaternion (w, x, y, z) of a rotation matrix (Shepperd's method), w ≥ 0.
fn quaternion(m: &M3) -> [f64; 4] {
    let tr = m[0][0] + m[1][1] + m[2][2];
    let q = if tr > 0.0 {
        let s = 2.0 * (tr + 1.0).sqrt();
        [0.25 * s, (m[2][1] - m[1][2]) / s, (m[0][2] - m[2][0]) / s, (m[1][0] - m[0][1]) / s]
    } else if m[0][0] > m[1][1] && m[0][0] > m[2][2] {
        let s = 2.0 * (1.0 + m[0][0] - m[1][1] - m[2][2]).sqrt();
        [(m[2][1] - m[1][2]) / s, 0.25 * s, (m[0][1] + m[1][0]) / s, (m[0][2] + m[2][0]) / s]
    } else if m[1][1] > m[2][2] {
        let s = 2.0 * (1.0 + m[1][1] - m[0][0] - m[2][2]).sqrt();
        [(m[0][2] - m[2][0]) / s, (m[0][1] + m[1][0]) / s, 0.25 * s, (m[1][2] + m[2][1]) / s]
    } else {
        let s = 2.0 * (1.0 + m[2][2] - m[0][0] - m[1][1]).sqrt();
        [(m[1][0] - m[0][1]) / s, (m[0][2] + m[2][0]) / s, (m[1][2] + m[2][1]) / s, 0.25 * s]
    };
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    let sign = if q[0] < 0.0 { -1.0 } else { 1.0 };
    q.map(|v| sign * v / n)
}

/// The PHANToM models the generator knows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phantom {
    /// PHANToM Omni: potentiometer gimbals, about 133 mm links.
    Omni,
    /// PHANToM Premium 1.5: encoder gimbals, about 210 mm links.
    Premium15,
}

impl Phantom {
    /// `device` field of recording.json.
    pub fn name(self) -> &'static str {
        match self {
            Phantom::Omni => "omni",
            Phantom::Premium15 => "premium15",
        }
    }

    /// Link lengths l1, l2 in mm — deliberately unequal.
    pub fn links_mm(self) -> (f64, f64) {
        match self {
            Phantom::Omni => (133.35, 139.7),
            Phantom::Premium15 => (209.55, 203.2),
        }
    }
}

/// Where landmark target T2 sits on the turret relative to the central joint.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum T2Mount {
    /// On top of the turret, above the central joint.
    Above,
    /// On the turret base, below the central joint.
    Below,
    /// At the height of the central joint, to one side.
    Beside,
}

impl T2Mount {
    /// T2's origin in the turret frame (origin at the central joint, y up the θ1 axis), mm.
    fn offset_mm(self) -> V3 {
        match self {
            T2Mount::Above => [18.0, 65.0, 22.0],
            T2Mount::Below => [-25.0, -95.0, 30.0],
            T2Mount::Beside => [60.0, 2.0, -35.0],
        }
    }
}

/// How the driver writes joint readings (and what recording.json may declare).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Convention {
    /// Readings in degrees instead of radians.
    pub degrees: bool,
    /// θ3 reported relative to θ2 (θ3 − θ2) instead of absolute.
    pub theta3_relative: bool,
    /// Sign of each reading.
    pub sign: [f64; 6],
    /// CSV column (1-based, raw1…raw6) each joint is written to.
    pub columns: [usize; 6],
}

impl Default for Convention {
    fn default() -> Self {
        Convention { degrees: false, theta3_relative: false, sign: [1.0; 6], columns: [1, 2, 3, 4, 5, 6] }
    }
}

impl Convention {
    fn json(&self) -> String {
        format!(
            r#"{{"unit":"{}","theta3":"{}","sign":[{}],"columns":[{}]}}"#,
            if self.degrees { "deg" } else { "rad" },
            if self.theta3_relative { "relative" } else { "absolute" },
            self.sign.map(|s| format!("{s:.0}")).join(","),
            self.columns.map(|c| c.to_string()).join(",")
        )
    }

    /// CSV values for sensor readings in the model convention (radians, θ3 absolute).
    fn encode(&self, raw: &[f64; 6]) -> [f64; 6] {
        let mut v = *raw;
        if self.theta3_relative {
            v[2] -= v[1];
        }
        let unit = if self.degrees { 180.0 / std::f64::consts::PI } else { 1.0 };
        let mut out = [0.0; 6];
        for j in 0..6 {
            out[self.columns[j] - 1] = v[j] * self.sign[j] * unit;
        }
        out
    }
}

/// A sensor: true angle θ = j·raw² + k·raw + m (radians).
#[derive(Clone, Copy, Debug)]
pub struct Sensor {
    /// Quadratic term, 1/rad.
    pub j: f64,
    /// Gain.
    pub k: f64,
    /// Offset, rad.
    pub m: f64,
}

impl Sensor {
    fn angle(&self, raw: f64) -> f64 {
        self.j * raw * raw + self.k * raw + self.m
    }

    /// The reading for true angle θ (the root of the quadratic nearest the linear inverse).
    fn reading(&self, theta: f64) -> f64 {
        if self.j == 0.0 {
            return (theta - self.m) / self.k;
        }
        let disc = self.k * self.k + 4.0 * self.j * (theta - self.m);
        (2.0 * (theta - self.m)) / (self.k + disc.max(0.0).sqrt())
    }
}

/// Settings of one generated recording.
#[derive(Clone, Debug)]
pub struct GenOptions {
    /// Seed of everything random.
    pub seed: u64,
    /// Device model.
    pub phantom: Phantom,
    /// Potentiometer-like quadratic gimbal sensors (else linear).
    pub quadratic_gimbals: bool,
    /// Where T2 sits.
    pub t2: T2Mount,
    /// Tracker samples arrive this much later than the device's, ms.
    pub delay_ms: f64,
    /// Tracker rate, Hz.
    pub tracker_hz: f64,
    /// Tracker timestamp jitter, ± ms (uniform).
    pub jitter_ms: f64,
    /// Tracker position noise per axis, mm (1 σ).
    pub noise_mm: f64,
    /// Tracker rotation noise per axis, degrees (1 σ).
    pub noise_deg: f64,
    /// Wild tracker samples (10 m off) per target stream.
    pub wild_per_stream: usize,
    /// Fraction of each tracker stream lost in occlusion gaps of 50–500 ms.
    pub occlusion: f64,
    /// Seconds of free motion in joints/ (verify/ gets half of it, at least 10 s).
    pub joints_seconds: f64,
    /// Scale of the free motion in joints/ and verify/ (1 = the whole workspace).
    pub motion_scale: f64,
    /// Scale of the sensor errors (1: a poor reset and uncalibrated gimbals; 0: perfect sensors).
    pub sensor_error_scale: f64,
    /// How the driver writes the readings.
    pub recorded: Convention,
    /// What recording.json declares (`None`: no `joint_convention` field).
    pub declared: Option<Convention>,
}

impl Default for GenOptions {
    fn default() -> Self {
        GenOptions {
            seed: 1,
            phantom: Phantom::Omni,
            quadratic_gimbals: true,
            t2: T2Mount::Above,
            delay_ms: 12.3,
            tracker_hz: 90.0,
            jitter_ms: 0.3,
            noise_mm: 0.1,
            noise_deg: 0.05,
            wild_per_stream: 0,
            occlusion: 0.0,
            joints_seconds: 30.0,
            motion_scale: 1.0,
            sensor_error_scale: 1.0,
            recorded: Convention::default(),
            declared: None,
        }
    }
}

/// What a recording was made with, and what a perfect calibration would reach on verify/.
#[derive(Clone, Debug)]
pub struct GenTruth {
    /// True sensors of joints 1–3 and gimbals 4–6.
    pub sensors: [Sensor; 6],
    /// Delay, ms.
    pub delay_ms: f64,
    /// RMS distance of the tracker's HIP (true tip offset) from the true model's HIP on
    /// verify/, evaluated the way a calibration is (device read at stamp − delay), mm.
    pub floor_mm: f64,
    /// Same for the stylus axis, degrees.
    pub floor_deg: f64,
    /// Tracker samples written to verify/hip.csv that are not wild.
    pub verify_samples: usize,
    /// Wild samples written, all streams.
    pub wild_written: usize,
}

/// Forward kinematics of the paper (eqs. 7, 8 and 10), true angles in radians: HIP (mm) and
/// stylus rotation in device coordinates.
fn forward(l1: f64, l2: f64, th: &[f64; 6]) -> (V3, M3) {
    let (s1, c1) = th[0].sin_cos();
    let (s2, c2) = th[1].sin_cos();
    let (s3, c3) = th[2].sin_cos();
    let reach = c2 * l1 + l2 * s3;
    let t = [-s1 * reach, -c3 * l2 + l1 * s2 + l2, c1 * reach - l1];
    // Eq. 8, written out.
    let r123 = [[c1, s1 * s3, -s1 * c3], [0.0, c3, s3], [s1, -s3 * c1, c1 * c3]];
    // Eq. 9: θ4 about y, −θ5 about x, −θ6 about z.
    let r4 = rotvec(&[0.0, th[3], 0.0]);
    let r5 = rotvec(&[-th[4], 0.0, 0.0]);
    let r6 = rotvec(&[0.0, 0.0, -th[5]]);
    (t, mul(&mul(&mul(&r123, &r4), &r5), &r6))
}

/// A smooth random signal in [−1, 1]: normalised sum of sines.
struct Wave {
    parts: Vec<(f64, f64, f64)>,
}

impl Wave {
    fn new(rng: &mut ChaCha8Rng, f_lo: f64, f_hi: f64) -> Wave {
        let parts: Vec<(f64, f64, f64)> = (0..5)
            .map(|_| {
                (
                    0.3 + 0.7 * rng.random::<f64>(),
                    f_lo + (f_hi - f_lo) * rng.random::<f64>(),
                    std::f64::consts::TAU * rng.random::<f64>(),
                )
            })
            .collect();
        let total: f64 = parts.iter().map(|p| p.0).sum();
        Wave { parts: parts.into_iter().map(|(a, f, p)| (a / total, f, p)).collect() }
    }

    fn at(&self, t: f64) -> f64 {
        self.parts.iter().map(|(a, f, p)| a * (std::f64::consts::TAU * f * t + p).sin()).sum()
    }
}

/// True joint angles over time for one step.
struct Motion {
    kind: &'static str,
    waves: Vec<Wave>,
    scale: f64,
    stops: (f64, f64),
    seconds: f64,
}

impl Motion {
    fn theta(&self, t: f64) -> [f64; 6] {
        let w = |k: usize| self.waves[k].at(t);
        let (lo, hi) = self.stops;
        let mid = 0.5 * (lo + hi);
        let half = 0.5 * (hi - lo);
        let roll_free = mid + 0.8 * half * w(5);
        let s = self.scale;
        match self.kind {
            // The HIP in a stand; the stylus turned about it in all directions.
            "gimbal" => [0.08, 0.42, 0.28, 0.85 * w(3), 0.75 * w(4), roll_free],
            // The HIP in the stand, the stylus rolled from stop to stop (twice), a little wobble.
            "reference" => {
                let phase = 0.5 - 0.5 * (std::f64::consts::TAU * 2.0 * t / self.seconds).cos();
                [
                    0.08,
                    0.42,
                    0.28,
                    0.15 + 0.04 * w(3),
                    -0.1 + 0.04 * w(4),
                    lo + 0.004 + (hi - lo - 0.008) * phase,
                ]
            }
            // Towards and away from the device, briskly.
            "delay" => {
                [0.35 * w(0), 0.45 + 0.35 * w(1), 0.35 + 0.4 * w(2), 0.5 * w(3), 0.5 * w(4), roll_free]
            }
            // Swinging the turret through θ1 = 0 with the arm raised and lowered (T1 pivots
            // about the central joint, T2 circles the θ1 axis).
            "landmarks" => {
                [0.6 * w(0), 0.45 + 0.4 * w(1), 0.3 + 0.35 * w(2), 0.3 * w(3), 0.3 * w(4), roll_free]
            }
            // joints/ and verify/: the whole workspace.
            _ => [
                0.65 * s * w(0),
                0.45 + 0.42 * s * w(1),
                0.35 + 0.45 * s * w(2),
                0.8 * s * w(3),
                0.7 * s * w(4),
                mid + 0.8 * half * s * w(5),
            ],
        }
    }
}

fn gauss(rng: &mut ChaCha8Rng) -> f64 {
    // Box–Muller.
    let u1: f64 = rng.random::<f64>().max(1e-300);
    let u2: f64 = rng.random::<f64>();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// Occlusion gaps (start, end) in s covering about `fraction` of [0, seconds], 50–500 ms each.
fn gaps(rng: &mut ChaCha8Rng, seconds: f64, fraction: f64) -> Vec<(f64, f64)> {
    let mut out: Vec<(f64, f64)> = Vec::new();
    let mut covered = 0.0;
    let mut tries = 0;
    while covered < fraction * seconds && tries < 10_000 {
        tries += 1;
        let len = 0.05 + 0.45 * rng.random::<f64>();
        let start = 0.3 + (seconds - len - 0.6) * rng.random::<f64>();
        let end = start + len;
        if out.iter().any(|&(a, b)| start < b + 0.2 && end > a - 0.2) {
            continue;
        }
        out.push((start, end));
        covered += len;
    }
    out
}

/// Generate a recording into `dir` (created) and return its truth.
pub fn generate(options: &GenOptions, dir: &Path) -> std::io::Result<GenTruth> {
    let mut rng = ChaCha8Rng::seed_from_u64(options.seed);
    // Wild samples from their own stream: with and without them the recordings are the same.
    let mut wild_rng = ChaCha8Rng::seed_from_u64(options.seed ^ 0x005e_ed0f_3a1d_u64);
    let uniform = |rng: &mut ChaCha8Rng, a: f64| a * (2.0 * rng.random::<f64>() - 1.0);
    let (l1, l2) = options.phantom.links_mm();
    // Joint encoders after a poor reset: offsets of a few degrees, small gain errors.
    let mut sensors = [Sensor { j: 0.0, k: 1.0, m: 0.0 }; 6];
    let e = options.sensor_error_scale;
    for s in sensors.iter_mut().take(3) {
        *s = Sensor { j: 0.0, k: 1.0 + e * uniform(&mut rng, 0.025), m: e * uniform(&mut rng, 0.1) };
    }
    for s in sensors.iter_mut().skip(3) {
        let j = if options.quadratic_gimbals {
            let v = 0.05 + 0.05 * rng.random::<f64>();
            if rng.random::<f64>() < 0.5 {
                -v
            } else {
                v
            }
        } else {
            0.0
        };
        *s = Sensor { j: e * j, k: 1.0 + e * uniform(&mut rng, 0.05), m: e * uniform(&mut rng, 0.08) };
    }
    // Device → tracker, and the targets' mounts.
    let eh_r = rotvec(&[uniform(&mut rng, 1.0), 0.5 + uniform(&mut rng, 0.5), uniform(&mut rng, 1.0)]);
    let eh_t = [
        200.0 + uniform(&mut rng, 100.0),
        -100.0 + uniform(&mut rng, 80.0),
        900.0 + uniform(&mut rng, 150.0),
    ];
    let hip_mount_r = rotvec(&[0.4, 0.25, -0.7]);
    let hip_mount_t = [12.0, -6.0, 45.0];
    let t1_mount_r = rotvec(&[0.2, -0.3, 0.1]);
    let t1_mount_t = [8.0, 12.0, 0.55 * l1];
    let t2_mount_r = rotvec(&[-0.1, 0.5, 0.2]);
    let t2_mount_t = options.t2.offset_mm();
    let stops = (-2.55, 2.2);
    let central = [0.0, l2, -l1];
    let to_tracker = |p: &V3| add(&apply(&eh_r, p), &eh_t);
    let device_rate = 1000.0;
    let delay_s = options.delay_ms / 1000.0;
    let jitter_s = options.jitter_ms / 1000.0;
    let unit_header = "t_s,raw1,raw2,raw3,raw4,raw5,raw6\n";
    let target_header = "t_s,x_mm,y_mm,z_mm,qw,qx,qy,qz\n";
    std::fs::create_dir_all(dir)?;
    let mut header = format!(
        r#"{{"format":"haptic-recording/1","device":"{}","l1_mm":{l1},"l2_mm":{l2}"#,
        options.phantom.name()
    );
    if let Some(c) = options.declared {
        let _ = write!(header, r#","joint_convention":{}"#, c.json());
    }
    header.push('}');
    std::fs::write(dir.join("recording.json"), header)?;
    let steps: [(&'static str, f64, &[&str]); 6] = [
        ("delay", 12.0, &["hip"]),
        ("gimbal", 12.0, &["hip"]),
        ("reference", 12.0, &["hip"]),
        ("joints", options.joints_seconds, &["hip"]),
        ("landmarks", 14.0, &["hip", "t1", "t2"]),
        ("verify", (0.5 * options.joints_seconds).max(10.0), &["hip"]),
    ];
    let (mut floor_p, mut floor_a, mut floor_n, mut wild_written) = (0.0, 0.0, 0usize, 0usize);
    for (name, seconds, targets) in steps {
        let folder = dir.join(name);
        std::fs::create_dir_all(&folder)?;
        let motion = Motion {
            kind: name,
            waves: (0..6)
                .map(|k| {
                    let (lo, hi) = if name == "delay" && k < 3 { (0.4, 1.2) } else { (0.08, 0.5) };
                    Wave::new(&mut rng, lo, hi)
                })
                .collect(),
            scale: options.motion_scale,
            stops,
            seconds,
        };
        // The device stream: readings in the model convention, then as the driver writes them.
        let n_dev = (seconds * device_rate) as usize;
        let mut dev_t = Vec::with_capacity(n_dev);
        let mut dev_raw: Vec<[f64; 6]> = Vec::with_capacity(n_dev);
        let mut text = String::with_capacity(n_dev * 90);
        text.push_str(unit_header);
        for k in 0..n_dev {
            let t = k as f64 / device_rate + 0.00002 * (2.0 * rng.random::<f64>() - 1.0);
            let th = motion.theta(t);
            let raw: [f64; 6] = std::array::from_fn(|j| sensors[j].reading(th[j]));
            let v = options.recorded.encode(&raw);
            let _ = writeln!(
                text,
                "{t:.6},{:.8},{:.8},{:.8},{:.8},{:.8},{:.8}",
                v[0], v[1], v[2], v[3], v[4], v[5]
            );
            dev_t.push(t);
            dev_raw.push(raw);
        }
        std::fs::write(folder.join("device.csv"), text)?;
        for target in targets.iter() {
            let lost = gaps(&mut rng, seconds, options.occlusion);
            let n = (seconds * options.tracker_hz) as usize;
            let wild: Vec<usize> = (0..options.wild_per_stream)
                .map(|_| 20 + (wild_rng.random::<f64>() * (n - 40) as f64) as usize)
                .collect();
            let mut text = String::with_capacity(n * 90);
            text.push_str(target_header);
            for k in 0..n {
                let nominal = 0.02 + k as f64 / options.tracker_hz;
                let stamp = nominal + uniform(&mut rng, jitter_s);
                if stamp > seconds || lost.iter().any(|&(a, b)| nominal >= a && nominal <= b) {
                    continue;
                }
                // The pose the tracker saw: the device's state `delay` before the stamp.
                let th = motion.theta(nominal - delay_s);
                let (hip, r_hip) = forward(l1, l2, &th);
                let turret = rotvec(&[0.0, -th[0], 0.0]);
                let (r, p) = match *target {
                    "t1" => {
                        let link = mul(&turret, &rotvec(&[-th[1], 0.0, 0.0]));
                        (mul(&link, &t1_mount_r), add(&central, &apply(&link, &t1_mount_t)))
                    }
                    "t2" => (mul(&turret, &t2_mount_r), add(&central, &apply(&turret, &t2_mount_t))),
                    _ => (mul(&r_hip, &hip_mount_r), add(&hip, &apply(&r_hip, &hip_mount_t))),
                };
                let r_noise = rotvec(&[0, 1, 2].map(|_| options.noise_deg.to_radians() * gauss(&mut rng)));
                let r_meas = mul(&mul(&eh_r, &r), &r_noise);
                let mut p_meas = add(&to_tracker(&p), &[0, 1, 2].map(|_| options.noise_mm * gauss(&mut rng)));
                let is_wild = wild.contains(&k);
                let r_meas = if is_wild {
                    wild_written += 1;
                    p_meas[k % 3] += if k % 2 == 0 { 10_000.0 } else { -10_000.0 };
                    mul(&r_meas, &rotvec(&[0.9, -1.4, 0.6]))
                } else {
                    r_meas
                };
                let q = quaternion(&r_meas);
                let _ = writeln!(
                    text,
                    "{stamp:.6},{:.5},{:.5},{:.5},{:.9},{:.9},{:.9},{:.9}",
                    p_meas[0], p_meas[1], p_meas[2], q[0], q[1], q[2], q[3]
                );
                if name == "verify" && !is_wild {
                    // What a perfect calibration would see: the device read at stamp − delay.
                    let td = stamp - delay_s;
                    let i = dev_t.partition_point(|&x| x <= td).clamp(1, dev_t.len() - 1);
                    let w = ((td - dev_t[i - 1]) / (dev_t[i] - dev_t[i - 1])).clamp(0.0, 1.0);
                    let th_dev: [f64; 6] = std::array::from_fn(|j| {
                        sensors[j].angle(dev_raw[i - 1][j] * (1.0 - w) + dev_raw[i][j] * w)
                    });
                    let (hip_dev, r_dev) = forward(l1, l2, &th_dev);
                    let tip =
                        apply(&transpose(&hip_mount_r), &[-hip_mount_t[0], -hip_mount_t[1], -hip_mount_t[2]]);
                    let hip_meas = add(&apply(&r_meas, &tip), &p_meas);
                    floor_p += norm(&sub(&hip_meas, &to_tracker(&hip_dev))).powi(2);
                    let axis_target = apply(&transpose(&hip_mount_r), &[0.0, 0.0, 1.0]);
                    let a_meas = apply(&r_meas, &axis_target);
                    let a_dev = apply(&mul(&eh_r, &r_dev), &[0.0, 0.0, 1.0]);
                    let dot =
                        (a_meas[0] * a_dev[0] + a_meas[1] * a_dev[1] + a_meas[2] * a_dev[2]).clamp(-1.0, 1.0);
                    floor_a += dot.acos().to_degrees().powi(2);
                    floor_n += 1;
                }
            }
            std::fs::write(folder.join(format!("{target}.csv")), text)?;
        }
    }
    Ok(GenTruth {
        sensors,
        delay_ms: options.delay_ms,
        floor_mm: (floor_p / floor_n.max(1) as f64).sqrt(),
        floor_deg: (floor_a / floor_n.max(1) as f64).sqrt(),
        verify_samples: floor_n,
        wild_written,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kinematics_and_inverses_are_consistent() {
        // Reset pose: the HIP at the origin, the stylus along z.
        let (p, r) = forward(133.35, 139.7, &[0.0; 6]);
        assert!(norm(&p) < 1e-12 && (r[2][2] - 1.0).abs() < 1e-12);
        // The HIP is l1 and l2 from the central joint along the two links.
        let th = [0.3, 0.5, 0.2, 0.0, 0.0, 0.0];
        let (p, _) = forward(133.35, 139.7, &th);
        let elbow = add(
            &[0.0, 139.7, -133.35],
            &apply(&mul(&rotvec(&[0.0, -0.3, 0.0]), &rotvec(&[-0.5, 0.0, 0.0])), &[0.0, 0.0, 133.35]),
        );
        assert!((norm(&sub(&p, &elbow)) - 139.7).abs() < 1e-9);
        let s = Sensor { j: 0.08, k: 1.03, m: -0.05 };
        for th in [-2.0, -0.3, 0.0, 0.7, 2.1] {
            assert!((s.angle(s.reading(th)) - th).abs() < 1e-12);
        }
        let m = mul(&rotvec(&[0.3, -1.2, 2.0]), &rotvec(&[3.0, 0.1, 0.0]));
        let q = quaternion(&m);
        let back = rotvec(&{
            let a = 2.0 * q[0].clamp(-1.0, 1.0).acos();
            let s = (1.0 - q[0] * q[0]).sqrt().max(1e-15);
            [q[1] / s * a, q[2] / s * a, q[3] / s * a]
        });
        assert!((0..3).all(|i| (0..3).all(|j| (back[i][j] - m[i][j]).abs() < 1e-9)));
    }
}
