//! `kincal plan` against random placements on simulated data (the simulator's independent
//! forward path makes every measurement): the planned placements separate two rival effects
//! more, and shrink the weakest parameter's std more, than as many random reachable placements.
//! Lean (two seeds); `kincal bench --plan` prints the same over ten.

use kincal::calib::plan::{rival_trial, weak_trial, TrialOptions};
use kincal::model::effects::Effect;
use kincal::model::{ArmModel, ParamId};

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

#[test]
fn planned_placements_separate_rivals_better_than_random_ones() {
    let nominal = ArmModel::suta_nominal();
    let (a, b) = (Effect::parse("harmonic:3:3").unwrap(), Effect::parse("compliance:3").unwrap());
    let (mut planned, mut random) = (Vec::new(), Vec::new());
    for seed in 1..=2 {
        let trial = TrialOptions { seed, placements: 2, count: 2, random_draws: 2 };
        let o = rival_trial(&nominal, &[(ParamId::Harm3Sin(2), 0.006)], a, b, &trial).unwrap();
        eprintln!("seed {seed}: before {:.1}, planned {:.1}, random {:?}", o.before, o.planned, o.random);
        assert!(o.planned > o.before, "measuring more must separate more: {o:?}");
        planned.push(o.planned);
        random.push(mean(&o.random));
    }
    assert!(mean(&planned) > mean(&random), "planned {planned:?} vs random {random:?}");
}

#[test]
fn planned_placements_shrink_the_weakest_std_more_than_random_ones() {
    let nominal = ArmModel::suta_nominal();
    let (mut planned, mut random) = (Vec::new(), Vec::new());
    for seed in 1..=2 {
        let trial = TrialOptions { seed, placements: 2, count: 2, random_draws: 2 };
        let (name, o) = weak_trial(&nominal, &trial).unwrap();
        eprintln!(
            "seed {seed}: {name} before {:.4}, planned {:.4}, random {:?}",
            o.before, o.planned, o.random
        );
        assert!(o.planned < o.before, "{name}: {o:?}");
        planned.push(o.planned / o.before);
        random.push(mean(&o.random) / o.before);
    }
    assert!(mean(&planned) < mean(&random), "planned {planned:?} vs random {random:?}");
}
