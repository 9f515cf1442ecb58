//! The diagnosis loop on tracker runs, on the independent generator.

use kincal::calib::tracker_diagnose::{auto_tracker, diagnose_tracker, TrackerSetup};
use kincal_e2e::tracker_gen::{generate, GravitySag, TrackerOptions as GenOptions};
use kincal_e2e::tracker_setup::{nominal_model, scratch, split};

fn setup(model: kincal::model::ArmModel, sigma: Option<f64>) -> TrackerSetup {
    TrackerSetup {
        model,
        added: vec![],
        float_tool: vec![],
        drift_sessions: vec![],
        exclude_points: vec![],
        orientation_sigma_deg: None,
        stated_sigma_mm: sigma,
    }
}

#[test]
fn explore() {
    let dir = scratch("tracker-diag", "explore");
    let mut options = GenOptions::iiwa_five_sessions(3);
    options.gravity_sag = Some(GravitySag::floor_mounted(vec![0.0, 0.3, 0.0, 0.0, 0.0, 0.0, 0.0]));
    let generated = generate(&options);
    let nominal = nominal_model(&generated, &dir);
    let (cal, val) = split(&generated, &dir, &[0, 1, 2]);
    let floor = generated.true_floor_mm(&[3, 4]).rms_mm;
    let t = std::time::Instant::now();
    let d = diagnose_tracker(&setup(nominal.clone(), None), &cal, &val).expect("diagnoses");
    println!("{:.2} s, true floor {floor:.4}", t.elapsed().as_secs_f64());
    for l in &d.summary { println!("{l}"); }
    for c in d.candidates.iter().take(12).chain(&d.data_errors) {
        println!("{:<20} z {:>8.1} cv {:?} held {:.4} {:?} p {:?} {}", c.name, c.calibration_z, c.cv_gain, c.held_out_rms_mm, c.units_improved, c.p_value, c.significant);
    }
    let (auto, _) = auto_tracker(&setup(nominal, Some(0.02)), &cal, &val, 4).expect("auto");
    for s in &auto.steps { println!("{:?}", s); }
    println!("{:?}", auto.stop);
}
