//! `kincal plan RUN`: what to measure next — artefact placements (or, for an instrument run,
//! sessions of arm poses) that tell two rival effects apart, and ones that pin down the weakest
//! parameters.

use anyhow::{bail, Result};
use clap::Args;
use kincal::api::{self, PlanRequest, Planned};
use kincal::calib::plan::SEPARABLE_SIGMA2;
use kincal::store;
use std::path::PathBuf;

#[derive(Args)]
pub struct PlanArgs {
    /// A RUN folder written by `kincal calibrate`.
    run: PathBuf,
    /// Two rival effects to tell apart, e.g. `compliance:3,harmonic:3:3` (default: the first
    /// pair the diagnosis of RUN cannot tell apart, if any).
    #[arg(long, value_delimiter = ',')]
    rivals: Vec<String>,
    /// Placements to suggest (each).
    #[arg(long, default_value_t = 2, value_parser = crate::args::count(1, 20))]
    count: usize,
    /// Write the plan as JSON (`kincal-plan/1`) to this file.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Write the suggested touches' joint angles (the pose list) as CSV to this file.
    #[arg(long)]
    csv: Option<PathBuf>,
    /// Touch noise per axis, mm (default: the repeatability floor of the RUN's data).
    #[arg(long)]
    touch_std_mm: Option<f64>,
    /// Seed of the arm configurations of the candidate touches.
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

fn place(p: &kincal::calib::plan::SuggestedPlacement) -> String {
    match (p.origin_mm, p.yaw_deg) {
        (Some(o), Some(yaw)) => format!(
            "artefact origin at ({:.0}, {:.0}, {:.0}) mm, yaw {yaw:+.0}°, {} landmarks",
            o[0],
            o[1],
            o[2],
            p.landmarks.len()
        ),
        _ => format!(
            "a new session {} of {} poses (the instrument anywhere it sees the tool)",
            p.session.as_deref().unwrap_or(""),
            p.poses_deg.len()
        ),
    }
}

fn ranges(joint_ranges_deg: &[(usize, f64, f64)], joints: &[usize]) -> String {
    joint_ranges_deg
        .iter()
        .filter(|r| joints.is_empty() || joints.contains(&r.0))
        .map(|(j, a, b)| {
            if *b >= 360.0 {
                format!("joint {j} passes {a:.0}–{:.0}° (through 0°)", b - 360.0)
            } else {
                format!("joint {j} passes {a:.0}–{b:.0}°")
            }
        })
        .collect::<Vec<_>>()
        .join(", ")
}

pub fn cmd_plan(a: &PlanArgs) -> Result<()> {
    // Refuse an output that would replace someone's file before any work is done.
    if let Some(path) = &a.out {
        store::check_own_file(path, store::PLAN_FORMAT)?;
    }
    if let Some(path) = &a.csv {
        store::check_own_file(path, store::PLAN_CSV_HEADER)?;
    }
    let folder = api::load(&a.run)?;
    for problem in &folder.summary.not_trustworthy {
        eprintln!("warning: this run is marked not trustworthy: {problem}");
    }
    let rivals = match a.rivals.as_slice() {
        [] => None,
        [x, y] => Some((x.as_str(), y.as_str())),
        other => bail!("--rivals takes two effects, A,B (got {})", other.len()),
    };
    let started = std::time::Instant::now();
    let request = PlanRequest { rivals, count: a.count, seed: a.seed, touch_std_mm: a.touch_std_mm };
    let Planned { plan, from_diagnosis } = api::plan(&folder, &request)?;
    match from_diagnosis {
        Some(Some((x, y))) => println!("the diagnosis cannot tell {x} from {y}: planning to separate them"),
        Some(None) => {
            println!(
                "the diagnosis names no rivals it cannot tell apart (give --rivals A,B to plan for a pair)"
            )
        }
        None => {}
    }
    let sessions = plan.weak.placements.first().is_some_and(|p| p.session.is_some());
    println!(
        "{} {}, {} noise {:.3} mm per axis; planned in {:.1} s",
        plan.candidates,
        if sessions {
            "candidate sessions of poses within the joint ranges the data visit"
        } else {
            "reachable candidate placements"
        },
        if sessions { "point" } else { "touch" },
        plan.touch_std_mm,
        started.elapsed().as_secs_f64()
    );
    if let Some(r) = &plan.rivals {
        let (ra, rb) = &r.rivals;
        let joints: Vec<usize> = [ra, rb]
            .iter()
            .filter_map(|e| kincal::model::effects::Effect::parse(e).and_then(|e| e.joint).map(|j| j + 1))
            .collect();
        let (ab, ba) = r.before_sigma2;
        let calibration_side = if ab.max(ba) < SEPARABLE_SIGMA2 {
            "the touches so far hardly separate them"
        } else {
            "the touches so far separate them in the fit; whether the held-out placements can is the diagnosis' test"
        };
        println!("to tell {ra} from {rb}: if {ra} is the cause, {rb} misses it by {ab:.1} σ²; if {rb} is, {ra} misses by {ba:.1} σ² (linearised; {calibration_side}; {SEPARABLE_SIGMA2} σ² is clear)");
        println!(
            "  with these {} placements: {:.1} σ² and {:.1} σ²",
            r.placements.len(),
            r.after_sigma2.0,
            r.after_sigma2.1
        );
        for (k, p) in r.placements.iter().enumerate() {
            let (ab, ba) = p.differ_mm.unwrap_or((0.0, 0.0));
            println!("  {}. {}: {}", k + 1, place(p), ranges(&p.joint_ranges_deg, &joints));
            println!("     the two explanations differ by {ab:.3} mm per touch there if {ra} is the cause ({ba:.3} mm if {rb}); measure {}", p.landmarks.join(" "));
            let most = p.touch_differ_mm.iter().copied().fold(0.0, f64::max);
            let (marks, there) = p.where_rivals_differ(0.5);
            println!(
                "     most ({:.3}–{most:.3} mm) at {}, where {}",
                0.5 * most,
                marks.join(" "),
                ranges(&there, &joints)
            );
        }
    }
    let w = &plan.weak;
    println!("to pin down the weakest parameters (D-optimal; std as calibrated on the data so far → with these placements):");
    for (name, unit, before, after, tip) in w.stds.iter().take(4) {
        println!("  {name:<12} {before:>9.4} → {after:>9.4} {unit}   (one std moves a registered touch by {tip:.3} mm)");
    }
    for (k, p) in w.placements.iter().enumerate() {
        println!("  {}. {}: {}", k + 1, place(p), ranges(&p.joint_ranges_deg, &[]));
    }
    if let Some(path) = &a.out {
        store::write_own_file(path, &store::plan_json(&plan), store::PLAN_FORMAT)?;
        println!("plan: {}", path.display());
    }
    if let Some(path) = &a.csv {
        store::write_own_file(path, &store::plan_csv(&plan), store::PLAN_CSV_HEADER)?;
        println!("pose list: {}", path.display());
    }
    Ok(())
}
