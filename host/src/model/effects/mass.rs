//! The mass of a body of the mass table, fitted: `mass:BODY` (every body: `mass`).
//!
//! Formula: body b (mass m_b, kg; centre c_b fixed in the frame of the joint that carries it)
//! adds to the gravity moment of every joint j that carries it M_j += (c_b − o_j) × m_b·g (see
//! [`super::sag`]), so the deflections under gravity move with it:
//!
//! - ∂θ_j/∂m_b = s_j · τ_jb / 1000 (degrees per kg), τ_jb = a_j · ((c_b − o_j) × g) the torque
//!   one kilogram of b puts on joint j's axis (N·m/kg), s_j the joint compliance `sag:j`;
//! - the bend turn of joint j moves by b_j · M⊥_jb / 1000 (a rotation vector, degrees per kg),
//!   M⊥_jb the part of (c_b − o_j) × g across the axis, b_j the lateral compliance `bend:j`.
//!
//! Only the products s_j·m_b and b_j·m_b reach a measured point, so a mass is determined only
//! relative to the compliances it loads. Multiplying every mass a set of joints carries by k and
//! dividing their compliances by k moves no point: when every such mass and every such
//! compliance is free, that scale is left to the identifiability step, which holds the mass at its
//! value and says so. A mass is determined when the compliances it loads are known (held at the
//! values of an earlier calibration) or when bodies of known mass load the same joints with other
//! levers (a robot's links from the URDF, a payload of unknown mass on its flange). Its Jacobian
//! column is zero while the compliances are: identifiability is decided at compliances of a
//! typical size ([`PROBE_FRACTION`] of their bounds' width).
//!
//! Physical cause: a payload, a gripper or a tool the URDF does not know, or a link whose CAD
//! mass is wrong (cables, motors, a cover), pulls the arm down by its real weight: the joints
//! carrying it twist and bend under a torque the mass table misstates, so the sag differs from
//! the model's by the missing mass times its lever at every pose.
//!
//! The centre of mass stays where the table puts it: only the mass is fitted. A payload whose
//! centre is unknown too adds three first-moment products m·c per body, which this effect does
//! not fit (see docs/src/masses.md).

use crate::model::{ArmModel, ParamId};
use std::fmt;

/// Share of a load compliance's bounds width taken as its value when deciding, at a zero
/// compliance, whether the masses it multiplies are determined.
pub const PROBE_FRACTION: f64 = 1.0 / 6.0;

/// Longest body name an effect holds, bytes.
pub const MAX_NAME_BYTES: usize = 47;

/// A body's name held inline, so an effect stays `Copy`: at most [`MAX_NAME_BYTES`] bytes.
#[derive(Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct BodyName {
    len: u8,
    bytes: [u8; MAX_NAME_BYTES],
}

impl BodyName {
    /// `name` if it fits and is a plain name (no spaces, no commas, not empty).
    pub fn new(name: &str) -> Option<BodyName> {
        let plain = !name.is_empty() && !name.chars().any(|c| c.is_whitespace() || c == ',' || c == ':');
        (plain && name.len() <= MAX_NAME_BYTES).then(|| {
            let mut bytes = [0; MAX_NAME_BYTES];
            bytes[..name.len()].copy_from_slice(name.as_bytes());
            BodyName { len: name.len() as u8, bytes }
        })
    }

    /// The name.
    pub fn as_str(&self) -> &str {
        std::str::from_utf8(&self.bytes[..self.len as usize]).unwrap_or_default()
    }
}

impl fmt::Debug for BodyName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:?}", self.as_str())
    }
}

/// ∂θ_j/∂m_b, degrees per kg, for joint compliance `sag_deg_per_knm` and the torque one
/// kilogram of the body puts on the joint's axis, `torque_nm_per_kg`.
pub fn angle_partial(sag_deg_per_knm: f64, torque_nm_per_kg: f64) -> f64 {
    sag_deg_per_knm * torque_nm_per_kg / 1000.0
}

/// The bend turn's change per kg of the body (a rotation vector in the joint's frame, degrees
/// per kg) for lateral compliance `bend_deg_per_knm` and the lateral moment one kilogram puts
/// across the axis, `lateral_nm_per_kg`.
pub fn bend_partial(
    bend_deg_per_knm: f64,
    lateral_nm_per_kg: &nalgebra::Vector3<f64>,
) -> nalgebra::Vector3<f64> {
    lateral_nm_per_kg * (bend_deg_per_knm / 1000.0)
}

/// `model` with each free load compliance (`sag:j`, `bend:j`) that is zero and `determined` (by
/// the data, the masses aside) set to [`PROBE_FRACTION`] of its bounds' width: where the
/// identifiability of the masses is decided (at zero compliance no mass moves a point, whatever
/// the data; a compliance the data cannot determine stays zero, as the fit holds it).
pub fn probe_model(model: &ArmModel, determined: impl Fn(ParamId) -> bool) -> ArmModel {
    let mut probe = model.clone();
    let zero = |f: &&crate::model::FreeParam| f.id.is_load_compliance() && model.get(f.id) == 0.0;
    for f in model.free.iter().filter(zero).filter(|f| determined(f.id)) {
        probe.set(f.id, PROBE_FRACTION * (f.upper - f.lower));
    }
    probe
}

/// Why the mass `mass` of `model` is held, in words: it moves no point (no compliance loads
/// it), or it trades against `with` (the kept parameters its column is a combination of).
pub fn held_statement(model: &ArmModel, mass: ParamId, with: &[ParamId]) -> String {
    let name = model.param_name(mass);
    let body = name.trim_start_matches("mass:");
    let value = format!("held at its table value {:.3} kg", model.get(mass));
    if with.is_empty() {
        return format!(
            "{name} moves no measured point: no joint that carries {body} has a compliance under gravity (sag, bend) \
             free or non-zero; {value}"
        );
    }
    let mut names: Vec<String> = with.iter().take(8).map(|p| model.param_name(*p)).collect();
    if with.len() > 8 {
        names.push(format!("{} more", with.len() - 8));
    }
    let names = names.join(", ");
    let masses = with.iter().filter(|p| matches!(p, ParamId::Mass(_))).count();
    // Mostly like a compliance or another mass (the largest share first): the products' scale.
    let compliances = with.first().is_some_and(|p| p.is_load_compliance() || matches!(p, ParamId::Mass(_)))
        && with.iter().any(|p| p.is_load_compliance());
    match (compliances, masses) {
        (true, 0) => format!(
            "{name} is determined only together with {names}: a heavier {body} and softer joints look alike (only \
             mass × compliance reaches a point); {value}. Fix one: hold the compliances at an earlier calibration's \
             values, or weigh {body}"
        ),
        (true, _) => format!(
            "{name} is determined only together with {names}: heavier bodies ({body} and the masses named) and softer \
             joints look alike (only mass × compliance reaches a point); {value}, the others fitted relative to it. \
             Fix one: hold the compliances at an earlier calibration's values, or weigh {body}"
        ),
        (false, m) if m == with.len() => format!(
            "{name} loads the joints as {names} do (their centres of mass in line): only their sum is determined; {value}"
        ),
        (false, _) => format!(
            "{name} cannot be separated from {names} on this data (the joints carrying {body} have no free compliance \
             the data see); {value}"
        ),
    }
}
