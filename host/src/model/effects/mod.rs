//! The effect library: physically motivated terms that can be added to the arm model, named
//! `KIND:JOINT` (joints 1-based) or `KIND` for whole-arm effects. Each family lives in its own
//! file with its formula and physical cause; the kinematics evaluates all of them in closed form.

pub mod compliance;
pub mod eccentricity;
pub mod geometric;

use crate::model::{ArmModel, ParamId, JOINTS};
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
    /// 3-D tool offset.
    Tcp,
    /// Length scale.
    Scale,
}

const KINDS: [(EffectKind, &str); 10] = [
    (EffectKind::Offset, "offset"),
    (EffectKind::Length, "length"),
    (EffectKind::LinkOffset, "link_offset"),
    (EffectKind::Twist, "twist"),
    (EffectKind::Axis, "axis"),
    (EffectKind::Eccentricity, "eccentricity"),
    (EffectKind::Eccentricity2, "eccentricity2"),
    (EffectKind::Compliance, "compliance"),
    (EffectKind::Tcp, "tcp"),
    (EffectKind::Scale, "scale"),
];

/// One effect: a kind and, for per-joint kinds, the joint (0-based).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Effect {
    /// What kind.
    pub kind: EffectKind,
    /// Joint, 0-based, for per-joint kinds.
    pub joint: Option<usize>,
}

impl EffectKind {
    fn name(self) -> &'static str {
        KINDS.iter().find(|k| k.0 == self).map_or("?", |k| k.1)
    }

    /// Eccentricity and compliance: terms beyond the DH geometry, listed in model files.
    pub fn is_non_geometric(self) -> bool {
        matches!(self, EffectKind::Eccentricity | EffectKind::Eccentricity2 | EffectKind::Compliance)
    }

    fn per_joint(self) -> bool {
        !matches!(self, EffectKind::Tcp | EffectKind::Scale)
    }
}

impl Effect {
    /// Parse `eccentricity:5`, `tcp`, `scale`, …
    pub fn parse(name: &str) -> Option<Effect> {
        let (kind_name, joint) = match name.split_once(':') {
            Some((k, j)) => (k, Some(j.parse::<usize>().ok()?)),
            None => (name, None),
        };
        let kind = KINDS.iter().find(|k| k.1 == kind_name)?.0;
        match (kind.per_joint(), joint) {
            (true, Some(j)) if (1..=JOINTS).contains(&j) => Some(Effect { kind, joint: Some(j - 1) }),
            (false, None) => Some(Effect { kind, joint: None }),
            _ => None,
        }
    }

    /// Every effect of the library, per-joint kinds on every joint.
    pub fn library() -> Vec<Effect> {
        let mut out = Vec::new();
        for (kind, _) in KINDS {
            if kind.per_joint() {
                out.extend((0..JOINTS).map(|j| Effect { kind, joint: Some(j) }));
            } else {
                out.push(Effect { kind, joint: None });
            }
        }
        out
    }

    /// The model parameters this effect adds.
    pub fn params(self) -> Vec<ParamId> {
        let j = self.joint.unwrap_or(0);
        match self.kind {
            EffectKind::Offset => vec![ParamId::Offset(j)],
            EffectKind::Length => vec![ParamId::Length(j)],
            EffectKind::LinkOffset => vec![ParamId::LinkOffset(j)],
            EffectKind::Twist => vec![ParamId::Twist(j)],
            EffectKind::Axis => vec![ParamId::Axis(j)],
            EffectKind::Eccentricity => vec![ParamId::EccSin(j), ParamId::EccCos(j)],
            EffectKind::Eccentricity2 => vec![ParamId::Ecc2Sin(j), ParamId::Ecc2Cos(j)],
            EffectKind::Compliance => vec![ParamId::Compliance(j)],
            EffectKind::Tcp => vec![ParamId::Tcp(0), ParamId::Tcp(1), ParamId::Tcp(2)],
            EffectKind::Scale => vec![ParamId::Scale],
        }
    }

    /// True when every parameter of the effect is free in `model`.
    pub fn is_in(self, model: &ArmModel) -> bool {
        self.params().iter().all(|p| model.free.iter().any(|f| f.id == *p))
    }

    /// Make the effect's parameters free in `model`, with bounds of ± the default half-range
    /// around their current values (parameters already free keep their bounds).
    pub fn add_to(self, model: &mut ArmModel) {
        for p in self.params() {
            if !model.free.iter().any(|f| f.id == p) {
                let v = model.get(p);
                let h = default_half_range(p);
                model.free_param(p, v - h, v + h);
            }
        }
    }
}

/// Half-width of the bounds given to a parameter when an effect is added, in its unit.
pub fn default_half_range(p: ParamId) -> f64 {
    match p {
        ParamId::Offset(_) => 10.0,
        ParamId::Length(_) | ParamId::LinkOffset(_) | ParamId::Tcp(_) => 10.0,
        ParamId::Twist(_) | ParamId::Axis(_) => 5.0,
        ParamId::EccSin(_) | ParamId::EccCos(_) => 2.0,
        ParamId::Ecc2Sin(_) | ParamId::Ecc2Cos(_) => 1.0,
        ParamId::Compliance(_) => 2.0,
        ParamId::Scale => 5000.0,
    }
}

impl fmt::Display for Effect {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.joint {
            Some(j) => write!(f, "{}:{}", self.kind.name(), j + 1),
            None => write!(f, "{}", self.kind.name()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_effect_name_parses_back() {
        let library = Effect::library();
        assert_eq!(library.len(), 8 * JOINTS + 2);
        for e in library {
            assert_eq!(Effect::parse(&e.to_string()), Some(e), "{e}");
        }
        for bad in ["eccentricity", "tcp:1", "compliance:0", "warp:2", "scale:3"] {
            assert_eq!(Effect::parse(bad), None, "{bad}");
        }
    }
}
