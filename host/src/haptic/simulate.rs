//! `kincal haptic simulate`: a recording of a simulated PHANToM and tracker with known truth.
//!
//! The device has joint-sensor gain and offset errors (a poor initialisation), potentiometer
//! gimbals (quadratic, or linear), a 1 kHz stream; the tracker (90 Hz) sees a target on the
//! stylus, T1 on the first link and T2 on the turret (above, below or beside the central joint),
//! with position and rotation noise, and its samples arrive `delay_ms` later than the device's.
//! The user moves continuously. It shares the kinematics with the pipeline: the tests that
//! matter use the independent generator in `tests/src/haptic_gen.rs`.

use super::kinematics::{Device, SensorModel};
use super::recording::{DeviceStream, Recording, Step, TargetStream, REQUIRED_STEPS};
use super::reference::Pose;
use nalgebra::{Matrix3, Rotation3, UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use std::collections::BTreeMap;

/// Settings of a simulated recording.
#[derive(Clone, Debug)]
pub struct HapticSimOptions {
    /// Seed of the noise.
    pub seed: u64,
    /// Tracker delay behind the device, ms.
    pub delay_ms: f64,
    /// Potentiometer-like quadratic gimbal sensors (else linear).
    pub quadratic_gimbals: bool,
    /// Tracker rate, Hz.
    pub tracker_hz: f64,
    /// Tracker position noise, mm (standard deviation per axis).
    pub noise_mm: f64,
    /// Tracker rotation noise, degrees (standard deviation per axis).
    pub noise_deg: f64,
    /// Seconds of free motion in `joints/`.
    pub joints_seconds: f64,
    /// Height of landmark target T2 above the central joint, mm (negative: below, 0: beside);
    /// it sits 70 mm off the θ1 axis.
    pub t2_height_mm: f64,
}

impl Default for HapticSimOptions {
    fn default() -> Self {
        HapticSimOptions {
            seed: 1,
            delay_ms: 13.0,
            quadratic_gimbals: true,
            tracker_hz: 90.0,
            noise_mm: 0.1,
            noise_deg: 0.05,
            joints_seconds: 60.0,
            t2_height_mm: 50.0,
        }
    }
}

/// What the simulated recording was made with.
#[derive(Clone, Debug)]
pub struct HapticTruth {
    /// Device geometry.
    pub device: Device,
    /// True sensor models of joints 1–3 and gimbals 4–6.
    pub sensors: [SensorModel; 6],
    /// Device → tracker transform.
    pub eh: Pose,
    /// Stylus target in the stylus frame (rotation, offset of its origin from the HIP, mm).
    pub mount: Pose,
    /// Delay, ms.
    pub delay_ms: f64,
}

impl HapticTruth {
    /// True pose of the stylus target (target → tracker) for true joint angles.
    pub fn stylus_target(&self, theta: &[f64; 6]) -> Pose {
        let (re, te) = &self.eh;
        let r = self.device.rotation(theta);
        (re * r * self.mount.0, re * (self.device.position_mm(theta) + r * self.mount.1) + te)
    }

    /// True HIP position in tracker coordinates.
    pub fn hip(&self, theta: &[f64; 6]) -> Vector3<f64> {
        self.eh.0 * self.device.position_mm(theta) + self.eh.1
    }
}

/// Raw reading for true angle θ under `model` (the root nearest the linear one).
fn raw_for(model: &SensorModel, theta: f64) -> f64 {
    if model.j.abs() < 1e-12 {
        return (theta - model.m) / model.k;
    }
    let disc = (model.k * model.k - 4.0 * model.j * (model.m - theta)).max(0.0);
    (-model.k + disc.sqrt()) / (2.0 * model.j)
}

/// True joint angles of each step at time t (s).
fn motion(step: &str, t: f64) -> [f64; 6] {
    let phase = step.len() as f64;
    let s = t + phase;
    let free = [
        0.5 * (0.7 * s).sin() + 0.15 * (1.9 * s).sin(),
        0.45 + 0.3 * (0.5 * s + 1.0).sin(),
        0.3 + 0.35 * (0.83 * s).cos(),
        0.6 * (0.9 * s).sin(),
        0.5 * (1.1 * s + 0.3).sin(),
        1.5 * (0.6 * s).sin(),
    ];
    match step {
        // Towards and away from the device, briskly, as the delay step asks.
        "delay" => [
            0.3 * (1.7 * t).sin(),
            0.45 + 0.25 * (2.3 * t).sin() + 0.1 * (5.1 * t).sin(),
            0.3 + 0.3 * (3.1 * t).cos() + 0.1 * (6.7 * t).sin(),
            0.3 * (1.3 * t).sin(),
            0.3 * (0.9 * t).sin(),
            0.5 * (0.7 * t).sin(),
        ],
        "gimbal" => [0.1, 0.4, 0.3, 0.8 * (0.8 * t).sin(), 0.7 * (1.3 * t).sin(), 1.0 * (0.5 * t).sin()],
        "reference" => [
            0.1,
            0.4,
            0.3,
            0.2 + 0.03 * (0.9 * t).sin(),
            -0.1 + 0.02 * (0.7 * t).cos(),
            -2.6 + 5.2 * (0.5 - 0.5 * (std::f64::consts::TAU * t / 10.0).cos()),
        ],
        _ => free,
    }
}

fn step_seconds(step: &str, options: &HapticSimOptions) -> f64 {
    match step {
        "joints" => options.joints_seconds,
        "reference" => 20.0,
        _ => 20.0,
    }
}

/// Simulate a whole recording.
pub fn simulate_recording(options: &HapticSimOptions) -> (Recording, HapticTruth) {
    let device = Device::omni();
    let gimbal =
        |j: f64, k: f64, m: f64| SensorModel { j: if options.quadratic_gimbals { j } else { 0.0 }, k, m };
    let sensors = [
        SensorModel { j: 0.0, k: 1.02, m: 0.05 },
        SensorModel { j: 0.0, k: 0.97, m: -0.09 },
        SensorModel { j: 0.0, k: 1.03, m: 0.11 },
        gimbal(0.08, 1.04, 0.05),
        gimbal(-0.07, 0.97, -0.04),
        gimbal(0.05, 1.02, 0.08),
    ];
    let eh: Pose =
        (Rotation3::from_euler_angles(0.1, 0.6, -0.2).into_inner(), Vector3::new(220.0, -80.0, 950.0));
    let mount: Pose =
        (Rotation3::from_euler_angles(0.4, 0.2, -0.7).into_inner(), Vector3::new(12.0, -5.0, 40.0));
    let truth = HapticTruth { device, sensors, eh, mount, delay_ms: options.delay_ms };
    let mut rng = ChaCha8Rng::seed_from_u64(options.seed);
    let pos_noise = Normal::new(0.0, options.noise_mm.max(0.0))
        .unwrap_or_else(|_| Normal::new(0.0, 0.0).expect("zero noise"));
    let rot_noise = Normal::new(0.0, options.noise_deg.max(0.0).to_radians())
        .unwrap_or_else(|_| Normal::new(0.0, 0.0).expect("zero noise"));
    let central = Vector3::from(device.origin_mm) + Vector3::new(0.0, device.l2_mm, -device.l1_mm);
    let mut steps = BTreeMap::new();
    let names =
        REQUIRED_STEPS.iter().map(|(n, targets)| (*n, targets.to_vec())).chain([("verify", vec!["hip"])]);
    for (name, targets) in names {
        let seconds = step_seconds(name, options);
        let mut device_stream = DeviceStream::default();
        for k in 0..(seconds * 1000.0) as usize {
            let t = k as f64 / 1000.0;
            let theta = motion(name, t);
            device_stream.t_s.push(t);
            device_stream.raw.push(std::array::from_fn(|j| raw_for(&sensors[j], theta[j])));
        }
        let mut step = Step { device: device_stream, targets: BTreeMap::new() };
        for target in targets {
            let mut stream = TargetStream::default();
            for k in 0..(seconds * options.tracker_hz) as usize {
                // A sample stamped at t shows the pose of t − delay.
                let t = 0.05 + k as f64 / options.tracker_hz;
                if t > seconds {
                    break;
                }
                let theta = motion(name, t - options.delay_ms / 1000.0);
                let (r, p): (Matrix3<f64>, Vector3<f64>) = match target {
                    "t1" => {
                        // On the first link: rotates about the central joint with θ1 and θ2.
                        let link = (Rotation3::from_axis_angle(&Vector3::y_axis(), -theta[0])
                            * Rotation3::from_axis_angle(&Vector3::x_axis(), -theta[1]))
                        .into_inner();
                        (eh.0 * link, eh.0 * (central + link * Vector3::new(10.0, 30.0, 60.0)) + eh.1)
                    }
                    "t2" => {
                        // On the turret, `t2_height_mm` above the central joint: turns with θ1.
                        let turret = Rotation3::from_axis_angle(&Vector3::y_axis(), -theta[0]).into_inner();
                        (
                            eh.0 * turret,
                            eh.0 * (central
                                + Vector3::new(0.0, options.t2_height_mm, 0.0)
                                + turret * Vector3::new(0.0, 0.0, 70.0))
                                + eh.1,
                        )
                    }
                    _ => truth.stylus_target(&theta),
                };
                let noise_r = Rotation3::from_euler_angles(
                    rot_noise.sample(&mut rng),
                    rot_noise.sample(&mut rng),
                    rot_noise.sample(&mut rng),
                )
                .into_inner();
                stream.t_s.push(t);
                stream.position_mm.push(
                    p + Vector3::new(
                        pos_noise.sample(&mut rng),
                        pos_noise.sample(&mut rng),
                        pos_noise.sample(&mut rng),
                    ),
                );
                stream.rotation.push(UnitQuaternion::from_matrix(&(r * noise_r)));
            }
            step.targets.insert(target.to_string(), stream);
        }
        steps.insert(name.to_string(), step);
    }
    (Recording { device, device_name: "omni".into(), steps, convention: Default::default() }, truth)
}

/// Write a recording in the `haptic-recording/1` layout.
pub fn write_recording(recording: &Recording, dir: &std::path::Path) -> std::io::Result<()> {
    use std::fmt::Write;
    std::fs::create_dir_all(dir)?;
    let header = serde_json::json!({"format": super::recording::RECORDING_FORMAT, "device": recording.device_name, "l1_mm": recording.device.l1_mm, "l2_mm": recording.device.l2_mm});
    crate::files::write_atomic(&dir.join("recording.json"), header.to_string().as_bytes())?;
    for (name, step) in &recording.steps {
        let folder = dir.join(name);
        std::fs::create_dir_all(&folder)?;
        let mut text = String::from("t_s,raw1,raw2,raw3,raw4,raw5,raw6\n");
        for (t, r) in step.device.t_s.iter().zip(&step.device.raw) {
            let _ = writeln!(
                text,
                "{t:.6},{:.9},{:.9},{:.9},{:.9},{:.9},{:.9}",
                r[0], r[1], r[2], r[3], r[4], r[5]
            );
        }
        crate::files::write_atomic(&folder.join("device.csv"), text.as_bytes())?;
        for (target, s) in &step.targets {
            let mut text = String::from("t_s,x_mm,y_mm,z_mm,qw,qx,qy,qz\n");
            for ((t, p), q) in s.t_s.iter().zip(&s.position_mm).zip(&s.rotation) {
                let _ = writeln!(
                    text,
                    "{t:.6},{:.6},{:.6},{:.6},{:.9},{:.9},{:.9},{:.9}",
                    p.x, p.y, p.z, q.w, q.i, q.j, q.k
                );
            }
            crate::files::write_atomic(&folder.join(format!("{target}.csv")), text.as_bytes())?;
        }
    }
    Ok(())
}
