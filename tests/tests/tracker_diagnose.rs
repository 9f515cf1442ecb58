//! The loop on tracker runs (`kincal diagnose`, `--auto`, `compare`), on the independent
//! generator (`kincal_e2e::tracker_gen`, no forward code shared with kincal): a hidden arm effect
//! is named and the auto loop reaches the floor, a re-mounted tool is named as a data error and
//! no arm effect is claimed, clean data are called explained, an unknown floor never is, and a RUN
//! whose data moved or changed is refused naming the folder or file.

use kincal::calib::diagnose::auto::{auto_loop, Stop};
use kincal::calib::diagnose::{diagnose, held_out_rms_mm};
use kincal::calib::setup::Setup;
use kincal::data::Observations;
use kincal::model::ArmModel;
use kincal_e2e::kincal_bin;
use kincal_e2e::tracker_gen::{
    generate, EncoderHarmonic, GravitySag, ToolRemount, TrackerData as Generated,
    TrackerOptions as GenOptions, UncertaintyColumn,
};
use kincal_e2e::tracker_setup::{nominal_model, scratch, split};
use std::path::Path;
use std::process::Command;

/// The generator's 7-joint arm, five sessions of 40 poses, σ = 0.02 mm stated per point.
fn five_sessions(seed: u64) -> GenOptions {
    let mut options = GenOptions::iiwa_five_sessions(seed);
    for plan in &mut options.sessions {
        plan.poses = 40;
    }
    options
}

/// Generate, write three calibration and two held-out sessions, read them back and calibrate
/// the nominal model (no options): the setup and the calibrated model.
fn sessions(
    name: &str,
    options: &GenOptions,
) -> (std::path::PathBuf, Generated, Setup, ArmModel, Observations, Observations) {
    let dir = scratch("tracker-diagnose", name);
    let generated = generate(options);
    let nominal = nominal_model(&generated, &dir);
    let (cal, val) = split(&generated, &dir, &[0, 1, 2]);
    let setup = Setup::default();
    let calibrated = setup.calibrate(&nominal, &cal).expect("calibrates").model;
    (dir, generated, setup, calibrated, cal, val)
}

fn sag_on(joint: usize, deg_per_m: f64) -> GravitySag {
    let mut c = vec![0.0; 7];
    c[joint - 1] = deg_per_m;
    GravitySag::floor_mounted(c)
}

/// Must show: gravity sag on joint 2 of the 7-joint arm, hidden in tracker data: the diagnosis
/// names the joint's compliance (alone or among rivals), claims no data error, and the auto loop
/// ends within 1.10× the true floor.
#[test]
fn hidden_gravity_sag_is_named_and_the_auto_loop_reaches_the_floor() {
    for (seed, joint) in [(21, 2)] {
        let mut options = five_sessions(seed);
        options.gravity_sag = Some(sag_on(joint, 0.02));
        let (dir, generated, setup, model, cal, val) = sessions(&format!("sag-{seed}"), &options);
        let floor = generated.true_floor_mm(&[3, 4]).rms_mm;
        let auto = auto_loop(&setup, &model, &cal, &val, 4).expect("auto loop");
        let effect = format!("compliance:{joint}");
        println!(
            "seed {seed}, sag on joint {joint}, true floor {floor:.4} mm:\n  {}",
            auto.last.summary.join("\n  ")
        );
        let first = &auto.steps[0];
        assert!(first.named.contains(&effect) && first.incomplete, "seed {seed}: {:?} named", first.named);
        assert!(first.named.iter().all(|n| !n.starts_with("tool moved") && !n.starts_with("drift")));
        // The first step applies what the first diagnosis named first.
        assert_eq!(auto.steps[1].applied.as_deref(), Some(effect.as_str()), "seed {seed}: {:?}", auto.steps);
        assert_eq!(auto.steps[1].action.as_deref(), Some(format!("--add {effect}").as_str()));
        assert!(auto.steps[1].p_value.is_some_and(|p| p < 0.05));
        let end = auto.steps.last().expect("steps").held_out_rms_mm;
        for s in &auto.steps {
            println!("  step {:?}: {:.4} mm (p {:?})", s.applied, s.held_out_rms_mm, s.p_value);
        }
        assert_eq!(auto.stop, Stop::AtFloor, "seed {seed}: {:?}", auto.last.summary);
        assert!(end <= 1.10 * floor, "seed {seed}: auto ends at {end:.4} mm, true floor {floor:.4} mm");
        assert!(auto.setup.added().contains(&effect), "{:?}", auto.setup.added());
        std::fs::remove_dir_all(dir).ok();
    }
}

/// Must show: a 2-per-revolution encoder error on joint 4 (0.02° sin, −0.01° cos). Seen over the
/// joint's whole range it is named alone; seen over 30° only, its 1st and 2nd harmonics look alike
/// there, and the diagnosis names them as rivals (a statement, never one alone). Either way the
/// auto loop ends within 1.10× the true floor.
#[test]
fn a_two_per_rev_error_is_named_alone_or_among_rivals_when_coverage_cannot_tell() {
    for (span, rivals) in [(None, false), (Some(30.0), true)] {
        let mut options = five_sessions(61);
        options.encoder_harmonic =
            Some(EncoderHarmonic { joint: 4, order: 2, sin_deg: 0.02, cos_deg: -0.01 });
        options.low_coverage = span.map(|s| (4, s));
        let (dir, generated, setup, model, cal, val) = sessions(&format!("harmonic-{span:?}"), &options);
        let floor = generated.true_floor_mm(&[3, 4]).rms_mm;
        let auto = auto_loop(&setup, &model, &cal, &val, 3).expect("auto loop");
        let first = &auto.steps[0];
        println!("joint 4 seen over {span:?}°, true floor {floor:.4} mm: {:?} named", first.named);
        for s in &auto.steps {
            println!("  step {:?}: {:.4} mm", s.applied, s.held_out_rms_mm);
        }
        assert!(first.named.contains(&"eccentricity2:4".to_string()), "{:?}", first.named);
        assert_eq!(first.named.len() > 1, rivals, "{:?}", first.named);
        let end = auto.steps.last().expect("steps").held_out_rms_mm;
        assert!(end <= 1.10 * floor, "{span:?}: auto ends at {end:.4} mm, true floor {floor:.4} mm");
        std::fs::remove_dir_all(dir).ok();
    }
}

/// Must show: a tool re-mounted 0.8 mm in calibration session 2: the data error names that
/// session and the tool, no arm effect is claimed, and after the suggested action (`--float-tool
/// session_2`) the held-out RMS is within 1.10× the true floor.
#[test]
fn a_remounted_tool_is_the_data_error_and_no_arm_effect_is_claimed() {
    // Sixty poses a session, as the calibration tests use: with forty, the 30 arm values and the
    // floated tool leave the held-out error 1.13× the floor on this seed.
    let mut options = GenOptions::iiwa_five_sessions(5);
    options.tool_remount = Some(ToolRemount { session: 1, size_mm: 0.8 });
    let (dir, generated, setup, model, cal, val) = sessions("remount", &options);
    let floor = generated.true_floor_mm(&[3, 4]).rms_mm;
    let d = diagnose(&setup, &model, &cal, &val).expect("diagnoses");
    println!("true floor {floor:.4} mm:\n  {}", d.summary.join("\n  "));
    assert_eq!(d.named, ["tool moved: session_2"], "{:?}", d.summary);
    assert_eq!(d.action.as_deref(), Some("--float-tool session_2"));
    assert!(d.summary.iter().any(|l| l.contains("no arm effect is claimed")), "{:?}", d.summary);
    let (after, start) = setup.apply(&d.change.clone().expect("a change"), &model);
    let refit = after.calibrate(&start, &cal).expect("refit");
    let rms = held_out_rms_mm(&after, &refit.model, &val).expect("held-out sessions");
    println!("after --float-tool session_2: {rms:.4} mm held out");
    assert!(rms <= 1.10 * floor, "{rms:.4} mm vs true floor {floor:.4} mm");
    std::fs::remove_dir_all(dir).ok();
}

/// Must show: clean data (the model complete, a stated σ), over seeds: nothing is named, no data
/// error called, and the verdict says the model explains the held-out data. Without any stated
/// σ or repeat the floor is unknown: never "explains", with or without a hidden effect.
#[test]
fn clean_data_are_explained_and_an_unknown_floor_never_is() {
    for seed in [31, 32, 33] {
        let (dir, _, setup, model, cal, val) = sessions(&format!("clean-{seed}"), &five_sessions(seed));
        let d = diagnose(&setup, &model, &cal, &val).expect("diagnoses");
        println!("seed {seed}:\n  {}", d.summary.join("\n  "));
        assert!(d.named.is_empty(), "seed {seed}: {:?} named on clean data", d.named);
        assert!(d.candidates.iter().chain(&d.data_errors).all(|c| !c.significant), "seed {seed}");
        assert!(d.explains && !d.incomplete, "seed {seed}: {:?}", d.summary);
        assert!(d.summary[0].starts_with("the model explains the held-out data"), "{:?}", d.summary);
        std::fs::remove_dir_all(dir).ok();
    }
    let unknown = |seed: u64, sag: Option<GravitySag>| {
        let mut options = five_sessions(seed);
        options.uncertainty = UncertaintyColumn::None;
        options.gravity_sag = sag;
        sessions(&format!("unknown-{seed}"), &options)
    };
    let (dir, _, setup, model, cal, val) = unknown(34, None);
    let d = diagnose(&setup, &model, &cal, &val).expect("diagnoses");
    println!("seed 34, no σ:\n  {}", d.summary.join("\n  "));
    assert!(d.floor.floor_mm.is_none() && !d.explains, "{:?}", d.floor);
    assert!(d.summary.iter().all(|l| !l.contains("explains the held-out")), "{:?}", d.summary);
    std::fs::remove_dir_all(dir).ok();
    let (dir, _, setup, model, cal, val) = unknown(35, Some(sag_on(2, 0.02)));
    let auto = auto_loop(&setup, &model, &cal, &val, 3).expect("auto loop");
    println!("seed 35, no σ, sag:\n  {}", auto.last.summary.join("\n  "));
    assert_eq!(auto.steps[1].applied.as_deref(), Some("compliance:2"));
    assert!(auto.last.floor.floor_mm.is_none() && !auto.last.explains && auto.stop != Stop::AtFloor);
    assert!(
        auto.last.summary.iter().all(|l| !l.contains("explains the held-out")),
        "{:?}",
        auto.last.summary
    );
    std::fs::remove_dir_all(dir).ok();
}

fn kincal(dir: &Path, args: &[&str]) -> (bool, String, String) {
    let out = Command::new(kincal_bin()).args(args).current_dir(dir).output().expect("kincal runs");
    let text = |b: &[u8]| String::from_utf8_lossy(b).into_owned();
    (out.status.success(), text(&out.stdout), text(&out.stderr))
}

/// The CLI on a tracker RUN: diagnose, --auto and compare print and write their files; a RUN
/// whose data folder moved, or whose held-out file changed, is refused naming it; nothing panics.
#[test]
fn the_cli_diagnoses_compares_and_refuses_moved_or_changed_data() {
    let mut options = five_sessions(41);
    options.gravity_sag = Some(sag_on(2, 0.02));
    let (dir, _, _, _, _, _) = sessions("cli", &options);
    let calibrate = |out: &str, extra: &[&str]| {
        let mut args =
            vec!["calibrate", "--model", "nominal.toml", "--data", "cal", "--validate", "val", "--out", out];
        args.extend(extra);
        let (ok, stdout, stderr) = kincal(&dir, &args);
        assert!(ok, "{stdout}{stderr}");
    };
    calibrate("before", &[]);
    let (ok, stdout, stderr) = kincal(&dir, &["diagnose", "before"]);
    println!("{stdout}");
    assert!(ok, "{stderr}");
    assert!(stdout.contains("missing effect: compliance:2"), "{stdout}");
    assert!(stdout.contains("--add compliance:2"), "{stdout}");
    for file in ["diagnosis.json", "diagnosis.html"] {
        assert!(dir.join("before").join(file).is_file(), "{file}");
    }
    let (ok, stdout, stderr) = kincal(&dir, &["diagnose", "before", "--auto"]);
    println!("{stdout}");
    assert!(ok, "{stderr}");
    assert!(
        stdout.contains("stopped after 1 steps")
            && stdout.contains("at the floor: the model explains the data"),
        "{stdout}"
    );
    assert!(dir.join("before/auto/step-1.toml").is_file() && dir.join("before/auto/report.html").is_file());
    calibrate("after", &["--add", "compliance:2"]);
    let (ok, stdout, stderr) = kincal(&dir, &["compare", "before", "after", "--out", "compare.html"]);
    println!("{stdout}");
    assert!(ok, "{stderr}");
    assert!(stdout.contains("the second run is better on the held-out sessions"), "{stdout}");
    assert!(stdout.contains("the second run explains the held-out data"), "{stdout}");
    // A held-out file changed: named.
    let val_file = dir.join("val/session_4.csv");
    let text = std::fs::read_to_string(&val_file).expect("session file");
    let cut: Vec<&str> = text.lines().take(text.lines().count() - 3).collect();
    std::fs::write(&val_file, cut.join("\n") + "\n").expect("file changed");
    let (ok, _, stderr) = kincal(&dir, &["diagnose", "before"]);
    assert!(!ok && stderr.contains("session_4.csv") && stderr.contains("changed"), "{stderr}");
    // The data folder moved: named.
    std::fs::rename(dir.join("cal"), dir.join("cal-moved")).expect("moved");
    for args in
        [&["diagnose", "before"][..], &["diagnose", "before", "--auto"], &["compare", "before", "after"]]
    {
        let (ok, stdout, stderr) = kincal(&dir, args);
        assert!(!ok, "{args:?}: {stdout}");
        assert!(!stderr.contains("panicked"), "{stderr}");
        if args[0] == "diagnose" {
            assert!(stderr.contains("cal"), "{args:?}: {stderr}");
        }
    }
    std::fs::remove_dir_all(dir).ok();
}

/// False calls on clean data over 20 seeds (the README's figure; ≈ 30 s, so not in CI:
/// `cargo test --release -p kincal-e2e --test tracker_diagnose -- --ignored --nocapture`).
#[test]
#[ignore = "a 20-seed measurement, run by hand"]
fn clean_data_false_calls_over_twenty_seeds() {
    let (mut named, mut explains, mut incomplete) = (0, 0, 0);
    for seed in 100..120u64 {
        let (dir, _, setup, model, cal, val) = sessions(&format!("false-{seed}"), &five_sessions(seed));
        let d = diagnose(&setup, &model, &cal, &val).expect("diagnoses");
        named += usize::from(!d.named.is_empty());
        explains += usize::from(d.explains);
        incomplete += usize::from(d.incomplete);
        println!("seed {seed}: {}", d.summary[0]);
        std::fs::remove_dir_all(dir).ok();
    }
    println!(
        "named {named}/20, incomplete {incomplete}/20, explains {explains}/20, cannot tell {}/20",
        20 - explains - incomplete
    );
    assert!(named <= 2 && incomplete <= 2, "false calls: {named} named, {incomplete} incomplete of 20");
}

/// Where the model fails, on tracker sessions too: the apparent joint errors of the held-out
/// residuals (each session's frame refitted) show a 2-per-revolution encoder error on joint 4
/// (0.02° sin, −0.01° cos: 0.022° amplitude) as joint 4's largest harmonic, at its size (within
/// 40 %: the calibrated offsets and lengths absorb part of it over the angles visited), and the
/// diagnosis page draws every joint's apparent error.
#[test]
fn the_apparent_joint_errors_of_held_out_sessions_show_a_hidden_harmonic() {
    let mut options = five_sessions(61);
    options.encoder_harmonic = Some(EncoderHarmonic { joint: 4, order: 2, sin_deg: 0.02, cos_deg: -0.01 });
    let (dir, _, setup, model, cal, val) = sessions("apparent", &options);
    let d = diagnose(&setup, &model, &cal, &val).expect("diagnoses");
    let joint4 = &d.joints[3];
    let (order, fit) =
        joint4.spectrum.iter().max_by(|a, b| a.1.explained.total_cmp(&b.1.explained)).expect("a spectrum");
    println!("joint 4: {:?}, coverage {:.0}°", joint4.spectrum, joint4.coverage_deg);
    assert_eq!(d.joints.len(), 7);
    assert_eq!(joint4.points.len(), val.point_count(), "one apparent error per held-out point");
    assert_eq!(*order, 2, "{:?}", joint4.spectrum);
    assert!((fit.amplitude_deg - 0.0224).abs() < 0.4 * 0.0224, "amplitude {} vs 0.0224", fit.amplitude_deg);
    let page = kincal::report::diagnosis::diagnosis_report(&d, std::path::Path::new("run"));
    assert!((1..=7).all(|j| page.contains(&format!("joint {j} (deg)"))), "an apparent-error plot per joint");
    std::fs::remove_dir_all(dir).ok();
}
