//! `kincal bench`: figures for the speed targets, printed, never asserted.
//!
//! * one calibration of a thesis-sized problem (5 placements × 15 landmarks × 3 repeats,
//!   13 parameters, 8 random restarts, solved in parallel);
//! * the 1000-calibration dataset-size study on every core;
//! * kincal beside Ceres and SciPy on the same problems, with the limit of this machine
//!   (`bench_peers.rs`; `--peers` runs only that, `--peers-check` only their agreement);
//! * `kincal calibrate` as a whole (load, calibrate, validate, outliers with warm-started
//!   leave-one-out refits, report, write RUN/) on the thesis-sized data;
//! * `kincal diagnose --auto` on a mixture of four hidden effects;
//! * the tracker case first (see `bench_tracker.rs`).
//!
//! `kincal bench --plan` runs only the check of `kincal plan` on simulated data (see
//! [`plan_benchmark`]).

use anyhow::Result;
use kincal::calib::fit::calibrate;
use kincal::calib::peer::thesis_sized_problem;
use kincal::calib::setup::{Setup, SolveOptions};
use kincal::calib::study::{study, StudyOptions};
use kincal::data::Observations;
use kincal::model::ParamId;
use kincal::numerics::stats::median;
use kincal::simulate::{simulate, SimulationOptions};
use std::time::Instant;

use crate::bench_args::BenchArgs;
use crate::cpu_time::process_cpu_ms;

/// False calls on clean data over `seeds` seeds, and, over `power_seeds` seeds per effect, how
/// often each identifiable library effect hidden alone is named.
fn diagnosis_checks(seeds: usize, power_seeds: usize) -> Result<()> {
    use kincal::calib::monte_carlo::{false_calls, hidden_for, names, simulate_and_diagnose, Rate};
    use kincal::model::effects::Effect;
    use rayon::prelude::*;
    let t = Instant::now();
    let clean: Vec<_> = (0..seeds as u64)
        .into_par_iter()
        .map(|k| simulate_and_diagnose(1000 + k, vec![]).map(|d| (false_calls(&d), d)))
        .collect::<Result<_, _>>()?;
    let calls: Vec<_> = clean.iter().map(|c| c.0).collect();
    println!("clean data, seeds 1000–{} ({:.0} s):", 999 + seeds, t.elapsed().as_secs_f64());
    println!("  any false call:           {}  (goal <= 5 %)", Rate::of(&calls, |c| c.any()));
    println!("  an arm effect:            {}", Rate::of(&calls, |c| c.effect));
    println!("  a data error:             {}", Rate::of(&calls, |c| c.data_error));
    println!("  a knock or mis-seated:    {}", Rate::of(&calls, |c| c.knock));
    println!("  \"misses\" (gap test):      {}", Rate::of(&calls, |c| c.misses));
    let gaps: Vec<_> = clean.iter().filter_map(|c| c.1.floor.gap.clone()).collect();
    println!("  \"at the floor\" shown:     {}; otherwise \"cannot tell\"", Rate::of(&gaps, |g| g.at_floor));
    // The effects identifiable next to the thesis model (from the first clean run).
    let Some((_, first)) = clean.first() else { return Ok(()) };
    let effects: Vec<Effect> = first.candidates.iter().filter_map(|c| Effect::parse(&c.name)).collect();
    println!("power: each of {} identifiable library effects hidden alone, {power_seeds} seeds each (named first, or among rivals the data cannot tell apart, or exactly equivalent):", effects.len());
    let t = Instant::now();
    let mut all = Vec::new();
    for effect in effects {
        let runs: Vec<_> = (0..power_seeds as u64)
            .into_par_iter()
            .map(|k| simulate_and_diagnose(2000 + k, hidden_for(effect)))
            .collect::<Result<_, _>>()?;
        let named = Rate::of(&runs, |d| names(d, effect));
        let misses = Rate::of(&runs, |d| d.floor.gap.as_ref().is_some_and(|g| g.significant));
        let lift = runs
            .iter()
            .map(|d| d.floor.gap.as_ref().map_or(f64::NAN, |g| g.measured_mm / g.expected_mm))
            .sum::<f64>()
            / runs.len().max(1) as f64;
        let wrong: Vec<String> = runs
            .iter()
            .filter(|d| !names(d, effect))
            .map(|d| if d.named.is_empty() { "nothing".to_string() } else { d.named.join(" or ") })
            .collect();
        println!(
            "  {:<16} {:?}  named {}  (validation/floor {:.2}; gap test \"misses\" {}/{}){}",
            effect.to_string(),
            hidden_for(effect).iter().map(|(p, v)| format!("{p}={v}")).collect::<Vec<_>>(),
            named,
            lift,
            misses.hits,
            misses.runs,
            if wrong.is_empty() { String::new() } else { format!("; otherwise {}", wrong.join(", ")) }
        );
        all.extend(
            runs.iter().map(|d| (names(d, effect), d.floor.gap.as_ref().is_some_and(|g| g.significant))),
        );
    }
    println!("  all effects together: {} ({:.0} s)", Rate::of(&all, |n| n.0), t.elapsed().as_secs_f64());
    println!("  gap test \"misses\" with an effect hidden: {}", Rate::of(&all, |n| n.1));
    Ok(())
}

/// `kincal plan` against random placements, over `seeds` simulated arms, printed:
/// * rivals — the true arm has a 0.5 mm link offset at joint 5, which the thesis placements
///   confuse with an eccentricity of encoder 6; on the simulator's ten placements the
///   diagnosis names one, the other, or both as rivals. Two placements planned to tell
///   `link_offset:5` from `eccentricity:6`, or two random reachable ones (3 draws per seed), are
///   measured (3 repeats), added to the calibration data, and the arm recalibrated and diagnosed
///   again: the share of runs that name `link_offset:5` alone, and the separation
///   (SSR_eccentricity − SSR_link offset)/σ² of both refitted on every touch;
/// * weak parameter — a clean arm, two calibration placements; two D-optimal placements or two
///   random ones: the std of the parameter the plan names weakest, as the recalibration reports it.
fn plan_benchmark(seeds: u64) -> Result<()> {
    use kincal::calib::monte_carlo::Rate;
    use kincal::calib::plan::{rival_trial, weak_trial, RivalOutcome, TrialOptions};
    use kincal::model::effects::Effect;
    let nominal = kincal::model::ArmModel::suta_nominal();
    let (a, b) = (Effect::parse("link_offset:5"), Effect::parse("eccentricity:6"));
    let (Some(a), Some(b)) = (a, b) else { anyhow::bail!("effect names") };
    let hidden = [(ParamId::LinkOffset(4), 0.5)];
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let started = Instant::now();
    let (mut before, mut planned, mut random) = (Vec::new(), Vec::new(), Vec::new());
    let (mut alone_before, mut alone_planned, mut alone_random) = (Vec::new(), Vec::new(), Vec::new());
    println!("rivals: true link_offset:5 (0.5 mm) against eccentricity:6; what the diagnosis names (\"alone\": link_offset:5 alone, of 3 random draws), and the separation (SSR_B − SSR_A)/σ²");
    println!("  seed  named on the data so far                      + 2 planned                       + 2 random: alone  separation so far / planned / random");
    for seed in 1..=seeds {
        let trial = TrialOptions { seed, placements: 5, count: 2, random_draws: 3 };
        let o = rival_trial(&nominal, &hidden, a, b, &trial)?;
        let random_alone = o.named_random.iter().filter(|n| RivalOutcome::alone(n, a)).count();
        println!(
            "  {seed:>4}  {:<49} {:<33} {random_alone:>15}/{}  {:>16.0} / {:.0} / {:.0}",
            o.named_before.join(" or "),
            o.named_planned.join(" or "),
            o.named_random.len(),
            o.separation.before,
            o.separation.planned,
            mean(&o.separation.random)
        );
        alone_before.push(RivalOutcome::alone(&o.named_before, a));
        alone_planned.push(RivalOutcome::alone(&o.named_planned, a));
        alone_random.extend(o.named_random.iter().map(|n| RivalOutcome::alone(n, a)));
        before.push(o.separation.before);
        planned.push(o.separation.planned);
        random.extend(o.separation.random);
    }
    println!(
        "  link_offset:5 named alone: so far {}, planned {}, random {}",
        Rate::of(&alone_before, |x| *x),
        Rate::of(&alone_planned, |x| *x),
        Rate::of(&alone_random, |x| *x)
    );
    println!(
        "  separation, mean over runs: so far {:.0} σ², planned {:.0} σ², random {:.0} σ² ({:.0} s)",
        mean(&before),
        mean(&planned),
        mean(&random),
        started.elapsed().as_secs_f64()
    );
    let (mut planned, mut random) = (Vec::new(), Vec::new());
    println!(
        "weak parameter: clean arm, 2 calibration placements; std of the parameter the plan names weakest"
    );
    println!("  seed  parameter   data so far  + 2 planned  + 2 random (mean of 3)");
    for seed in 1..=seeds {
        let trial = TrialOptions { seed, placements: 2, count: 2, random_draws: 3 };
        let (name, o) = weak_trial(&nominal, &trial)?;
        println!(
            "  {seed:>4}  {name:<10}  {:>11.4}  {:>11.4}  {:>11.4}",
            o.before,
            o.planned,
            mean(&o.random)
        );
        planned.push(o.planned / o.before);
        random.push(mean(&o.random) / o.before);
    }
    println!(
        "  std relative to the data so far, mean over seeds: planned {:.2}, random {:.2}; {} seeds in {:.0} s",
        mean(&planned),
        mean(&random),
        seeds,
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

/// Calibrate and diagnose from session files of about `touches` calibration touches (the
/// simulated placements, 20 repeats each, copied under new names with fresh encoder noise until
/// the count is reached), and print the times beside the thesis-sized ones.
fn scale_benchmark(touches: usize) -> Result<()> {
    use kincal::calib::run::run;
    use kincal::calib::summary::RunInputs;
    use rand::SeedableRng;
    use rand_distr::Distribution;
    let model = kincal::model::ArmModel::suta_nominal();
    let dir = std::env::temp_dir().join(format!("kincal-scale-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    for (sub, n) in [("small", 225), ("large", touches)] {
        let sim = simulate(
            &model,
            &SimulationOptions { repeats: if n > 225 { 20 } else { 3 }, ..Default::default() },
        );
        let folder = dir.join(sub);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let noise = rand_distr::Normal::new(0.0, 0.003)?;
        let (mut written, mut copy) = (0, 0);
        std::fs::create_dir_all(folder.join("cal"))?;
        while written < n {
            for s in &sim.calibration {
                let mut s = s.clone();
                if copy > 0 {
                    s.placement = format!("{}_{copy}", s.placement);
                    for m in &mut s.measurements {
                        m.joints_deg
                            .iter_mut()
                            .for_each(|a| *a = (*a + noise.sample(&mut rng)).rem_euclid(360.0));
                    }
                }
                s.measurements.truncate(n - written);
                written += s.measurements.len();
                s.save(&folder.join("cal").join(format!("{}.json", s.placement)))?;
                if written >= n {
                    break;
                }
            }
            copy += 1;
        }
        std::fs::create_dir_all(folder.join("val"))?;
        for s in &sim.validation {
            s.save(&folder.join("val").join(format!("{}.json", s.placement)))?;
        }
        sim.artefact.save(&folder.join("artefact.json"))?;
        model.save(&folder.join("model.toml"))?;
        let inputs = RunInputs::new(
            folder.join("model.toml"),
            Some(folder.join("artefact.json")),
            folder.join("cal"),
            folder.join("val"),
        );
        let options = SolveOptions::default();
        let t = Instant::now();
        let result = run(&inputs, &options, 0, true)?;
        let run_s = t.elapsed().as_secs_f64();
        let s = &result.summary;
        let (cal, val) = (
            Observations::load_artefact_dir(
                &inputs.calibration,
                &sim.artefact,
                kincal::data::Purpose::Calibration,
            )?,
            &result.validation_data,
        );
        let t = Instant::now();
        kincal::calib::diagnose::diagnose(
            &Setup::new(options.clone()),
            &result.calibration.model,
            &cal,
            val,
        )?;
        let diagnose_s = t.elapsed().as_secs_f64();
        println!(
            "calibrate from files, {:>6} touches in {:>4} placements ({:>7} pairs): {run_s:6.2} s ({:.0} touches/s); diagnose {diagnose_s:6.2} s; validation RMS {:.3} mm",
            s.calibration.observations,
            cal.groups.len(),
            s.calibration.pairs,
            s.calibration.observations as f64 / run_s,
            s.held_out_rms_mm()
        );
    }
    std::fs::remove_dir_all(&dir).ok();
    Ok(())
}

/// Run every benchmark and print the figures.
pub fn run_benchmarks(args: &BenchArgs) -> Result<()> {
    if let Some(seeds) = args.plan {
        return plan_benchmark(seeds.max(1));
    }
    if args.scale_only {
        return scale_benchmark(args.scale_touches);
    }
    if args.diagnosis_seeds > 0 {
        return diagnosis_checks(args.diagnosis_seeds, args.power_seeds);
    }
    if args.peers_check {
        return crate::bench_peers::peers_check(args);
    }
    if args.peers {
        return crate::bench_peers::peers_benchmark(args);
    }
    crate::bench_tracker::tracker_benchmark()?;
    if args.tracker_only {
        return Ok(());
    }
    let (nominal, sim) = thesis_sized_problem(1);
    let cal = Observations::from_sessions(&sim.calibration, &sim.artefact);
    let val = Observations::from_sessions(&sim.validation, &sim.artefact);
    let options = SolveOptions::default();
    if args.calibrate_only {
        println!("{}", whole_calibration(&sim, &options)?);
        return Ok(());
    }
    println!("thesis-sized problem: {} placements, {} touches, {} pairs, {} free parameters, {} restarts + nominal start", cal.groups.len(), cal.obs.len(), cal.landmark_pairs().len(), nominal.free.len(), options.resolve(&cal).restarts);
    let mut times = Vec::new();
    for _ in 0..args.repeats.max(1) {
        let t = Instant::now();
        calibrate(&nominal, &cal, &options)?;
        times.push(t.elapsed().as_secs_f64() * 1e3);
    }
    let single_ms = median(times.clone());
    println!("one calibration ({} threads, restarts in parallel): median {single_ms:.1} ms, min {:.1} ms over {} runs  (target <= 50 ms)", rayon::current_num_threads(), times.iter().cloned().fold(f64::INFINITY, f64::min), times.len());
    let study_options = StudyOptions {
        subsets: args.study_subsets,
        seed: 1,
        setup: Setup::new(SolveOptions { restarts: Some(0), ..options.clone() }),
        progress: false,
    };
    let t = Instant::now();
    let rows = study(&nominal, &cal, &val, &study_options);
    let study_s = t.elapsed().as_secs_f64();
    let count: usize = rows.iter().map(|r| r.calibrations + r.failed).sum();
    println!(
        "study: {count} calibrations on {} threads: {study_s:.2} s  (target <= 10 s on 2 cores)",
        rayon::current_num_threads()
    );
    let hidden = SimulationOptions {
        seed: 1,
        hidden: vec![(ParamId::EccSin(4), 0.2), (ParamId::EccCos(4), -0.1)],
        ..SimulationOptions::default()
    };
    let sim_hidden = simulate(&nominal, &hidden);
    let (cal_h, val_h) = (
        Observations::from_sessions(&sim_hidden.calibration, &sim_hidden.artefact),
        Observations::from_sessions(&sim_hidden.validation, &sim_hidden.artefact),
    );
    let fit_h = calibrate(&nominal, &cal_h, &options)?;
    let t = Instant::now();
    let diagnosis =
        kincal::calib::diagnose::diagnose(&Setup::new(options.clone()), &fit_h.model, &cal_h, &val_h)?;
    println!("diagnose, whole library ({} candidates scored, {} not identifiable), {} threads: {:.2} s  (target <= 2 s on 2 cores)", diagnosis.candidates.len(), diagnosis.not_identifiable.len(), rayon::current_num_threads(), t.elapsed().as_secs_f64());
    println!("{}", whole_calibration(&sim, &options)?);
    println!("{}", auto_loop_on_a_mixture(&nominal, &options)?);
    // Haptic: a 5-minute recording (100 s of fixed steps + 200 s of free motion).
    let (recording, _) =
        kincal::haptic::simulate::simulate_recording(&kincal::haptic::simulate::HapticSimOptions {
            joints_seconds: 200.0,
            ..Default::default()
        });
    let t = Instant::now();
    match kincal::haptic::pipeline::calibrate_recording(&recording) {
        Ok(h) => println!("haptic pipeline on a 5-minute recording: {:.2} s  (target <= 1 s); delay {:.2} ms, position {:.3} mm, orientation {:.3} deg", t.elapsed().as_secs_f64(), h.delay_ms, h.position_mm.after, h.orientation_deg.after),
        Err(e) => println!("haptic pipeline failed: {e}"),
    }
    if args.scale_touches > 0 {
        scale_benchmark(args.scale_touches)?;
    }
    crate::bench_peers::peers_benchmark(args)
}

/// Median wall time of the whole `kincal calibrate` process on `sim` written to disk.
fn whole_calibration(sim: &kincal::simulate::SimulatedData, options: &SolveOptions) -> Result<String> {
    let dir = std::env::temp_dir().join(format!("kincal-bench-run-{}", std::process::id()));
    sim.write(&dir)?;
    kincal::model::ArmModel::suta_nominal().save(&dir.join("nominal.toml"))?;
    let inputs = kincal::calib::summary::RunInputs::new(
        dir.join("nominal.toml"),
        Some(dir.join("artefact.json")),
        dir.join("cal"),
        dir.join("val"),
    );
    let (mut wall, mut cpu, mut parts, mut report) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for _ in 0..10 {
        let (t, c) = (Instant::now(), process_cpu_ms());
        let run = kincal::calib::run::run(&inputs, options, 0, true)?;
        let mut steps = run.steps.clone();
        kincal::store::write_run(&run, &dir.join("run"))?;
        steps.lap("report and write");
        wall.push(t.elapsed().as_secs_f64() * 1e3);
        cpu.push(process_cpu_ms() - c);
        parts.push(steps.ms);
        let t = Instant::now();
        std::hint::black_box(kincal::report::run::run_report(&run, std::path::Path::new("RUN")));
        report.push(t.elapsed().as_secs_f64() * 1e3);
    }
    std::fs::remove_dir_all(&dir).ok();
    let breakdown: Vec<String> = parts[0]
        .iter()
        .enumerate()
        .map(|(k, (name, _))| format!("{name} {:.1}", median(parts.iter().map(|p| p[k].1).collect())))
        .collect();
    Ok(format!(
        "kincal calibrate, whole process in the library: median {:.1} ms wall, {:.1} ms CPU (all threads) \
         over 10 runs  (target <= 60 ms wall)\n  parts, median ms wall: {}; rendering the report alone \
         {:.1}",
        median(wall),
        median(cpu),
        breakdown.join(", "),
        median(report)
    ))
}

/// Wall time of the auto loop on a mixture of four hidden effects.
fn auto_loop_on_a_mixture(nominal: &kincal::model::ArmModel, options: &SolveOptions) -> Result<String> {
    let hidden = SimulationOptions {
        seed: 105,
        hidden: vec![
            (ParamId::EccSin(1), 0.2),
            (ParamId::EccCos(4), 0.15),
            (ParamId::Twist(3), 0.25),
            (ParamId::Compliance(1), 0.2),
        ],
        ..SimulationOptions::default()
    };
    let sim = simulate(nominal, &hidden);
    let cal = Observations::from_sessions(&sim.calibration, &sim.artefact);
    let val = Observations::from_sessions(&sim.validation, &sim.artefact);
    let fit = calibrate(nominal, &cal, options)?;
    let t = Instant::now();
    let run =
        kincal::calib::diagnose::auto::auto_loop(&Setup::new(options.clone()), &fit.model, &cal, &val, 8)?;
    let added: Vec<&str> = run.steps.iter().filter_map(|s| s.applied.as_deref()).collect();
    Ok(format!(
        "diagnose --auto on a 4-effect mixture: {:.2} s on {} threads, added {} ({:.3} → {:.3} mm)  (target <= 3 s on 2 cores)",
        t.elapsed().as_secs_f64(),
        rayon::current_num_threads(),
        added.join(", "),
        run.steps.first().map_or(f64::NAN, |s| s.held_out_rms_mm),
        run.steps.last().map_or(f64::NAN, |s| s.held_out_rms_mm)
    ))
}
