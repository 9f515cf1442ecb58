//! `kincal`: the command-line edge. Parses arguments, calls the library, prints.

mod args;
mod arm;
mod bench;
mod bench_args;
mod bench_limit;
mod bench_peers;
mod bench_tracker;
mod calibrate;
mod certificate;
#[cfg(test)]
mod cli_reference;
mod controller;
mod cpu_time;
mod demo;
mod diagnose;
mod dynamic;
mod emulated_arm;
mod haptic;
mod igtl_record;
mod model;
mod plan;
mod progress;

use clap::parser::ValueSource;
use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "kincal",
    version,
    about = "Calibrate serial arms from artefact touches and tracker measurements"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Write an artefact and calibration/validation sessions from a simulated "true" arm.
    Simulate(arm::SimulateArgs),
    /// Calibrate the arm model from artefact touches, tracker sessions or both, and validate it on
    /// held-out sessions.
    Calibrate(Box<calibrate::CalibrateArgs>),
    /// The calibration certificate of RUN (RUN/certificate.html): the arm, the RUN hash, the
    /// reference and data, the result against the floor, the validity, what it does not cover and
    /// how to re-check it. Exit 2 when no calibration can be certified.
    Certificate(certificate::CertificateArgs),
    /// Dataset-size study: calibrate on random subsets of placements or sessions, validate each.
    Study(arm::StudyArgs),
    /// Where the calibrated model of RUN fails and which physical effect is missing.
    Diagnose(diagnose::DiagnoseArgs),
    /// What to measure next: placements that tell rival effects apart or pin down weak parameters.
    Plan(plan::PlanArgs),
    /// Compare two runs: validation errors, per landmark, residual plots side by side.
    Compare(diagnose::CompareArgs),
    /// The whole loop on the emulated controller: record, calibrate, upload, stream the pose.
    Demo(demo::DemoArgs),
    /// Controller identity, protocol match, stored parameters and encoder health.
    Info(controller::PortArgs),
    /// Read back the parameters stored on the controller.
    Params(controller::PortArgs),
    /// Sign a calibrated model with a station key and send it to the controller (chunked, read
    /// back, verified and committed by the controller).
    Upload(controller::UploadArgs),
    /// Station keys that sign parameter sets.
    #[command(subcommand)]
    Key(controller::KeyCommand),
    /// Live joint angles or calibrated tool pose, with rate, gap and error statistics.
    Stream(controller::StreamArgs),
    /// Guided measurement of one artefact placement; resumes an interrupted session.
    Record(controller::RecordArgs),
    /// Does the arm still hold its stored calibration? A few touches judged with the stored set
    /// against the floor of their repeats: holds (exit 0), does not hold (2), cannot tell (3).
    Check(controller::CheckArgs),
    /// The streamed pose in motion against a reference tracker's recording of the same tool:
    /// latency, clock offset and drift, path error at rest, in motion and at direction changes.
    Dynamic(dynamic::DynamicArgs),
    /// Record the TRANSFORMs an OpenIGTLink server sends (the arm's pose from `kincal stream
    /// --igtl`, or an optical tracker through PLUS) as a client receives them, for `kincal
    /// dynamic`.
    IgtlRecord(igtl_record::IgtlRecordArgs),
    /// Emulated controller: start one as an arm, pose it, script it from a geometry, inject
    /// encoder noise and faults.
    #[command(subcommand)]
    EmulatedArm(emulated_arm::EmulatedArmCommand),
    /// Haptic device (PHANToM) workspace calibration.
    #[command(subcommand)]
    Haptic(haptic::HapticCommand),
    /// Model files: from and to URDF, and the built-in SUTA model.
    #[command(subcommand)]
    Model(model::ModelCommand),
    /// Benchmarks: calibration time, study throughput, and kincal beside Ceres and SciPy on the same problems.
    Bench(bench_args::BenchArgs),
}

fn main() {
    // Behave like other command-line tools when the reader of stdout goes away (`| head`).
    #[cfg(unix)]
    // SAFETY: resetting a signal disposition to its default before any thread is started.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    keep_freed_memory();
    let (cli, builtin_model) = parse();
    let result = run(cli);
    drop(builtin_model);
    if let Err(e) = result {
        eprintln!("error: {}", message(&e));
        std::process::exit(1);
    }
}

/// Let glibc's allocator keep the memory the process frees for its next allocations instead of
/// handing it back to the kernel: a calibration's refits allocate and free blocks of the same
/// sizes (subsets of the observations, their encoder rows, the product's buffers) over and over,
/// and each page handed back is faulted in again when touched (about 1.6 µs a page on a virtual
/// machine). Blocks up to 32 MB come from the heap, and the heap's free top is not trimmed: the
/// whole tracker run takes about 20 % fewer page faults and 2 % less CPU, its peak memory
/// unchanged. Each thread's arena keeps what it freed at its own peak: a long-running command
/// (`stream`, `record`) allocates little once started.
fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets the allocator's parameters; called before any thread starts.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 1 << 30);
    }
}

/// The command line; `simulate` without `--model` reads the built-in SUTA model from a file that
/// lives as long as the command.
fn parse() -> (Cli, Option<args::BuiltinModelFile>) {
    let matches = Cli::command().get_matches();
    let default_model = matches
        .subcommand_matches("simulate")
        .is_some_and(|m| m.value_source("model") == Some(ValueSource::DefaultValue));
    if !default_model {
        return (Cli::from_arg_matches(&matches).unwrap_or_else(|e| e.exit()), None);
    }
    let file = args::BuiltinModelFile::write().unwrap_or_else(|e| {
        eprintln!("error: writing the built-in SUTA model to the temporary folder: {e}");
        std::process::exit(1)
    });
    let argv = std::env::args_os().chain(["--model".into(), file.path().as_os_str().to_owned()]);
    (Cli::parse_from(argv), Some(file))
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Simulate(a) => arm::cmd_simulate(&a),
        Command::Calibrate(a) => calibrate::cmd_calibrate(&a),
        Command::Certificate(a) => certificate::cmd_certificate(&a),
        Command::Study(a) => arm::cmd_study(&a),
        Command::Diagnose(a) => diagnose::cmd_diagnose(&a),
        Command::Compare(a) => diagnose::cmd_compare(&a),
        Command::Plan(a) => plan::cmd_plan(&a),
        Command::Demo(a) => demo::cmd_demo(&a),
        Command::Info(a) => controller::cmd_info(&a),
        Command::Params(a) => controller::cmd_params(&a),
        Command::Upload(a) => controller::cmd_upload(&a),
        Command::Key(controller::KeyCommand::New(a)) => controller::cmd_key_new(&a),
        Command::Stream(a) => controller::cmd_stream(&a),
        Command::Record(a) => controller::cmd_record(&a),
        Command::Check(a) => controller::cmd_check(&a),
        Command::Dynamic(a) => dynamic::cmd_dynamic(&a),
        Command::IgtlRecord(a) => igtl_record::cmd_igtl_record(&a),
        Command::EmulatedArm(c) => emulated_arm::run(&c),
        Command::Haptic(haptic::HapticCommand::Simulate(a)) => haptic::cmd_haptic_simulate(&a),
        Command::Haptic(haptic::HapticCommand::Calibrate(a)) => haptic::cmd_haptic_calibrate(&a),
        Command::Model(c) => model::run(&c),
        Command::Bench(a) => bench::run_benchmarks(&a),
    }
}

/// The error and its causes, each cause only when the text before does not already say it
/// (errors that name a file carry the operating system's reason in their own message).
fn message(e: &anyhow::Error) -> String {
    let mut text = e.to_string();
    for cause in e.chain().skip(1) {
        let cause = cause.to_string();
        if !text.contains(&cause) {
            text = format!("{text}: {cause}");
        }
    }
    text
}
