//! URDF in and out: a serial chain of a URDF file as a `kincal-arm/1` model (convention
//! "urdf"), and a calibrated model written back into a copy of that URDF.
//!
//! The file is parsed with the `urdf-rs` crate for its meaning, and indexed with `quick-xml` for
//! where each `<robot>/<joint>` element sits (its line, its `<origin>`). URDF lengths are metres
//! and angles radians; the model holds millimetres and degrees. Fixed joints between `base` and
//! `tip` are folded into the next revolute joint's origin (fixed joints after the last revolute
//! joint into the tool point); continuous joints are revolute; any other joint type, and a joint
//! that mimics another, in the chain is refused.
//!
//! Several tips (`--tip left_marker,right_marker`) make a branched model: the union of the chains
//! base → tip, joints in the order the chains first reach them (a parent before its children),
//! each tip with its last revolute joint and tool point (see [`crate::model::Tree`]). The mass
//! table ([`read_masses`]) comes from the links' `<inertial>` elements.
//!
//! The model records where it came from ([`UrdfSource`]: the file, base, tip, a SHA-256 of the
//! chain as the file states it, the joints' names and limits). Writing back refuses another
//! chain, edits only the `<origin>` of each revolute joint of the chain among the `<robot>`'s own
//! `<joint>` elements (never the `<joint>` entries of `<ros2_control>`, `<transmission>` or
//! `<gazebo>`), so every other byte keeps its text, and reads the written text back to check that
//! its forward kinematics is the calibrated model's.

use super::{ArmModel, Body, Convention, Joint, ParamId, Tip, Tree, MAX_JOINTS, MAX_TREE_JOINTS};
use crate::files::FileError;
use crate::model::kinematics::Chain as ModelChain;
use crate::model::plausible::MAX_LENGTH_MM;
use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, Unit, UnitQuaternion, Vector3};
use std::path::Path;

/// Bounds given to each free origin translation by [`model_from_urdf`], ± mm.
pub const ORIGIN_HALF_RANGE_MM: f64 = 10.0;
/// Bounds given to each free origin turn and joint offset by [`model_from_urdf`], ± degrees.
pub const ORIGIN_HALF_RANGE_DEG: f64 = 5.0;
/// Readings at which [`calibrated_urdf`] compares the written file with the model.
pub const READ_BACK_POSES: usize = 16;
/// Largest difference, mm, between the written URDF's forward kinematics and the model's that
/// [`calibrated_urdf`] accepts (the numbers are written in full: only round-off remains).
pub const READ_BACK_TOLERANCE_MM: f64 = 1e-6;

/// The URDF chain a model was made from, recorded in the model (`[urdf]`) by
/// [`model_from_urdf`] and checked by [`calibrated_urdf`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct UrdfSource {
    /// The URDF file as given to `from-urdf`.
    pub file: String,
    /// The file's `<robot name>`.
    pub robot: String,
    /// The chain's first link.
    pub base: String,
    /// The chain's last link (the tips' links, comma-separated, for a branched model).
    pub tip: String,
    /// SHA-256 (hex) of the chain as the file states it: each joint's name, type, origin, axis
    /// and parent and child links, base to tip. Comments, meshes, limits and other elements do not
    /// enter it.
    pub chain_sha256: String,
    /// The chain's revolute joints, base to tip: one per model joint.
    pub joint: Vec<UrdfJoint>,
}

/// One revolute joint of the URDF chain: its name and limits.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct UrdfJoint {
    /// The joint's name in the URDF.
    pub name: String,
    /// Its lower and upper limit, degrees (`None` for a continuous joint).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub limits_deg: Option<[f64; 2]>,
}

impl UrdfSource {
    /// The model joint (0-based) a data column names: the URDF joint's name, alone or with
    /// `_deg` (`shoulder_pan_joint`, `shoulder_pan_joint_deg`).
    pub fn joint_index(&self, column: &str) -> Option<usize> {
        let name = column.strip_suffix("_deg").filter(|n| self.joint.iter().any(|j| j.name == *n));
        let name = name.unwrap_or(column);
        self.joint.iter().position(|j| j.name == name)
    }

    /// `count` readings (deg) spread over the joints' limits (±180° for a continuous joint),
    /// deterministic: the middle of every range first, then a low-discrepancy fraction per
    /// (reading, joint).
    pub fn spread_readings(&self, count: usize) -> Vec<Vec<f64>> {
        (0..count)
            .map(|k| {
                self.joint
                    .iter()
                    .enumerate()
                    .map(|(j, joint)| {
                        let [lo, hi] = joint.limits_deg.unwrap_or([-180.0, 180.0]);
                        let f =
                            if k == 0 { 0.5 } else { ((k * 7 + j * 13) as f64 * 0.618_033_988_75).fract() };
                        lo + (hi - lo) * f
                    })
                    .collect()
            })
            .collect()
    }

    /// The readings of `q_deg` outside their joint's URDF limits: (joint, reading, limits), deg.
    pub fn outside_limits(&self, q_deg: &[f64]) -> Vec<(&UrdfJoint, f64, [f64; 2])> {
        self.joint
            .iter()
            .zip(q_deg)
            .filter_map(|(j, &q)| {
                j.limits_deg.filter(|[lo, hi]| !(*lo..=*hi).contains(&q)).map(|l| (j, q, l))
            })
            .collect()
    }
}

/// One `<joint>` element that is a child of `<robot>`: where it is in the text.
#[derive(Clone, Debug)]
struct JointElement {
    name: String,
    /// Byte offset just after its start tag (where an `<origin>` is inserted when there is none).
    head_end: usize,
    /// Byte range of its `<origin>` child, if any.
    origin: Option<(usize, usize)>,
    /// 1-based line of its start tag.
    line: usize,
}

/// A URDF read: its text, its meaning and where its kinematic joints are.
struct Document<'a> {
    path: &'a Path,
    text: String,
    robot: urdf_rs::Robot,
    joints: Vec<JointElement>,
    /// Its links' mass values ([`Places::link_masses`]).
    link_masses: Vec<(String, (usize, usize))>,
}

/// One revolute joint of the chain: its name in the URDF and the fixed joints folded before it.
#[derive(Clone, Debug)]
struct ChainJoint {
    name: String,
    /// Product of the fixed joints' origins between the previous revolute joint and this one.
    folded: Isometry3<f64>,
    origin: Isometry3<f64>,
    axis: Vector3<f64>,
    limits_deg: Option<[f64; 2]>,
}

/// The chain base → tip of a document.
struct Chain {
    joints: Vec<ChainJoint>,
    /// The fixed transform after the last revolute joint.
    after: Isometry3<f64>,
    sha256: String,
}

/// The chains base → each tip of a document, merged: every revolute joint once.
struct Branches {
    joints: Vec<ChainJoint>,
    /// Each joint's parent joint (index into `joints`), `None` on the base.
    parents: Vec<Option<usize>>,
    /// Per tip: its link, its last joint (index into `joints`) and the fixed transform after it.
    tips: Vec<(String, usize, Isometry3<f64>)>,
    /// The one chain's hash, or the hash of the tips' hashes.
    sha256: String,
}

fn field(path: &Path, field: String, message: String) -> FileError {
    FileError::Field { path: path.to_owned(), field, message }
}

fn line_of(text: &str, at: usize) -> usize {
    text[..at.min(text.len())].matches('\n').count() + 1
}

/// Where the `<robot>`'s own elements an edit rewrites are in the text, from one pass over it.
struct Places {
    /// Its `<joint>` elements, in file order.
    joints: Vec<JointElement>,
    /// Its links with an `<inertial><mass value="…">`: each link's name and the byte range of
    /// its mass value (between the quotes), in file order.
    link_masses: Vec<(String, (usize, usize))>,
}

/// The [`Places`] of `text` (the URDF at `path`), refused with the line of an XML error.
fn index_places(path: &Path, text: &str) -> Result<Places, FileError> {
    use quick_xml::events::Event;
    let mut reader = quick_xml::Reader::from_str(text);
    let syntax = |at: u64, what: String| FileError::Syntax {
        path: path.to_owned(),
        message: format!("line {}: not a URDF robot description: {what}", line_of(text, at as usize)),
    };
    let name_of = |e: &quick_xml::events::BytesStart, at: usize| -> Result<String, FileError> {
        let attribute = e.try_get_attribute("name").ok().flatten();
        let value = attribute.map(|a| a.unescape_value().map(|v| v.into_owned()));
        value.unwrap_or(Ok(String::new())).map_err(|err| syntax(at as u64, err.to_string()))
    };
    let mut places = Places { joints: Vec::new(), link_masses: Vec::new() };
    let (mut depth, mut joint, mut origin_start) = (0usize, None::<JointElement>, None);
    let (mut link, mut inertial) = (None::<String>, false);
    loop {
        let start = reader.buffer_position() as usize;
        let event = reader.read_event().map_err(|e| syntax(reader.error_position(), e.to_string()))?;
        let end = reader.buffer_position() as usize;
        match event {
            Event::Start(e) | Event::Empty(e) => {
                let empty = text[start..end].ends_with("/>");
                match (depth, e.name().as_ref(), empty) {
                    (1, b"joint", false) => {
                        let (name, line) = (name_of(&e, start)?, line_of(text, start));
                        joint = Some(JointElement { name, head_end: end, origin: None, line });
                    }
                    (1, b"link", false) => link = Some(name_of(&e, start)?),
                    (2, b"origin", true) => {
                        if let Some(joint) = joint.as_mut() {
                            joint.origin.get_or_insert((start, end));
                        }
                    }
                    (2, b"origin", false) if joint.is_some() => origin_start = Some(start),
                    (2, b"inertial", false) => inertial = link.is_some(),
                    (3, b"mass", _) if inertial => {
                        if let (Some(name), Some(range)) = (link.clone(), value_range(&text[start..end])) {
                            places.link_masses.push((name, (start + range.0, start + range.1)));
                        }
                    }
                    _ => {}
                }
                depth += usize::from(!empty);
            }
            Event::End(e) => {
                depth = depth.saturating_sub(1);
                match (depth, e.name().as_ref()) {
                    (2, b"origin") => {
                        if let (Some(joint), Some(o)) = (joint.as_mut(), origin_start.take()) {
                            joint.origin.get_or_insert((o, end));
                        }
                    }
                    (2, b"inertial") => inertial = false,
                    (1, b"joint") => places.joints.extend(joint.take()),
                    (1, _) => link = None,
                    _ => {}
                }
            }
            Event::Eof => break,
            _ => {}
        }
    }
    Ok(places)
}

/// The byte range of the `value` attribute's text (between its quotes) in an element's tag.
fn value_range(tag: &str) -> Option<(usize, usize)> {
    let mut from = 0;
    while let Some(at) = tag[from..].find("value").map(|a| a + from) {
        let before_ok = tag[..at].ends_with(|c: char| c.is_whitespace());
        let rest = tag[at + 5..].trim_start();
        if let (true, Some(after_eq)) = (before_ok, rest.strip_prefix('=')) {
            let quoted = after_eq.trim_start();
            let quote = quoted.chars().next().filter(|q| *q == '"' || *q == '\'')?;
            let open = tag.len() - quoted.len() + 1;
            let close = tag[open..].find(quote)? + open;
            return Some((open, close));
        }
        from = at + 5;
    }
    None
}

/// Read the URDF text of `path`: refused when it is a xacro file, not XML or not a tree of
/// declared links (a missing link, a link with two parents, a loop, two joints of one name).
fn read_document<'a>(path: &'a Path, text: String) -> Result<Document<'a>, FileError> {
    let xacro = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("xacro"));
    if xacro || text.contains("<xacro:") {
        let name = path.display();
        return Err(FileError::Syntax {
            path: path.to_owned(),
            message: format!(
                "a xacro file (macros, not a URDF yet): expand it first, then pass the URDF: \
                 `xacro {name} > robot.urdf` (ROS 2: `ros2 run xacro xacro {name} > robot.urdf`)"
            ),
        });
    }
    let Places { joints, link_masses } = index_places(path, &text)?;
    let robot = urdf_rs::read_from_string(&text).map_err(|e| FileError::Syntax {
        path: path.to_owned(),
        message: format!("not a URDF robot description: {e}"),
    })?;
    let doc = Document { path, text, robot, joints, link_masses };
    doc.check_tree()?;
    Ok(doc)
}

fn read_file(path: &Path) -> Result<Document<'_>, FileError> {
    crate::files::check_regular_file(path)?;
    let text =
        std::fs::read_to_string(path).map_err(|source| FileError::Io { path: path.to_owned(), source })?;
    read_document(path, text)
}

fn origin_of(pose: &urdf_rs::Pose) -> Isometry3<f64> {
    let [x, y, z] = pose.xyz.0;
    let [roll, pitch, yaw] = pose.rpy.0;
    Isometry3::from_parts(
        Translation3::new(x * 1000.0, y * 1000.0, z * 1000.0),
        UnitQuaternion::from_euler_angles(roll, pitch, yaw),
    )
}

impl Document<'_> {
    /// An error at the kinematic joint `name`, with its line (1 when it has no element).
    fn at_joint(&self, name: &str, what: &str, message: String) -> FileError {
        let line = self.joints.iter().find(|j| j.name == name).map_or(1, |j| j.line);
        FileError::Element {
            path: self.path.to_owned(),
            line,
            element: format!("<joint name=\"{name}\">{what}"),
            message,
        }
    }

    /// Every joint joins two declared links, each link has at most one parent joint, joint names
    /// are unique and no chain of parents comes back to where it started.
    fn check_tree(&self) -> Result<(), FileError> {
        for (k, element) in self.joints.iter().enumerate() {
            if let Some(first) = self.joints[..k].iter().find(|e| e.name == element.name) {
                return Err(self.at_joint(
                    &element.name,
                    "",
                    format!(
                        "a second joint of this name (the first is on line {}): joint names are unique",
                        first.line
                    ),
                ));
            }
        }
        let declared = |link: &str| self.robot.links.iter().any(|l| l.name == link);
        for joint in &self.robot.joints {
            for (role, link) in [("parent", &joint.parent.link), ("child", &joint.child.link)] {
                if !declared(link) {
                    return Err(self.at_joint(
                        &joint.name,
                        &format!("/<{role}>"),
                        format!(
                            "link {link} is not declared: expected a <link name=\"{link}\"/> in the file"
                        ),
                    ));
                }
            }
        }
        for link in &self.robot.links {
            let mut parents = self.robot.joints.iter().filter(|j| j.child.link == link.name);
            if let (Some(first), Some(second)) = (parents.next(), parents.next()) {
                return Err(self.at_joint(
                    &second.name,
                    "",
                    format!(
                        "link {} is the child of joint {} too: a URDF is a tree, each link has one parent joint",
                        link.name, first.name
                    ),
                ));
            }
        }
        for start in &self.robot.links {
            let mut link = start.name.as_str();
            for _ in 0..=self.robot.joints.len() {
                match self.robot.joints.iter().find(|j| j.child.link == link) {
                    Some(joint) if joint.parent.link == start.name => {
                        return Err(self.at_joint(
                            &joint.name,
                            "",
                            format!("the joints form a loop through link {}: a URDF is a tree", start.name),
                        ))
                    }
                    Some(joint) => link = &joint.parent.link,
                    None => break,
                }
            }
        }
        Ok(())
    }

    /// The chain from `base` to `tip`: its revolute joints, the fixed transform after them and
    /// the hash of the chain's text.
    fn chain(&self, base: &str, tip: &str) -> Result<Chain, FileError> {
        let (path, robot) = (self.path, &self.robot);
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
        // Walk from the tip to the base through each link's parent joint (a tree: one each).
        let mut walked = Vec::new();
        let mut link = tip;
        while link != base {
            let joint = robot.joints.iter().find(|j| j.child.link == link).ok_or_else(|| {
                field(
                    path,
                    format!("<link name=\"{link}\">"),
                    format!("no joint has this link as its child: the link is not below --base {base}"),
                )
            })?;
            walked.push(joint);
            link = &joint.parent.link;
        }
        walked.reverse();
        let mut hash = sha2::Sha256::new();
        use sha2::Digest;
        hash.update(format!("{base}\n{tip}\n"));
        let mut joints = Vec::new();
        let mut folded = Isometry3::identity();
        for joint in walked {
            self.check_joint(joint, base, tip)?;
            let bits = |v: &[f64; 3]| v.map(|x| format!("{:016x}", x.to_bits())).join(" ");
            hash.update(format!(
                "{} {:?} {} {} {} {} {}\n",
                joint.name,
                joint.joint_type,
                joint.parent.link,
                joint.child.link,
                bits(&joint.origin.xyz.0),
                bits(&joint.origin.rpy.0),
                bits(&joint.axis.xyz.0)
            ));
            if let urdf_rs::JointType::Fixed = joint.joint_type {
                folded *= origin_of(&joint.origin);
                continue;
            }
            let axis = Vector3::from(joint.axis.xyz.0);
            let limits_deg = match joint.joint_type {
                urdf_rs::JointType::Revolute if joint.limit.lower < joint.limit.upper => {
                    Some([joint.limit.lower.to_degrees(), joint.limit.upper.to_degrees()])
                }
                _ => None,
            };
            joints.push(ChainJoint {
                name: joint.name.clone(),
                folded,
                origin: origin_of(&joint.origin),
                axis: axis / axis.norm(),
                limits_deg,
            });
            folded = Isometry3::identity();
        }
        if !(1..=MAX_JOINTS).contains(&joints.len()) {
            return Err(field(
                path,
                format!("chain {base} → {tip}"),
                format!("expected 1 to {MAX_JOINTS} revolute joints, found {}", joints.len()),
            ));
        }
        let sha256 = hash.finalize().iter().map(|b| format!("{b:02x}")).collect();
        Ok(Chain { joints, after: folded, sha256 })
    }

    /// The chains `base` → each of the comma-separated `tips`, merged (one tip: its chain).
    fn branches(&self, base: &str, tips: &str) -> Result<Branches, FileError> {
        let mut out =
            Branches { joints: Vec::new(), parents: Vec::new(), tips: Vec::new(), sha256: String::new() };
        let mut hashes = Vec::new();
        for tip in tips.split(',').map(str::trim) {
            let chain = self.chain(base, tip)?;
            let mut parent = None;
            for joint in chain.joints {
                let at = match out.joints.iter().position(|j| j.name == joint.name) {
                    Some(at) => at,
                    None => {
                        out.joints.push(joint);
                        out.parents.push(parent);
                        out.joints.len() - 1
                    }
                };
                parent = Some(at);
            }
            let last = parent.unwrap_or(0);
            if out.tips.iter().any(|t| t.0 == tip) {
                return Err(field(
                    self.path,
                    format!("--tip {tips}"),
                    format!("the tip {tip} is named twice"),
                ));
            }
            out.tips.push((tip.to_string(), last, chain.after));
            hashes.push(chain.sha256);
        }
        if out.joints.len() > MAX_TREE_JOINTS {
            return Err(field(
                self.path,
                format!("chains {base} → {tips}"),
                format!(
                    "expected at most {MAX_TREE_JOINTS} revolute joints in all, found {}",
                    out.joints.len()
                ),
            ));
        }
        out.sha256 = match hashes.len() {
            1 => hashes.remove(0),
            _ => {
                use sha2::Digest;
                let digest = sha2::Sha256::digest(hashes.join("\n").as_bytes());
                digest.iter().map(|b| format!("{b:02x}")).collect()
            }
        };
        Ok(out)
    }

    /// One joint of the chain: a revolute, continuous or fixed joint of its own (no mimic) with a
    /// finite origin of arm size and an axis.
    fn check_joint(&self, joint: &urdf_rs::Joint, base: &str, tip: &str) -> Result<(), FileError> {
        let values = joint.origin.xyz.0.iter().chain(&joint.origin.rpy.0);
        if !values.chain(&joint.axis.xyz.0).all(|v| v.is_finite()) {
            return Err(self.at_joint(
                &joint.name,
                "/<origin>",
                "expected finite numbers in origin xyz (m), rpy (rad) and axis xyz".into(),
            ));
        }
        let distance_m = Vector3::from(joint.origin.xyz.0).norm();
        if distance_m * 1000.0 > MAX_LENGTH_MM {
            return Err(self.at_joint(
                &joint.name,
                "/<origin>",
                format!(
                    "xyz {:?} puts the joint {distance_m} m from its parent; expected at most {} m for an \
                     arm: URDF lengths are in metres",
                    joint.origin.xyz.0,
                    MAX_LENGTH_MM / 1000.0
                ),
            ));
        }
        match joint.joint_type {
            urdf_rs::JointType::Fixed => return Ok(()),
            urdf_rs::JointType::Revolute | urdf_rs::JointType::Continuous => {}
            ref other => {
                return Err(self.at_joint(
                    &joint.name,
                    "",
                    format!(
                    "type {other:?} in the chain {base} → {tip}; kincal calibrates revolute (or continuous) \
                         joints, with fixed joints folded in"
                ),
                ))
            }
        }
        if let Some(mimic) = &joint.mimic {
            return Err(self.at_joint(
                &joint.name,
                "/<mimic>",
                format!(
                    "this joint mimics joint {}: its angle is no reading of its own, and kincal calibrates \
                     chains of independent joints; end the chain before it (--tip) or use a URDF without <mimic>",
                    mimic.joint
                ),
            ));
        }
        if Vector3::from(joint.axis.xyz.0).norm() <= 1e-9 {
            return Err(self.at_joint(
                &joint.name,
                "/<axis>",
                format!("the axis {:?} is not a direction: expected a non-zero xyz", joint.axis.xyz.0),
            ));
        }
        Ok(())
    }

    /// The chain (or the branches) as a model: origins and axes, the tool points, the source
    /// record.
    fn model(&self, base: &str, tip: &str) -> Result<(ArmModel, Branches), FileError> {
        let chain = self.branches(base, tip)?;
        let joints = chain
            .joints
            .iter()
            .map(|c| {
                let (origin_xyz_mm, origin_rpy_deg) = xyz_rpy(&(c.folded * c.origin));
                Joint { origin_xyz_mm, origin_rpy_deg, axis: c.axis.into(), ..Joint::default() }
            })
            .collect();
        let point = |after: &Isometry3<f64>| {
            let t = after.translation.vector;
            [t.x, t.y, t.z]
        };
        let tree = match chain.tips.len() {
            1 => Tree::default(),
            _ => Tree {
                parents: chain.parents.clone(),
                tips: chain
                    .tips
                    .iter()
                    .map(|(name, joint, after)| Tip {
                        name: name.clone(),
                        joint: *joint,
                        tcp_mm: point(after),
                    })
                    .collect(),
                bodies: Vec::new(),
            },
        };
        let source = UrdfSource {
            file: self.path.display().to_string(),
            robot: self.robot.name.clone(),
            base: base.into(),
            tip: tip.into(),
            chain_sha256: chain.sha256.clone(),
            joint: chain
                .joints
                .iter()
                .map(|c| UrdfJoint { name: c.name.clone(), limits_deg: c.limits_deg })
                .collect(),
        };
        let model = ArmModel {
            name: format!("{} ({base} → {tip}, from {})", self.robot.name, self.path.display()),
            convention: Convention::Urdf,
            joints,
            tcp_mm: point(&chain.tips[0].2),
            scale_ppm: 0.0,
            free: Vec::new(),
            urdf: Some(source),
            arm: None,
            tree,
        };
        if let Some((name, message)) = model.implausible() {
            return Err(field(self.path, format!("chain {base} → {tip}: {name}"), message));
        }
        Ok((model, chain))
    }
}

/// Roll, pitch, yaw (rad) of a rotation, R = Rz(yaw)·Ry(pitch)·Rx(roll). Yaw comes from the
/// first column; pitch and roll from Rz(yaw)ᵀ·R, so near pitch ±90° (where yaw alone is
/// ill-conditioned) roll absorbs yaw's round-off and the three still give R to round-off.
fn rpy_of(r: &Matrix3<f64>) -> [f64; 3] {
    let yaw = r[(1, 0)].atan2(r[(0, 0)]);
    let m = Rotation3::from_axis_angle(&Vector3::z_axis(), -yaw).into_inner() * r;
    let pitch = (-m[(2, 0)]).atan2(m[(0, 0)]);
    let roll = (-m[(1, 2)]).atan2(m[(1, 1)]);
    [roll, pitch, yaw]
}

/// Origin xyz (mm) and rpy (deg) of an isometry.
fn xyz_rpy(pose: &Isometry3<f64>) -> ([f64; 3], [f64; 3]) {
    let t = pose.translation.vector;
    let rpy = rpy_of(pose.rotation.to_rotation_matrix().matrix());
    ([t.x, t.y, t.z], rpy.map(f64::to_degrees))
}

/// The chain `base` → `tip` of the URDF at `path` as a model (convention "urdf"): every origin
/// translation, origin turn and joint offset free (± [`ORIGIN_HALF_RANGE_MM`], ±
/// [`ORIGIN_HALF_RANGE_DEG`]); the tool point is the fixed transform after the last revolute
/// joint (only its translation); the model records the chain ([`UrdfSource`]).
pub fn model_from_urdf(path: &Path, base: &str, tip: &str) -> Result<ArmModel, FileError> {
    let (mut model, _) = read_file(path)?.model(base, tip)?;
    for t in 1..model.tree.tips.len() {
        for k in 0..3 {
            let v = model.get(ParamId::TipTcp(t, k));
            model.free_param(ParamId::TipTcp(t, k), v - ORIGIN_HALF_RANGE_MM, v + ORIGIN_HALF_RANGE_MM);
        }
    }
    for j in 0..model.joints.len() {
        let v = model.get(ParamId::Offset(j));
        model.free_param(ParamId::Offset(j), v - ORIGIN_HALF_RANGE_DEG, v + ORIGIN_HALF_RANGE_DEG);
        for k in 0..3 {
            let v = model.get(ParamId::OriginXyz(j, k));
            model.free_param(ParamId::OriginXyz(j, k), v - ORIGIN_HALF_RANGE_MM, v + ORIGIN_HALF_RANGE_MM);
            let v = model.get(ParamId::OriginTurn(j, k));
            model.free_param(ParamId::OriginTurn(j, k), v - ORIGIN_HALF_RANGE_DEG, v + ORIGIN_HALF_RANGE_DEG);
        }
    }
    model.free.sort_by_key(|f| f.id.dense_index());
    Ok(model)
}

/// Read the mass table of `model` (made by [`model_from_urdf`]) from the `<inertial>` elements of
/// the URDF at `path`: each link with a mass becomes a [`Body`] of the model joint that carries
/// it (the nearest revolute joint of the model above it, through fixed joints and joints the
/// model does not hold, those taken at their zero), its centre of mass in that joint's frame.
/// Links carried by no joint of the model (the base's) load none and are left out. Returns the
/// total mass read, kg.
pub fn read_masses(path: &Path, model: &mut ArmModel) -> Result<f64, FileError> {
    let doc = read_file(path)?;
    let Some(source) = model.urdf.as_ref().filter(|_| model.convention == Convention::Urdf) else {
        return Err(field(
            path,
            "<inertial>".into(),
            "the model records no URDF chain: make it with `kincal model from-urdf`".into(),
        ));
    };
    let names: Vec<String> = source.joint.iter().map(|j| j.name.clone()).collect();
    let mut bodies = Vec::new();
    for link in &doc.robot.links {
        let mass = link.inertial.mass.value;
        if mass <= 0.0 {
            continue;
        }
        if !mass.is_finite() || mass > 10_000.0 {
            return Err(field(
                path,
                format!("<link name=\"{}\">/<inertial>/<mass>", link.name),
                format!("{mass}: expected a mass in kg, 0 < m <= 10000"),
            ));
        }
        let mut at = origin_of(&link.inertial.origin).translation.vector;
        let mut current = link.name.as_str();
        let carrier = loop {
            let Some(joint) = doc.robot.joints.iter().find(|j| j.child.link == current) else { break None };
            if let Some(j) = names.iter().position(|n| *n == joint.name) {
                break Some(j);
            }
            at = (origin_of(&joint.origin) * nalgebra::Point3::from(at)).coords;
            current = &joint.parent.link;
        };
        if let Some(joint) = carrier {
            bodies.push(Body { name: link.name.clone(), joint, mass_kg: mass, com_mm: [at.x, at.y, at.z] });
        }
    }
    if bodies.len() > crate::model::MAX_BODIES {
        return Err(field(
            path,
            "<inertial>".into(),
            format!(
                "{} links with a mass are carried by the chain; a mass table holds at most {} (merge links)",
                bodies.len(),
                crate::model::MAX_BODIES
            ),
        ));
    }
    let total = bodies.iter().map(|b| b.mass_kg).sum();
    model.tree.bodies = bodies;
    Ok(total)
}

/// A calibrated URDF: its text and how it was checked.
#[derive(Clone, Debug)]
pub struct CalibratedUrdf {
    /// The file's new text.
    pub text: String,
    /// The joints whose `<origin>` was rewritten, base to tip.
    pub joints: Vec<String>,
    /// The links whose `<inertial><mass>` was rewritten (a body's fitted mass, `mass:BODY`).
    pub masses: Vec<String>,
    /// Largest distance between the written file's forward kinematics and the model's, mm, over
    /// [`CalibratedUrdf::poses_checked`] poses (the last joint's frame origin and points 100 mm
    /// along its axes).
    pub read_back_mm: f64,
    /// Poses at which the written file was compared with the model.
    pub poses_checked: usize,
}

/// The URDF text at `urdf` with the origins of the model's chain replaced by the calibrated ones
/// (each origin R(rpy)·exp(ω) with the joint offset folded in, the folded fixed joints taken back
/// out), so the URDF's forward kinematics at the readings q equals the model's. Refused: a model
/// not made by [`model_from_urdf`], a `base` or `tip` other than the model's, a chain other than
/// the one it was made from (by joint, then by hash), and a model holding effects a URDF cannot
/// carry. The text is read back and its forward kinematics compared with the model's before it
/// is returned. `model_path` only names the model in messages.
pub fn calibrated_urdf(
    urdf: &Path,
    model: &ArmModel,
    model_path: &Path,
    base: Option<&str>,
    tip: Option<&str>,
) -> Result<CalibratedUrdf, FileError> {
    let doc = read_file(urdf)?;
    let m = model_path.display();
    let Some(source) = model.urdf.as_ref().filter(|_| model.convention == Convention::Urdf) else {
        let (base, tip) = (base.unwrap_or("?"), tip.unwrap_or("?"));
        let count = doc
            .branches(base, tip)
            .map(|c| format!(", the chain {base} → {tip} {} revolute joints", c.joints.len()));
        return Err(field(
            urdf,
            format!("chain {base} → {tip}"),
            format!(
                "the model is not this chain: {m} has {} {:?} joints{}; only a model made by `kincal model \
                 from-urdf` (and calibrated) records its URDF chain and can be written into it",
                model.joints.len(),
                model.convention,
                count.unwrap_or_default()
            ),
        ));
    };
    for (option, given, own) in [("--base", base, &source.base), ("--tip", tip, &source.tip)] {
        if let Some(given) = given.filter(|g| g != own) {
            return Err(field(
                urdf,
                format!("{option} {given}"),
                format!(
                    "the model {m} is the chain {} → {} of {}: its origins belong to that chain only; leave \
                     out {option} or give {own}",
                    source.base, source.tip, source.file
                ),
            ));
        }
    }
    let chain = doc.branches(&source.base, &source.tip)?;
    let made_from = format!(
        "{m} was made from {} (robot {}, chain {} → {})",
        source.file, source.robot, source.base, source.tip
    );
    if chain.joints.len() != model.joints.len() || chain.joints.len() != source.joint.len() {
        return Err(field(
            urdf,
            format!("chain {} → {}", source.base, source.tip),
            format!(
                "the model is not this chain: {made_from}, {} joints; here the chain has {} revolute joints",
                model.joints.len(),
                chain.joints.len()
            ),
        ));
    }
    for (j, ((c, joint), recorded)) in chain.joints.iter().zip(&model.joints).zip(&source.joint).enumerate() {
        if c.name != recorded.name {
            return Err(doc.at_joint(
                &c.name,
                "",
                format!(
                    "joint {} of the chain is {} in the model: {made_from}, not from this file",
                    j + 1,
                    recorded.name
                ),
            ));
        }
        let axis = Vector3::from(joint.axis);
        if !axis.iter().all(|v| v.is_finite()) || (axis.normalize() - c.axis).norm() > 1e-6 {
            return Err(doc.at_joint(
                &c.name,
                "/<axis>",
                format!(
                    "the model's joint {} turns about {:?}, this joint about {:?}: the model was not made from this \
                     chain ({made_from})",
                    j + 1,
                    joint.axis,
                    <[f64; 3]>::from(c.axis)
                ),
            ));
        }
    }
    if chain.sha256 != source.chain_sha256 {
        return Err(field(
            urdf,
            format!("chain {} → {}", source.base, source.tip),
            format!(
                "the chain differs from the one the model was made from: {made_from}, chain hash {}; this file \
                 (robot {}) has chain hash {}: its origins or joints were changed. Write the model into the URDF \
                 it was made from",
                short(&source.chain_sha256),
                doc.robot.name,
                short(&chain.sha256)
            ),
        ));
    }
    let not_in_urdf: Vec<String> = model
        .params()
        .into_iter()
        .filter(|id| {
            !id.is_geometry()
                && !matches!(id, ParamId::Offset(_) | ParamId::Tcp(_) | ParamId::TipTcp(..))
                && !id.is_load_compliance()
                && !matches!(id, ParamId::Mass(_))
        })
        .filter(|id| model.get(*id) != 0.0)
        .map(|id| format!("{id} = {} {}", model.get(id), id.unit()))
        .collect();
    if !not_in_urdf.is_empty() {
        return Err(field(
            model_path,
            "joint".into(),
            format!(
                "a URDF cannot carry {}: the written file would not be the calibrated arm; calibrate without \
                 these effects to write a URDF",
                not_in_urdf.join(", ")
            ),
        ));
    }
    let mut edits = Vec::new();
    for (c, joint) in chain.joints.iter().zip(&model.joints) {
        let axis = Unit::new_normalize(Vector3::from(joint.axis));
        let rotation =
            joint.origin_rotation() * Rotation3::from_axis_angle(&axis, joint.offset_deg.to_radians());
        let calibrated = Isometry3::from_parts(
            Translation3::from(Vector3::from(joint.origin_xyz_mm)),
            UnitQuaternion::from_rotation_matrix(&rotation),
        );
        let (xyz_mm, rpy_deg) = xyz_rpy(&(c.folded.inverse() * calibrated));
        let [x, y, z] = xyz_mm.map(|v| v / 1000.0);
        let [roll, pitch, yaw] = rpy_deg.map(f64::to_radians);
        let origin = format!("<origin xyz=\"{x} {y} {z}\" rpy=\"{roll} {pitch} {yaw}\"/>");
        let element = doc.joints.iter().find(|e| e.name == c.name).ok_or_else(|| {
            doc.at_joint(&c.name, "", "no <joint> element of this name under <robot>".into())
        })?;
        edits.push(match element.origin {
            Some((start, end)) => (start, end, origin),
            None => (element.head_end, element.head_end, origin),
        });
    }
    let (masses, kept_in_model) = mass_edits(&doc, model);
    let weighed: Vec<String> = masses.iter().map(|m| m.link.clone()).collect();
    edits.extend(masses.into_iter().map(|m| (m.start, m.end, m.value)));
    edits.sort_by_key(|e| std::cmp::Reverse(e.0));
    let mut text = doc.text.clone();
    for (start, end, origin) in edits {
        text.replace_range(start..end, &origin);
    }
    let note = format!(
        "<!-- {} model to-urdf: the <origin> of the joints {} → {} calibrated ({m}); everything else as in {} -->",
        crate::files::WRITTEN_BY,
        source.base,
        source.tip,
        urdf.display()
    );
    let note = match weighed.is_empty() {
        true => note,
        false => format!("{note}\n<!-- the <mass> of the links {} fitted ({m}) -->", weighed.join(", ")),
    };
    let loads: Vec<String> = model
        .params()
        .into_iter()
        .filter(|id| id.is_load_compliance() && model.get(*id) != 0.0)
        .map(|id| format!("{id} = {} {}", model.get(id), id.unit()))
        .chain(kept_in_model)
        .collect();
    let note = match loads.is_empty() {
        true => note,
        false => format!(
            "{note}\n<!-- the compliances under gravity and the masses of bodies that are not links here ({}) have no \
             URDF element: they stay in {m} -->",
            loads.join(", ")
        ),
    };
    mark(&mut text, &note);
    let (read_back_mm, poses_checked) = read_back(urdf, &text, model, source)?;
    Ok(CalibratedUrdf {
        text,
        masses: weighed,
        joints: chain.joints.iter().map(|c| c.name.clone()).collect(),
        read_back_mm,
        poses_checked,
    })
}

/// One `<mass value>` edit: the link and the byte range of its value's text, and the new text.
struct MassEdit {
    link: String,
    start: usize,
    end: usize,
    value: String,
}

/// The `<mass value>` edits that write the model's masses into the URDF: one per body named
/// after a link with an `<inertial><mass>` whose mass the model changed; and the fitted masses of
/// bodies no link of the URDF holds (`mass:NAME = … kg`: they stay in the model file).
fn mass_edits(doc: &Document, model: &ArmModel) -> (Vec<MassEdit>, Vec<String>) {
    let (mut edits, mut elsewhere) = (Vec::new(), Vec::new());
    for (b, body) in model.tree.bodies.iter().enumerate() {
        let link = doc.robot.links.iter().find(|l| l.name == body.name);
        if link.is_some_and(|l| l.inertial.mass.value == body.mass_kg) {
            continue;
        }
        match doc.link_masses.iter().find(|p| p.0 == body.name).filter(|_| link.is_some()) {
            Some((name, (start, end))) => edits.push(MassEdit {
                link: name.clone(),
                start: *start,
                end: *end,
                value: format!("{}", body.mass_kg),
            }),
            None if model.free.iter().any(|f| f.id == ParamId::Mass(b)) => {
                elsewhere.push(format!("{} = {} kg", model.param_name(ParamId::Mass(b)), body.mass_kg))
            }
            None => {}
        }
    }
    (edits, elsewhere)
}

/// Put `note` on a line of its own after the XML declaration (or first), in place of the note of
/// an earlier run, so a URDF written from a written URDF carries one note.
fn mark(text: &mut String, note: &str) {
    let earlier = format!("<!-- {} model to-urdf", crate::files::WRITTEN_BY);
    if let Some(at) = text.find(&earlier) {
        let end = at + text[at..].find("-->").map_or(earlier.len(), |e| e + 3);
        text.replace_range(at..end, note);
        return;
    }
    let at = if text.trim_start().starts_with("<?xml") { text.find("?>").map_or(0, |e| e + 2) } else { 0 };
    let (before, after) = if at == 0 { ("", "\n") } else { ("\n", "") };
    text.insert_str(at, &format!("{before}{note}{after}"));
}

/// The first 12 hex digits of a hash.
fn short(hash: &str) -> &str {
    &hash[..hash.len().min(12)]
}

/// Read the written `text` as a URDF again and compare its forward kinematics with `model`'s at
/// [`READ_BACK_POSES`] readings ([`UrdfSource::spread_readings`]): the last joint's frame origin and points 100 mm along its axes. Returns the
/// largest distance (mm) and the number of poses; refused beyond [`READ_BACK_TOLERANCE_MM`].
fn read_back(
    urdf: &Path,
    text: &str,
    model: &ArmModel,
    source: &UrdfSource,
) -> Result<(f64, usize), FileError> {
    let doc = read_document(urdf, text.to_string())?;
    for body in &model.tree.bodies {
        let Some(link) = doc.robot.links.iter().find(|l| l.name == body.name && l.inertial.mass.value > 0.0)
        else {
            continue;
        };
        let (written, fitted) = (link.inertial.mass.value, body.mass_kg);
        if (written - fitted).abs() > 1e-12 * fitted.abs().max(1.0) {
            return Err(field(
                urdf,
                format!("<link name=\"{}\">/<inertial>/<mass>", body.name),
                format!(
                    "the URDF as written would hold {written} kg, the model {fitted} kg: nothing was written"
                ),
            ));
        }
    }
    let (mut written, _) = doc.model(&source.base, &source.tip)?;
    // The rigid arm: the compliances under gravity stay in the model file.
    let mut calibrated = model.clone();
    calibrated.tree.bodies.clear();
    let poses = source.spread_readings(READ_BACK_POSES);
    let mut worst: f64 = 0.0;
    for tcp in [[0.0; 3], [100.0, 0.0, 0.0], [0.0, 100.0, 0.0], [0.0, 0.0, 100.0]] {
        written.tcp_mm = tcp;
        calibrated.tcp_mm = tcp;
        written.tree.tips.iter_mut().for_each(|t| t.tcp_mm = tcp);
        calibrated.tree.tips.iter_mut().for_each(|t| t.tcp_mm = tcp);
        for tip in 0..written.tree.tip_count() {
            let (a, b) = (ModelChain::for_tip(&written, tip), ModelChain::for_tip(&calibrated, tip));
            for q in &poses {
                worst = worst.max((a.pose(q).position_mm - b.pose(q).position_mm).norm());
            }
        }
    }
    if worst.is_nan() || worst > READ_BACK_TOLERANCE_MM {
        return Err(field(
            urdf,
            format!("chain {} → {}", source.base, source.tip),
            format!(
                "the URDF as written would be {worst:.3e} mm from the calibrated model (read back at {} poses; \
                 at most {READ_BACK_TOLERANCE_MM} mm expected): nothing was written",
                poses.len()
            ),
        ));
    }
    Ok((worst, poses.len()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::kinematics::tool_pose;

    fn temp_dir(name: &str) -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!("kincal-urdf-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    const TWO_JOINTS: &str = "<robot name=\"t\"><link name=\"b\"/><link name=\"l1\"/><link name=\"m\"/><link name=\"l2\"/><link name=\"tool\"/>\
         <joint name=\"j1\" type=\"revolute\"><parent link=\"b\"/><child link=\"l1\"/><origin xyz=\"0 0 0.3\" rpy=\"0.1 0 0.2\"/><axis xyz=\"0 0 1\"/><limit lower=\"-2\" upper=\"2\" effort=\"1\" velocity=\"1\"/></joint>\
         <joint name=\"f\" type=\"fixed\"><parent link=\"l1\"/><child link=\"m\"/><origin xyz=\"0.2 0 0\" rpy=\"0 0.3 0\"/></joint>\
         <joint name=\"j2\" type=\"continuous\"><parent link=\"m\"/><child link=\"l2\"/><origin xyz=\"0.1 0.05 0\" rpy=\"0 0 0.5\"/><axis xyz=\"0 1 1\"/></joint>\
         <joint name=\"t\" type=\"fixed\"><parent link=\"l2\"/><child link=\"tool\"/><origin xyz=\"0 0 0.1\"/></joint></robot>";

    /// One pass finds the joints' origins and the links' masses, whatever the order of links and
    /// joints and whether an origin is an empty or a full element; a name the XML cannot read is
    /// refused with its line.
    #[test]
    fn one_pass_finds_joint_origins_and_link_masses() {
        let text = "<robot name=\"t\">\n<link name=\"b\"><inertial><mass value=\"2.5\"/></inertial></link>\n\
             <joint name=\"j1\" type=\"revolute\"><origin xyz=\"0 0 1\"></origin></joint>\n\
             <link name=\"l1\"><visual/><inertial><origin xyz=\"0 0 0\"/><mass value='0.75'/></inertial></link>\n\
             <joint name=\"j2\" type=\"revolute\"><origin xyz=\"0 0 2\"/></joint>\n<joint name=\"j3\"></joint></robot>";
        let places = index_places(Path::new("r.urdf"), text).unwrap();
        let names: Vec<&str> = places.joints.iter().map(|j| j.name.as_str()).collect();
        assert_eq!(names, ["j1", "j2", "j3"]);
        let origin = |k: usize| places.joints[k].origin.map(|(a, b)| &text[a..b]);
        assert_eq!(origin(0), Some("<origin xyz=\"0 0 1\"></origin>"));
        assert_eq!(origin(1), Some("<origin xyz=\"0 0 2\"/>"));
        assert_eq!(origin(2), None);
        assert_eq!(places.joints.iter().map(|j| j.line).collect::<Vec<_>>(), [3, 5, 6]);
        let masses: Vec<(&str, &str)> =
            places.link_masses.iter().map(|(name, (a, b))| (name.as_str(), &text[*a..*b])).collect();
        assert_eq!(masses, [("b", "2.5"), ("l1", "0.75")]);
        let bad = "<robot name=\"t\">\n<link name=\"b\"/>\n<joint name=\"j&bogus;\"></joint></robot>";
        let error = index_places(Path::new("r.urdf"), bad).err().map(|e| e.to_string()).unwrap_or_default();
        assert!(error.contains("r.urdf") && error.contains("line 3"), "{error}");
    }

    /// A two-joint URDF with a fixed joint between and a tool joint after: the model's tool point
    /// equals the URDF chain multiplied out by hand, and writing the model back reproduces it.
    #[test]
    fn a_urdf_chain_becomes_a_model_with_the_same_forward_kinematics() {
        let dir = temp_dir("fk");
        let path = dir.join("r.urdf");
        std::fs::write(&path, TWO_JOINTS).unwrap();
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
        let pose = tool_pose(&model, &q);
        assert!((pose.position_mm - tool.coords).norm() < 1e-9, "{} vs {}", pose.position_mm, tool.coords);
        assert_eq!(model.free.len(), 14);
        let source = model.urdf.clone().unwrap();
        assert_eq!(
            source.joint[0],
            UrdfJoint { name: "j1".into(), limits_deg: Some([-2f64.to_degrees(), 2f64.to_degrees()]) }
        );
        assert_eq!(source.joint[1], UrdfJoint { name: "j2".into(), limits_deg: None });
        assert_eq!(source.joint_index("j2_deg"), Some(1));
        assert_eq!(source.joint_index("j1"), Some(0));
        assert_eq!(source.joint_index("q1_deg"), None);
        let outside = source.outside_limits(&[120.0, 1000.0]);
        assert_eq!(outside.len(), 1, "only j1 has limits");
        assert_eq!(outside[0].0.name, "j1");
        // Calibrated values written back: the new URDF read as a model gives the same tool point.
        model.joints[1].offset_deg = 1.5;
        model.joints[0].origin_xyz_mm[0] += 0.7;
        model.joints[0].origin_turn_deg = [0.2, -0.1, 0.05];
        let out = calibrated_urdf(&path, &model, Path::new("m.toml"), None, None).unwrap();
        assert!(out.read_back_mm < READ_BACK_TOLERANCE_MM && out.poses_checked == READ_BACK_POSES, "{out:?}");
        assert_eq!(out.joints, ["j1", "j2"]);
        let back = dir.join("back.urdf");
        std::fs::write(&back, &out.text).unwrap();
        let reread = model_from_urdf(&back, "b", "tool").unwrap();
        let (a, b) = (tool_pose(&model, &q), tool_pose(&reread, &q));
        assert!((a.position_mm - b.position_mm).norm() < 1e-9, "{} vs {}", a.position_mm, b.position_mm);
        // Only the two revolute origins changed: the fixed joints' text is as it was.
        assert!(out.text.contains("<origin xyz=\"0.2 0 0\" rpy=\"0 0.3 0\"/>"), "{}", out.text);
        let prismatic = TWO_JOINTS.replace("\"continuous\"", "\"prismatic\"");
        std::fs::write(&path, prismatic).unwrap();
        let err = model_from_urdf(&path, "b", "tool").unwrap_err().to_string();
        assert!(err.contains("<joint name=\"j2\">") && err.contains("Prismatic"), "{err}");
        std::fs::remove_dir_all(&dir).ok();
    }

    /// A ROS 2 description names the joints again in `<ros2_control>` (and `<transmission>`)
    /// before the kinematic tree: only the `<robot>`'s own joints are edited.
    #[test]
    fn joints_named_in_ros2_control_and_transmissions_are_never_edited() {
        let dir = temp_dir("ros2");
        let control = "<ros2_control name=\"hw\" type=\"system\"><joint name=\"j1\"><origin xyz=\"9 9 9\"/><command_interface name=\"position\"/></joint>\
             <joint name=\"j2\"><command_interface name=\"position\"/></joint></ros2_control>\
             <transmission name=\"tr\"><joint name=\"j1\"><hardwareInterface>x</hardwareInterface></joint></transmission>";
        let text = TWO_JOINTS.replacen("<link name=\"b\"/>", &format!("{control}\n<link name=\"b\"/>"), 1);
        let path = dir.join("r.urdf");
        std::fs::write(&path, &text).unwrap();
        let mut model = model_from_urdf(&path, "b", "tool").unwrap();
        model.joints[0].origin_xyz_mm[2] += 1.0;
        let out = calibrated_urdf(&path, &model, Path::new("m.toml"), None, None).unwrap();
        assert!(out.text.contains(control), "the ros2_control and transmission entries are untouched");
        assert!(out.text.contains("<origin xyz=\"0 0 0.301\""), "{}", out.text);
        std::fs::remove_dir_all(&dir).ok();
    }

    /// Near pitch ±90° the roll-pitch-yaw of a rotation still gives it back to round-off.
    #[test]
    fn rpy_of_gives_the_rotation_back_at_and_near_gimbal_lock() {
        for pitch in [std::f64::consts::FRAC_PI_2, -std::f64::consts::FRAC_PI_2, 1.570796325, 0.3] {
            for (roll, yaw) in [(0.0, 0.0), (0.4, -1.1), (3.0, 2.0)] {
                let r = Rotation3::from_euler_angles(roll, pitch, yaw);
                let [a, b, c] = rpy_of(r.matrix());
                let back = Rotation3::from_euler_angles(a, b, c);
                assert!((back.matrix() - r.matrix()).norm() < 1e-15, "{roll} {pitch} {yaw}: {a} {b} {c}");
            }
        }
    }
}
