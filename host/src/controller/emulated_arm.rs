//! The emulated arm's geometry. The emulated controller emulates encoders only; the arm they sit
//! on is a model file (its "true" geometry, e.g. `truth.toml` from `kincal simulate`) that poses
//! them: at each landmark of an artefact placement the joint angles come from inverse
//! kinematics of that geometry, with seating noise, and go to the controller as a record script
//! (`pose_counts`). Two emulators with two identities posed from two geometries are two arms;
//! the same emulator posed from a changed geometry is the arm after a knock.
//!
//! Repeats are posed in the configuration of the landmark's first touch, as an operator touches
//! a landmark again the same way, so repeats measure repeatability (the floor).

use crate::controller::record::{Script, ScriptStep};
use crate::data::{Artefact, Measurement, Session, SESSION_FORMAT};
use crate::model::ArmModel;
use crate::simulate::{
    calibration_placements, touch_encoders, touch_encoders_from, validation_placements, Placement,
};
use kincal_protocol::biss::deg_to_counts;
use nalgebra::Vector3;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// The named artefact placement (`A_O`, `C_A`…`C_D`, `V_A`…`V_E`), or every name when unknown.
pub fn placement_named(name: &str) -> Result<Placement, Vec<String>> {
    let all: Vec<Placement> = calibration_placements().into_iter().chain(validation_placements()).collect();
    all.iter().find(|p| p.name == name).cloned().ok_or_else(|| all.into_iter().map(|p| p.name).collect())
}

/// Touch every landmark of `artefact` at `place` with the arm of geometry `truth`, `repeats`
/// times, the tip seated with `seating_noise_mm` (standard deviation per axis); landmarks the
/// arm cannot reach are left out. The session holds the exact joint angles (no encoder noise:
/// the emulated encoders add their own).
pub fn touch_placement(
    truth: &ArmModel,
    artefact: &Artefact,
    place: &Placement,
    repeats: u32,
    seating_noise_mm: f64,
    rng: &mut ChaCha8Rng,
) -> Session {
    let seat =
        Normal::new(0.0, seating_noise_mm.max(0.0)).unwrap_or_else(|_| Normal::new(0.0, 0.0).expect("0"));
    let mut first: Vec<Option<[f64; 6]>> = vec![None; artefact.landmarks.len()];
    let mut measurements = Vec::new();
    for repeat in 1..=repeats {
        for (k, l) in artefact.landmarks.iter().enumerate() {
            let noise = Vector3::new(seat.sample(rng), seat.sample(rng), seat.sample(rng));
            let touched = match &first[k] {
                Some(near) => touch_encoders_from(truth, place, l, noise, near, rng),
                None => touch_encoders(truth, place, l, noise, rng),
            };
            let Some(enc) = touched else { continue };
            first[k].get_or_insert(enc);
            measurements.push(Measurement {
                landmark: l.id.clone(),
                repeat,
                joints_deg: enc.to_vec(),
                std_deg: None,
                samples: None,
                rejected: None,
                at_unix_s: None,
            });
        }
    }
    Session {
        format: SESSION_FORMAT.into(),
        placement: place.name.clone(),
        purpose: "validation".into(),
        measurements,
        arm: None,
    }
}

/// The record script that poses the emulated arm at `session`'s touches.
pub fn script_of(session: &Session) -> Script {
    Script {
        steps: session
            .measurements
            .iter()
            .filter_map(|m| {
                let deg: [f64; 6] = m.joints_deg.as_slice().try_into().ok()?;
                Some(ScriptStep {
                    landmark: m.landmark.clone(),
                    repeat: m.repeat,
                    pose_counts: Some(deg.map(deg_to_counts)),
                    ..ScriptStep::default()
                })
            })
            .collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn repeats_keep_the_first_touchs_configuration_and_the_script_poses_them() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let artefact = crate::simulate::suta_artefact(&mut rng);
        let truth = ArmModel::suta_nominal();
        let place = placement_named("V_A").unwrap();
        let session = touch_placement(&truth, &artefact, &place, 3, 0.1, &mut rng);
        assert!(session.measurements.len() >= 40, "{} touches", session.measurements.len());
        for m in session.measurements.iter().filter(|m| m.repeat > 1) {
            let first =
                session.measurements.iter().find(|f| f.landmark == m.landmark && f.repeat == 1).unwrap();
            let a: [f64; 6] = m.joints_deg.as_slice().try_into().unwrap();
            let b: [f64; 6] = first.joints_deg.as_slice().try_into().unwrap();
            assert!(crate::calib::repeats::same_pose(&a, &b), "{} repeat {}", m.landmark, m.repeat);
        }
        let script = script_of(&session);
        assert_eq!(script.steps.len(), session.measurements.len());
        let counts = script.steps[0].pose_counts.unwrap();
        assert_eq!(counts[0], deg_to_counts(session.measurements[0].joints_deg[0]));
        let unknown = placement_named("V_Z").unwrap_err();
        assert!(unknown.contains(&"C_A".to_string()) && unknown.contains(&"V_E".to_string()));
    }
}
