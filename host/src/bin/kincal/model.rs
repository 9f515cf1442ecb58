//! `kincal model`: URDF in and out, and the built-in SUTA model.

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use kincal::files::write_output;
use kincal::model::urdf::{calibrated_urdf, model_from_urdf, read_masses};
use kincal::model::ArmModel;
use std::path::PathBuf;

/// Model files and URDF.
#[derive(Subcommand)]
pub enum ModelCommand {
    /// Write the chain BASE → TIP of a URDF as a kincal-arm/1 model (convention "urdf").
    FromUrdf(FromUrdfArgs),
    /// Write a calibrated URDF model's joint origins back into a copy of the URDF it was made
    /// from (only the kinematic `<joint>` origins change; the copy is read back and checked).
    ToUrdf(ToUrdfArgs),
    /// Write the SUTA nominal model built into kincal (thesis Table 3.2, the file
    /// examples/suta/model.toml), to calibrate or to edit into your own arm's model.
    Suta(SutaArgs),
}

#[derive(Args)]
pub struct SutaArgs {
    /// Model file to write (never replaced); without it the model is printed.
    #[arg(long)]
    out: Option<PathBuf>,
}

/// The chain of a URDF: its first and last link.
#[derive(Args)]
pub struct ChainArgs {
    /// The chain's first link.
    #[arg(long)]
    base: String,
    /// The chain's last link (the tool point is its origin); several, comma-separated, for a
    /// branched robot (`left_marker,right_marker`: the chains share the joints they have in
    /// common).
    #[arg(long)]
    tip: String,
}

#[derive(Args)]
pub struct FromUrdfArgs {
    /// The robot's URDF file.
    urdf: PathBuf,
    #[command(flatten)]
    chain: ChainArgs,
    /// Model file to write (.toml or .json); without it the model is printed.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Read the links' masses and centres of mass (`<inertial>`) into the model's mass table:
    /// what the compliances under gravity `sag:J` and `bend:J` need.
    #[arg(long)]
    masses: bool,
}

#[derive(Args)]
pub struct ToUrdfArgs {
    /// The calibrated model (RUN/model.toml).
    model: PathBuf,
    /// The URDF the model was made from.
    #[arg(long)]
    urdf: PathBuf,
    /// The chain's first link (recorded in the model; given, it must be the same).
    #[arg(long)]
    base: Option<String>,
    /// The chain's last link (recorded in the model; given, it must be the same).
    #[arg(long)]
    tip: Option<String>,
    /// The calibrated URDF to write (a new file, never one of the inputs).
    #[arg(long)]
    out: PathBuf,
}

/// Run one `kincal model` command.
pub fn run(command: &ModelCommand) -> Result<()> {
    match command {
        ModelCommand::FromUrdf(a) => {
            let mut model = model_from_urdf(&a.urdf, &a.chain.base, &a.chain.tip)?;
            let mass_kg = if a.masses { Some(read_masses(&a.urdf, &mut model)?) } else { None };
            match &a.out {
                Some(out) => {
                    let note = format!(
                        "model from-urdf {} --base {} --tip {}{}",
                        a.urdf.display(),
                        a.chain.base,
                        a.chain.tip,
                        if a.masses { " --masses" } else { "" }
                    );
                    model.save_output(out, "--out", &[&a.urdf], &note)?;
                    println!(
                        "{}: {} revolute joints, {} free parameters (origins ±{} mm, turns ±{} deg, offsets)",
                        out.display(),
                        model.joints.len(),
                        model.free.len(),
                        kincal::model::urdf::ORIGIN_HALF_RANGE_MM,
                        kincal::model::urdf::ORIGIN_HALF_RANGE_DEG
                    );
                    if model.tree.is_branched() {
                        let tips: Vec<&str> = model.tree.tips.iter().map(|t| t.name.as_str()).collect();
                        println!("  a branched robot: tips {}", tips.join(", "));
                    }
                    if let Some(kg) = mass_kg {
                        println!(
                            "  mass table: {} bodies, {kg:.3} kg carried by the model's joints (the effects sag and bend deflect the joints under them)",
                            model.tree.bodies.len()
                        );
                    }
                }
                None => print!("{}", model.to_text(false)),
            }
        }
        ModelCommand::ToUrdf(a) => {
            kincal::files::check_output(&a.out, "--out", &[&a.model, &a.urdf])?;
            let model = ArmModel::load(&a.model)?;
            let written = calibrated_urdf(&a.urdf, &model, &a.model, a.base.as_deref(), a.tip.as_deref())?;
            write_output(&a.out, "--out", &[&a.model, &a.urdf], written.text.as_bytes())?;
            println!(
                "{}: {} joint origins calibrated ({})",
                a.out.display(),
                written.joints.len(),
                written.joints.join(", ")
            );
            if !written.masses.is_empty() {
                println!("  fitted masses written into <inertial><mass> of {}", written.masses.join(", "));
            }
            println!(
                "  read back: forward kinematics within {:.1e} mm of {} at {} poses",
                written.read_back_mm,
                a.model.display(),
                written.poses_checked
            );
            if let Some(source) = &model.urdf {
                println!(
                    "  the tool point stays in the model (tcp_mm); the URDF's tip {} is where it was",
                    source.tip
                );
            }
        }
        ModelCommand::Suta(a) => {
            let text = kincal::model::file::SUTA_MODEL_TOML;
            match &a.out {
                Some(out) => {
                    if out.symlink_metadata().is_ok() {
                        anyhow::bail!(
                            "{} exists: kincal never replaces it; choose another name",
                            out.display()
                        );
                    }
                    kincal::files::write_atomic(out, text.as_bytes())
                        .with_context(|| format!("{}: cannot write", out.display()))?;
                    let model = ArmModel::suta_nominal();
                    println!(
                        "{}: {} ({} joints, {} free parameters)",
                        out.display(),
                        model.name,
                        model.joints.len(),
                        model.free.len()
                    );
                }
                None => print!("{text}"),
            }
        }
    }
    Ok(())
}
