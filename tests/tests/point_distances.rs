//! A new observation kind is one file of terms plus its reader: frame-free distances between an
//! instrument's points (`kincal-point-distances/1`, `host/src/data/point_distances.rs` and
//! `host/src/calib/terms/point_distance.rs`). Sessions of the independent tracker generator,
//! written under that tag, calibrate the arm with no frame fitted at all, and the model is at the
//! floor on held-out tracker sessions (each frame refitted there), as a calibration on the same
//! sessions as framed points is.

use kincal::calib::run::{run, EXPLAINS_WITHIN};
use kincal::calib::setup::SolveOptions;
use kincal::calib::summary::RunInputs;
use kincal::data::point_distances::POINT_DISTANCES_FORMAT;
use kincal_e2e::tracker_gen::{generate, TrackerOptions, FOLDER_TAG};
use kincal_e2e::tracker_setup::{nominal_model, scratch};

#[test]
fn frame_free_distances_alone_calibrate_the_arm_to_the_floor_of_held_out_sessions() {
    let dir = scratch("point-distances", "iiwa");
    let generated = generate(&TrackerOptions::iiwa_five_sessions(23));
    nominal_model(&generated, &dir);
    for to in ["framed", "free", "val"] {
        std::fs::create_dir_all(dir.join(to)).expect("folder");
    }
    for s in 0..generated.sessions.len() {
        let name = format!("{}.csv", generated.sessions[s].plan.name);
        let csv = generated.csv(s);
        if s < 3 {
            std::fs::write(dir.join("framed").join(&name), &csv).expect("written");
            let free = csv.replacen(&format!("# {FOLDER_TAG}"), &format!("# {POINT_DISTANCES_FORMAT}"), 1);
            std::fs::write(dir.join("free").join(&name), free).expect("written");
        } else {
            std::fs::write(dir.join("val").join(&name), &csv).expect("written");
        }
    }
    let calibrate = |folder: &str| {
        let inputs = RunInputs::new(dir.join("nominal.toml"), None, dir.join(folder), dir.join("val"));
        run(&inputs, &SolveOptions::default(), 0, true).expect("calibrates")
    };
    let (free, framed) = (calibrate("free"), calibrate("framed"));
    let held_out = |r: &kincal::calib::run::Run| {
        r.summary.validation.sessions.as_ref().expect("held out").overall.rms_mm
    };
    let floor = free.summary.point_floor().rms_mm.expect("stated σ gives a floor");
    println!(
        "held out: frame-free distances {:.4} mm, framed points {:.4} mm, floor {floor:.4} mm; {} distances",
        held_out(&free),
        held_out(&framed),
        free.summary.calibration.distances.map_or(0, |d| d.count)
    );
    // No frame was fitted: the calibration's rows are the distances, every pair of each session.
    let pairs: usize = (0..3).map(|s| generated.sessions[s].rows.len()).map(|n| n * (n - 1) / 2).sum();
    assert_eq!(free.summary.calibration.distances.map(|d| d.count), Some(pairs));
    assert!(free.summary.calibration.points.is_none());
    assert!(held_out(&free) <= EXPLAINS_WITHIN * floor, "{} vs floor {floor}", held_out(&free));
    assert!(held_out(&free) <= 1.05 * held_out(&framed), "{} vs {}", held_out(&free), held_out(&framed));
    // What distances cannot see is said: the base's placement is not in them.
    let fixed = &free.summary.identifiability.report.fixed;
    assert!(fixed.iter().any(|p| p == "offset:1"), "{fixed:?}");
    std::fs::remove_dir_all(dir).ok();
}
