//! Appendix-F outlier diagnostics find a landmark whose certified position is wrong.

use kincal::calib::fit::calibrate;
use kincal::calib::outliers::landmark_outliers;
use kincal::calib::setup::SolveOptions;
use kincal::data::Observations;
use kincal::model::ArmModel;
use kincal::simulate::{simulate, SimulationOptions};

#[test]
fn a_miscertified_landmark_is_flagged_and_no_other() {
    let nominal = ArmModel::suta_nominal();
    let sim = simulate(&nominal, &SimulationOptions { seed: 9, ..SimulationOptions::default() });
    let cal = Observations::from_sessions(&sim.calibration, &sim.artefact);
    let val = Observations::from_sessions(&sim.validation, &sim.artefact);
    let options = SolveOptions { restarts: Some(0), ..SolveOptions::default() };
    // Clean data: nothing is flagged.
    let fit = calibrate(&nominal, &cal, &options).unwrap();
    let clean = landmark_outliers(&fit, &cal, Some(&val), &options);
    assert!(clean.iter().all(|o| !o.flagged), "{clean:#?}");
    // The certificate of S2 is 2 mm off (the pillar was touched where it really is).
    let mut artefact = sim.artefact.clone();
    let s2 = artefact.index_of("S2").unwrap();
    artefact.landmarks[s2].xyz_mm[0] += 1.6;
    artefact.landmarks[s2].xyz_mm[1] -= 1.2;
    let (cal, val) = (cal.with_landmarks(&artefact.landmarks), val.with_landmarks(&artefact.landmarks));
    let fit = calibrate(&nominal, &cal, &options).unwrap();
    let report = landmark_outliers(&fit, &cal, Some(&val), &options);
    let flagged: Vec<&str> = report.iter().filter(|o| o.flagged).map(|o| o.landmark.as_str()).collect();
    assert_eq!(flagged, vec!["S2"], "{report:#?}");
    let worst = report.iter().max_by(|a, b| a.contribution_pct.total_cmp(&b.contribution_pct)).unwrap();
    assert_eq!(worst.landmark, "S2");
    assert!(report[s2].bias_mm > 1.0, "bias {}", report[s2].bias_mm);
}
