use kincal::*;
fn main() {
    let nominal = model::ArmModel::suta_nominal();
    let t = std::time::Instant::now();
    let sim = simulate::simulate(&nominal, &simulate::SimulationOptions::default());
    println!("simulate {:?}, skipped {}", t.elapsed(), sim.skipped);
    let cal = data::Dataset::from_sessions(&sim.calibration, &sim.artefact);
    let val = data::Dataset::from_sessions(&sim.validation, &sim.artefact);
    println!("cal touches {} val touches {}", cal.touches.len(), val.touches.len());
    let t = std::time::Instant::now();
    let c = calibrate::calibrate(&nominal, &sim.artefact, &cal, &calibrate::CalibrationOptions::default()).unwrap();
    println!("calibrate {:?}", t.elapsed());
    for s in &c.starts { println!("{:?}", s); }
    println!("before unident: {:#?}", c.before.unidentifiable.iter().map(|x| &x.text).collect::<Vec<_>>());
    println!("before poor: {:#?}", c.before.poorly_identified.iter().map(|x| (&x.text, x.relative_singular_value)).collect::<Vec<_>>());
    println!("cond before {} after {}", c.before.condition_number, c.after.condition_number);
    for e in &c.estimates { println!("{} nominal {:.3} value {:.3} true {:.3} std {:?} {}", e.param, e.nominal, e.value, sim.truth.get(model::ParamId::parse(&e.param).unwrap()), e.std, e.status); }
    let vn = validate::validate(&nominal, &sim.artefact, &val).overall;
    let vc = validate::validate(&c.model, &sim.artefact, &val).overall;
    let vt = validate::validate(&sim.truth, &sim.artefact, &val).overall;
    println!("val nominal {:?}\nval calibrated {:?}\nval truth {:?}", vn, vc, vt);
    println!("cal rms {}", c.rms_mm);
}
