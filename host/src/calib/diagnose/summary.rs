//! The diagnosis in words: the verdict first, then where it fails, what is named and what to do.

use super::apparent::periodic_line;
use super::sequence::RivalVerdict;
use super::words::mm;
use super::{Candidate, Diagnosis, Measure};
use crate::calib::floor::Gap;
use crate::calib::setup::{Change, Setup};
use crate::model::tree::Tree;

/// Held-out units below which the summary says the test rests on too few numbers.
const MIN_UNITS: usize = 5;

/// How the line naming the next calibration starts; where the RUN's inputs are known, the line
/// is given the whole command instead ([`crate::calib::summary::RunInputs::calibrate_command`]).
pub const WHAT_TO_DO: &str = "what to do: kincal calibrate … ";

/// "what to do: kincal calibrate … OPTIONS (the run's options: …)".
fn what_to_do(c: &Candidate, setup: &Setup) -> String {
    let given = setup.options_text();
    format!(
        "{WHAT_TO_DO}{} (the run's options: {})",
        c.action,
        if given.is_empty() { "none" } else { &given }
    )
}

/// On a model that lets its joints sag under a unit mass at the tool point (`compliance:J`) and
/// has no mass table, while the model still misses the floor: the sag is not a tip mass's.
fn tip_mass_line(d: &Diagnosis) -> Option<String> {
    use crate::model::ParamId;
    let model = d.model.as_ref()?;
    let gap = d.floor.gap.as_ref().filter(|g| g.significant && d.incomplete)?;
    if !model.tree.bodies.is_empty() {
        return None;
    }
    let tip_levers: Vec<String> = model
        .free
        .iter()
        .filter(|f| matches!(f.id, ParamId::Compliance(_)))
        .map(|f| f.id.to_string())
        .collect();
    if tip_levers.is_empty() {
        return None;
    }
    Some(format!(
        "the sag is not explained by a tip mass alone: with {} (a unit mass at the tool point) the model still misses \
         about {} mm; the links' own weight (and a branched robot's other branches) load the joints with torques a \
         tool-point lever cannot follow: give the model a mass table (`kincal model from-urdf … --masses`) and add \
         sag (and bend)",
        tip_levers.join(", "),
        mm(gap.missing_mm)
    ))
}

/// For rivals the data cannot tell apart that are joint compliance under the link masses
/// (`sag`, `sag:J`) and lateral compliance (`bend`, `bend:J`) of the same joints, or of joints
/// next to each other in `tree` (`bend:J` turns the chain as `sag` of the joint after or before
/// it does where their axes meet at a right angle): why they look alike, and that they are
/// rivals, not one effect.
fn deflection_rivals_line(rivals: &[super::Rival], tree: &Tree) -> Option<String> {
    use crate::model::effects::{Effect, EffectKind};
    let near = |a: Option<usize>, b: Option<usize>| match (a, b) {
        (Some(a), Some(b)) => a == b || tree.parent(a) == Some(b) || tree.parent(b) == Some(a),
        (a, b) => a == b,
    };
    let r = rivals.iter().filter(|r| r.verdict == RivalVerdict::CannotTell).find(|r| {
        match (Effect::parse(&r.a), Effect::parse(&r.b)) {
            (Some(a), Some(b)) => {
                let kinds = [a.kind, b.kind];
                kinds.contains(&EffectKind::Sag)
                    && kinds.contains(&EffectKind::Bend)
                    && near(a.joint, b.joint)
            }
            _ => false,
        }
    })?;
    let (sag, bend) = if r.a.starts_with("sag") { (&r.a, &r.b) } else { (&r.b, &r.a) };
    Some(format!(
        "{sag} and {bend} are rivals: joint compliance under the link masses ({sag}: the joint turns about its axis by \
         its compliance times the torque of the masses beyond it) and lateral compliance ({bend}: the joint's frame \
         tilts across its axis under the moment the joint does not carry) deflect the tips alike on these data — where \
         a joint's axis meets the next one at a right angle, the moment across one is the torque about the other; \
         poses that load the joints with their axes apart tell them apart"
    ))
}

/// The summary lines of `d`; `with` is the gap the named change would leave.
pub(super) fn lines(d: &Diagnosis, setup: &Setup, with: Option<&Gap>) -> Vec<String> {
    let what = match d.measure {
        Measure::Distances => "pairs",
        Measure::Points => "points",
    };
    let mut lines = vec![d.floor.verdict(d.baseline.rms_mm, d.baseline.count, what)];
    let effects: Vec<String> =
        d.named.iter().filter(|n| d.candidates.iter().any(|c| c.name == **n)).cloned().collect();
    lines.extend(periodic_line(&d.joints, &effects));
    // A flagged block or observation is named even when the held-out data cannot show its harm.
    for c in d
        .data_errors
        .iter()
        .filter(|c| !c.significant && matches!(c.change, Change::ExcludeBlock(_) | Change::ExcludePoints(_)))
    {
        lines.push(format!("suspect data: {} — {}; {}", c.name, c.evidence, c.action));
    }
    let first = d.named.first().and_then(|n| d.candidate(n));
    let best_arm = d.candidates.iter().find(|c| c.significant && c.equivalent_to.is_none());
    match first {
        Some(c) if c.change.is_data_error() => {
            lines.push(format!("data error: {} — {}", c.name, c.evidence));
            lines.push(what_to_do(c, setup));
            lines.push(match best_arm {
                Some(a) => format!(
                    "no arm effect is claimed: the best one ({}, {} mm) explains the residuals no better than this data error; fix the data first and diagnose again",
                    a.name,
                    mm(a.held_out_rms_mm)
                ),
                None => "no arm effect is claimed: fix the data first and diagnose again".into(),
            });
        }
        Some(c) if d.named.len() > 1 => {
            let detail: Vec<String> = d
                .rivals
                .iter()
                .filter(|r| r.verdict == RivalVerdict::CannotTell)
                .map(|r| {
                    let lambda = r.separability.map_or(String::new(), |l| format!(", separability λ = {l:.1}"));
                    format!(
                        "adding {} to {} p = {:.3}, adding {} to {} p = {:.3}{lambda}",
                        r.b, r.a, r.b_adds_p, r.a, r.b, r.a_adds_p
                    )
                })
                .collect();
            lines.push(format!(
                "missing effect: {}: these data cannot tell them apart (neither lowers the held-out error beyond the other: {})",
                d.named.join(" or "),
                detail.join("; ")
            ));
            let chain = Tree::default();
            lines.extend(deflection_rivals_line(&d.rivals, d.model.as_ref().map_or(&chain, |m| &m.tree)));
            lines.extend(d.refinement.as_ref().map(|r| r.line()));
            for n in &d.named {
                if let Some(c) = d.candidate(n) {
                    lines.push(format!("  {} — {}", c.name, c.evidence));
                }
            }
            lines.push(format!(
                "what to measure next: `kincal plan RUN` names where {} predict different measurements (by default for the first pair these data cannot tell apart), the joint ranges they pass and how far apart the explanations put the measurements there; measure them, add them to the calibration data, recalibrate and diagnose again",
                d.named.join(", ")
            ));
            lines.push(what_to_do(c, setup));
        }
        Some(c) => {
            let same = if c.equivalent.is_empty() {
                String::new()
            } else {
                format!(" (these data cannot tell it from {})", c.equivalent.join(", "))
            };
            lines.push(format!("missing effect: {} — {}{same}", c.name, c.evidence));
            lines.extend(d.refinement.as_ref().map(|r| r.line()));
            for r in &d.rivals {
                match &r.verdict {
                    RivalVerdict::Proxy { cause, proxy } => lines.push(format!(
                        "{proxy} looks like a proxy of {cause}: added to {cause} it gives no significant further gain on the held-out data (p = {:.3}), while {cause} added to {proxy} does (p = {:.3})",
                        if *proxy == r.b { r.b_adds_p } else { r.a_adds_p },
                        if *proxy == r.b { r.a_adds_p } else { r.b_adds_p },
                    )),
                    RivalVerdict::Both => lines.push(format!(
                        "{} and {} are both missing: each lowers the held-out error beyond the other (p = {:.3} and {:.3}; both together {} mm)",
                        r.a, r.b, r.b_adds_p, r.a_adds_p, mm(r.both_rms_mm)
                    )),
                    RivalVerdict::CannotTell => {}
                }
            }
            lines.push(what_to_do(c, setup));
        }
        None => lines.push(if d.candidates.iter().chain(&d.data_errors).all(|c| !c.tested) {
            "no candidate effect or data error promises a practical gain on the calibration data: none was tested on the held-out data".into()
        } else {
            match &d.floor.gap {
                Some(g) if g.significant => format!(
                    "no candidate effect or data error improves the held-out error beyond noise, yet the model misses about {} mm: the model is incomplete (look at the apparent joint errors for an error outside the library)",
                    mm(g.missing_mm)
                ),
                Some(g) if g.at_floor => "no candidate effect improves the held-out error beyond noise, and the error is at the floor".into(),
                Some(_) => "no candidate effect improves the held-out error beyond noise; whether anything is missing cannot be told from these data".into(),
                None => "no candidate effect improves the held-out error beyond noise (the noise floor is unknown, so whether the model is complete cannot be told)".into(),
            }
        }),
    }
    if (1..MIN_UNITS).contains(&d.units) {
        lines.push(match d.measure {
            Measure::Distances => format!(
                "with {n} validation placements the held-out test rests on {n} numbers (the exact sign-flip test cannot go below 2⁻{n}, only a t test on so few can pass): measure at least {MIN_UNITS} validation placements (8–10 with one repeat each carry more evidence than 5 × 3)",
                n = d.units
            ),
            Measure::Points => format!(
                "the held-out sessions give {n} test units only (the exact sign-flip test cannot go below 2⁻{n}): hold out more poses or sessions (at least {MIN_UNITS} blocks of {} poses)",
                super::units::MIN_UNIT_POINTS,
                n = d.units
            ),
        });
    }
    for t in d.held_out_tools.iter().filter(|t| t.significant) {
        lines.push(format!("data error in a held-out session: {} (apply with {})", t.text, t.action));
        if first.is_none() && d.change.as_ref().is_some_and(|c| c.action() == t.action) {
            lines.push(
                "no arm effect is claimed: a held-out session's own error spoils the held-out test of every arm \
                 effect; apply it and diagnose again"
                    .into(),
            );
        }
    }
    lines.extend(d.floor.neighbour_lines());
    if let (Some(c), Some(g), Some(after)) = (first, &d.floor.gap, with) {
        if g.significant && after.significant {
            lines.push(format!(
                "even with {} the model would miss about {} mm ({} mm against ≈{} mm expected): the model is incomplete — more effects, or an error outside the library (see the periodic residuals per joint)",
                c.name,
                mm(after.missing_mm),
                mm(c.held_out_rms_mm),
                mm(after.expected_mm)
            ));
        }
    }
    lines.extend(tip_mass_line(d));
    if d.incomplete && first.is_none() && d.change.is_none() {
        lines.push("the cause is not in the effect library nor among the data errors kincal scores".into());
    }
    lines
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::diagnose::Rival;

    fn rival(a: &str, b: &str, verdict: RivalVerdict) -> Rival {
        Rival {
            a: a.into(),
            b: b.into(),
            both_rms_mm: 1.0,
            a_adds_p: 0.4,
            b_adds_p: 0.5,
            separability: Some(2.0),
            verdict,
        }
    }

    /// Joint compliance and lateral compliance of the same joints, or of neighbours in the chain,
    /// that the data cannot tell apart are stated as rivals, with why they look alike; other
    /// pairs, joints apart or a verdict the data reached are not.
    #[test]
    fn sag_and_bend_the_data_cannot_tell_apart_are_stated_as_rivals() {
        // Two branches on joint 1 (0-based 0): joints 2-3 and joints 4-5.
        let tree = Tree { parents: vec![None, Some(0), Some(1), Some(0), Some(3)], ..Tree::default() };
        for (a, b) in [("bend", "sag"), ("sag:5", "bend:5"), ("sag:3", "bend:2"), ("bend:4", "sag:1")] {
            let line =
                deflection_rivals_line(&[rival(a, b, RivalVerdict::CannotTell)], &tree).expect("a line");
            let sag = if a.starts_with("sag") { a } else { b };
            assert!(line.starts_with(&format!("{sag} and ")), "{line}");
            assert!(line.contains("are rivals") && line.contains("torque about the other"), "{line}");
        }
        for (a, b) in [("sag:4", "bend:3"), ("sag:2", "bend:4"), ("sag:5", "bend:3"), ("sag", "bend:2")] {
            assert_eq!(
                deflection_rivals_line(&[rival(a, b, RivalVerdict::CannotTell)], &tree),
                None,
                "{a} {b}"
            );
        }
        assert_eq!(
            deflection_rivals_line(&[rival("sag", "eccentricity:2", RivalVerdict::CannotTell)], &tree),
            None
        );
        assert_eq!(deflection_rivals_line(&[rival("bend", "sag", RivalVerdict::Both)], &tree), None);
    }
}
