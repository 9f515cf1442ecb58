//! The dataset-size study page (thesis §4.3): held-out RMS against the number of calibration
//! groups (placements or sessions).

use super::{page, svg, table};
use crate::calib::study::StudyRow;

/// Within this share of the error with every group, more groups are not worth measuring.
const ENOUGH_SHARE: f64 = 0.05;

/// The study's verdict: how many calibration groups bring the held-out error within 5 % of what
/// all of them give, and the next step.
pub fn verdict_lines(rows: &[StudyRow]) -> Vec<String> {
    let done: Vec<&StudyRow> = rows.iter().filter(|r| r.calibrations > 0 && r.mean_mm.is_finite()).collect();
    let Some(all) = done.iter().max_by_key(|r| r.groups) else {
        return vec!["no calibration of any subset succeeded: there is no result".into()];
    };
    let enough =
        done.iter().filter(|r| r.mean_mm <= all.mean_mm * (1.0 + ENOUGH_SHARE)).min_by_key(|r| r.groups);
    let first = match enough {
        Some(r) if r.groups < all.groups => format!(
            "{} groups (placements or sessions) bring the held-out error within {:.0} % of what all {} give ({:.3} against {:.3} mm): more of the same would not lower it; what remains is the model or the noise",
            r.groups,
            100.0 * ENOUGH_SHARE,
            all.groups,
            r.mean_mm,
            all.mean_mm
        ),
        _ => format!(
            "the held-out error still falls with the last group added ({:.3} mm with all {}): more placements or sessions would lower it",
            all.mean_mm, all.groups
        ),
    };
    vec![
        first,
        "next: kincal calibrate on all of them, then kincal diagnose on that run for what the model misses"
            .into(),
    ]
}

/// The study's HTML page: verdict, table and box plot.
pub fn study_report(rows: &[StudyRow]) -> String {
    let items: String =
        verdict_lines(rows).iter().map(|l| format!("<li>{}</li>", super::svg::escape(l))).collect();
    page("kincal dataset-size study", &format!("<h2>Verdict</h2><ul>{items}</ul>{}", study_body(rows)))
}

/// The study's table and box plot as an HTML fragment.
pub fn study_body(rows: &[StudyRow]) -> String {
    let cells: Vec<Vec<String>> = rows
        .iter()
        .map(|r| {
            vec![
                r.groups.to_string(),
                format!("{} of {}", r.calibrations + r.failed + r.implausible, r.possible_subsets),
                r.calibrations.to_string(),
                format!("{:.3}", r.mean_mm),
                format!("{:.3}", r.std_mm),
                format!("{:.3}", r.min_mm),
                format!("{:.3}", r.max_mm),
            ]
        })
        .collect();
    let groups: Vec<(String, Vec<f64>)> =
        rows.iter().map(|r| (r.groups.to_string(), r.rms_mm.clone())).collect();
    format!(
        "<p>Held-out RMS of calibrations on distinct random subsets of the calibration groups \
         (placements or sessions; every subset once when there are no more than asked for).</p>{}{}",
        table(
            &["groups", "distinct subsets", "calibrations", "mean mm", "std mm", "min mm", "max mm"],
            &cells
        ),
        svg::boxplot(&groups, "held-out RMS (mm)")
    )
}
