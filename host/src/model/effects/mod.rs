//! The effect library: physically motivated terms that can be added to the arm model, named
//! `KIND:JOINT` (joints 1-based) or `KIND` for whole-arm effects (`harmonic:JOINT:ORDER` for the
//! periodic encoder errors of order 3 and 4). Each family lives in its own file with its formula
//! and physical cause; the kinematics evaluates all of them in closed form.
//!
//! # Adding a family
//!
//! Today a new family touches these places (the compiler finds most of them once step 2 is done):
//! 1. `model/effects/NAME.rs`: a doc comment with the formula (in the parameters' units, on the
//!    raw encoder angle φ or the geometry) and the physical cause, and its partial derivatives
//!    (see [`harmonic`]); `pub mod NAME;` here.
//! 2. `model/params.rs`: one [`ParamId`] variant per scalar, its name in `JOINT_KINDS`, its slot
//!    in `joint_kind`/`from_joint_kind`, its unit.
//! 3. `model/mod.rs`: the field of [`crate::model::Joint`] (serde default, skipped when zero, so
//!    old model files load) and its `slot`.
//! 4. Here: an [`EffectKind`], its name in `KINDS`, its parameters in [`Effect::params`], its
//!    default bounds in [`default_half_range`], and `is_non_geometric` if it is not DH geometry.
//! 5. `model/kinematics.rs`: the term in `joint_angle` (angle effects) or an op (geometry), and
//!    its partials in the `AnglePartials` list (`ANGLE_DEPS`).
//! 6. `simulate.rs`: the same term written again in the independent forward path
//!    (`tool_frame_with`), so tests can hide it in data the fitting code did not make.
//! 7. `calib/diagnose/evidence.rs`: the plain words (`effect_words`) for the kind.
//! 8. The controller: `protocol/src/params.rs` (the parameter blob), `controller/device.rs`
//!    (the mapping) and the firmware kinematics — until then [`beyond_controller`] names the
//!    parameters the controller cannot evaluate and `kincal upload` refuses such a model.
//!
//! `mass:BODY` ([`mass`]) fits a body's mass in those loads: it names a body of the model's mass
//! table, not a joint, and is resolved against the model ([`Effect::check_in`],
//! [`Effect::params_in`]); it is not among the candidates the diagnosis screens (only the products
//! of masses and compliances reach a point, see its module).
//!
//! `sag` and `bend` (deflections under the loads of a mass table, [`crate::model::tree`]) have no
//! second forward path in `simulate.rs`: their independent peer is the pinocchio generator
//! `tests/gen/humanoid.py`, which the humanoid test checks kincal's loads against.

pub mod bend;
pub mod compliance;
pub mod eccentricity;
pub mod geometric;
pub mod harmonic;
pub mod mass;
pub mod sag;

use crate::model::{ArmModel, ParamId, MAX_BODIES, MAX_TREE_JOINTS};
use mass::BodyName;
use std::fmt;

/// Kinds of effect.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum EffectKind {
    /// Encoder zero offset δθ.
    Offset,
    /// DH d.
    Length,
    /// DH a.
    LinkOffset,
    /// DH α error.
    Twist,
    /// Hayati β.
    Axis,
    /// First-harmonic angle error.
    Eccentricity,
    /// Second-harmonic angle error.
    Eccentricity2,
    /// Gravity compliance.
    Compliance,
    /// Third-harmonic angle error.
    Harmonic3,
    /// Fourth-harmonic angle error.
    Harmonic4,
    /// Joint compliance under the gravity torque of the masses beyond the joint.
    Sag,
    /// Lateral compliance under the gravity moment across the joint's axis.
    Bend,
    /// The mass of a body of the mass table (every body, without a name).
    Mass,
    /// 3-D tool offset.
    Tcp,
    /// Length scale.
    Scale,
}

const KINDS: [(EffectKind, &str); 15] = [
    (EffectKind::Offset, "offset"),
    (EffectKind::Length, "length"),
    (EffectKind::LinkOffset, "link_offset"),
    (EffectKind::Twist, "twist"),
    (EffectKind::Axis, "axis"),
    (EffectKind::Eccentricity, "eccentricity"),
    (EffectKind::Eccentricity2, "eccentricity2"),
    (EffectKind::Compliance, "compliance"),
    (EffectKind::Harmonic3, "harmonic:3"),
    (EffectKind::Harmonic4, "harmonic:4"),
    (EffectKind::Sag, "sag"),
    (EffectKind::Bend, "bend"),
    (EffectKind::Mass, "mass"),
    (EffectKind::Tcp, "tcp"),
    (EffectKind::Scale, "scale"),
];

/// One effect: a kind and, for per-joint kinds, the joint (0-based). The compliances under
/// gravity (`sag`, `bend`) also come without a joint: every joint of the robot at once (the
/// joints that carry no load are left to the identifiability step). A mass names its body
/// (`mass:payload`), or none for every body of the mass table.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Effect {
    /// What kind.
    pub kind: EffectKind,
    /// Joint, 0-based, for per-joint kinds.
    pub joint: Option<usize>,
    /// The body, for a mass.
    pub body: Option<BodyName>,
}

impl EffectKind {
    fn name(self) -> &'static str {
        KINDS.iter().find(|k| k.0 == self).map_or("?", |k| k.1)
    }

    /// Eccentricity, harmonics and compliance: terms beyond the DH geometry, listed in model
    /// files.
    pub fn is_non_geometric(self) -> bool {
        matches!(
            self,
            EffectKind::Eccentricity
                | EffectKind::Eccentricity2
                | EffectKind::Harmonic3
                | EffectKind::Harmonic4
                | EffectKind::Compliance
                | EffectKind::Sag
                | EffectKind::Bend
        )
    }

    /// Cycles per revolution of a periodic encoder error (1 for eccentricity).
    pub fn harmonic_order(self) -> Option<u32> {
        match self {
            EffectKind::Eccentricity => Some(1),
            EffectKind::Eccentricity2 => Some(2),
            EffectKind::Harmonic3 => Some(3),
            EffectKind::Harmonic4 => Some(4),
            _ => None,
        }
    }

    fn per_joint(self) -> bool {
        !matches!(self, EffectKind::Tcp | EffectKind::Scale)
    }

    /// Kinds that also stand for every joint at once (no joint given).
    fn whole_robot(self) -> bool {
        matches!(self, EffectKind::Sag | EffectKind::Bend)
    }

    /// Sag, bend and mass: the gravity loads of a mass table.
    pub fn needs_masses(self) -> bool {
        matches!(self, EffectKind::Sag | EffectKind::Bend | EffectKind::Mass)
    }
}

impl Effect {
    /// The periodic encoder error of `order` (1..=4) cycles per revolution on `joint` (0-based).
    pub fn harmonic(joint: usize, order: u32) -> Option<Effect> {
        let kind = match order {
            1 => EffectKind::Eccentricity,
            2 => EffectKind::Eccentricity2,
            3 => EffectKind::Harmonic3,
            4 => EffectKind::Harmonic4,
            _ => return None,
        };
        (joint < MAX_TREE_JOINTS).then_some(Effect { kind, joint: Some(joint), body: None })
    }

    /// The mass of the body named `body` (see [`mass`]).
    pub fn mass(body: &str) -> Option<Effect> {
        Some(Effect { kind: EffectKind::Mass, joint: None, body: Some(BodyName::new(body)?) })
    }

    /// Parse `eccentricity:5`, `harmonic:3:3` (joint 3, 3 per revolution), `tcp`, `scale`, …
    pub fn parse(name: &str) -> Option<Effect> {
        if let Some(rest) = name.strip_prefix("harmonic:") {
            let (joint, order) = rest.split_once(':')?;
            let joint: usize = joint.parse().ok()?;
            return Effect::harmonic(joint.checked_sub(1)?, order.parse().ok()?);
        }
        if let Some(body) = name.strip_prefix("mass:") {
            return Effect::mass(body);
        }
        if name == "mass" {
            return Some(Effect { kind: EffectKind::Mass, joint: None, body: None });
        }
        let (kind_name, joint) = match name.split_once(':') {
            Some((k, j)) => (k, Some(j.parse::<usize>().ok()?)),
            None => (name, None),
        };
        let kind = KINDS.iter().find(|k| k.1 == kind_name)?.0;
        match (kind.per_joint(), joint) {
            _ if kind == EffectKind::Mass => None,
            (true, Some(j)) if (1..=MAX_TREE_JOINTS).contains(&j) => {
                Some(Effect { kind, joint: Some(j - 1), body: None })
            }
            (false, None) => Some(Effect { kind, joint: None, body: None }),
            (true, None) if kind.whole_robot() => Some(Effect { kind, joint: None, body: None }),
            _ => None,
        }
    }

    /// The effect names [`Effect::parse`] reads, for error messages: `J` stands for a joint
    /// number (1-based), `N` for the harmonic's order per revolution and `BODY` for a body of
    /// the mass table.
    pub fn syntax() -> String {
        let mut names = Vec::new();
        for (kind, name) in KINDS {
            let name = match name.split_once(':') {
                Some((harmonic, _)) if names.iter().any(|n: &String| n.starts_with(harmonic)) => continue,
                Some((harmonic, _)) => format!("{harmonic}:J:N"),
                None if kind == EffectKind::Mass => format!("{name}[:BODY]"),
                None if kind.whole_robot() => format!("{name}[:J]"),
                None if kind.per_joint() => format!("{name}:J"),
                None => name.to_string(),
            };
            names.push(name);
        }
        names.join(", ")
    }

    /// Every effect of the library for an arm of `joints` joints, per-joint kinds on every joint
    /// (the compliances under gravity once, for every joint at once; no mass: see [`mass`]).
    pub fn library(joints: usize) -> Vec<Effect> {
        let mut out = Vec::new();
        for (kind, _) in KINDS.into_iter().filter(|k| k.0 != EffectKind::Mass) {
            if kind.per_joint() && !kind.whole_robot() {
                out.extend((0..joints).map(|j| Effect { kind, joint: Some(j), body: None }));
            } else {
                out.push(Effect { kind, joint: None, body: None });
            }
        }
        out
    }

    /// The effects of the library that apply to `model`: [`Effect::library`] for its joints,
    /// without the mass-torque compliances when it has no mass table.
    pub fn library_for(model: &ArmModel) -> Vec<Effect> {
        let masses = !model.tree.bodies.is_empty();
        Effect::library(model.joints.len()).into_iter().filter(|e| masses || !e.kind.needs_masses()).collect()
    }

    /// The model parameters this effect adds (of every joint a tree may have, for a whole-robot
    /// effect, and of every body a mass table may have for a mass: a model holds those of its own
    /// joints and bodies, see [`Effect::params_in`]).
    pub fn params(self) -> Vec<ParamId> {
        let j = self.joint.unwrap_or(0);
        match (self.kind, self.joint) {
            (EffectKind::Sag, None) => return (0..MAX_TREE_JOINTS).map(ParamId::Sag).collect(),
            (EffectKind::Bend, None) => return (0..MAX_TREE_JOINTS).map(ParamId::Bend).collect(),
            (EffectKind::Mass, _) => return (0..MAX_BODIES).map(ParamId::Mass).collect(),
            _ => {}
        }
        match self.kind {
            EffectKind::Offset => vec![ParamId::Offset(j)],
            EffectKind::Length => vec![ParamId::Length(j)],
            EffectKind::LinkOffset => vec![ParamId::LinkOffset(j)],
            EffectKind::Twist => vec![ParamId::Twist(j)],
            EffectKind::Axis => vec![ParamId::Axis(j)],
            EffectKind::Eccentricity => vec![ParamId::EccSin(j), ParamId::EccCos(j)],
            EffectKind::Eccentricity2 => vec![ParamId::Ecc2Sin(j), ParamId::Ecc2Cos(j)],
            EffectKind::Compliance => vec![ParamId::Compliance(j)],
            EffectKind::Harmonic3 => vec![ParamId::Harm3Sin(j), ParamId::Harm3Cos(j)],
            EffectKind::Harmonic4 => vec![ParamId::Harm4Sin(j), ParamId::Harm4Cos(j)],
            EffectKind::Sag => vec![ParamId::Sag(j)],
            EffectKind::Bend => vec![ParamId::Bend(j)],
            EffectKind::Tcp => vec![ParamId::Tcp(0), ParamId::Tcp(1), ParamId::Tcp(2)],
            EffectKind::Scale => vec![ParamId::Scale],
            EffectKind::Mass => unreachable!("returned above"),
        }
    }

    /// The parameters of the effect that `model` holds (a whole-robot effect: those of its
    /// joints; a mass: its body's, every body's without a name).
    pub fn params_in(self, model: &ArmModel) -> Vec<ParamId> {
        if self.kind == EffectKind::Mass {
            return match self.body {
                Some(name) => model.tree.body_index(name.as_str()).map(ParamId::Mass).into_iter().collect(),
                None => (0..model.tree.bodies.len()).map(ParamId::Mass).collect(),
            };
        }
        let joints = model.joints.len();
        self.params().into_iter().filter(|p| p.joint().is_none_or(|j| j < joints)).collect()
    }

    /// Why `model` cannot take this effect (a joint it does not have, a mass-torque effect
    /// without a mass table, a body its table does not have), in words naming what the model
    /// has; `None` when it can.
    pub fn check_in(self, model: &ArmModel) -> Option<String> {
        if self.joint.is_some_and(|j| j >= model.joints.len()) {
            return Some(format!("the model has {} joints; no such joint", model.joints.len()));
        }
        // The first parameter stands for the kind (a mass table, a tip); the others for joints and
        // bodies a model may not have, checked below.
        if let Some(why) = self.params().first().and_then(|p| model.lacks(*p)) {
            return Some(why);
        }
        let body = self.body.filter(|_| self.kind == EffectKind::Mass)?;
        model.tree.body_index(body.as_str()).is_none().then(|| {
            format!(
                "the mass table has no body named \"{}\"; its bodies are {}",
                body.as_str(),
                model.tree.body_names()
            )
        })
    }

    /// True when every parameter of the effect that `model` holds is free in it.
    pub fn is_in(self, model: &ArmModel) -> bool {
        self.params_in(model).iter().all(|p| model.free.iter().any(|f| f.id == *p))
    }

    /// Make the effect's parameters free in `model`, with bounds of ± the default half-range
    /// around their current values (a mass: from zero to [`mass_upper_bound`]; parameters
    /// already free keep their bounds).
    pub fn add_to(self, model: &mut ArmModel) {
        for p in self.params_in(model) {
            if !model.free.iter().any(|f| f.id == p) {
                let v = model.get(p);
                let h = default_half_range(p);
                match p {
                    ParamId::Mass(_) => model.free_param(p, 0.0, mass_upper_bound(v)),
                    _ => model.free_param(p, v - h, v + h),
                }
            }
        }
    }
}

/// The upper bound a fitted mass gets from its table value `kg`: three times it, at least 20 kg
/// more (an unknown payload is often entered as a guess or as zero).
pub fn mass_upper_bound(kg: f64) -> f64 {
    (3.0 * kg).max(kg + 20.0).min(crate::model::tree::MAX_BODY_KG)
}

/// Half-width of the bounds given to a parameter when an effect is added, in its unit.
pub fn default_half_range(p: ParamId) -> f64 {
    match p {
        ParamId::Offset(_) => 10.0,
        ParamId::Length(_) | ParamId::LinkOffset(_) | ParamId::Tcp(_) | ParamId::OriginXyz(..) => 10.0,
        ParamId::TipTcp(..) => 10.0,
        ParamId::Sag(_) | ParamId::Bend(_) => 30.0,
        ParamId::Twist(_) | ParamId::Axis(_) | ParamId::OriginTurn(..) => 5.0,
        ParamId::EccSin(_) | ParamId::EccCos(_) => 2.0,
        ParamId::Ecc2Sin(_) | ParamId::Ecc2Cos(_) => 1.0,
        ParamId::Compliance(_) => 2.0,
        ParamId::Harm3Sin(_) | ParamId::Harm3Cos(_) | ParamId::Harm4Sin(_) | ParamId::Harm4Cos(_) => 1.0,
        ParamId::Scale => 5000.0,
        ParamId::Mass(_) => 20.0,
    }
}

/// Parameters of `model` with a non-zero value that the controller's parameter blob cannot
/// carry (the higher harmonics, the compliances under a mass table's loads): uploading would
/// silently drop them.
pub fn beyond_controller(model: &ArmModel) -> Vec<ParamId> {
    (0..model.joints.len())
        .flat_map(|j| {
            [
                ParamId::Harm3Sin(j),
                ParamId::Harm3Cos(j),
                ParamId::Harm4Sin(j),
                ParamId::Harm4Cos(j),
                ParamId::Sag(j),
                ParamId::Bend(j),
            ]
        })
        .filter(|p| model.get(*p) != 0.0)
        .collect()
}

impl fmt::Display for Effect {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if let (Some(order @ 3..), Some(j)) = (self.kind.harmonic_order(), self.joint) {
            return write!(f, "harmonic:{}:{order}", j + 1);
        }
        if let Some(body) = self.body {
            return write!(f, "{}:{}", self.kind.name(), body.as_str());
        }
        match self.joint {
            Some(j) => write!(f, "{}:{}", self.kind.name(), j + 1),
            None => write!(f, "{}", self.kind.name()),
        }
    }
}

impl serde::Serialize for Effect {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_str(self)
    }
}

impl<'de> serde::Deserialize<'de> for Effect {
    /// An effect by its name (`compliance:2`, `harmonic:3:3`, `scale`).
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Effect, D::Error> {
        let name = String::deserialize(d)?;
        Effect::parse(&name)
            .ok_or_else(|| serde::de::Error::custom(format!("\"{name}\" is not an effect of the library")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_effect_name_parses_back() {
        let library = Effect::library(6);
        assert_eq!(library.len(), 10 * 6 + 2 + 2);
        for example in
            ["offset:2", "harmonic:3:3", "sag", "sag:2", "bend:1", "tcp", "mass", "mass:panda_hand"]
        {
            assert!(Effect::parse(example).is_some(), "{example}");
        }
        assert_eq!(Effect::syntax().matches("harmonic").count(), 1, "{}", Effect::syntax());
        assert!(Effect::syntax().contains("sag[:J]") && Effect::syntax().contains("eccentricity2:J"));
        assert_eq!(Effect::parse("sag:3").map(|e| e.to_string()).as_deref(), Some("sag:3"));
        assert_eq!(Effect::parse("mass:payload").map(|e| e.to_string()).as_deref(), Some("mass:payload"));
        assert!(Effect::syntax().contains("mass[:BODY]"), "{}", Effect::syntax());
        for e in library {
            assert_eq!(Effect::parse(&e.to_string()), Some(e), "{e}");
        }
        assert_eq!(Effect::parse("harmonic:3:1"), Effect::parse("eccentricity:3"));
        assert_eq!(Effect::parse("harmonic:2:2"), Effect::parse("eccentricity2:2"));
        assert_eq!(Effect::parse("harmonic:3:3").map(|e| e.to_string()).as_deref(), Some("harmonic:3:3"));
        for bad in [
            "eccentricity",
            "tcp:1",
            "compliance:0",
            "warp:2",
            "scale:3",
            "harmonic:3:5",
            "harmonic:0:3",
            "harmonic:3",
            "mass:",
            "mass:a b",
            &format!("mass:{}", "x".repeat(48)),
        ] {
            assert_eq!(Effect::parse(bad), None, "{bad}");
        }
    }
}
