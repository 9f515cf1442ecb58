//! What no arm can be: the largest plausible value of each parameter and the reach of a real
//! arm. A model file or a URDF holding more is a typo or a unit mistake (metres for millimetres),
//! refused before anything is computed from it.

use super::{ArmModel, ParamId};

/// Largest magnitude a parameter may plausibly have, with the unit, by kind: anything larger is a
/// typo or a unit mistake, and would make the kinematics meaningless (a scale of −10⁶ ppm
/// collapses the arm to a point).
pub fn plausible_limit(id: ParamId) -> f64 {
    match id {
        ParamId::Offset(_) => 720.0,
        ParamId::Twist(_) | ParamId::Axis(_) => 360.0,
        // A turn about the nominal origin: far beyond any CAD error, and below the half turn where
        // the rotation vector would wrap.
        ParamId::OriginTurn(..) => 90.0,
        ParamId::EccSin(_)
        | ParamId::EccCos(_)
        | ParamId::Ecc2Sin(_)
        | ParamId::Ecc2Cos(_)
        | ParamId::Harm3Sin(_)
        | ParamId::Harm3Cos(_)
        | ParamId::Harm4Sin(_)
        | ParamId::Harm4Cos(_) => 10.0,
        ParamId::Length(_) | ParamId::LinkOffset(_) | ParamId::Tcp(_) | ParamId::OriginXyz(..) => {
            MAX_LENGTH_MM
        }
        ParamId::TipTcp(..) => MAX_LENGTH_MM,
        ParamId::Compliance(_) => 100.0,
        // deg per kN·m: a degree per metre of a 100 kg lever is about 1 deg/(kN·m).
        ParamId::Sag(_) | ParamId::Bend(_) => 1000.0,
        ParamId::Scale => 100_000.0,
        ParamId::Mass(_) => super::tree::MAX_BODY_KG,
    }
}

/// Longest single length (d, a, tool offset) a model may hold, mm.
pub const MAX_LENGTH_MM: f64 = 5000.0;
/// Longest total reach (Σ|d| + |a| + |tool|), mm.
pub const MAX_REACH_MM: f64 = 10_000.0;
/// Shortest total reach, mm: a smaller arm is a unit mistake (metres?).
pub const MIN_REACH_MM: f64 = 10.0;

impl ArmModel {
    /// Farthest the tool point can be from the base axis origin: Σ|d| + |a| + |origin| + |tool|, mm.
    pub fn reach_mm(&self) -> f64 {
        let norm = |v: &[f64; 3]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
        self.joints.iter().map(|j| j.d_mm.abs() + j.a_mm.abs() + norm(&j.origin_xyz_mm)).sum::<f64>()
            + self.tcp_mm.iter().map(|v| v * v).sum::<f64>().sqrt()
    }

    /// The first value no arm can have, as (field, what is wrong): a non-finite or implausibly
    /// large parameter ([`plausible_limit`]) or a reach outside [`MIN_REACH_MM`]…[`MAX_REACH_MM`].
    pub fn implausible(&self) -> Option<(String, String)> {
        for id in self.params() {
            let (value, limit) = (self.get(id), plausible_limit(id));
            if !value.is_finite() {
                return Some((id.to_string(), "must be a finite number".into()));
            }
            if value.abs() > limit {
                return Some((
                    id.to_string(),
                    format!(
                        "{value} {} is beyond any plausible arm (|value| <= {limit}): a unit mistake?",
                        id.unit()
                    ),
                ));
            }
        }
        let reach = self.reach_mm();
        if !(MIN_REACH_MM..=MAX_REACH_MM).contains(&reach) {
            return Some((
                "joint".into(),
                format!(
                    "the arm's reach (Σ|d| + |a| + |origin| + |tool|) is {reach:.3} mm; expected {MIN_REACH_MM} \
                     to {MAX_REACH_MM} mm: lengths are in millimetres"
                ),
            ));
        }
        None
    }
}
