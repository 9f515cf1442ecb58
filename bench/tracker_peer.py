#!/usr/bin/env python3
"""SciPy peer of kincal's tracker calibration (`kincal bench`): the same problem solved by
scipy.optimize.least_squares (TRF, linear loss, finite-difference Jacobian).

Reads a problem file written by kincal (the Ceres peer reads the same file):
  {"dh": [[theta_offset_deg, d_mm, a_mm, alpha_deg], ...]   classic DH, Rz Tz Tx Rx,
   "tool_mm": [x, y, z],
   "params": ["offset:2", "length:3", "link_offset:1", "twist:4", "tcp.x", ...]   (joints from 1),
   "lower": [...], "upper": [...],                      bounds of the params,
   "sessions": [{"q_deg": [[...], ...], "x_mm": [[x, y, z], ...]}, ...]}
Unknowns: the params and one base (rotation vector + shift) per session, each base started at
Kabsch for the nominal arm. Prints {"seconds", "cpu_seconds", "cost", "rms_mm", "nfev",
"scipy_version"} as JSON. Forward kinematics written here with numpy, independent of kincal.
"""
import json
import sys
import time

import numpy as np
import scipy
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

COLUMN = {"offset": 0, "length": 1, "link_offset": 2, "twist": 3}


def fk(q_deg, dh, tool):
    n = q_deg.shape[0]
    t = np.tile(np.eye(4), (n, 1, 1))
    for i in range(dh.shape[0]):
        th, al = np.radians(q_deg[:, i] + dh[i, 0]), np.radians(dh[i, 3])
        ct, st, ca, sa = np.cos(th), np.sin(th), np.cos(al), np.sin(al)
        a = np.zeros((n, 4, 4))
        a[:, 0, 0], a[:, 0, 1], a[:, 0, 2], a[:, 0, 3] = ct, -st * ca, st * sa, dh[i, 2] * ct
        a[:, 1, 0], a[:, 1, 1], a[:, 1, 2], a[:, 1, 3] = st, ct * ca, -ct * sa, dh[i, 2] * st
        a[:, 2, 1], a[:, 2, 2], a[:, 2, 3] = sa, ca, dh[i, 1]
        a[:, 3, 3] = 1.0
        t = t @ a
    return np.einsum("nij,j->ni", t[:, :3, :3], tool) + t[:, :3, 3]


def kabsch(a, b):
    ca, cb = a.mean(0), b.mean(0)
    u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return np.r_[Rotation.from_matrix(r).as_rotvec(), cb - r @ ca]


def main():
    with open(sys.argv[1]) as f:
        p = json.load(f)
    dh0, tool0 = np.array(p["dh"], float), np.array(p["tool_mm"], float)
    # (table, row, column) each param sets: the DH table (joint, column) or the tool point (axis).
    free = [("tool", "xyz".index(name[4:]), None) if name.startswith("tcp.") else
            ("dh", int(name.split(":")[1]) - 1, COLUMN[name.split(":")[0]]) for name in p["params"]]
    sessions = [(np.array(s["q_deg"], float), np.array(s["x_mm"], float)) for s in p["sessions"]]
    k = len(free)

    def unpack(z):
        dh, tool = dh0.copy(), tool0.copy()
        for v, (table, i, c) in zip(z[:k], free):
            if table == "dh":
                dh[i, c] = v
            else:
                tool[i] = v
        return dh, tool

    def residual(z):
        dh, tool = unpack(z)
        out = []
        for s, (q, x) in enumerate(sessions):
            b = z[k + 6 * s:k + 6 + 6 * s]
            pts = fk(q, dh, tool) @ Rotation.from_rotvec(b[:3]).as_matrix().T + b[3:]
            out.append((pts - x).ravel())
        return np.concatenate(out)

    z0 = np.array([dh0[i, c] if table == "dh" else tool0[i] for table, i, c in free])
    for q, x in sessions:
        z0 = np.r_[z0, kabsch(fk(q, dh0, tool0), x)]
    bases = 6 * len(sessions)
    lower = np.r_[p["lower"], np.full(bases, -np.inf)]
    upper = np.r_[p["upper"], np.full(bases, np.inf)]
    wall, cpu = time.perf_counter(), time.process_time()
    r = least_squares(residual, z0, bounds=(lower, upper), method="trf", x_scale="jac")
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    res = residual(r.x).reshape(-1, 3)
    print(json.dumps({"seconds": wall, "cpu_seconds": cpu, "cost": float(r.cost), "nfev": int(r.nfev),
                      "rms_mm": float(np.sqrt((res ** 2).sum(1).mean())), "scipy_version": scipy.__version__}))


if __name__ == "__main__":
    main()
