//! Self-tests of the independent tracker-data generator (`kincal_e2e::tracker_gen`): its URDF
//! against its DH, the Python URDF peer (`bench/urdf_fk_peer.py`) against its Rust kinematics, its
//! quaternions, inverse kinematics and traits against their configured sizes, and reproducibility.

use kincal_e2e::tracker_gen::{
    fit_rigid, generate, gravity_levers_m, inverse_kinematics, perturb, quaternion_matrix,
    rotation_vector_of, v_norm, Arm, BadPoints, Chain, EncoderHarmonic, ExportMistake, GravitySag,
    HiddenErrorSizes, InstrumentDrift, Mat3, Pose, SessionPlan, ThermalDrift, ToolRemount, TrackerOptions,
    UncertaintyColumn, UrdfJoint, Vec3, FOLDER_TAG,
};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::path::{Path, PathBuf};

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("kincal-tracker-gen-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("scratch folder");
    dir
}

fn distance(a: Vec3, b: Vec3) -> f64 {
    v_norm([a[0] - b[0], a[1] - b[1], a[2] - b[2]])
}

/// Angle between two rotations, rad.
fn angle_between(a: &Mat3, b: &Mat3) -> f64 {
    let bt = [0, 1, 2].map(|i| [b[0][i], b[1][i], b[2][i]]);
    let m = [0, 1, 2].map(|i| [0, 1, 2].map(|j| (0..3).map(|k| a[i][k] * bt[k][j]).sum::<f64>()));
    v_norm(rotation_vector_of(&m))
}

fn random_q(arm: &Arm, rng: &mut ChaCha8Rng) -> Vec<f64> {
    arm.limits_deg.iter().map(|&(lo, hi)| lo + (hi - lo) * rng.random::<f64>()).collect()
}

/// A minimal reader of the URDF this generator writes: revolute origins and axes in order, then
/// the flange and tool origins.
fn read_own_urdf(text: &str, like: &Arm) -> Arm {
    let attr = |line: &str, name: &str| -> Vec3 {
        let start = line.find(&format!("{name}=\"")).expect("attribute") + name.len() + 2;
        let end = start + line[start..].find('"').expect("closing quote");
        let v: Vec<f64> = line[start..end].split_whitespace().map(|v| v.parse().expect("number")).collect();
        [v[0], v[1], v[2]]
    };
    let origins: Vec<(Vec3, Vec3)> = text
        .lines()
        .filter(|l| l.contains("<origin"))
        .map(|l| (attr(l, "xyz").map(|v| v * 1000.0), attr(l, "rpy").map(f64::to_degrees)))
        .collect();
    let axes: Vec<Vec3> = text.lines().filter(|l| l.contains("<axis")).map(|l| attr(l, "xyz")).collect();
    let n = axes.len();
    assert_eq!(origins.len(), n + 2, "N joints + flange + tool");
    Arm {
        chain: Chain::Urdf {
            joints: (0..n)
                .map(|j| UrdfJoint { xyz_mm: origins[j].0, rpy_deg: origins[j].1, axis: axes[j] })
                .collect(),
            flange_xyz_mm: origins[n].0,
            flange_rpy_deg: origins[n].1,
        },
        tool_mm: origins[n + 1].0,
        tool_rpy_deg: origins[n + 1].1,
        ..like.clone()
    }
}

#[test]
fn urdf_written_and_dh_give_the_same_tool_pose() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    for options in [TrackerOptions::iiwa_five_sessions(3), TrackerOptions::industrial_6dof(4)] {
        let data = generate(&options);
        for arm in [&data.truth.nominal, &data.truth.truth] {
            let converted = arm.to_urdf_chain();
            let reread = read_own_urdf(&arm.urdf("robot"), arm);
            for _ in 0..20 {
                let q = random_q(arm, &mut rng);
                let dh = arm.tool_pose(&q);
                for other in [converted.tool_pose(&q), reread.tool_pose(&q)] {
                    let d = distance(dh.translation_mm, other.translation_mm);
                    assert!(d < 1e-9, "{}: URDF and DH differ by {d:e} mm at {q:?}", arm.name);
                    assert!(angle_between(&dh.rotation, &other.rotation) < 1e-12);
                }
            }
        }
    }
}

#[test]
fn python_urdf_peer_agrees_with_the_rust_kinematics() {
    let dir = scratch("peer");
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    // The two true DH arms, the nominal 6R arm (an origin at pitch −90°, where rpy is degenerate),
    // a URDF-joint arm with perturbed origins, and the most and fewest joints (12R, 2R).
    let urdf_arm = perturb(&Arm::iiwa7().to_urdf_chain(), &HiddenErrorSizes::default(), 21).0;
    let arms = [
        generate(&TrackerOptions::iiwa_five_sessions(5)).truth.truth,
        generate(&TrackerOptions::industrial_6dof(6)).truth.truth,
        Arm::industrial6(),
        urdf_arm,
        perturb(&Arm::serial12(), &HiddenErrorSizes::default(), 22).0,
        Arm::shoulder2(),
    ];
    let peer = Path::new(env!("CARGO_MANIFEST_DIR")).join("../bench/urdf_fk_peer.py");
    let python = |args: &[&std::ffi::OsStr]| {
        std::process::Command::new("python3")
            .arg(&peer)
            .args(args)
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .expect("python3 runs (scripts/setup.sh installs it with numpy)")
    };
    // One peer per arm, all running at once.
    let runs: Vec<(Vec<Vec<f64>>, std::process::Child)> = arms
        .iter()
        .enumerate()
        .map(|(k, arm)| {
            let urdf = dir.join(format!("arm{k}.urdf"));
            arm.write_urdf(&urdf, "robot").expect("URDF written");
            let poses: Vec<Vec<f64>> = (0..20).map(|_| random_q(arm, &mut rng)).collect();
            let mut csv: String =
                (1..=arm.joints()).map(|j| format!("q{j}_deg")).collect::<Vec<_>>().join(",") + "\n";
            for q in &poses {
                csv += &(q.iter().map(|v| format!("{v:.17e}")).collect::<Vec<_>>().join(",") + "\n");
            }
            let q_file = dir.join(format!("q{k}.csv"));
            std::fs::write(&q_file, csv).expect("poses written");
            let args = ["--base", "base_link", "--tip", "tool0", "--q-file"].map(std::ffi::OsStr::new);
            let child = python(&[&[urdf.as_os_str()], &args[..], &[q_file.as_os_str()]].concat());
            (poses, child)
        })
        .collect();
    for (arm, (poses, child)) in arms.iter().zip(runs) {
        let out = child.wait_with_output().expect("peer ends");
        assert!(out.status.success(), "peer failed: {}", String::from_utf8_lossy(&out.stderr));
        let json: serde_json::Value = serde_json::from_slice(&out.stdout).expect("peer prints JSON");
        let got = json["poses"].as_array().expect("poses");
        assert_eq!(got.len(), poses.len());
        for (q, pose) in poses.iter().zip(got) {
            let ours = arm.tool_pose(q);
            let p: Vec<f64> =
                pose["position_mm"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect();
            let d = distance(ours.translation_mm, [p[0], p[1], p[2]]);
            assert!(d < 1e-6, "{}: peer differs by {d:e} mm at {q:?}", arm.name);
            for i in 0..3 {
                for j in 0..3 {
                    let r = pose["rotation"][i][j].as_f64().unwrap();
                    assert!((r - ours.rotation[i][j]).abs() < 1e-9);
                }
            }
        }
    }
    // Wrong input: a named error and exit status 2, no pose.
    let args = ["--base", "tool0", "--tip", "base_link", "--q", "1,2,3,4,5,6,7"].map(std::ffi::OsStr::new);
    let out = python(&[&[dir.join("arm0.urdf").as_os_str()], &args[..]].concat())
        .wait_with_output()
        .expect("peer ends");
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("'base_link' is not below 'tool0'"));
    assert!(out.stdout.is_empty());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn quaternions_are_unit_and_match_base_chain_and_probe() {
    let mut options = TrackerOptions::industrial_6dof(7);
    options.orientation_sigma_deg = Some(0.0);
    let data = generate(&options);
    for (s, session) in data.sessions.iter().enumerate() {
        for row in &session.rows {
            let q = row.quaternion.expect("6-DoF probe");
            assert!((q.iter().map(|v| v * v).sum::<f64>() - 1.0).abs() < 1e-12);
            assert!(q[0] >= 0.0, "scalar first and non-negative");
            // R_meas = R(B_s) · R(F) · R_t, composed here independently of the generator.
            let chain = data.truth.truth.frames(&row.q_deg).flange.rotation;
            let expected = Pose::rotation(data.truth.bases[s].rotation)
                .then(&Pose::rotation(chain))
                .then(&Pose::rotation(data.truth.truth.tool().rotation));
            assert!(angle_between(&quaternion_matrix(q), &expected.rotation) < 1e-9);
        }
    }
    // With noise, the orientation differs by about σ√3.
    options.orientation_sigma_deg = Some(0.01);
    let noisy = generate(&options);
    let angles: Vec<f64> = noisy.sessions[0]
        .rows
        .iter()
        .map(|r| angle_between(&quaternion_matrix(r.quaternion.unwrap()), &r.exact_rotation).to_degrees())
        .collect();
    let rms = (angles.iter().map(|a| a * a).sum::<f64>() / angles.len() as f64).sqrt();
    assert!((rms / (0.01 * 3f64.sqrt()) - 1.0).abs() < 0.25, "orientation noise RMS {rms}°");
}

#[test]
fn inverse_kinematics_reaches_targets_and_constant_orientation_sessions_hold_it() {
    let mut rng = ChaCha8Rng::seed_from_u64(8);
    for arm in [Arm::iiwa7(), Arm::industrial6()] {
        let mut far = 0;
        for _ in 0..20 {
            // A target reachable by construction (the pose at q0 + up to ±5° per joint), started
            // at q0, is reached; a random target from a random start often is not (a local
            // method, and a target beyond a stretched elbow is out of reach), but when it is,
            // exactly.
            let inner: Vec<(f64, f64)> =
                arm.limits_deg.iter().map(|&(lo, hi)| (lo + 10.0, hi - 10.0)).collect();
            let q0 = random_q(&Arm { limits_deg: inner, ..arm.clone() }, &mut rng);
            let near_start = q0.clone();
            let q_near: Vec<f64> = q0.iter().map(|v| v + 10.0 * (rng.random::<f64>() - 0.5)).collect();
            let near = arm.tool_pose(&q_near);
            let q = inverse_kinematics(&arm, &near, &near_start).expect("a near target is reached");
            let got = arm.tool_pose(&q);
            assert!(distance(got.translation_mm, near.translation_mm) < 1e-6, "{}", arm.name);
            assert!(angle_between(&got.rotation, &near.rotation) < 1e-9);
            let goal = arm.tool_pose(&random_q(&arm, &mut rng));
            if let Some(q) = inverse_kinematics(&arm, &goal, &q0) {
                let got = arm.tool_pose(&q);
                assert!(distance(got.translation_mm, goal.translation_mm) < 1e-6, "{}", arm.name);
                assert!(angle_between(&got.rotation, &goal.rotation) < 1e-9);
                far += 1;
            }
        }
        println!("{}: IK reached {far} of 20 random far targets", arm.name);
    }

    let mut options = TrackerOptions::iiwa_five_sessions(9);
    options.sessions[1] =
        SessionPlan { name: "grid".into(), poses: 27, constant_orientation: true, joints_deg: Vec::new() };
    let data = generate(&options);
    let grid = &data.sessions[1].rows;
    assert_eq!(grid.len(), 27);
    let first = grid[0].tool_in_base;
    for row in grid {
        let angle = angle_between(&row.tool_in_base.rotation, &first.rotation);
        assert!(angle < 1e-6, "grid orientation moved by {angle:e} rad");
        // Positions on a 100 mm grid (readings rounded to 1e-6°).
        for i in 0..3 {
            let steps =
                (row.tool_in_base.translation_mm[i] - first.translation_mm[i]) / options.grid_spacing_mm;
            assert!((steps - steps.round()).abs() < 1e-6, "off the grid: {steps}");
        }
    }
    // The random sessions do vary their orientation.
    let random = &data.sessions[0].rows;
    let spread =
        random.iter().map(|r| angle_between(&r.tool_in_base.rotation, &random[0].tool_in_base.rotation));
    assert!(spread.fold(0.0, f64::max).to_degrees() > 30.0);
}

#[test]
fn thermal_drift_and_tool_remount_have_their_configured_size() {
    let mut options = TrackerOptions::iiwa_five_sessions(10);
    options.thermal = Some(ThermalDrift {
        expansion_per_c: 12e-6,
        start_c: 20.0,
        rise_c: 1.0,
        session: None,
        time_constant_s: None,
    });
    options.tool_remount = Some(ToolRemount { session: 2, size_mm: 0.8 });
    let data = generate(&options);
    let (session, offset) = data.truth.tool_remount.expect("remount recorded");
    assert_eq!(session, 2);
    assert!((v_norm(offset) - 0.8).abs() < 1e-12);
    let n = data.sessions[0].rows.len() as f64;
    for (s, sess) in data.sessions.iter().enumerate() {
        for row in &sess.rows {
            let undisturbed = data.truth.truth.tool_pose(&row.q_deg);
            let flange = data.truth.truth.frames(&row.q_deg).flange;
            let moved = if s == 2 {
                [0, 1, 2].map(|i| (0..3).map(|k| flange.rotation[i][k] * offset[k]).sum::<f64>())
            } else {
                [0.0; 3]
            };
            let expected_c = row.time_s / (options.seconds_per_point * n);
            assert!((row.temp_c - 20.0 - expected_c).abs() < 1e-12);
            let scale = 1.0 + 12e-6 * expected_c;
            let p = [0, 1, 2].map(|i| (undisturbed.translation_mm[i] + moved[i]) * scale);
            assert!(distance(p, row.tool_in_base.translation_mm) < 1e-9);
        }
        // Over the session the arm grows by 12 µm/°C·m: ~1 °C at ~1 m reach is ~10 µm.
        let last = sess.rows.last().unwrap();
        assert!((last.temp_c - 20.0 - (n - 1.0) / n).abs() < 1e-9);
    }
    let csv = data.csv(0);
    let header = csv.lines().nth(1).unwrap();
    assert_eq!(
        header,
        "pose,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,q7_deg,x_mm,y_mm,z_mm,sigma_mm,time_s,temp_C"
    );
}

/// Thermal drift in one session only, as an exponential warm-up: that session's temperature and
/// scale follow `T_ref + rise·(1 − e^(−t/τ))/(1 − e^(−D/τ))`, the others stay at T_ref, unscaled.
#[test]
fn a_warm_up_in_one_session_follows_its_formula_and_leaves_the_others_alone() {
    let mut options = TrackerOptions::iiwa_five_sessions(11);
    let thermal = ThermalDrift {
        expansion_per_c: 23e-6,
        start_c: 20.0,
        rise_c: 8.0,
        session: Some(1),
        time_constant_s: Some(300.0),
    };
    options.thermal = Some(thermal);
    let data = generate(&options);
    let duration_s = options.seconds_per_point * data.sessions[1].rows.len() as f64;
    for (s, sess) in data.sessions.iter().enumerate() {
        for row in &sess.rows {
            let rise = if s == 1 {
                8.0 * (1.0 - (-row.time_s / 300.0).exp()) / (1.0 - (-duration_s / 300.0).exp())
            } else {
                0.0
            };
            assert!((row.temp_c - 20.0 - rise).abs() < 1e-12, "session {s}: {} °C", row.temp_c);
            let undisturbed = data.truth.truth.tool_pose(&row.q_deg).translation_mm;
            let p = undisturbed.map(|v| v * (1.0 + 23e-6 * rise));
            assert!(distance(p, row.tool_in_base.translation_mm) < 1e-9);
        }
    }
    // Most of the rise comes early: two thirds of it by a third of the session (τ = D/3).
    let third = &data.sessions[1].rows[data.sessions[1].rows.len() / 3];
    assert!(third.temp_c - 20.0 > 0.6 * 8.0, "{}", third.temp_c);
}

#[test]
fn gravity_levers_and_sag_follow_the_formula() {
    // Stretched horizontally (iiwa q2 = 90°, tool at the flange): joint 2 carries unit masses at
    // the joint origins 0, 420, 420, 820, 820 mm, the flange (946 mm) and the tool point (946 mm)
    // from its axis; the vertical arm has no lever anywhere.
    let mut arm = Arm::iiwa7();
    arm.tool_mm = [0.0; 3];
    let vertical = gravity_levers_m(&arm, &[0.0; 7], [0.0, 0.0, -1.0]);
    assert!(vertical.iter().all(|l| l.abs() < 1e-12), "{vertical:?}");
    let horizontal = gravity_levers_m(&arm, &[0.0, 90.0, 0.0, 0.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0]);
    assert!((horizontal[1].abs() - 4.372).abs() < 1e-9, "{horizontal:?}");
    assert!(horizontal[0].abs() < 1e-12, "a vertical axis carries no gravity moment");
    // Hanging from the ceiling the moments turn sign. On a wall with gravity along base y, the
    // arm stretched along base x: joint 2's axis (base y) is parallel to gravity and carries
    // nothing, joint 1's (base z) carries the whole lever.
    let hanging = gravity_levers_m(&arm, &[0.0, 90.0, 0.0, 0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0]);
    assert!(hanging.iter().zip(&horizontal).all(|(a, b)| (a + b).abs() < 1e-12));
    let wall = gravity_levers_m(&arm, &[0.0, 90.0, 0.0, 0.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0]);
    assert!(wall[1].abs() < 1e-12 && (wall[0].abs() - 4.372).abs() < 1e-9, "{wall:?}");

    let mut options = TrackerOptions::iiwa_five_sessions(11);
    let c = vec![0.0, 0.01, 0.005, 0.01, 0.0, 0.0, 0.0];
    options.gravity_sag = Some(GravitySag::floor_mounted(c.clone()));
    let data = generate(&options);
    let truth = &data.truth.truth;
    let mut largest_mm: f64 = 0.0;
    for row in &data.sessions[0].rows {
        let levers = gravity_levers_m(truth, &row.q_deg, [0.0, 0.0, -1.0]);
        let deflected: Vec<f64> =
            row.q_deg.iter().zip(&levers).zip(&c).map(|((q, l), c)| q + c * l).collect();
        let expected = truth.tool_pose(&deflected).translation_mm;
        assert!(distance(expected, row.tool_in_base.translation_mm) < 1e-9);
        largest_mm = largest_mm.max(distance(expected, truth.tool_pose(&row.q_deg).translation_mm));
    }
    assert!(largest_mm > 0.05 && largest_mm < 2.0, "sag of {largest_mm} mm is not realistic");
}

#[test]
fn sessions_bases_noise_floor_and_hidden_errors_are_as_configured() {
    let data = generate(&TrackerOptions::iiwa_five_sessions(12));
    let bases = &data.truth.bases;
    for base in &bases[1..] {
        let turn_deg = angle_between(&base.rotation, &bases[0].rotation).to_degrees();
        assert!((5.0..=10.0).contains(&turn_deg), "session turned by {turn_deg}°");
        let shift = distance(base.translation_mm, bases[0].translation_mm);
        assert!((300.0..=1000.0).contains(&shift), "session moved by {shift} mm");
    }
    // Horn on noise-free points returns the true base.
    let rows = &data.sessions[3].rows;
    let p: Vec<Vec3> = rows.iter().map(|r| r.tool_in_base.translation_mm).collect();
    let exact: Vec<Vec3> = rows.iter().map(|r| r.exact_mm).collect();
    let fitted = fit_rigid(&p, &exact);
    for (p, x) in p.iter().zip(&exact) {
        assert!(distance(bases[3].inverse().apply(*x), *p) < 1e-9);
    }
    assert!(angle_between(&fitted.rotation, &bases[3].rotation) < 1e-10);
    assert!(distance(fitted.translation_mm, bases[3].translation_mm) < 1e-7);
    // The floor is the noise: about σ√3 per point.
    let floor = data.true_floor_mm(&[0, 1, 2, 3, 4]);
    assert_eq!(floor.points, 300);
    let expected = 0.02 * 3f64.sqrt();
    assert!((floor.rms_mm / expected - 1.0).abs() < 0.12, "floor {} mm, σ√3 = {expected}", floor.rms_mm);
    // Hidden errors inside their stated sizes, and the truth differs from nominal.
    for e in &data.truth.hidden_errors {
        let limit = if e.name.starts_with("tcp") {
            1.0
        } else if e.name.starts_with("length") || e.name.starts_with("link_offset") {
            0.5
        } else {
            0.1
        };
        assert!((e.truth - e.nominal).abs() <= limit, "{}: {} → {}", e.name, e.nominal, e.truth);
    }
    assert_eq!(data.truth.hidden_errors.len(), 7 * 4 + 3);
    // The 6R arm's parallel pair: β perturbed on row 2, its d left at nominal (Hayati).
    let industrial = generate(&TrackerOptions::industrial_6dof(13));
    let names: Vec<&str> = industrial.truth.hidden_errors.iter().map(|e| e.name.as_str()).collect();
    assert!(names.contains(&"axis:2") && !names.contains(&"length:2") && !names.contains(&"axis:3"));
    let row2 = industrial.truth.truth.dh_rows().unwrap()[1];
    assert!(row2.beta_deg != 0.0 && row2.d_mm == 0.0);
}

#[test]
fn csv_files_are_tagged_reproducible_and_carry_repeats_and_coverage() {
    let mut options = TrackerOptions::industrial_6dof(14).few_placements(2);
    options.repeats = 3;
    options.low_coverage = Some((4, 10.0));
    let a = scratch("csv-a");
    let b = scratch("csv-b");
    let files_a = generate(&options).write(&a).expect("written");
    let files_b = generate(&options).write(&b).expect("written");
    assert_eq!(files_a.len(), 2);
    for (fa, fb) in files_a.iter().zip(&files_b) {
        assert_eq!(std::fs::read(fa).unwrap(), std::fs::read(fb).unwrap(), "same seed, same bytes");
    }
    let text = std::fs::read_to_string(&files_a[0]).unwrap();
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some(format!("# {FOLDER_TAG}").as_str()));
    assert_eq!(
        lines.next(),
        Some("pose,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,x_mm,y_mm,z_mm,qw,qx,qy,qz,u95_mm")
    );
    let rows: Vec<Vec<f64>> =
        lines.map(|l| l.split(',').map(|v| v.parse().expect("number")).collect()).collect();
    assert_eq!(rows.len(), 150);
    for triple in rows.chunks(3) {
        assert!(
            triple.iter().all(|r| r[0] == triple[0][0] && r[1..7] == triple[0][1..7]),
            "repeats share a pose"
        );
        assert!(triple[0][4].abs() <= 5.0, "joint 4 kept to ±5°: {}", triple[0][4]);
        assert!(triple[0][14] == 0.04, "u95 = 2σ");
    }
    options.seed += 1;
    assert_ne!(generate(&options).csv(0), std::fs::read_to_string(&files_a[0]).unwrap());
    options.uncertainty = UncertaintyColumn::None;
    options.tag = "other/2".into();
    assert!(generate(&options).csv(0).starts_with("# other/2\npose,"));
    let _ = std::fs::remove_dir_all(&a);
    let _ = std::fs::remove_dir_all(&b);
}

#[test]
fn instrument_drift_and_bad_points_have_their_size_and_traits_leave_the_rest_alone() {
    let mut options = TrackerOptions::iiwa_five_sessions(15);
    options.noise_sigma_mm = 0.0;
    let plain = generate(&options);
    // Without noise the true model leaves nothing, whatever Horn has to undo.
    assert!(plain.true_floor_mm(&[0, 1, 2, 3, 4]).max_mm < 1e-9);
    options.tool_remount = Some(ToolRemount { session: 1, size_mm: 0.6 });
    options.instrument_drift = Some(InstrumentDrift { session: 3, mm_per_hour: 0.05 });
    options.bad_points = Some(BadPoints { count: 4, size_mm: 1.5 });
    let data = generate(&options);
    let (_, velocity) = data.truth.instrument_drift.expect("drift recorded");
    assert!((v_norm(velocity) * 3600.0 - 0.05).abs() < 1e-15);
    assert_eq!(data.truth.bad_points.len(), 4);
    for (s, session) in data.sessions.iter().enumerate() {
        for (k, row) in session.rows.iter().enumerate() {
            let base = data.truth.bases[s].apply(row.tool_in_base.translation_mm);
            let drift = if s == 3 { velocity.map(|v| v * row.time_s) } else { [0.0; 3] };
            assert!(distance(row.exact_mm, [0, 1, 2].map(|i| base[i] + drift[i])) < 1e-9);
            let bad = data.truth.bad_points.iter().find(|b| (b.0, b.1) == (s, k));
            let gross = distance(row.x_mm, row.exact_mm);
            match bad {
                Some(b) => assert!((gross - 1.5).abs() < 1e-9 && (v_norm(b.2) - 1.5).abs() < 1e-12),
                None => assert!(gross < 1e-12),
            }
        }
        // Each trait has its own random stream: sessions it does not touch are unchanged.
        let touched = s == 1 || s == 3 || data.truth.bad_points.iter().any(|b| b.0 == s);
        assert_eq!(data.csv(s) == plain.csv(s), !touched, "session {s}");
    }
    // The floor keeps the bad points (no model explains them) and removes the drift.
    let drifting = data.true_floor_mm(&[3]);
    let has_bad = data.truth.bad_points.iter().any(|b| b.0 == 3);
    assert_eq!(drifting.max_mm > 0.5, has_bad, "{drifting:?}");
}

#[test]
fn kincal_model_lists_every_row() {
    let arm = generate(&TrackerOptions::industrial_6dof(16)).truth.truth;
    let toml = arm.kincal_model_toml().expect("a DH arm");
    assert!(toml.starts_with("format = \"kincal-arm/1\"\n"));
    assert_eq!(toml.matches("[[joint]]").count(), 6);
    let beta = arm.dh_rows().unwrap()[1].beta_deg;
    assert!(toml.contains(&format!("axis_deg = {beta:?}\n")));
    assert!(arm.to_urdf_chain().kincal_model_toml().is_none());
}

#[test]
fn written_rows_are_the_measurement_of_their_written_readings() {
    let mut options = TrackerOptions::industrial_6dof(17);
    options.noise_sigma_mm = 0.0;
    options.orientation_sigma_deg = Some(0.0);
    options.sessions[2].constant_orientation = true;
    options.tool_remount = Some(ToolRemount { session: 2, size_mm: 0.7 });
    let data = generate(&options);
    for (s, base) in data.truth.bases.iter().enumerate() {
        let csv = data.csv(s);
        for line in csv.lines().skip(2) {
            let v: Vec<f64> = line.split(',').map(|f| f.parse().expect("number")).collect();
            let mut arm = data.truth.truth.clone();
            if let Some((_, offset)) = data.truth.tool_remount.filter(|r| r.0 == s) {
                arm.tool_mm = [0, 1, 2].map(|i| arm.tool_mm[i] + offset[i]);
            }
            let expected = base.then(&arm.tool_pose(&v[1..7]));
            assert!(distance(expected.translation_mm, [v[7], v[8], v[9]]) < 2e-6, "{line}");
            let written = quaternion_matrix([v[10], v[11], v[12], v[13]]);
            assert!(angle_between(&written, &expected.rotation) < 1e-8, "{line}");
            // The grid session's probe keeps one orientation (readings rounded to 1e-6°).
            let first = data.sessions[s].rows[0].exact_rotation;
            assert!(s != 2 || angle_between(&written, &first) < 1e-6, "{line}");
        }
    }
}

#[test]
fn export_mistakes_write_wrong_values_under_the_right_header() {
    let mut options = TrackerOptions::industrial_6dof(18).few_placements(1);
    let right = generate(&options).csv(0);
    let parse = |text: &str| -> Vec<Vec<f64>> {
        text.lines().skip(2).map(|l| l.split(',').map(|v| v.parse().expect("number")).collect()).collect()
    };
    let good = parse(&right);
    for (mistake, check) in [
        (ExportMistake::MetresUnderMm, 7..10),
        (ExportMistake::RadiansUnderDeg, 1..7),
        (ExportMistake::ScalarLastQuaternion, 10..14),
    ] {
        options.export_mistake = mistake;
        let text = generate(&options).csv(0);
        assert_eq!(text.lines().nth(1), right.lines().nth(1), "{mistake:?}: same header");
        for (bad, good) in parse(&text).iter().zip(&good) {
            for c in check.clone() {
                let expected = match mistake {
                    ExportMistake::MetresUnderMm => good[c] / 1000.0,
                    ExportMistake::RadiansUnderDeg => good[c].to_radians(),
                    _ => good[10 + (c - 10 + 1) % 4],
                };
                assert!((bad[c] - expected).abs() < 1e-8, "{mistake:?} column {c}: {} vs {expected}", bad[c]);
            }
        }
    }
}

/// The periodic encoder error turns only its joint, by a·sin nq + b·cos nq of the reported angle.
#[test]
fn an_encoder_harmonic_turns_its_joint_as_configured() {
    let mut options = TrackerOptions::iiwa_five_sessions(13);
    let h = EncoderHarmonic { joint: 4, order: 2, sin_deg: 0.02, cos_deg: -0.01 };
    options.encoder_harmonic = Some(h);
    let data = generate(&options);
    let truth = &data.truth.truth;
    let mut largest_mm: f64 = 0.0;
    for row in &data.sessions[0].rows {
        let mut turned = row.q_deg.clone();
        let phase = 2.0 * row.q_deg[3].to_radians();
        turned[3] += 0.02 * phase.sin() - 0.01 * phase.cos();
        let expected = truth.tool_pose(&turned).translation_mm;
        assert!(distance(expected, row.tool_in_base.translation_mm) < 1e-9);
        largest_mm = largest_mm.max(distance(expected, truth.tool_pose(&row.q_deg).translation_mm));
    }
    assert!(largest_mm > 0.05 && largest_mm < 2.0, "{largest_mm} mm");
    assert_eq!(data.truth.encoder_harmonic, Some(h));
}
