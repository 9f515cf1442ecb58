//! The dataset-size study: more placements calibrate better on held-out data.

use kincal::calib::setup::SolveOptions;
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
        calibration: SolveOptions { restarts: Some(0), ..SolveOptions::default() },
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
