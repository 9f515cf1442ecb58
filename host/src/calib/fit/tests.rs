//! The fit's own checks: consistency of the solver with kincal's kinematics (accuracy is tested
//! on the independent generators in `tests/`).

use super::*;
use crate::calib::validate::validate_session;
use crate::data::{Joints, Landmark, Observation, Target};
use crate::model::kinematics::tool_pose;
use crate::model::Joint;
use nalgebra::{Rotation3, UnitQuaternion};

/// A 7-joint arm with lengths and twists free (consistency of the solver with its own
/// kinematics only; accuracy is tested on the independent generator in `tests/`).
pub(super) fn arm() -> ArmModel {
    let alpha = [-90.0, 90.0, -90.0, 90.0, -90.0, 90.0, 0.0];
    let d = [340.0, 0.0, 400.0, 0.0, 400.0, 0.0, 126.0];
    let mut model = ArmModel::suta_nominal();
    model.joints = (0..7).map(|j| Joint { d_mm: d[j], alpha_deg: alpha[j], ..Joint::default() }).collect();
    model.tcp_mm = [10.0, 20.0, 80.0];
    model.free.clear();
    for (j, dj) in d.iter().enumerate() {
        model.free_param(ParamId::Offset(j), -5.0, 5.0);
        model.free_param(ParamId::Length(j), dj - 10.0, dj + 10.0);
    }
    model
}

/// `arm()` and the arm the tests' data are measured on: 1.5 mm longer at joint 3's d, 0.2° more
/// offset at joint 4.
pub(super) fn arm_and_truth() -> (ArmModel, ArmModel) {
    let nominal = arm();
    let mut truth = nominal.clone();
    truth.joints[2].d_mm += 1.5;
    truth.joints[3].offset_deg += 0.2;
    (nominal, truth)
}

/// Three sessions of 40 noise-free points of `truth`, each seen from its own frame, with the
/// probe's orientation when `probe` is given.
pub(super) fn sessions(truth: &ArmModel, probe: Option<Matrix3<f64>>) -> Observations {
    let mut data = Observations::new(7, Vec::new());
    for s in 0..3 {
        let group = data.push_group(format!("s{s}"), "s.csv".into(), Kind::Tracker);
        let frame = Frame {
            rotation: Rotation3::from_euler_angles(0.1 * s as f64, -0.05, 0.3 * s as f64).into_inner(),
            translation_mm: Vector3::new(2000.0, -500.0 * s as f64, 300.0),
        };
        for i in 0..40 {
            let f = (i + 40 * s) as f64;
            let q: Vec<f64> = (0..7).map(|j| 60.0 * (0.37 * f * (j + 1) as f64).sin()).collect();
            let pose = tool_pose(truth, &q);
            let orientation = probe.map(|p| {
                let r = frame.rotation * crate::calib::nuisance::tool::flange_rotation(&pose) * p;
                UnitQuaternion::from_matrix(&r)
            });
            let point = frame.apply(&pose.position_mm);
            data.obs.push(Observation::point(
                group,
                Joints::new(&q).unwrap(),
                point,
                orientation,
                None,
                i + 3,
            ));
        }
    }
    data.rebuild_blocks();
    data
}

#[test]
fn noise_free_points_of_its_own_kinematics_are_fitted_exactly() {
    let (nominal, mut truth) = arm_and_truth();
    truth.tcp_mm[2] += 2.0;
    let data = sessions(&truth, None);
    let fit = calibrate(&nominal, &data, &SolveOptions::default()).unwrap();
    assert!(fit.rms_mm < 1e-6, "{:?}", fit.stats);
    assert!(fit.fixed.contains(&ParamId::Offset(0)), "{:?}", fit.fixed);
    assert!(
        fit.statements.iter().any(|s| s.contains("offset:1 is absorbed by the session bases")),
        "{:?}",
        fit.statements
    );
    let v = validate_session(&fit.model, &data, 1, [0.0; 3]);
    assert!(v.rms_mm < 1e-6 && v.pairwise_rms_mm < 1e-6, "{v:?}");
}

/// ∂r/∂x of `problem` at `x` by central differences against its own Jacobian, and its sparse
/// normal equations against JᵀJ of the dense one. (A floated tool's offset Δ is taken at zero:
/// the arm columns leave out ∂(R_F·Δ)/∂θ, second order for an offset of millimetres.)
fn check_jacobian(problem: &Problem, x: &[f64], h: f64) {
    let (m, n) = (problem.len(), x.len());
    let (r, jac) = jacobian_at(problem, x);
    for c in 0..n {
        let (mut xp, mut xm) = (x.to_vec(), x.to_vec());
        xp[c] += h;
        xm[c] -= h;
        let (mut rp, mut rm) = (vec![0.0; m], vec![0.0; m]);
        problem.evaluate(&xp, &mut rp, None);
        problem.evaluate(&xm, &mut rm, None);
        for i in 0..m {
            let fd = (rp[i] - rm[i]) / (2.0 * h);
            assert!(
                (jac[i * n + c] - fd).abs() < 1e-4 * (1.0 + fd.abs()),
                "row {i} column {c}: {} vs {fd}",
                jac[i * n + c]
            );
        }
    }
    let mut r2 = vec![0.0; m];
    let (h, g) = problem.normal_equations(x, &mut r2, Loss::Linear);
    let (hd, gd) = solver::normal_equations(&jac, &r, &vec![1.0; m], n);
    assert!((&h - &hd).norm() <= 1e-9 * hd.norm() && (&g - &gd).norm() <= 1e-9 * gd.norm().max(1.0));
}

#[test]
fn six_dof_jacobian_matches_central_differences() {
    let model = ArmModel::suta_nominal();
    let landmarks: Vec<Landmark> = (0..3)
        .map(|i| Landmark {
            id: format!("L{i}"),
            xyz_mm: [10.0 * i as f64, 5.0, 20.0],
            yaw_deg: 30.0 * i as f64,
        })
        .collect();
    let touches: [(usize, usize, u32, &[f64]); 3] = [
        (0, 0, 1, &[10.0, 200.0, 30.0, 300.0, 40.0, 120.0]),
        (0, 1, 1, &[12.0, 205.0, 28.0, 290.0, 45.0, 100.0]),
        (0, 2, 1, &[8.0, 190.0, 35.0, 310.0, 50.0, 80.0]),
    ];
    let data = Observations::from_touches(&["A"], landmarks, &touches);
    let params = ParamId::all();
    let options = SolveOptions {
        objective: Some(crate::calib::setup::Objective::SixDof { lever_mm: Some(100.0) }),
        float_tool: vec!["A".into()],
        ..SolveOptions::default()
    };
    let pieces = Pieces::new(&model, &data, &options, &Encoders::of(&data)).unwrap();
    let frames = vec![Frame::identity(); data.blocks.len()];
    let problem = pieces.problem(params.clone(), &model, &frames, None);
    let mut x: Vec<f64> = params.iter().map(|p| model.get(*p)).collect();
    x.extend([0.0; 3]);
    check_jacobian(&problem, &x, 1e-6);
    // Without the floated tool no term has unknowns of its own: the normal equations are summed
    // from dense rows (one-row distances in place, four-row relative orientations scattered).
    let options = SolveOptions { float_tool: Vec::new(), ..options };
    let pieces = Pieces::new(&model, &data, &options, &Encoders::of(&data)).unwrap();
    let problem = pieces.problem(params.clone(), &model, &frames, None);
    assert!(!problem.layout.has_block_unknowns());
    x.truncate(params.len());
    check_jacobian(&problem, &x, 1e-6);
}

#[test]
fn point_and_orientation_jacobians_match_central_differences() {
    let nominal = arm();
    let probe = Rotation3::from_euler_angles(0.2, -0.1, 0.4).into_inner();
    let data = sessions(&nominal, Some(probe)).subset(&[0]);
    let options = SolveOptions { float_tool: vec!["s0".into()], ..SolveOptions::default() };
    let pieces = Pieces::new(&nominal, &data, &options, &Encoders::of(&data)).unwrap();
    let frames = pieces.closed_form_frames(&pieces.model);
    let start = start_probe_rotation(&pieces.model, &data, &frames);
    let arm: Vec<ParamId> = pieces.model.free.iter().map(|f| f.id).collect();
    let problem = pieces.problem(arm, &pieces.model, &frames, start);
    let tools = vec![Vector3::zeros()];
    // Near the solution: an orientation row's derivative takes its residual for small (and
    // the rotation vector of a rotation of 1e-8 rad reads as zero).
    let mut x = pieces.x_of(&problem, &pieces.model, &frames, &tools, &[Vec::new()]);
    let c = problem.layout.rotation_column().expect("the probe rotation is fitted");
    x[c..c + 3].copy_from_slice(&[0.02, -0.01, 0.015]);
    // A larger step: the rotation vector of an orientation residual is extracted iteratively,
    // to about 1e-12 rad, which a step of 1e-6 would show.
    check_jacobian(&problem, &x, 1e-4);
}

#[test]
fn an_encoder_table_is_that_of_its_angles_and_no_other() {
    use crate::model::kinematics::encoder_sin_cos;
    let mut data = sessions(&arm(), None);
    let joints = data.joints;
    let first = Encoders::of(&data);
    let row = |e: &Encoders, k: usize, j: usize| e.table()[k * joints + j];
    for (k, o) in data.obs.iter().enumerate() {
        for (j, &q) in o.q_deg.iter().enumerate() {
            assert_eq!(row(&first, k, j), encoder_sin_cos(q));
        }
    }
    // The same observations: the same table, shared.
    assert!(std::ptr::eq(first.for_data(&data).table().as_ptr(), first.table().as_ptr()));
    // A session left out: the rows of the others, in their order.
    let without = data.without(|k| data.obs[k].block == 1);
    let kept: Vec<usize> = (0..data.obs.len()).filter(|&k| data.obs[k].block != 1).collect();
    let taken = first.for_data(&without);
    assert_eq!(taken.table().len(), without.obs.len() * joints);
    for (i, &k) in kept.iter().enumerate() {
        for j in 0..joints {
            assert_eq!(row(&taken, i, j), row(&first, k, j));
        }
    }
    // One angle moved by a hair: its own row, not the first table's.
    data.obs[3].q_deg[2] += 1e-9;
    let moved = first.for_data(&data);
    assert_eq!(row(&moved, 3, 2), encoder_sin_cos(data.obs[3].q_deg[2]));
    assert_ne!(row(&moved, 3, 2), row(&first, 3, 2));
    assert_eq!(moved.table(), Encoders::of(&data).table());
}

/// A point that is not a number is refused (the residuals' finiteness is checked on the solve's
/// first evaluation at the start): by a calibration and by a refit from a fit's solution.
#[test]
fn a_start_that_is_not_finite_is_refused() {
    let nominal = arm();
    let data = sessions(&nominal, None);
    let options = SolveOptions::default();
    let fit = calibrate(&nominal, &data, &options).expect("fit");
    let mut broken = data.clone();
    let k = broken.blocks[1].members[4];
    if let Target::Point { xyz_mm, .. } = &mut broken.obs[k].target {
        xyz_mm.x = f64::NAN;
    }
    assert!(matches!(calibrate(&nominal, &broken, &options), Err(CalibError::NonFinite)));
    assert!(matches!(recalibrate(&nominal, &broken, &options, &fit), Err(CalibError::NonFinite)));
}

/// A calibration that takes the tool point's first fit from another one's (a run's tool-only
/// reference beside its calibration) is the one calibrated alone; on other arm values the kept
/// fit is not taken.
#[test]
fn a_shared_tool_first_fit_is_the_calibration_alone() {
    let (nominal, truth) = arm_and_truth();
    let data = sessions(&truth, None);
    let (options, encoders) = (SolveOptions::default(), Encoders::of(&data));
    let mut tool_only = nominal.clone();
    tool_only.free.retain(|f| matches!(f.id, ParamId::Tcp(_)));
    // As a run: the check of the data takes the closed-form frames and builds the terms, the
    // calibrations take the rest and borrow the terms.
    let (start, terms) = (ToolFirstFit::default(), SharedTerms::default());
    check_data_sharing(&nominal, &data, &encoders, &options, &start, Some(&terms)).expect("checked");
    assert!(start.0.borrow().as_ref().is_some_and(|kept| kept.tool_fit.is_none()));
    assert!(terms.is_built());
    let (fit, reference) = calibrate_with_reference_on(
        &nominal,
        Some(&tool_only),
        &data,
        &encoders,
        &options,
        &start,
        Some(&terms),
    )
    .expect("fit");
    let reference = reference.expect("asked for").expect("reference");
    let same = |a: &Fit, b: &Fit| {
        assert_eq!(a.model, b.model);
        assert_eq!((a.cost, &a.estimated, a.iterations), (b.cost, &b.estimated, b.iterations));
        assert_eq!(a.frames.len(), b.frames.len());
        for (f, g) in a.frames.iter().zip(&b.frames) {
            assert_eq!((&f.0, f.1.rotation, f.1.translation_mm), (&g.0, g.1.rotation, g.1.translation_mm));
        }
    };
    same(&fit, &calibrate_on(&nominal, &data, &encoders, &options).expect("alone"));
    same(&reference, &calibrate_on(&tool_only, &data, &encoders, &options).expect("alone"));
    assert!(
        !reference.estimated.is_empty() && reference.estimated.iter().all(|p| matches!(p, ParamId::Tcp(_)))
    );
    // The first fit was kept and taken; an arm of other values solves its own.
    let first_fit = ToolFirstFit::default();
    calibrate_on_sharing(&nominal, &data, &encoders, &options, &first_fit, None).expect("fit");
    assert!(first_fit.0.borrow().as_ref().is_some_and(|kept| kept.tool_fit.is_some()));
    let mut other = tool_only.clone();
    other.joints[2].d_mm += 1.0;
    let shared = calibrate_on_sharing(&other, &data, &encoders, &options, &first_fit, None).expect("other");
    same(&shared, &calibrate_on(&other, &data, &encoders, &options).expect("alone"));
}

/// The closed-form frames and orientation spreads a calibration from the nominal values keeps
/// for the next one on the same data (a run's tool-only reference) are those of the arm's values
/// computed again, to the bit; for an arm of other values its own are computed.
#[test]
fn kept_frames_and_spreads_are_those_of_the_arm() {
    let (nominal, truth) = arm_and_truth();
    let data = sessions(&truth, None);
    let (options, encoders) = (SolveOptions::default(), Encoders::of(&data));
    let first_fit = ToolFirstFit::default();
    let fit = calibrate_on_sharing(&nominal, &data, &encoders, &options, &first_fit, None).expect("fit");
    let spreads_of = |model: &ArmModel| -> Vec<(String, f64)> {
        (0..data.blocks.len())
            .map(|b| (data.block_name(b), orientation_spread_deg(model, &data, b)))
            .collect()
    };
    assert_eq!(fit.orientation_spread_deg, spreads_of(&nominal));
    assert!(fit.orientation_spread_deg.iter().all(|s| s.1 > CONSTANT_ORIENTATION_DEG));
    let mut other = nominal.clone();
    other.joints[2].d_mm += 1.0;
    other.joints[4].alpha_deg += 0.5;
    let mut kept = Vec::new();
    for model in [&nominal, &other, &nominal] {
        let pieces = Pieces::new(model, &data, &options, &encoders).expect("pieces");
        let (frames, spreads) = (first_fit.closed_form_frames(&pieces), first_fit.spreads(&pieces));
        assert_eq!(frames, pieces.closed_form_frames(&pieces.model));
        assert_eq!(spreads, spreads_of(model));
        kept.push((frames, spreads));
    }
    assert!(kept[0].0 != kept[1].0 && kept[0].1 != kept[1].1, "other values, other frames and spreads");
}

/// The first normal equations a solve takes from the group factors of every free parameter at
/// its start are the ones it would evaluate there, to rounding, over the columns it keeps (an
/// arm column fewer, the sessions' frames, a floated tool); there are none when it starts
/// elsewhere or a residual is beyond a Huber threshold (the factors' rows are unweighted).
#[test]
fn the_factors_give_the_first_normal_equations_of_a_solve_at_their_point() {
    let (nominal, truth) = arm_and_truth();
    let data = sessions(&truth, None);
    let options = SolveOptions { float_tool: vec!["s1".into()], ..SolveOptions::default() };
    let pieces = Pieces::new(&nominal, &data, &options, &Encoders::of(&data)).unwrap();
    let frames = pieces.closed_form_frames(&pieces.model);
    let (tools, drifts) =
        (vec![Vector3::new(0.5, -0.2, 0.1); data.groups.len()], vec![Vec::new(); data.blocks.len()]);
    let all: Vec<ParamId> = pieces.model.free.iter().map(|f| f.id).collect();
    let full = pieces.problem(all.clone(), &pieces.model, &frames, None);
    let x = pieces.x_of(&full, &pieces.model, &frames, &tools, &drifts);
    let factored = Factored::new(&full, &x, pieces::check_framed(&full, &x).unwrap(), &data);
    let problem = pieces.problem(all[1..].to_vec(), &pieces.model, &frames, None);
    assert!(problem.layout.unknowns() < full.layout.unknowns() && problem.layout.tool_column(1).is_some());
    let x0 = pieces.x_of(&problem, &pieces.model, &frames, &tools, &drifts);
    let known = factored.normal_at(&problem, &x0, Loss::Linear).expect("the same point");
    let mut r = vec![0.0; problem.len()];
    let (h, g) = problem.normal_equations(&x0, &mut r, Loss::Linear);
    let close = |a: f64, b: f64, scale: f64| (a - b).abs() <= 1e-10 * scale;
    let (h_scale, g_scale) = (h.amax(), g.amax());
    assert!(h_scale > 0.0 && g_scale > 0.0);
    assert!(known.normal.iter().zip(h.iter()).all(|(a, b)| close(*a, *b, h_scale)), "normal matrix");
    assert!(known.gradient.iter().zip(g.iter()).all(|(a, b)| close(*a, *b, g_scale)), "gradient");
    let cost = Loss::Linear.cost(&r);
    assert!(cost > 0.0 && close(known.cost, cost, cost), "cost {} against {cost}", known.cost);
    let mut moved = x0.clone();
    moved[0] += 1e-3;
    assert!(factored.normal_at(&problem, &moved, Loss::Linear).is_none(), "another point");
    let largest = r.iter().fold(0.0, |m: f64, v| v.abs().max(m));
    assert!(factored.normal_at(&problem, &x0, Loss::Huber(0.5 * largest)).is_none(), "weighted rows");
    assert!(factored.normal_at(&problem, &x0, Loss::Huber(2.0 * largest)).is_some(), "unit weights");
}

/// The artefact's solves with each trial point's normal equations ([`dense::dense_solver`]) are
/// the plain ones to the bit (a distance's residuals are the same from either evaluation), from
/// the nominal start and from random ones, with the normal matrix at the solution.
#[test]
fn a_distance_fit_with_normal_equations_at_its_trials_is_the_plain_one() {
    let nominal = ArmModel::suta_nominal();
    let sim = crate::simulate::simulate(&nominal, &crate::simulate::SimulationOptions::default());
    let data = Observations::from_sessions(&sim.calibration, &sim.artefact);
    let options = SolveOptions::default();
    let pieces = Pieces::new(&nominal, &data, &options, &Encoders::of(&data)).unwrap();
    assert!(!pieces.blocked());
    let params: Vec<ParamId> = nominal.free.iter().map(|f| f.id).collect();
    let problem = pieces.problem(params.clone(), &nominal, &vec![Frame::identity(); data.blocks.len()], None);
    let n = problem.layout.unknowns();
    let (lower, upper) = pieces.bounds(&params, n);
    let x_nominal: Vec<f64> = params.iter().map(|&id| nominal.get(id)).collect();
    let trial = dense::dense_solver(&pieces, &options);
    let plain = SolverOptions { trial_normal: false, ..trial };
    assert!(trial.trial_normal && matches!(trial.loss, Loss::Huber(_)));
    for (start, x0) in start_points(&x_nominal, &lower, &upper, 7, 0..=2) {
        let a = solver::solve(&problem, &x0, &lower, &upper, &plain);
        let b = solver::solve(&problem, &x0, &lower, &upper, &trial);
        assert!(a.iterations > 2, "start {start}: {a:?}");
        assert_eq!((&a.x, a.cost, &a.residuals), (&b.x, b.cost, &b.residuals), "start {start}");
        assert_eq!((a.iterations, a.stop, a.initial_cost), (b.iterations, b.stop, b.initial_cost));
        let mut r = vec![0.0; problem.len()];
        let at_x = problem.normal_equations(&b.x, &mut r, trial.loss).0;
        assert_eq!(b.normal_at_x, Some(at_x), "start {start}");
    }
}

/// Restarts that reach the calibration's own minimum leave it as it is: their costs differ from
/// the nominal start's by rounding, which is a tie, and the earliest start wins a tie. Which
/// start counts as lowest must not turn on rounding (a lower cost by 1e-14 relative once picked
/// a point 1e-7 away and moved a leave-one-out figure by 1e-4).
#[test]
fn restarts_reaching_the_same_minimum_keep_the_nominal_start_s_solution() {
    let (nominal, truth) = arm_and_truth();
    let mut data = sessions(&truth, None);
    // 0.05 mm of deterministic scatter: a cost well above zero, whose rounding differs by start.
    for (i, o) in data.obs.iter_mut().enumerate() {
        if let Target::Point { xyz_mm, .. } = &mut o.target {
            let f = i as f64;
            *xyz_mm += Vector3::new((1.3 * f).sin(), (2.9 * f).cos(), (0.7 * f).sin()) * 0.05;
        }
    }
    let alone = calibrate(&nominal, &data, &SolveOptions::default()).expect("nominal start");
    let options = SolveOptions { restarts: Some(6), seed: 11, ..SolveOptions::default() };
    let restarted = calibrate(&nominal, &data, &options).expect("restarts");
    assert_the_nominal_start_is_kept(&alone, &restarted, 1e-9);
}

/// `restarted`'s starts all reach `alone`'s minimum (costs within `tolerance` relative), some
/// lower by rounding (the check has teeth: a plain `<` would take that start), and its solution
/// is the nominal start's, `alone`'s, to the bit.
#[track_caller]
fn assert_the_nominal_start_is_kept(alone: &Fit, restarted: &Fit, tolerance: f64) {
    let costs: Vec<f64> = restarted.starts.iter().map(|s| s.final_cost).collect();
    assert_eq!(restarted.starts[0].final_cost, alone.cost, "{costs:?}");
    assert!(costs.iter().all(|c| (c - alone.cost).abs() <= tolerance * alone.cost), "one minimum: {costs:?}");
    assert!(costs.iter().any(|&c| c < alone.cost), "no restart lower by rounding: {costs:?}");
    assert_eq!(restarted.model, alone.model);
    assert_eq!(restarted.cost, alone.cost);
}

#[test]
fn a_later_start_beats_the_best_only_by_more_than_the_function_tolerance() {
    assert!(!beats(1.0 - 1e-13, 1.0, 1e-10), "a rounding-size difference is a tie");
    assert!(!beats(1.0, 1.0, 1e-10));
    assert!(beats(1.0 - 1e-9, 1.0, 1e-10));
    assert!(!beats(f64::NAN, 1.0, 1e-10));
    assert!(beats(1.0, f64::NAN, 1e-10), "a finite cost beats one that is not");
    assert!(beats(1.0, f64::INFINITY, 1e-10));
    assert!(!beats(f64::INFINITY, f64::INFINITY, 1e-10));
}

/// The same on artefact distances (the dense path, whose nominal start is solved before its
/// restarts): restarts that reach the nominal start's minimum leave its solution as it is.
#[test]
fn artefact_restarts_reaching_the_same_minimum_keep_the_nominal_start_s_solution() {
    let nominal = ArmModel::suta_nominal();
    let sim = crate::simulate::simulate(&nominal, &crate::simulate::SimulationOptions::default());
    let data = Observations::from_sessions(&sim.calibration, &sim.artefact);
    let alone = calibrate(&nominal, &data, &SolveOptions { restarts: Some(0), ..SolveOptions::default() })
        .expect("nominal start");
    let restarted =
        calibrate(&nominal, &data, &SolveOptions { restarts: Some(8), ..SolveOptions::default() })
            .expect("restarts");
    assert_the_nominal_start_is_kept(&alone, &restarted, 1e-12);
}
