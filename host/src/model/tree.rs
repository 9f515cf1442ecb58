//! Branched robots and the masses gravity pulls on.
//!
//! A [`Tree`] turns the model's joint rows into a tree: each joint names its parent (or the
//! base), joints come in topological order (a parent before its children), and named tips each
//! end on a joint with their own tool point. A tip's chain reads only the joints on its path
//! from the base, so the joints two tips share (a humanoid's torso) carry one set of parameters
//! for both. A single chain is a tree without tips: joint j's parent is joint j − 1 and its tool
//! point is the model's `tcp_mm`.
//!
//! The mass table ([`Body`]: a mass and its centre in the frame of the joint that carries it,
//! from a URDF's `<inertial>` elements) gives every joint its gravity load at a pose
//! ([`loads`]): the moment M_j about joint j's origin of the weight of everything beyond it (every
//! branch), its component τ_j along the axis and the rest M⊥_j. The mass-torque compliances
//! [`crate::model::effects::sag`] and [`crate::model::effects::bend`] deflect the joints under
//! these loads; the loads are those of the deflected robot (a fixed point, a few iterations).

use super::{ArmModel, Convention, MAX_TREE_JOINTS};
use nalgebra::{Rotation3, Vector3};

/// Standard gravity, m/s², pulling along −z of the base frame (the base is level).
pub const GRAVITY_MPS2: f64 = 9.81;
/// Most fixed-point iterations of the deflected loads.
const MAX_ITERATIONS: usize = 12;
/// The fixed point's tolerance on any deflection, radians.
const TOLERANCE_RAD: f64 = 1e-10;

/// A named tool point of a tree.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Tip {
    /// Its name, as observations name it (a URDF link, e.g. `left_marker`).
    pub name: String,
    /// The last joint of its chain (0-based in memory, 1-based in files).
    pub joint: usize,
    /// The tool point in that joint's frame, mm (the first tip's point is the model's `tcp_mm`:
    /// this one is not read for it).
    pub tcp_mm: [f64; 3],
}

/// Most bodies a mass table may hold.
pub const MAX_BODIES: usize = 48;
/// Heaviest plausible body, kg.
pub const MAX_BODY_KG: f64 = 10_000.0;

/// A point mass gravity pulls on: one link (or several merged) carried by a joint.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Body {
    /// Its name (the URDF link, e.g. `payload`), by which `mass:NAME` fits its mass; a file
    /// without one names it `bodyN` (N its row, 1-based).
    #[serde(default)]
    pub name: String,
    /// The joint that carries it (0-based in memory, 1-based in files).
    pub joint: usize,
    /// Its mass, kg.
    pub mass_kg: f64,
    /// Its centre of mass in the joint's frame (after the joint's rotation), mm.
    pub com_mm: [f64; 3],
}

/// Parents, tips and masses of a model (see the module doc); empty for a single chain without
/// masses.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Tree {
    /// Each joint's parent joint (0-based), `None` for a joint on the base; empty for a chain.
    pub parents: Vec<Option<usize>>,
    /// The named tips; empty for a chain (one tip: the last joint and `tcp_mm`).
    pub tips: Vec<Tip>,
    /// The masses; empty when gravity loads are not modelled.
    pub bodies: Vec<Body>,
}

impl Tree {
    /// True for a branched model (named tips).
    pub fn is_branched(&self) -> bool {
        !self.tips.is_empty()
    }

    /// Joint j's parent (0-based) among `joints` joints.
    pub fn parent(&self, j: usize) -> Option<usize> {
        match self.parents.get(j) {
            Some(p) => *p,
            None => j.checked_sub(1),
        }
    }

    /// Number of tips (1 for a chain).
    pub fn tip_count(&self) -> usize {
        self.tips.len().max(1)
    }

    /// The joints of tip `tip`'s chain, base first (every joint of a chain).
    pub fn path(&self, joints: usize, tip: usize) -> Vec<usize> {
        let Some(last) = self.tips.get(tip).map(|t| t.joint) else { return (0..joints).collect() };
        let mut path = Vec::new();
        let mut j = Some(last);
        while let Some(k) = j.filter(|k| *k < joints && path.len() <= joints) {
            path.push(k);
            j = self.parent(k);
        }
        path.reverse();
        path
    }

    /// The tip named `name`, if the tree has one.
    pub fn tip_index(&self, name: &str) -> Option<usize> {
        self.tips.iter().position(|t| t.name == name)
    }

    /// The body named `name` in the mass table, if any.
    pub fn body_index(&self, name: &str) -> Option<usize> {
        self.bodies.iter().position(|b| b.name == name)
    }

    /// The bodies' names, for messages (`hand, payload`; "none" for an empty table).
    pub fn body_names(&self) -> String {
        match self.bodies.is_empty() {
            true => "none: the model has no mass table".into(),
            false => self.bodies.iter().map(|b| b.name.as_str()).collect::<Vec<_>>().join(", "),
        }
    }

    /// The joints (bit j) that carry body `b`: its joint and every joint before it on the path
    /// to the base (0 for a body the table does not have).
    pub fn carriers(&self, b: usize, joints: usize) -> u32 {
        let mut bits = 0u32;
        let mut j = self.bodies.get(b).map(|body| body.joint).filter(|j| *j < joints.min(32));
        while let Some(k) = j.filter(|k| bits & (1 << k) == 0) {
            bits |= 1 << k;
            j = self.parent(k).filter(|p| *p < k);
        }
        bits
    }
}

/// The gravity load of every joint at one pose, on the deflected robot.
#[derive(Clone, Copy, Debug)]
pub struct Loads {
    /// τ_j: the gravity torque about joint j's axis, N·m.
    pub torque_nm: [f64; MAX_TREE_JOINTS],
    /// M⊥_j: the gravity moment perpendicular to joint j's axis, in joint j's frame, N·m.
    pub lateral_nm: [Vector3<f64>; MAX_TREE_JOINTS],
    /// Each joint's frame on the deflected robot (after its rotation and bend): its rotation
    /// and origin (m) in the base frame, and its axis in the base frame.
    frames: [(Rotation3<f64>, Vector3<f64>, Vector3<f64>); MAX_TREE_JOINTS],
}

impl Loads {
    /// The load on joint j of one kilogram more of `body` (its centre where the table puts it):
    /// ∂τ_j/∂m (N·m/kg) and ∂M⊥_j/∂m (N·m/kg, joint j's frame). Zero unless joint j carries the
    /// body (see [`Tree::carriers`]; not checked here).
    pub fn per_kg(&self, body: &Body, j: usize) -> (f64, Vector3<f64>) {
        let (Some(at), Some(&(r, o, axis))) = (self.frames.get(body.joint), self.frames.get(j)) else {
            return (0.0, Vector3::zeros());
        };
        let centre_m = at.1 + at.0 * Vector3::from(body.com_mm) / 1000.0;
        let moment = (centre_m - o).cross(&Vector3::new(0.0, 0.0, -GRAVITY_MPS2));
        let tau = axis.dot(&moment);
        (tau, r.inverse() * (moment - axis * tau))
    }
}

/// The loads of `model`'s joints at raw encoder angles `enc_deg` (degrees, one per joint of the
/// tree), for a model of the URDF convention with a mass table; `None` otherwise.
///
/// Joint j's angle is θ_j = φ_j + δθ_j + s_j·τ_j and its frame turns after θ_j by the rotation
/// vector b_j·M⊥_j (see [`crate::model::effects::sag`], [`crate::model::effects::bend`]); the
/// moments are evaluated on that deflected robot, iterated from the undeflected one to their
/// fixed point (each iteration shrinks the change by the deflection per unit load, well under
/// one for any real arm). Encoder harmonics, the tool-lever compliance and the scale are not
/// read: they move the centres of mass by micrometres.
pub fn loads(model: &ArmModel, enc_deg: impl Fn(usize) -> f64) -> Option<Loads> {
    if model.convention != Convention::Urdf || model.tree.bodies.is_empty() {
        return None;
    }
    let n = model.joints.len().min(MAX_TREE_JOINTS);
    let deg = std::f64::consts::PI / 180.0;
    let rigid: Vec<f64> = (0..n).map(|j| (enc_deg(j) + model.joints[j].offset_deg) * deg).collect();
    let deflects = model.joints[..n].iter().any(|j| j.sag_deg_per_knm != 0.0 || j.bend_deg_per_knm != 0.0);
    let mut theta = rigid.clone();
    let mut bend = vec![Vector3::zeros(); n];
    let mut out = Loads {
        torque_nm: [0.0; MAX_TREE_JOINTS],
        lateral_nm: [Vector3::zeros(); MAX_TREE_JOINTS],
        frames: [(Rotation3::identity(), Vector3::zeros(), Vector3::zeros()); MAX_TREE_JOINTS],
    };
    for _ in 0..MAX_ITERATIONS {
        moments(model, n, &theta, &bend, &mut out);
        if !deflects {
            break;
        }
        let mut change: f64 = 0.0;
        for j in 0..n {
            let joint = &model.joints[j];
            let t = rigid[j] + joint.sag_deg_per_knm * deg * out.torque_nm[j] / 1000.0;
            let b = out.lateral_nm[j] * (joint.bend_deg_per_knm * deg / 1000.0);
            change = change.max((t - theta[j]).abs()).max((b - bend[j]).amax());
            (theta[j], bend[j]) = (t, b);
        }
        if change < TOLERANCE_RAD {
            break;
        }
    }
    Some(out)
}

/// The moments of the tree at link angles `theta` (rad) and lateral turns `bend` (rotation
/// vectors, rad, joint frames), written into `out`.
fn moments(model: &ArmModel, n: usize, theta: &[f64], bend: &[Vector3<f64>], out: &mut Loads) {
    // Each joint's frame after its rotation and bend: (R, o) in the base frame, o in mm.
    let mut frames: Vec<(Rotation3<f64>, Vector3<f64>)> = Vec::with_capacity(n);
    let mut axes = Vec::with_capacity(n);
    for j in 0..n {
        let joint = &model.joints[j];
        let (r_parent, o_parent) = match model.tree.parent(j).filter(|p| *p < j) {
            Some(p) => frames[p],
            None => (Rotation3::identity(), Vector3::zeros()),
        };
        let before = r_parent * joint.origin_rotation();
        let origin = o_parent + r_parent * Vector3::from(joint.origin_xyz_mm);
        let axis = Vector3::from(joint.axis);
        axes.push(before * axis);
        let r = before * Rotation3::new(axis * theta[j]) * Rotation3::new(bend[j]);
        frames.push((r, origin));
    }
    // Per joint: the weight F and the moment about the base origin Σ c × f of its subtree.
    let mut force = vec![Vector3::zeros(); n];
    let mut moment = vec![Vector3::zeros(); n];
    for body in model.tree.bodies.iter().filter(|b| b.joint < n) {
        let (r, o) = frames[body.joint];
        let centre_m = (o + r * Vector3::from(body.com_mm)) / 1000.0;
        let weight = Vector3::new(0.0, 0.0, -GRAVITY_MPS2 * body.mass_kg);
        force[body.joint] += weight;
        moment[body.joint] += centre_m.cross(&weight);
    }
    for j in (0..n).rev() {
        if let Some(p) = model.tree.parent(j).filter(|p| *p < j) {
            let (f, m) = (force[j], moment[j]);
            force[p] += f;
            moment[p] += m;
        }
    }
    for j in 0..n {
        let (r, o) = frames[j];
        let about_joint = moment[j] - (o / 1000.0).cross(&force[j]);
        let tau = axes[j].dot(&about_joint);
        out.torque_nm[j] = tau;
        out.lateral_nm[j] = r.inverse() * (about_joint - axes[j] * tau);
        out.frames[j] = (r, o / 1000.0, axes[j]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::Joint;

    /// One horizontal link: joint 1 turns about y at the base, 2 kg at 0.5 m along x.
    fn lever() -> ArmModel {
        let mut model = ArmModel::suta_nominal();
        model.convention = Convention::Urdf;
        model.joints = vec![Joint { axis: [0.0, 1.0, 0.0], ..Default::default() }];
        model.tree.bodies =
            vec![Body { name: "lever".into(), joint: 0, mass_kg: 2.0, com_mm: [500.0, 0.0, 0.0] }];
        model
    }

    #[test]
    fn a_horizontal_lever_carries_m_g_l_and_sags_to_its_fixed_point() {
        let mut model = lever();
        let loads = loads(&model, |_| 0.0).expect("a URDF model with masses");
        // Moment of −2·9.81 N along z at (0.5, 0, 0) m: (0.5, 0, 0) × (0, 0, −19.62) = (0, 9.81, 0).
        assert!((loads.torque_nm[0] - 9.81).abs() < 1e-12, "{}", loads.torque_nm[0]);
        assert!(loads.lateral_nm[0].norm() < 1e-12);
        // Positive torque about +y turns x towards −z: the lever sags; the load falls as cos θ.
        model.joints[0].sag_deg_per_knm = 1000.0;
        let sagged = super::loads(&model, |_| 0.0).expect("loads");
        let theta = sagged.torque_nm[0].to_radians();
        assert!((sagged.torque_nm[0] - 9.81 * theta.cos()).abs() < 1e-9, "fixed point θ = s·τ(θ)");
        assert!(sagged.torque_nm[0] < 9.81);
    }

    #[test]
    fn a_tree_sums_every_branch_on_a_shared_joint() {
        let mut model = lever();
        // Two branches on joint 1, each a joint about z with 1 kg at 0.2 m along its x.
        let branch = Joint { origin_xyz_mm: [500.0, 0.0, 0.0], ..Default::default() };
        model.joints = vec![model.joints[0], branch, branch];
        model.tree.parents = vec![None, Some(0), Some(0)];
        model.tree.bodies.extend([1, 2].map(|joint| Body {
            name: format!("b{joint}"),
            joint,
            mass_kg: 1.0,
            com_mm: [200.0, 0.0, 0.0],
        }));
        let loads = loads(&model, |j| if j == 2 { 90.0 } else { 0.0 }).expect("loads");
        // About joint 1 (y): 2 kg at 0.5 m, 1 kg at 0.7 m and 1 kg at 0.5 m (turned to +y).
        let expected = GRAVITY_MPS2 * (2.0 * 0.5 + 0.7 + 0.5);
        assert!((loads.torque_nm[0] - expected).abs() < 1e-9, "{} vs {expected}", loads.torque_nm[0]);
        // Joint 3 about z carries its mass's moment about x and y only: all lateral.
        assert!(loads.torque_nm[2].abs() < 1e-12);
        assert!((loads.lateral_nm[2].norm() - GRAVITY_MPS2 * 0.2).abs() < 1e-9);
        assert_eq!(model.tree.path(3, 0), vec![0, 1, 2]);
    }
}
