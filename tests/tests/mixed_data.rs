//! One calibration from artefact placements and tracker sessions together. The same true arm
//! (the SUTA nominal with its parameters perturbed by kincal's simulator) is touched on the
//! artefact by `kincal::simulate` and measured by a laser tracker in the independent generator
//! (`kincal_e2e::tracker_gen`, its own kinematics); both kinds go into one calibration folder and
//! one held-out folder. The one engine fits the arm, each tracker session's frame and nothing
//! else, and the calibrated model is at the floor on both kinds of held-out data.

use kincal::calib::run::{run, EXPLAINS_WITHIN};
use kincal::calib::setup::SolveOptions;
use kincal::calib::summary::RunInputs;
use kincal::data::DataKind;
use kincal::model::ArmModel;
use kincal::simulate::{simulate, SimulationOptions};
use kincal_e2e::tracker_gen::{generate, Arm, Chain, DhRow, HiddenErrorSizes, SessionPlan, TrackerOptions};
use kincal_e2e::tracker_setup::scratch;

/// The simulator's true arm as the tracker generator's arm (classic DH rows, the same tool).
fn as_generator_arm(truth: &ArmModel) -> Arm {
    // The simulator perturbs the free parameters only: DH values and the tool, nothing else.
    for f in &truth.free {
        let name = f.id.to_string();
        assert!(["offset:", "length:", "tcp."].iter().any(|p| name.starts_with(p)), "{name}");
    }
    assert_eq!(truth.scale_ppm, 0.0);
    let rows = truth
        .joints
        .iter()
        .map(|j| DhRow {
            theta_offset_deg: j.offset_deg,
            d_mm: j.d_mm,
            a_mm: j.a_mm,
            alpha_deg: j.alpha_deg,
            beta_deg: j.axis_deg,
        })
        .collect();
    Arm {
        name: "SUTA truth".into(),
        chain: Chain::ClassicDh(rows),
        limits_deg: vec![(-170.0, 170.0); truth.joints.len()],
        tool_mm: truth.tcp_mm,
        tool_rpy_deg: [0.0; 3],
        min_z_mm: -400.0,
        min_radius_mm: 200.0,
    }
}

#[test]
fn artefact_placements_and_tracker_sessions_calibrate_together_to_the_floor_of_both() {
    let dir = scratch("mixed", "suta");
    let nominal = ArmModel::suta_nominal();
    let sim = simulate(&nominal, &SimulationOptions::default());
    sim.write(&dir).expect("artefact sessions written");
    nominal.save(&dir.join("nominal.toml")).expect("model saved");
    let options = TrackerOptions {
        arm: as_generator_arm(&sim.truth),
        hidden: HiddenErrorSizes {
            offset_deg: 0.0,
            length_mm: 0.0,
            twist_deg: 0.0,
            beta_deg: 0.0,
            tool_mm: 0.0,
        },
        sessions: (1..=3)
            .map(|k| SessionPlan {
                name: format!("tracker_{k}"),
                poses: 60,
                constant_orientation: false,
                joints_deg: Vec::new(),
            })
            .collect(),
        ..TrackerOptions::iiwa_five_sessions(11)
    };
    let generated = generate(&options);
    assert_eq!(generated.truth.truth, options.arm, "the tracker measures the simulator's true arm");
    generated.write(&dir.join("tracker")).expect("tracker sessions written");
    for (name, to) in [("tracker_1", "cal"), ("tracker_2", "cal"), ("tracker_3", "val")] {
        let file = format!("{name}.csv");
        std::fs::rename(dir.join("tracker").join(&file), dir.join(to).join(&file)).expect("session moved");
    }
    let inputs = RunInputs::new(
        dir.join("nominal.toml"),
        Some(dir.join("artefact.json")),
        dir.join("cal"),
        dir.join("val"),
    );
    let run = run(&inputs, &SolveOptions::default(), 0, true).expect("a mixed calibration runs");
    let s = &run.summary;
    assert_eq!(s.kind, DataKind::Mixed);
    assert_eq!(s.calibration.groups.len(), 5 + 2, "five placements and two sessions calibrate");
    assert!(s.not_trustworthy.is_empty(), "{:?}", s.not_trustworthy);
    // Held-out distances against their floor (repeated touches).
    let gap = s.floor.distance_gap.as_ref().expect("repeated touches give the distance floor");
    println!("distances: {:.4} mm held out, floor {:.4} mm", gap.measured_mm, gap.expected_mm);
    assert!(gap.measured_mm <= EXPLAINS_WITHIN * gap.expected_mm, "{}", gap.sentence());
    // Held-out tracker points against theirs (the stated σ).
    let sessions = s.validation.sessions.as_ref().expect("a held-out tracker session");
    let floor = s.point_floor().rms_mm.expect("stated σ gives the point floor");
    println!("points: {:.4} mm held out, floor {floor:.4} mm", sessions.overall.rms_mm);
    assert!(sessions.overall.rms_mm <= EXPLAINS_WITHIN * floor, "{} vs {floor}", sessions.overall.rms_mm);
    assert!(sessions.overall.rms_mm < 0.1 * sessions.nominal_overall.rms_mm, "{sessions:?}");
    // The tool is the same on both kinds: one tool point, no floated tool, no extra unknown.
    assert!(s.calibration.tool_offsets.is_empty());
    let tcp = s.calibration.estimates.iter().find(|e| e.param == "tcp.z").expect("tcp.z");
    assert!((tcp.value - sim.truth.tcp_mm[2]).abs() < 3.0 * tcp.std.unwrap_or(0.05).max(0.05), "{tcp:?}");
    std::fs::remove_dir_all(dir).ok();
}
