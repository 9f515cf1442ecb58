//! `kincal study`: the dataset-size study (thesis §4.3). For 1..N calibration placements,
//! K random subsets each are calibrated and validated on the held-out sessions; the table gives
//! mean, standard deviation and range of the validation RMS per subset size.

use crate::calib::calibrate::{calibrate, CalibrationOptions};
use crate::calib::validate::{distance_errors, ErrorStats};
use crate::data::{Artefact, Dataset};
use crate::model::ArmModel;
use indicatif::{ProgressBar, ProgressStyle};
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

/// Settings of a study.
#[derive(Clone, Copy, Debug)]
pub struct StudyOptions {
    /// Random subsets per subset size.
    pub subsets: usize,
    /// Seed of the subset draws.
    pub seed: u64,
    /// Settings of each calibration.
    pub calibration: CalibrationOptions,
    /// Draw a progress bar on stderr.
    pub progress: bool,
}

/// Results for one subset size.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct StudyRow {
    /// Placements used for calibration.
    pub placements: usize,
    /// Calibrations run (failed ones are counted in `failed`).
    pub calibrations: usize,
    /// Calibrations that could not run (too few pairs).
    pub failed: usize,
    /// Mean validation RMS, mm.
    pub mean_mm: f64,
    /// Standard deviation of the validation RMS, mm.
    pub std_mm: f64,
    /// Smallest validation RMS, mm.
    pub min_mm: f64,
    /// Largest validation RMS, mm.
    pub max_mm: f64,
    /// Every validation RMS, mm.
    pub rms_mm: Vec<f64>,
}

/// Most touch-calibrations (touches of each subset summed over every calibration) a study may
/// ask for: about 12 minutes on two cores at the measured 14 000 touch-calibrations per second.
pub const MAX_STUDY_WORK: usize = 10_000_000;

/// Why a study is refused before it starts.
#[derive(Debug, thiserror::Error)]
pub enum StudyError {
    /// The study would run far too long.
    #[error(
        "a study of {subsets} subsets per placement count over {placements} placements and {touches} \
         touches means {work} touch-calibrations; at most {MAX_STUDY_WORK} are run (about 12 minutes on \
         two cores): use fewer subsets"
    )]
    TooLarge {
        /// Subsets per placement count.
        subsets: usize,
        /// Calibration placements.
        placements: usize,
        /// Calibration touches.
        touches: usize,
        /// Touch-calibrations it would take.
        work: usize,
    },
}

/// Refuse up front a study larger than [`MAX_STUDY_WORK`]: subset k of n placements holds about
/// k/n of the touches, so the work is subsets × touches × (n + 1) / 2.
pub fn check_study_size(cal: &Dataset, subsets: usize) -> Result<(), StudyError> {
    let (placements, touches) = (cal.placements.len(), cal.touches.len());
    let work = subsets.saturating_mul(touches).saturating_mul(placements + 1) / 2;
    if work > MAX_STUDY_WORK {
        return Err(StudyError::TooLarge { subsets, placements, touches, work });
    }
    Ok(())
}

/// Why the rows of a study cannot be taken as a result, if they cannot.
pub fn study_problems(rows: &[StudyRow]) -> Vec<String> {
    let mut problems = Vec::new();
    if rows.iter().all(|r| r.calibrations == 0) {
        problems.push(
            "no calibration of any subset succeeded: too few landmark pairs per placement for the free \
             parameters, or no validation pairs"
                .to_string(),
        );
    }
    for r in rows {
        let figures = [r.mean_mm, r.std_mm, r.min_mm, r.max_mm].into_iter().chain(r.rms_mm.iter().copied());
        if figures.into_iter().any(|v| !v.is_finite()) {
            problems.push(format!("the row for {} placements holds a non-finite figure", r.placements));
        }
    }
    problems
}

/// Run the study. Uses every core rayon is given.
pub fn study(
    nominal: &ArmModel,
    artefact: &Artefact,
    cal: &Dataset,
    val: &Dataset,
    options: &StudyOptions,
) -> Vec<StudyRow> {
    let n = cal.placements.len();
    let mut rng = ChaCha8Rng::seed_from_u64(options.seed);
    let mut tasks = Vec::new();
    for k in 1..=n {
        for _ in 0..options.subsets {
            let mut all: Vec<usize> = (0..n).collect();
            all.shuffle(&mut rng);
            all.truncate(k);
            all.sort_unstable();
            tasks.push((k, all));
        }
    }
    let bar = if options.progress { ProgressBar::new(tasks.len() as u64) } else { ProgressBar::hidden() };
    if let Ok(style) =
        ProgressStyle::with_template("{bar:40} {pos}/{len} calibrations, {elapsed} elapsed, ETA {eta}")
    {
        bar.set_style(style);
    }
    let results: Vec<(usize, Option<f64>)> = tasks
        .par_iter()
        .map(|(k, subset)| {
            let rms = calibrate(nominal, artefact, &cal.subset(subset), &options.calibration)
                .ok()
                .map(|fit| {
                    let e: Vec<f64> =
                        distance_errors(&fit.model, artefact, val).iter().map(|e| e.error_mm).collect();
                    ErrorStats::of(&e)
                })
                // A calibration whose validation is empty or not finite is a failed one.
                .filter(|v| v.pairs > 0 && v.rms_mm.is_finite())
                .map(|v| v.rms_mm);
            bar.inc(1);
            (*k, rms)
        })
        .collect();
    bar.finish_and_clear();
    (1..=n)
        .map(|k| {
            let rms_mm: Vec<f64> = results.iter().filter(|r| r.0 == k).filter_map(|r| r.1).collect();
            let failed = results.iter().filter(|r| r.0 == k && r.1.is_none()).count();
            // A row where no calibration ran holds zeros with `calibrations` 0, never ∞ or NaN.
            let count = rms_mm.len().max(1) as f64;
            let mean = rms_mm.iter().sum::<f64>() / count;
            let std = (rms_mm.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / count).sqrt();
            let min = rms_mm.iter().copied().reduce(f64::min).unwrap_or(0.0);
            let max = rms_mm.iter().copied().fold(0.0_f64, f64::max);
            StudyRow {
                placements: k,
                calibrations: rms_mm.len(),
                failed,
                mean_mm: mean,
                std_mm: std,
                min_mm: min,
                max_mm: max,
                rms_mm,
            }
        })
        .collect()
}
