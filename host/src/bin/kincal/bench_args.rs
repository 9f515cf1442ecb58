//! The options of `kincal bench`.

/// Options of `kincal bench`.
#[derive(Clone, Debug, clap::Args)]
pub struct BenchArgs {
    /// Timed repetitions of the single calibration.
    #[arg(long, default_value_t = 20)]
    pub repeats: usize,
    /// Random subsets per placement count in the study (5 counts × 200 = 1000 calibrations).
    #[arg(long, default_value_t = 200)]
    pub study_subsets: usize,
    /// Python interpreter with SciPy for the peer run.
    #[arg(long, default_value = "python3")]
    pub python: String,
    /// Skip the SciPy peer.
    #[arg(long)]
    pub no_scipy: bool,
    /// Only kincal beside Ceres and SciPy on the same problems, with the limit of this machine.
    #[arg(long)]
    pub peers: bool,
    /// Only check that kincal and Ceres reach the same cost on small instances (untimed).
    #[arg(long)]
    pub peers_check: bool,
    /// Keep the peers' problem files in this folder (to run the peers again by hand).
    #[arg(long, value_name = "DIR")]
    pub peer_problems: Option<std::path::PathBuf>,
    /// Only the whole `kincal calibrate` process on thesis-sized data, with its parts.
    #[arg(long)]
    pub calibrate_only: bool,
    /// Only the tracker case (3 600 points, 5 sessions, 26 free parameters).
    #[arg(long)]
    pub tracker_only: bool,
    /// Calibration touches of the scale benchmark (calibrate and diagnose from files); 0 skips it.
    #[arg(long, default_value_t = 10_000, value_parser = crate::args::count(0, kincal::data::MAX_TOUCHES))]
    pub scale_touches: usize,
    /// Only the check of `kincal plan`: planned against random placements over this many seeds.
    #[arg(long, value_name = "SEEDS", num_args = 0..=1, default_missing_value = "10")]
    pub plan: Option<u64>,
    /// Run only the scale benchmark (with `--scale-touches`).
    #[arg(long)]
    pub scale_only: bool,
    /// Run only the diagnosis' Monte Carlo checks: false calls on this many clean seeds, and
    /// the power per library effect (see `--power-seeds`); 0 skips them.
    #[arg(long, default_value_t = 0, value_parser = crate::args::count(0, 100_000))]
    pub diagnosis_seeds: usize,
    /// Seeds per library effect in the power check.
    #[arg(long, default_value_t = 5, value_parser = crate::args::count(1, 10_000))]
    pub power_seeds: usize,
}
