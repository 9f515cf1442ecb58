//! Agreement with an independent peer: SciPy's least_squares(method='trf', loss='huber',
//! f_scale=1.35) on the same objective, from the same start, with its own numpy kinematics.
//! Needs python3 with numpy and scipy (`scripts/test.sh` installs them); set KINCAL_NO_PEER=1 to
//! skip it deliberately (the skip is printed).

use kincal::calib::fit::calibrate;
use kincal::calib::peer::{run_peer, thesis_sized_problem, write_peer_problem};
use kincal::calib::setup::SolveOptions;
use kincal::data::Observations;

#[test]
fn kincal_reaches_scipys_cost_or_lower() {
    if std::env::var_os("KINCAL_NO_PEER").is_some() {
        eprintln!("SKIPPED on request (KINCAL_NO_PEER): SciPy peer comparison");
        return;
    }
    let (nominal, sim) = thesis_sized_problem(2);
    let cal = Observations::from_sessions(&sim.calibration, &sim.artefact);
    let options = SolveOptions { restarts: Some(0), ..SolveOptions::default() };
    let fit = calibrate(&nominal, &cal, &options).expect("calibrates");
    let dir = std::env::temp_dir().join(format!("kincal-peer-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let problem = dir.join("problem.json");
    write_peer_problem(
        &problem,
        &nominal,
        &fit.estimated,
        &cal,
        fit.options.huber_delta_mm().unwrap_or_default(),
    )
    .unwrap();
    let peer = run_peer("python3", &problem).unwrap_or_else(|e| {
        panic!("{e}\ninstall the peer with `pip install numpy scipy`, or set KINCAL_NO_PEER=1")
    });
    std::fs::remove_dir_all(&dir).ok();
    eprintln!(
        "kincal cost {:.9}, SciPy cost {:.9} ({} evaluations, {:.0} ms)",
        fit.cost,
        peer.cost,
        peer.nfev,
        peer.seconds * 1e3
    );
    assert!(fit.cost <= peer.cost * (1.0 + 1e-6), "kincal cost {} is above SciPy's {}", fit.cost, peer.cost);
    for (k, id) in fit.estimated.iter().enumerate() {
        assert!(
            (fit.model.get(*id) - peer.x[k]).abs() < 1e-3,
            "{id}: kincal {} SciPy {}",
            fit.model.get(*id),
            peer.x[k]
        );
    }
}
