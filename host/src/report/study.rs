//! The dataset-size study page (thesis §4.3): held-out RMS against the number of calibration
//! groups (placements or sessions).

use super::{page, svg, table};
use crate::calib::study::StudyRow;

/// The study's HTML page: table and box plot.
pub fn study_report(rows: &[StudyRow]) -> String {
    page("kincal dataset-size study", &study_body(rows))
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
