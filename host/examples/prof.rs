//! Profiling harness for the calibration's speed (built with `--profile profiling` for line tables,
//! under `perf record --call-graph dwarf` or `valgrind --tool=callgrind`, or by
//! its own CPU and wall times, median over N runs):
//! `cargo run --release -p kincal --example prof -- MODE [N]`, MODE one of `artefact` (nominal +
//! 8 restarts), `one` (nominal start), `tracker` (one calibration of the bench arm's 5 sessions),
//! `fk` (one pose with and without its Jacobian), `evals` (one residual and one normal-equation
//! evaluation of each problem), `write DIR` (the problems' files, for `kincal calibrate`), or
//! `steps DIR [N]` (the run of `kincal calibrate` on `write`'s tracker files, in the library, N
//! times: the median CPU time of the whole run and the wall time of each of its steps).
//!
//! The tracker problem is `kincal bench`'s ([`kincal::calib::bench_problem`]).
use anyhow::{Context, Result};
use kincal::calib::bench_problem;
use kincal::calib::fit::calibrate;
use kincal::calib::setup::SolveOptions;
use kincal::data::Observations;
use kincal::model::kinematics::tool_pose;
use kincal::model::ParamId;
use std::path::Path;
use std::time::Instant;

fn cpu_ms() -> f64 {
    let mut t = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut t) };
    t.tv_sec as f64 * 1e3 + t.tv_nsec as f64 * 1e-6
}

/// The residual terms of `cal`'s positions (no orientation rows, unit weight).
fn position_terms(cal: &Observations) -> Vec<Box<dyn kincal::calib::terms::Term>> {
    kincal::calib::terms::build(
        cal,
        &kincal::calib::terms::TermChoice {
            relative_orientation_lever_mm: None,
            orientation_weight_mm_per_rad: None,
            point_weight: 1.0,
        },
    )
}

/// The layout of `fit`'s estimated parameters on `cal`, with a frame per block when `framed`.
fn arm_layout(
    fit: &kincal::calib::fit::Fit,
    cal: &Observations,
    framed: bool,
) -> kincal::calib::layout::Layout {
    kincal::calib::layout::Layout::new(
        fit.estimated.clone(),
        &vec![framed; cal.blocks.len()],
        &vec![false; cal.groups.len()],
        false,
        &vec![None; cal.blocks.len()],
    )
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let n: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(20);
    match args.get(1).map_or("", String::as_str) {
        "write" => {
            let (nominal, cal, val) = bench_problem::problem();
            let dir = Path::new(args.get(2).context("write DIR")?);
            bench_problem::write_sessions(&cal, &dir.join("cal")).context("writing the sessions")?;
            bench_problem::write_sessions(&val, &dir.join("val")).context("writing the sessions")?;
            nominal.save(&dir.join("nominal.toml"))?;
            let (nom, sim) = kincal::calib::peer::thesis_sized_problem(1);
            sim.write(&dir.join("art"))?;
            nom.save(&dir.join("art/nominal.toml"))?;
        }
        "steps" => {
            let dir = Path::new(args.get(2).context("steps DIR")?);
            let n: usize = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(10);
            let inputs = kincal::calib::summary::RunInputs {
                model: dir.join("nominal.toml"),
                calibration: dir.join("cal"),
                validation: dir.join("val"),
                ..Default::default()
            };
            let mut runs = vec![];
            for _ in 0..n {
                let c = cpu_ms();
                let run = kincal::calib::run::run(&inputs, &SolveOptions::default(), 0, true)?;
                runs.push((cpu_ms() - c, run.steps.ms));
            }
            runs.sort_by(|a, b| a.0.total_cmp(&b.0));
            let (cpu, steps) = &runs[runs.len() / 2];
            println!("whole run (median of {n}): {cpu:.1} ms CPU; steps (wall ms) {steps:?}");
        }
        "tracker" => {
            let (nominal, cal, _) = bench_problem::problem();
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
            let nominal = bench_problem::arm();
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
            use kincal::calib::problem::Problem;
            use kincal::numerics::solver::{Loss, Residuals};
            let (nominal, sim) = kincal::calib::peer::thesis_sized_problem(1);
            let cal = Observations::from_sessions(&sim.calibration, &sim.artefact);
            let fit =
                calibrate(&nominal, &cal, &SolveOptions { restarts: Some(0), ..SolveOptions::default() })?;
            let terms = position_terms(&cal);
            let layout = arm_layout(&fit, &cal, false);
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
            let (nominal, cal, _) = bench_problem::problem();
            let fit = calibrate(&nominal, &cal, &SolveOptions::default())?;
            let terms = position_terms(&cal);
            let layout = arm_layout(&fit, &cal, true);
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
