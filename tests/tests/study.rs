//! The dataset-size study: more placements calibrate better on held-out data.

use kincal::calib::setup::{Setup, SolveOptions};
use kincal::calib::study::{study, StudyOptions};
use kincal::data::Observations;
use kincal::model::ArmModel;
use kincal::simulate::{simulate, SimulationOptions};

#[test]
fn more_placements_give_lower_validation_error() {
    let nominal = ArmModel::suta_nominal();
    let sim = simulate(&nominal, &SimulationOptions { seed: 11, ..SimulationOptions::default() });
    let cal = Observations::from_sessions(&sim.calibration, &sim.artefact);
    let val = Observations::from_sessions(&sim.validation, &sim.artefact);
    let options = StudyOptions {
        subsets: 6,
        seed: 1,
        setup: Setup::new(SolveOptions { restarts: Some(0), ..SolveOptions::default() }),
        progress: false,
    };
    let rows = study(&nominal, &cal, &val, &options);
    assert_eq!(rows.len(), 5);
    // Distinct subsets: C(5, k) of them when that is fewer than the 6 asked for.
    let drawn: Vec<usize> = rows.iter().map(|r| r.calibrations + r.failed + r.implausible).collect();
    assert_eq!(drawn, vec![5, 6, 6, 5, 1]);
    for r in &rows {
        assert_eq!(r.implausible, 0, "{r:?}");
        assert!(r.min_mm <= r.mean_mm + 1e-12 && r.mean_mm <= r.max_mm + 1e-12, "{r:?}");
    }
    assert!(
        rows[4].mean_mm <= rows[0].mean_mm,
        "5 placements {} vs 1 placement {}",
        rows[4].mean_mm,
        rows[0].mean_mm
    );
    // Same seed, same study.
    let again = study(&nominal, &cal, &val, &options);
    assert_eq!(
        rows.iter().map(|r| r.rms_mm.clone()).collect::<Vec<_>>(),
        again.iter().map(|r| r.rms_mm.clone()).collect::<Vec<_>>()
    );
}

/// The same study on tracker sessions of the independent generator: more calibration sessions
/// give a lower held-out error (each held-out session's frame refitted), every subset once.
#[test]
fn more_sessions_give_lower_held_out_error() {
    use kincal_e2e::tracker_gen::{generate, TrackerOptions};
    use kincal_e2e::tracker_setup::{nominal_model, scratch, split};
    let dir = scratch("study", "sessions");
    let mut options = TrackerOptions::iiwa_five_sessions(12);
    for plan in &mut options.sessions {
        plan.poses = 40;
    }
    let generated = generate(&options);
    let nominal = nominal_model(&generated, &dir);
    let (cal, val) = split(&generated, &dir, &[0, 1, 2]);
    let options = StudyOptions { subsets: 3, seed: 1, setup: Setup::default(), progress: false };
    let rows = study(&nominal, &cal, &val, &options);
    for r in &rows {
        eprintln!(
            "{} sessions: {} calibrations, mean {:.4} mm ({:?})",
            r.groups, r.calibrations, r.mean_mm, r.rms_mm
        );
    }
    let drawn: Vec<usize> = rows.iter().map(|r| r.calibrations + r.failed + r.implausible).collect();
    assert_eq!(drawn, vec![3, 3, 1], "every subset of 3 sessions once");
    assert!(rows.iter().all(|r| r.implausible == 0 && r.calibrations > 0), "{rows:?}");
    assert!(
        rows[2].mean_mm < rows[0].mean_mm,
        "3 sessions {} vs 1 session {}",
        rows[2].mean_mm,
        rows[0].mean_mm
    );
    std::fs::remove_dir_all(dir).ok();
}
