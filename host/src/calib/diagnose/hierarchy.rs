//! Effects that refine others: which of them the diagnosis names first.
//!
//! Lateral compliance (`bend`, `bend:J`) refines joint compliance (`sag`, `sag:J`) under the same
//! gravity loads: a modeller, and the published calibration of a humanoid (Tenhumberg & Bäuml,
//! Humanoids 2020), give the joints their own spring first and let them bend across their axes
//! after, the way a statistician adds an interaction only after its main effects. The data alone
//! would often name the refinement first: where a joint's axis meets the next one at a right
//! angle, the moment across the one is the torque about the other, so `bend` imitates most of
//! the missing `sag` (and `sag` little of `bend`), and removes more of the held-out error.
//!
//! The rule: while the main effect is not in the model and is itself significant, the diagnosis
//! names the main effect in the refinement's place (both were scored on the same held-out data;
//! the refinement is scored again on top of it at the next diagnosis) and says so. Where the main
//! effect is not significant by itself (or the data cannot determine it), the refinement is named
//! without it, and the diagnosis says that too. The rule chooses among significant candidates
//! only: it adds no test and changes no p value.

use super::Candidate;
use crate::model::effects::{Effect, EffectKind};
use crate::model::ArmModel;

/// Refinement kind, the kind it refines, and why.
const REFINES: [(EffectKind, EffectKind, &str); 1] =
    [(EffectKind::Bend, EffectKind::Sag, "lateral compliance refines joint compliance")];

/// What the hierarchy did to the effect the data name first.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Refinement {
    /// The refinement the data name first (`bend`).
    pub refinement: String,
    /// Its main effect, not in the model (`sag`).
    pub main: String,
    /// Why the one refines the other.
    pub why: String,
    /// The main effect is named in its place (it is significant); otherwise the refinement is
    /// named without it.
    pub main_first: bool,
}

impl Refinement {
    /// The statement in the diagnosis's words.
    pub fn line(&self) -> String {
        let (r, m) = (&self.refinement, &self.main);
        if self.main_first {
            format!(
                "{r} is offered once {m} is in the model: {}; {m} is significant by itself and is named first, \
                 and the next diagnosis scores {r} on top of it",
                self.why
            )
        } else {
            format!(
                "{r} is named without {m}: {} (so {m} comes first where it helps), but {m} is not significant by \
                 itself on these data (or they cannot determine it)",
                self.why
            )
        }
    }
}

/// The main effect `effect` refines, when it refines one that `model` does not hold yet: for
/// `bend`, `sag`; for `bend:J`, `sag:J` (held too when the whole `sag` is in the model).
fn missing_main(effect: Effect, model: &ArmModel) -> Option<(Effect, &'static str)> {
    let &(_, main, why) = REFINES.iter().find(|r| r.0 == effect.kind)?;
    let main = Effect { kind: main, joint: effect.joint, body: None };
    (!main.is_in(model)).then_some((main, why))
}

/// Apply the rule (see the module doc) to the effects `named` (leader first) among `candidates`,
/// for the calibrated `model`: the names in the order the diagnosis gives them, and what the rule
/// did, if anything.
pub fn main_first(
    named: &[String],
    candidates: &[Candidate],
    model: &ArmModel,
) -> (Vec<String>, Option<Refinement>) {
    let unchanged = || (named.to_vec(), None);
    let Some(lead) = named.first().and_then(|n| Effect::parse(n)) else { return unchanged() };
    let Some((main, why)) = missing_main(lead, model) else { return unchanged() };
    // A per-joint main effect the library does not offer is stood for by its whole family.
    let family = Effect { kind: main.kind, joint: None, body: None };
    let found = [main, family].into_iter().find_map(|m| candidates.iter().find(|c| c.name == m.to_string()));
    let main_first = found.is_some_and(|c| c.significant);
    let refinement = Refinement {
        refinement: lead.to_string(),
        main: found.map_or(main.to_string(), |c| c.name.clone()),
        why: why.into(),
        main_first,
    };
    let order = match found {
        // A rival the data cannot tell from the refinement goes first, the rivals stay named.
        Some(c) if main_first && named.contains(&c.name) => {
            std::iter::once(c.name.clone()).chain(named.iter().filter(|n| **n != c.name).cloned()).collect()
        }
        Some(c) if main_first => vec![c.name.clone()],
        _ => named.to_vec(),
    };
    (order, Some(refinement))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::calib::diagnose::Ranking;
    use crate::calib::setup::Change;

    fn candidate(name: &str, significant: bool) -> Candidate {
        let ranking = Ranking {
            order: Some(1.0),
            calibration_z: 1.0,
            cv_gain: None,
            delta_bic: None,
            calibration_rms_mm: None,
            refitted: true,
        };
        Candidate {
            name: name.into(),
            change: Change::Effect(Effect::parse(name).expect("an effect")),
            action: format!("--add {name}"),
            held_out_rms_mm: 1.0,
            explained: 0.5,
            units_improved: (8, 8),
            parts_improved: (8, 8),
            mean_log_ratio: 0.5,
            p_value: if significant { 0.004 } else { 0.3 },
            tested: true,
            significant,
            ranking,
            fitted: Vec::new(),
            evidence: String::new(),
            equivalent: Vec::new(),
            equivalent_to: None,
        }
    }

    fn names(n: &[&str]) -> Vec<String> {
        n.iter().map(|s| s.to_string()).collect()
    }

    /// `bend` named first gives way to a significant `sag` not yet in the model (a rival the data
    /// cannot tell from it goes first, the rivals stay named); a `sag` that is not significant
    /// leaves `bend` named and the rule says why; with `sag` in the model, or another effect
    /// leading, nothing changes.
    #[test]
    fn the_main_effect_is_named_before_its_refinement() {
        let model = ArmModel::suta_nominal();
        let scored = [candidate("bend", true), candidate("sag", true), candidate("eccentricity:2", true)];
        let (order, r) = main_first(&names(&["bend"]), &scored, &model);
        assert_eq!(order, names(&["sag"]));
        let r = r.expect("the rule applied");
        assert!(
            r.main_first
                && r.line().starts_with(
                    "bend is offered once sag is in the model: lateral compliance refines joint compliance"
                ),
            "{}",
            r.line()
        );
        let (order, _) = main_first(&names(&["bend", "sag"]), &scored, &model);
        assert_eq!(order, names(&["sag", "bend"]));
        let (order, _) = main_first(&names(&["bend", "eccentricity:2"]), &scored, &model);
        assert_eq!(order, names(&["sag"]), "eccentricity:2 was a rival of bend, not of sag");
        // Per joint: bend:3 waits for sag:3, which the library stands for by the whole sag.
        assert_eq!(main_first(&names(&["bend:3"]), &scored, &model).0, names(&["sag"]));

        let weak = [candidate("bend", true), candidate("sag", false)];
        let (order, r) = main_first(&names(&["bend"]), &weak, &model);
        assert_eq!(order, names(&["bend"]));
        let r = r.expect("the rule is stated");
        assert!(!r.main_first && r.line().starts_with("bend is named without sag"), "{}", r.line());
        assert_eq!(
            main_first(&names(&["bend"]), &scored[..1], &model).0,
            names(&["bend"]),
            "sag not determined"
        );

        let mut with_sag = model.clone();
        Effect::parse("sag").expect("sag").add_to(&mut with_sag);
        assert_eq!(main_first(&names(&["bend"]), &scored, &with_sag), (names(&["bend"]), None));
        assert_eq!(
            main_first(&names(&["eccentricity:2"]), &scored, &model),
            (names(&["eccentricity:2"]), None)
        );
    }
}
