//! Profiling harness for the calibration's speed (under `perf record --call-graph dwarf`, or by
//! its own CPU and wall times, median over N runs):
//! `cargo run --release -p kincal --example prof -- MODE [N]`, MODE one of `artefact` (nominal +
//! 8 restarts), `one` (nominal start), `tracker` (one calibration of the bench arm's 5 sessions),
//! `fk` (one pose with and without its Jacobian), `evals` (one residual and one normal-equation
//! evaluation of each problem), or `write DIR` (the problems' files, for `kincal calibrate`).
use anyhow::{Context, Result};
use kincal::calib::fit::calibrate;
use kincal::calib::setup::SolveOptions;
use kincal::data::tracker::TRACKER_FORMAT;
use kincal::data::{Joints, Kind, Observation, Observations, Target};
use kincal::model::kinematics::tool_pose;
use kincal::model::{ArmModel, Joint, ParamId};
use nalgebra::{Rotation3, Vector3};
use rand::{RngExt, SeedableRng};
use rand_distr::Distribution;
use std::path::Path;
use std::time::Instant;

fn arm() -> ArmModel {
    let alpha = [-90.0, 90.0, 90.0, -90.0, -90.0, 90.0, 0.0];
    let d = [360.0, 0.0, 420.0, 0.0, 400.0, 0.0, 126.0];
    let mut model = ArmModel::suta_nominal();
    model.name = "7R bench arm".into();
    model.joints = (0..7).map(|j| Joint { d_mm: d[j], alpha_deg: alpha[j], ..Joint::default() }).collect();
    model.tcp_mm = [40.0, -25.0, 120.0];
    model.free.clear();
    for j in 1..7 {
        model.free_param(ParamId::Offset(j), -5.0, 5.0);
    }
    for (j, dj) in d.iter().enumerate().take(6).skip(1) {
        model.free_param(ParamId::Length(j), dj - 10.0, dj + 10.0);
    }
    for (j, aj) in alpha.iter().enumerate().take(6) {
        model.free_param(ParamId::LinkOffset(j), -10.0, 10.0);
        model.free_param(ParamId::Twist(j), aj - 5.0, aj + 5.0);
    }
    model
}

fn sessions(truth: &ArmModel, count: usize, points: usize, seed: u64) -> Result<Observations> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let noise = rand_distr::Normal::new(0.0, 0.02)?;
    let mut data = Observations::new(7, Vec::new());
    for s in 0..count {
        let group = data.push_group(format!("bench_{}", s + 1), "bench.csv".into(), Kind::Tracker);
        let rotation = Rotation3::from_euler_angles(0.1, -0.05, 1.2 * s as f64).into_inner();
        let shift = Vector3::new(2500.0, -300.0 * s as f64, 400.0);
        for i in 0..points {
            let q: Vec<f64> = (0..7).map(|_| rng.random_range(-120.0..120.0)).collect();
            let p = rotation * tool_pose(truth, &q).position_mm + shift;
            let n = Vector3::from_fn(|_, _| noise.sample(&mut rng));
            data.obs.push(Observation {
                block: 0,
                group,
                repeat: 1,
                q_deg: Joints::new(&q).context("seven joint angles")?,
                q_sigma_deg: None,
                target: Target::Point { xyz_mm: p + n, orientation: None },
                sigma_mm: Some(0.02),
                time_s: None,
                temp_c: None,
                pose: None,
                line: i + 3,
                tip: 0,
            });
        }
    }
    data.rebuild_blocks();
    Ok(data)
}

fn write_sessions(data: &Observations, dir: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| dir.display().to_string())?;
    for (g, group) in data.groups.iter().enumerate() {
        let mut text = format!("# {TRACKER_FORMAT}\n");
        let joints: Vec<String> = (1..=data.joints).map(|j| format!("q{j}_deg")).collect();
        text += &format!("{},x_mm,y_mm,z_mm,sigma_mm\n", joints.join(","));
        for p in data.obs.iter().filter(|o| o.group == g) {
            let q: Vec<String> = p.q_deg.iter().map(|v| format!("{v:?}")).collect();
            let point = p.point_mm().unwrap_or_default();
            let [x, y, z] = [point.x, point.y, point.z];
            text += &format!("{},{x:?},{y:?},{z:?},{:?}\n", q.join(","), p.sigma_mm.unwrap_or(0.02));
        }
        let path = dir.join(format!("{}.csv", group.name));
        std::fs::write(&path, text).with_context(|| path.display().to_string())?;
    }
    Ok(())
}

fn truth(nominal: &ArmModel) -> ArmModel {
    let mut truth = nominal.clone();
    for (k, f) in nominal.free.iter().enumerate() {
        truth.set(f.id, nominal.get(f.id) + 0.2 * ((k as f64 * 1.7).sin()));
    }
    truth
}

fn cpu_ms() -> f64 {
    let mut t = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut t) };
    t.tv_sec as f64 * 1e3 + t.tv_nsec as f64 * 1e-6
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(20);
    match args[1].as_str() {
        "write" => {
            let nominal = arm();
            let t = truth(&nominal);
            let cal = sessions(&t, 5, 720, 1)?;
            let mut val = sessions(&t, 1, 720, 2)?;
            val.groups[0].name = "bench_held_out".into();
            let dir = Path::new(&args[2]);
            write_sessions(&cal, &dir.join("cal"))?;
            write_sessions(&val, &dir.join("val"))?;
            nominal.save(&dir.join("nominal.toml"))?;
            let (nom, sim) = kincal::calib::peer::thesis_sized_problem(1);
            sim.write(&dir.join("art"))?;
            nom.save(&dir.join("art/nominal.toml"))?;
        }
        "tracker" => {
            let nominal = arm();
            let t = truth(&nominal);
            let cal = sessions(&t, 5, 720, 1)?;
            let mut times = vec![];
            let mut fit = None;
            for _ in 0..n {
                let (w, c) = (Instant::now(), cpu_ms());
                fit = Some(calibrate(&nominal, &cal, &SolveOptions::default())?);
                times.push((cpu_ms() - c, w.elapsed().as_secs_f64() * 1e3));
            }
            times.sort_by(|a, b| a.0.total_cmp(&b.0));
            let f = fit.context("no fit")?;
            println!(
                "tracker cpu/wall ms median {:?}, cost {:.15e}, rms {:.12} iters {}",
                times[times.len() / 2],
                f.cost,
                f.rms_mm,
                f.iterations
            );
        }
        "artefact" | "one" => {
            let restarts = if args[1] == "one" { Some(0) } else { None };
            let (nominal, sim) = kincal::calib::peer::thesis_sized_problem(1);
            let cal = Observations::from_sessions(&sim.calibration, &sim.artefact);
            let options = SolveOptions { restarts, ..SolveOptions::default() };
            let mut times = vec![];
            let mut fit = None;
            for _ in 0..n {
                let (w, c) = (Instant::now(), cpu_ms());
                fit = Some(calibrate(&nominal, &cal, &options)?);
                times.push((cpu_ms() - c, w.elapsed().as_secs_f64() * 1e3));
            }
            times.sort_by(|a, b| a.0.total_cmp(&b.0));
            let f = fit.context("no fit")?;
            println!(
                "{} cpu/wall ms median {:?}, cost {:.15e}, rms {:.12} iters {:?}",
                args[1],
                times[times.len() / 2],
                f.cost,
                f.rms_mm,
                f.starts.iter().map(|s| s.iterations).collect::<Vec<_>>()
            );
        }
        "fk" => {
            let nominal = arm();
            let ids: Vec<ParamId> = nominal
                .free
                .iter()
                .map(|f| f.id)
                .chain([ParamId::Tcp(0), ParamId::Tcp(1), ParamId::Tcp(2)])
                .collect();
            let cols = kincal::model::kinematics::ColumnMap::new(&ids);
            let mut jac = vec![[0.0; 9]; ids.len()];
            let qs: Vec<Vec<f64>> = (0..1000)
                .map(|i| (0..7).map(|j| ((i * 7 + j) as f64 * 0.37).sin() * 100.0).collect())
                .collect();
            let mut acc = 0.0;
            let c = cpu_ms();
            for _ in 0..n {
                for q in &qs {
                    let p = kincal::model::kinematics::tool_pose_with_jacobian(&nominal, q, &cols, &mut jac);
                    acc += p.position_mm.x + jac[3][0];
                }
            }
            let t1 = (cpu_ms() - c) * 1e3 / (n * 1000) as f64;
            let c = cpu_ms();
            for _ in 0..n {
                for q in &qs {
                    let p = tool_pose(&nominal, q);
                    acc += p.position_mm.x;
                }
            }
            let t2 = (cpu_ms() - c) * 1e3 / (n * 1000) as f64;
            let chain = kincal::model::kinematics::Chain::new(&nominal);
            let c = cpu_ms();
            for _ in 0..n {
                for q in &qs {
                    let p = chain.pose_with_jacobian(q, &cols, &mut jac);
                    acc += p.position_mm.x + jac[3][0];
                }
            }
            let t3 = (cpu_ms() - c) * 1e3 / (n * 1000) as f64;
            let c = cpu_ms();
            for _ in 0..n {
                for q in &qs {
                    let p = chain.pose(q);
                    acc += p.position_mm.x;
                }
            }
            let t4 = (cpu_ms() - c) * 1e3 / (n * 1000) as f64;
            println!("chain reused: with jacobian {t3:.3} us, pose only {t4:.3} us");
            println!(
                "7 joints, {} columns: with jacobian {t1:.3} us, pose only {t2:.3} us ({acc})",
                ids.len()
            );
        }
        "evals" => {
            use kincal::calib::layout::Layout;
            use kincal::calib::problem::Problem;
            use kincal::calib::terms::{build, TermChoice};
            use kincal::numerics::solver::{Loss, Residuals};
            let (nominal, sim) = kincal::calib::peer::thesis_sized_problem(1);
            let cal = Observations::from_sessions(&sim.calibration, &sim.artefact);
            let fit =
                calibrate(&nominal, &cal, &SolveOptions { restarts: Some(0), ..SolveOptions::default() })?;
            let terms = build(
                &cal,
                &TermChoice {
                    relative_orientation_lever_mm: None,
                    orientation_weight_mm_per_rad: None,
                    point_weight: 1.0,
                },
            );
            let layout = Layout::new(
                fit.estimated.clone(),
                &vec![false; cal.blocks.len()],
                &vec![false; cal.groups.len()],
                false,
                &vec![None; cal.blocks.len()],
            );
            let problem = Problem::new(
                layout,
                &nominal,
                &cal,
                &terms,
                vec![nalgebra::Matrix3::identity(); cal.blocks.len()],
                None,
            );
            let x: Vec<f64> = fit.estimated.iter().map(|&id| fit.model.get(id)).collect();
            let mut r = vec![0.0; problem.len()];
            let c = cpu_ms();
            for _ in 0..n {
                problem.evaluate(&x, &mut r, None);
            }
            let t1 = (cpu_ms() - c) / n as f64;
            let c = cpu_ms();
            for _ in 0..n {
                std::hint::black_box(problem.normal_equations(&x, &mut r, Loss::Huber(1.35)));
            }
            let t2 = (cpu_ms() - c) / n as f64;
            println!(
                "artefact {} terms {} obs: residuals {:.3} ms, normal equations {:.3} ms",
                terms.len(),
                cal.obs.len(),
                t1,
                t2
            );
            // tracker
            let nominal = arm();
            let t = truth(&nominal);
            let cal = sessions(&t, 5, 720, 1)?;
            let fit = calibrate(&nominal, &cal, &SolveOptions::default())?;
            let terms = build(
                &cal,
                &TermChoice {
                    relative_orientation_lever_mm: None,
                    orientation_weight_mm_per_rad: None,
                    point_weight: 1.0,
                },
            );
            let layout = Layout::new(
                fit.estimated.clone(),
                &vec![true; cal.blocks.len()],
                &vec![false; cal.groups.len()],
                false,
                &vec![None; cal.blocks.len()],
            );
            let frames: Vec<_> = fit.frames.iter().map(|f| f.1.rotation).collect();
            let problem = Problem::new(layout, &fit.model, &cal, &terms, frames, None);
            let mut x: Vec<f64> = fit.estimated.iter().map(|&id| fit.model.get(id)).collect();
            for f in &fit.frames {
                x.extend([0.0, 0.0, 0.0, f.1.translation_mm.x, f.1.translation_mm.y, f.1.translation_mm.z]);
            }
            let mut r = vec![0.0; problem.len()];
            let c = cpu_ms();
            for _ in 0..n {
                problem.evaluate(&x, &mut r, None);
            }
            let t1 = (cpu_ms() - c) / n as f64;
            let c = cpu_ms();
            for _ in 0..n {
                std::hint::black_box(problem.normal_equations(&x, &mut r, Loss::Linear));
            }
            let t2 = (cpu_ms() - c) / n as f64;
            let c = cpu_ms();
            for _ in 0..n {
                std::hint::black_box(problem.group_factors(&x));
            }
            let t3 = (cpu_ms() - c) / n as f64;
            println!("tracker {} terms, {} unknowns: residuals {:.3} ms, normal equations {:.3} ms, group factors {:.3} ms, cost {:e}", terms.len(), x.len(), t1, t2, t3, Loss::Linear.cost(&r));
        }
        _ => anyhow::bail!("mode"),
    }
    Ok(())
}
