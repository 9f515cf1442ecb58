//! `kincal study`: the dataset-size study (thesis §4.3). For 1..N calibration groups (artefact
//! placements or instrument sessions), up to K distinct subsets each are calibrated and validated
//! on the held-out data (distances, or points with each session's frame refitted); the table gives
//! mean, standard deviation and range of the held-out RMS per subset size. When there are no more
//! than K subsets of a size (C(N, k) ≤ K, always at k = N) each is calibrated once: the row's
//! sample is every subset there is, never one subset counted K times. A calibration beyond the
//! model-independent scales ([`crate::calib::trust`]) is not a sample: it is counted in
//! `implausible`, its figure left out.

use crate::calib::diagnose::Measure;
use crate::calib::error_stats::ErrorStats;
use crate::calib::setup::Setup;
use crate::calib::trust::TrustScales;
use crate::data::Observations;
use crate::model::ArmModel;
use indicatif::{ProgressBar, ProgressStyle};
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

/// Settings of a study.
#[derive(Clone, Debug)]
pub struct StudyOptions {
    /// Random subsets per subset size.
    pub subsets: usize,
    /// Seed of the subset draws.
    pub seed: u64,
    /// What each calibration is asked (its options, the floated tools).
    pub setup: Setup,
    /// Draw a progress bar on stderr.
    pub progress: bool,
}

/// Results for one subset size.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct StudyRow {
    /// Calibration groups (placements or sessions) used.
    #[serde(alias = "placements")]
    pub groups: usize,
    /// Calibrations run (failed ones are counted in `failed`).
    pub calibrations: usize,
    /// Calibrations that could not run (too few pairs).
    pub failed: usize,
    /// Calibrations beyond the model-independent scales: not a calibration, figure left out.
    #[serde(default)]
    pub implausible: usize,
    /// Distinct subsets of this many placements there are, C(N, k) (saturating).
    #[serde(default)]
    pub possible_subsets: usize,
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

/// C(n, k), saturating at `usize::MAX`.
pub fn subset_count(n: usize, k: usize) -> usize {
    let k = k.min(n - k.min(n));
    let mut c: u128 = 1;
    for i in 0..k {
        c = c * (n - i) as u128 / (i + 1) as u128;
        if c > usize::MAX as u128 {
            return usize::MAX;
        }
    }
    c as usize
}

/// Up to `wanted` distinct k-subsets of 0..n (each sorted): every one of them when there are at
/// most `wanted`, else `wanted` drawn at random without repetition.
pub fn distinct_subsets(n: usize, k: usize, wanted: usize, rng: &mut ChaCha8Rng) -> Vec<Vec<usize>> {
    let possible = subset_count(n, k);
    if possible <= wanted {
        // Every combination, in lexicographic order.
        let mut out = Vec::with_capacity(possible);
        let mut c: Vec<usize> = (0..k).collect();
        loop {
            out.push(c.clone());
            let Some(i) = (0..k).rev().find(|&i| c[i] != i + n - k) else { break };
            c[i] += 1;
            for j in i + 1..k {
                c[j] = c[j - 1] + 1;
            }
        }
        return out;
    }
    // More subsets than wanted: each draw is new with probability at least
    // 1 − wanted/possible > 0, so the draws end (at worst after about wanted·ln(wanted) of them).
    let mut seen = std::collections::HashSet::new();
    let mut out = Vec::with_capacity(wanted);
    while out.len() < wanted {
        let mut all: Vec<usize> = (0..n).collect();
        all.shuffle(rng);
        all.truncate(k);
        all.sort_unstable();
        if seen.insert(all.clone()) {
            out.push(all);
        }
    }
    out
}

/// Most touch-calibrations (touches of each subset summed over every calibration) a study may
/// ask for: about 12 minutes on two cores at the measured 14 000 touch-calibrations per second.
pub const MAX_STUDY_WORK: usize = 10_000_000;

/// Why a study is refused before it starts.
#[derive(Debug, thiserror::Error)]
pub enum StudyError {
    /// The study would run far too long.
    #[error(
        "a study of {subsets} subsets per group count over {groups} calibration groups and {touches} \
         observations means {work} touch-calibrations (observations × calibrations); at most {MAX_STUDY_WORK} \
         are run (about 12 minutes on two cores): use fewer subsets"
    )]
    TooLarge {
        /// Subsets per group count.
        subsets: usize,
        /// Calibration groups.
        groups: usize,
        /// Calibration observations.
        touches: usize,
        /// Touch-calibrations it would take.
        work: usize,
    },
}

/// Refuse up front a study larger than [`MAX_STUDY_WORK`]: subset k of n groups holds about
/// k/n of the observations, so the work is subsets × observations × (n + 1) / 2.
pub fn check_study_size(cal: &Observations, subsets: usize) -> Result<(), StudyError> {
    let (groups, touches) = (cal.groups.len(), cal.obs.len());
    let work = subsets.saturating_mul(touches).saturating_mul(groups + 1) / 2;
    if work > MAX_STUDY_WORK {
        return Err(StudyError::TooLarge { subsets, groups, touches, work });
    }
    Ok(())
}

/// Why the rows of a study cannot be taken as a result, if they cannot.
pub fn study_problems(rows: &[StudyRow]) -> Vec<String> {
    let mut problems = Vec::new();
    let implausible: usize = rows.iter().map(|r| r.implausible).sum();
    if implausible > 0 {
        problems.push(format!(
            "{implausible} subset calibrations are beyond the model-independent scales (the artefact's \
             size, the repeats' spread through the nominal model): the model does not describe these \
             measurements, so no row is a result — check the model file (a sign, a unit, an offset, \
             joints in another order, another arm) and the artefact file"
        ));
    } else if rows.iter().all(|r| r.calibrations == 0) {
        problems.push(
            "no calibration of any subset succeeded: too few measurements per group for the free \
             parameters, or no held-out data"
                .to_string(),
        );
    }
    for r in rows {
        let figures = [r.mean_mm, r.std_mm, r.min_mm, r.max_mm].into_iter().chain(r.rms_mm.iter().copied());
        if figures.into_iter().any(|v| !v.is_finite()) {
            problems.push(format!("the row for {} groups holds a non-finite figure", r.groups));
        }
    }
    problems
}

/// What became of one subset's calibration.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Outcome {
    /// It could not run, or its validation is empty or not finite.
    Failed,
    /// Beyond the model-independent scales: not a calibration.
    Implausible,
    /// Its validation RMS, mm.
    Validated(f64),
}

/// Run the study. Uses every core rayon is given.
pub fn study(
    nominal: &ArmModel,
    cal: &Observations,
    val: &Observations,
    options: &StudyOptions,
) -> Vec<StudyRow> {
    let n = cal.groups.len();
    let mut rng = ChaCha8Rng::seed_from_u64(options.seed);
    let mut tasks = Vec::new();
    for k in 1..=n {
        tasks.extend(distinct_subsets(n, k, options.subsets, &mut rng).into_iter().map(|s| (k, s)));
    }
    let scales = TrustScales::of(nominal, cal, val);
    let bar = if options.progress { ProgressBar::new(tasks.len() as u64) } else { ProgressBar::hidden() };
    if let Ok(style) =
        ProgressStyle::with_template("{bar:40} {pos}/{len} calibrations, {elapsed} elapsed, ETA {eta}")
    {
        bar.set_style(style);
    }
    let results: Vec<(usize, Outcome)> = tasks
        .par_iter()
        .map(|(k, subset)| {
            let outcome = match (options.setup.calibrate(nominal, &cal.subset(subset)), Measure::of(val)) {
                (Err(_), _) | (_, None) => Outcome::Failed,
                (Ok(fit), Some(measure)) => {
                    let v = ErrorStats::of(&measure.errors(&fit.model, val, &options.setup.float_tool));
                    if v.count == 0 || !v.rms_mm.is_finite() {
                        // A calibration whose validation is empty or not finite is a failed one.
                        Outcome::Failed
                    } else if !scales.calibration_beyond(fit.rms_mm).is_empty()
                        || scales.artefact_limit_mm().is_some_and(|limit| v.rms_mm > limit)
                    {
                        // Few groups may validate poorly; only an artefact bounds their
                        // validation, while the fit itself must be a calibration.
                        Outcome::Implausible
                    } else {
                        Outcome::Validated(v.rms_mm)
                    }
                }
            };
            bar.inc(1);
            (*k, outcome)
        })
        .collect();
    bar.finish_and_clear();
    (1..=n)
        .map(|k| {
            let of_k = || results.iter().filter(move |r| r.0 == k).map(|r| r.1);
            let rms_mm: Vec<f64> =
                of_k().filter_map(|o| if let Outcome::Validated(v) = o { Some(v) } else { None }).collect();
            let failed = of_k().filter(|o| *o == Outcome::Failed).count();
            let implausible = of_k().filter(|o| *o == Outcome::Implausible).count();
            // A row where no calibration ran holds zeros with `calibrations` 0, never ∞ or NaN.
            let count = rms_mm.len().max(1) as f64;
            let mean = rms_mm.iter().sum::<f64>() / count;
            let std = (rms_mm.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / count).sqrt();
            let min = rms_mm.iter().copied().reduce(f64::min).unwrap_or(0.0);
            let max = rms_mm.iter().copied().fold(0.0_f64, f64::max);
            StudyRow {
                groups: k,
                calibrations: rms_mm.len(),
                failed,
                implausible,
                possible_subsets: subset_count(n, k),
                mean_mm: mean,
                std_mm: std,
                min_mm: min,
                max_mm: max,
                rms_mm,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::simulate::{simulate, SimulationOptions};

    #[test]
    fn subsets_are_distinct_and_all_of_them_when_there_are_few() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        assert_eq!((subset_count(5, 2), subset_count(5, 5), subset_count(70, 35) > 1 << 60), (10, 1, true));
        // C(5, 4) = 5 ≤ 100 wanted: each of the 5 once.
        let four = distinct_subsets(5, 4, 100, &mut rng);
        assert_eq!(four.len(), 5);
        assert_eq!(distinct_subsets(5, 5, 100, &mut rng), vec![vec![0, 1, 2, 3, 4]]);
        // C(10, 3) = 120 > 50 wanted: 50 different ones.
        let drawn = distinct_subsets(10, 3, 50, &mut rng);
        let unique: std::collections::HashSet<_> = drawn.iter().cloned().collect();
        assert_eq!((drawn.len(), unique.len()), (50, 50));
        assert!(drawn.iter().all(|s| s.len() == 3 && s.windows(2).all(|w| w[0] < w[1]) && s[2] < 10));
    }

    #[test]
    fn a_study_of_few_placements_counts_each_subset_once_and_an_absurd_model_is_no_result() {
        let nominal = ArmModel::suta_nominal();
        let sim = simulate(&nominal, &SimulationOptions::default());
        let (cal, val) = (
            Observations::from_sessions(&sim.calibration, &sim.artefact),
            Observations::from_sessions(&sim.validation, &sim.artefact),
        );
        let cal = cal.subset(&[0, 1, 2]);
        let calibration = crate::calib::setup::SolveOptions { restarts: Some(0), ..Default::default() };
        let options = StudyOptions { subsets: 100, seed: 1, setup: Setup::new(calibration), progress: false };
        let rows = study(&nominal, &cal, &val, &options);
        let drawn: Vec<(usize, usize)> =
            rows.iter().map(|r| (r.calibrations + r.failed + r.implausible, r.possible_subsets)).collect();
        assert_eq!(drawn, vec![(3, 3), (3, 3), (1, 1)], "every subset once, never 100 copies");
        assert!(study_problems(&rows).is_empty(), "{:?}", study_problems(&rows));
        let mut wrong = nominal.clone();
        wrong.set(crate::model::ParamId::Length(4), -371.0);
        wrong.free_param(crate::model::ParamId::Length(4), -381.0, -361.0);
        let rows = study(&wrong, &cal, &val, &options);
        assert!(
            rows.iter().all(|r| r.calibrations == 0 && r.rms_mm.is_empty()),
            "no figure of an absurd model"
        );
        let problems = study_problems(&rows);
        assert!(problems.iter().any(|p| p.contains("model-independent scales")), "{problems:?}");
    }
}
