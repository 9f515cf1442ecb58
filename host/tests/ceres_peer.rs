//! The Ceres peer (`bench/ceres/`) builds and reaches kincal's cost: `kincal bench --peers-check`
//! builds it with g++ against libceres-dev (`scripts/setup.sh` installs both) and solves, with
//! kincal and with Ceres, untimed: the thesis-sized artefact problem from the nominal start and
//! two of kincal's random restarts, a modified-DH artefact problem (a Hayati axis, a scale error,
//! a twist, a link offset and the tool's x) from two starts, and a 200-point tracker problem. It
//! fails when the peer does not build or run, when a start's initial cost differs (the peer's
//! kinematics, data or start is not kincal's), or when the costs or RMS differ by more than 1e-9
//! relative.

use std::process::Command;

#[test]
fn ceres_peer_builds_and_reaches_kincals_cost() {
    let out = Command::new(env!("CARGO_BIN_EXE_kincal"))
        .args(["bench", "--peers-check"])
        .output()
        .expect("kincal runs");
    let (stdout, stderr) = (String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(
        out.status.success(),
        "kincal bench --peers-check failed (scripts/setup.sh installs g++, libceres-dev and nlohmann-json3-dev):\n{stdout}\n{stderr}"
    );
    eprintln!("{stdout}");
    // Every start solved by both from the same point: 3 + 2.
    assert_eq!(stdout.matches("initial cost").count(), 5, "{stdout}");
    // Three agreements (two artefact problems, the tracker), each a relative difference in cost
    // and one in RMS.
    let differences: Vec<f64> = stdout
        .lines()
        .filter(|l| l.contains("relative difference"))
        .flat_map(|l| {
            l.split(['(', ')'])
                .filter_map(|part| part.trim_start_matches("relative difference ").trim().parse::<f64>().ok())
                .collect::<Vec<_>>()
        })
        .collect();
    assert_eq!(differences.len(), 6, "{stdout}");
    assert!(differences.iter().all(|d| *d <= 1e-9), "{differences:?}\n{stdout}");
}
