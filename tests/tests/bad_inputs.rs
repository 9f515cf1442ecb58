//! The bad-input corpus (issue 11): valid simulated data, mutated the ways a careless or unlucky
//! user mutates it, run through every command. Each case's outcome is asserted: the expected
//! error (naming the file, field or option and what was expected) or the expected success, and
//! for all: no panic, no hang, no exit 0 with a non-finite or absurd figure, no user file lost or
//! changed, no staging folder left. Cases run in parallel, each in its own copy of the inputs.

use kincal_e2e::corpus::{
    all, assert_all_pass, copy_tree, edit_json, replace, unchanged, words, write, Case, Check, Expect, Setup,
};
use kincal_e2e::kincal_bin;
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

/// The input options every calibrate and study case starts from.
const INPUTS: &[&str] = &[
    "--model",
    "model.toml",
    "--artefact",
    "data/artefact.json",
    "--data",
    "data/cal",
    "--validate",
    "data/val",
];

/// `kincal calibrate` on the valid inputs into `out/`.
fn cal() -> Vec<&'static str> {
    [&["calibrate"], INPUTS, &["--restarts", "1", "--out", "out"]].concat()
}

/// `kincal study` on the valid inputs into `study/`.
fn study() -> Vec<&'static str> {
    [&["study"], INPUTS, &["--subsets", "2", "--out", "study"]].concat()
}

const SIM: &[&str] = &["simulate", "--model", "model.toml", "--out", "sim", "--repeats", "1"];

fn example_model() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/suta/model.toml")
}

fn kincal(dir: &Path, args: &[&str]) {
    let out = Command::new(kincal_bin()).args(args).current_dir(dir).output().unwrap();
    assert!(out.status.success(), "kincal {args:?}: {}", String::from_utf8_lossy(&out.stderr));
}

/// The valid inputs every case starts from: model.toml, model.json, data/ (simulated, seed 1),
/// other-arm/ (validation sessions of another arm and artefact, seed 2), run/ (a RUN of data/,
/// diagnosed).
fn template(root: &Path) -> PathBuf {
    let t = root.join("template");
    std::fs::create_dir_all(&t).unwrap();
    std::fs::copy(example_model(), t.join("model.toml")).unwrap();
    kincal::model::ArmModel::load(&example_model()).unwrap().save(&t.join("model.json")).unwrap();
    kincal(&t, &["simulate", "--model", "model.toml", "--out", "data"]);
    kincal(&t, &["simulate", "--model", "model.toml", "--out", "other", "--seed", "2"]);
    // The data are the user's now: no kincal marker, so nothing in them may ever be replaced.
    std::fs::remove_file(t.join("data/.kincal-output")).unwrap();
    copy_tree(&t.join("other/val"), &t.join("other-arm"));
    std::fs::remove_dir_all(t.join("other")).unwrap();
    let run: Vec<&str> = cal().into_iter().map(|s| if s == "out" { "run" } else { s }).collect();
    kincal(&t, &run);
    kincal(&t, &["diagnose", "run"]);
    tracker_template(&t);
    t
}

/// tracker/: a 7-joint model and generated tracker sessions (the independent generator, seed 1),
/// three to calibrate and two held out.
fn tracker_template(t: &Path) {
    use kincal_e2e::tracker_gen::{generate, TrackerOptions};
    let generated = generate(&TrackerOptions::iiwa_five_sessions(1));
    let dir = t.join("tracker");
    generated.write(&dir.join("all")).unwrap();
    for (k, set) in ["cal", "cal", "cal", "val", "val"].iter().enumerate() {
        std::fs::create_dir_all(dir.join(set)).unwrap();
        let name = format!("session_{}.csv", k + 1);
        std::fs::rename(dir.join("all").join(&name), dir.join(set).join(&name)).unwrap();
    }
    std::fs::remove_dir_all(dir.join("all")).unwrap();
    std::fs::write(dir.join("model.toml"), generated.options.arm.kincal_model_toml().unwrap()).unwrap();
    let mut model = kincal::model::ArmModel::load(&dir.join("model.toml")).unwrap();
    model.free_every_dh_value(5.0, 10.0);
    model.save(&dir.join("model.toml")).unwrap();
    // The same arm as URDF (joint_N at line 6 + 8·(N − 1)) and the model from-urdf makes of it.
    generated.options.arm.write_urdf(&dir.join("robot.urdf"), "iiwa7").unwrap();
    kincal(
        t,
        &[
            "model",
            "from-urdf",
            "tracker/robot.urdf",
            "--base",
            "base_link",
            "--tip",
            "tool0",
            "--out",
            "tracker/urdf_model.toml",
        ],
    );
    // A tracker RUN, read back by diagnose and compare (issue 27).
    let run: Vec<String> =
        tracker_cal(&[]).into_iter().map(|a| if a == "tout" { "trun".into() } else { a }).collect();
    kincal(t, &run.iter().map(String::as_str).collect::<Vec<_>>());
}

/// `kincal calibrate` on the tracker sessions into `tout/`, with `extra` options.
fn tracker_cal(extra: &[&str]) -> Vec<String> {
    words(
        &[
            "calibrate",
            "--model",
            "tracker/model.toml",
            "--data",
            "tracker/cal",
            "--validate",
            "tracker/val",
            "--out",
            "tout",
        ],
        extra,
    )
}

/// The tracker model with its first `[[joint]]` row repeated until it has 13 (one more than
/// kincal takes).
fn thirteen_joint_model() -> Setup {
    Box::new(|dir| {
        let path = dir.join("tracker/model.toml");
        let text = std::fs::read_to_string(&path).unwrap();
        let joints = text.matches("[[joint]]").count();
        let start = text.find("[[joint]]").unwrap();
        let end = start + 1 + text[start + 1..].find("[[").unwrap();
        let row = &text[start..end];
        std::fs::write(&path, format!("{}{}{}", &text[..start], row.repeat(13 - joints), &text[start..]))
            .unwrap();
    })
}

/// `q1_deg,…,qN_deg`.
fn joint_columns(n: usize) -> String {
    (1..=n).map(|j| format!("q{j}_deg")).collect::<Vec<_>>().join(",")
}

/// A URDF chain `link_0` … `link_N` of N revolute joints about z, 100 mm apart.
fn urdf_chain(n: usize) -> String {
    let links: String = (0..=n).map(|k| format!("<link name=\"link_{k}\"/>")).collect();
    let joints: String = (1..=n)
        .map(|k| {
            format!(
                "<joint name=\"j{k}\" type=\"revolute\"><parent link=\"link_{}\"/><child link=\"link_{k}\"/>\
                 <origin xyz=\"0 0 0.1\" rpy=\"0 0 0\"/><axis xyz=\"0 0 1\"/>\
                 <limit lower=\"-3\" upper=\"3\" effort=\"1\" velocity=\"1\"/></joint>",
                k - 1
            )
        })
        .collect();
    format!("<?xml version=\"1.0\"?>\n<robot name=\"r13\">{links}{joints}</robot>\n")
}

/// Replace line `line` (1-based) of `file` by `edit` of it.
fn csv_line(file: &'static str, line: usize, edit: impl Fn(&str) -> String + Send + Sync + 'static) -> Setup {
    Box::new(move |dir| {
        let path = dir.join(file);
        let text = std::fs::read_to_string(&path).unwrap();
        let lines: Vec<String> = text
            .lines()
            .enumerate()
            .map(|(k, l)| if k + 1 == line { edit(l) } else { l.to_string() })
            .collect();
        std::fs::write(&path, lines.join("\n") + "\n").unwrap();
    })
}

/// Replace cell `cell` (0-based) of line `line` of `file` by `value`.
fn csv_cell(file: &'static str, line: usize, cell: usize, value: &'static str) -> Setup {
    csv_line(file, line, move |l| {
        let mut cells: Vec<&str> = l.split(',').collect();
        cells[cell] = value;
        cells.join(",")
    })
}

/// Edit the text of `file` through `edit`.
fn edit_text(file: &'static str, edit: impl Fn(&str) -> String + Send + Sync + 'static) -> Setup {
    Box::new(move |dir| {
        let path = dir.join(file);
        let text = std::fs::read_to_string(&path).unwrap();
        std::fs::write(&path, edit(&text)).unwrap();
    })
}

/// Bad tracker CSVs beyond single cells: headers, encodings, whole files, folders, drift options.
fn tracker_file_cases(cases: &mut Vec<Case>) {
    const S1: &str = "tracker/cal/session_1.csv";
    const HEADER: &str = "pose,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,q7_deg,x_mm,y_mm,z_mm";
    let fails = |what: &str, setup: Setup, extra: &[&str], needles: &[&str]| {
        Case::fails(&format!("tracker/{what}"), setup, tracker_cal(extra), needles)
    };
    let passes = |what: &str, setup: Setup| {
        Case::succeeds(&format!("tracker/{what}"), setup, tracker_cal(&[]), exists("tout/summary.json"))
    };
    cases.extend([
        fails(
            "a joint column missing in the middle",
            csv_line(S1, 2, |l| l.replace("q3_deg", "q3")),
            &[],
            &["session_1.csv:2: column `q3_deg`", "q4_deg is there", "without a gap"],
        ),
        fails(
            "qw and qx without qy and qz",
            write(S1, &format!("# kincal-tracker/1\n{HEADER},qw,qx\n1,0,0,0,0,0,0,0,100,0,0,1,0\n")),
            &[],
            &["session_1.csv:2: column `qy`", "needs all of qw, qx, qy, qz"],
        ),
        fails(
            "a quaternion that is not unit",
            write(
                S1,
                &format!("# kincal-tracker/1\n{HEADER},qw,qx,qy,qz\n1,0,0,0,0,0,0,0,100,0,0,1,0,0,0.5\n"),
            ),
            &[],
            &["session_1.csv:3: column `qw`", "unit quaternion"],
        ),
        fails(
            "sigma_mm and u95_mm both",
            csv_line(S1, 2, |l| l.replace("sigma_mm", "sigma_mm,u95_mm")),
            &[],
            &["session_1.csv:2: column `u95_mm`", "not both"],
        ),
        fails(
            "a negative u95_mm",
            all(vec![csv_line(S1, 2, |l| l.replace("sigma_mm", "u95_mm")), csv_cell(S1, 4, 11, "-0.04")]),
            &[],
            &["session_1.csv:4: column `u95_mm`", "<= value < 100 mm"],
        ),
        fails(
            "a NaN sigma_mm",
            csv_cell(S1, 6, 11, "nan"),
            &[],
            &["session_1.csv:6: column `sigma_mm`", "finite"],
        ),
        fails(
            "an infinite joint angle",
            csv_cell(S1, 8, 4, "-inf"),
            &[],
            &["session_1.csv:8: column `q4_deg`", "finite"],
        ),
        fails(
            "a session of 2 points",
            write(
                S1,
                &format!("# kincal-tracker/1\n{HEADER}\n1,0,0,0,0,0,0,0,100,0,0\n2,10,0,0,0,0,0,0,0,200,0\n"),
            ),
            &[],
            &["session_1.csv: session \"session_1\" has 2 points", "at least 3"],
        ),
        fails(
            "the header twice",
            edit_text(S1, |t| t.replacen(HEADER, &format!("{HEADER},sigma_mm\n{HEADER}"), 1)),
            &[],
            &["session_1.csv:3: column `q1_deg`", "expected a number, found \"q1_deg\""],
        ),
        fails("an empty file", write(S1, ""), &[], &["session_1.csv:1: column `format`", "kincal-tracker/1"]),
        fails(
            "semicolons for commas",
            edit_text(S1, |t| t.replace(',', ";")),
            &[],
            &["session_1.csv:2: column `q1_deg`", "missing"],
        ),
        fails(
            "decimal commas",
            csv_line(S1, 5, |l| l.replace('.', ",")),
            &[],
            &["session_1.csv:5:", "expected 12 cells as in the header"],
        ),
        fails(
            "an untagged CSV among the sessions",
            write("tracker/cal/notes.csv", "when,who\nmonday,ana\n"),
            &[],
            &["notes.csv:1: column `format`", "expected the tag line \"# kincal-tracker/1\""],
        ),
        fails(
            "no session tagged",
            all([S1, "tracker/cal/session_2.csv", "tracker/cal/session_3.csv"]
                .map(|f| csv_line(f, 1, |_| String::new()))
                .into()),
            &[],
            &["--artefact is required", "tracker/cal holds no tracker sessions", "# kincal-tracker/1"],
        ),
        fails(
            "joint angles in radians (ROS joint_states) under q1_deg",
            edit_text(S1, |t| joints_in_radians(t, false)),
            &[],
            &["session_1.csv:2: column `q1_deg`", "within ±2π", "radians", "q1_rad … q7_rad"],
        ),
        passes(
            "joint angles in radians under q1_rad … q7_rad",
            edit_text(S1, |t| joints_in_radians(t, true)),
        ),
        passes("a byte-order mark", edit_text(S1, |t| format!("\u{feff}{t}"))),
        passes("CRLF line ends", edit_text(S1, |t| t.replace('\n', "\r\n"))),
        fails(
            "--drift-session with an unknown kind",
            unchanged(),
            &["--drift-session", "session_1:scael-temp"],
            &[
                "--drift-session",
                "\"scael-temp\" is not a drift kind",
                "offset-time, scale-time, offset-temp, scale-temp",
            ],
        ),
        fails(
            "--drift-session without time_s",
            unchanged(),
            &["--drift-session", "session_1"],
            &["--drift-session session_1:offset-time", "session_1.csv:3 has no time_s"],
        ),
        fails(
            "--drift-session scale-temp without temp_C",
            unchanged(),
            &["--drift-session", "session_2:scale-temp"],
            &["session_2.csv:3 has no temp_C"],
        ),
        fails(
            "--drift-session twice for one session",
            unchanged(),
            &["--drift-session", "session_1", "--drift-session", "session_1:scale-time"],
            &["--drift-session session_1", "named twice"],
        ),
        fails(
            "--drift-session of no session",
            unchanged(),
            &["--drift-session", "session_9:scale-time"],
            &["--drift-session session_9:scale-time", "no calibration session"],
        ),
    ]);
}

/// A tracker CSV with its seven joint columns in radians, as ROS `joint_states` gives them; the
/// header renamed to `qN_rad` when `rename`.
fn joints_in_radians(text: &str, rename: bool) -> String {
    let mut lines = text.lines();
    let mut out = format!("{}\n", lines.next().unwrap_or_default());
    let header = lines.next().unwrap_or_default();
    out += &if rename { header.replace("_deg", "_rad") } else { header.to_string() };
    out.push('\n');
    for line in lines {
        let cells: Vec<String> = line
            .split(',')
            .enumerate()
            .map(|(c, v)| match (c, v.parse::<f64>()) {
                (1..=7, Ok(deg)) => format!("{:.9}", deg.to_radians()),
                _ => v.to_string(),
            })
            .collect();
        out += &cells.join(",");
        out.push('\n');
    }
    out
}

/// `kincal model from-urdf` on the template's URDF into m.toml, with other words.
fn from_urdf(extra: &[&str]) -> Vec<String> {
    words(&["model", "from-urdf", "tracker/robot.urdf", "--out", "m.toml"], extra)
}

const CHAIN: &[&str] = &["--base", "base_link", "--tip", "tool0"];

/// Replace the `nth` (1-based) occurrence of `from` in `file` by `to`.
fn replace_nth(file: &'static str, nth: usize, from: &'static str, to: &'static str) -> Setup {
    edit_text(file, move |t| {
        let at = t
            .match_indices(from)
            .nth(nth - 1)
            .map(|m| m.0)
            .unwrap_or_else(|| panic!("{file}: no {from:?} #{nth}"));
        format!("{}{to}{}", &t[..at], &t[at + from.len()..])
    })
}

/// Bad URDFs for `kincal model from-urdf` and models that do not match for `to-urdf`.
fn urdf_cases(cases: &mut Vec<Case>) {
    const U: &str = "tracker/robot.urdf";
    let fails = |what: &str, setup: Setup, args: Vec<String>, needles: &[&str]| {
        Case::fails(&format!("urdf/{what}"), setup, args, needles)
    };
    let before_end =
        |xml: &'static str| edit_text(U, move |t| t.replace("</robot>", &format!("{xml}</robot>")));
    let thirteen = {
        let mut xml = String::from("<robot name=\"long\"><link name=\"l0\"/>");
        for j in 1..=13 {
            xml += &format!("<link name=\"l{j}\"/><joint name=\"j{j}\" type=\"revolute\"><parent link=\"l{}\"/><child link=\"l{j}\"/><origin xyz=\"0 0 0.1\"/><axis xyz=\"0 0 1\"/></joint>", j - 1);
        }
        xml + "</robot>"
    };
    let axis_of_joint_2 = Box::new(|dir: &Path| {
        let model = kincal::model::ArmModel::load(&dir.join("m.toml")).map_err(|e| e.to_string())?;
        (model.joints.len() == 7 && model.joints[1].axis == [1.0, 0.0, 0.0])
            .then_some(())
            .ok_or(format!("joint 2 turns about {:?}, URDF's default axis is x", model.joints[1].axis))
    });
    let to_urdf = |model: &str| words(&["model", "to-urdf", model, "--urdf", U, "--out", "c.urdf"], CHAIN);
    cases.extend([
        Case::succeeds("urdf/valid chain", unchanged(), from_urdf(CHAIN), exists("m.toml")),
        Case::succeeds("urdf/a continuous joint", replace_nth(U, 3, "\"revolute\"", "\"continuous\""), from_urdf(CHAIN), exists("m.toml")),
        Case::succeeds("urdf/a joint without axis is about x", replace_nth(U, 2, "<axis xyz=\"0 0 1\"/>", ""), from_urdf(CHAIN), Some(axis_of_joint_2)),
        fails("not XML", write(U, "joint_1: revolute\n"), from_urdf(CHAIN), &["robot.urdf", "not a URDF robot description"]),
        fails("an empty file", write(U, ""), from_urdf(CHAIN), &["robot.urdf", "not a URDF robot description"]),
        fails("no such file", unchanged(), words(&["model", "from-urdf", "tracker/nothing.urdf", "--out", "m.toml"], CHAIN), &["nothing.urdf"]),
        fails("a prismatic joint in the chain", replace_nth(U, 1, "\"revolute\"", "\"prismatic\""), from_urdf(CHAIN), &["robot.urdf:6: <joint name=\"joint_1\">", "Prismatic", "kincal calibrates revolute (or continuous) joints"]),
        fails("a floating joint in the chain", replace_nth(U, 3, "\"revolute\"", "\"floating\""), from_urdf(CHAIN), &["robot.urdf:22: <joint name=\"joint_3\">", "Floating"]),
        fails("a planar joint in the chain", replace_nth(U, 7, "\"revolute\"", "\"planar\""), from_urdf(CHAIN), &["robot.urdf:54: <joint name=\"joint_7\">", "Planar"]),
        fails("--base not in the file", unchanged(), from_urdf(&["--base", "world", "--tip", "tool0"]), &["robot.urdf", "<link name=\"world\">", "no such link (--base)", "base_link, link_1"]),
        fails("--tip not in the file", unchanged(), from_urdf(&["--base", "base_link", "--tip", "tool1"]), &["<link name=\"tool1\">", "no such link (--tip)"]),
        fails("--tip above --base", unchanged(), from_urdf(&["--base", "link_3", "--tip", "link_1"]), &["robot.urdf", "not below --base link_3"]),
        fails("a link with two parents", before_end("<joint name=\"extra\" type=\"fixed\"><parent link=\"base_link\"/><child link=\"link_3\"/></joint>\n"), from_urdf(CHAIN), &["robot.urdf:", "<joint name=\"extra\">", "link_3 is the child of joint joint_3 too", "one parent joint"]),
        fails("a loop", before_end("<link name=\"world\"/><joint name=\"back\" type=\"fixed\"><parent link=\"link_2\"/><child link=\"base_link\"/></joint>\n"), from_urdf(&["--base", "world", "--tip", "tool0"]), &["robot.urdf:", "the joints form a loop"]),
        fails("a zero axis", replace_nth(U, 2, "<axis xyz=\"0 0 1\"/>", "<axis xyz=\"0 0 0\"/>"), from_urdf(CHAIN), &["robot.urdf:14: <joint name=\"joint_2\">/<axis>", "not a direction"]),
        fails("four origin values", replace_nth(U, 4, "<origin xyz=\"", "<origin xyz=\"nan "), from_urdf(CHAIN), &["robot.urdf", "expected 3 found 4"]),
        fails("a NaN origin value", replace_nth(U, 4, " rpy=\"", " rpy=\"NaN 0 0\" a=\""), from_urdf(CHAIN), &["robot.urdf:30: <joint name=\"joint_4\">/<origin>", "finite"]),
        fails("13 revolute joints", write(U, &thirteen), from_urdf(&["--base", "l0", "--tip", "l13"]), &["robot.urdf", "chain l0 → l13", "expected 1 to 12 revolute joints, found 13"]),
        fails("no revolute joint between base and tip", unchanged(), from_urdf(&["--base", "flange", "--tip", "tool0"]), &["chain flange → tool0", "found 0"]),
        Case::succeeds("urdf/to-urdf of its model", unchanged(), to_urdf("tracker/urdf_model.toml"), exists("c.urdf")),
        fails("to-urdf of a DH model", unchanged(), to_urdf("tracker/model.toml"), &["robot.urdf", "the model is not this chain", "7 Classic joints"]),
        fails("to-urdf of the six-joint SUTA model", unchanged(), to_urdf("model.toml"), &["the model is not this chain", "6 Classic joints", "7 revolute joints"]),
        fails("to-urdf into another URDF", replace_nth(U, 4, "<axis xyz=\"0 0 1\"/>", "<axis xyz=\"0 1 0\"/>"), to_urdf("tracker/urdf_model.toml"), &["robot.urdf:30: <joint name=\"joint_4\">/<axis>", "the model's joint 4 turns about", "not made from this chain"]),
        fails("to-urdf over its own URDF", unchanged(), words(&["model", "to-urdf", "tracker/urdf_model.toml", "--urdf", U, "--out", U], CHAIN), &["tracker/robot.urdf", "--out", "is the same file as the input tracker/robot.urdf"]),
    ]);
}

fn tracker_cases(cases: &mut Vec<Case>) {
    const S1: &str = "tracker/cal/session_1.csv";
    const V4: &str = "tracker/val/session_4.csv";
    cases.push(Case::succeeds(
        "tracker/valid sessions",
        unchanged(),
        tracker_cal(&[]),
        Some(Box::new(|dir: &Path| {
            let s: Value = serde_json::from_str(
                &std::fs::read_to_string(dir.join("tout/summary.json")).map_err(|e| e.to_string())?,
            )
            .map_err(|e| e.to_string())?;
            let rms = s["validation"]["sessions"]["sessions"][0]["rms_mm"]
                .as_f64()
                .ok_or("no validation.sessions.sessions[0].rms_mm")?;
            (rms > 0.0 && rms < 1.0).then_some(()).ok_or(format!("held-out RMS {rms}"))
        })),
    ));
    for (what, cell, value, needles) in [
        (
            "a joint angle that is not a number",
            1,
            "abc",
            &["session_1.csv:5: column `q1_deg`", "expected a number"][..],
        ),
        ("a NaN coordinate", 8, "NaN", &["session_1.csv:5: column `x_mm`", "finite"][..]),
        ("an infinite coordinate", 9, "inf", &["session_1.csv:5: column `y_mm`", "finite"][..]),
        (
            "a coordinate in micrometres",
            10,
            "1e9",
            &["session_1.csv:5: column `z_mm`", "beyond any tracker"][..],
        ),
        ("an empty joint angle", 7, "", &["session_1.csv:5: column `q7_deg`", "expected a number"][..]),
        (
            "joint angles in hundredths of a degree",
            3,
            "12000",
            &["session_1.csv:5: column `q3_deg`", "ten turns"][..],
        ),
        ("a negative sigma", 11, "-0.02", &["session_1.csv:5: column `sigma_mm`", "<= value < 100 mm"][..]),
        (
            "a zero sigma (a zero floor)",
            11,
            "0",
            &["session_1.csv:5: column `sigma_mm`", "0.0001 <= value", "zero floor"][..],
        ),
        (
            "a sigma of 1e-300 mm",
            11,
            "1e-300",
            &["session_1.csv:5: column `sigma_mm`", "0.0001 <= value"][..],
        ),
    ] {
        cases.push(Case::fails(
            &format!("tracker/{what}"),
            csv_cell(S1, 5, cell, value),
            tracker_cal(&[]),
            needles,
        ));
    }
    let fails = |what: &str, setup: Setup, extra: &[&str], needles: &[&str]| {
        Case::fails(&format!("tracker/{what}"), setup, tracker_cal(extra), needles)
    };
    cases.extend([
        fails("no tag line", csv_line(S1, 1, |_| "# some export".into()), &[], &["session_1.csv:1: column `format`", "kincal-tracker/1"]),
        fails("a short row", csv_line(S1, 7, |l| l.rsplit_once(',').map_or(String::new(), |(a, _)| a.to_string())), &[], &["session_1.csv:7:", "cells"]),
        fails("x_mm renamed", csv_line(S1, 2, |l| l.replace("x_mm", "X")), &[], &["session_1.csv:2: column `x_mm`", "missing"]),
        fails("a column named twice", csv_line(S1, 2, |l| l.replace("y_mm", "x_mm")), &[], &["session_1.csv:2: column `x_mm`", "twice"]),
        fails("no joint columns", csv_line(S1, 2, |l| l.replace("q1_deg", "joint1")), &[], &["session_1.csv:2: column `q1_deg`", "missing"]),
        fails("only the header", write(S1, "# kincal-tracker/1\npose,q1_deg,x_mm,y_mm,z_mm\n"), &[], &["session_1.csv", "no data rows"]),
        fails(
            "points in metres",
            write(S1, "# kincal-tracker/1\nq1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg,q7_deg,x_mm,y_mm,z_mm\n0,0,0,0,0,0,0,0.1,0,0\n10,0,0,0,0,0,0,0.2,0,0\n20,0,0,0,0,0,0,0.3,0,0\n30,0,0,0,0,0,0,0.4,0.1,0\n"),
            &[],
            &["session_1.csv:3", "metres"],
        ),
        fails(
            "another joint count in one file",
            write(S1, "# kincal-tracker/1\nq1_deg,q2_deg,x_mm,y_mm,z_mm\n0,0,100,0,0\n10,0,0,200,0\n20,5,0,0,300\n"),
            &[],
            &["session_2.csv:3: column `q3_deg`", "joints here"],
        ),
        fails("a model of another joint count", unchanged(), &[], &["7 joint columns", "the model has 6 joints"]).with_args(words(
            &["calibrate", "--model", "model.toml", "--data", "tracker/cal", "--validate", "tracker/val", "--out", "tout"],
            &[],
        )),
        fails("a model of 13 joints", thirteen_joint_model(), &[], &["model.toml", "expected 1 to 12 [[joint]] rows", "found 13"]),
        fails(
            "13 joint columns",
            write(S1, &format!("# kincal-tracker/1\n{},x_mm,y_mm,z_mm\n{}100,0,0\n", joint_columns(13), "0,".repeat(13))),
            &[],
            &["session_1.csv:2: column `q13_deg`", "at most 12 joints"],
        ),
        fails("a URDF of 13 revolute joints", write("robot13.urdf", &urdf_chain(13)), &[], &["robot13.urdf", "expected 1 to 12 revolute joints, found 13"]).with_args(words(
            &["model", "from-urdf", "robot13.urdf", "--base", "link_0", "--tip", "link_13", "--out", "m13.toml"],
            &[],
        )),
        fails("--float-tool of no session", unchanged(), &["--float-tool", "session_9"], &["--float-tool / --drift-session session_9", "no calibration session"]),
        fails("--sigma-mm NaN", unchanged(), &["--sigma-mm", "NaN"], &["--sigma-mm"]),
        fails("--sigma-mm 0 (a zero floor)", unchanged(), &["--sigma-mm", "0"], &["--sigma-mm"]),
        fails("--sigma-mm 1e-300", unchanged(), &["--sigma-mm", "1e-300"], &["--sigma-mm"]),
        // Issue 27: what users get wrong, each refused naming the file, line, column or option.
        fails(
            "a time_s of 1e300 with --drift-session",
            edit_text(S1, |t| {
                t.lines()
                    .enumerate()
                    .map(|(k, l)| match k {
                        0 => l.to_string(),
                        1 => format!("{l},time_s"),
                        4 => format!("{l},1e300"),
                        _ => format!("{l},{}", 10 * k),
                    })
                    .collect::<Vec<_>>()
                    .join("\n")
                    + "\n"
            }),
            &["--drift-session", "session_1"],
            &["session_1.csv:5: column `time_s`", "another unit"],
        ),
        fails(
            "one pose id on two poses",
            csv_cell(V4, 5, 0, "1"),
            &[],
            &["session_4.csv:5: column `pose`", "pose id 1", "line 3", "give each pose its own id"],
        ),
        fails(
            "a held-out session of 2 points",
            edit_text(V4, |t| t.lines().take(4).map(|l| format!("{l}\n")).collect()),
            &[],
            &["session_4.csv", "held-out session session_4 has 2 points", "at least 3", "--same-base"],
        ),
        fails(
            "a held-out session of 1 point",
            edit_text(V4, |t| t.lines().take(3).map(|l| format!("{l}\n")).collect()),
            &[],
            &["session_4.csv", "held-out session session_4 has 1 point:"],
        ),
        fails(
            "--float-tool on every calibration session",
            unchanged(),
            &["--float-tool", "session_1", "--float-tool", "session_2", "--float-tool", "session_3"],
            &["--float-tool", "every calibration session floats its tool", "session_1, session_2, session_3"],
        ),
        fails("--add compliance:8 on a 7-joint arm", unchanged(), &["--add", "compliance:8"], &["--add compliance:8", "7 joints"]),
        fails(
            "x and y columns swapped",
            all(["cal/session_1.csv", "cal/session_2.csv", "cal/session_3.csv", "val/session_4.csv", "val/session_5.csv"]
                .map(|f| Box::new(move |d: &Path| {
                    let path = d.join("tracker").join(f);
                    let text = std::fs::read_to_string(&path).unwrap();
                    std::fs::write(&path, text.replacen("x_mm,y_mm", "y_mm,x_mm", 1)).unwrap();
                }) as Setup)
                .into()),
            &[],
            &["not trustworthy", "of the arm's reach", "columns swapped"],
        ),
        fails(
            "an artefact session in a tracker folder",
            Box::new(|d: &Path| {
                std::fs::copy(d.join(CA), d.join("tracker/cal/C_A.json")).unwrap();
            }),
            &[],
            &["tracker/cal", "--artefact is required", "1 artefact session files"],
        ),
        fails("validation = calibration", unchanged(), &[], &["in both the calibration and the validation folder"]).with_args(words(
            &["calibrate", "--model", "tracker/model.toml", "--data", "tracker/cal", "--validate", "tracker/cal", "--out", "tout"],
            &[],
        )),
        fails("no validation sessions", unchanged(), &[], &["tracker", "no tracker session files"]).with_args(words(
            &["calibrate", "--model", "tracker/model.toml", "--data", "tracker/cal", "--validate", "tracker", "--out", "tout"],
            &[],
        )),
        fails("--orientation-sigma-deg on artefact data", unchanged(), &[], &["--orientation-sigma-deg: not for artefact data", "no probe orientation"]).with_args(
            [cal(), vec!["--orientation-sigma-deg", "0.01"]].concat().into_iter().map(String::from).collect(),
        ),
    ]);
}

/// The calibration succeeded with a plausible, finite validation figure on every pair.
fn calibrated(out: &'static str, touches: u64) -> Option<Check> {
    Some(Box::new(move |dir: &Path| {
        let text = std::fs::read_to_string(dir.join(out).join("summary.json")).map_err(|e| e.to_string())?;
        let s: Value = serde_json::from_str(&text).map_err(|e| e.to_string())?;
        let rms = s["validation"]["distances"]["calibrated"]["rms_mm"].as_f64().unwrap_or(f64::NAN);
        let pairs = s["validation"]["distances"]["calibrated"]["count"].as_u64().unwrap_or(0);
        let used = s["calibration"]["observations"].as_u64().unwrap_or(0);
        if !(rms.is_finite() && rms > 0.0 && rms < 1.0 && pairs > 0) {
            return Err(format!("validation RMS {rms} mm over {pairs} pairs is not a plausible result"));
        }
        if used != touches {
            return Err(format!("{used} calibration touches used, expected {touches}"));
        }
        if s.get("not_trustworthy").is_some() {
            return Err("a successful run is marked not trustworthy".into());
        }
        Ok(())
    }))
}

fn exists(path: &'static str) -> Option<Check> {
    Some(Box::new(move |dir: &Path| {
        dir.join(path).exists().then_some(()).ok_or_else(|| format!("{path} was not written"))
    }))
}

/// Set `field` of the `joint`-th (1-based) [[joint]] row of model.toml to `value` (TOML text).
fn model_joint(joint: usize, field: &str, value: &str) -> Setup {
    let (field, value) = (field.to_string(), value.to_string());
    Box::new(move |dir| {
        let path = dir.join("model.toml");
        let text = std::fs::read_to_string(&path).unwrap();
        let mut blocks: Vec<String> = text.split("[[joint]]").map(str::to_string).collect();
        let lines: Vec<String> =
            blocks[joint]
                .lines()
                .map(|l| {
                    if l.starts_with(&format!("{field} =")) {
                        format!("{field} = {value}")
                    } else {
                        l.into()
                    }
                })
                .collect();
        blocks[joint] = lines.join("\n") + "\n";
        std::fs::write(&path, blocks.join("[[joint]]")).unwrap();
    })
}

fn session(file: &'static str, edit: impl Fn(&mut Value) + Send + Sync + 'static) -> Setup {
    edit_json(file, edit)
}

const CA: &str = "data/cal/C_A.json";

/// Keep only the touches of landmark O in every session of `folder`: no distance pair is left.
fn one_landmark(folder: &'static str) -> Setup {
    Box::new(move |d: &Path| {
        for f in std::fs::read_dir(d.join(folder)).unwrap() {
            let p = f.unwrap().path();
            let mut v: Value = serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
            v["measurements"].as_array_mut().unwrap().retain(|m| m["landmark"] == "O");
            std::fs::write(p, v.to_string()).unwrap();
        }
    })
}

/// Text edits of model.toml: (case, text replaced, replacement, what the error must say).
type TextEdit = (&'static str, &'static str, &'static str, &'static [&'static str]);
const BOUNDS: &str = "[10.7, 30.7]";
const TCP: &str = "[0.0, 0.0, 253.0]";
const SCALE: &str = "scale_ppm = 0.0";
const MODEL_TEXT_EDITS: &[TextEdit] = &[
    ("bounds with 3 numbers", BOUNDS, "[10.7, 20.7, 30.7]", &["offset:2", "expected 2 numbers"]),
    ("bounds with 1 number", BOUNDS, "[10.7]", &["offset:2", "expected 2 numbers"]),
    ("bounds empty", BOUNDS, "[]", &["offset:2", "expected 2 numbers"]),
    ("bounds nan", BOUNDS, "[nan, 30.7]", &["offset:2", "finite"]),
    ("bounds ±1e200", "[-10.0, 10.0]", "[-1e200, 1e200]", &["length:2", "plausible"]),
    ("bounds reversed", BOUNDS, "[30.7, 10.7]", &["offset:2", "lower < upper"]),
    ("bounds equal", BOUNDS, "[20.7, 20.7]", &["offset:2", "lower < upper"]),
    ("value outside bounds", BOUNDS, "[30.0, 40.0]", &["offset:2", "outside its bounds"]),
    ("bounds as text", BOUNDS, "\"10.7..30.7\"", &["model.toml", "invalid type"]),
    ("unknown parameter", "\"offset:2\"", "\"offset:9\"", &["offset:9", "unknown parameter"]),
    ("tcp with 4 numbers", TCP, "[0.0, 0.0, 253.0, 1.0]", &["tcp_mm", "expected 3 numbers"]),
    ("tcp with 2 numbers", TCP, "[0.0, 253.0]", &["tcp_mm", "expected 3 numbers"]),
    ("tcp nan", TCP, "[0.0, nan, 253.0]", &["tcp.y", "finite"]),
    ("tcp 1e308", TCP, "[0.0, 0.0, 1e308]", &["tcp.z", "plausible"]),
    ("tcp missing", "tcp_mm = [0.0, 0.0, 253.0]", "", &["model.toml", "tcp_mm"]),
    ("scale -1e6 ppm", SCALE, "scale_ppm = -1e6", &["scale", "plausible"]),
    ("scale nan", SCALE, "scale_ppm = nan", &["scale", "finite"]),
    ("scale 1e308", SCALE, "scale_ppm = 1e308", &["scale", "plausible"]),
    ("format", "kincal-arm/1", "kincal-arm/2", &["format", "kincal-arm/1"]),
    ("convention", "\"classic\"", "\"banana\"", &["model.toml", "banana"]),
    ("five joints", "[[joint]]\noffset_deg = 20.7", "[[jointx]]\noffset_deg = 20.7", &["model.toml"]),
    (
        "seven joints",
        "\n[free]\n",
        "\n[[joint]]\noffset_deg = 0\nd_mm = 0\na_mm = 0\nalpha_deg = 0\n[free]\n",
        &["artefact sessions record 6 encoder angles", "the model has 7 joints"],
    ),
    ("unknown key", SCALE, "scale_ppm = 0.0\nscael = 1", &["model.toml", "scael"]),
    ("unknown effect", SCALE, "scale_ppm = 0.0\neffects = [\"wobble:2\"]", &["wobble:2", "unknown effect"]),
];

fn model_cases(cases: &mut Vec<Case>) {
    let params =
        [("offset_deg", "offset"), ("d_mm", "length"), ("a_mm", "link_offset"), ("alpha_deg", "twist")];
    for j in 1..=6 {
        for (field, param) in params {
            let name = format!("{param}:{j}");
            for (value, needles) in [
                ("nan", vec![name.as_str(), "finite"]),
                ("inf", vec![name.as_str(), "finite"]),
                ("-inf", vec![name.as_str(), "finite"]),
                ("1e308", vec![name.as_str(), "plausible"]),
                ("-1e12", vec![name.as_str(), "plausible"]),
                ("\"12\"", vec!["model.toml", "invalid type"]),
            ] {
                cases.push(Case::fails(
                    &format!("model/{name}={value}"),
                    model_joint(j, field, value),
                    words(&cal(), &[]),
                    &needles,
                ));
            }
        }
    }
    let m = "model.toml";
    for (name, from, to, needles) in MODEL_TEXT_EDITS {
        cases.push(Case::fails(&format!("model/{name}"), replace(m, from, to), words(&cal(), &[]), needles));
    }
    let free_table_only = |extra: &'static str| -> Setup {
        Box::new(move |d: &Path| {
            let t = std::fs::read_to_string(d.join("model.toml")).unwrap();
            std::fs::write(
                d.join("model.toml"),
                format!("{}{extra}", &t[..t.find("\n[free]\n").unwrap() + 8]),
            )
            .unwrap();
        })
    };
    let list: Vec<(&str, Setup, &[&str])> = vec![
        ("empty free table", free_table_only(""), &["no free parameter"]),
        (
            "only offset:1 free",
            free_table_only("\"offset:1\" = [-11.6, 8.4]\n"),
            &["none of the free parameters"],
        ),
        (
            "lengths in metres",
            all(vec![
                model_joint(1, "d_mm", "0.047"),
                model_joint(3, "d_mm", "0.571"),
                model_joint(5, "d_mm", "0.371"),
                replace(m, "[0.0, 0.0, 253.0]", "[0.0, 0.0, 0.253]"),
                replace(m, "\"length:1\" = [37.0, 57.0]", "\"length:1\" = [0.0, 1.0]"),
                replace(m, "\"length:3\" = [561.0, 581.0]", "\"length:3\" = [0.0, 1.0]"),
                replace(m, "\"length:5\" = [361.0, 381.0]", "\"length:5\" = [0.0, 1.0]"),
                replace(m, "\"tcp.z\" = [243.0, 263.0]", "\"tcp.z\" = [0.0, 1.0]"),
            ]),
            &["reach", "millimetres"],
        ),
        ("twist 400", model_joint(2, "alpha_deg", "400.0"), &["twist:2", "plausible"]),
        (
            "an arm too short for the artefact",
            all(vec![
                model_joint(3, "d_mm", "20.0"),
                model_joint(5, "d_mm", "10.0"),
                replace(m, "\"length:3\" = [561.0, 581.0]", "\"length:3\" = [15.0, 25.0]"),
                replace(m, "\"length:5\" = [361.0, 381.0]", "\"length:5\" = [5.0, 15.0]"),
                replace(m, TCP, "[0.0, 0.0, 10.0]"),
                replace(m, "\"tcp.z\" = [243.0, 263.0]", "\"tcp.z\" = [5.0, 15.0]"),
            ]),
            &["cannot touch them all"],
        ),
        ("truncated file", free_table_only("\"offset:2\" = [10.7,"), &["model.toml"]),
        ("empty file", write(m, ""), &["model.toml"]),
        ("binary garbage", write(m, "\u{0}\u{1}\u{2}PK"), &["model.toml"]),
        (
            "missing file",
            Box::new(|d: &Path| std::fs::remove_file(d.join("model.toml")).unwrap()),
            &["model.toml", "no such file"],
        ),
        (
            "a folder",
            Box::new(|d: &Path| {
                std::fs::remove_file(d.join("model.toml")).unwrap();
                std::fs::create_dir(d.join("model.toml")).unwrap();
            }),
            &["model.toml"],
        ),
    ];
    for (name, setup, needles) in list {
        cases.push(Case::fails(&format!("model/{name}"), setup, words(&cal(), &[]), needles));
    }
    let json_model: Vec<(&str, Setup, &[&str])> = vec![
        ("json tcp null", replace("model.json", "253.0", "null"), &["model.json", "tcp_mm"]),
        (
            "json bounds of 3",
            replace("model.json", "10.7,\n      30.7", "10.7, 20.7, 30.7"),
            &["offset:2", "expected 2 numbers"],
        ),
        (
            "json d as string",
            replace("model.json", "\"d_mm\": 47.0", "\"d_mm\": \"47\""),
            &["model.json", "d_mm"],
        ),
        (
            "json trailing garbage",
            replace("model.json", "kincal-arm/1\",", "kincal-arm/1\",,"),
            &["model.json"],
        ),
    ];
    let cal_json: Vec<String> = words(&cal(), &[])
        .into_iter()
        .map(|w| if w == "model.toml" { "model.json".into() } else { w })
        .collect();
    for (name, setup, needles) in json_model {
        cases.push(Case::fails(&format!("model/{name}"), setup, cal_json.clone(), needles));
    }
    cases.push(Case::succeeds("model/json is fine", unchanged(), cal_json, calibrated("out", 225)));
    cases.push(Case::succeeds(
        "model/a comment and blank lines",
        replace(m, "\n[free]\n", "\n# bounds below\n\n[free]\n"),
        words(&cal(), &[]),
        calibrated("out", 225),
    ));
}

fn artefact_cases(cases: &mut Vec<Case>) {
    let a = "data/artefact.json";
    let lm = |f: fn(&mut Value)| edit_json(a, move |v| f(&mut v["landmarks"]));
    let list: Vec<(&str, Setup, &[&str])> = vec![
        (
            "in metres",
            lm(|l| {
                for x in l.as_array_mut().unwrap() {
                    for k in 0..3 {
                        x["xyz_mm"][k] = json!(x["xyz_mm"][k].as_f64().unwrap() / 1000.0)
                    }
                }
            }),
            &["artefact.json", "are they in metres"],
        ),
        (
            "all at one point",
            lm(|l| {
                for x in l.as_array_mut().unwrap() {
                    x["xyz_mm"] = json!([0.0, 0.0, 40.0])
                }
            }),
            &["artefact.json", "all landmarks are at one point"],
        ),
        (
            "two at one point",
            lm(|l| {
                let p = l[3]["xyz_mm"].clone();
                l[7]["xyz_mm"] = p;
            }),
            &["landmarks[7].xyz_mm", "cannot share a point"],
        ),
        ("duplicate id", lm(|l| l[5]["id"] = l[2]["id"].clone()), &["landmarks[5].id", "duplicate"]),
        (
            "empty certificate",
            edit_json(a, |v| v["certificate"] = json!(" ")),
            &["artefact.json", "certificate"],
        ),
        ("empty id", lm(|l| l[5]["id"] = json!(" ")), &["landmarks[5].id"]),
        ("xyz null", lm(|l| l[2]["xyz_mm"][1] = Value::Null), &["artefact.json", "xyz_mm"]),
        ("xyz text", lm(|l| l[2]["xyz_mm"][1] = json!("12")), &["artefact.json", "xyz_mm"]),
        ("xyz with 2 numbers", lm(|l| l[2]["xyz_mm"] = json!([1.0, 2.0])), &["artefact.json", "xyz_mm"]),
        (
            "xyz with 4 numbers",
            lm(|l| l[2]["xyz_mm"] = json!([1.0, 2.0, 3.0, 4.0])),
            &["artefact.json", "xyz_mm"],
        ),
        ("xyz 1e308", lm(|l| l[2]["xyz_mm"][0] = json!(1e308)), &["artefact.json", "reach"]),
        ("yaw 1000", lm(|l| l[4]["yaw_deg"] = json!(1000.0)), &["landmarks[4].yaw_deg"]),
        (
            "yaw missing",
            lm(|l| {
                l[4].as_object_mut().unwrap().remove("yaw_deg");
            }),
            &["artefact.json", "yaw_deg"],
        ),
        ("one landmark", lm(|l| l.as_array_mut().unwrap().truncate(1)), &["at least two"]),
        ("no landmarks", lm(|l| l.as_array_mut().unwrap().clear()), &["at least two"]),
        ("format", edit_json(a, |v| v["format"] = json!("suta-artefact/2")), &["artefact.json", "format"]),
        (
            "landmarks not a list",
            edit_json(a, |v| v["landmarks"] = json!({})),
            &["artefact.json", "landmarks"],
        ),
        ("not json", write(a, "id,x,y,z\nO,0,0,40\n"), &["artefact.json"]),
        ("empty", write(a, ""), &["artefact.json"]),
        (
            "missing",
            Box::new(|d: &Path| std::fs::remove_file(d.join("data/artefact.json")).unwrap()),
            &["artefact.json", "no such file"],
        ),
        (
            "one landmark moved 10 mm",
            lm(|l| {
                let x = l[6]["xyz_mm"][0].as_f64().unwrap();
                l[6]["xyz_mm"][0] = json!(x + 10.0)
            }),
            &["not trustworthy", "repeatability"],
        ),
        (
            "ids swapped",
            lm(|l| {
                let a = l[1]["id"].clone();
                l[1]["id"] = l[9]["id"].clone();
                l[9]["id"] = a;
            }),
            &["not trustworthy"],
        ),
    ];
    for (name, setup, needles) in list {
        cases.push(Case::fails(&format!("artefact/{name}"), setup, words(&cal(), &[]), needles));
    }
    for i in [0usize, 4, 9, 14] {
        cases.push(Case::fails(
            &format!("artefact/landmark {i} 1 km away"),
            edit_json(a, move |v| v["landmarks"][i]["xyz_mm"] = json!([1.0e6, 0.0, 40.0])),
            words(&cal(), &[]),
            &[&format!("landmarks[{i}].xyz_mm"), "beyond any arm's reach"],
        ));
        cases.push(Case::fails(
            &format!("artefact/landmark {i} in micrometres"),
            edit_json(a, move |v| {
                for k in 0..3 {
                    let x = v["landmarks"][i]["xyz_mm"][k].as_f64().unwrap();
                    v["landmarks"][i]["xyz_mm"][k] = json!(x * 1000.0 + 7000.0);
                }
            }),
            words(&cal(), &[]),
            &[&format!("landmarks[{i}].xyz_mm"), "beyond any arm's reach"],
        ));
    }
}

fn session_cases(cases: &mut Vec<Case>) {
    let m0 = |f: fn(&mut Value)| session(CA, move |v| f(&mut v["measurements"][0]));
    let list: Vec<(&str, Setup, &[&str])> = vec![
        (
            "5 angles",
            m0(|m| {
                m["joints_deg"].as_array_mut().unwrap().pop();
            }),
            &["C_A.json", "measurements[0].joints_deg", "expected 6"],
        ),
        (
            "7 angles",
            m0(|m| m["joints_deg"].as_array_mut().unwrap().push(json!(1.0))),
            &["C_A.json", "measurements[0].joints_deg", "expected 6"],
        ),
        (
            "angle 400",
            m0(|m| m["joints_deg"][2] = json!(400.0)),
            &["measurements[0].joints_deg[2]", "[0, 360)"],
        ),
        (
            "angle -1",
            m0(|m| m["joints_deg"][2] = json!(-1.0)),
            &["measurements[0].joints_deg[2]", "[0, 360)"],
        ),
        (
            "angle 360",
            m0(|m| m["joints_deg"][2] = json!(360.0)),
            &["measurements[0].joints_deg[2]", "[0, 360)"],
        ),
        ("angle 1e308", m0(|m| m["joints_deg"][2] = json!(1e308)), &["measurements[0].joints_deg[2]"]),
        ("angle null", m0(|m| m["joints_deg"][2] = Value::Null), &["C_A.json", "joints_deg"]),
        ("angle text", m0(|m| m["joints_deg"][2] = json!("12.5")), &["C_A.json", "joints_deg"]),
        (
            "angles missing",
            m0(|m| {
                m.as_object_mut().unwrap().remove("joints_deg");
            }),
            &["C_A.json", "joints_deg"],
        ),
        (
            "angles in radians",
            session(CA, |v| {
                for m in v["measurements"].as_array_mut().unwrap() {
                    for k in 0..6 {
                        m["joints_deg"][k] = json!(m["joints_deg"][k].as_f64().unwrap().to_radians())
                    }
                }
            }),
            &["not trustworthy"],
        ),
        ("repeat 0", m0(|m| m["repeat"] = json!(0)), &["measurements[0].repeat", "from 1"]),
        (
            "arm id with a space",
            session(CA, |v| v["arm"] = json!({"id": "lab arm"})),
            &["C_A.json", "arm.id", "not an arm identity"],
        ),
        ("arm without id", session(CA, |v| v["arm"] = json!({"board": "b"})), &["C_A.json", "id"]),
        (
            "one session of another arm",
            all(vec![
                edit_json("data/cal/C_A.json", |v| v["arm"] = json!({"id": "lab-arm-A"})),
                edit_json("data/cal/C_B.json", |v| v["arm"] = json!({"id": "lab-arm-B"})),
            ]),
            &[
                "C_A.json was recorded on arm lab-arm-A",
                "C_B.json on arm lab-arm-B",
                "one calibration is of one arm",
            ],
        ),
        (
            "one session names its arm, the others none",
            edit_json("data/cal/C_A.json", |v| v["arm"] = json!({"id": "lab-arm-A"})),
            &["C_A.json was recorded on arm lab-arm-A", "names no arm"],
        ),
        ("repeat -1", m0(|m| m["repeat"] = json!(-1)), &["C_A.json", "repeat"]),
        ("repeat 1.5", m0(|m| m["repeat"] = json!(1.5)), &["C_A.json", "repeat"]),
        (
            "same landmark and repeat twice",
            session(CA, |v| {
                let m = v["measurements"][0].clone();
                v["measurements"].as_array_mut().unwrap().push(m);
            }),
            &["C_A.json", "already touched in measurements[0]"],
        ),
        (
            "same landmark and repeat, 10 mm apart",
            session(CA, |v| {
                let mut m = v["measurements"][0].clone();
                m["joints_deg"][1] = json!(m["joints_deg"][1].as_f64().unwrap() + 1.0);
                v["measurements"].as_array_mut().unwrap().insert(3, m);
            }),
            &["C_A.json", "measurements[3].repeat", "already touched"],
        ),
        ("unknown landmark", m0(|m| m["landmark"] = json!("Z9")), &["measurements[0].landmark", "Z9"]),
        ("landmark lower case", m0(|m| m["landmark"] = json!("m1")), &["measurements[0].landmark", "m1"]),
        ("samples 0", m0(|m| m["samples"] = json!(0)), &["measurements[0].samples", "0 accepted"]),
        (
            "rejected > samples",
            m0(|m| {
                m["samples"] = json!(10);
                m["rejected"] = json!(11)
            }),
            &["measurements[0].rejected", "rejected"],
        ),
        ("samples negative", m0(|m| m["samples"] = json!(-5)), &["C_A.json", "samples"]),
        ("std negative", m0(|m| m["std_deg"][0] = json!(-0.1)), &["measurements[0].std_deg"]),
        (
            "std 5 values",
            m0(|m| {
                m["std_deg"].as_array_mut().unwrap().pop();
            }),
            &["measurements[0].std_deg"],
        ),
        (
            "purpose banana",
            session(CA, |v| v["purpose"] = json!("banana")),
            &["C_A.json", "purpose", "banana"],
        ),
        (
            "purpose validation in cal",
            session(CA, |v| v["purpose"] = json!("validation")),
            &["C_A.json", "purpose", "folder of calibration"],
        ),
        (
            "purpose calibration in val",
            session("data/val/V_B.json", |v| v["purpose"] = json!("calibration")),
            &["V_B.json", "purpose", "folder of validation"],
        ),
        (
            "purpose missing",
            session(CA, |v| {
                v.as_object_mut().unwrap().remove("purpose");
            }),
            &["C_A.json", "purpose"],
        ),
        ("placement empty", session(CA, |v| v["placement"] = json!("")), &["C_A.json", "placement"]),
        (
            "placement duplicated across files",
            session(CA, |v| v["placement"] = json!("C_B")),
            &["placement", "also in", "C_B.json"],
        ),
        (
            "file copied",
            Box::new(|d: &Path| {
                std::fs::copy(d.join(CA), d.join("data/cal/C_A copy.json")).unwrap();
            }),
            &["also in"],
        ),
        ("format", session(CA, |v| v["format"] = json!("suta-session/0")), &["C_A.json", "format"]),
        (
            "measurements not a list",
            session(CA, |v| v["measurements"] = json!(3)),
            &["C_A.json", "measurements"],
        ),
        (
            "truncated",
            Box::new(|d: &Path| {
                let t = std::fs::read_to_string(d.join(CA)).unwrap();
                std::fs::write(d.join(CA), &t[..t.len() / 3]).unwrap();
            }),
            &["C_A.json", "EOF"],
        ),
        ("empty file", write(CA, ""), &["C_A.json"]),
        ("CSV named json", write(CA, "landmark,repeat,j1\nO,1,10\n"), &["C_A.json"]),
        (
            "empty folder",
            Box::new(|d: &Path| {
                std::fs::remove_dir_all(d.join("data/cal")).unwrap();
                std::fs::create_dir(d.join("data/cal")).unwrap();
            }),
            &["data/cal", "no session files"],
        ),
        (
            "folder missing",
            Box::new(|d: &Path| std::fs::remove_dir_all(d.join("data/val")).unwrap()),
            &["data/val", "no such file"],
        ),
        (
            "over 64 MB",
            Box::new(|d: &Path| {
                std::fs::File::create(d.join("data/cal/big.json")).unwrap().set_len(65 << 20).unwrap()
            }),
            &["big.json", "at most 64 MB"],
        ),
        (
            "every touch identical",
            session(CA, |v| {
                let j = v["measurements"][0]["joints_deg"].clone();
                for m in v["measurements"].as_array_mut().unwrap() {
                    m["joints_deg"] = j.clone()
                }
            }),
            &["not trustworthy"],
        ),
        (
            "validation = calibration",
            Box::new(|d: &Path| {
                std::fs::remove_dir_all(d.join("data/val")).unwrap();
                copy_tree(&d.join("data/cal"), &d.join("data/val"));
                for f in std::fs::read_dir(d.join("data/val")).unwrap() {
                    let p = f.unwrap().path();
                    let t = std::fs::read_to_string(&p).unwrap().replace("\"calibration\"", "\"validation\"");
                    std::fs::write(p, t).unwrap();
                }
            }),
            &["same touches as calibration placement", "held out"],
        ),
        (
            "one validation file copies a calibration file",
            Box::new(|d: &Path| {
                let t = std::fs::read_to_string(d.join("data/cal/C_C.json"))
                    .unwrap()
                    .replace("\"calibration\"", "\"validation\"")
                    .replace("\"C_C\"", "\"V_X\"");
                std::fs::write(d.join("data/val/V_X.json"), t).unwrap();
            }),
            &["\"V_X\"", "\"C_C\""],
        ),
        (
            "validation from another arm",
            Box::new(|d: &Path| {
                std::fs::remove_dir_all(d.join("data/val")).unwrap();
                copy_tree(&d.join("other-arm"), &d.join("data/val"));
            }),
            &["not trustworthy", "validation RMS", "another arm"],
        ),
        (
            "validation with one landmark per repeat",
            one_landmark("data/val"),
            &["data/val", "no distance to validate"],
        ),
        ("calibration with one landmark per repeat", one_landmark("data/cal"), &["0 landmark pairs"]),
        (
            "no measurements anywhere",
            Box::new(|d: &Path| {
                for f in std::fs::read_dir(d.join("data/cal")).unwrap() {
                    let p = f.unwrap().path();
                    let mut v: Value = serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
                    v["measurements"] = json!([]);
                    std::fs::write(p, v.to_string()).unwrap();
                }
            }),
            &["0 landmark pairs"],
        ),
    ];
    for (name, setup, needles) in list {
        cases.push(Case::fails(&format!("session/{name}"), setup, words(&cal(), &[]), needles));
    }
    // Every landmark position of the first measurement, one bad angle each joint.
    for k in 0..6 {
        for (value, label) in [(json!(-0.5), "negative"), (json!(720.0), "two turns"), (Value::Null, "null")]
        {
            let needle = if value.is_null() { "joints_deg".to_string() } else { format!("joints_deg[{k}]") };
            cases.push(Case::fails(
                &format!("session/joint {} {label} in val", k + 1),
                session("data/val/V_C.json", move |v| v["measurements"][4]["joints_deg"][k] = value.clone()),
                words(&cal(), &[]),
                &["V_C.json", &needle],
            ));
        }
    }
    let mut ok: Vec<(&str, Setup, u64)> = vec![
        (
            "upper-case .JSON is read",
            Box::new(|d: &Path| std::fs::rename(d.join(CA), d.join("data/cal/C_A.JSON")).unwrap()),
            225,
        ),
        ("a README beside the sessions", write("data/cal/README.txt", "recorded on Monday"), 225),
        ("a hidden temporary file", write("data/cal/.C_A.json.swp", "{"), 225),
        (
            "a missing landmark",
            session(CA, |v| {
                v["measurements"].as_array_mut().unwrap().remove(4);
            }),
            224,
        ),
        (
            "std, samples, rejected absent",
            session(CA, |v| {
                for m in v["measurements"].as_array_mut().unwrap() {
                    let o = m.as_object_mut().unwrap();
                    o.remove("std_deg");
                    o.remove("samples");
                    o.remove("rejected");
                }
            }),
            225,
        ),
        (
            "rejected = samples",
            session(CA, |v| {
                v["measurements"][0]["samples"] = json!(5);
                v["measurements"][0]["rejected"] = json!(5)
            }),
            225,
        ),
        (
            "one placement fewer",
            Box::new(|d: &Path| std::fs::remove_file(d.join("data/cal/C_D.json")).unwrap()),
            180,
        ),
    ];
    // Scale: one session of 3000 touches (200 repeats) is calibrated; 20 placements make a study of
    // 10 000 subsets too large, refused up front with the limit.
    ok.push((
        "3000 touches in one session",
        session(CA, |v| {
            let first: Vec<Value> =
                v["measurements"].as_array().unwrap().iter().filter(|m| m["repeat"] == 1).cloned().collect();
            let mut all = Vec::new();
            for repeat in 1..=200u32 {
                for (k, m) in first.iter().enumerate() {
                    let mut m = m.clone();
                    m["repeat"] = json!(repeat);
                    let a = m["joints_deg"][5].as_f64().unwrap();
                    m["joints_deg"][5] = json!(a + 1e-4 * ((repeat as f64 * 7.0 + k as f64).sin()));
                    all.push(m);
                }
            }
            v["measurements"] = Value::Array(all);
        }),
        3180,
    ));
    for (name, setup, touches) in ok {
        cases.push(Case::succeeds(
            &format!("session/{name}"),
            setup,
            words(&cal(), &[]),
            calibrated("out", touches),
        ));
    }
}

fn option_cases(cases: &mut Vec<Case>) {
    let bad: Vec<(Vec<&str>, &str, &[&str])> = vec![
        (cal(), "--huber-delta-mm", &["0", "-1", "1e-300", "NaN", "inf", "1e9", "abc", ""]),
        (cal(), "--lever-mm", &["NaN", "0", "-5", "inf", "1e300"]),
        (cal(), "--restarts", &["-1", "1001", "x", "1.5"]),
        (cal(), "--study-subsets", &["-1", "10001", "NaN"]),
        (cal(), "--seed", &["-1", "x"]),
        (cal(), "--objective", &["banana", ""]),
        (cal(), "--add", &["wobble:2", "eccentricity:25", ""]),
        (SIM.to_vec(), "--perturb-deg", &["NaN", "-1", "100", "inf"]),
        (SIM.to_vec(), "--perturb-mm", &["NaN", "-1", "1000"]),
        (SIM.to_vec(), "--seating-noise-mm", &["NaN", "-0.1", "1e9", "inf"]),
        (SIM.to_vec(), "--encoder-noise-deg", &["NaN", "-1", "5", "inf"]),
        (SIM.to_vec(), "--repeats", &["0", "-1", "21", "1.5", "NaN"]),
        (
            SIM.to_vec(),
            "--hidden",
            &["offset:25=1", "offset:2=NaN", "offset:2=1e9", "junk", "offset:2=", "scale=-1e6"],
        ),
        (study(), "--subsets", &["0", "-1", "10001", "NaN"]),
        (study(), "--restarts", &["-1", "5000"]),
        (vec!["haptic", "simulate", "--out", "rec"], "--delay-ms", &["NaN", "-1", "inf", "1e9"]),
        (vec!["haptic", "simulate", "--out", "rec"], "--joints-seconds", &["NaN", "0", "-5", "601", "1e12"]),
    ];
    for (base, option, values) in bad {
        for value in values.iter() {
            // An option the base command line already gives is replaced, not repeated.
            let mut args = words(&base, &[]);
            match args.iter().position(|w| w == option) {
                Some(at) => args[at + 1] = value.to_string(),
                None => args.extend([option.to_string(), value.to_string()]),
            }
            cases.push(Case::fails(
                &format!("option/{} {option} {value}", base[0]),
                unchanged(),
                args,
                &if value.is_empty() { vec![option] } else { vec![option, "invalid value"] },
            ));
        }
    }
    // Joint 9 is a name kincal knows (up to 24 joints in a tree); the six-joint model has no such joint.
    cases.push(Case::fails(
        "option/calibrate --add eccentricity:9 on six joints",
        unchanged(),
        words(&cal(), &["--add", "eccentricity:9"]),
        &["--add eccentricity:9", "the model has 6 joints"],
    ));
    cases.push(Case::fails(
        "option/simulate --hidden offset:9=1 on six joints",
        unchanged(),
        words(SIM, &["--hidden", "offset:9=1"]),
        &["--hidden offset:9", "the model has 6 joints"],
    ));
    let many = || -> Setup {
        Box::new(|d: &Path| {
            for copy in 1..4 {
                for f in std::fs::read_dir(d.join("data/cal")).unwrap().collect::<Vec<_>>() {
                    let p = f.unwrap().path();
                    let mut v: Value = serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
                    let name = format!("{}_{copy}", v["placement"].as_str().unwrap());
                    v["placement"] = json!(name);
                    std::fs::write(d.join("data/cal").join(format!("{name}.json")), v.to_string()).unwrap();
                }
            }
        })
    };
    cases.push(Case::fails(
        "option/study, validation with one landmark per repeat",
        one_landmark("data/val"),
        words(&study(), &[]),
        &["data/val", "no distance to validate"],
    ));
    cases.push(Case::fails(
        "option/study, calibration with one landmark per repeat",
        one_landmark("data/cal"),
        words(&study(), &[]),
        &["no calibration of any subset succeeded", "nothing was written"],
    ));
    cases.push(Case::fails(
        "session/more than 50 000 touches in 1112 files",
        Box::new(|d: &Path| {
            let mut v: Value = serde_json::from_str(&std::fs::read_to_string(d.join(CA)).unwrap()).unwrap();
            for copy in 0..1112 {
                v["placement"] = json!(format!("P{copy}"));
                std::fs::write(d.join(format!("data/cal/P{copy}.json")), v.to_string()).unwrap();
            }
        }),
        words(&cal(), &[]),
        &["data/cal", "at most 50000 are read"],
    ));
    cases.push(Case::fails(
        "option/study of 10000 subsets over 20 placements",
        many(),
        words(&study()[..study().len() - 4], &["--subsets", "10000", "--out", "study"]),
        &["touch-calibrations", "at most 10000000", "fewer subsets"],
    ));
    cases.push(Case::fails(
        "option/calibrate with a study of 10000 subsets over 20 placements",
        many(),
        words(&cal(), &["--study-subsets", "10000"]),
        &["touch-calibrations", "fewer subsets"],
    ));
    let good: Vec<(&str, Vec<String>, Option<Check>)> = vec![
        ("huber 0.5", words(&cal(), &["--huber-delta-mm", "0.5"]), calibrated("out", 225)),
        (
            "six-dof lever 50",
            words(&cal(), &["--objective", "six-dof", "--lever-mm", "50"]),
            calibrated("out", 225),
        ),
        (
            "no restarts",
            words(&cal(), &[]).into_iter().map(|w| if w == "1" { "0".into() } else { w }).collect(),
            calibrated("out", 225),
        ),
        ("add eccentricity:5", words(&cal(), &["--add", "eccentricity:5"]), calibrated("out", 225)),
        ("with a study", words(&cal(), &["--study-subsets", "2"]), calibrated("out", 225)),
        ("json", words(&cal(), &["--json"]), calibrated("out", 225)),
        ("simulate hidden", words(SIM, &["--hidden", "eccentricity_sin:5=0.2"]), exists("sim/cal/C_A.json")),
        (
            "simulate no noise",
            words(SIM, &["--seating-noise-mm", "0", "--encoder-noise-deg", "0"]),
            exists("sim/val/V_A.json"),
        ),
        ("study", words(&study(), &[]), exists("study/study.json")),
        ("study json", words(&study(), &["--json"]), exists("study/study.json")),
    ];
    for (name, args, check) in good {
        cases.push(Case::succeeds(&format!("option/{name}"), unchanged(), args, check));
    }
}

fn output_cases(cases: &mut Vec<Case>) {
    let out_as = |out: &str| -> Vec<String> {
        words(&cal(), &[]).into_iter().map(|w| if w == "out" { out.to_string() } else { w }).collect()
    };
    let thesis = write("mine/thesis.docx", "years of work");
    let list: Vec<(&str, Setup, Vec<String>, &[&str])> = vec![
        ("out = the data folder", unchanged(), out_as("data"), &["contains the input"]),
        ("out = the calibration folder", unchanged(), out_as("data/cal"), &["contains the input"]),
        ("out = the validation folder", unchanged(), out_as("data/val"), &["contains the input"]),
        ("out = .", unchanged(), out_as("."), &["not a folder name"]),
        ("out = ..", unchanged(), out_as(".."), &["not a folder name"]),
        ("out = data/..", unchanged(), out_as("data/.."), &["not a folder name"]),
        ("out = a file", write("notes.txt", "mine"), out_as("notes.txt"), &["not a folder"]),
        ("out = the model file", unchanged(), out_as("model.toml"), &["contains the input"]),
        ("out = a folder of the user's", thesis, out_as("mine"), &["thesis.docx", "did not write"]),
        (
            "out = a RUN with a user's file added",
            write("run/notes.txt", "mine"),
            out_as("run"),
            &["notes.txt"],
        ),
        (
            "out = a study folder",
            Box::new(|d: &Path| {
                std::fs::create_dir(d.join("st")).unwrap();
                std::fs::write(d.join("st/.kincal-output"), "study").unwrap();
            }),
            out_as("st"),
            &["study folder"],
        ),
        (
            "study out = the data",
            unchanged(),
            words(&study()[..study().len() - 1], &["data"]),
            &["contains the input"],
        ),
        ("study out = a user's folder", write("study/plan.md", "mine"), words(&study(), &[]), &["plan.md"]),
        (
            "simulate out = the data",
            unchanged(),
            words(&["simulate", "--model", "model.toml", "--out", "data"], &[]),
            &["did not write"],
        ),
        (
            "simulate out = a user's folder",
            write("sim/notes.txt", "mine"),
            words(SIM, &[]),
            &["did not write"],
        ),
        (
            "simulate out = .",
            unchanged(),
            words(&["simulate", "--model", "model.toml", "--out", "."], &[]),
            &["not a folder name"],
        ),
        (
            "compare out = the user's page",
            write("page.html", "<html>mine</html>"),
            words(&["compare", "run", "run", "--out", "page.html"], &[]),
            &["not a page kincal wrote"],
        ),
        (
            "compare out = a folder",
            unchanged(),
            words(&["compare", "run", "run", "--out", "data"], &[]),
            &["is a folder"],
        ),
        (
            "compare out = the run's own report",
            unchanged(),
            words(&["compare", "run", "run", "--out", "run/report.html"], &[]),
            &["inside a folder kincal writes"],
        ),
        (
            "haptic simulate out = the user's file beside its recording",
            write("rec/mine.csv", "1,2"),
            words(&["haptic", "simulate", "--out", "rec", "--joints-seconds", "5"], &[]),
            &["did not write", "mine.csv"],
        ),
        (
            "haptic simulate out = .",
            unchanged(),
            words(&["haptic", "simulate", "--out", ".", "--joints-seconds", "5"], &[]),
            &["not a folder name"],
        ),
        (
            "haptic simulate --t2-height-mm NaN",
            unchanged(),
            words(&["haptic", "simulate", "--out", "rec", "--t2-height-mm", "NaN"], &[]),
            &["t2-height-mm"],
        ),
    ];
    for (name, setup, args, needles) in list {
        cases.push(Case::fails(&format!("output/{name}"), setup, args, needles));
    }
    let ok: Vec<(&str, Setup, Vec<String>, Option<Check>)> = vec![
        ("out = a RUN kincal wrote is replaced", unchanged(), out_as("run"), calibrated("run", 225)),
        ("out = a new nested folder", unchanged(), out_as("a/b/c"), calibrated("a/b/c", 225)),
        (
            "out = an empty folder",
            Box::new(|d: &Path| std::fs::create_dir(d.join("empty")).unwrap()),
            out_as("empty"),
            calibrated("empty", 225),
        ),
        (
            "out beside the user's files",
            write("mine/thesis.docx", "years"),
            out_as("mine/run"),
            calibrated("mine/run", 225),
        ),
        ("simulate twice into its own folder", unchanged(), words(SIM, &[]), exists("sim/artefact.json")),
        (
            "haptic simulate beside the user's folder",
            write("mine/notes.csv", "1,2"),
            words(&["haptic", "simulate", "--out", "mine/rec", "--joints-seconds", "5"], &[]),
            exists("mine/rec/recording.json"),
        ),
        (
            "haptic simulate twice into its own recording",
            Box::new(|d: &Path| {
                let ok = std::process::Command::new(kincal_e2e::kincal_bin())
                    .args(["haptic", "simulate", "--out", "rec", "--joints-seconds", "5"])
                    .current_dir(d)
                    .status()
                    .map(|s| s.success());
                assert_eq!(ok.ok(), Some(true), "first haptic simulate");
            }),
            words(&["haptic", "simulate", "--out", "rec", "--joints-seconds", "5"], &[]),
            exists("rec/recording.json"),
        ),
        (
            "compare twice onto its own page",
            unchanged(),
            words(&["compare", "run", "run", "--out", "cmp.html"], &[]),
            exists("cmp.html"),
        ),
    ];
    for (name, setup, args, check) in ok {
        cases.push(Case::succeeds(&format!("output/{name}"), setup, args, check));
    }
}

/// Every command that writes, on a disk that fills up part-way: the error says so, nothing
/// half-written is left and an existing output is kept as it was.
fn disk_full_cases(cases: &mut Vec<Case>) {
    let list: Vec<(&str, Vec<String>, u64)> = vec![
        ("calibrate", words(&cal(), &[]), 8),
        ("calibrate over a RUN it wrote", words(&cal()[..cal().len() - 1], &["run"]), 8),
        ("calibrate, the report", words(&cal(), &[]), 200),
        ("study", words(&study(), &[]), 2),
        ("simulate", words(SIM, &[]), 2),
        ("diagnose", words(&["diagnose", "run"], &[]), 4),
        ("diagnose, the second file", words(&["diagnose", "run"], &[]), 300),
        ("compare", words(&["compare", "run", "run", "--out", "cmp.html"], &[]), 4),
        ("haptic simulate", words(&["haptic", "simulate", "--out", "rec", "--joints-seconds", "5"], &[]), 16),
    ];
    for (name, args, kib) in list {
        cases.push(
            Case::fails(&format!("disk full/{name} ({kib} KiB)"), unchanged(), args, &["file too large"])
                .with_disk_full_at(kib),
        );
    }
}

fn run_folder_cases(cases: &mut Vec<Case>) {
    const S: &str = "run/summary.json";
    let s = S;
    let list: Vec<(&str, Setup, &[&str])> = vec![
        (
            "validation rms null",
            edit_json(s, |v| v["validation"]["distances"]["calibrated"]["rms_mm"] = Value::Null),
            &["summary.json", "rms_mm"],
        ),
        (
            "validation rms text",
            edit_json(s, |v| v["validation"]["distances"]["calibrated"]["rms_mm"] = json!("0.15")),
            &["summary.json", "rms_mm"],
        ),
        (
            "pairs negative",
            edit_json(s, |v| v["validation"]["distances"]["calibrated"]["count"] = json!(-3)),
            &["summary.json", "count"],
        ),
        (
            "calibration missing",
            edit_json(s, |v| {
                v.as_object_mut().unwrap().remove("calibration");
            }),
            &["summary.json", "calibration"],
        ),
        ("options null", edit_json(s, |v| v["options"] = Value::Null), &["summary.json", "options"]),
        (
            "huber null",
            edit_json(s, |v| v["options"]["huber_delta_mm"] = Value::Null),
            &["summary.json", "huber_delta_mm"],
        ),
        (
            "restarts 1e9 (diagnose would refit with them)",
            edit_json(s, |v| v["options"]["restarts"] = json!(1_000_000_000u64)),
            &["summary.json", "options.restarts", "at most 1000"],
        ),
        (
            "huber 0",
            edit_json(s, |v| v["options"]["huber_delta_mm"] = json!(0.0)),
            &["summary.json", "options.huber_delta_mm"],
        ),
        (
            "huber negative",
            edit_json(s, |v| v["options"]["huber_delta_mm"] = json!(-5.0)),
            &["summary.json", "options.huber_delta_mm"],
        ),
        (
            "unknown added effect",
            edit_json(s, |v| v["inputs"]["add"] = json!(["nonsense:9"])),
            &["summary.json", "inputs.add", "nonsense:9"],
        ),
        (
            "format of a study",
            edit_json(s, |v| v["format"] = json!("kincal-study/1")),
            &["summary.json", "format", "kincal-run/2"],
        ),
        (
            "format missing",
            edit_json(s, |v| {
                v.as_object_mut().unwrap().remove("format");
            }),
            &["summary.json", "format"],
        ),
        (
            "inputs moved away",
            edit_json(s, |v| v["inputs"]["artefact"] = json!("/nonexistent/artefact.json")),
            &["artefact.json"],
        ),
        (
            "summary truncated",
            Box::new(|d: &Path| {
                let t = std::fs::read_to_string(d.join(S)).unwrap();
                std::fs::write(d.join(S), &t[..t.len() / 2]).unwrap();
            }),
            &["summary.json"],
        ),
        (
            "summary missing",
            Box::new(|d: &Path| std::fs::remove_file(d.join(S)).unwrap()),
            &["summary.json", "no such file"],
        ),
        (
            "model missing",
            Box::new(|d: &Path| std::fs::remove_file(d.join("run/model.toml")).unwrap()),
            &["model.toml", "no such file"],
        ),
        (
            "model edited to nan",
            replace("run/model.toml", "scale_ppm = 0.0", "scale_ppm = nan"),
            &["model.toml", "scale"],
        ),
        ("not a run", unchanged(), &[]),
    ];
    for (name, setup, needles) in list {
        let args = if name == "not a run" {
            words(&["diagnose", "data"], &[])
        } else {
            words(&["diagnose", "run"], &[])
        };
        cases.push(Case::fails(&format!("run/diagnose: {name}"), setup, args, needles));
    }
    const R: &str = "run/residuals.json";
    let r = R;
    let compare: Vec<(&str, Setup, &[&str])> = vec![
        (
            "residuals error null",
            edit_json(r, |v| v["pairs"][3]["error_mm"] = Value::Null),
            &["residuals.json", "error_mm"],
        ),
        (
            "residuals angles of 5",
            edit_json(r, |v| {
                v["pairs"][0]["enc_deg"][0].as_array_mut().unwrap().pop();
            }),
            &["residuals.json", "enc_deg"],
        ),
        (
            "residuals format",
            edit_json(r, |v| v["format"] = json!("kincal-residuals/9")),
            &["residuals.json", "format"],
        ),
        (
            "residuals missing",
            Box::new(|d: &Path| std::fs::remove_file(d.join(R)).unwrap()),
            &["residuals.json"],
        ),
        (
            "summary null rms",
            edit_json(s, |v| v["validation"]["distances"]["nominal"]["rms_mm"] = Value::Null),
            &["summary.json", "rms_mm"],
        ),
        (
            "residuals error 1e308",
            edit_json(r, |v| v["pairs"][3]["error_mm"] = json!(1e308)),
            &["residuals.json", "pairs[3].error_mm", "1e308"],
        ),
        (
            "residuals error -1e12",
            edit_json(r, |v| v["pairs"][0]["error_mm"] = json!(-1e12)),
            &["residuals.json", "pairs[0].error_mm"],
        ),
        (
            "residuals angle 1e308",
            edit_json(r, |v| v["pairs"][2]["enc_deg"][1][4] = json!(1e308)),
            &["residuals.json", "pairs[2].enc_deg[1][4]", "[0, 360)"],
        ),
        (
            "summary validation rms 1e308",
            edit_json(s, |v| v["validation"]["distances"]["calibrated"]["rms_mm"] = json!(1e308)),
            &["summary.json", "validation.distances.calibrated.rms_mm", "1e308"],
        ),
        (
            "summary per-landmark max -5",
            edit_json(s, |v| {
                v["validation"]["distances"]["detail"]["per_landmark"][2]["stats"]["max_mm"] = json!(-5.0)
            }),
            &["summary.json", "validation.distances.detail.per_landmark[2].stats.max_mm"],
        ),
        (
            "summary calibration rms 1e300",
            edit_json(s, |v| v["calibration"]["rms_mm"] = json!(1e300)),
            &["summary.json", "calibration.rms_mm"],
        ),
        ("run is a file", unchanged(), &["model.toml"]),
    ];
    for (name, setup, needles) in compare {
        let args = if name == "run is a file" {
            words(&["compare", "run", "model.toml", "--out", "cmp.html"], &[])
        } else {
            words(&["compare", "run", "run", "--out", "cmp.html"], &[])
        };
        cases.push(Case::fails(&format!("run/compare: {name}"), setup, args, needles));
    }
    cases.push(Case::succeeds(
        "run/diagnose a valid run",
        unchanged(),
        words(&["diagnose", "run"], &[]),
        exists("run/diagnosis.json"),
    ));
    cases.push(Case::succeeds(
        "run/compare a valid run with itself",
        unchanged(),
        words(&["compare", "run", "run", "--out", "cmp.html"], &[]),
        exists("cmp.html"),
    ));
}

/// Point run/summary.json's inputs at this case's copies, so a mutation of data/ reaches
/// `diagnose run`.
fn run_reads_case_data() -> Setup {
    Box::new(|d: &Path| {
        let path = d.join("run/summary.json");
        let mut v: Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        for (key, rel) in
            [("artefact", "data/artefact.json"), ("calibration", "data/cal"), ("validation", "data/val")]
        {
            v["inputs"][key] = json!(d.join(rel).canonicalize().unwrap());
        }
        std::fs::write(path, serde_json::to_string_pretty(&v).unwrap()).unwrap();
    })
}

/// An entry `data/cal/NAME` that is not a regular file, made by `make(path)`.
fn entry(name: &'static str, make: fn(&Path)) -> Setup {
    Box::new(move |d: &Path| make(&d.join("data/cal").join(name)))
}

/// (case, entry name, how the entry is made, what the error must say).
type EntryCase = (&'static str, &'static str, fn(&Path), &'static [&'static str]);

/// Session-folder entries that are not regular files (issue 21, item 1): named and refused by
/// every command that reads the folder, never skipped.
/// Tracker RUNs read back (issue 27): a figure out of range, another arm's model beside the
/// summary, a comparison with no held-out session in common; each refused naming the file and
/// field, never evaluated.
fn tracker_run_cases(cases: &mut Vec<Case>) {
    let diagnose = || words(&["diagnose", "trun"], &[]);
    cases.push(Case::fails(
        "tracker run/a held-out rms_mm of 1e308",
        edit_json("trun/summary.json", |v| {
            v["validation"]["sessions"]["sessions"][0]["rms_mm"] = json!(1e308)
        }),
        diagnose(),
        &["trun/summary.json", "validation.sessions.sessions[0].rms_mm", "1e308"],
    ));
    cases.push(Case::fails(
        "tracker run/a calibration rms_mm of 1e308",
        edit_json("trun/summary.json", |v| v["calibration"]["rms_mm"] = json!(1e308)),
        diagnose(),
        &["trun/summary.json", "calibration.rms_mm", "1e308"],
    ));
    cases.push(Case::fails(
        "tracker run/another arm's model.toml",
        Box::new(|d: &Path| {
            std::fs::copy(d.join("model.toml"), d.join("trun/model.toml")).unwrap();
        }),
        diagnose(),
        &["trun/summary.json", "joints", "7 joints", "has 6"],
    ));
    cases.push(Case::fails(
        "tracker run/compare with no held-out session in common",
        unchanged(),
        words(&["compare", "run", "trun", "--out", "c.html"], &[]),
        &["run and trun", "the same held-out data"],
    ));
}

fn entry_cases(cases: &mut Vec<Case>) {
    let list: [EntryCase; 5] = [
        (
            "dangling symlink",
            "x.json",
            |p| std::os::unix::fs::symlink("gone.json", p).unwrap(),
            &["x.json", "symlink", "dangling"],
        ),
        (
            "symlink loop",
            "loop.json",
            |p| std::os::unix::fs::symlink("loop.json", p).unwrap(),
            &["loop.json", "symlink", "loop"],
        ),
        (
            "symlink to /dev/zero",
            "z.json",
            |p| std::os::unix::fs::symlink("/dev/zero", p).unwrap(),
            &["z.json", "a device"],
        ),
        ("folder named x.json", "x.json", |p| std::fs::create_dir(p).unwrap(), &["x.json", "a folder"]),
        (
            "FIFO",
            "f.json",
            |p| assert!(Command::new("mkfifo").arg(p).status().unwrap().success()),
            &["f.json", "FIFO"],
        ),
    ];
    for (what, name, make, needles) in list {
        cases.push(Case::fails(
            &format!("entries/calibrate: {what}"),
            entry(name, make),
            words(&cal(), &[]),
            needles,
        ));
        cases.push(Case::fails(
            &format!("entries/study: {what}"),
            entry(name, make),
            words(&study(), &[]),
            needles,
        ));
        cases.push(Case::fails(
            &format!("entries/diagnose: {what}"),
            all(vec![run_reads_case_data(), entry(name, make)]),
            words(&["diagnose", "run"], &[]),
            needles,
        ));
    }
    // The same entries named *.csv in a tracker folder (issue 27).
    for (what, name, make, needles) in list {
        let csv = name.replace(".json", ".csv");
        let needles: Vec<String> =
            needles.iter().map(|n| n.replace(".json", ".csv")).chain(["tracker/cal".into()]).collect();
        let needles: Vec<&str> = needles.iter().map(String::as_str).collect();
        cases.push(Case::fails(
            &format!("entries/tracker folder: {what}"),
            Box::new(move |d: &Path| make(&d.join("tracker/cal").join(&csv))),
            tracker_cal(&[]),
            &needles,
        ));
    }
    cases.push(Case::fails(
        "entries/model is a FIFO",
        Box::new(|d: &Path| {
            std::fs::remove_file(d.join("model.toml")).unwrap();
            assert!(Command::new("mkfifo").arg(d.join("model.toml")).status().unwrap().success());
        }),
        words(&cal(), &[]),
        &["model.toml", "FIFO"],
    ));
    // A symlink to a regular session file is followed: it is a session like any other.
    cases.push(Case::succeeds(
        "entries/a symlink to a session is read",
        Box::new(|d: &Path| {
            std::fs::rename(d.join(CA), d.join("C_A.json")).unwrap();
            std::os::unix::fs::symlink(d.join("C_A.json"), d.join(CA)).unwrap();
        }),
        words(&cal(), &[]),
        calibrated("out", 225),
    ));
}

/// Edit run/model.toml (the calibrated model) and run/nominal.toml through `edit`.
fn run_models(edit: fn(&mut kincal::model::ArmModel)) -> Setup {
    Box::new(move |d: &Path| {
        for name in ["run/model.toml", "run/nominal.toml"] {
            let mut model = kincal::model::ArmModel::load(&d.join(name)).unwrap();
            edit(&mut model);
            model.save(&d.join(name)).unwrap();
        }
    })
}

/// Plausible-looking wrong models (issue 21, item 2): the figures are not a result, exit 1,
/// whatever the command; the reason names the artefact's scale.
fn wrong_model_cases(cases: &mut Vec<Case>) {
    let scale = &["not trustworthy", "largest certified distance"][..];
    let list: Vec<(&str, Setup)> = vec![
        (
            "sign flipped: d5 = -371 mm",
            all(vec![
                model_joint(5, "d_mm", "-371.0"),
                replace("model.toml", "[361.0, 381.0]", "[-381.0, -361.0]"),
            ]),
        ),
        (
            "length in metres: d3 = 0.571",
            all(vec![
                model_joint(3, "d_mm", "0.571"),
                replace("model.toml", "[561.0, 581.0]", "[-9.429, 10.571]"),
            ]),
        ),
        (
            "joints 3 and 5 swapped",
            all(vec![
                model_joint(3, "offset_deg", "88.7"),
                model_joint(3, "d_mm", "371.0"),
                model_joint(3, "alpha_deg", "90.0"),
                model_joint(5, "offset_deg", "201.3"),
                model_joint(5, "d_mm", "571.0"),
                model_joint(5, "alpha_deg", "-90.0"),
                replace("model.toml", "\"offset:3\" = [191.3, 211.3]", "\"offset:3\" = [78.7, 98.7]"),
                replace("model.toml", "\"offset:5\" = [78.7, 98.7]", "\"offset:5\" = [191.3, 211.3]"),
                replace("model.toml", "\"length:3\" = [561.0, 581.0]", "\"length:3\" = [361.0, 381.0]"),
                replace("model.toml", "\"length:5\" = [361.0, 381.0]", "\"length:5\" = [561.0, 581.0]"),
            ]),
        ),
        (
            "another arm: a PUMA's link lengths along x",
            all(vec![model_joint(2, "a_mm", "431.8"), model_joint(3, "a_mm", "20.3")]),
        ),
        (
            "180 degree offset on joint 2",
            all(vec![model_joint(2, "offset_deg", "200.7"), replace("model.toml", BOUNDS, "[190.7, 210.7]")]),
        ),
    ];
    for (name, setup) in list {
        cases.push(Case::fails(&format!("wrong model/calibrate: {name}"), setup, words(&cal(), &[]), scale));
    }
    cases.push(Case::fails(
        "wrong model/study: d5 = -371 mm",
        all(vec![
            model_joint(5, "d_mm", "-371.0"),
            replace("model.toml", "[361.0, 381.0]", "[-381.0, -361.0]"),
        ]),
        words(&study(), &[]),
        &["study has no result", "model-independent scales"],
    ));
    cases.push(Case::fails(
        "wrong model/diagnose: a RUN whose model has d5 = -371 mm",
        run_models(|m| {
            m.joints[4].d_mm = -m.joints[4].d_mm;
            for f in m.free.iter_mut().filter(|f| f.id == kincal::model::ParamId::Length(4)) {
                (f.lower, f.upper) = (-f.upper, -f.lower);
            }
        }),
        words(&["diagnose", "run"], &[]),
        &["does not describe these touches", "largest certified distance"],
    ));
}

/// `diagnose` refuses what `calibrate` refuses, with the same message (issue 21, items 3 and 4).
fn diagnose_refusal_cases(cases: &mut Vec<Case>) {
    // Every touch its own repeat: no two landmarks share a (placement, repeat), so no pair.
    let own_repeats = || -> Setup {
        Box::new(|d: &Path| {
            for f in std::fs::read_dir(d.join("data/cal")).unwrap() {
                let p = f.unwrap().path();
                let mut v: Value = serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
                for (k, m) in v["measurements"].as_array_mut().unwrap().iter_mut().enumerate() {
                    m["repeat"] = json!(k + 1);
                }
                std::fs::write(p, v.to_string()).unwrap();
            }
        })
    };
    let needles = &["0 landmark pairs cannot determine"][..];
    cases.push(Case::fails(
        "refusals/calibrate: no distance pair",
        own_repeats(),
        words(&cal(), &[]),
        needles,
    ));
    cases.push(Case::fails(
        "refusals/diagnose: no distance pair",
        all(vec![run_reads_case_data(), own_repeats()]),
        words(&["diagnose", "run"], &[]),
        needles,
    ));
    cases.push(Case::fails(
        "refusals/diagnose: the RUN's model frees no parameter",
        run_models(|m| m.free.clear()),
        words(&["diagnose", "run"], &[]),
        &["no free parameter"],
    ));
    cases.push(Case::fails(
        "refusals/diagnose --auto: the RUN's model frees no parameter",
        run_models(|m| m.free.clear()),
        words(&["diagnose", "run", "--auto"], &[]),
        &["no free parameter"],
    ));
}

/// Every numeric leaf of a JSON value, as JSON pointers.
fn numbers(value: &Value, at: String, out: &mut Vec<String>) {
    match value {
        Value::Number(_) => out.push(at),
        Value::Array(items) => {
            items.iter().enumerate().for_each(|(i, v)| numbers(v, format!("{at}/{i}"), out))
        }
        Value::Object(map) => map.iter().for_each(|(k, v)| numbers(v, format!("{at}/{k}"), out)),
        _ => {}
    }
}

/// Seeded random mutations of one number in the artefact or a session: either a clear error
/// naming the file (or a result marked not trustworthy), or a finite result over some pairs.
fn random_cases(cases: &mut Vec<Case>, template: &Path) {
    use rand::{RngExt, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let files = ["data/artefact.json", "data/cal/C_B.json", "data/val/V_D.json"];
    let replacements = [
        json!(null),
        json!("12"),
        json!(true),
        json!(-1),
        json!(0),
        json!(1e308),
        json!(-1e308),
        json!(359.999_999),
        json!(4_294_967_296_u64),
        json!([1.0]),
    ];
    for k in 0..60 {
        let file = files[k % files.len()];
        let value: Value =
            serde_json::from_str(&std::fs::read_to_string(template.join(file)).unwrap()).unwrap();
        let mut leaves = Vec::new();
        numbers(&value, String::new(), &mut leaves);
        let pointer = leaves[rng.random_range(0..leaves.len())].clone();
        let (by, scale) =
            (replacements[rng.random_range(0..replacements.len())].clone(), rng.random_range(0..3));
        let name = file.rsplit('/').next().unwrap().to_string();
        let label = format!("random/{k} {file}{pointer} = {by}{}", ["", " (scaled)", " (nudged)"][scale]);
        let setup = edit_json(file, move |v| {
            let Some(leaf) = v.pointer_mut(&pointer) else { return };
            *leaf = match (scale, leaf.as_f64()) {
                (1, Some(x)) => json!(x * 1000.0),
                (2, Some(x)) => json!(x + 0.5),
                _ => by.clone(),
            };
        });
        let finite: Check = Box::new(|dir: &Path| {
            let s: Value = serde_json::from_str(
                &std::fs::read_to_string(dir.join("out/summary.json")).map_err(|e| e.to_string())?,
            )
            .map_err(|e| e.to_string())?;
            let rms = s["validation"]["distances"]["calibrated"]["rms_mm"].as_f64().unwrap_or(f64::NAN);
            let pairs = s["validation"]["distances"]["calibrated"]["count"].as_u64().unwrap_or(0);
            (rms.is_finite() && pairs > 0)
                .then_some(())
                .ok_or(format!("validation {rms} mm over {pairs} pairs"))
        });
        cases.push(Case {
            name: label,
            setup,
            args: words(&cal(), &[]),
            expect: Expect::Either(vec![name, "not trustworthy".into()], Some(finite)),
            max_file_kib: None,
        });
    }
}

/// Every case of the corpus.
/// Station key files for `upload --key` (read before any controller is contacted: the port has
/// no controller behind it) and `key new`.
fn key_cases(cases: &mut Vec<Case>) {
    const SECRET: &str = "4b1d2c3e4f5a6b7c8d9e0f1a2b3c4d5e6f7a8b9c0d1e2f3a4b5c6d7e8f9a0b1c";
    let upload = || words(&["upload", "--port", "tcp:127.0.0.1:9", "model.toml"], &["--key", "station.key"]);
    let mut fails = |name: &str, setup: Setup, needles: &[&str]| {
        cases.push(Case::fails(&format!("key/{name}"), setup, upload(), needles))
    };
    fails("missing", unchanged(), &["station.key", "no such station key", "kincal key new"]);
    fails("empty", write("station.key", ""), &["station.key is empty", "kincal-station-key/1"]);
    fails("blank lines", write("station.key", "\n\n"), &["station.key is empty"]);
    fails(
        "pem private key",
        write("station.key", "-----BEGIN OPENSSH PRIVATE KEY-----\nb3BlbnNzaC1rZXktdjEAAAAA\n-----END OPENSSH PRIVATE KEY-----\n"),
        &["station.key line 1", "pem file", "not a kincal station key"],
    );
    fails(
        "public key instead of the secret",
        write("station.key", &format!("kincal-station-public-key/1\n{SECRET}\n")),
        &["station.key line 1", "public key", "secret key file"],
    );
    fails(
        "short secret",
        write("station.key", "kincal-station-key/1\n4b1d2c\n"),
        &["station.key line 2", "64 hex digits"],
    );
    fails(
        "secret not hex",
        write("station.key", &format!("kincal-station-key/1\n{}\n", SECRET.replace('4', "g"))),
        &["station.key line 2", "64 hex digits"],
    );
    // Readable by others (written with the default 0644): warned, then used (here the upload
    // stops at the port with no controller behind it).
    fails(
        "readable by others",
        write("station.key", &format!("kincal-station-key/1\n{SECRET}\n")),
        &["warning: station.key can be read by others", "chmod 600 station.key", "tcp:127.0.0.1:9"],
    );
    let no_key = words(&["upload", "--port", "tcp:127.0.0.1:9", "model.toml"], &[]);
    cases.push(Case::fails(
        "key/upload without --key",
        unchanged(),
        no_key,
        &["pass --key", "kincal key new"],
    ));
    cases.push(Case::fails(
        "key/new over an existing file",
        unchanged(),
        words(&["key", "new", "--out", "model.toml"], &[]),
        &["model.toml exists", "never replaces a key file"],
    ));
    let owner_only: Check = Box::new(|dir: &Path| {
        use std::os::unix::fs::PermissionsExt;
        let mode = std::fs::metadata(dir.join("new.key")).map_err(|e| e.to_string())?.permissions().mode();
        let public = std::fs::read_to_string(dir.join("new.key.pub")).map_err(|e| e.to_string())?;
        match (mode & 0o777, public.starts_with("kincal-station-public-key/1\n")) {
            (0o600, true) => Ok(()),
            (mode, public) => Err(format!("key mode {mode:o}, public key file written: {public}")),
        }
    });
    cases.push(Case::succeeds(
        "key/new",
        unchanged(),
        words(&["key", "new", "--out", "new.key"], &[]),
        Some(owner_only),
    ));
}

/// Arm identities, RUN dates and validity periods (issue 32), refused before any controller is
/// contacted (the port has none behind it), and the emulated arm's script options.
fn trace_cases(cases: &mut Vec<Case>) {
    const SECRET: &str = "4b1d2c3e4f5a6b7c8d9e0f1a2b3c4d5e6f7a8b9c0d1e2f3a4b5c6d7e8f9a0b1c";
    let append = |file: &'static str, text: &'static str| -> Setup {
        Box::new(move |d: &Path| {
            let t = std::fs::read_to_string(d.join(file)).unwrap();
            std::fs::write(d.join(file), format!("{t}\n{text}")).unwrap();
        })
    };
    for (name, text, needles) in [
        (
            "arm id with a space",
            "[arm]\nid = \"lab arm\"\n",
            &["model.toml", "arm.id", "not an arm identity"][..],
        ),
        ("arm id empty", "[arm]\nid = \"\"\n", &["model.toml", "arm.id"]),
        ("arm id of 25 characters", "[arm]\nid = \"aaaaaaaaaaaaaaaaaaaaaaaaa\"\n", &["model.toml", "arm.id"]),
        ("arm without id", "[arm]\nfirmware = \"fw\"\n", &["model.toml", "id"]),
        ("arm with an unknown key", "[arm]\nid = \"a\"\nserial = 7\n", &["model.toml", "serial"]),
        (
            "arm firmware with a newline",
            "[arm]\nid = \"a\"\nfirmware = \"fw\\n2\"\n",
            &["model.toml", "arm.firmware"],
        ),
    ] {
        cases.push(Case::fails(
            &format!("trace/model {name}"),
            append("model.toml", text),
            words(&cal(), &[]),
            needles,
        ));
    }
    let key = || write("station.key", &format!("kincal-station-key/1\n{SECRET}\n"));
    let upload = |model: &str, extra: &[&str]| {
        words(&["upload", "--key", "station.key", "--port", "tcp:127.0.0.1:9", model], extra)
    };
    let mut fails = |name: &str, setup: Setup, args: Vec<String>, needles: &[&str]| {
        cases.push(Case::fails(&format!("trace/{name}"), setup, args, needles))
    };
    fails(
        "upload --valid-days of a model not in a RUN",
        key(),
        upload("model.toml", &["--valid-days", "30"]),
        &["--valid-days", "model.toml", "not a RUN's model"],
    );
    fails(
        "upload --valid-days 0",
        key(),
        upload("run/model.toml", &["--valid-days", "0"]),
        &["--valid-days 0"],
    );
    fails("upload --valid-days -3", key(), upload("run/model.toml", &["--valid-days=-3"]), &["--valid-days"]);
    // Issue 27: a parameter on its bound is never uploaded silently; --allow-on-bound lets it
    // through (here the upload then stops at the port with no controller behind it).
    let on_bound = || {
        all(vec![key(), replace("model.toml", "tcp_mm = [0.0, 0.0, 253.0]", "tcp_mm = [0.0, 0.0, 243.0]")])
    };
    fails(
        "upload a parameter on its bound",
        on_bound(),
        upload("model.toml", &[]),
        &[
            "model.toml",
            "tcp.z on its lower bound (243)",
            "not a result",
            "--allow-on-bound",
            "nothing was uploaded",
        ],
    );
    fails(
        "upload a parameter on its bound, allowed",
        on_bound(),
        upload("model.toml", &["--allow-on-bound"]),
        &["tcp:127.0.0.1:9"],
    );
    fails(
        "upload a validity that has passed",
        all(vec![key(), edit_json("run/summary.json", |v| v["validated_at_unix_s"] = json!(1_000_000_000))]),
        upload("run/model.toml", &["--valid-days", "365"]),
        &["valid for 365 days", "2002-09-09", "before this upload"],
    );
    fails(
        "upload a RUN whose date is text",
        all(vec![key(), edit_json("run/summary.json", |v| v["validated_at_unix_s"] = json!("yesterday"))]),
        upload("run/model.toml", &[]),
        &["summary.json", "validated_at_unix_s", "Unix seconds"],
    );
    fails(
        "upload a RUN whose date is 0",
        all(vec![key(), edit_json("run/summary.json", |v| v["validated_at_unix_s"] = json!(0))]),
        upload("run/model.toml", &[]),
        &["summary.json", "validated_at_unix_s"],
    );
    fails(
        "upload a RUN without its summary's file",
        all(vec![key(), Box::new(|d: &Path| std::fs::create_dir_all(d.join("run/summary.json.d")).unwrap())]),
        upload("run/nominal.toml", &["--valid-days", "5"]),
        &["nominal.toml", "not a RUN's model"],
    );
    fails(
        "check with one repeat",
        unchanged(),
        words(
            &[
                "check",
                "--port",
                "tcp:127.0.0.1:9",
                "--artefact",
                "data/artefact.json",
                "--placement",
                "V_A",
                "--out",
                "c",
                "--repeats",
                "1",
            ],
            &[],
        ),
        &["--repeats", "1"],
    );
    let script = |extra: &[&str]| {
        words(
            &[
                "emulated-arm",
                "script",
                "--geometry",
                "data/truth.toml",
                "--artefact",
                "data/artefact.json",
                "--placement",
                "V_A",
            ],
            extra,
        )
    };
    fails(
        "script knock without a delta",
        unchanged(),
        script(&["--knock", "offset:2", "--out", "s.json"]),
        &["--knock offset:2", "PARAM=DELTA"],
    );
    fails(
        "script knock of an unknown parameter",
        unchanged(),
        script(&["--knock", "wobble:2=1", "--out", "s.json"]),
        &["--knock wobble:2=1"],
    );
    fails(
        "script knock of a joint the arm lacks",
        unchanged(),
        script(&["--knock", "offset:9=1", "--out", "s.json"]),
        &["--knock offset:9=1"],
    );
    fails(
        "script knock nan",
        unchanged(),
        script(&["--knock", "offset:2=nan", "--out", "s.json"]),
        &["--knock offset:2=nan"],
    );
    fails(
        "script over an existing file",
        unchanged(),
        script(&["--out", "model.toml"]),
        &["model.toml exists", "never replaces"],
    );
    fails(
        "script seating noise negative",
        unchanged(),
        script(&["--seating-noise-mm=-1", "--out", "s.json"]),
        &["--seating-noise-mm"],
    );
    fails(
        "script of a 7-joint geometry",
        unchanged(),
        words(
            &[
                "emulated-arm",
                "script",
                "--geometry",
                "tracker/model.toml",
                "--artefact",
                "data/artefact.json",
                "--placement",
                "V_A",
                "--out",
                "s.json",
            ],
            &[],
        ),
        &["tracker/model.toml", "6 joints"],
    );
    fails(
        "start with a bad arm id",
        unchanged(),
        words(&["emulated-arm", "start", "--arm-id", "arm,A"], &[]),
        &["--arm-id", "arm,A"],
    );
    cases.push(Case::succeeds(
        "trace/script of the simulated arm",
        unchanged(),
        script(&["--repeats", "2", "--out", "s.json"]),
        Some(Box::new(|dir: &Path| {
            let text = std::fs::read_to_string(dir.join("s.json")).map_err(|e| e.to_string())?;
            let steps = serde_json::from_str::<Value>(&text).map_err(|e| e.to_string())?["steps"]
                .as_array()
                .map_or(0, |s| s.len());
            (steps == 30).then_some(()).ok_or(format!("{steps} steps, expected 15 landmarks × 2"))
        })),
    ));
}

fn corpus(template: &Path) -> Vec<Case> {
    let mut cases = Vec::new();
    random_cases(&mut cases, template);
    model_cases(&mut cases);
    artefact_cases(&mut cases);
    session_cases(&mut cases);
    option_cases(&mut cases);
    output_cases(&mut cases);
    run_folder_cases(&mut cases);
    entry_cases(&mut cases);
    tracker_run_cases(&mut cases);
    wrong_model_cases(&mut cases);
    diagnose_refusal_cases(&mut cases);
    disk_full_cases(&mut cases);
    tracker_cases(&mut cases);
    tracker_file_cases(&mut cases);
    urdf_cases(&mut cases);
    key_cases(&mut cases);
    trace_cases(&mut cases);
    cases
}

#[test]
fn every_bad_input_ends_in_a_clear_error_or_a_correct_result() {
    let root = std::env::temp_dir().join(format!("kincal-bad-inputs-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let template = template(&root);
    let cases = corpus(&template);
    assert!(cases.len() >= 300, "only {} cases", cases.len());
    assert_all_pass(&kincal_bin(), &template, &root.join("cases"), &cases, Duration::from_secs(60));
    std::fs::remove_dir_all(&root).ok();
}
