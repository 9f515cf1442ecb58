//! `kincal dynamic`: the streamed pose against a reference tracker's recording of the same motion.

use anyhow::{bail, Result};
use clap::Args;
use std::path::PathBuf;

/// `kincal dynamic`.
#[derive(Args)]
pub struct DynamicArgs {
    /// The arm's pose: the CSV of `kincal stream --pose --csv`, or `t_s,x_mm,y_mm,z_mm` as an
    /// OpenIGTLink client received it (`kincal igtl-record`).
    #[arg(long)]
    arm: PathBuf,
    /// The reference tracker's recording of the same tool: `t_s,x_mm,y_mm,z_mm` at its own rate,
    /// on its own clock and in its own frame, occlusions simply missing; with `host_s` (arrival on
    /// the host's clock) for the latency.
    #[arg(long)]
    tracker: PathBuf,
    /// Folder for dynamic.json and report.html (a new folder, or one kincal wrote before).
    #[arg(long)]
    out: PathBuf,
}

pub fn cmd_dynamic(a: &DynamicArgs) -> Result<()> {
    if a.arm == a.tracker {
        bail!(
            "--arm and --tracker are the same file ({}): the arm's pose and the reference tracker's recording are two recordings of one motion",
            a.arm.display()
        );
    }
    let arm = kincal::motion::recording::read_track(&a.arm)?;
    let tracker = kincal::motion::recording::read_track(&a.tracker)?;
    kincal::store::check_output_folder(&a.out, kincal::store::FolderKind::Dynamic, &[&a.arm, &a.tracker])?;
    let d = kincal::motion::analyze(&arm, &tracker)
        .map_err(|e| anyhow::anyhow!("{} against {}: {e}", a.tracker.display(), a.arm.display()))?;
    for line in d.summary() {
        println!("{line}");
    }
    kincal::store::write_dynamic(&d, None, &a.out, &a.arm, &a.tracker)?;
    println!("report: {}", a.out.join("report.html").display());
    Ok(())
}
