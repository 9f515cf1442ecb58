//! Haptic calibration on recordings from the independent generator (`kincal_e2e::haptic_gen`).

use kincal_e2e::haptic_gen::{generate, GenOptions, Phantom, T2Mount};

#[test]
fn explore() {
    for (i, t2) in [T2Mount::Above, T2Mount::Below, T2Mount::Beside].into_iter().enumerate() {
        let dir = std::env::temp_dir().join(format!("kincal-hg-{i}"));
        let _ = std::fs::remove_dir_all(&dir);
        let truth =
            generate(&GenOptions { t2, phantom: Phantom::Omni, ..GenOptions::default() }, &dir).unwrap();
        let rec = kincal::haptic::recording::load(&dir);
        match rec {
            Err(e) => eprintln!("{t2:?}: load error {e}"),
            Ok(rec) => match kincal::haptic::pipeline::calibrate_recording(&rec) {
                Ok(r) => eprintln!("{t2:?}: delay {:.3} (truth {}), pos {:.3}->{:.3} (floor {:.3}), ori {:.3}->{:.3} (floor {:.3}) {:?}", r.delay_ms, truth.delay_ms, r.position_mm.before, r.position_mm.after, truth.floor_mm, r.orientation_deg.before, r.orientation_deg.after, truth.floor_deg, r.gimbal_model),
                Err(e) => eprintln!("{t2:?}: error {e}"),
            },
        }
    }
}
