//! The bad-input corpus of the model layer (issue 27): URDFs and models as users bring them, the
//! public arms of `tests/data/urdf/` mutated the ways a user gets them wrong, and outputs that
//! would land on an input. Each case ends in a clear error naming the file, line, joint or
//! option, or in a right result; the runner (`kincal_e2e::corpus`) also asserts for every case:
//! no panic, no hang, no user file lost or changed, no temporary left behind.

use kincal_e2e::corpus::{all, assert_all_pass, unchanged, words, write, Case, Check, Setup};
use kincal_e2e::kincal_bin;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

/// The public arms the cases use, with their chains: (model file, URDF, base, tip).
const ARMS: [(&str, &str, &str, &str); 5] = [
    ("ur5.toml", "ur5.urdf", "base_link", "tool0"),
    ("ur10.toml", "ur10.urdf", "base_link", "tool0"),
    ("baxter.toml", "baxter.urdf", "base", "left_gripper"),
    ("gen3.toml", "gen3_2f85.urdf", "gen3_base_link", "gen3_end_effector_link"),
    ("pr2.toml", "pr2.urdf", "torso_lift_link", "r_gripper_tool_frame"),
];

/// The valid inputs: the URDFs as published and the model `kincal model from-urdf` makes of each.
fn template(root: &Path) -> PathBuf {
    let t = root.join("template");
    std::fs::create_dir_all(&t).unwrap();
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/urdf");
    for (model, urdf, base, tip) in ARMS {
        std::fs::copy(data.join(urdf), t.join(urdf)).unwrap();
        let out = Command::new(kincal_bin())
            .args(["model", "from-urdf", urdf, "--base", base, "--tip", tip, "--out", model])
            .current_dir(&t)
            .output()
            .unwrap();
        assert!(out.status.success(), "from-urdf {urdf}: {}", String::from_utf8_lossy(&out.stderr));
    }
    t
}

fn fifo(name: &'static str) -> Setup {
    Box::new(move |d: &Path| {
        let _ = std::fs::remove_file(d.join(name));
        assert!(Command::new("mkfifo").arg(d.join(name)).status().unwrap().success());
    })
}

fn symlink(target: &'static str, name: &'static str) -> Setup {
    Box::new(move |d: &Path| {
        let _ = std::fs::remove_file(d.join(name));
        std::os::unix::fs::symlink(target, d.join(name)).unwrap();
    })
}

fn hard_link(target: &'static str, name: &'static str) -> Setup {
    Box::new(move |d: &Path| std::fs::hard_link(d.join(target), d.join(name)).unwrap())
}

fn folder(name: &'static str) -> Setup {
    Box::new(move |d: &Path| {
        let _ = std::fs::remove_file(d.join(name));
        std::fs::create_dir_all(d.join(name).join("inside")).unwrap();
    })
}

/// Edit the text file `file` with `edit`.
fn edit(file: &'static str, edit: impl Fn(&str) -> String + Send + Sync + 'static) -> Setup {
    Box::new(move |d: &Path| {
        let path = d.join(file);
        let text = std::fs::read_to_string(&path).unwrap();
        let edited = edit(&text);
        assert_ne!(edited, text, "{file}: the edit changed nothing");
        std::fs::write(path, edited).unwrap();
    })
}

/// Replace the first `from` after the line holding `anchor` in `file` by `to`.
fn after(file: &'static str, anchor: &'static str, from: &'static str, to: &'static str) -> Setup {
    edit(file, move |t| {
        let at = t.find(anchor).unwrap_or_else(|| panic!("{file}: no {anchor:?}"));
        let hit = at + t[at..].find(from).unwrap_or_else(|| panic!("{file}: no {from:?} after {anchor:?}"));
        format!("{}{to}{}", &t[..hit], &t[hit + from.len()..])
    })
}

/// The 1-based line of the first `needle` in the template's `file`.
fn line_of(file: &str, needle: &str) -> usize {
    let text =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("data/urdf").join(file)).unwrap();
    text[..text.find(needle).unwrap()].matches('\n').count() + 1
}

fn from_urdf(urdf: &str, base: &str, tip: &str, out: &str) -> Vec<String> {
    words(&["model", "from-urdf", urdf, "--base", base, "--tip", tip, "--out", out], &[])
}

fn to_urdf(model: &str, urdf: &str, out: &str, extra: &[&str]) -> Vec<String> {
    words(&["model", "to-urdf", model, "--urdf", urdf, "--out", out], extra)
}

fn ur5(out: &str) -> Vec<String> {
    from_urdf("ur5.urdf", "base_link", "tool0", out)
}

/// Outputs that would replace an input or a file of the user's (the template's models were written
/// by kincal, but the runner treats every file already there as the user's), and every write
/// atomic.
fn output_cases(cases: &mut Vec<Case>) {
    let to_ur5 = |out: &str| to_urdf("ur5.toml", "ur5.urdf", out, &[]);
    cases.extend([
        Case::fails(
            "out/from-urdf over its URDF",
            unchanged(),
            ur5("ur5.urdf"),
            &["ur5.urdf", "--out", "is the same file as the input ur5.urdf"],
        ),
        Case::fails(
            "out/from-urdf over its URDF by another path",
            unchanged(),
            ur5("./ur5.urdf"),
            &["--out", "the same file as the input"],
        ),
        Case::fails(
            "out/from-urdf into a hard link of its URDF",
            hard_link("ur5.urdf", "copy.urdf"),
            ur5("copy.urdf"),
            &["copy.urdf", "--out", "is a hard link to the input ur5.urdf"],
        ),
        Case::fails(
            "out/from-urdf into a symlink to its URDF",
            symlink("ur5.urdf", "link.toml"),
            ur5("link.toml"),
            &["link.toml", "--out", "is a symlink to the input ur5.urdf"],
        ),
        Case::fails(
            "out/from-urdf into a folder",
            folder("m.toml"),
            ur5("m.toml"),
            &["m.toml", "--out", "is a folder"],
        ),
        Case::fails(
            "out/to-urdf over the model",
            unchanged(),
            to_ur5("ur5.toml"),
            &["ur5.toml", "--out", "is the same file as the input ur5.toml"],
        ),
        Case::fails(
            "out/to-urdf over the URDF",
            unchanged(),
            to_ur5("ur5.urdf"),
            &["--out", "the same file as the input ur5.urdf"],
        ),
        Case::fails(
            "out/to-urdf into a hard link of the model",
            hard_link("ur5.toml", "c.urdf"),
            to_ur5("c.urdf"),
            &["c.urdf", "a hard link to the input ur5.toml"],
        ),
        Case::fails(
            "out/to-urdf into a symlink to the URDF",
            symlink("ur5.urdf", "c.urdf"),
            to_ur5("c.urdf"),
            &["c.urdf", "a symlink to the input ur5.urdf"],
        ),
        Case::fails(
            "out/to-urdf over another file of the user's",
            write("c.urdf", "mine"),
            to_ur5("c.urdf"),
            &["c.urdf", "--out", "kincal did not write it", "choose another name"],
        ),
        Case::fails(
            "out/from-urdf over a model of the user's",
            write("m.toml", "format = \"kincal-arm/1\"\n"),
            ur5("m.toml"),
            &["m.toml", "kincal did not write it"],
        ),
        Case::succeeds(
            "out/to-urdf into a new file",
            unchanged(),
            to_ur5("c.urdf"),
            Some(urdf_written("c.urdf", "ur5")),
        ),
        // PR2's URDF is 110 KB: on a disk that takes no file over 16 KiB the write fails, the
        // error names the file, and neither it nor a temporary is left behind.
        Case::fails(
            "out/to-urdf on a full disk",
            unchanged(),
            to_urdf("pr2.toml", "pr2.urdf", "c.urdf", &[]),
            &["c.urdf"],
        )
        .with_disk_full_at(16),
    ]);
}

fn urdf_written(file: &'static str, robot: &'static str) -> Check {
    Box::new(move |d: &Path| {
        let text = std::fs::read_to_string(d.join(file)).map_err(|e| e.to_string())?;
        text.contains(&format!("<robot name=\"{robot}\""))
            .then_some(())
            .ok_or(format!("{file} is not the URDF"))
    })
}

fn model_written(file: &'static str) -> Check {
    Box::new(move |d: &Path| {
        kincal::model::ArmModel::load(&d.join(file)).map(|_| ()).map_err(|e| e.to_string())
    })
}

/// Inputs that are not regular files: a clear error, never a hang.
fn file_type_cases(cases: &mut Vec<Case>) {
    let upload = words(&["upload", "--port", "tcp:127.0.0.1:9", "ur5.toml", "--key", "station.key"], &[]);
    cases.extend([
        Case::fails("type/a FIFO as --key", fifo("station.key"), upload.clone(), &["station.key", "FIFO"]),
        Case::fails(
            "type/--key a symlink to /dev/zero",
            symlink("/dev/zero", "station.key"),
            upload.clone(),
            &["station.key", "a device"],
        ),
        Case::fails(
            "type/--key a folder",
            folder("station.key"),
            upload.clone(),
            &["station.key", "a folder"],
        ),
        Case::fails(
            "type/--key a dangling symlink",
            symlink("gone.key", "station.key"),
            upload,
            &["station.key", "dangling"],
        ),
        Case::fails("type/a FIFO as the URDF", fifo("ur5.urdf"), ur5("m.toml"), &["ur5.urdf", "FIFO"]),
        Case::fails(
            "type/the URDF a symlink to /dev/zero",
            symlink("/dev/zero", "ur5.urdf"),
            ur5("m.toml"),
            &["ur5.urdf", "a device"],
        ),
        Case::fails("type/the URDF a folder", folder("ur5.urdf"), ur5("m.toml"), &["ur5.urdf", "a folder"]),
        Case::fails(
            "type/the URDF a dangling symlink",
            symlink("gone.urdf", "ur5.urdf"),
            ur5("m.toml"),
            &["ur5.urdf", "dangling"],
        ),
        Case::fails(
            "type/a FIFO as the model",
            fifo("ur5.toml"),
            to_urdf("ur5.toml", "ur5.urdf", "c.urdf", &[]),
            &["ur5.toml", "FIFO"],
        ),
        Case::fails(
            "type/the model a symlink to /dev/zero",
            symlink("/dev/zero", "ur5.toml"),
            to_urdf("ur5.toml", "ur5.urdf", "c.urdf", &[]),
            &["ur5.toml", "a device"],
        ),
        Case::fails(
            "type/to-urdf's URDF a FIFO",
            fifo("ur5.urdf"),
            to_urdf("ur5.toml", "ur5.urdf", "c.urdf", &[]),
            &["ur5.urdf", "FIFO"],
        ),
    ]);
}

/// URDFs from-urdf refuses, by file, line and joint.
fn from_urdf_cases(cases: &mut Vec<Case>) {
    let lift = line_of("ur5.urdf", "<joint name=\"shoulder_lift_joint\"");
    let elbow = line_of("ur5.urdf", "<joint name=\"elbow_joint\"");
    let lift_at = format!("ur5.urdf:{lift}: <joint name=\"shoulder_lift_joint\">");
    let elbow_at = format!("ur5.urdf:{elbow}: <joint name=\"elbow_joint\">/<origin>");
    cases.extend([
        Case::fails(
            "urdf/a missing link",
            after("ur5.urdf", "<joint name=\"shoulder_lift_joint\"", "<parent link=\"shoulder_link\"/>", "<parent link=\"shoulder\"/>"),
            ur5("m.toml"),
            &[&lift_at, "link shoulder is not declared"],
        ),
        Case::fails(
            "urdf/a loop away from the chain",
            edit("ur5.urdf", |t| {
                t.replace(
                    "</robot>",
                    "<link name=\"a\"/><link name=\"b\"/>\
                     <joint name=\"ab\" type=\"fixed\"><parent link=\"a\"/><child link=\"b\"/></joint>\
                     <joint name=\"ba\" type=\"fixed\"><parent link=\"b\"/><child link=\"a\"/></joint></robot>",
                )
            }),
            ur5("m.toml"),
            &["ur5.urdf:", "<joint name=", "the joints form a loop"],
        ),
        Case::fails(
            "urdf/an origin 1 km away",
            after("ur5.urdf", "<joint name=\"elbow_joint\"", "xyz=\"0.0 -0.1197 0.425\"", "xyz=\"1000 -0.1197 0.425\""),
            ur5("m.toml"),
            &[&elbow_at, "1000", "m from its parent", "at most 5 m", "URDF lengths are in metres"],
        ),
        Case::fails(
            "urdf/an origin 1e300 m away",
            after("ur5.urdf", "<joint name=\"elbow_joint\"", "xyz=\"0.0 -0.1197 0.425\"", "xyz=\"1e300 -0.1197 0.425\""),
            ur5("m.toml"),
            &[&elbow_at, "m from its parent", "URDF lengths are in metres"],
        ),
        Case::fails(
            "urdf/lengths in millimetres",
            after("ur5.urdf", "<joint name=\"elbow_joint\"", "xyz=\"0.0 -0.1197 0.425\"", "xyz=\"0.0 -119.7 425.0\""),
            ur5("m.toml"),
            &[&elbow_at, "URDF lengths are in metres"],
        ),
        Case::fails(
            "urdf/two joints of one name",
            edit("ur5.urdf", |t| t.replacen("name=\"elbow_joint\"", "name=\"shoulder_lift_joint\"", 1)),
            ur5("m.toml"),
            &["ur5.urdf:", "<joint name=\"shoulder_lift_joint\">", &format!("the first is on line {lift}"), "unique"],
        ),
        Case::fails(
            "urdf/a mimic joint in the chain",
            unchanged(),
            from_urdf("gen3_2f85.urdf", "gen3_base_link", "gen3_robotiq_85_left_finger_tip_link", "m.toml"),
            &["gen3_2f85.urdf:", "<joint name=\"gen3_robotiq_85_left_finger_tip_joint\">/<mimic>", "mimics joint gen3_robotiq_85_left_knuckle_joint"],
        ),
        Case::succeeds(
            "urdf/the arm before the gripper's mimic joints",
            unchanged(),
            from_urdf("gen3_2f85.urdf", "gen3_base_link", "gen3_robotiq_85_left_knuckle_link", "m.toml"),
            Some(model_written("m.toml")),
        ),
        Case::fails(
            "urdf/a xacro file",
            write(
                "arm.urdf.xacro",
                "<robot name=\"arm\" xmlns:xacro=\"http://wiki.ros.org/xacro\">\n<xacro:macro name=\"arm\" params=\"prefix\">\n<link name=\"${prefix}base\"/>\n</xacro:macro>\n<xacro:arm prefix=\"\"/>\n</robot>\n",
            ),
            from_urdf("arm.urdf.xacro", "base", "tool0", "m.toml"),
            &["arm.urdf.xacro", "a xacro file", "xacro arm.urdf.xacro > robot.urdf", "ros2 run xacro xacro"],
        ),
        Case::fails(
            "urdf/a xacro macro in a .urdf",
            edit("ur5.urdf", |t| t.replace("</robot>", "<xacro:include filename=\"$(find ur_description)/urdf/ur.transmission.xacro\"/></robot>")),
            ur5("m.toml"),
            &["ur5.urdf", "a xacro file", "xacro ur5.urdf > robot.urdf"],
        ),
    ]);
}

/// Models to-urdf refuses: another URDF, base or tip, naming both.
fn to_urdf_cases(cases: &mut Vec<Case>) {
    let unchanged_control: Check = Box::new(|d: &Path| {
        let (before, after) = (
            std::fs::read_to_string(d.join("gen3_2f85.urdf")).map_err(|e| e.to_string())?,
            std::fs::read_to_string(d.join("c.urdf")).map_err(|e| e.to_string())?,
        );
        let block =
            |t: &str| t[t.find("<ros2_control").unwrap()..t.find("</ros2_control>").unwrap()].to_string();
        if block(&before) != block(&after) {
            return Err("the <ros2_control> block changed".into());
        }
        // The kinematic joint gen3_joint_1 carries the 1° offset in its origin's yaw now.
        let joint = &after[after.find("<joint name=\"gen3_joint_1\" type").ok_or("no gen3_joint_1")?..];
        let origin = &joint[..joint.find("</joint>").unwrap()];
        (!origin.contains("rpy=\"3.1416 2.7629E-18 -4.9305E-36\""))
            .then_some(())
            .ok_or(format!("not calibrated: {origin}"))
    });
    cases.extend([
        Case::fails(
            "to-urdf/a UR10 model into ur5.urdf",
            unchanged(),
            to_urdf("ur10.toml", "ur5.urdf", "c.urdf", &[]),
            &[
                "ur5.urdf",
                "ur10.toml was made from ur10.urdf (robot ur10, chain base_link → tool0)",
                "chain hash",
                "this file (robot ur5)",
            ],
        ),
        Case::fails(
            "to-urdf/another --base",
            unchanged(),
            to_urdf("baxter.toml", "baxter.urdf", "c.urdf", &["--base", "torso"]),
            &[
                "--base torso",
                "baxter.toml is the chain base → left_gripper of baxter.urdf",
                "leave out --base or give base",
            ],
        ),
        Case::fails(
            "to-urdf/another --tip",
            unchanged(),
            to_urdf("baxter.toml", "baxter.urdf", "c.urdf", &["--tip", "left_hand"]),
            &["--tip left_hand", "chain base → left_gripper"],
        ),
        Case::fails(
            "to-urdf/an edited chain",
            after(
                "ur5.urdf",
                "<joint name=\"elbow_joint\"",
                "xyz=\"0.0 -0.1197 0.425\"",
                "xyz=\"0.0 -0.1197 0.4251\"",
            ),
            to_urdf("ur5.toml", "ur5.urdf", "c.urdf", &[]),
            &["ur5.urdf", "the chain differs from the one the model was made from", "chain hash"],
        ),
        Case::fails(
            "to-urdf/a renamed joint",
            edit("ur5.urdf", |t| t.replace("\"elbow_joint\"", "\"elbow\"")),
            to_urdf("ur5.toml", "ur5.urdf", "c.urdf", &[]),
            &["ur5.urdf:", "<joint name=\"elbow\">", "joint 3 of the chain is elbow_joint in the model"],
        ),
        Case::fails(
            "to-urdf/a model without its URDF record",
            edit("ur5.toml", |t| t[..t.find("[urdf]").unwrap()].to_string()),
            to_urdf("ur5.toml", "ur5.urdf", "c.urdf", &["--base", "base_link", "--tip", "tool0"]),
            &["the model is not this chain", "ur5.toml has 6 Urdf joints", "kincal model from-urdf"],
        ),
        Case::fails(
            "to-urdf/a model with an effect a URDF cannot hold",
            edit("ur5.toml", |t| {
                t.replacen("offset_deg = 0.0", "offset_deg = 0.0\neccentricity_sin_deg = 0.01", 1)
            }),
            to_urdf("ur5.toml", "ur5.urdf", "c.urdf", &[]),
            &["ur5.toml", "a URDF cannot carry eccentricity_sin:1 = 0.01 deg"],
        ),
        Case::succeeds(
            "to-urdf/the ROS 2 file: its ros2_control block untouched",
            edit("gen3.toml", |t| t.replacen("offset_deg = 0.0", "offset_deg = 1.0", 1)),
            to_urdf("gen3.toml", "gen3_2f85.urdf", "c.urdf", &[]),
            Some(unchanged_control),
        ),
        Case::succeeds(
            "to-urdf/with the model's own base and tip",
            unchanged(),
            to_urdf("baxter.toml", "baxter.urdf", "c.urdf", &["--base", "base", "--tip", "left_gripper"]),
            Some(urdf_written("c.urdf", "baxter")),
        ),
    ]);
}

/// A model file made before kincal turned URDF origins by ω: the old parameter names, explained.
fn old_model_cases(cases: &mut Vec<Case>) {
    cases.push(Case::fails(
        "model/roll-pitch-yaw parameters of an older kincal",
        all(vec![edit("ur5.toml", |t| t.replace("\"origin_rx:2\"", "\"origin_roll:2\""))]),
        to_urdf("ur5.toml", "ur5.urdf", "c.urdf", &[]),
        &["ur5.toml", "origin_roll:2", "origin_rx, origin_ry, origin_rz", "kincal model from-urdf"],
    ));
}

#[test]
fn every_bad_model_input_ends_in_a_clear_error_or_a_right_result() {
    let root = std::env::temp_dir().join(format!("kincal-bad-model-inputs-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let template = template(&root);
    let mut cases = Vec::new();
    output_cases(&mut cases);
    file_type_cases(&mut cases);
    from_urdf_cases(&mut cases);
    to_urdf_cases(&mut cases);
    old_model_cases(&mut cases);
    assert_all_pass(&kincal_bin(), &template, &root.join("cases"), &cases, Duration::from_secs(30));
    std::fs::remove_dir_all(&root).ok();
}
