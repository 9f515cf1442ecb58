#!/usr/bin/env python3
"""What a correct calibration reaches, stage by stage, on humanoid tracker data (kincal issue 31).

A reference least-squares fit, independent of kincal, to put beside the published figures and
beside kincal's loop: it reads the kincal-tracker/2 sessions that tests/gen/humanoid.py wrote (with
its own reader of the format of docs/src/humanoid-data.md) and the nominal URDF, fits on every
session but the last and reports the last one held out (its base refitted), for these models:

  nominal                  the URDF as it is (only the bases fitted)
  geometry                 + every revolute joint's origin (6 values: T . Trans(dp) . Rot(dw)) and
                             each marker's offset in its link (3 values)
  +joint (tip mass)        + c_j, the torque from 1 kg at each marker only
  +joint (links)           + c_j, the torque from the URDF's link masses (the whole tree)
  +joint+lateral (links)   + k_j, bending under the same moments

The deflection model is the one humanoid.py documents (theta = q + c.tau, phi = k.M_perp, fixed
point). Gauss-Newton with analytic first-order Jacobians (the moments' own change with the
parameters left out), redundant geometric values resolved by the minimum-norm step. Standard
deviations of c_j and k_j: sigma^2 (J^T J)^+ with sigma the stated instrument noise.

Usage: humanoid_fit.py DATA_DIR [--urdf NOMINAL.urdf] [--stages ...] [--json OUT.json]
"""

import argparse
import csv
import glob
import json
import math
import os
import sys

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # small problems: threads only contend
os.environ.setdefault("OMP_NUM_THREADS", "1")
import numpy as np  # noqa: E402
import pinocchio as pin  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from humanoid import DeflectionError, InputError, Robot, kabsch  # noqa: E402  (the same physics, stated once)

TAG = "kincal-tracker/2"
STAGES = ["nominal", "geometry", "+joint (tip mass)", "+joint (links)", "+joint+lateral (links)"]


# --------------------------------------------------------------------------------------------
# The session reader (docs/src/humanoid-data.md).


def read_session(path, joint_names):
    """Rows of one kincal-tracker/2 file: dicts of pose, tip, q (rad, model order), x (mm), sigma."""
    with open(path, encoding="utf-8-sig", newline="") as f:
        lines = f.read().splitlines()
    if not lines or lines[0].strip() != f"# {TAG}":
        raise InputError(f"{path}:1: expected the tag line `# {TAG}`")
    body = [(n, l) for n, l in enumerate(lines, start=1) if not l.startswith("#") and l.strip()]
    if not body:
        raise InputError(f"{path}: no header row")
    header_line, header = body[0][0], next(csv.reader([body[0][1]]))
    col = {h: i for i, h in enumerate(header)}
    if len(col) != len(header):
        raise InputError(f"{path}:{header_line}: a column named twice")
    for req in ("pose", "tip", "x_mm", "y_mm", "z_mm"):
        if req not in col:
            raise InputError(f"{path}:{header_line}: column `{req}` missing")
    joints = {}
    for h, i in col.items():
        for unit, scale in (("_deg", math.pi / 180), ("_rad", 1.0)):
            if h.endswith(unit) and h not in ("x_mm",):
                name = h[: -len(unit)]
                if name not in joint_names:
                    raise InputError(f"{path}:{header_line}: column `{h}`: no joint `{name}` in the URDF")
                if name in joints:
                    raise InputError(f"{path}:{header_line}: joint `{name}` given twice")
                joints[name] = (i, scale)
    missing = [n for n in joint_names if n not in joints]
    if missing:
        raise InputError(f"{path}:{header_line}: no column for joint(s) {', '.join(missing)}")
    sigma = ("sigma_mm", 1.0) if "sigma_mm" in col else ("u95_mm", 0.5) if "u95_mm" in col else None
    rows = []
    for n, line in body[1:]:
        cells = next(csv.reader([line]))
        if len(cells) != len(header):
            raise InputError(f"{path}:{n}: {len(cells)} cells, expected {len(header)}")

        def num(h, i):
            try:
                v = float(cells[i])
            except ValueError:
                v = math.nan
            if not math.isfinite(v):
                raise InputError(f"{path}:{n}: column `{h}`: `{cells[i]}` is not a finite number")
            return v

        q = np.array([num(name, joints[name][0]) * joints[name][1] for name in joint_names])
        x = np.array([num(h, col[h]) for h in ("x_mm", "y_mm", "z_mm")])
        s = num(sigma[0], col[sigma[0]]) * sigma[1] if sigma else None
        rows.append({"pose": cells[col["pose"]], "tip": cells[col["tip"]], "q": q, "x": x, "sigma": s, "line": n})
    return rows


def read_folder(folder, joint_names):
    files = sorted(glob.glob(os.path.join(folder, "*.csv")))
    if not files:
        raise InputError(f"{folder}: no *.csv session files")
    return [(os.path.basename(f)[:-4], read_session(f, joint_names)) for f in files]


# --------------------------------------------------------------------------------------------
# The model being fitted.


def cross(a, b):
    """a x b over the last axis (numpy's cross is slow on small arrays)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


class Fit:
    """The nominal robot and its corrections, one vector: per revolute joint j (dp mm, dw rad) with
    origin_j = nominal_j . Trans(dp) . Rot(dw); per tip (dt mm) added to its offset in its link;
    c_j and k_j (rad/(N m))."""

    def __init__(self, urdf, tips, masses, mode):
        self.robot = Robot(urdf, tips, masses)
        self.mode = mode
        r = self.robot
        self.n, self.tips = r.n, len(tips)
        self.nominal_origins = [pin.SE3(o) for o in r.origins]
        self.nominal_tips = [np.array(r.model.frames[f].placement.translation) for f in r.tip_frames]
        self.tip_joint = [r.model.frames[f].parentJoint for f in r.tip_frames]
        self.support = np.zeros((self.tips, r.n), dtype=bool)
        for t, jt in enumerate(self.tip_joint):
            for s in r.model.supports[jt].tolist():
                if s > 0:
                    self.support[t, s - 1] = True
        self.size = 6 * r.n + 3 * self.tips + 2 * r.n
        self.c_at, self.k_at = 6 * r.n + 3 * self.tips, 7 * r.n + 3 * self.tips
        self.params = np.zeros(self.size)
        self.start = {}  # warm starts of the deflection, per pose

    def set_params(self, p):
        r = self.robot
        self.params = np.array(p, dtype=float)
        g = self.params[: 6 * r.n].reshape(r.n, 6)
        for j in range(r.n):
            r.origins[j] = self.nominal_origins[j] * pin.SE3(pin.exp3(g[j, 3:]), g[j, :3] * 1e-3)
            r.model.jointPlacements[j + 1] = r.origins[j]
        r._bent = []
        for t, f in enumerate(r.tip_frames):
            frame = r.model.frames[f]
            offset = self.nominal_tips[t] + self.params[6 * r.n + 3 * t: 6 * r.n + 3 * t + 3] * 1e-3
            frame.placement = pin.SE3(frame.placement.rotation, offset)
            r.model.frames[f] = frame

    def pose(self, key, q):
        """Tip points (mm) and per-joint arrays (mm, world) for the Jacobian, at readings q."""
        r = self.robot
        c = self.params[self.c_at: self.c_at + r.n]
        k = self.params[self.k_at: self.k_at + r.n]
        theta, phi, _ = r.deflect(q, c, k, self.mode, start=self.start.get(key))
        self.start[key] = (theta, phi)
        big_m = r.last_moments if r.last_moments is not None else r.moments(theta, phi)
        r.set_lateral(theta, phi)
        pin.framesForwardKinematics(r.model, r.data, theta)
        d = r.data
        tips = np.array([d.oMf[f].translation for f in r.tip_frames]) * 1e3
        tip_r = np.array([d.oMi[j].rotation for j in self.tip_joint])
        o = np.empty((r.n, 3))
        rot = np.empty((r.n, 3, 3))
        pre_r = np.empty((r.n, 3, 3))
        pre_p = np.empty((r.n, 3))
        for j in range(r.n):
            parent = r.model.parents[j + 1]
            pre = (d.oMi[parent] * self.nominal_origins[j]) if parent else self.nominal_origins[j]
            pre_r[j], pre_p[j] = pre.rotation, pre.translation
            o[j], rot[j] = d.oMi[j + 1].translation, d.oMi[j + 1].rotation
        r.set_lateral(theta, None)
        tau = np.einsum("ij,ij->i", big_m, r.axes)
        w = np.einsum("jab,jb->ja", rot, r.axes)
        m_perp = np.einsum("jab,jb->ja", rot, big_m - tau[:, None] * r.axes)
        return tips, (o * 1e3, w, pre_r, pre_p * 1e3, tau, m_perp, tip_r)

    def jacobian(self, x, world, tip, base_r):
        """d(point in the instrument frame)/d(parameters), 3 x size, for tip `tip` at point x (mm)."""
        o, w, pre_r, pre_p, tau, m_perp, tip_r = world
        r = self.robot
        mask = self.support[tip][:, None, None]
        jac = np.zeros((3, self.size))
        dp = pre_r * mask  # columns a of pre_r: d x / d dp[a]
        dw = cross(np.swapaxes(pre_r, 1, 2), (x - pre_p)[:, None, :]) * mask  # (j, a, xyz)
        geo = np.concatenate([np.swapaxes(dp, 1, 2), dw], axis=1)  # (j, 6, xyz)
        jac[:, : 6 * r.n] = geo.reshape(6 * r.n, 3).T
        jac[:, 6 * r.n + 3 * tip: 6 * r.n + 3 * tip + 3] = tip_r[tip]
        lever = x - o
        jac[:, self.c_at: self.c_at + r.n] = (cross(w, lever) * tau[:, None] * mask[:, :, 0]).T
        jac[:, self.k_at: self.k_at + r.n] = (cross(m_perp, lever) * mask[:, :, 0]).T
        return base_r @ jac


class Problem:
    """Measured rows of some sessions, indexed for the fit."""

    def __init__(self, sessions, tip_index):
        self.names = [name for name, _ in sessions]
        self.rows = []
        self.poses = {}
        for s, (_, rows) in enumerate(sessions):
            for row in rows:
                key = (s, row["pose"], row["q"].tobytes())
                self.poses.setdefault(key, row["q"])
                self.rows.append((s, key, tip_index[row["tip"]], row["x"]))
        self.session_of = np.array([r[0] for r in self.rows])
        self.measured = np.array([r[3] for r in self.rows])

    def predictions(self, fit, with_jacobian=False):
        pts, worlds = {}, {}
        for key, q in self.poses.items():
            pts[key], worlds[key] = fit.pose(key, q)
        pred = np.array([pts[key][tip] for _, key, tip, _ in self.rows])
        return pred, worlds

    def bases(self, pred):
        return [kabsch(pred[self.session_of == s], self.measured[self.session_of == s]) for s in range(len(self.names))]

    def figures(self, fit):
        pred, _ = self.predictions(fit)
        res = np.empty_like(pred)
        for s, (r, t) in enumerate(self.bases(pred)):
            sel = self.session_of == s
            res[sel] = self.measured[sel] - (pred[sel] @ r.T + t)
        d = np.linalg.norm(res, axis=1)
        return {"rms_mm": float(np.sqrt(np.mean(d * d))), "mean_mm": float(np.mean(d))}


def linearise(fit, problem, free, bases):
    pred, worlds = problem.predictions(fit)
    ns = len(problem.names)
    jac = np.zeros((3 * len(problem.rows), len(free) + 6 * ns))
    res = np.empty(3 * len(problem.rows))
    for n, (s, key, tip, meas) in enumerate(problem.rows):
        base_r, base_t = bases[s]
        bx = base_r @ pred[n]
        jac[3 * n: 3 * n + 3, : len(free)] = fit.jacobian(pred[n], worlds[key], tip, base_r)[:, free]
        jac[3 * n: 3 * n + 3, len(free) + 6 * s: len(free) + 6 * s + 3] = np.eye(3)
        jac[3 * n: 3 * n + 3, len(free) + 6 * s + 3: len(free) + 6 * s + 6] = -pin.skew(bx)
        res[3 * n: 3 * n + 3] = meas - (bx + base_t)
    return jac, res


def gauss_newton(fit, problem, free, iterations=15, tol=1e-6):
    """Fit the parameters `free` (indices into fit.params) and every session's base: Gauss-Newton
    damped as Levenberg-Marquardt on unit-norm columns (a poorly determined direction takes a
    small step). Returns the last Jacobian of `free`."""
    pred, _ = problem.predictions(fit)
    bases = problem.bases(pred)
    jac, res = linearise(fit, problem, free, bases)
    cost = float(res @ res)
    damping = 1e-4
    for _ in range(iterations):
        scale = np.linalg.norm(jac, axis=0)
        scale[scale == 0] = 1.0
        u, sv, vt = np.linalg.svd(jac / scale, full_matrices=False)
        ur = u.T @ res
        old_params, old_bases, old_start = fit.params.copy(), bases, dict(fit.start)
        for _ in range(10):
            step = (vt.T @ (sv / (sv * sv + damping * sv[0] ** 2) * ur)) / scale
            trial = old_params.copy()
            trial[free] += step[: len(free)]
            fit.set_params(trial)
            bases = [(pin.exp3(step[len(free) + 6 * s + 3: len(free) + 6 * s + 6]) @ r,
                      t + step[len(free) + 6 * s: len(free) + 6 * s + 3]) for s, (r, t) in enumerate(old_bases)]
            try:
                new_jac, new_res = linearise(fit, problem, free, bases)
                new_cost = float(new_res @ new_res)
            except DeflectionError:
                new_cost = math.inf
            if new_cost <= cost:
                damping = max(damping / 10, 1e-12)
                break
            fit.start = dict(old_start)
            damping *= 10
        else:
            fit.set_params(old_params)
            fit.start = old_start
            return jac[:, : len(free)]
        done = cost - new_cost <= tol * cost
        jac, res, cost = new_jac, new_res, new_cost
        if done:
            break
    return jac[:, : len(free)]


def determined_compliances(fit, problem, kind, threshold=1e-3):
    """The joints whose c (or k) the data can see: the RMS of the load it multiplies (tau_j, or
    |M_perp|) over the poses at least `threshold` of the largest joint's."""
    r = fit.robot
    loads = []
    for q in problem.poses.values():
        m = r.moments(q)
        tau = np.einsum("ij,ij->i", m, r.axes)
        loads.append(tau if kind == "c" else np.linalg.norm(m - tau[:, None] * r.axes, axis=1))
    rms = np.sqrt(np.mean(np.square(loads), axis=0))
    return [j for j in range(r.n) if rms[j] >= threshold * rms.max()]


def compliance_sd(jac, sigma):
    """sigma sqrt(diag((J^T J)^+)) for the columns of jac (the free parameters, bases left out)."""
    scale = np.linalg.norm(jac, axis=0)
    scale[scale == 0] = 1.0
    _, sv, vt = np.linalg.svd(jac / scale, full_matrices=False)
    keep = sv > sv[0] * 1e-10
    cov = (vt[keep].T / sv[keep] ** 2) @ vt[keep]
    return sigma * np.sqrt(np.diag(cov)) / scale


PLANS = {
    "nominal": ("links", ()),
    "geometry": ("links", ("geometry",)),
    "+joint (tip mass)": ("tip-mass", ("geometry", "c")),
    "+joint (links)": ("links", ("geometry", "c")),
    "+joint+lateral (links)": ("links", ("geometry", "c", "k")),
}


def run(data_dir, urdf, stages, heldout=None, mode="fixed-point"):
    sessions_dir = os.path.join(data_dir, "sessions")
    truth_path = os.path.join(data_dir, "truth.json")
    truth = None
    if os.path.exists(truth_path):
        with open(truth_path, encoding="utf-8") as f:
            truth = json.load(f)
    if urdf is None:
        if truth is None:
            raise InputError(f"{data_dir}: no truth.json naming the nominal URDF; give --urdf")
        urdf = os.path.normpath(os.path.join(data_dir, truth["urdf_nominal"]))
    probe = Robot(urdf, [], "links")
    sessions = read_folder(sessions_dir, probe.names)
    tips = sorted({row["tip"] for _, rows in sessions for row in rows})
    tip_index = {t: i for i, t in enumerate(tips)}
    sigmas = [row["sigma"] for _, rows in sessions for row in rows if row["sigma"] is not None]
    sigma = float(np.sqrt(np.mean(np.square(sigmas)))) if sigmas else None
    held_name = heldout or sessions[-1][0]
    held = Problem([s for s in sessions if s[0] == held_name], tip_index)
    cal = Problem([s for s in sessions if s[0] != held_name], tip_index)
    if not cal.rows or not held.rows:
        raise InputError(f"{sessions_dir}: need at least two sessions (one held out)")
    report = {"deflection": mode, "calibration_sessions": cal.names, "heldout_sessions": held.names, "sigma_mm": sigma,
              "tips": tips, "stages": {}}
    for stage in stages:
        masses, kinds = PLANS[stage]
        fit = Fit(urdf, tips, masses, mode)
        entry = {}
        free = []
        if "geometry" in kinds:
            free = list(range(6 * fit.n + 3 * fit.tips))
            gauss_newton(fit, cal, free, iterations=4 if len(kinds) > 1 else 10)
        seen = {}
        for kind, at in (("c", fit.c_at), ("k", fit.k_at)):
            if kind in kinds:
                seen[kind] = determined_compliances(fit, cal, kind)
                free += [at + j for j in seen[kind]]
        if len(kinds) > 1:
            jac = gauss_newton(fit, cal, free)
            sd = compliance_sd(jac, sigma) if sigma else None
            entry["compliances"] = []
            for kind, at in (("c", fit.c_at), ("k", fit.k_at)):
                for j in range(fit.n) if kind in kinds else []:
                    determined = j in seen[kind]
                    entry["compliances"].append({
                        "joint": fit.robot.names[j], "kind": kind,
                        "value_rad_per_Nm": float(fit.params[at + j]) if determined else None,
                        "sd_rad_per_Nm": float(sd[free.index(at + j)]) if determined and sd is not None else None,
                    })
        entry["calibration"] = cal.figures(fit)
        entry["heldout"] = held.figures(fit)
        report["stages"][stage] = entry
    return report, truth


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("data", help="a folder humanoid.py wrote (sessions/, truth.json)")
    p.add_argument("--urdf", help="the nominal URDF (default: the one truth.json names)")
    p.add_argument("--stages", default=",".join(STAGES), help="comma-separated, of: " + ", ".join(STAGES))
    p.add_argument("--heldout", help="the held-out session's file name without .csv (default: the last)")
    p.add_argument("--deflection", choices=["fixed-point", "first-order"], default="fixed-point",
                   help="how the fitted model solves the deflection (the data's way: truth.json)")
    p.add_argument("--json", help="write the figures and fitted compliances here")
    a = p.parse_args(argv)
    stages = [s.strip() for s in a.stages.split(",") if s.strip()]
    for s in stages:
        if s not in STAGES:
            p.error(f"--stages: `{s}` is none of {', '.join(STAGES)}")
    try:
        report, truth = run(a.data, a.urdf, stages, a.heldout, a.deflection)
    except InputError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"fitted on {', '.join(report['calibration_sessions'])}; held out {', '.join(report['heldout_sessions'])}")
    print("model                      calibration RMS/mean mm   held-out RMS/mean mm")
    for stage, e in report["stages"].items():
        c, h = e["calibration"], e["heldout"]
        print(f"  {stage:24s} {c['rms_mm']:8.2f} {c['mean_mm']:7.2f}      {h['rms_mm']:8.2f} {h['mean_mm']:7.2f}")
    if truth:
        true = {(j["name"], kind): j[f"{kind}_rad_per_Nm"] for j in truth["joints"] for kind in ("c", "k")}
        for stage, e in report["stages"].items():
            for comp in e.get("compliances", []):
                t = true[(comp["joint"], comp["kind"])]
                comp["true_rad_per_Nm"] = t
                v, sd = comp["value_rad_per_Nm"], comp["sd_rad_per_Nm"]
                comp["z"] = (v - t) / sd if v is not None and sd else None
        last = [e for e in report["stages"].values() if "compliances" in e]
        if last:
            print("fitted compliances of the last stage (rad/(N m) x 1e-6): joint, kind, fitted, sd, true, z")
            for comp in last[-1]["compliances"]:
                if comp["value_rad_per_Nm"] is None:
                    print(f"  {comp['joint']:18s} {comp['kind']}  not determined (no load about it)")
                else:
                    print(f"  {comp['joint']:18s} {comp['kind']} {comp['value_rad_per_Nm'] * 1e6:8.2f} "
                          f"{(comp['sd_rad_per_Nm'] or math.nan) * 1e6:6.2f} {comp['true_rad_per_Nm'] * 1e6:8.2f} "
                          f"{comp['z'] if comp['z'] is not None else math.nan:6.2f}")
    if a.json:
        with open(a.json + ".tmp", "w", encoding="utf-8") as f:
            json.dump(report, f, indent=1)
        os.replace(a.json + ".tmp", a.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
