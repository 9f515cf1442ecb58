//! The pipeline on simulated recordings with known truth.

use super::*;
use crate::haptic::simulate::{simulate_recording, HapticSimOptions};

/// Noise floors of the simulated tracker on verify/: RMS distance of the measured HIP from
/// the true one, and RMS angle of the measured stylus axis from the true one.
fn floors(rec: &Recording, truth: &crate::haptic::simulate::HapticTruth) -> (f64, f64) {
    let verify = &rec.steps["verify"];
    let hip = &verify.targets["hip"];
    let tip_true = -(truth.mount.0.transpose() * truth.mount.1);
    let axis_true = truth.mount.0.transpose() * Vector3::z();
    let (mut dp, mut da) = (Vec::new(), Vec::new());
    for ((t, q), p) in hip.t_s.iter().zip(&hip.rotation).zip(&hip.position_mm) {
        let theta: [f64; 6] = {
            let raw = raw_at(&verify.device, t - truth.delay_ms / 1000.0);
            angles(&truth.sensors, &raw)
        };
        let (r_true, _) = truth.stylus_target(&theta);
        dp.push((q * tip_true + p - truth.hip(&theta)).norm());
        da.push((q * axis_true).dot(&(r_true * axis_true)).clamp(-1.0, 1.0).acos().to_degrees());
    }
    (rms(&dp), rms(&da))
}

#[test]
fn a_simulated_recording_calibrates_to_the_tracker_noise_floor() {
    for quadratic in [true, false] {
        let options = HapticSimOptions {
            seed: 5,
            delay_ms: 13.3,
            quadratic_gimbals: quadratic,
            joints_seconds: 40.0,
            ..HapticSimOptions::default()
        };
        let (rec, truth) = simulate_recording(&options);
        let result = calibrate_recording(&rec).expect("calibrates");
        let (floor_mm, floor_deg) = floors(&rec, &truth);
        eprintln!("quadratic {quadratic}: delay {:.3} ms, position {:.3} → {:.3} mm (floor {floor_mm:.3}), orientation {:.3} → {:.3}° (floor {floor_deg:.3}), gimbals {:?}", result.delay_ms, result.position_mm.before, result.position_mm.after, result.orientation_deg.before, result.orientation_deg.after, result.gimbal_model);
        assert!(
            (result.delay_ms - options.delay_ms).abs() < 0.25,
            "delay {} vs {}",
            result.delay_ms,
            options.delay_ms
        );
        assert!(result.position_mm.before > 3.0 * result.position_mm.after);
        assert!(
            result.position_mm.after <= 1.10 * floor_mm,
            "position {} vs floor {floor_mm}",
            result.position_mm.after
        );
        assert!(
            result.orientation_deg.after <= 1.10 * floor_deg,
            "orientation {} vs floor {floor_deg}",
            result.orientation_deg.after
        );
        assert_eq!(result.gimbal_model, if quadratic { GimbalModel::Quadratic } else { GimbalModel::Linear });
    }
}
