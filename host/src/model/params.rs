//! Parameter identifiers: `offset:3`, `length:1`, `twist:5`, `tcp.z`, `scale`, …

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
    /// `tcp.x`, `tcp.y`, `tcp.z` — tool centre point in the last frame (mm).
    Tcp(usize),
    /// `scale` — length scale error (ppm).
    Scale,
}

/// Number of distinct parameter slots (see [`ParamId::dense_index`]).
pub const PARAM_SLOTS: usize = 5 * super::JOINTS + 4;

const JOINT_KINDS: [&str; 5] = ["offset", "length", "link_offset", "twist", "axis"];
const TCP_AXES: [&str; 3] = ["x", "y", "z"];

impl ParamId {
    /// Every parameter the model holds, in a stable order.
    pub fn all() -> Vec<ParamId> {
        (0..PARAM_SLOTS).map(ParamId::from_dense_index).collect()
    }

    /// A dense index in `0..PARAM_SLOTS`, for lookup tables.
    pub fn dense_index(self) -> usize {
        let n = super::JOINTS;
        match self {
            ParamId::Offset(j) => j,
            ParamId::Length(j) => n + j,
            ParamId::LinkOffset(j) => 2 * n + j,
            ParamId::Twist(j) => 3 * n + j,
            ParamId::Axis(j) => 4 * n + j,
            ParamId::Tcp(k) => 5 * n + k,
            ParamId::Scale => 5 * n + 3,
        }
    }

    fn from_dense_index(i: usize) -> ParamId {
        let n = super::JOINTS;
        match i / n {
            0 => ParamId::Offset(i % n),
            1 => ParamId::Length(i % n),
            2 => ParamId::LinkOffset(i % n),
            3 => ParamId::Twist(i % n),
            4 => ParamId::Axis(i % n),
            _ if i - 5 * n < 3 => ParamId::Tcp(i - 5 * n),
            _ => ParamId::Scale,
        }
    }

    /// The unit of the parameter's value.
    pub fn unit(self) -> &'static str {
        match self {
            ParamId::Offset(_) | ParamId::Twist(_) | ParamId::Axis(_) => "deg",
            ParamId::Length(_) | ParamId::LinkOffset(_) | ParamId::Tcp(_) => "mm",
            ParamId::Scale => "ppm",
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
        let (kind, joint) = name.split_once(':')?;
        let j: usize = joint.parse().ok()?;
        if !(1..=super::JOINTS).contains(&j) {
            return None;
        }
        let j = j - 1;
        Some(match JOINT_KINDS.iter().position(|k| *k == kind)? {
            0 => ParamId::Offset(j),
            1 => ParamId::Length(j),
            2 => ParamId::LinkOffset(j),
            3 => ParamId::Twist(j),
            _ => ParamId::Axis(j),
        })
    }
}

impl fmt::Display for ParamId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            ParamId::Offset(j) => write!(f, "offset:{}", j + 1),
            ParamId::Length(j) => write!(f, "length:{}", j + 1),
            ParamId::LinkOffset(j) => write!(f, "link_offset:{}", j + 1),
            ParamId::Twist(j) => write!(f, "twist:{}", j + 1),
            ParamId::Axis(j) => write!(f, "axis:{}", j + 1),
            ParamId::Tcp(k) => write!(f, "tcp.{}", TCP_AXES[k]),
            ParamId::Scale => write!(f, "scale"),
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
        for bad in ["offset:0", "offset:7", "offset", "tcp.w", "warp:1", "length:x"] {
            assert_eq!(ParamId::parse(bad), None, "{bad}");
        }
    }
}
