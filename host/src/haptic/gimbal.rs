//! Gimbal calibration against a reference stylus axis and roll.
//!
//! θ4 and θ5 are fitted by Levenberg–Marquardt minimising 1 − ẑ_ref·(R123·R4(θ4)·R5(θ5)·e_z) per
//! sample (ẑ_ref, the physical stylus axis in device coordinates); θ6 by linear least squares
//! against the reference roll. Each gimbal gets a linear (θ = k·raw + m) and a quadratic
//! (θ = j·raw² + k·raw + m) sensor model — potentiometers are often non-linear — and the model
//! is chosen by the error on held-out samples, never by the fit error: the quadratic model only
//! when it lowers the held-out error by more than [`QUADRATIC_GAIN`].

use super::kinematics::{Device, SensorModel};
use crate::numerics::solver::{self, Residuals, SolverOptions, Termination};
use crate::numerics::stats::rms;
use nalgebra::{DMatrix, DVector, Vector3};

/// Relative held-out improvement the quadratic model must bring to be chosen.
pub const QUADRATIC_GAIN: f64 = 0.05;

/// One sample for the gimbal calibration.
#[derive(Clone, Copy, Debug)]
pub struct GimbalSample {
    /// Calibrated joint angles θ1–θ3, radians.
    pub theta123: [f64; 3],
    /// Raw readings of the gimbals 4–6, radians.
    pub raw: [f64; 3],
    /// Reference stylus axis in device coordinates (unit).
    pub axis: Vector3<f64>,
    /// Reference roll θ6, radians, where known (the roll step).
    pub roll: Option<f64>,
}

/// Which sensor model a gimbal uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum GimbalModel {
    /// θ = k·raw + m.
    Linear,
    /// θ = j·raw² + k·raw + m.
    Quadratic,
}

impl GimbalModel {
    /// The model in words, as the CLI and the report say it.
    pub fn words(self) -> &'static str {
        match self {
            GimbalModel::Linear => "linear (θ = k·raw + m)",
            GimbalModel::Quadratic => "quadratic (θ = j·raw² + k·raw + m)",
        }
    }
}

/// Result of the gimbal calibration.
#[derive(Clone, Debug)]
pub struct GimbalCalibration {
    /// Sensor models of gimbals 4, 5, 6.
    pub sensors: [SensorModel; 3],
    /// The model chosen.
    pub model: GimbalModel,
    /// Held-out axis error of the linear and the quadratic model, degrees (RMS).
    pub held_out_deg: (f64, f64),
}

fn axis(device: &Device, s: &GimbalSample, t4: f64, t5: f64) -> Vector3<f64> {
    let r = device.rotation(&[s.theta123[0], s.theta123[1], s.theta123[2], t4, t5, 0.0]);
    r.column(2).into_owned()
}

/// Axis errors of `sensors` on `samples`, degrees.
pub fn axis_errors_deg(device: &Device, sensors: &[SensorModel; 3], samples: &[GimbalSample]) -> Vec<f64> {
    samples
        .iter()
        .map(|s| {
            axis(device, s, sensors[0].angle(s.raw[0]), sensors[1].angle(s.raw[1]))
                .dot(&s.axis)
                .clamp(-1.0, 1.0)
                .acos()
                .to_degrees()
        })
        .collect()
}

struct AxisProblem<'a> {
    device: &'a Device,
    samples: &'a [GimbalSample],
    quadratic: bool,
}

impl AxisProblem<'_> {
    fn models(&self, x: &[f64]) -> (SensorModel, SensorModel) {
        if self.quadratic {
            (SensorModel { j: x[4], k: x[0], m: x[1] }, SensorModel { j: x[5], k: x[2], m: x[3] })
        } else {
            (SensorModel { j: 0.0, k: x[0], m: x[1] }, SensorModel { j: 0.0, k: x[2], m: x[3] })
        }
    }

    fn residual(&self, x: &[f64], s: &GimbalSample) -> f64 {
        let (g4, g5) = self.models(x);
        1.0 - axis(self.device, s, g4.angle(s.raw[0]), g5.angle(s.raw[1])).dot(&s.axis)
    }
}

impl Residuals for AxisProblem<'_> {
    fn len(&self) -> usize {
        self.samples.len()
    }

    fn evaluate(&self, x: &[f64], r: &mut [f64], jacobian: Option<&mut [f64]>) {
        for (i, s) in self.samples.iter().enumerate() {
            r[i] = self.residual(x, s);
        }
        // Central differences: a handful of parameters, closed-form residuals.
        if let Some(j) = jacobian {
            let n = x.len();
            let mut xp = x.to_vec();
            for c in 0..n {
                let h = 1e-7 * (1.0 + x[c].abs());
                xp[c] = x[c] + h;
                let plus: Vec<f64> = self.samples.iter().map(|s| self.residual(&xp, s)).collect();
                xp[c] = x[c] - h;
                for (i, s) in self.samples.iter().enumerate() {
                    j[i * n + c] = (plus[i] - self.residual(&xp, s)) / (2.0 * h);
                }
                xp[c] = x[c];
            }
        }
    }
}

fn fit(device: &Device, samples: &[GimbalSample], quadratic: bool) -> [SensorModel; 3] {
    let problem = AxisProblem { device, samples, quadratic };
    let (x0, lower, upper): (Vec<f64>, Vec<f64>, Vec<f64>) = if quadratic {
        (
            vec![1.0, 0.0, 1.0, 0.0, 0.0, 0.0],
            vec![0.5, -1.0, 0.5, -1.0, -0.5, -0.5],
            vec![1.5, 1.0, 1.5, 1.0, 0.5, 0.5],
        )
    } else {
        (vec![1.0, 0.0, 1.0, 0.0], vec![0.5, -1.0, 0.5, -1.0], vec![1.5, 1.0, 1.5, 1.0])
    };
    let solved = solver::solve(
        &problem,
        &x0,
        &lower,
        &upper,
        &SolverOptions {
            max_iterations: 100,
            termination: Termination::AcceptedSteps,
            ..SolverOptions::default()
        },
    );
    let (g4, g5) = problem.models(&solved.x);
    // θ6 by linear least squares on (raw², raw, 1) or (raw, 1), over the samples with a roll.
    let cols = if quadratic { 3 } else { 2 };
    let rolls: Vec<(f64, f64)> = samples.iter().filter_map(|s| s.roll.map(|r| (s.raw[2], r))).collect();
    let a = DMatrix::from_fn(rolls.len(), cols, |i, c| rolls[i].0.powi((cols - 1 - c) as i32));
    let b = DVector::from_iterator(rolls.len(), rolls.iter().map(|r| r.1));
    let coef = a.svd(true, true).solve(&b, 1e-12).unwrap_or_else(|_| DVector::zeros(cols));
    let g6 = if quadratic {
        SensorModel { j: coef[0], k: coef[1], m: coef[2] }
    } else {
        SensorModel { j: 0.0, k: coef[0], m: coef[1] }
    };
    [g4, g5, g6]
}

/// Held-out axis error (degrees, RMS) of the linear model fitted on `calibration`: a quick
/// score of how well a reading convention explains the data.
pub fn linear_held_out_deg(device: &Device, calibration: &[GimbalSample], held_out: &[GimbalSample]) -> f64 {
    rms(&axis_errors_deg(device, &fit(device, calibration, false), held_out))
}

/// Fit both sensor models on `calibration` and choose by the error on `held_out`.
pub fn calibrate_gimbals(
    device: &Device,
    calibration: &[GimbalSample],
    held_out: &[GimbalSample],
) -> GimbalCalibration {
    let linear = fit(device, calibration, false);
    let quadratic = fit(device, calibration, true);
    let (e_lin, e_quad) = (
        rms(&axis_errors_deg(device, &linear, held_out)),
        rms(&axis_errors_deg(device, &quadratic, held_out)),
    );
    let (sensors, model) = if e_quad < (1.0 - QUADRATIC_GAIN) * e_lin {
        (quadratic, GimbalModel::Quadratic)
    } else {
        (linear, GimbalModel::Linear)
    };
    GimbalCalibration { sensors, model, held_out_deg: (e_lin, e_quad) }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, Normal};

    fn samples(truth: &[SensorModel; 3], n: usize, seed: u64) -> Vec<GimbalSample> {
        let device = Device::omni();
        let noise = Normal::new(0.0, 0.05f64.to_radians()).unwrap();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        (0..n)
            .map(|k| {
                let s = k as f64 * 0.37 + seed as f64;
                let raw = [0.9 * (0.7 * s).sin(), 0.8 * (1.3 * s).cos(), 1.5 * (0.45 * s).sin()];
                let theta123 =
                    [0.3 * (0.2 * s).sin(), 0.4 + 0.2 * (0.3 * s).cos(), 0.3 + 0.2 * (0.5 * s).sin()];
                let s0 = GimbalSample { theta123, raw, axis: Vector3::z(), roll: None };
                let true_axis = axis(
                    &device,
                    &s0,
                    truth[0].angle(raw[0]) + noise.sample(&mut rng),
                    truth[1].angle(raw[1]) + noise.sample(&mut rng),
                );
                GimbalSample {
                    axis: true_axis,
                    roll: Some(truth[2].angle(raw[2]) + noise.sample(&mut rng)),
                    ..s0
                }
            })
            .collect()
    }

    #[test]
    fn the_model_is_chosen_by_held_out_error() {
        let device = Device::omni();
        let linear = [
            SensorModel { j: 0.0, k: 1.05, m: 0.04 },
            SensorModel { j: 0.0, k: 0.96, m: -0.06 },
            SensorModel { j: 0.0, k: 1.02, m: 0.1 },
        ];
        let pot = [
            SensorModel { j: 0.12, k: 1.05, m: 0.04 },
            SensorModel { j: -0.1, k: 0.96, m: -0.06 },
            SensorModel { j: 0.08, k: 1.02, m: 0.1 },
        ];
        let got = calibrate_gimbals(&device, &samples(&linear, 300, 1), &samples(&linear, 150, 2));
        assert_eq!(got.model, GimbalModel::Linear, "{:?}", got.held_out_deg);
        assert!(got.held_out_deg.0 < 0.1, "linear held-out error {}°", got.held_out_deg.0);
        let got = calibrate_gimbals(&device, &samples(&pot, 300, 3), &samples(&pot, 150, 4));
        assert_eq!(got.model, GimbalModel::Quadratic, "{:?}", got.held_out_deg);
        assert!(got.held_out_deg.1 < 0.1 && got.held_out_deg.0 > 0.3, "{:?}", got.held_out_deg);
        assert!((got.sensors[2].j - 0.08).abs() < 0.01, "roll model {:?}", got.sensors[2]);
    }
}
