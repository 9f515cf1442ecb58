//! Parameter identifiers: `offset:3`, `length:1`, `twist:5`, `origin_rz:2`, `tcp.z`, `scale`, …

use super::tree::MAX_BODIES;
use std::fmt;

/// One scalar of the arm model. Joint indices are 0-based here, 1-based in names.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum ParamId {
    /// `offset:j` — encoder zero offset δθ_j (deg).
    Offset(usize),
    /// `length:j` — DH d_j (mm).
    Length(usize),
    /// `link_offset:j` — DH a_j (mm).
    LinkOffset(usize),
    /// `twist:j` — DH α_j (deg).
    Twist(usize),
    /// `axis:j` — Hayati β_j about y (deg).
    Axis(usize),
    /// `eccentricity_sin:j` — first-harmonic angle error, sine part (deg).
    EccSin(usize),
    /// `eccentricity_cos:j` — first-harmonic angle error, cosine part (deg).
    EccCos(usize),
    /// `eccentricity2_sin:j` — second-harmonic angle error, sine part (deg).
    Ecc2Sin(usize),
    /// `eccentricity2_cos:j` — second-harmonic angle error, cosine part (deg).
    Ecc2Cos(usize),
    /// `harmonic3_sin:j` — third-harmonic angle error, sine part (deg).
    Harm3Sin(usize),
    /// `harmonic3_cos:j` — third-harmonic angle error, cosine part (deg).
    Harm3Cos(usize),
    /// `harmonic4_sin:j` — fourth-harmonic angle error, sine part (deg).
    Harm4Sin(usize),
    /// `harmonic4_cos:j` — fourth-harmonic angle error, cosine part (deg).
    Harm4Cos(usize),
    /// `compliance:j` — joint deflection per metre of unit-weight gravity lever (deg/m).
    Compliance(usize),
    /// `sag:j` — joint deflection per gravity torque of the masses beyond the joint (deg/(kN·m)).
    Sag(usize),
    /// `bend:j` — lateral deflection per gravity moment perpendicular to the axis (deg/(kN·m)).
    Bend(usize),
    /// `origin_x:j`, `origin_y:j`, `origin_z:j` — URDF joint origin translation (mm), axis 0..3.
    OriginXyz(usize, usize),
    /// `origin_rx:j`, `origin_ry:j`, `origin_rz:j` — a small rotation of the URDF joint origin
    /// about its own nominal x, y, z axes, component k of the rotation vector ω (deg): the origin
    /// turns by R(rpy)·exp(ω), which has no gimbal lock at any nominal orientation.
    OriginTurn(usize, usize),
    /// `tcp.x`, `tcp.y`, `tcp.z` — tool centre point in the last frame (mm); of the first tip in
    /// a tree.
    Tcp(usize),
    /// `tcpN.x`, `tcpN.y`, `tcpN.z` — the point of a tree's tip N (N = 2…[`MAX_TIPS`], 0-based
    /// index t = N − 1 here) in its last joint's frame (mm), axis 0..3.
    TipTcp(usize, usize),
    /// `scale` — length scale error (ppm).
    Scale,
    /// `mass:N` — the mass of body N of the mass table (N = 1…[`MAX_BODIES`], 0-based index
    /// b = N − 1 here), kg; a model names it by the body's name (`mass:payload`, see
    /// [`crate::model::ArmModel::param_name`]).
    Mass(usize),
}

/// Most tips (tool points) a tree model may have.
pub const MAX_TIPS: usize = 4;

/// Number of distinct parameter slots (see [`ParamId::dense_index`]).
pub const PARAM_SLOTS: usize = JOINT_KINDS.len() * super::MAX_TREE_JOINTS + 3 * MAX_TIPS + 1 + MAX_BODIES;
const MASS_SLOT: usize = TCP_SLOT + 3 * MAX_TIPS + 1;

const JOINT_KINDS: [&str; 22] = [
    "offset",
    "length",
    "link_offset",
    "twist",
    "axis",
    "eccentricity_sin",
    "eccentricity_cos",
    "eccentricity2_sin",
    "eccentricity2_cos",
    "compliance",
    "harmonic3_sin",
    "harmonic3_cos",
    "harmonic4_sin",
    "harmonic4_cos",
    "origin_x",
    "origin_y",
    "origin_z",
    "origin_rx",
    "origin_ry",
    "origin_rz",
    "sag",
    "bend",
];
const TCP_SLOT: usize = JOINT_KINDS.len() * super::MAX_TREE_JOINTS;
const TCP_AXES: [&str; 3] = ["x", "y", "z"];

impl ParamId {
    /// Every parameter the model holds, in a stable order.
    pub fn all() -> Vec<ParamId> {
        (0..PARAM_SLOTS).map(ParamId::from_dense_index).collect()
    }

    /// A dense index in `0..PARAM_SLOTS`, for lookup tables.
    pub fn dense_index(self) -> usize {
        match self.joint_kind() {
            Some((kind, j)) => kind * super::MAX_TREE_JOINTS + j,
            None => match self {
                ParamId::Tcp(k) => TCP_SLOT + k,
                ParamId::TipTcp(t, k) => TCP_SLOT + 3 * t + k,
                ParamId::Mass(b) => MASS_SLOT + b,
                _ => TCP_SLOT + 3 * MAX_TIPS,
            },
        }
    }

    /// (index into the per-joint kinds, joint) for per-joint parameters.
    fn joint_kind(self) -> Option<(usize, usize)> {
        Some(match self {
            ParamId::Offset(j) => (0, j),
            ParamId::Length(j) => (1, j),
            ParamId::LinkOffset(j) => (2, j),
            ParamId::Twist(j) => (3, j),
            ParamId::Axis(j) => (4, j),
            ParamId::EccSin(j) => (5, j),
            ParamId::EccCos(j) => (6, j),
            ParamId::Ecc2Sin(j) => (7, j),
            ParamId::Ecc2Cos(j) => (8, j),
            ParamId::Compliance(j) => (9, j),
            ParamId::Harm3Sin(j) => (10, j),
            ParamId::Harm3Cos(j) => (11, j),
            ParamId::Harm4Sin(j) => (12, j),
            ParamId::Harm4Cos(j) => (13, j),
            ParamId::OriginXyz(j, k) => (14 + k, j),
            ParamId::OriginTurn(j, k) => (17 + k, j),
            ParamId::Sag(j) => (20, j),
            ParamId::Bend(j) => (21, j),
            ParamId::Tcp(_) | ParamId::TipTcp(..) | ParamId::Scale | ParamId::Mass(_) => return None,
        })
    }

    fn from_joint_kind(kind: usize, j: usize) -> ParamId {
        match kind {
            14..=16 => return ParamId::OriginXyz(j, kind - 14),
            17..=19 => return ParamId::OriginTurn(j, kind - 17),
            20 => return ParamId::Sag(j),
            21 => return ParamId::Bend(j),
            _ => {}
        }
        [
            ParamId::Offset,
            ParamId::Length,
            ParamId::LinkOffset,
            ParamId::Twist,
            ParamId::Axis,
            ParamId::EccSin,
            ParamId::EccCos,
            ParamId::Ecc2Sin,
            ParamId::Ecc2Cos,
            ParamId::Compliance,
            ParamId::Harm3Sin,
            ParamId::Harm3Cos,
            ParamId::Harm4Sin,
            ParamId::Harm4Cos,
        ][kind](j)
    }

    fn from_dense_index(i: usize) -> ParamId {
        let n = super::MAX_TREE_JOINTS;
        if i < TCP_SLOT {
            ParamId::from_joint_kind(i / n, i % n)
        } else if i < TCP_SLOT + 3 {
            ParamId::Tcp(i - TCP_SLOT)
        } else if i < TCP_SLOT + 3 * MAX_TIPS {
            ParamId::TipTcp((i - TCP_SLOT) / 3, (i - TCP_SLOT) % 3)
        } else if i < MASS_SLOT {
            ParamId::Scale
        } else {
            ParamId::Mass(i - MASS_SLOT)
        }
    }

    /// True for the joint geometry a convention holds (DH d, a, α, β or URDF origins).
    pub fn is_geometry(self) -> bool {
        matches!(self, ParamId::Length(_) | ParamId::LinkOffset(_) | ParamId::Twist(_) | ParamId::Axis(_))
            || self.is_urdf_geometry()
    }

    /// True for a compliance under the gravity loads of a mass table (`sag:j`, `bend:j`).
    pub fn is_load_compliance(self) -> bool {
        matches!(self, ParamId::Sag(_) | ParamId::Bend(_))
    }

    /// True for a URDF joint origin value.
    pub fn is_urdf_geometry(self) -> bool {
        matches!(self, ParamId::OriginXyz(..) | ParamId::OriginTurn(..))
    }

    /// The joint (0-based) of a per-joint parameter.
    pub fn joint(self) -> Option<usize> {
        self.joint_kind().map(|(_, j)| j)
    }

    /// The unit of the parameter's value.
    pub fn unit(self) -> &'static str {
        match self {
            ParamId::Offset(_) | ParamId::Twist(_) | ParamId::Axis(_) | ParamId::OriginTurn(..) => "deg",
            ParamId::EccSin(_) | ParamId::EccCos(_) | ParamId::Ecc2Sin(_) | ParamId::Ecc2Cos(_) => "deg",
            ParamId::Harm3Sin(_) | ParamId::Harm3Cos(_) | ParamId::Harm4Sin(_) | ParamId::Harm4Cos(_) => {
                "deg"
            }
            ParamId::Length(_) | ParamId::LinkOffset(_) | ParamId::Tcp(_) | ParamId::OriginXyz(..) => "mm",
            ParamId::TipTcp(..) => "mm",
            ParamId::Compliance(_) => "deg/m",
            ParamId::Sag(_) | ParamId::Bend(_) => "deg/(kN·m)",
            ParamId::Scale => "ppm",
            ParamId::Mass(_) => "kg",
        }
    }

    /// Parse a name such as `offset:2` or `tcp.z`.
    pub fn parse(name: &str) -> Option<ParamId> {
        if name == "scale" {
            return Some(ParamId::Scale);
        }
        if let Some(axis) = name.strip_prefix("tcp.") {
            return TCP_AXES.iter().position(|a| *a == axis).map(ParamId::Tcp);
        }
        if let Some((tip, axis)) = name.strip_prefix("tcp").and_then(|rest| rest.split_once('.')) {
            let t: usize = tip.parse().ok()?;
            let k = TCP_AXES.iter().position(|a| *a == axis)?;
            return (2..=MAX_TIPS).contains(&t).then(|| ParamId::TipTcp(t - 1, k));
        }
        let (kind, joint) = name.split_once(':')?;
        let j: usize = joint.parse().ok()?;
        if kind == "mass" {
            return (1..=MAX_BODIES).contains(&j).then(|| ParamId::Mass(j - 1));
        }
        if !(1..=super::MAX_TREE_JOINTS).contains(&j) {
            return None;
        }
        Some(ParamId::from_joint_kind(JOINT_KINDS.iter().position(|k| *k == kind)?, j - 1))
    }
}

impl fmt::Display for ParamId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match (self.joint_kind(), *self) {
            (Some((kind, j)), _) => write!(f, "{}:{}", JOINT_KINDS[kind], j + 1),
            (None, ParamId::Tcp(k)) => write!(f, "tcp.{}", TCP_AXES[k]),
            (None, ParamId::TipTcp(t, k)) => write!(f, "tcp{}.{}", t + 1, TCP_AXES[k]),
            (None, ParamId::Mass(b)) => write!(f, "mass:{}", b + 1),
            (None, _) => write!(f, "scale"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_name_parses_back_to_its_id() {
        for id in ParamId::all() {
            assert_eq!(ParamId::parse(&id.to_string()), Some(id), "{id}");
            assert_eq!(ParamId::from_dense_index(id.dense_index()), id);
        }
        assert_eq!(ParamId::all().len(), PARAM_SLOTS);
    }

    #[test]
    fn bad_names_are_rejected() {
        for bad in [
            "offset:0",
            "offset:25",
            "offset",
            "tcp.w",
            "warp:1",
            "length:x",
            "tcp1.x",
            "tcp5.x",
            "tcp2.w",
            "mass:0",
            "mass:49",
        ] {
            assert_eq!(ParamId::parse(bad), None, "{bad}");
        }
    }
}
