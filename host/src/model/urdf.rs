//! URDF in and out: a serial chain of a URDF file as a `kincal-arm/1` model (convention
//! "urdf"), and a calibrated model written back into a copy of the URDF.
//!
//! The file is parsed with the `urdf-rs` crate. URDF lengths are metres and angles radians; the
//! model holds millimetres and degrees. Fixed joints between `base` and `tip` are folded into the
//! next revolute joint's origin (fixed joints after the last revolute joint into the tool point);
//! continuous joints are revolute; any other joint type in the chain is refused.
//! Writing back edits only the `<origin>` of each revolute joint of the chain, so every other
//! element (links, meshes, limits, comments) keeps its text.

use super::{ArmModel, Convention, Joint, ParamId, MAX_JOINTS};
use crate::files::FileError;
use nalgebra::{Isometry3, Rotation3, Translation3, Unit, UnitQuaternion, Vector3};
use std::path::Path;

/// Bounds given to each free origin translation by [`model_from_urdf`], ± mm.
pub const ORIGIN_HALF_RANGE_MM: f64 = 10.0;
/// Bounds given to each free origin angle and joint offset by [`model_from_urdf`], ± degrees.
pub const ORIGIN_HALF_RANGE_DEG: f64 = 5.0;

/// One revolute joint of the chain: its name in the URDF and the fixed joints folded before it.
#[derive(Clone, Debug)]
struct ChainJoint {
    name: String,
    /// Product of the fixed joints' origins between the previous revolute joint and this one.
    folded: Isometry3<f64>,
    origin: Isometry3<f64>,
    axis: Vector3<f64>,
}

fn field(path: &Path, field: String, message: String) -> FileError {
    FileError::Field { path: path.to_owned(), field, message }
}

/// Byte offset of the `<joint …>` element named `name` in `text`.
fn joint_start(text: &str, name: &str) -> Option<usize> {
    ["\"", "'"].iter().find_map(|q| {
        let needle = format!("name={q}{name}{q}");
        let mut from = 0;
        while let Some(i) = text[from..].find(&needle) {
            let at = from + i;
            let open = text[..at].rfind('<')?;
            if text[open..].starts_with("<joint") {
                return Some(open);
            }
            from = at + needle.len();
        }
        None
    })
}

/// An error at the joint `name` of the URDF `text`, with the joint's line (1 when not found).
fn at_joint(path: &Path, text: &str, name: &str, what: &str, message: String) -> FileError {
    let line = joint_start(text, name).map_or(1, |at| text[..at].matches('\n').count() + 1);
    FileError::Element {
        path: path.to_owned(),
        line,
        element: format!("<joint name=\"{name}\">{what}"),
        message,
    }
}

fn read_robot(path: &Path) -> Result<(String, urdf_rs::Robot), FileError> {
    crate::files::check_regular_file(path)?;
    let text =
        std::fs::read_to_string(path).map_err(|source| FileError::Io { path: path.to_owned(), source })?;
    let robot = urdf_rs::read_from_string(&text).map_err(|e| FileError::Syntax {
        path: path.to_owned(),
        message: format!("not a URDF robot description: {e}"),
    })?;
    Ok((text, robot))
}

fn origin_of(pose: &urdf_rs::Pose) -> Isometry3<f64> {
    let [x, y, z] = pose.xyz.0;
    let [roll, pitch, yaw] = pose.rpy.0;
    Isometry3::from_parts(
        Translation3::new(x * 1000.0, y * 1000.0, z * 1000.0),
        UnitQuaternion::from_euler_angles(roll, pitch, yaw),
    )
}

/// The revolute joints from `base` to `tip`, and the fixed transform after the last one.
fn chain(
    path: &Path,
    text: &str,
    robot: &urdf_rs::Robot,
    base: &str,
    tip: &str,
) -> Result<(Vec<ChainJoint>, Isometry3<f64>), FileError> {
    for (what, link) in [("--base", base), ("--tip", tip)] {
        if !robot.links.iter().any(|l| l.name == link) {
            let names: Vec<&str> = robot.links.iter().map(|l| l.name.as_str()).collect();
            return Err(field(
                path,
                format!("<link name=\"{link}\">"),
                format!("no such link ({what}); the file's links are {}", names.join(", ")),
            ));
        }
    }
    // Walk from the tip to the base through each link's parent joint.
    let mut walked = Vec::new();
    let mut link = tip;
    while link != base {
        let mut parents = robot.joints.iter().filter(|j| j.child.link == link);
        let joint = parents.next().ok_or_else(|| {
            field(
                path,
                format!("<link name=\"{link}\">"),
                format!("no joint has this link as its child: the link is not below --base {base}"),
            )
        })?;
        if let Some(second) = parents.next() {
            return Err(at_joint(
                path,
                text,
                &second.name,
                "",
                format!(
                    "link {link} is the child of joint {} too: a URDF is a tree, each link has one parent joint",
                    joint.name
                ),
            ));
        }
        if walked.len() > robot.joints.len() {
            return Err(at_joint(path, text, &joint.name, "", "the joints form a loop".into()));
        }
        walked.push(joint);
        link = &joint.parent.link;
    }
    walked.reverse();
    let mut joints = Vec::new();
    let mut folded = Isometry3::identity();
    for joint in walked {
        let values = joint.origin.xyz.0.iter().chain(&joint.origin.rpy.0);
        if !values.chain(&joint.axis.xyz.0).all(|v| v.is_finite()) {
            return Err(at_joint(
                path,
                text,
                &joint.name,
                "/<origin>",
                "expected finite numbers in origin xyz (m), rpy (rad) and axis xyz".into(),
            ));
        }
        match &joint.joint_type {
            urdf_rs::JointType::Fixed => folded *= origin_of(&joint.origin),
            urdf_rs::JointType::Revolute | urdf_rs::JointType::Continuous => {
                let axis = Vector3::from(joint.axis.xyz.0);
                let norm = axis.norm();
                if norm <= 1e-9 {
                    return Err(at_joint(
                        path,
                        text,
                        &joint.name,
                        "/<axis>",
                        format!(
                            "the axis {:?} is not a direction: expected a non-zero xyz",
                            joint.axis.xyz.0
                        ),
                    ));
                }
                joints.push(ChainJoint {
                    name: joint.name.clone(),
                    folded,
                    origin: origin_of(&joint.origin),
                    axis: axis / norm,
                });
                folded = Isometry3::identity();
            }
            other => {
                return Err(at_joint(
                    path,
                    text,
                    &joint.name,
                    "",
                    format!(
                        "type {other:?} in the chain {base} → {tip}; kincal calibrates revolute \
                         (or continuous) joints, with fixed joints folded in"
                    ),
                ))
            }
        }
    }
    if !(1..=MAX_JOINTS).contains(&joints.len()) {
        return Err(field(
            path,
            format!("chain {base} → {tip}"),
            format!("expected 1 to {MAX_JOINTS} revolute joints, found {}", joints.len()),
        ));
    }
    Ok((joints, folded))
}

/// Origin xyz (mm) and rpy (deg) of an isometry.
fn xyz_rpy(pose: &Isometry3<f64>) -> ([f64; 3], [f64; 3]) {
    let t = pose.translation.vector;
    let (roll, pitch, yaw) = pose.rotation.euler_angles();
    ([t.x, t.y, t.z], [roll.to_degrees(), pitch.to_degrees(), yaw.to_degrees()])
}

/// The chain `base` → `tip` of the URDF at `path` as a model (convention "urdf"): every origin
/// value and joint offset free (± [`ORIGIN_HALF_RANGE_MM`], ± [`ORIGIN_HALF_RANGE_DEG`]); the tool
/// point is the fixed transform after the last revolute joint (only its translation).
pub fn model_from_urdf(path: &Path, base: &str, tip: &str) -> Result<ArmModel, FileError> {
    let (text, robot) = read_robot(path)?;
    let (chain, after) = chain(path, &text, &robot, base, tip)?;
    let joints = chain
        .iter()
        .map(|c| {
            let (origin_xyz_mm, origin_rpy_deg) = xyz_rpy(&(c.folded * c.origin));
            Joint { origin_xyz_mm, origin_rpy_deg, axis: c.axis.into(), ..Joint::default() }
        })
        .collect();
    let t = after.translation.vector;
    let mut model = ArmModel {
        name: format!("{} ({base} → {tip}, from {})", robot.name, path.display()),
        convention: Convention::Urdf,
        joints,
        tcp_mm: [t.x, t.y, t.z],
        scale_ppm: 0.0,
        free: Vec::new(),
        arm: None,
    };
    for j in 0..model.joints.len() {
        let v = model.get(ParamId::Offset(j));
        model.free_param(ParamId::Offset(j), v - ORIGIN_HALF_RANGE_DEG, v + ORIGIN_HALF_RANGE_DEG);
        for k in 0..3 {
            let v = model.get(ParamId::OriginXyz(j, k));
            model.free_param(ParamId::OriginXyz(j, k), v - ORIGIN_HALF_RANGE_MM, v + ORIGIN_HALF_RANGE_MM);
            let v = model.get(ParamId::OriginRpy(j, k));
            model.free_param(ParamId::OriginRpy(j, k), v - ORIGIN_HALF_RANGE_DEG, v + ORIGIN_HALF_RANGE_DEG);
        }
    }
    model.free.sort_by_key(|f| f.id.dense_index());
    Ok(model)
}

/// The URDF text at `path` with the origins of the chain's revolute joints replaced by those of
/// `model` (each joint offset folded into its origin, the folded fixed joints taken back out), so
/// the URDF's forward kinematics at the readings q equals the model's. Nothing else changes.
pub fn calibrated_urdf(path: &Path, base: &str, tip: &str, model: &ArmModel) -> Result<String, FileError> {
    let (text, robot) = read_robot(path)?;
    let (chain, _) = chain(path, &text, &robot, base, tip)?;
    if model.convention != Convention::Urdf || model.joints.len() != chain.len() {
        return Err(field(
            path,
            format!("chain {base} → {tip}"),
            format!(
                "the model is not this chain: it has {} {:?} joints, the chain {} revolute joints",
                model.joints.len(),
                model.convention,
                chain.len()
            ),
        ));
    }
    for (j, (c, joint)) in chain.iter().zip(&model.joints).enumerate() {
        let axis = Vector3::from(joint.axis);
        if (axis.normalize() - c.axis).norm() > 1e-6 || !axis.iter().all(|v| v.is_finite()) {
            return Err(at_joint(
                path,
                &text,
                &c.name,
                "/<axis>",
                format!(
                    "the model's joint {} turns about {:?}, this joint about {:?}: the model was not made from this \
                     chain (kincal model from-urdf)",
                    j + 1,
                    joint.axis,
                    <[f64; 3]>::from(c.axis)
                ),
            ));
        }
    }
    let mut out = text;
    for (c, joint) in chain.iter().zip(&model.joints) {
        let [x, y, z] = joint.origin_xyz_mm;
        let [roll, pitch, yaw] = joint.origin_rpy_deg.map(f64::to_radians);
        let axis = Unit::new_normalize(Vector3::from(joint.axis));
        let calibrated = Isometry3::from_parts(
            Translation3::new(x, y, z),
            UnitQuaternion::from_euler_angles(roll, pitch, yaw)
                * UnitQuaternion::from_rotation_matrix(&Rotation3::from_axis_angle(
                    &axis,
                    joint.offset_deg.to_radians(),
                )),
        );
        let (xyz_mm, rpy_deg) = xyz_rpy(&(c.folded.inverse() * calibrated));
        let origin = format!(
            "<origin xyz=\"{} {} {}\" rpy=\"{} {} {}\"/>",
            xyz_mm[0] / 1000.0,
            xyz_mm[1] / 1000.0,
            xyz_mm[2] / 1000.0,
            rpy_deg[0].to_radians(),
            rpy_deg[1].to_radians(),
            rpy_deg[2].to_radians()
        );
        out = replace_joint_origin(&out, &c.name, &origin).ok_or_else(|| {
            field(path, format!("<joint name=\"{}\">", c.name), "element not found in the text".into())
        })?;
    }
    Ok(out)
}

/// `text` with the `<origin …/>` of joint `name` replaced by `origin` (inserted when absent).
fn replace_joint_origin(text: &str, name: &str, origin: &str) -> Option<String> {
    let start = joint_start(text, name)?;
    let end = start + text[start..].find("</joint>")?;
    let element = &text[start..end];
    let head_end = element.find('>')? + 1;
    let replaced = match element.find("<origin") {
        Some(o) => {
            let close = o + element[o..].find('>')? + 1;
            // `<origin ...></origin>` written long-hand.
            let close = if element[o..close].ends_with("/>") {
                close
            } else {
                close + element[close..].find("</origin>")? + "</origin>".len()
            };
            format!("{}{origin}{}", &element[..o], &element[close..])
        }
        None => format!("{}\n    {origin}{}", &element[..head_end], &element[head_end..]),
    };
    Some(format!("{}{replaced}{}", &text[..start], &text[end..]))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_origin_is_replaced_inside_its_joint_only() {
        let text =
            "<robot><joint name=\"a\" type=\"revolute\"><origin xyz=\"1 2 3\"/><axis xyz=\"0 0 1\"/></joint>\
                    <joint name='b' type=\"revolute\"><axis xyz=\"0 0 1\"/></joint></robot>";
        let out = replace_joint_origin(text, "b", "<origin xyz=\"9 9 9\"/>").unwrap();
        assert!(out.contains("<origin xyz=\"1 2 3\"/>"), "{out}");
        assert!(out.contains("<joint name='b' type=\"revolute\">\n    <origin xyz=\"9 9 9\"/>"), "{out}");
        let out = replace_joint_origin(&out, "a", "<origin xyz=\"0 0 0\"/>").unwrap();
        assert!(!out.contains("1 2 3") && out.contains("<axis xyz=\"0 0 1\"/></joint>"), "{out}");
        assert_eq!(replace_joint_origin(text, "c", ""), None);
    }

    /// A two-joint URDF with a fixed joint between and a tool joint after: the model's tool point
    /// equals the URDF chain multiplied out by hand, and writing the model back reproduces it.
    #[test]
    fn a_urdf_chain_becomes_a_model_with_the_same_forward_kinematics() {
        let dir = std::env::temp_dir().join(format!("kincal-urdf-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("r.urdf");
        std::fs::write(
            &path,
            "<robot name=\"t\"><link name=\"b\"/><link name=\"l1\"/><link name=\"m\"/><link name=\"l2\"/><link name=\"tool\"/>\
             <joint name=\"j1\" type=\"revolute\"><parent link=\"b\"/><child link=\"l1\"/><origin xyz=\"0 0 0.3\" rpy=\"0.1 0 0.2\"/><axis xyz=\"0 0 1\"/></joint>\
             <joint name=\"f\" type=\"fixed\"><parent link=\"l1\"/><child link=\"m\"/><origin xyz=\"0.2 0 0\" rpy=\"0 0.3 0\"/></joint>\
             <joint name=\"j2\" type=\"continuous\"><parent link=\"m\"/><child link=\"l2\"/><origin xyz=\"0.1 0.05 0\" rpy=\"0 0 0.5\"/><axis xyz=\"0 1 1\"/></joint>\
             <joint name=\"t\" type=\"fixed\"><parent link=\"l2\"/><child link=\"tool\"/><origin xyz=\"0 0 0.1\"/></joint></robot>",
        )
        .unwrap();
        let mut model = model_from_urdf(&path, "b", "tool").unwrap();
        let q = [10.0_f64, 20.0];
        let by_hand = |x: f64, y: f64, z: f64, r: f64, p: f64, w: f64| {
            Isometry3::from_parts(Translation3::new(x, y, z), UnitQuaternion::from_euler_angles(r, p, w))
        };
        let turn = |axis: Vector3<f64>, deg: f64| {
            Isometry3::from_parts(
                Translation3::identity(),
                UnitQuaternion::from_axis_angle(&Unit::new_normalize(axis), deg.to_radians()),
            )
        };
        let tool = by_hand(0.0, 0.0, 300.0, 0.1, 0.0, 0.2)
            * turn(Vector3::z(), q[0])
            * by_hand(200.0, 0.0, 0.0, 0.0, 0.3, 0.0)
            * by_hand(100.0, 50.0, 0.0, 0.0, 0.0, 0.5)
            * turn(Vector3::new(0.0, 1.0, 1.0), q[1])
            * nalgebra::Point3::new(0.0, 0.0, 100.0);
        let pose = crate::model::kinematics::tool_pose(&model, &q);
        assert!((pose.position_mm - tool.coords).norm() < 1e-9, "{} vs {}", pose.position_mm, tool.coords);
        assert_eq!(model.free.len(), 14);
        // Calibrated values written back: the new URDF read as a model gives the same tool point.
        model.joints[1].offset_deg = 1.5;
        model.joints[0].origin_xyz_mm[0] += 0.7;
        let back = dir.join("back.urdf");
        std::fs::write(&back, calibrated_urdf(&path, "b", "tool", &model).unwrap()).unwrap();
        let reread = model_from_urdf(&back, "b", "tool").unwrap();
        let (a, b) = (
            crate::model::kinematics::tool_pose(&model, &q),
            crate::model::kinematics::tool_pose(&reread, &q),
        );
        assert!((a.position_mm - b.position_mm).norm() < 1e-6, "{} vs {}", a.position_mm, b.position_mm);
        let prismatic = std::fs::read_to_string(&path).unwrap().replace("\"continuous\"", "\"prismatic\"");
        std::fs::write(&path, prismatic).unwrap();
        let err = model_from_urdf(&path, "b", "tool").unwrap_err().to_string();
        assert!(err.contains("<joint name=\"j2\">") && err.contains("Prismatic"), "{err}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
