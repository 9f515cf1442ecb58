//! One calibration against another on the held-out data both validated on, by the diagnosis'
//! own test: the same units, the same sign-flip and t test, the same practical gain.

use super::sequence::{FAMILY_ALPHA, SIGNIFICANT_GAIN};
use super::units::Measure;
use super::words::mm;
use crate::data::Observations;
use crate::model::ArmModel;
use crate::numerics::significance::held_out_p;
use crate::numerics::stats::rms;

/// One held-out group (placement or session) of two runs side by side.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct ComparedGroup {
    /// Placement or session name.
    pub name: String,
    /// Held-out errors (distances or points).
    pub count: usize,
    /// Held-out RMS of the run before, mm.
    pub before_rms_mm: f64,
    /// Held-out RMS of the run after, mm.
    pub after_rms_mm: f64,
}

/// One side of a comparison: a calibrated model and what it needs to be validated.
pub struct Side<'a> {
    /// The calibrated model.
    pub model: &'a ArmModel,
    /// Groups whose tool floats (held-out ones refit theirs).
    pub float_tool: &'a [String],
    /// The floor its run reported, mm (`None`: unknown).
    pub floor_mm: Option<f64>,
    /// Where the floor comes from.
    pub floor_source: String,
    /// Its run found its held-out error at the floor.
    pub at_floor: bool,
}

/// Two calibrations on the same held-out data.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct Comparison {
    /// What the held-out data measure.
    pub measure: Measure,
    /// The held-out groups.
    pub groups: Vec<ComparedGroup>,
    /// Held-out RMS before, mm.
    pub before_rms_mm: f64,
    /// Held-out RMS after, mm.
    pub after_rms_mm: f64,
    /// The floor of each run, mm.
    pub floors_mm: (Option<f64>, Option<f64>),
    /// Test units improved by the run after, of all.
    pub units_improved: (usize, usize),
    /// Held-out p that the run after is better.
    pub p_better: f64,
    /// Held-out p that it is worse.
    pub p_worse: f64,
    /// The verdict, in words.
    pub verdict: Vec<String>,
}

/// Compare `before` with `after` on the held-out data `val` (both runs validated on it).
pub fn compare(before: &Side, after: &Side, val: &Observations) -> Option<Comparison> {
    let measure = Measure::of(val)?;
    let units = measure.units(val);
    let (b, a) = (
        measure.errors(before.model, val, before.float_tool),
        measure.errors(after.model, val, after.float_tool),
    );
    let numbers = units.numbers(&units.mse(&b), &units.mse(&a));
    let negated: Vec<f64> = numbers.iter().map(|r| -r).collect();
    let (p_better, p_worse) = (held_out_p(&numbers), held_out_p(&negated));
    let mut groups: Vec<ComparedGroup> = Vec::new();
    for u in &units.units {
        let indices: Vec<usize> = u.parts.iter().flatten().copied().collect();
        let name = &val.groups[u.group].name;
        let (eb, ea): (Vec<f64>, Vec<f64>) = indices.iter().map(|&i| (b[i], a[i])).unzip();
        match groups.iter_mut().find(|g| g.name == *name) {
            Some(g) => {
                // A session's blocks of poses: pool them.
                let n = (g.count + eb.len()) as f64;
                let pool = |rms_mm: f64, count: usize, more: &[f64]| {
                    ((rms_mm * rms_mm * count as f64 + more.iter().map(|e| e * e).sum::<f64>()) / n).sqrt()
                };
                g.before_rms_mm = pool(g.before_rms_mm, g.count, &eb);
                g.after_rms_mm = pool(g.after_rms_mm, g.count, &ea);
                g.count += eb.len();
            }
            None => groups.push(ComparedGroup {
                name: name.clone(),
                count: eb.len(),
                before_rms_mm: rms(&eb),
                after_rms_mm: rms(&ea),
            }),
        }
    }
    let (rb, ra) = (rms(&b), rms(&a));
    let improved = numbers.iter().filter(|r| **r > 0.0).count();
    let (data, units_word) = match measure {
        Measure::Distances => ("held-out placements", "placements"),
        Measure::Points => ("held-out sessions", "blocks"),
    };
    let mut verdict = vec![if groups.is_empty() {
        format!("the two runs share no {data}: nothing to compare")
    } else if p_better < FAMILY_ALPHA && ra < (1.0 - SIGNIFICANT_GAIN) * rb {
        format!("the second run is better on the {data}: {} → {} mm ({improved}/{} {units_word} improved, p {p_better:.1e})", mm(rb), mm(ra), numbers.len())
    } else if p_worse < FAMILY_ALPHA && rb < (1.0 - SIGNIFICANT_GAIN) * ra {
        format!("the second run is worse on the {data}: {} → {} mm ({improved}/{} {units_word} improved, p {p_worse:.1e})", mm(rb), mm(ra), numbers.len())
    } else {
        format!(
            "no significant difference on the {data}: {} vs {} mm ({improved}/{} {units_word} improved)",
            mm(rb),
            mm(ra),
            numbers.len()
        )
    }];
    let source = &after.floor_source;
    verdict.push(match after.floor_mm {
        Some(f) if after.at_floor => {
            format!(
                "the second run explains the held-out data: {} mm against a floor of {} mm ({source})",
                mm(ra),
                mm(f)
            )
        }
        Some(f) => format!("the second run is {:.2}× its floor of {} mm ({source})", ra / f, mm(f)),
        None => "the second run's floor is unknown: it cannot be called explained".into(),
    });
    Some(Comparison {
        measure,
        groups,
        before_rms_mm: rb,
        after_rms_mm: ra,
        floors_mm: (before.floor_mm, after.floor_mm),
        units_improved: (improved, numbers.len()),
        p_better,
        p_worse,
        verdict,
    })
}
