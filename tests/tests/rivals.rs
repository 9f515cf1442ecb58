//! Rivals end to end, on data from the simulator's independent forward path: a 0.5 mm link
//! offset at joint 5 (the thesis placements, seed 4) moves the tool tip over these poses as an
//! eccentricity of encoder 6 does. The diagnosis names them together ("these data cannot tell
//! them apart"), never the wrong one alone, and points to `kincal plan`; measuring the two
//! placements the plan suggests, adding them to the calibration data and diagnosing again names
//! the link offset alone.

use kincal::calib::monte_carlo::simulate_and_diagnose;
use kincal::calib::plan::{rival_trial, RivalOutcome, TrialOptions};
use kincal::model::effects::Effect;
use kincal::model::{ArmModel, ParamId};

const SEED: u64 = 4;

fn hidden() -> Vec<(ParamId, f64)> {
    vec![(ParamId::parse("link_offset:5").unwrap(), 0.5)]
}

#[test]
fn rivals_the_data_cannot_tell_apart_are_named_together_and_the_planned_placements_resolve_them() {
    let d = simulate_and_diagnose(SEED, hidden()).unwrap();
    for line in &d.summary {
        eprintln!("  {line}");
    }
    assert!(d.named.len() >= 2, "rivals are expected here, not one effect: {:?}", d.summary);
    assert!(
        d.named.iter().any(|n| n == "link_offset:5"),
        "the true effect must be among the rivals: {:?}",
        d.named
    );
    let statement = d
        .summary
        .iter()
        .find(|l| l.contains("these data cannot tell them apart"))
        .unwrap_or_else(|| panic!("no rivals statement: {:?}", d.summary));
    assert!(statement.contains("link_offset:5") && statement.contains("eccentricity:6"), "{statement}");
    assert!(
        d.summary.iter().any(|l| l.starts_with("what to measure next") && l.contains("kincal plan")),
        "the next step must point to `kincal plan`: {:?}",
        d.summary
    );
    let (a, b) = (Effect::parse("link_offset:5").unwrap(), Effect::parse("eccentricity:6").unwrap());
    let trial = TrialOptions { seed: SEED, placements: 5, count: 2, random_draws: 0 };
    let o = rival_trial(&ArmModel::suta_nominal(), &hidden(), a, b, &trial).unwrap();
    eprintln!(
        "before {:?}, with the planned placements {:?}; separation {:?}",
        o.named_before, o.named_planned, o.separation
    );
    assert_eq!(o.named_before, d.named, "the trial starts from the same diagnosis");
    assert!(RivalOutcome::alone(&o.named_planned, a), "after the planned placements: {:?}", o.named_planned);
    assert!(o.separation.planned > o.separation.before, "{:?}", o.separation);
}
