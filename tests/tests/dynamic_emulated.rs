//! The arm in motion on the emulated controller (QEMU): it follows a trajectory with direction
//! changes, its calibrated pose is served over OpenIGTLink and recorded by a client, and
//! simulated optical trackers of known latency (5, 12 and 20 ms), clock offset, drift, noise and
//! occlusions watch the true tool, which flexes under acceleration. The dynamic validation
//! recovers the latency within ±0.5 ms and the path error of the truth within its uncertainty,
//! and says where the error grows; `kincal dynamic` does the same from the recordings' files and
//! refuses bad options with clear errors.

use kincal::controller::demo::demo_truth;
use kincal::controller::emulator::Emulator;
use kincal::controller::motion::{record_motion, tracker_track, DEMO_CENTER_DEG};
use kincal::model::{ArmModel, ParamId};
use kincal::motion::recording::track_csv;
use kincal::motion::trajectory::Trajectory;
use kincal::motion::truth::against_truth;
use kincal::motion::{analyze, Category};
use kincal::simulate::optical::{record, OpticalOptions};
use kincal_e2e::{emulated_firmware, kincal_bin};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("kincal-dynamic-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn kincal(args: &[&str]) -> Output {
    Command::new(kincal_bin()).args(args).output().expect("kincal runs")
}

fn text(out: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr))
}

fn path(p: &Path) -> &str {
    p.to_str().expect("a UTF-8 temporary path")
}

#[test]
fn latency_and_dynamic_error_are_recovered_on_the_emulator() {
    let (_emulator, mut link) = Emulator::start(&emulated_firmware()).expect("QEMU starts");
    link.hello().unwrap();
    // The controller holds a calibration a little off the true arm (what a calibration leaves).
    let truth = demo_truth(&ArmModel::suta_nominal(), 2);
    let mut calibrated = truth.clone();
    calibrated.set(ParamId::Offset(1), truth.get(ParamId::Offset(1)) + 0.01);
    calibrated.tcp_mm[2] += 0.1;
    link.upload(&kincal_e2e::signed_set(&calibrated, 1)).unwrap();
    let trajectory = Trajectory::demo(DEMO_CENTER_DEG);
    let rec = record_motion(&mut link, &trajectory, "127.0.0.1:0", &mut |s| eprintln!("{s}")).unwrap();
    drop(link);
    // The OpenIGTLink client got every valid pose the host streamed, equal to it.
    let streamed_valid = rec.poses.iter().filter(|p| p.report.valid).count();
    eprintln!(
        "streamed {} poses ({streamed_valid} valid, link: {:?}); the client received {} ({} lost, {} unordered), worst {:?} µm",
        rec.poses.len(),
        rec.stream,
        rec.received.track.len(),
        rec.lost_by_client(),
        rec.received.unordered,
        rec.received_vs_streamed_um()
    );
    assert_eq!(rec.lost_by_client(), 0, "the OpenIGTLink client lost poses");
    assert!(rec.received_vs_streamed_um().is_some_and(|u| u < 1.0), "{:?}", rec.received_vs_streamed_um());
    assert!(rec.received.track.len() as f64 > 0.9 * trajectory.duration_s() * 768.0);
    let arm = rec.moving_arm(&truth);
    assert!((arm.tick_hz - 768.0).abs() < 1.0, "the controller's tick on the host clock: {} Hz", arm.tick_hz);
    let track = &rec.received.track;
    let received = kincal::motion::align::Path::new(&track.t_s, &track.p);
    let dir = scratch("files");
    for (seed, latency_ms) in [(1, 5.0), (2, 12.0), (3, 20.0)] {
        let o = OpticalOptions { latency_ms, flex_mm_per_m_s2: 0.3, seed, ..OpticalOptions::default() };
        let samples = record(&arm, track.t_s[0] + 0.2, track.t_s[track.len() - 1] - 0.2, &o);
        let tracker = tracker_track(&samples);
        let d = analyze(track, &tracker).unwrap();
        let lat = &d.latency;
        let err = (lat.mean_ms - latency_ms).abs();
        eprintln!(
            "latency {latency_ms} ms: measured {:.3} ± {:.3} ms; clock {:+.3} ± {:.3} ms (true {:+.1}); drift {:+.1} ± {:.1} ppm",
            lat.mean_ms,
            lat.u95_ms,
            d.clock_offset_at_start_ms,
            d.clock_offset_at_start_u95_ms,
            o.clock_offset_s * 1e3,
            d.clock.drift_ppm,
            d.clock.drift_u95_ppm
        );
        assert!(
            err < 0.5 && err <= lat.u95_ms,
            "latency {} ± {} ms, true {latency_ms}",
            lat.mean_ms,
            lat.u95_ms
        );
        let err = (d.clock_offset_at_start_ms - o.clock_offset_s * 1e3).abs();
        assert!(
            err <= d.clock_offset_at_start_u95_ms,
            "clock {} ± {}",
            d.clock_offset_at_start_ms,
            d.clock_offset_at_start_u95_ms
        );
        let rows = against_truth(&d, &|k| {
            let at = samples[k].taken_s;
            received.at(at).map(|reported| (arm.true_point(at, o.flex_mm_per_m_s2), reported))
        });
        for row in &rows {
            eprintln!(
                "  {:<48} {:>30}  true {:.3} mm",
                row.category.label(),
                row.measured.text(),
                row.truth_rms_mm
            );
            // The headline figures within their 95 % uncertainty, the others within 1.5 times it.
            let factor = if matches!(row.category, Category::All | Category::InMotion) { 1.0 } else { 1.5 };
            let ok = match (row.measured.rms_mm, row.measured.u95_mm) {
                (Some(rms), Some(u)) => (rms - row.truth_rms_mm).abs() <= factor * u,
                _ => row.agrees,
            };
            assert!(
                ok,
                "{:?}: measured {}, truth {:.3} mm",
                row.category,
                row.measured.text(),
                row.truth_rms_mm
            );
        }
        for what in ["in motion", "at direction changes"] {
            let grows = format!("the error grows {what}");
            assert!(d.findings.iter().any(|f| f.starts_with(&grows)), "{what}: {:?}", d.findings);
        }
        if latency_ms == 12.0 {
            std::fs::write(dir.join("arm.csv"), track_csv(track)).unwrap();
            std::fs::write(dir.join("tracker.csv"), track_csv(&tracker)).unwrap();
        }
    }

    // The command on the recordings' files: the same figures, a report page.
    let (arm_csv, tracker_csv, out) = (dir.join("arm.csv"), dir.join("tracker.csv"), dir.join("dynamic"));
    let run =
        kincal(&["dynamic", "--arm", path(&arm_csv), "--tracker", path(&tracker_csv), "--out", path(&out)]);
    let printed = text(&run);
    assert!(run.status.success(), "{printed}");
    assert!(printed.contains("latency of the tracker behind the arm: 1"), "{printed}");
    assert!(printed.contains("the error grows at direction changes"), "{printed}");
    let page = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(page.contains("<b>Latency</b>") && page.contains("<svg"), "the page leads with the verdict");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("dynamic.json")).unwrap()).unwrap();
    let latency = json["latency"]["mean_ms"].as_f64().unwrap();
    assert!((latency - 12.0).abs() < 0.5, "{latency}");

    // Bad options and inputs: errors naming the file, line, column or option.
    let same =
        kincal(&["dynamic", "--arm", path(&arm_csv), "--tracker", path(&arm_csv), "--out", path(&out)]);
    assert!(!same.status.success() && text(&same).contains("are the same file"), "{}", text(&same));
    let bad = dir.join("bad.csv");
    std::fs::write(&bad, "t_s,x_mm,y_mm\n1,2,3\n").unwrap();
    let missing = kincal(&["dynamic", "--arm", path(&arm_csv), "--tracker", path(&bad), "--out", path(&out)]);
    let said = text(&missing);
    assert!(!missing.status.success() && said.contains("bad.csv:1") && said.contains("z_mm"), "{said}");
    let absent = kincal(&[
        "dynamic",
        "--arm",
        path(&dir.join("none.csv")),
        "--tracker",
        path(&bad),
        "--out",
        path(&out),
    ]);
    assert!(!absent.status.success() && text(&absent).contains("none.csv"), "{}", text(&absent));
    let mine = dir.join("mine");
    std::fs::create_dir_all(&mine).unwrap();
    std::fs::write(mine.join("notes.txt"), "mine").unwrap();
    let refused =
        kincal(&["dynamic", "--arm", path(&arm_csv), "--tracker", path(&tracker_csv), "--out", path(&mine)]);
    assert!(!refused.status.success() && text(&refused).contains("did not write"), "{}", text(&refused));
    assert_eq!(std::fs::read_to_string(mine.join("notes.txt")).unwrap(), "mine");
    let no_out = kincal(&["dynamic", "--arm", path(&arm_csv), "--tracker", path(&tracker_csv)]);
    assert!(!no_out.status.success() && text(&no_out).contains("--out"), "{}", text(&no_out));
    std::fs::remove_dir_all(&dir).ok();
}
