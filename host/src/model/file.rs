//! The model file (`kincal-arm/1`), TOML or JSON by extension.
//!
//! ```toml
//! format = "kincal-arm/1"
//! name = "SUTA nominal"
//! convention = "classic"          # or "modified"
//! tcp_mm = [0.0, 0.0, 253.0]
//! scale_ppm = 0.0                 # optional
//! [[joint]]                       # six rows, base to tip
//! offset_deg = -1.6
//! d_mm = 47.0
//! a_mm = 0.0
//! alpha_deg = 90.0
//! axis_deg = 0.0                  # optional
//! effects = ["eccentricity:5"]    # optional: effects whose parameters are free (default bounds)
//! [free]                          # parameters the calibration may move: [lower, upper]
//! "offset:2" = [10.7, 30.7]
//! [arm]                           # optional: the arm this model was calibrated on
//! id = "lab-arm-2"                # its controller's identity (what `kincal upload` checks)
//! firmware = "kincal-fw 0.1.0"    # optional
//! ```
//!
//! A branched robot (convention "urdf", up to [`MAX_TREE_JOINTS`] joints, each tip's path at most
//! [`MAX_JOINTS`]) adds each joint's parent and its named tips; any URDF model may carry a mass
//! table (what the gravity loads of `sag:j` and `bend:j` read):
//!
//! ```toml
//! parents = [0, 1, 2, 3, 4, 5]    # per joint, its parent joint (1-based), 0 = the base
//! [[tip]]                         # the first tip's point is tcp_mm; its own tcp_mm is ignored
//! name = "left_marker"
//! joint = 11                      # its last joint (1-based)
//! tcp_mm = [45.0, 30.0, 150.0]
//! [[body]]                        # a mass carried by a joint, centre in the joint's frame
//! name = "payload"                # optional (default bodyN): `mass:payload` fits its mass
//! joint = 1
//! mass_kg = 6.0
//! com_mm = [20.0, 10.0, 90.0]
//! ```

use super::params::MAX_TIPS;
use super::plausible::{plausible_limit, MAX_LENGTH_MM};
use super::tree::MAX_BODY_KG;
use super::urdf::UrdfSource;
use super::{
    ArmModel, Body, Convention, FreeParam, Joint, ParamId, Tip, Tree, MAX_BODIES, MAX_JOINTS, MAX_TREE_JOINTS,
};
use crate::files::{self, FileError};
use crate::model::effects::Effect;
use std::collections::BTreeMap;
use std::path::Path;

/// The format tag every model file carries.
pub const MODEL_FORMAT: &str = "kincal-arm/1";

#[derive(serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct ModelFile {
    format: String,
    #[serde(default)]
    name: String,
    convention: Convention,
    // Read as lists and checked for length: TOML would silently cut a longer list to an array.
    tcp_mm: Vec<f64>,
    #[serde(default)]
    scale_ppm: f64,
    joint: Vec<Joint>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    effects: Vec<String>,
    #[serde(default)]
    free: BTreeMap<String, Vec<f64>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    urdf: Option<UrdfSource>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    arm: Option<crate::trace::ArmIdentity>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    parents: Vec<usize>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    tip: Vec<Tip>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    body: Vec<Body>,
}

/// The tree of a model file (1-based joints there, 0-based here), checked: parents before
/// children, tips on joints the model has, each tip's path at most [`MAX_JOINTS`] joints,
/// bodies with a positive finite mass on a joint the model has.
fn tree_of(file: &ModelFile, joints: usize) -> Result<Tree, (String, String)> {
    let branched = !file.parents.is_empty() || !file.tip.is_empty();
    if branched && file.convention != Convention::Urdf {
        return Err((
            "parents".into(),
            "a branched model (parents, [[tip]]) has convention = \"urdf\"".into(),
        ));
    }
    if !file.body.is_empty() && file.convention != Convention::Urdf {
        return Err((
            "body".into(),
            "a mass table ([[body]]) belongs to a model of convention = \"urdf\"".into(),
        ));
    }
    if branched && (file.parents.len() != joints || file.tip.is_empty()) {
        return Err((
            "parents".into(),
            format!(
                "a branched model gives one parent per joint ({joints}, found {}) and at least one [[tip]]",
                file.parents.len()
            ),
        ));
    }
    let mut tree = Tree::default();
    for (j, &p) in file.parents.iter().enumerate() {
        if p > j {
            return Err((
                format!("parents[{}]", j + 1),
                format!(
                    "joint {} has parent {p}: expected 0 (the base) or an earlier joint (1 to {j})",
                    j + 1
                ),
            ));
        }
        tree.parents.push(p.checked_sub(1));
    }
    if file.tip.len() > MAX_TIPS {
        return Err(("tip".into(), format!("at most {MAX_TIPS} tips, found {}", file.tip.len())));
    }
    for (t, tip) in file.tip.iter().enumerate() {
        let key = format!("tip[{}]", t + 1);
        if !(1..=joints).contains(&tip.joint) {
            return Err((
                format!("{key}.joint"),
                format!("expected a joint 1 to {joints}, found {}", tip.joint),
            ));
        }
        if file.tip[..t].iter().any(|o| o.name == tip.name) || tip.name.trim().is_empty() {
            return Err((
                format!("{key}.name"),
                format!("\"{}\": expected a name no other tip has", tip.name),
            ));
        }
        if !tip.tcp_mm.iter().all(|v| v.is_finite() && v.abs() <= MAX_LENGTH_MM) {
            return Err((format!("{key}.tcp_mm"), format!("expected finite mm within ±{MAX_LENGTH_MM}")));
        }
        tree.tips.push(Tip { joint: tip.joint - 1, ..tip.clone() });
        let path = tree.path(joints, t);
        if path.len() > MAX_JOINTS {
            return Err((key, format!("its chain has {} joints; at most {MAX_JOINTS}", path.len())));
        }
    }
    if file.body.len() > MAX_BODIES {
        return Err(("body".into(), format!("at most {MAX_BODIES} bodies, found {}", file.body.len())));
    }
    for (b, body) in file.body.iter().enumerate() {
        let key = format!("body[{}]", b + 1);
        let name = match body.name.trim() {
            "" => format!("body{}", b + 1),
            name => name.to_string(),
        };
        if name.chars().any(|c| c.is_whitespace() || c == ',')
            || name.parse::<usize>().is_ok()
            || tree.body_index(&name).is_some()
        {
            return Err((
                format!("{key}.name"),
                format!(
                    "\"{name}\": expected a name no other body has, without spaces or commas, not a number"
                ),
            ));
        }
        if !(1..=joints).contains(&body.joint) {
            return Err((
                format!("{key}.joint"),
                format!("expected a joint 1 to {joints}, found {}", body.joint),
            ));
        }
        if !(body.mass_kg.is_finite() && body.mass_kg >= 0.0 && body.mass_kg <= MAX_BODY_KG) {
            return Err((
                format!("{key}.mass_kg"),
                format!("expected a mass in kg, 0 <= m <= {MAX_BODY_KG}"),
            ));
        }
        if !body.com_mm.iter().all(|v| v.is_finite() && v.abs() <= MAX_LENGTH_MM) {
            return Err((format!("{key}.com_mm"), format!("expected finite mm within ±{MAX_LENGTH_MM}")));
        }
        tree.bodies.push(Body { name, joint: body.joint - 1, ..body.clone() });
    }
    Ok(tree)
}

/// Check a joint row holds only its convention's geometry, and normalise a URDF axis.
fn check_joint_convention(joint: &mut Joint, convention: Convention) -> Result<(), String> {
    let dh = [joint.d_mm, joint.a_mm, joint.alpha_deg, joint.axis_deg];
    let urdf = joint.origin_xyz_mm.iter().chain(&joint.origin_rpy_deg).chain(&joint.origin_turn_deg);
    match convention {
        Convention::Urdf => {
            if dh.iter().any(|v| *v != 0.0) {
                return Err("a URDF joint holds origin_xyz_mm, origin_rpy_deg and axis; d_mm, a_mm, \
                            alpha_deg and axis_deg must be 0"
                    .into());
            }
            if !joint.origin_rpy_deg.iter().all(|v| v.is_finite() && v.abs() <= 360.0) {
                return Err(format!(
                    "origin_rpy_deg {:?} must be finite angles within ±360°",
                    joint.origin_rpy_deg
                ));
            }
            let norm = joint.axis.iter().map(|x| x * x).sum::<f64>().sqrt();
            if !(norm.is_finite() && norm > 1e-9) {
                return Err(format!("axis {:?} is not a direction; expected e.g. [0, 0, 1]", joint.axis));
            }
            joint.axis = joint.axis.map(|x| x / norm);
        }
        Convention::Classic | Convention::Modified => {
            if urdf.into_iter().any(|v| *v != 0.0) || joint.axis != [0.0, 0.0, 1.0] {
                return Err(
                    "origin_xyz_mm, origin_rpy_deg, origin_turn_deg and axis belong to convention = \"urdf\""
                        .into(),
                );
            }
        }
    }
    Ok(())
}

/// Where the SUTA model lives in the repository, and the name its built-in copy goes by.
pub const SUTA_MODEL_PATH: &str = "examples/suta/model.toml";

/// The SUTA nominal model file (thesis Table 3.2), built into kincal.
pub const SUTA_MODEL_TOML: &str = include_str!("../../../examples/suta/model.toml");

/// The built-in SUTA model ([`SUTA_MODEL_TOML`]); a test holds it to parse.
pub(crate) fn suta_model() -> ArmModel {
    ArmModel::parse(SUTA_MODEL_TOML, Path::new(SUTA_MODEL_PATH))
        .unwrap_or_else(|e| unreachable!("the built-in SUTA model parses (tested): {e}"))
}

fn is_json(path: &Path) -> bool {
    path.extension().is_some_and(|e| e.eq_ignore_ascii_case("json"))
}

impl ArmModel {
    /// Why the model has no parameter `id` although its joint exists: a tip it does not have,
    /// a mass-torque compliance or a mass without a mass table, a body the table does not have.
    pub fn lacks(&self, id: ParamId) -> Option<String> {
        match id {
            ParamId::TipTcp(t, _) if t >= self.tree.tips.len() => {
                Some(format!("the model has {} tip(s); no tip {}", self.tree.tip_count(), t + 1))
            }
            ParamId::Sag(_) | ParamId::Bend(_) | ParamId::Mass(_)
                if self.tree.bodies.is_empty() || self.convention != Convention::Urdf =>
            {
                Some("sag, bend and mass are the gravity loads of a mass table: a URDF model with [[body]] rows \
                      (`kincal model from-urdf --masses` reads them from <inertial>); this model has no mass table"
                    .into())
            }
            ParamId::Mass(b) if b >= self.tree.bodies.len() => Some(format!(
                "the mass table has {} bodies ({}); no body {}",
                self.tree.bodies.len(),
                self.tree.body_names(),
                b + 1
            )),
            _ => None,
        }
    }

    /// Read a model file (`.toml`, or `.json`).
    pub fn load(path: &Path) -> Result<ArmModel, FileError> {
        files::check_regular_file(path)?;
        let text = std::fs::read_to_string(path)
            .map_err(|source| FileError::Io { path: path.to_owned(), source })?;
        ArmModel::parse(&text, path)
    }

    /// A model from the text of a file named `path` (JSON by its extension, otherwise TOML).
    fn parse(text: &str, path: &Path) -> Result<ArmModel, FileError> {
        let syntax = |message: String| FileError::Syntax { path: path.to_owned(), message };
        let file: ModelFile = if is_json(path) {
            serde_json::from_str(text).map_err(|e| files::json_error(path, text, e))?
        } else {
            toml::from_str(text).map_err(|e| syntax(e.to_string()))?
        };
        ArmModel::from_file(file, path)
    }

    fn from_file(file: ModelFile, path: &Path) -> Result<ArmModel, FileError> {
        let field =
            |field: String, message: String| FileError::Field { path: path.to_owned(), field, message };
        if file.format != MODEL_FORMAT {
            return Err(field(
                "format".into(),
                format!("expected \"{MODEL_FORMAT}\", found \"{}\"", file.format),
            ));
        }
        let most = if file.parents.is_empty() { MAX_JOINTS } else { MAX_TREE_JOINTS };
        if !(1..=most).contains(&file.joint.len()) {
            return Err(field(
                "joint".into(),
                format!("expected 1 to {most} [[joint]] rows (revolute joints), found {}", file.joint.len()),
            ));
        }
        let tree = tree_of(&file, file.joint.len()).map_err(|(name, message)| field(name, message))?;
        let mut joints = file.joint.clone();
        for (j, joint) in joints.iter_mut().enumerate() {
            check_joint_convention(joint, file.convention)
                .map_err(|message| field(format!("joint[{}]", j + 1), message))?;
        }
        let tcp_mm: [f64; 3] = file.tcp_mm.clone().try_into().map_err(|_| {
            field("tcp_mm".into(), format!("expected 3 numbers [x, y, z] in mm, found {}", file.tcp_mm.len()))
        })?;
        if let Some(source) = &file.urdf {
            if file.convention != Convention::Urdf || source.joint.len() != joints.len() {
                return Err(field(
                    "urdf".into(),
                    format!(
                        "records a URDF chain of {} joints for a {:?} model of {} joints: the [urdf] table \
                         belongs to the model `kincal model from-urdf` made of that chain",
                        source.joint.len(),
                        file.convention,
                        joints.len()
                    ),
                ));
            }
        }
        if let Some(arm) = &file.arm {
            arm.check().map_err(|(key, message)| field(format!("arm.{key}"), message))?;
        }
        let mut model = ArmModel {
            name: file.name,
            convention: file.convention,
            joints,
            tcp_mm,
            scale_ppm: file.scale_ppm,
            free: Vec::new(),
            urdf: file.urdf,
            arm: file.arm,
            tree,
        };
        if let Some((name, message)) = model.implausible() {
            return Err(field(name, message));
        }
        for name in &file.effects {
            let effect = Effect::parse(name).ok_or_else(|| {
                field(
                    format!("effects[\"{name}\"]"),
                    format!(
                        "unknown effect; expected one of {} (J: a joint number, N: 1–4)",
                        Effect::syntax()
                    ),
                )
            })?;
            if let Some(message) = effect.check_in(&model) {
                return Err(field(format!("effects[\"{name}\"]"), message));
            }
            effect.add_to(&mut model);
        }
        for (name, bounds) in file.free {
            let key = format!("free.\"{name}\"");
            let id = model.parse_param(&name).ok_or_else(|| {
                let replaced = ["origin_roll:", "origin_pitch:", "origin_yaw:"].iter().any(|p| name.starts_with(p));
                field(
                    key.clone(),
                    if replaced {
                        "origin_roll, origin_pitch and origin_yaw are no longer parameters (gimbal-locked at pitch \
                         ±90°): a URDF origin now turns by origin_rx, origin_ry, origin_rz about its nominal frame; \
                         make the model again with `kincal model from-urdf`"
                            .into()
                    } else {
                        format!(
                            "unknown parameter; expected e.g. offset:1, length:3, link_offset:2, twist:5, axis:2, \
                             origin_x:2, origin_rz:2, tcp.z, scale, mass:BODY (bodies: {})",
                            model.tree.body_names()
                        )
                    },
                )
            })?;
            if id.joint().is_some_and(|j| j >= model.joints.len()) {
                return Err(field(
                    key,
                    format!(
                        "unknown parameter: the model has {} joints, there is no such joint",
                        model.joints.len()
                    ),
                ));
            }
            if let Some(message) = model.lacks(id) {
                return Err(field(key, message));
            }
            let [lower, upper] = <[f64; 2]>::try_from(bounds.as_slice()).map_err(|_| {
                field(key.clone(), format!("expected 2 numbers [lower, upper], found {}", bounds.len()))
            })?;
            if !(lower.is_finite() && upper.is_finite() && lower < upper) {
                return Err(field(
                    key,
                    format!("bounds must be finite with lower < upper, found [{lower}, {upper}]"),
                ));
            }
            let limit = plausible_limit(id);
            if lower < -limit || upper > limit {
                return Err(field(
                    key,
                    format!(
                        "bounds [{lower}, {upper}] {} reach beyond any plausible arm (|value| <= {limit})",
                        id.unit()
                    ),
                ));
            }
            let value = model.get(id);
            if !(lower..=upper).contains(&value) {
                return Err(field(
                    key,
                    format!("current value {value} lies outside its bounds [{lower}, {upper}]"),
                ));
            }
            model.fix_param(id);
            model.free.push(FreeParam { id, lower, upper });
        }
        model.free.sort_by_key(|f| f.id.dense_index());
        Ok(model)
    }

    /// The model as file text (TOML, or JSON when `json`).
    pub fn to_text(&self, json: bool) -> String {
        let file = ModelFile {
            format: MODEL_FORMAT.into(),
            name: self.name.clone(),
            convention: self.convention,
            tcp_mm: self.tcp_mm.to_vec(),
            scale_ppm: self.scale_ppm,
            joint: self.joints.to_vec(),
            effects: crate::model::effects::Effect::library_for(self)
                .into_iter()
                .filter(|e| e.is_in(self) && e.kind.is_non_geometric())
                .map(|e| e.to_string())
                .collect(),
            free: self.free.iter().map(|f| (self.param_name(f.id), vec![f.lower, f.upper])).collect(),
            urdf: self.urdf.clone(),
            arm: self.arm.clone(),
            parents: match self.tree.is_branched() {
                true => (0..self.joints.len()).map(|j| self.tree.parent(j).map_or(0, |p| p + 1)).collect(),
                false => Vec::new(),
            },
            tip: self.tree.tips.iter().map(|t| Tip { joint: t.joint + 1, ..t.clone() }).collect(),
            body: self.tree.bodies.iter().map(|b| Body { joint: b.joint + 1, ..b.clone() }).collect(),
        };
        if json {
            serde_json::to_string_pretty(&file).unwrap_or_default()
        } else {
            toml::to_string_pretty(&file).unwrap_or_default()
        }
    }

    /// Write the model atomically (`.json` by extension, otherwise TOML).
    pub fn save(&self, path: &Path) -> Result<(), FileError> {
        files::write_atomic(path, self.to_text(is_json(path)).as_bytes())
            .map_err(|source| FileError::Io { path: path.to_owned(), source })
    }

    /// Write the model to the file the user named with `option` ([`files::write_output`]:
    /// refused over one of `inputs` or a file kincal did not write). A TOML file starts with
    /// `# written by kincal NOTE`, so a later run may replace it (JSON has no comments: an existing
    /// JSON file is never replaced).
    pub fn save_output(
        &self,
        path: &Path,
        option: &str,
        inputs: &[&Path],
        note: &str,
    ) -> Result<(), FileError> {
        let text = if is_json(path) {
            self.to_text(true)
        } else {
            format!("# {} {note}\n{}", files::WRITTEN_BY, self.to_text(false))
        };
        files::write_output(path, option, inputs, text.as_bytes())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_built_in_suta_model_is_the_repository_file() {
        let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(SUTA_MODEL_PATH);
        let model = ArmModel::suta_nominal();
        assert_eq!(ArmModel::load(&file).unwrap(), model);
        assert_eq!((model.joints.len(), model.free.len()), (6, 13));
        assert_eq!(model.joints[2].d_mm, 571.0);
    }

    #[test]
    fn model_round_trips_through_toml_and_json() {
        let dir = std::env::temp_dir().join(format!("kincal-model-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut model = ArmModel::suta_nominal();
        model.joints[4].axis_deg = 0.125;
        model.free_param(ParamId::Scale, -500.0, 500.0);
        for name in ["m.toml", "m.json"] {
            let path = dir.join(name);
            model.save(&path).unwrap();
            assert_eq!(ArmModel::load(&path).unwrap(), model, "{name}");
        }
        std::fs::remove_dir_all(&dir).ok();
    }

    /// A model may name its arm; the identity round-trips, a model without one reads as before,
    /// and a bad identity names `arm.id` or an unknown key.
    #[test]
    fn a_model_carries_its_arms_identity() {
        let dir = std::env::temp_dir().join(format!("kincal-model-arm-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut model = ArmModel::suta_nominal();
        model.arm = Some(crate::trace::ArmIdentity {
            firmware: Some("kincal-fw 0.1.0".into()),
            ..crate::trace::ArmIdentity::of("lab-arm-2")
        });
        for name in ["m.toml", "m.json"] {
            let path = dir.join(name);
            model.save(&path).unwrap();
            assert_eq!(ArmModel::load(&path).unwrap(), model, "{name}");
        }
        let text = model.to_text(false);
        assert!(text.contains("[arm]\nid = \"lab-arm-2\""), "{text}");
        assert!(!ArmModel::suta_nominal().to_text(false).contains("[arm]"), "none written when none");
        let path = dir.join("bad.toml");
        for (bad, named) in [
            (text.replace("\"lab-arm-2\"", "\"lab arm 2\""), "arm.id"),
            (text.replace("id = \"lab-arm-2\"", "serial = \"7\""), "serial"),
        ] {
            std::fs::write(&path, bad).unwrap();
            let err = ArmModel::load(&path).unwrap_err().to_string();
            assert!(err.contains("bad.toml") && err.contains(named), "{err}");
        }
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn listed_effects_become_free_with_default_bounds() {
        let dir = std::env::temp_dir().join(format!("kincal-effects-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("m.toml");
        // A key after a [[joint]] table belongs to that joint: it must be refused, not ignored.
        let misplaced = ArmModel::suta_nominal()
            .to_text(false)
            .replace("[free]", "effects = [\"eccentricity:5\"]\n\n[free]");
        std::fs::write(&path, &misplaced).unwrap();
        let err = ArmModel::load(&path).unwrap_err().to_string();
        assert!(err.contains("effects"), "{err}");
        let text = format!(
            "effects = [\"eccentricity:5\", \"compliance:2\"]\n{}",
            ArmModel::suta_nominal().to_text(false)
        );
        std::fs::write(&path, &text).unwrap();
        let model = ArmModel::load(&path).unwrap();
        for id in [ParamId::EccSin(4), ParamId::EccCos(4), ParamId::Compliance(1)] {
            assert!(model.free.iter().any(|f| f.id == id), "{id} should be free");
        }
        assert!(model.to_text(false).contains("eccentricity:5"), "saved files list their effects");
        std::fs::write(&path, text.replace("compliance:2", "wobble:2")).unwrap();
        let err = ArmModel::load(&path).unwrap_err().to_string();
        assert!(err.contains("wobble:2") && err.contains("unknown effect"), "{err}");
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn bad_model_files_name_the_field() {
        let dir = std::env::temp_dir().join(format!("kincal-badmodel-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let good = ArmModel::suta_nominal().to_text(false);
        let cases = [
            (good.replace("kincal-arm/1", "arm/9"), "format"),
            (good.replace("\"offset:1\"", "\"offset:9\""), "free.\"offset:9\""),
            (good.replacen("[[joint]]", "", 1).replacen("offset_deg = -1.6\n", "", 1), ""),
            // A longer list is an error, never cut to its expected length.
            (good.replace("[\n    10.7,\n    30.7,\n]", "[10.7, 20.7, 30.7]"), "expected 2 numbers"),
            (good.replace("253.0,\n]", "253.0,\n    1.0,\n]"), "tcp_mm"),
            (good.replace("scale_ppm = 0.0", "scale_ppm = -1000000.0"), "plausible"),
            (good.replace("d_mm = 571.0", "d_mm = 1e308"), "length:3"),
            (good.replace("d_mm = 571.0", "d_mm = 0.571").replace("d_mm = 371.0", "d_mm = 0.371"), "bounds"),
        ];
        for (i, (text, field)) in cases.iter().enumerate() {
            let path = dir.join(format!("bad{i}.toml"));
            std::fs::write(&path, text).unwrap();
            let err = ArmModel::load(&path).unwrap_err().to_string();
            assert!(err.contains("bad"), "{err}");
            assert!(err.contains(field), "{err} should name {field}");
        }
        std::fs::remove_dir_all(&dir).ok();
    }

    /// A model made from a URDF keeps its source (file, chain, hash, joint names and limits) and
    /// its origin turns through TOML and JSON; a file with the old roll-pitch-yaw parameter
    /// names is refused with the way forward.
    #[test]
    fn a_urdf_model_keeps_its_source_and_old_parameter_names_are_explained() {
        let dir = std::env::temp_dir().join(format!("kincal-urdfmodel-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let urdf = dir.join("r.urdf");
        std::fs::write(
            &urdf,
            "<robot name=\"r\"><link name=\"a\"/><link name=\"b\"/><link name=\"c\"/>\
             <joint name=\"shoulder\" type=\"revolute\"><parent link=\"a\"/><child link=\"b\"/><origin xyz=\"0 0 0.3\" rpy=\"0 1.5707963 0\"/><axis xyz=\"0 1 0\"/><limit lower=\"-1\" upper=\"1\" effort=\"1\" velocity=\"1\"/></joint>\
             <joint name=\"elbow\" type=\"continuous\"><parent link=\"b\"/><child link=\"c\"/><origin xyz=\"0.4 0 0\"/><axis xyz=\"0 0 1\"/></joint></robot>",
        )
        .unwrap();
        let mut model = crate::model::urdf::model_from_urdf(&urdf, "a", "c").unwrap();
        model.joints[1].origin_turn_deg = [0.1, -0.2, 0.3];
        for name in ["m.toml", "m.json"] {
            let path = dir.join(name);
            model.save(&path).unwrap();
            let back = ArmModel::load(&path).unwrap();
            assert_eq!(back, model, "{name}");
            let source = back.urdf.unwrap();
            assert_eq!((source.base.as_str(), source.tip.as_str(), source.joint.len()), ("a", "c", 2));
            assert_eq!(source.joint[0].name, "shoulder");
        }
        let text = model.to_text(false).replace("origin_rx:1", "origin_roll:1");
        let path = dir.join("old.toml");
        std::fs::write(&path, text).unwrap();
        let err = ArmModel::load(&path).unwrap_err().to_string();
        assert!(
            err.contains("origin_roll:1") && err.contains("origin_rx") && err.contains("from-urdf"),
            "{err}"
        );
        std::fs::remove_dir_all(&dir).ok();
    }
}
