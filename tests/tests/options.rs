//! Every `kincal calibrate` and `kincal diagnose` option on both kinds of data: it works and its
//! effect shows in what the run writes, or it is refused naming the option and the kind of data.
//! Nothing is silently ignored. Artefact data: `kincal simulate`; tracker data: the independent
//! generator (three calibration sessions, one held out, times and temperatures, no σ column).

use kincal_e2e::kincal_bin;
use kincal_e2e::tracker_gen::{generate, TrackerOptions, UncertaintyColumn};
use kincal_e2e::tracker_setup::{nominal_model, scratch, split};
use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;

/// The two data sets and their calibrate arguments.
struct Data {
    dir: PathBuf,
}

impl Data {
    fn new() -> Data {
        let dir = scratch("options", "both");
        let suta = Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/suta/model.toml");
        std::fs::copy(suta, dir.join("suta.toml")).expect("model copied");
        let out = Command::new(kincal_bin())
            .args(["simulate", "--model", "suta.toml", "--out", "art"])
            .current_dir(&dir)
            .output()
            .expect("kincal runs");
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let mut options = TrackerOptions::iiwa_five_sessions(31).few_placements(4);
        options.uncertainty = UncertaintyColumn::None;
        options.time_columns = true;
        let generated = generate(&options);
        let tracker = dir.join("trk");
        std::fs::create_dir_all(&tracker).expect("folder");
        nominal_model(&generated, &tracker);
        split(&generated, &tracker, &[0, 1, 2]);
        Data { dir }
    }

    fn args(&self, kind: &str, out: &str, extra: &[&str]) -> Vec<String> {
        let base: &[&str] = match kind {
            "artefact" => &[
                "calibrate",
                "--model",
                "suta.toml",
                "--artefact",
                "art/artefact.json",
                "--data",
                "art/cal",
                "--validate",
                "art/val",
            ],
            _ => &["calibrate", "--model", "trk/nominal.toml", "--data", "trk/cal", "--validate", "trk/val"],
        };
        base.iter().chain(&["--out", out]).chain(extra).map(|s| s.to_string()).collect()
    }

    fn kincal(&self, args: &[String]) -> (bool, String, String) {
        let out = Command::new(kincal_bin()).args(args).current_dir(&self.dir).output().expect("kincal runs");
        let text = |b: &[u8]| String::from_utf8_lossy(b).into_owned();
        (out.status.success(), text(&out.stdout), text(&out.stderr))
    }

    /// Calibrate and read summary.json back.
    fn calibrate(&self, kind: &str, out: &str, extra: &[&str]) -> Value {
        let (ok, stdout, stderr) = self.kincal(&self.args(kind, out, extra));
        assert!(ok, "{kind} {extra:?}: {stdout}{stderr}");
        let text = std::fs::read_to_string(self.dir.join(out).join("summary.json")).expect("summary.json");
        serde_json::from_str(&text).expect("summary.json parses")
    }

    /// The option is refused, naming itself and the kind of data (or why it would change nothing).
    fn refused(&self, kind: &str, extra: &[&str], needles: &[&str]) {
        let (ok, _, stderr) = self.kincal(&self.args(kind, "refused", extra));
        assert!(!ok, "{kind} {extra:?} accepted");
        for needle in needles {
            assert!(stderr.contains(needle), "{kind} {extra:?}: {needle:?} not in {stderr}");
        }
        assert!(!stderr.contains("panicked") && !self.dir.join("refused").exists(), "{stderr}");
    }
}

fn f(v: &Value) -> f64 {
    v.as_f64().unwrap_or(f64::NAN)
}

#[test]
fn every_calibrate_and_diagnose_option_works_on_both_kinds_or_is_refused_naming_the_kind() {
    let data = Data::new();
    for kind in ["artefact", "tracker"] {
        let other = if kind == "artefact" { "tracker" } else { "artefact" };
        let base = data.calibrate(kind, &format!("{kind}-base"), &[]);
        let run = |name: &str, extra: &[&str]| data.calibrate(kind, &format!("{kind}-{name}"), extra);
        let obs = |s: &Value| s["calibration"]["observations"].as_u64().unwrap_or(0);
        let starts = |s: &Value| s["calibration"]["starts"].as_array().map_or(0, Vec::len);
        // --restarts and --seed: the starts drawn.
        let two = run("restarts", &["--restarts", "2"]);
        assert_eq!(starts(&two), 3, "{kind}: --restarts 2");
        let seeded = run("seed", &["--restarts", "2", "--seed", "7"]);
        assert_ne!(two["calibration"]["starts"][1], seeded["calibration"]["starts"][1], "{kind}: --seed");
        // --huber-delta-mm: the loss.
        let huber = run("huber", &["--huber-delta-mm", "0.01"]);
        assert_eq!(f(&huber["options"]["huber_delta_mm"]), 0.01, "{kind}");
        assert_ne!(huber["calibration"]["cost"], base["calibration"]["cost"], "{kind}: --huber-delta-mm");
        // --add: the effect's parameters are estimated.
        let added = run("add", &["--add", "compliance:2"]);
        let params: Vec<&str> = added["calibration"]["estimates"]
            .as_array()
            .expect("estimates")
            .iter()
            .filter_map(|e| e["param"].as_str())
            .collect();
        assert!(params.contains(&"compliance:2"), "{kind}: --add {params:?}");
        // --exclude-block and --exclude-point: observations left out.
        let (block, point) =
            if kind == "artefact" { ("A_O/1", "A_O/1/O") } else { ("session_1", "session_1:3") };
        let blocked = run("block", &["--exclude-block", block]);
        assert!(obs(&blocked) < obs(&base), "{kind}: --exclude-block");
        let pointed = run("point", &["--exclude-point", point]);
        assert_eq!(obs(&pointed) + 1, obs(&base), "{kind}: --exclude-point");
        // --float-tool: the group gets its own tool offset.
        let group = if kind == "artefact" { "A_O" } else { "session_2" };
        let floated = run("float", &["--float-tool", group]);
        assert_eq!(floated["calibration"]["tool_offsets"][0]["session"], group, "{kind}: --float-tool");
        // --study-subsets: the dataset-size study over calibration groups; --no-outliers: the
        // per-landmark or per-session outlier metrics skipped.
        let study = run("study", &["--study-subsets", "1"]);
        assert!(study["study"].as_array().is_some_and(|r| !r.is_empty()), "{kind}: --study-subsets");
        assert!(base["outliers"].as_array().is_some_and(|o| !o.is_empty()), "{kind}: outlier metrics");
        let quick = run("no-outliers", &["--no-outliers"]);
        assert_eq!(quick["outliers_skipped"], true, "{kind}: --no-outliers");
        assert!(quick["outliers"].as_array().is_some_and(|o| o.is_empty()), "{kind}: --no-outliers");
        // --objective distance is the default on both; --lever-mm needs six-dof.
        let distance = run("distance", &["--objective", "distance"]);
        assert_eq!(distance["calibration"]["rms_mm"], base["calibration"]["rms_mm"], "{kind}");
        data.refused(kind, &["--lever-mm", "50"], &["--lever-mm", "--objective six-dof"]);
        // --json prints summary.json.
        let (ok, stdout, _) = data.kincal(&data.args(kind, &format!("{kind}-json"), &["--json"]));
        let printed: Value = serde_json::from_str(&stdout).expect("--json prints JSON");
        assert!(ok && printed["calibration"]["rms_mm"] == base["calibration"]["rms_mm"], "{kind}: --json");
        // The options of one kind only: they work on it and are refused on the other.
        if kind == "artefact" {
            let landmark = run("landmark", &["--exclude-landmark", "S2"]);
            assert!(obs(&landmark) < obs(&base), "--exclude-landmark");
            let six = run("six-dof", &["--objective", "six-dof", "--lever-mm", "50"]);
            assert_eq!(six["options"]["objective"]["six_dof"]["lever_mm"], 50.0, "--objective six-dof");
            for (option, needle) in [
                (&["--sigma-mm", "0.02"][..], "--sigma-mm: not for artefact data"),
                (&["--orientation-sigma-deg", "0.01"], "--orientation-sigma-deg: not for artefact data"),
                (&["--drift-session", "A_O"], "--drift-session A_O:offset-time: not for artefact data"),
                (&["--same-base", "V_A=A_O"], "--same-base: not for artefact data"),
            ] {
                data.refused(kind, option, &[needle]);
            }
        } else {
            let stated = run("sigma", &["--sigma-mm", "0.02"]);
            let floor = &stated["floor"]["points"];
            assert_eq!(
                (floor["source"].as_str(), base["floor"]["points"]["source"].as_str()),
                (Some("stated uncertainty"), Some("unknown"))
            );
            let drift = run("drift", &["--drift-session", "session_2:offset-time"]);
            assert_eq!(drift["calibration"]["drifts"][0]["session"], "session_2", "--drift-session");
            let same = run("same-base", &["--same-base", "session_4=session_1"]);
            let figures = &same["validation"]["sessions"]["sessions"][0]["same_base"];
            assert_eq!(figures["calibration_session"], "session_1", "--same-base");
            for (option, needle) in [
                (&["--exclude-landmark", "S2"][..], "--exclude-landmark: not for tracker data"),
                (&["--objective", "six-dof"], "--objective six-dof: not for tracker data"),
                (&["--orientation-sigma-deg", "0.01"], "--orientation-sigma-deg: not for tracker data"),
            ] {
                data.refused(kind, option, &[needle]);
            }
        }
        let _ = other;
        // diagnose, --json, --auto, --max-steps on the run of this kind.
        let run_dir = format!("{kind}-base");
        let diagnose = |extra: &[&str]| {
            let args: Vec<String> =
                ["diagnose", run_dir.as_str()].iter().chain(extra).map(|s| s.to_string()).collect();
            let (ok, stdout, stderr) = data.kincal(&args);
            assert!(ok, "{kind} diagnose {extra:?}: {stderr}");
            stdout
        };
        assert!(diagnose(&[]).contains("diagnosis.html"), "{kind}: diagnose");
        let json: Value = serde_json::from_str(&diagnose(&["--json"])).expect("diagnose --json prints JSON");
        assert!(
            json["format"].as_str().is_some_and(|f| f.contains("diagnosis")),
            "{kind}: {}",
            json["format"]
        );
        let auto = diagnose(&["--auto", "--max-steps", "1"]);
        assert!(
            auto.contains("stopped after") && !auto.contains("   2  "),
            "{kind}: --auto --max-steps 1: {auto}"
        );
    }
    std::fs::remove_dir_all(&data.dir).ok();
}

/// `--float-tool` on an artefact placement measured with the tool re-mounted 3 mm off to the side
/// (its touches simulated with the true arm's tool point moved, every other placement as it was):
/// the floated offset finds the 3 mm, says that the component along the tool's axis is not
/// determined, and the held-out distances improve.
#[test]
fn a_floated_tool_finds_a_remounted_tool_in_an_artefact_placement() {
    use kincal::calib::run::run;
    use kincal::calib::setup::SolveOptions;
    use kincal::calib::summary::RunInputs;
    use kincal::model::{ArmModel, ParamId};
    use kincal::simulate::{simulate, SimulationOptions};
    let dir = scratch("options", "remount");
    let nominal = ArmModel::suta_nominal();
    simulate(&nominal, &SimulationOptions::default()).write(&dir).expect("written");
    let longer = SimulationOptions { hidden: vec![(ParamId::Tcp(0), 3.0)], ..SimulationOptions::default() };
    simulate(&nominal, &longer).write(&dir.join("longer")).expect("written");
    std::fs::copy(dir.join("longer/cal/C_A.json"), dir.join("cal/C_A.json")).expect("placement swapped");
    nominal.save(&dir.join("nominal.toml")).expect("saved");
    let inputs = RunInputs::new(
        dir.join("nominal.toml"),
        Some(dir.join("artefact.json")),
        dir.join("cal"),
        dir.join("val"),
    );
    let plain = run(&inputs, &SolveOptions::default(), 0, true).expect("runs");
    let floated = RunInputs { float_tool: vec!["C_A".into()], ..inputs.clone() };
    let fixed = run(&floated, &SolveOptions::default(), 0, true).expect("runs");
    let tool = &fixed.summary.calibration.tool_offsets[0];
    let held_out = |r: &kincal::calib::run::Run| r.summary.held_out_rms_mm();
    println!(
        "C_A's tool offset {:?} ± {:.3} mm; held out {:.4} → {:.4} mm",
        tool.offset_mm,
        tool.size_std_mm,
        held_out(&plain),
        held_out(&fixed)
    );
    assert_eq!(tool.session, "C_A");
    assert!((tool.offset_mm[0] - 3.0).abs() < 0.3 && tool.offset_mm[1].abs() < 0.3, "{tool:?}");
    // Along the tool's own axis the distances of one placement hardly see a re-mount: said so.
    assert!(tool.determined(0) && tool.determined(1) && !tool.determined(2), "{tool:?}");
    assert!(held_out(&fixed) < 0.8 * held_out(&plain), "{} vs {}", held_out(&fixed), held_out(&plain));
    std::fs::remove_dir_all(dir).ok();
}
