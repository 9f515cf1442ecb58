//! `kincal emulated-arm`: start an emulated controller as an arm of its own identity, pose its
//! arm, write record scripts from the arm's geometry, and inject encoder faults, so sessions,
//! uploads and checks can be rehearsed without hardware.

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand};
use kincal::controller::link::Link;
use kincal::controller::record::measure_window;
use kincal_protocol::biss::{counts_to_deg, deg_to_counts};
use kincal_protocol::{
    joints::JOINTS,
    messages::{Crash, SimFaults, SimSetPose},
};
use std::path::PathBuf;

/// What to do to the emulated arm.
#[derive(Subcommand)]
pub enum EmulatedArmCommand {
    /// Start an emulated controller (QEMU) with an arm identity and print its port; runs until
    /// Ctrl-C. Two started with two identities are two arms.
    Start(StartArgs),
    /// Write the record script that poses the emulated arm of a geometry (a model file, e.g.
    /// `truth.toml` from `kincal simulate`) at every landmark of an artefact placement.
    Script(ScriptArgs),
    /// Set the six joint positions the emulated encoders report, then read them back.
    Pose(PoseArgs),
    /// Encoder noise and fault rates of the emulated bus (all 0: a clean bus).
    Faults(FaultArgs),
    /// Move the arm along joint waypoints with times (a CSV file), smoothly, from 0.5 s after
    /// the command; `kincal stream --pose` then streams the moving pose.
    Trajectory(TrajectoryArgs),
}

/// `kincal emulated-arm trajectory`.
#[derive(Args)]
pub struct TrajectoryArgs {
    /// The emulated controller: pty path or tcp:HOST:PORT.
    #[arg(long)]
    port: String,
    /// Waypoints: `t_s,j1_deg,…,j6_deg` rows (encoder angles, unwrapped); `--demo` writes one.
    #[arg(long, required_unless_present = "write_demo")]
    file: Option<std::path::PathBuf>,
    /// Start again at the end, until another pose or trajectory is set (the first and last
    /// waypoints must then be the same pose).
    #[arg(long)]
    repeat: bool,
    /// Write the demo's trajectory (around the arm's present pose) to this new file and play it.
    #[arg(long, conflicts_with = "file")]
    write_demo: Option<std::path::PathBuf>,
}

/// `kincal emulated-arm start`.
#[derive(Args)]
pub struct StartArgs {
    /// The arm's identity (1 to 24 ASCII letters, digits or -_.:); what signed sets must name.
    #[arg(long, default_value = "emulated-arm")]
    arm_id: String,
    /// The emulated controller's firmware image (`cargo build-emulated` writes it here).
    #[arg(long, default_value = "firmware/target/thumbv7em-none-eabihf/release/emulated")]
    firmware: PathBuf,
}

/// `kincal emulated-arm script`.
#[derive(Args)]
pub struct ScriptArgs {
    /// The emulated arm's geometry: a model file (the arm as it really is).
    #[arg(long)]
    geometry: PathBuf,
    /// Artefact file.
    #[arg(long)]
    artefact: PathBuf,
    /// Placement of the artefact (A_O, C_A…C_D, V_A…V_E).
    #[arg(long)]
    placement: String,
    /// Repeats of every landmark (posed in the configuration of its first touch).
    #[arg(long, default_value_t = 3)]
    repeats: u32,
    /// Seating noise of the tip, mm (standard deviation per axis).
    #[arg(long, default_value_t = 0.1)]
    seating_noise_mm: f64,
    /// Seed of the seating noise and of the inverse kinematics' starts.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Change the geometry before posing, as a knock would: PARAM=DELTA in the parameter's unit
    /// (degrees, mm, ppm), e.g. `offset:2=+0.05` or `length:3=1.0`; repeatable.
    #[arg(long, value_name = "PARAM=DELTA")]
    knock: Vec<String>,
    /// The script file to write (a new file).
    #[arg(long)]
    out: PathBuf,
}

/// `kincal emulated-arm pose`.
#[derive(Args)]
pub struct PoseArgs {
    /// The emulated controller: pty path or tcp:HOST:PORT.
    #[arg(long)]
    port: String,
    /// Joint angles, degrees, base to tip: six comma-separated values.
    #[arg(long, value_delimiter = ',', conflicts_with = "counts", required_unless_present = "counts")]
    deg: Vec<f64>,
    /// Raw encoder positions, counts in 0..4194304, base to tip: six comma-separated values.
    #[arg(long, value_delimiter = ',')]
    counts: Vec<u32>,
}

/// `kincal emulated-arm faults`.
#[derive(Args)]
pub struct FaultArgs {
    /// The emulated controller: pty path or tcp:HOST:PORT.
    #[arg(long)]
    port: String,
    /// Standard deviation of the position noise, counts.
    #[arg(long, default_value_t = 0)]
    noise_counts: u16,
    /// Frames per 10 000 sent with a corrupted CRC.
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u16).range(0..=10_000))]
    crc_errors_per_10k: u16,
    /// Frames per 10 000 with no answer.
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u16).range(0..=10_000))]
    dropouts_per_10k: u16,
    /// Frames per 10 000 with the encoder's error bit set.
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u16).range(0..=10_000))]
    error_bits_per_10k: u16,
    /// Frames per 10 000 with the encoder's warning bit set.
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u16).range(0..=10_000))]
    warnings_per_10k: u16,
    /// Unplug these joints (1-6, comma separated): their line floats high, no encoder answers.
    /// Every `faults` command sets all faults: without it, every joint is plugged in.
    #[arg(long, value_delimiter = ',', value_parser = clap::value_parser!(u8).range(1..=6))]
    unplug: Vec<u8>,
    /// Make the controller's firmware fail now, to see the watchdog or the panic handler reset
    /// it (`kincal info` then reports the cause): `panic` or `hang` (the sampling loop stops).
    #[arg(long, value_enum)]
    crash: Option<CrashArg>,
}

/// A firmware failure to inject.
#[derive(Clone, Copy, clap::ValueEnum)]
pub enum CrashArg {
    /// Panic in the task serving the host.
    Panic,
    /// Hang the sampling loop (spins in an encoder read).
    Hang,
}

fn greeted(port: &str) -> Result<Link> {
    let mut link = Link::open(port)?;
    link.hello().with_context(|| format!("handshake with the controller on {port}"))?;
    Ok(link)
}

/// Run one `emulated-arm` command.
pub fn run(command: &EmulatedArmCommand) -> Result<()> {
    match command {
        EmulatedArmCommand::Start(a) => start(a),
        EmulatedArmCommand::Script(a) => script(a),
        EmulatedArmCommand::Pose(a) => pose(a),
        EmulatedArmCommand::Faults(a) => faults(a),
        EmulatedArmCommand::Trajectory(a) => trajectory(a),
    }
}

fn start(a: &StartArgs) -> Result<()> {
    if !kincal_protocol::signed::valid_arm_id(&a.arm_id) {
        bail!("--arm-id {:?}: expected 1 to 24 ASCII letters, digits or -_.:", a.arm_id);
    }
    let (mut emulator, port) =
        kincal::controller::emulator::Emulator::start_server_as(&a.firmware, Some(&a.arm_id))?;
    println!("emulated controller of arm {} on {port} (Ctrl-C stops it)", a.arm_id);
    crate::controller::catch_ctrl_c();
    while !crate::controller::INTERRUPTED.load(std::sync::atomic::Ordering::SeqCst) {
        if !emulator.running() {
            bail!("the emulated controller of arm {} stopped", a.arm_id);
        }
        std::thread::sleep(std::time::Duration::from_millis(100));
    }
    println!("stopped the emulated controller of arm {}", a.arm_id);
    Ok(())
}

fn script(a: &ScriptArgs) -> Result<()> {
    use kincal::controller::emulated_arm::{placement_named, script_of, touch_placement};
    if a.out.exists() {
        bail!("{} exists; kincal never replaces it: choose a new name", a.out.display());
    }
    if !(a.seating_noise_mm.is_finite() && a.seating_noise_mm >= 0.0) {
        bail!("--seating-noise-mm {}: expected a non-negative number of millimetres", a.seating_noise_mm);
    }
    let mut geometry = kincal::model::ArmModel::load(&a.geometry)?;
    for knock in &a.knock {
        let parsed = knock.split_once('=').and_then(|(id, delta)| {
            Some((kincal::model::ParamId::parse(id.trim())?, delta.trim().parse::<f64>().ok()?))
        });
        let Some((id, delta)) = parsed.filter(|(id, d)| d.is_finite() && geometry.params().contains(id))
        else {
            bail!("--knock {knock}: expected PARAM=DELTA with a parameter of this geometry, e.g. offset:2=+0.05");
        };
        geometry.set(id, geometry.get(id) + delta);
    }
    if geometry.joints.len() != JOINTS {
        bail!(
            "{}: the emulated arm has {JOINTS} joints, this geometry {}",
            a.geometry.display(),
            geometry.joints.len()
        );
    }
    let artefact = kincal::data::Artefact::load(&a.artefact)?;
    let place = placement_named(&a.placement).map_err(|names| {
        anyhow::anyhow!("--placement {}: not a placement; expected one of {}", a.placement, names.join(", "))
    })?;
    let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(a.seed);
    let session = touch_placement(&geometry, &artefact, &place, a.repeats, a.seating_noise_mm, &mut rng);
    let script = script_of(&session);
    let text = serde_json::to_string_pretty(&script)?;
    kincal::files::write_atomic(&a.out, text.as_bytes())
        .with_context(|| format!("writing {}", a.out.display()))?;
    let reachable = artefact.landmarks.len() * a.repeats as usize;
    println!(
        "{}: {} touches of {} at {} by the arm of {}{} ({} unreachable)",
        a.out.display(),
        script.steps.len(),
        a.artefact.display(),
        place.name,
        a.geometry.display(),
        if a.knock.is_empty() { String::new() } else { format!(" knocked by {}", a.knock.join(", ")) },
        reachable - script.steps.len()
    );
    Ok(())
}

fn pose(a: &PoseArgs) -> Result<()> {
    let counts: [u32; JOINTS] = if a.counts.is_empty() {
        let deg: [f64; JOINTS] = a.deg.as_slice().try_into().context("--deg: expected 6 angles")?;
        if let Some(bad) = deg.iter().find(|d| !d.is_finite()) {
            bail!("--deg: {bad} is not an angle");
        }
        deg.map(deg_to_counts)
    } else {
        let counts: [u32; JOINTS] =
            a.counts.as_slice().try_into().context("--counts: expected 6 positions")?;
        if let Some(bad) = counts.iter().find(|c| **c >= kincal_protocol::biss::COUNTS_PER_TURN) {
            bail!("--counts: {bad} is outside 0..{}", kincal_protocol::biss::COUNTS_PER_TURN);
        }
        counts
    };
    let mut link = greeted(&a.port)?;
    link.call(SimSetPose { counts })?;
    // Read it back through the controller, as a touch would.
    let window = measure_window(&mut link, 96)?;
    println!("joint  set counts  set deg      read deg   accepted");
    for (j, jw) in window.joints.iter().enumerate() {
        println!(
            "{:>5}  {:>10}  {:>10.4}  {:>10.4}  {:>5}/{}",
            j + 1,
            counts[j],
            counts_to_deg(counts[j] as f64),
            counts_to_deg(jw.mean_counts),
            jw.accepted,
            window.ticks
        );
    }
    Ok(())
}

fn faults(a: &FaultArgs) -> Result<()> {
    let mut link = greeted(&a.port)?;
    link.call(SimFaults {
        noise_counts: a.noise_counts,
        crc_errors_per_10k: a.crc_errors_per_10k,
        dropouts_per_10k: a.dropouts_per_10k,
        error_bits_per_10k: a.error_bits_per_10k,
        warnings_per_10k: a.warnings_per_10k,
        unplugged: a.unplug.iter().fold(0, |mask, j| mask | 1 << (j - 1)),
        crash: match a.crash {
            None => Crash::None,
            Some(CrashArg::Panic) => Crash::Panic,
            Some(CrashArg::Hang) => Crash::Hang,
        },
    })?;
    let unplugged: Vec<String> = a.unplug.iter().map(|j| j.to_string()).collect();
    println!(
        "emulated encoders: noise {} counts, per 10 000 frames: {} CRC errors, {} dropouts, {} error bits, {} warnings; unplugged joints: {}",
        a.noise_counts,
        a.crc_errors_per_10k,
        a.dropouts_per_10k,
        a.error_bits_per_10k,
        a.warnings_per_10k,
        if unplugged.is_empty() { "none".to_string() } else { unplugged.join(", ") }
    );
    if a.crash.is_some() {
        println!("failure injected: the controller resets (`kincal info` reports why)");
    }
    Ok(())
}

fn trajectory(a: &TrajectoryArgs) -> Result<()> {
    use kincal::motion::trajectory::Trajectory;
    let mut link = greeted(&a.port)?;
    let trajectory = match (&a.file, &a.write_demo) {
        (Some(file), _) => Trajectory::load(file)?,
        (None, Some(out)) => {
            if out.exists() {
                bail!("{} exists; choose a new file for the demo trajectory", out.display());
            }
            let window = measure_window(&mut link, 16)?;
            let here = window.joints.map(|j| counts_to_deg(j.mean_counts));
            let demo = Trajectory::demo(here);
            kincal::files::write_atomic(out, demo.to_csv().as_bytes())
                .with_context(|| format!("writing {}", out.display()))?;
            println!("demo trajectory around the present pose written to {}", out.display());
            demo
        }
        (None, None) => bail!("--file or --write-demo is needed"),
    };
    if a.repeat
        && trajectory.waypoints.first().map(|w| w.counts) != trajectory.waypoints.last().map(|w| w.counts)
    {
        bail!("--repeat needs the last waypoint at the first one's pose, or the arm would jump at every restart");
    }
    let start = kincal::controller::motion::play(&mut link, &trajectory, a.repeat)?;
    println!(
        "the emulated arm follows {} waypoints over {:.1} s{} from controller tick {start} (0.5 s from now)",
        trajectory.waypoints.len(),
        trajectory.duration_s(),
        if a.repeat { ", repeated" } else { "" }
    );
    Ok(())
}
