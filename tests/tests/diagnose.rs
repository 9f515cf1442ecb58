//! Diagnostics on data with one hidden effect: the effect is found, named, added, and the
//! held-out error falls to the noise floor. Data come from the simulator's independent forward
//! path (plain 4×4 matrices with the effects written out again), not from the model's code.

use kincal::calib::diagnose::auto::{auto_loop, Stop};
use kincal::calib::diagnose::data_errors::touches::calibrate_with_landmark_freed;
use kincal::calib::diagnose::diagnose;
use kincal::calib::fit::calibrate;
use kincal::calib::setup::Objective;
use kincal::calib::setup::{Setup, SolveOptions};
use kincal::calib::validate::validate;
use kincal::data::Observations;
use kincal::model::effects::Effect;
use kincal::model::{ArmModel, ParamId};
use kincal::simulate::{
    record_placement, simulate, simulate_with_errors, EncoderHarmonic, HiddenErrors, Knock, Placement,
    SimulationOptions,
};

struct Case {
    hidden: Vec<(ParamId, f64)>,
    effect: &'static str,
    /// Parameters of the thesis set the user fixes (trusted by design) for this dataset.
    fixed: Vec<ParamId>,
    seed: u64,
    objective: Objective,
}

fn p(name: &str) -> ParamId {
    ParamId::parse(name).unwrap()
}

struct Outcome {
    floor: f64,
    before: f64,
    first: String,
    significant: bool,
    after: f64,
}

fn run_case(case: &Case) -> Outcome {
    let mut nominal = ArmModel::suta_nominal();
    for id in &case.fixed {
        nominal.fix_param(*id);
    }
    let sim = simulate(
        &nominal,
        &SimulationOptions { seed: case.seed, hidden: case.hidden.clone(), ..SimulationOptions::default() },
    );
    let cal = Observations::from_sessions(&sim.calibration, &sim.artefact);
    let val = Observations::from_sessions(&sim.validation, &sim.artefact);
    let options = SolveOptions {
        restarts: Some(2),
        seed: case.seed,
        objective: Some(case.objective),
        ..SolveOptions::default()
    };
    let fit = calibrate(&nominal, &cal, &options).expect("calibrates");
    let floor = validate(&sim.truth, &val).overall.rms_mm;
    let before = validate(&fit.model, &val).overall.rms_mm;
    let d = diagnose(&Setup::new(options.clone()), &fit.model, &cal, &val).unwrap();
    let leader = d.candidates.first().expect("some candidate");
    // Effects the data cannot tell apart are reported together; the hidden one must lead or be
    // named in the leading group.
    let first = if leader.equivalent.iter().any(|e| e == case.effect) {
        case.effect.to_string()
    } else {
        leader.name.clone()
    };
    let significant = leader.significant;
    print_sequence(&d);
    eprintln!(
        "  leader {}: blocks {:?} mean log ratio {:.3} p {:.2e} ΔBIC {:.1}",
        leader.name,
        leader.parts_improved,
        leader.mean_log_ratio,
        leader.p_value,
        leader.ranking.delta_bic.unwrap_or(f64::NAN)
    );
    if !leader.equivalent.is_empty() {
        eprintln!("  leading group: {} ≡ {}", leader.name, leader.equivalent.join(", "));
    }
    let mut with = nominal.clone();
    Effect::parse(case.effect).unwrap().add_to(&mut with);
    let refit = calibrate(&with, &cal, &options).expect("calibrates with the effect");
    let after = validate(&refit.model, &val).overall.rms_mm;
    eprintln!("{:<16} floor {floor:.3}  before {before:.3} ({:+.0} %)  first {first} significant {significant}  after {after:.3} ({:+.1} %)", case.effect, 100.0 * (before / floor - 1.0), 100.0 * (after / floor - 1.0));
    Outcome { floor, before, first, significant, after }
}

/// The first candidates of the held-out test sequence (calibration evidence order).
fn print_sequence(d: &kincal::calib::diagnose::Diagnosis) {
    let mut all: Vec<&kincal::calib::diagnose::Candidate> =
        d.candidates.iter().chain(&d.data_errors).collect();
    all.sort_by(|a, b| b.ranking.calibration_z.total_cmp(&a.ranking.calibration_z));
    for c in all.iter().take(6) {
        eprintln!(
            "    z {:7.1} {:<18} {:.3} mm p {:.3} placements {:?} refitted {} significant {}",
            c.ranking.calibration_z,
            c.name,
            c.held_out_rms_mm,
            c.p_value,
            c.units_improved,
            c.ranking.refitted,
            c.significant
        );
    }
    for r in &d.rivals {
        eprintln!(
            "    rival {} vs {}: {:?} (p {:.3} / {:.3}, λ {:.1})",
            r.a,
            r.b,
            r.verdict,
            r.a_adds_p,
            r.b_adds_p,
            r.separability.unwrap_or(f64::NAN)
        );
    }
    eprintln!("    named {:?}", d.named);
}

fn check(case: Case) {
    let o = run_case(&case);
    assert!(
        o.before >= 1.3 * o.floor,
        "{}: the hidden effect must lift validation RMS by 30 %: {} vs floor {}",
        case.effect,
        o.before,
        o.floor
    );
    assert_eq!(o.first, case.effect, "{}: ranked first instead: {}", case.effect, o.first);
    assert!(o.significant, "{}: not marked significant", case.effect);
    assert!(
        o.after <= 1.15 * o.floor,
        "{}: with the effect added validation RMS {} is not within 15 % of the floor {}",
        case.effect,
        o.after,
        o.floor
    );
}

#[test]
fn eccentricity_is_found_on_several_joints() {
    check(Case {
        hidden: vec![(p("eccentricity_sin:5"), 0.2), (p("eccentricity_cos:5"), -0.1)],
        effect: "eccentricity:5",
        fixed: vec![],
        seed: 21,
        objective: Objective::Distance,
    });
    check(Case {
        hidden: vec![(p("eccentricity_sin:2"), 0.25), (p("eccentricity_cos:2"), 0.15)],
        effect: "eccentricity:2",
        fixed: vec![],
        seed: 22,
        objective: Objective::Distance,
    });
    check(Case {
        hidden: vec![(p("eccentricity_cos:4"), 0.15)],
        effect: "eccentricity:4",
        fixed: vec![],
        seed: 23,
        objective: Objective::Distance,
    });
}

#[test]
fn twist_is_found_on_several_joints() {
    check(Case {
        hidden: vec![(p("twist:2"), 0.3)],
        effect: "twist:2",
        fixed: vec![],
        seed: 31,
        objective: Objective::Distance,
    });
    check(Case {
        hidden: vec![(p("twist:4"), -0.3)],
        effect: "twist:4",
        fixed: vec![],
        seed: 32,
        objective: Objective::Distance,
    });
}

#[test]
fn link_offset_is_found_on_several_joints() {
    check(Case {
        hidden: vec![(p("link_offset:3"), 1.0)],
        effect: "link_offset:3",
        fixed: vec![],
        seed: 41,
        objective: Objective::Distance,
    });
    check(Case {
        hidden: vec![(p("link_offset:4"), -1.0)],
        effect: "link_offset:4",
        fixed: vec![],
        seed: 42,
        objective: Objective::Distance,
    });
}

#[test]
fn a_link_offset_is_not_outranked_by_a_two_parameter_effect_with_a_smaller_drop() {
    // A 0.5 mm link offset on joint 5 moves the tip like an eccentricity of joint 6 over these
    // poses. The calibration evidence ordered the held-out tests by a Wilson–Hilferty deviate that
    // favoured the 2-parameter effect at χ² ≈ 350, so `eccentricity:6` was named alone on these
    // seeds; with the exact χ² tail the link offset is named (alone or as a rival).
    use kincal::calib::monte_carlo::{hidden_for, names, simulate_and_diagnose};
    let effect = Effect::parse("link_offset:5").unwrap();
    for seed in [2002, 2003, 2004] {
        let d = simulate_and_diagnose(seed, hidden_for(effect)).unwrap();
        print_sequence(&d);
        assert!(names(&d, effect), "seed {seed}: link_offset:5 not named: {:?}", d.summary);
        assert_ne!(d.named, ["eccentricity:6"], "seed {seed}");
    }
}

#[test]
fn compliance_is_found_on_several_joints() {
    check(Case {
        hidden: vec![(p("compliance:2"), 0.3)],
        effect: "compliance:2",
        fixed: vec![],
        seed: 51,
        objective: Objective::Distance,
    });
    check(Case {
        hidden: vec![(p("compliance:4"), 0.1)],
        effect: "compliance:4",
        fixed: vec![],
        seed: 52,
        objective: Objective::Distance,
    });
}

#[test]
fn tool_offset_is_found_when_the_tool_flange_length_is_trusted() {
    // With d6 free a tool offset along the last axis is indistinguishable from d6 (reported so);
    // a user who trusts d6 = 0 by construction fixes it. Distances alone still cannot tell the
    // tip offset from a stylus tilt (twist:6): both move the tip alike. The orientation
    // residuals of the asymmetric pillars can — a tilt turns the tool axis, an offset does not.
    check(Case {
        hidden: vec![(p("tcp.y"), 1.0)],
        effect: "tcp",
        fixed: vec![p("length:6")],
        seed: 61,
        objective: Objective::SixDof { lever_mm: Some(100.0) },
    });
}

#[test]
fn scale_is_found_when_link_lengths_are_trusted() {
    // With every length free a uniform scale is absorbed by them (reported as not identifiable);
    // with lengths measured on a CMM and fixed, the scale shows.
    let lengths: Vec<ParamId> = (0..6).map(ParamId::Length).chain([p("tcp.z")]).collect();
    check(Case {
        hidden: vec![(p("scale"), 1500.0)],
        effect: "scale",
        fixed: lengths,
        seed: 71,
        objective: Objective::Distance,
    });
}

#[test]
fn with_no_hidden_effect_nothing_is_significant_and_a_wrong_effect_does_not_help() {
    for seed in [81, 82] {
        let nominal = ArmModel::suta_nominal();
        let sim = simulate(&nominal, &SimulationOptions { seed, ..SimulationOptions::default() });
        let cal = Observations::from_sessions(&sim.calibration, &sim.artefact);
        let val = Observations::from_sessions(&sim.validation, &sim.artefact);
        let options = SolveOptions { restarts: Some(2), seed, ..SolveOptions::default() };
        let fit = calibrate(&nominal, &cal, &options).unwrap();
        let d = diagnose(&Setup::new(options.clone()), &fit.model, &cal, &val).unwrap();
        let significant: Vec<&str> =
            d.candidates.iter().filter(|c| c.significant).map(|c| c.name.as_str()).collect();
        assert!(significant.is_empty(), "seed {seed}: spurious effects {significant:?}");
        let before = validate(&fit.model, &val).overall.rms_mm;
        for wrong in ["eccentricity:3", "compliance:2", "twist:2"] {
            let mut with = nominal.clone();
            Effect::parse(wrong).unwrap().add_to(&mut with);
            let refit = calibrate(&with, &cal, &options).unwrap();
            let after = validate(&refit.model, &val).overall.rms_mm;
            assert!(
                after >= 0.99 * before,
                "seed {seed}: adding {wrong} lowered validation RMS {before} → {after}"
            );
        }
    }
}

/// A dataset from the independent forward path with hidden errors, calibrated with the thesis
/// model; returns the simulation, datasets, fit, options and the true floor.
struct Scenario {
    sim: kincal::simulate::SimulatedData,
    cal: Observations,
    val: Observations,
    nominal: ArmModel,
    options: SolveOptions,
    /// Validation RMS of the true arm against the true artefact: the noise floor.
    floor: f64,
}

fn scenario(
    seed: u64,
    hidden: Vec<(ParamId, f64)>,
    errors: HiddenErrors,
    validation_placements: usize,
) -> Scenario {
    let nominal = ArmModel::suta_nominal();
    let hidden_again = hidden.clone();
    let mut sim = simulate_with_errors(
        &nominal,
        &SimulationOptions { seed, hidden, ..SimulationOptions::default() },
        &errors,
    );
    sim.validation.truncate(validation_placements);
    let cal = Observations::from_sessions(&sim.calibration, &sim.artefact);
    let val = Observations::from_sessions(&sim.validation, &sim.artefact);
    let options = SolveOptions { restarts: Some(2), seed, ..SolveOptions::default() };
    // The true arm's model cannot hold an error outside the library: its floor is that of the
    // same arm and noise without it (a twin dataset of the same seed).
    let floor = if errors.encoder_harmonics.is_empty() {
        validate(&sim.truth, &val.with_landmarks(&sim.true_artefact.landmarks)).overall.rms_mm
    } else {
        let twin = simulate(
            &nominal,
            &SimulationOptions { seed, hidden: hidden_again, ..SimulationOptions::default() },
        );
        let mut twin_val = twin.validation;
        twin_val.truncate(validation_placements);
        validate(&twin.truth, &Observations::from_sessions(&twin_val, &twin.artefact)).overall.rms_mm
    };
    Scenario { sim, cal, val, nominal, options, floor }
}

/// `s` with five more validation placements recorded by the same true arm (ten in all).
fn with_ten_validation_placements(mut s: Scenario, seed: u64) -> Scenario {
    use rand::SeedableRng;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let options = SimulationOptions { seed, ..SimulationOptions::default() };
    for (k, (x, y, yaw)) in [
        (587.5, 62.5, 3.0),
        (437.5, -37.5, -3.0),
        (462.5, 137.5, 8.0),
        (562.5, -112.5, -8.0),
        (637.5, -37.5, 4.0),
    ]
    .into_iter()
    .enumerate()
    {
        let place = Placement { name: format!("V_{}", k + 6), origin_mm: [x, y, 0.0], yaw_deg: yaw };
        let (session, _) =
            record_placement(&s.sim.truth, &s.sim.artefact, &place, "validation", &options, &mut rng);
        s.sim.validation.push(session);
    }
    s.val = Observations::from_sessions(&s.sim.validation, &s.sim.artefact);
    s.floor = validate(&s.sim.truth, &s.val.with_landmarks(&s.sim.true_artefact.landmarks)).overall.rms_mm;
    s
}

#[test]
fn clean_data_floor_estimate_and_nothing_flagged() {
    for seed in [91, 92, 93, 94, 95] {
        let s = scenario(seed, vec![], HiddenErrors::default(), 5);
        // Two of the seeds with ten validation placements (30 blocks).
        let s = if seed >= 94 { with_ten_validation_placements(s, seed) } else { s };
        let fit = calibrate(&s.nominal, &s.cal, &s.options).unwrap();
        let d = diagnose(&Setup::new(s.options.clone()), &fit.model, &s.cal, &s.val).unwrap();
        let floor = d.floor.distances.as_ref().expect("repeats give a floor");
        let gap = d.floor.gap.as_ref().unwrap();
        eprintln!(
            "seed {seed} ({} validation placements): true floor {:.4} estimated {:.4} (encoder share {:.4}) expected {:.4} measured {:.4} z {:.2}",
            s.val.groups.len(),
            s.floor,
            floor.distance_rms_mm,
            floor.encoder_rms_mm.unwrap_or(f64::NAN),
            floor.expected_rms_mm,
            gap.measured_mm,
            gap.z
        );
        assert!(
            (floor.distance_rms_mm / s.floor - 1.0).abs() <= 0.2,
            "seed {seed}: floor estimate {} not within 20 % of the true floor {}",
            floor.distance_rms_mm,
            s.floor
        );
        let encoder = floor.encoder_rms_mm.expect("the simulated sessions report encoder std");
        assert!(encoder < floor.distance_rms_mm, "encoder share {encoder} exceeds the whole floor");
        assert!(!gap.significant, "seed {seed}: a gap is claimed on clean data: {}", gap.sentence());
        assert!(floor.inconsistent.is_empty(), "seed {seed}: groups flagged {:?}", floor.inconsistent);
        assert!(
            d.disturbed.is_empty() && d.mis_seated.is_empty() && d.data_errors.iter().all(|c| !c.significant),
            "seed {seed}: data errors flagged on clean data: {:?} {:?} {:?}",
            d.disturbed,
            d.mis_seated,
            d.data_errors.iter().filter(|c| c.significant).map(|c| &c.name).collect::<Vec<_>>()
        );
        let significant: Vec<&str> =
            d.candidates.iter().filter(|c| c.significant).map(|c| c.name.as_str()).collect();
        assert!(significant.is_empty(), "seed {seed}: spurious effects {significant:?}");
        // "At the floor" needs an equivalence test to pass; otherwise the report says it cannot
        // tell — never that the model misses something.
        assert!(
            d.summary.iter().any(|l| l.contains("at the floor") || l.contains("cannot be told")),
            "seed {seed}: the summary must say the error is at the floor or that it cannot tell: {:?}",
            d.summary
        );
        assert!(d.summary.iter().all(|l| !l.contains("misses")), "seed {seed}: {:?}", d.summary);
    }
}

fn calibrated(s: &Scenario) -> (ArmModel, kincal::calib::diagnose::Diagnosis) {
    let fit = calibrate(&s.nominal, &s.cal, &s.options).unwrap();
    let d = diagnose(&Setup::new(s.options.clone()), &fit.model, &s.cal, &s.val).unwrap();
    for line in &d.summary {
        eprintln!("  {line}");
    }
    (fit.model, d)
}

#[test]
fn a_wrong_certificate_is_named_before_any_arm_effect_and_fixing_it_reaches_the_floor() {
    let errors =
        HiddenErrors { wrong_certificates: vec![("S2".into(), [1.2, -1.0, 0.9])], ..Default::default() };
    let s = scenario(101, vec![], errors, 5);
    let (_, d) = calibrated(&s);
    let first = d.data_errors.first().expect("data errors are scored");
    assert_eq!(first.name, "landmark:S2");
    assert!(first.significant, "{first:?}");
    assert!(d.summary.iter().any(|l| l.starts_with("data error: landmark:S2")), "{:?}", d.summary);
    assert!(
        d.summary.iter().all(|l| !l.starts_with("missing effect")),
        "an arm effect is claimed: {:?}",
        d.summary
    );
    // The suggested actions: drop the landmark, or fit its position.
    let s2 = s.sim.artefact.index_of("S2").unwrap();
    let fit = calibrate(&s.nominal, &s.cal.without_landmark(s2), &s.options).unwrap();
    let excluded = validate(&fit.model, &s.val.without_landmark(s2)).overall.rms_mm;
    let floor_without = validate(&s.sim.truth, &s.val.without_landmark(s2)).overall.rms_mm;
    let (freed, corrected) = calibrate_with_landmark_freed(&s.nominal, &s.cal, s2, &s.options).unwrap();
    let with_freed = validate(&freed.model, &s.val.with_landmarks(&corrected)).overall.rms_mm;
    eprintln!("floor {:.3} / {floor_without:.3}; excluded {excluded:.3}; freed {with_freed:.3}", s.floor);
    assert!(excluded <= 1.15 * floor_without, "excluding S2: {excluded} vs floor {floor_without}");
    assert!(with_freed <= 1.15 * s.floor, "freeing S2: {with_freed} vs floor {}", s.floor);
}

#[test]
fn an_artefact_knocked_within_a_repeat_is_named_with_its_touch() {
    let knock = Knock {
        placement: "C_A".into(),
        repeat: 2,
        after_touch: 8,
        shift_mm: [0.5, 0.5, 0.0],
        yaw_deg: 0.25,
    };
    let s = scenario(102, vec![], HiddenErrors { knock: Some(knock), ..Default::default() }, 5);
    let (_, d) = calibrated(&s);
    let block = d.disturbed.first().expect("the knocked block is flagged");
    assert_eq!((s.cal.groups[block.placement].name.as_str(), block.repeat, block.after_touch), ("C_A", 2, 8));
    assert_eq!(d.disturbed.len(), 1, "{:?}", d.disturbed);
    assert!(d.summary.iter().any(|l| l.contains("block:C_A/2") && l.contains("#9")), "{:?}", d.summary);
    assert!(
        d.summary.iter().all(|l| !l.starts_with("missing effect")),
        "an arm effect is claimed: {:?}",
        d.summary
    );
    let kept = s.cal.without(|k| s.cal.obs[k].group == block.placement && s.cal.obs[k].repeat == 2);
    let fit = calibrate(&s.nominal, &kept, &s.options).unwrap();
    let after = validate(&fit.model, &s.val).overall.rms_mm;
    eprintln!("floor {:.3} after excluding the block {after:.3}", s.floor);
    assert!(after <= 1.15 * s.floor, "{after} vs floor {}", s.floor);
}

#[test]
fn a_three_per_rev_error_shows_its_pattern_and_harmonic_3_reaches_the_floor() {
    let harmonic = EncoderHarmonic { joint: 2, order: 3, sin_deg: 0.12, cos_deg: 0.0 };
    let s =
        scenario(103, vec![], HiddenErrors { encoder_harmonics: vec![harmonic], ..Default::default() }, 5);
    let (_, d) = calibrated(&s);
    assert!(d.floor.gap.as_ref().unwrap().significant);
    assert!(
        d.summary.iter().any(|l| l.contains("joint 3") && l.contains("3 per revolution")),
        "the 3-per-rev pattern on joint 3 must be shown: {:?}",
        d.summary
    );
    assert!(
        d.summary.iter().any(|l| l.contains("the model misses about")),
        "the report must say the model is incomplete: {:?}",
        d.summary
    );
    let joint3 = &d.joints[2];
    let (order, fit) = joint3.spectrum.iter().max_by(|a, b| a.1.explained.total_cmp(&b.1.explained)).unwrap();
    assert_eq!(*order, 3);
    assert!((fit.amplitude_deg - 0.12).abs() < 0.02, "amplitude {} vs 0.12", fit.amplitude_deg);
    // harmonic:3:3 is named (never compliance:3 alone), and it brings the error to the floor.
    assert_eq!(d.named.first().map(String::as_str), Some("harmonic:3:3"), "{:?}", d.summary);
    let mut with = s.nominal.clone();
    Effect::parse("harmonic:3:3").unwrap().add_to(&mut with);
    let refit = calibrate(&with, &s.cal, &s.options).unwrap();
    let after = validate(&refit.model, &s.val).overall.rms_mm;
    eprintln!("harmonic:3:3 brings {:.3} to {after:.3} (floor {:.3})", d.baseline.rms_mm, s.floor);
    assert!(after <= 1.15 * s.floor, "{after} vs floor {}", s.floor);
}

/// `d` names `effect`, alone or among rivals the data cannot tell apart, and never `not`
/// alone.
fn assert_named(d: &kincal::calib::diagnose::Diagnosis, effect: &str, not: &str) {
    assert!(d.named.iter().any(|n| n == effect), "{effect} must be named: {:?}\n{:?}", d.named, d.summary);
    assert!(d.named != [not.to_string()], "{not} alone is named: {:?}", d.summary);
}

#[test]
fn a_small_three_per_rev_error_on_joint_3_is_named_and_the_loop_ends_at_the_floor_with_it() {
    // Small enough that compliance:3 also helps on the held-out data: a rival, not the cause.
    for (seed, amplitude_deg) in [(106, 0.04), (107, 0.06)] {
        let harmonic = EncoderHarmonic { joint: 2, order: 3, sin_deg: amplitude_deg, cos_deg: 0.0 };
        let s = scenario(
            seed,
            vec![],
            HiddenErrors { encoder_harmonics: vec![harmonic], ..Default::default() },
            5,
        );
        let (fit, d) = calibrated(&s);
        print_sequence(&d);
        assert_named(&d, "harmonic:3:3", "compliance:3");
        assert!(
            d.summary.iter().all(|l| !l.contains("1 per revolution")),
            "the periodic line must agree with the named effect: {:?}",
            d.summary
        );
        let run = auto_loop(&Setup::new(s.options.clone()), &fit, &s.cal, &s.val, 4).unwrap();
        let last = run.steps.last().unwrap();
        let added: Vec<&str> = run.steps.iter().filter_map(|s| s.applied.as_deref()).collect();
        eprintln!(
            "seed {seed}: loop {added:?} ends at {:.4} (true floor {:.4}), stop {:?}",
            last.held_out_rms_mm, s.floor, run.stop
        );
        assert!(added.contains(&"harmonic:3:3"), "the loop must add harmonic:3:3: {added:?}");
        assert!(
            last.held_out_rms_mm <= 1.05 * s.floor,
            "seed {seed}: the loop ends at {} vs true floor {}",
            last.held_out_rms_mm,
            s.floor
        );
    }
}

#[test]
fn compliance_on_joint_3_is_named_not_a_harmonic_and_no_knock_is_flagged() {
    for seed in [108, 109] {
        let s = scenario(seed, vec![(p("compliance:3"), 0.2)], HiddenErrors::default(), 5);
        // The repeats are taken in other arm configurations: the knock detector must not read
        // the configuration-dependent sag as the artefact moving.
        let other_configuration = s.cal.obs.iter().any(|t| {
            s.cal.obs.iter().any(|u| {
                u.group == t.group
                    && u.landmark() == t.landmark()
                    && u.repeat != t.repeat
                    && !kincal::calib::repeats::same_pose(&t.q_deg, &u.q_deg)
            })
        });
        assert!(other_configuration, "seed {seed}: the data must have repeats in other configurations");
        let (_, d) = calibrated(&s);
        print_sequence(&d);
        assert_eq!(d.named.first().map(String::as_str), Some("compliance:3"), "seed {seed}: {:?}", d.summary);
        assert!(
            d.named.iter().all(|n| !n.starts_with("harmonic") && !n.starts_with("eccentricity")),
            "seed {seed}: a harmonic is named: {:?}",
            d.named
        );
        assert!(d.disturbed.is_empty(), "seed {seed}: artefact moved flagged: {:?}", d.disturbed);
        assert!(d.summary.iter().all(|l| !l.contains("the artefact moved")), "{:?}", d.summary);
    }
}

#[test]
fn clean_data_false_calls_stay_rare_over_24_seeds() {
    // The README's figures come from `kincal bench --diagnosis-seeds 100`; this keeps CI short
    // and still fails if the false-call rate climbs well above 5 %: 4 or more calls in 24 runs
    // happen with probability 3 % at a true rate of 5 %.
    use kincal::calib::monte_carlo::{false_calls, simulate_and_diagnose};
    let calls: Vec<_> =
        (0..24u64).map(|k| false_calls(&simulate_and_diagnose(3000 + k, vec![]).unwrap())).collect();
    let bad: Vec<(usize, _)> = calls.iter().copied().enumerate().filter(|(_, c)| c.any()).collect();
    eprintln!("false calls on clean data: {} of {}: {bad:?}", bad.len(), calls.len());
    assert!(bad.len() <= 3, "{} of 24 clean runs had a false call: {bad:?}", bad.len());
}

#[test]
fn with_three_validation_placements_a_large_effect_leads_and_the_report_warns() {
    let hidden = vec![(p("eccentricity_sin:2"), 1.0), (p("eccentricity_cos:2"), 0.8)];
    let s = scenario(104, hidden, HiddenErrors::default(), 3);
    let (_, d) = calibrated(&s);
    let leader = &d.candidates[0];
    eprintln!(
        "{}: {:.3} → {:.3} blocks {:?} p {:.1e}",
        leader.name, d.baseline.rms_mm, leader.held_out_rms_mm, leader.parts_improved, leader.p_value
    );
    assert_eq!(leader.parts_improved.1, 9);
    assert_eq!(leader.name, "eccentricity:2");
    assert!(d.baseline.rms_mm >= 3.0 * leader.held_out_rms_mm, "the effect must cut validation RMS 3×");
    // Three placements are three units: the report says so whatever the verdict.
    assert_eq!(leader.units_improved, (3, 3));
    assert!(
        d.summary.iter().any(|l| l.contains("with 3 validation placements") && l.contains("at least 5")),
        "{:?}",
        d.summary
    );
}

#[test]
fn the_auto_loop_adds_a_mixture_of_four_effects_down_to_the_floor() {
    let hidden = vec![
        (p("eccentricity_sin:2"), 0.2),
        (p("eccentricity_cos:5"), 0.15),
        (p("twist:4"), 0.25),
        (p("compliance:2"), 0.2),
    ];
    // Ten validation placements: with the placement as the test's unit, five are too few to
    // confirm a third and fourth effect whose gain one placement does not share.
    let s = with_ten_validation_placements(scenario(105, hidden, HiddenErrors::default(), 5), 105);
    let fit = calibrate(&s.nominal, &s.cal, &s.options).unwrap();
    let started = std::time::Instant::now();
    let run = auto_loop(&Setup::new(s.options.clone()), &fit.model, &s.cal, &s.val, 8).unwrap();
    eprintln!("auto loop: {:.2} s, stop {:?}", started.elapsed().as_secs_f64(), run.stop);
    for step in &run.steps {
        eprintln!(
            "  {:<16} {:.3} mm (expected {:.3}) p {:?}",
            step.applied.as_deref().unwrap_or("(start)"),
            step.held_out_rms_mm,
            step.expected_rms_mm.unwrap_or(f64::NAN),
            step.p_value
        );
    }
    for step in &run.steps {
        eprintln!("  {:?}", step.summary);
    }
    print_sequence(&run.last);
    for c in run.last.candidates.iter().take(3).chain(run.last.data_errors.iter().take(2)) {
        eprintln!(
            "   {} {:.4} blocks {:?} p {:.2e} ΔBIC {:.1} sig {}",
            c.name,
            c.held_out_rms_mm,
            c.parts_improved,
            c.p_value,
            c.ranking.delta_bic.unwrap_or(f64::NAN),
            c.significant
        );
    }
    let last = run.steps.last().unwrap();
    assert!(
        last.held_out_rms_mm <= 1.10 * s.floor,
        "the loop ends at {} vs true floor {}",
        last.held_out_rms_mm,
        s.floor
    );
    assert_eq!(run.stop, Stop::AtFloor);
    for pair in run.steps.windows(2) {
        assert!(pair[1].held_out_rms_mm < pair[0].held_out_rms_mm, "each step lowers the error");
        assert!(pair[1].p_value.is_some_and(|p| p < 0.05), "each added effect is significant at its step");
    }
}
