#!/usr/bin/env python3
"""Tracker data of a humanoid upper body that sags under its own weight (kincal issue 31).

An independent generator: written from the physics and pinocchio (`pip install pin`), sharing no
code and no formula's implementation with kincal. It reads a URDF with inertials (by default
tests/data/humanoid/upper_body.urdf: a torso of four joints and two 7-joint arms), makes a "true"
robot by perturbing every joint origin, lets every revolute joint deflect under the gravity of the
whole tree, and measures a marker on each hand with a motion-capture system, one unknown
instrument placement per session. docs/src/humanoid-data.md is the specification; the formulas
below are the ones it states.

Frames and units: pinocchio works in m, kg, N, rad; files carry mm and degrees (or radians, with
--angles rad). The robot base frame is the URDF's root link, z up, gravity g = (0, 0, -9.81) m/s^2
in it. The frame of joint j is the URDF joint frame (the child side of the joint's <origin>,
after the joint's motion), as in pinocchio.

Physics (every j a revolute joint, a_j its unit axis as the URDF declares it, in joint j's frame):

  M_j = sum over the bodies b carried by joint j of (c_b - o_j) x (m_b g), expressed in joint j's
        frame: the moment of gravity about joint j's origin from everything beyond the joint, both
        arms and the head included on a torso joint. In pinocchio: M_j = -data.f[j].angular after
        rnea(model, data, theta, 0, 0) (data.f[j] is the wrench joint j transmits to its subtree).
  tau_j = a_j . M_j = -computeGeneralizedGravity(model, data, theta)[j]   (N m)
  joint compliance:   theta_j = q_j + c_j tau_j        (q_j the encoder reading written in the
                                                        file, theta_j the link's angle)
  lateral compliance: phi_j = k_j (M_j - tau_j a_j)    (a rotation vector in joint j's frame,
                                                        perpendicular to a_j)
  joint j's transform, parent link <- child link:  T_origin_j . Rot(a_j, theta_j) . Rot(phi_j)

c_j, k_j >= 0 (rad/(N m)): every deflection turns along the moment of gravity, so the potential
energy falls (dV = -c_j tau_j^2 - k_j |M_j perp|^2): the arm sags. (theta, phi) is the fixed point
of the equations above (M evaluated on the deflected robot), iterated from (q, 0); with
--deflection first-order, M is evaluated once on the undeflected robot at q.

The true origins: T_origin_true = T_origin_nominal . Trans(dp) . Rot(dw), dp (0.5-2 mm) and dw
(0.05-0.3 deg) of random directions, both in the nominal joint frame, for every joint of the URDF
(fixed ones too: the markers' and the head's).

Measurement of tip i in session s: X = R_s (1000 p_i(theta, phi)) + t_s + e (mm),
e ~ N(0, sigma^2 I3), (R_s, t_s) the instrument <- robot base of the session.

Usage: humanoid.py --seed 1 --out DIR [--poses 500 --sessions 5 --gravity links|tip-mass ...]
"""

import argparse
import json
import math
import os
import shutil
import sys
import tempfile
import xml.etree.ElementTree as ET

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small problems: threads only contend
os.environ.setdefault("OMP_NUM_THREADS", "1")
import numpy as np  # noqa: E402
import pinocchio as pin  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
DEFAULT_URDF = os.path.normpath(os.path.join(HERE, "..", "data", "humanoid", "upper_body.urdf"))
DEFAULT_TIPS = ("left_marker", "right_marker")
DEFAULT_FRONT_FRAME = "torso_4_link"
GRAVITY_MPS2 = np.array([0.0, 0.0, -9.81])
TRUTH_FORMAT = "kincal-humanoid-truth/1"
SESSION_TAG = "kincal-tracker/2"

# Joint compliance (rad/(N m)) before the seeded spread (x 0.7..1.3) and --joint-compliance-scale:
# a torso joint carries tens of kg at half a metre and is stiffer than an arm joint.
JOINT_COMPLIANCE_RAD_PER_NM = {"torso": 5.0e-5, "arm": 1.5e-4}
# Lateral compliance (bending of a bearing or link), the same way, before --lateral-scale.
LATERAL_COMPLIANCE_RAD_PER_NM = {"torso": 4.4e-5, "arm": 8.7e-5}
# Sampling ranges (deg) of the reference robot's torso; other joints use 85 % of their limits.
TORSO_RANGES_DEG = {
    "torso_1_joint": (-60.0, 60.0),
    "torso_2_joint": (-10.0, 50.0),
    "torso_3_joint": (-80.0, 10.0),
    "torso_4_joint": (-40.0, 60.0),
}


class InputError(Exception):
    """A bad input: the message names the file or option and what was expected."""


class DeflectionError(RuntimeError):
    """The deflection equations have no stable fixed point (compliance too large for the load)."""


# --------------------------------------------------------------------------------------------
# Small rigid-body helpers (numpy; pinocchio's exp3 for rotation vectors).


def rot(w):
    """Rotation matrix of a rotation vector w (rad)."""
    return pin.exp3(np.asarray(w, dtype=float))


def random_unit(rng):
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def kabsch(p, x):
    """(R, t) minimising sum |R p_i + t - x_i|^2 (rows of p and x are points)."""
    pc, xc = p.mean(axis=0), x.mean(axis=0)
    h = (p - pc).T @ (x - xc)
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return r, xc - r @ pc


# --------------------------------------------------------------------------------------------
# The URDF: read, perturb, write.


def read_urdf(path):
    try:
        tree = ET.parse(path, parser=ET.XMLParser(target=ET.TreeBuilder(insert_comments=True)))
    except (OSError, ET.ParseError) as e:
        raise InputError(f"{path}: cannot read the URDF: {e}") from e
    return tree


def origin_of(joint_el):
    """The joint's <origin> as (xyz m, rpy rad); a missing element or attribute is zero."""
    o = joint_el.find("origin")
    xyz = np.zeros(3)
    rpy = np.zeros(3)
    if o is not None:
        for key, into in (("xyz", xyz), ("rpy", rpy)):
            text = o.get(key)
            if text is not None:
                values = text.split()
                if len(values) != 3:
                    raise InputError(f"joint {joint_el.get('name')}: origin {key}=\"{text}\": expected 3 numbers")
                into[:] = [float(v) for v in values]
    return xyz, rpy


def set_origin(joint_el, xyz, rpy):
    o = joint_el.find("origin")
    if o is None:
        o = ET.SubElement(joint_el, "origin")
    o.set("xyz", " ".join(f"{v:.12g}" for v in xyz))
    o.set("rpy", " ".join(f"{v:.12g}" for v in rpy))


def perturb_origins(tree, rng, scale):
    """Perturb every joint origin in place: T_true = T_nom . Trans(dp) . Rot(dw).

    |dp| uniform in 0.5-2 mm and |dw| in 0.05-0.3 deg (times `scale`), random directions, both
    in the nominal joint frame. Returns {joint name: record of nominal, delta and true origin}."""
    records = {}
    for j in tree.getroot().iter("joint"):
        name = j.get("name")
        xyz, rpy = origin_of(j)
        dp_m = random_unit(rng) * rng.uniform(0.5, 2.0) * 1e-3 * scale
        dw_rad = random_unit(rng) * math.radians(rng.uniform(0.05, 0.3)) * scale
        r_nom = pin.rpy.rpyToMatrix(*rpy)
        xyz_true = xyz + r_nom @ dp_m
        rpy_true = pin.rpy.matrixToRpy(r_nom @ rot(dw_rad))
        set_origin(j, xyz_true, rpy_true)
        records[name] = {
            "type": j.get("type"),
            "origin_nominal": {"xyz_m": list(xyz), "rpy_rad": list(rpy)},
            "translation_mm": list(dp_m * 1e3),
            "rotation_vector_deg": list(np.degrees(dw_rad)),
            "origin_true": {"xyz_m": list(xyz_true), "rpy_rad": list(rpy_true)},
        }
    return records


def urdf_text(tree):
    return ET.tostring(tree.getroot(), encoding="unicode", xml_declaration=True) + "\n"


# --------------------------------------------------------------------------------------------
# The robot and its deflection under gravity.


class Robot:
    """A pinocchio model of a URDF (fixed base) with named tips and the gravity loads of its joints.

    `masses` is "links" (the URDF's inertials) or "tip-mass" (links weightless, 1 kg point masses
    at the tips)."""

    def __init__(self, urdf_path, tips, masses="links"):
        try:
            self.model = pin.buildModelFromUrdf(urdf_path)
        except (RuntimeError, ValueError) as e:
            raise InputError(f"{urdf_path}: pinocchio cannot build the model: {e}") from e
        m = self.model
        if m.nq != m.nv or any(m.joints[i].nq != 1 for i in range(1, m.njoints)):
            raise InputError(f"{urdf_path}: expected revolute (or fixed) joints only")
        self.tips = list(tips)
        self.tip_frames = []
        for t in self.tips:
            if not m.existFrame(t):
                raise InputError(f"{urdf_path}: no link or frame named `{t}` (option --tips)")
            self.tip_frames.append(m.getFrameId(t))
        self.names = [m.names[i] for i in range(1, m.njoints)]
        self.data = m.createData()
        pin.forwardKinematics(m, self.data, pin.neutral(m))
        self.axes = np.array([np.array(self.data.joints[i].S).reshape(-1)[3:6] for i in range(1, m.njoints)])
        if np.any(np.abs(np.linalg.norm(self.axes, axis=1) - 1.0) > 1e-9):
            raise InputError(f"{urdf_path}: a joint that is not revolute about a unit axis")
        self.origins = [pin.SE3(m.jointPlacements[i]) for i in range(1, m.njoints)]
        if masses == "tip-mass":
            for i in range(m.njoints):
                m.inertias[i] = pin.Inertia.Zero()
            for f in self.tip_frames:
                frame = m.frames[f]
                point = pin.Inertia(1.0, frame.placement.translation, np.zeros((3, 3)))
                m.inertias[frame.parentJoint] = m.inertias[frame.parentJoint] + point
        elif masses != "links":
            raise InputError(f"--gravity {masses}: expected links or tip-mass")
        self.zero = np.zeros(m.nv)
        self._zero3 = np.zeros(3)
        self._bent = []

    @property
    def n(self):
        return self.model.nv

    def set_lateral(self, theta, phi):
        """Put the lateral rotations phi (rad, joint frames) into the joint placements, or take
        them out (phi None): T_origin . Rot(a, theta) . Rot(phi) = T_origin . Rot(Rot(a, theta) phi)
        . Rot(a, theta), and Rot(a, theta) phi = phi cos(theta) + (a x phi) sin(theta) for phi
        perpendicular to a."""
        m = self.model
        for j in self._bent:
            m.jointPlacements[j + 1] = self.origins[j]
        self._bent = []
        if phi is None:
            return
        turned = phi * np.cos(theta)[:, None] + np.cross(self.axes, phi) * np.sin(theta)[:, None]
        for j in np.flatnonzero(np.any(phi != 0.0, axis=1)).tolist():
            m.jointPlacements[j + 1] = self.origins[j] * pin.SE3(pin.exp3(turned[j]), self._zero3)
            self._bent.append(j)

    def moments(self, theta, phi=None):
        """M_j (N m, joint j's frame): gravity's moment about joint j's origin from its subtree."""
        self.set_lateral(theta, phi)
        pin.rnea(self.model, self.data, theta, self.zero, self.zero)
        return np.array([-np.array(self.data.f[j + 1].angular) for j in range(self.n)])

    def deflect(self, q, c, k, mode="fixed-point", start=None, tol_rad=1e-12, max_iter=100):
        """The link angles theta and lateral rotations phi of the robot at encoder readings q.

        Fixed point of theta = q + c.tau(theta, phi), phi = k.M_perp(theta, phi), iterated from
        `start` (theta, phi) or (q, 0); "first-order" evaluates M once at (q, 0). Returns (theta,
        phi, iterations); the moments at the solution are left in self.last_moments."""
        theta = np.array(q, dtype=float)
        phi = np.zeros((self.n, 3))
        if start is not None and mode == "fixed-point":
            theta, phi = np.array(start[0], dtype=float), np.array(start[1], dtype=float)
        if not np.any(c) and not np.any(k):
            self.last_moments = None
            return np.array(q, dtype=float), np.zeros((self.n, 3)), 0
        for it in range(1, max_iter + 1):
            big_m = self.moments(theta, phi)
            tau = np.einsum("ij,ij->i", big_m, self.axes)
            new_theta = q + c * tau
            new_phi = k[:, None] * (big_m - tau[:, None] * self.axes)
            change = max(np.max(np.abs(new_theta - theta)), np.max(np.abs(new_phi - phi)))
            theta, phi = new_theta, new_phi
            self.last_moments = big_m
            if mode == "first-order" or change < tol_rad:
                return theta, phi, it
        raise DeflectionError(f"the deflection did not converge in {max_iter} iterations (change {change:.3g} rad)")

    def tip_points_m(self, theta, phi=None):
        """The tips' positions (m, robot base frame), one row per tip."""
        self.set_lateral(theta, phi)
        pin.framesForwardKinematics(self.model, self.data, theta)
        points = np.array([self.data.oMf[f].translation for f in self.tip_frames])
        self.set_lateral(theta, None)
        return points

    def frame(self, name, theta):
        """Placement of a frame at link angles theta, undeflected (for the pose sampler)."""
        self.set_lateral(theta, None)
        pin.framesForwardKinematics(self.model, self.data, theta)
        return pin.SE3(self.data.oMf[self.model.getFrameId(name)])

    def potential_energy(self, theta, phi):
        self.set_lateral(theta, phi)
        e = pin.computePotentialEnergy(self.model, self.data, theta)
        self.set_lateral(theta, None)
        return e


def joint_group(name):
    return "torso" if "torso" in name else "arm"


def compliances(robot, rng, joint_scale, lateral_scale):
    """c_j and k_j (rad/(N m)): a base value per group, spread x 0.7..1.3 by the seed.

    c is 0 on a joint whose axis is vertical at every pose (torso_1: no gravity torque about it,
    so no c could be seen); its k stays (the whole upper body bends it)."""
    c = np.zeros(robot.n)
    k = np.zeros(robot.n)
    for j, name in enumerate(robot.names):
        g = joint_group(name)
        c[j] = JOINT_COMPLIANCE_RAD_PER_NM[g] * rng.uniform(0.7, 1.3) * joint_scale
        k[j] = LATERAL_COMPLIANCE_RAD_PER_NM[g] * rng.uniform(0.7, 1.3) * lateral_scale
        parent = robot.model.parents[j + 1]
        if parent == 0 and abs(robot.axes[j] @ robot.origins[j].rotation.T @ [0, 0, 1]) > math.cos(math.radians(1)):
            c[j] = 0.0
    return c, k


# --------------------------------------------------------------------------------------------
# Poses.


def sampling_ranges(robot):
    lo = robot.model.lowerPositionLimit
    hi = robot.model.upperPositionLimit
    ranges = []
    for j, name in enumerate(robot.names):
        if name in TORSO_RANGES_DEG:
            ranges.append(tuple(math.radians(v) for v in TORSO_RANGES_DEG[name]))
        else:
            mid, half = (lo[j] + hi[j]) / 2, (hi[j] - lo[j]) / 2 * 0.85
            ranges.append((mid - half, mid + half))
    return np.array(ranges)


def plausible(robot, q, front_frame):
    """A pose a motion-capture session would record: the chest within 25 deg of upright, both
    markers at least 0.1 m in front of it, 0.3 m from its origin and 0.3 m from each other."""
    chest = robot.frame(front_frame, q)
    if chest.rotation[2, 2] < math.cos(math.radians(25)):
        return False
    tips = np.array([robot.data.oMf[f].translation for f in robot.tip_frames])
    local = (tips - chest.translation) @ chest.rotation
    if np.any(local[:, 0] < 0.1) or np.any(np.linalg.norm(local, axis=1) < 0.3):
        return False
    return len(tips) < 2 or np.linalg.norm(tips[0] - tips[1]) >= 0.3


def sample_poses(robot, rng, count, front_frame, max_draws=2_000_000):
    ranges = sampling_ranges(robot)
    poses = []
    draws = 0
    while len(poses) < count:
        draws += 1
        if draws > max_draws:
            raise RuntimeError(f"only {len(poses)} plausible poses in {max_draws} draws")
        q = rng.uniform(ranges[:, 0], ranges[:, 1])
        if plausible(robot, q, front_frame):
            poses.append(q)
    return np.array(poses), draws


# --------------------------------------------------------------------------------------------
# Output.


def write_atomic(path, text):
    directory = os.path.dirname(path) or "."
    fd, tmp = tempfile.mkstemp(dir=directory, prefix=".tmp-", suffix=os.path.basename(path))
    with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as f:
        f.write(text)
    os.replace(tmp, path)


def prepare_out(out, inputs):
    """An output folder: new, empty, or one this generator wrote before (its truth.json)."""
    out = os.path.abspath(out)
    for i in inputs:
        if os.path.commonpath([out, os.path.abspath(i)]) == out:
            raise InputError(f"--out {out}: holds the input {i}; choose another folder")
    if os.path.isdir(out) and os.listdir(out):
        truth = os.path.join(out, "truth.json")
        try:
            with open(truth, encoding="utf-8") as f:
                mine = json.load(f).get("format") == TRUTH_FORMAT
        except (OSError, ValueError):
            mine = False
        if not mine:
            raise InputError(f"--out {out}: not empty and not written by this generator (no {TRUTH_FORMAT} truth.json)")
        shutil.rmtree(os.path.join(out, "sessions"), ignore_errors=True)
    os.makedirs(os.path.join(out, "sessions"), exist_ok=True)
    return out


def session_csv(robot, rows, angles):
    """One session file: rows of (pose id, tip index, q (rad), measured point (mm), sigma (mm))."""
    unit = "deg" if angles == "deg" else "rad"
    header = ["pose", "tip"] + [f"{n}_{unit}" for n in robot.names] + ["x_mm", "y_mm", "z_mm", "sigma_mm"]
    lines = [f"# {SESSION_TAG}", ",".join(header)]
    for pose, tip, q, x, sigma in rows:
        a = np.degrees(q) if angles == "deg" else q
        fmt = "{:.6f}" if angles == "deg" else "{:.9f}"
        cells = [str(pose), robot.tips[tip]] + [fmt.format(v) for v in a]
        cells += [f"{v:.4f}" for v in x] + [f"{sigma:g}"]
        lines.append(",".join(cells))
    return "\n".join(lines) + "\n"


def instrument_placement(rng):
    """A motion-capture frame: z nearly vertical (tilt <= 2 deg), any heading, 1-3 m away."""
    yaw = rng.uniform(-math.pi, math.pi)
    tilt = random_unit(rng) * math.radians(rng.uniform(0.0, 2.0))
    r = rot(tilt) @ rot([0.0, 0.0, yaw])
    t = np.array([rng.uniform(-3000, 3000), rng.uniform(-3000, 3000), rng.uniform(-500, 500)])
    return r, t


# --------------------------------------------------------------------------------------------
# Stage figures: what a model leaves at the markers, each session's base fitted.


def residual_figures(predicted_mm, measured_mm, session_of):
    """RMS (3-D) and mean distance (mm) after a best-fit base per session."""
    res = []
    for s in np.unique(session_of):
        sel = session_of == s
        r, t = kabsch(predicted_mm[sel], measured_mm[sel])
        res.append(measured_mm[sel] - (predicted_mm[sel] @ r.T + t))
    res = np.concatenate(res)
    d = np.linalg.norm(res, axis=1)
    return {"rms_mm": float(np.sqrt(np.mean(d * d))), "mean_mm": float(np.mean(d))}


# --------------------------------------------------------------------------------------------


def parse_args(argv):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seed", type=int, default=1, help="every random draw follows from it")
    p.add_argument("--out", required=True, help="output folder: sessions/*.csv, truth.json, truth.urdf")
    p.add_argument("--urdf", default=DEFAULT_URDF, help="nominal URDF with <inertial> elements")
    p.add_argument("--tips", default=",".join(DEFAULT_TIPS), help="marker frames (URDF link names), comma-separated")
    p.add_argument("--front-frame", default=DEFAULT_FRONT_FRAME, help="the chest: markers are in front of it")
    p.add_argument("--poses", type=int, default=500, help="distinct poses over all sessions")
    p.add_argument("--sessions", type=int, default=5, help="instrument placements (one unknown base each)")
    p.add_argument("--repeats", type=int, default=10, help="poses measured twice per session (the floor)")
    p.add_argument("--sigma-mm", type=float, default=0.15, help="instrument noise per axis, mm")
    p.add_argument("--occlusion", type=float, default=0.05, help="chance a marker is hidden in a pose")
    p.add_argument("--gravity", choices=["links", "tip-mass"], default="links",
                   help="what weighs: the URDF's link masses, or 1 kg at each marker only")
    p.add_argument("--geometry-scale", type=float, default=1.0, help="x the origin perturbations")
    p.add_argument("--joint-compliance-scale", type=float, default=1.0, help="x every c_j")
    p.add_argument("--lateral-scale", type=float, default=None,
                   help="x every k_j (default 1 with link masses, 0 with a tip mass)")
    p.add_argument("--deflection", choices=["fixed-point", "first-order"], default="fixed-point")
    p.add_argument("--angles", choices=["deg", "rad"], default="deg", help="unit of the joint columns")
    p.add_argument("--split-tips", action="store_true",
                   help="one file per session and tip (each file then its own placement)")
    a = p.parse_args(argv)
    for name in ("poses", "sessions"):
        if getattr(a, name) < 1:
            p.error(f"--{name} {getattr(a, name)}: expected at least 1")
    if a.poses < a.sessions:
        p.error(f"--poses {a.poses}: expected at least one per session (--sessions {a.sessions})")
    if a.repeats < 0 or a.sigma_mm < 0 or not 0 <= a.occlusion < 0.5:
        p.error("expected --repeats >= 0, --sigma-mm >= 0 and 0 <= --occlusion < 0.5")
    if a.lateral_scale is None:
        a.lateral_scale = 1.0 if a.gravity == "links" else 0.0
    return a


def generate(a):
    """Write the data set of options `a`; return the truth (also written as truth.json)."""
    tips = [t for t in a.tips.split(",") if t]
    out = prepare_out(a.out, [a.urdf])
    streams = [np.random.default_rng([a.seed, k]) for k in range(6)]
    rng_geometry, rng_compliance, rng_poses, rng_base, rng_noise, rng_occlusion = streams

    tree = read_urdf(a.urdf)
    nominal = Robot(a.urdf, tips, "links")
    deltas = perturb_origins(tree, rng_geometry, a.geometry_scale)
    truth_urdf = os.path.join(out, "truth.urdf")
    write_atomic(truth_urdf, urdf_text(tree))
    true_robot = Robot(truth_urdf, tips, a.gravity)
    if true_robot.names != nominal.names:
        raise RuntimeError("the perturbed URDF changed the joints")

    c, k = compliances(true_robot, rng_compliance, a.joint_compliance_scale, a.lateral_scale)
    poses, draws = sample_poses(nominal, rng_poses, a.poses, a.front_frame)
    if a.gravity == "tip-mass":
        # Same deflection sizes as with the link masses: c_j, k_j scaled by the RMS load ratio.
        links = Robot(truth_urdf, tips, "links")
        load_l = np.array([links.moments(q) for q in poses])
        load_t = np.array([true_robot.moments(q) for q in poses])
        for j in range(true_robot.n):
            ax = true_robot.axes[j]
            tl, tt = load_l[:, j] @ ax, load_t[:, j] @ ax
            pl = load_l[:, j] - np.outer(tl, ax)
            pt = load_t[:, j] - np.outer(tt, ax)
            rms = lambda v: math.sqrt(np.mean(np.square(v)))
            c[j] = c[j] * rms(tl) / rms(tt) if rms(tt) > 1e-9 else 0.0
            k[j] = k[j] * rms(pl) / rms(pt) if rms(pt) > 1e-9 else 0.0

    per_session = np.array_split(np.arange(a.poses), a.sessions)
    rows_by_file = {}
    truth_sessions = []
    records = []  # (session, q, theta, phi, tip, measured_mm) for the stage figures
    max_iter = 0
    for s, idx in enumerate(per_session, start=1):
        r_s, t_s = instrument_placement(rng_base)
        order = list(idx) + list(rng_poses.choice(idx, size=min(a.repeats, len(idx)), replace=False))
        for i in order:
            q = poses[i]
            theta, phi, it = true_robot.deflect(q, c, k, a.deflection)
            max_iter = max(max_iter, it)
            points = true_robot.tip_points_m(theta, phi) * 1e3
            visible = rng_occlusion.random(len(tips)) >= a.occlusion
            if not visible.any():
                visible[rng_occlusion.integers(len(tips))] = True
            for tip in range(len(tips)):
                noise = rng_noise.normal(0.0, a.sigma_mm, 3)
                if not visible[tip]:
                    continue
                measured = r_s @ points[tip] + t_s + noise
                name = f"S{s}" + (f"_{tips[tip]}" if a.split_tips else "")
                rows_by_file.setdefault(name, []).append((i + 1, tip, q, measured, a.sigma_mm))
                records.append((s, i, tip, measured, points[tip]))
        truth_sessions.append({
            "session": s,
            "files": [f"sessions/{n}.csv" for n in rows_by_file if n.split("_")[0] == f"S{s}"],
            "rotation": r_s.tolist(),
            "translation_mm": list(t_s),
            "poses": [int(i) + 1 for i in idx],
        })
    for name, rows in rows_by_file.items():
        write_atomic(os.path.join(out, "sessions", f"{name}.csv"), session_csv(true_robot, rows, a.angles))

    stages = stage_figures(nominal, truth_urdf, tips, a, c, k, poses, records)
    truth = {
        "format": TRUTH_FORMAT,
        "generator": "tests/gen/humanoid.py",
        "options": {key: (v if not isinstance(v, float) else float(v)) for key, v in vars(a).items() if key != "out"},
        "urdf_nominal": os.path.relpath(os.path.abspath(a.urdf), out),
        "urdf_true": "truth.urdf",
        "gravity_mps2": list(GRAVITY_MPS2),
        "masses": a.gravity,
        "deflection": a.deflection,
        "deflection_iterations_max": max_iter,
        "sigma_mm": a.sigma_mm,
        "tips": [
            {"name": t, "parent_joint": true_robot.names[true_robot.model.frames[f].parentJoint - 1],
             "offset_true_mm": list(np.array(true_robot.model.frames[f].placement.translation) * 1e3),
             "offset_nominal_mm": list(np.array(nominal.model.frames[nominal.tip_frames[i]].placement.translation) * 1e3)}
            for i, (t, f) in enumerate(zip(tips, true_robot.tip_frames))
        ],
        "joints": [],
        "bodies": [],
        "sessions": truth_sessions,
        "pose_draws": draws,
        "stages": stages,
    }
    for j, name in enumerate(true_robot.names):
        rec = dict(name=name, index=j + 1, axis=list(true_robot.axes[j]),
                   parent=true_robot.names[true_robot.model.parents[j + 1] - 1] if true_robot.model.parents[j + 1] else None,
                   c_rad_per_Nm=float(c[j]), k_rad_per_Nm=float(k[j]))
        rec.update(deltas.pop(name))
        truth["joints"].append(rec)
    truth["fixed_joints"] = [dict(name=n, **v) for n, v in deltas.items()]
    for i in range(1, true_robot.model.njoints):
        inertia = true_robot.model.inertias[i]
        if inertia.mass > 0:
            truth["bodies"].append({"joint": true_robot.names[i - 1], "mass_kg": float(inertia.mass),
                                    "com_m": list(inertia.lever)})
    write_atomic(os.path.join(out, "truth.json"), json.dumps(truth, indent=1) + "\n")
    return truth


def stage_figures(nominal, truth_urdf, tips, a, c, k, poses, records):
    """The RMS and mean distance at the markers (mm) that each model leaves, bases refitted:
    nominal; the true geometry alone; + the true joint compliance; + the true lateral compliance
    (the whole truth: the noise alone)."""
    session_of = np.array([r[0] for r in records])
    measured = np.array([r[3] for r in records])
    true_robot = Robot(truth_urdf, tips, a.gravity)
    zero = np.zeros(true_robot.n)

    def predicted(robot, cc, kk, mode=a.deflection):
        cache = {}
        for _, i, _, _, _ in records:
            if i not in cache:
                theta, phi, _ = robot.deflect(poses[i], cc, kk, mode)
                cache[i] = robot.tip_points_m(theta, phi) * 1e3
        return np.array([cache[i][tip] for _, i, tip, _, _ in records])

    full = np.array([r[4] for r in records])
    stages = {
        "nominal": residual_figures(predicted(nominal, zero, zero), measured, session_of),
        "geometry": residual_figures(predicted(true_robot, zero, zero), measured, session_of),
        "geometry+joint_compliance": residual_figures(predicted(true_robot, c, zero), measured, session_of),
        "geometry+joint+lateral": residual_figures(full, measured, session_of),
    }
    other = "first-order" if a.deflection == "fixed-point" else "fixed-point"
    diff = np.linalg.norm(full - predicted(true_robot, c, k, other), axis=1)
    stages[f"{other}_vs_{a.deflection}_rms_mm"] = float(np.sqrt(np.mean(diff * diff)))
    return stages


def print_stages(stages):
    published = {"nominal": 21.3, "geometry": 10.5, "geometry+joint_compliance": 5.64, "geometry+joint+lateral": 3.12}
    print("model at the markers (bases refitted)   RMS mm   mean mm   published mean mm (Agile Justin)")
    for key, pub in published.items():
        s = stages[key]
        print(f"  {key:36s} {s['rms_mm']:7.2f}  {s['mean_mm']:7.2f}   {pub:5.2f}")
    for key, v in stages.items():
        if key.endswith("_rms_mm"):
            print(f"  {key}: {v:.3f}")


def main(argv=None):
    a = parse_args(sys.argv[1:] if argv is None else argv)
    try:
        truth = generate(a)
    except InputError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print_stages(truth["stages"])
    print(f"wrote {os.path.join(a.out, 'sessions')} ({len(truth['sessions'])} sessions), truth.json, truth.urdf")
    return 0


if __name__ == "__main__":
    sys.exit(main())
