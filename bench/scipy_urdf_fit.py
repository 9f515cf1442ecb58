#!/usr/bin/env python3
"""SciPy least squares of a public arm's calibration, with pinocchio's kinematics: a peer for kincal.

On a folder written by `pinocchio_peer.py sessions` (DIR/cal: sessions 1–4, DIR/val: session 5,
DIR/truth.json): each revolute joint's placement M of the published URDF becomes
(M.translation + shift, M.rotation·exp(ω)), each reading gets an offset, the tool point is in the
last joint's frame (starting at the URDF's tip), and each session has its own base (started at
its Kabsch fit). SciPy's `least_squares` (trf, tolerances 1e-12) fits sessions 1–4; session 5 is
scored with its base refitted. Prints JSON: parameters fitted, calibration RMS, held-out RMS, the
true floor and their ratio. Shares no code with kincal.

  scipy_urdf_fit.py DIR [--params all|RUN] [--tcp nominal|true]

--params RUN fits only the parameters kincal estimated in DIR/RUN/summary.json (e.g. `run`);
--tcp true starts the tool point at the true one instead of the URDF's tip.
"""
import argparse
import csv
import glob
import json
import math
import os
import sys

import numpy as np
import pinocchio as pin
from scipy.optimize import least_squares

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from pinocchio_peer import Arm, kabsch  # noqa: E402


def read_csv(path):
    q, x = [], []
    with open(path) as f:
        rows = [r for r in csv.reader(l for l in f if not l.startswith("#"))]
    head = rows[0]
    qi = [i for i, h in enumerate(head) if h.startswith("q")]
    xi = [head.index(h) for h in ("x_mm", "y_mm", "z_mm")]
    for r in rows[1:]:
        q.append([float(r[i]) for i in qi])
        x.append([float(r[i]) for i in xi])
    return np.array(q), np.array(x)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("dir")
    ap.add_argument("--params", default="all")
    ap.add_argument("--tcp", default="nominal")
    a = ap.parse_args()
    truth = json.load(open(os.path.join(a.dir, "truth.json")))
    arm = Arm(truth["urdf"], truth["base"], truth["tip"])
    model, data = arm.model, arm.data
    nj = len(arm.ids)
    nominal = [pin.SE3(model.jointPlacements[j]) for j in arm.ids]
    # The tool point in the last joint's frame: the tip frame's origin (nominal) or the true tool.
    pin.framesForwardKinematics(model, data, arm.q([0.0] * nj))
    last = data.oMi[arm.ids[-1]]
    tip = data.oMf[arm.tip]
    tip_in_last = last.actInv(tip)
    tcp0 = tip_in_last.translation * 1000.0
    if a.tcp == "true":
        tcp0 = tcp0 + tip_in_last.rotation @ np.array(truth["tool_mm"])
    cal = [read_csv(p) for p in sorted(glob.glob(os.path.join(a.dir, "cal", "*.csv")))]
    val = [read_csv(p) for p in sorted(glob.glob(os.path.join(a.dir, "val", "*.csv")))]
    names = []
    for j in range(nj):
        names += [f"offset:{j+1}", f"origin_x:{j+1}", f"origin_y:{j+1}", f"origin_z:{j+1}",
                  f"origin_rx:{j+1}", f"origin_ry:{j+1}", f"origin_rz:{j+1}"]
    names += ["tcp.x", "tcp.y", "tcp.z"]
    if a.params == "all":
        free = list(range(len(names)))
    else:
        s = json.load(open(os.path.join(a.dir, a.params, "summary.json")))
        est = set(s["identifiability"]["report"]["estimated"])
        free = [i for i, n in enumerate(names) if n in est]
    narm = len(names)

    def arm_values(xfree):
        v = np.zeros(narm)
        v[narm - 3:] = tcp0
        for k, i in enumerate(free):
            v[i] = xfree[k] if i < narm - 3 else tcp0[i - (narm - 3)] + xfree[k]
        return v

    def points(v, qs):
        for j, jid in enumerate(arm.ids):
            p = v[7 * j:7 * j + 7]
            n = nominal[j]
            model.jointPlacements[jid] = pin.SE3(n.rotation @ pin.exp3(np.radians(p[4:7])),
                                                 n.translation + p[1:4] / 1000.0)
        tcp = v[narm - 3:]
        out = np.empty((len(qs), 3))
        for k, q in enumerate(qs):
            qq = np.array(q) + np.array([v[7 * j] for j in range(nj)])
            pin.forwardKinematics(model, data, arm.q(qq))
            m = data.oMi[arm.ids[-1]]
            out[k] = m.translation * 1000.0 + m.rotation @ tcp
        return out

    base_frames = []
    v0 = arm_values(np.zeros(len(free)))
    for q, x in cal:
        r, t = kabsch(points(v0, q), x)
        base_frames += list(pin.log3(r)) + list(t)
    x0 = np.concatenate([np.zeros(len(free)), base_frames])
    nf = len(free)

    def resid(x):
        v = arm_values(x[:nf])
        out = []
        for s, (q, meas) in enumerate(cal):
            b = x[nf + 6 * s: nf + 6 * s + 6]
            r = pin.exp3(b[:3])
            out.append((points(v, q) @ r.T + b[3:] - meas).ravel())
        return np.concatenate(out)

    sol = least_squares(resid, x0, method="trf", x_scale="jac", xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=200)
    v = arm_values(sol.x[:nf])
    cal_rms = math.sqrt(np.mean(np.sum(sol.fun.reshape(-1, 3) ** 2, axis=1)))
    sq = []
    for q, meas in val:
        p = points(v, q)
        r, t = kabsch(p, meas)
        sq += list(np.sum((p @ r.T + t - meas) ** 2, axis=1))
    held = math.sqrt(np.mean(sq))
    floor = truth["held_out_floor_mm"]
    print(json.dumps({"free": nf, "cal_rms_mm": cal_rms, "held_out_mm": held, "floor_mm": floor,
                      "ratio": held / floor, "nfev": sol.nfev, "status": sol.status}))


if __name__ == "__main__":
    main()
