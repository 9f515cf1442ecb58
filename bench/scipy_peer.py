#!/usr/bin/env python3
"""Independent peer for kincal's calibration: the same objective solved by SciPy.

Reads a problem file written by kincal (``kincal bench`` or the peer test):
  {"model": {"convention", "joint": [{"offset_deg","d_mm","a_mm","alpha_deg","axis_deg"}...],
             "tcp_mm", "scale_ppm"},
   "landmarks_mm": [[x,y,z], ...],
   "touches": [{"placement", "landmark", "repeat", "enc_deg": [6]}],
   "params": ["offset:2", ...], "x0": [...], "lower": [...], "upper": [...],
   "huber_delta_mm": 1.35,
   "starts": [[...], ...]}          (optional: kincal's random restarts, solved with --all-starts)
and prints {"cost", "x", "seconds", "cpu_seconds", "nfev", "rms_mm", "scipy_version"} as JSON: from x0,
or with --all-starts from x0 and every start (the lowest cost kept, the earliest on an equal one; kincal
also counts costs within its function tolerance as equal, the same minimum; the
times and evaluations summed, "starts" listing each start's cost and evaluations). The forward kinematics here is written
from the DH definition with numpy, independent of kincal's Rust code.
Cost convention: SciPy's 0.5 * f_scale**2 * sum(rho((f/f_scale)**2)), the same as kincal's.
"""
import json
import sys
import time

import numpy as np
import scipy
from scipy.optimize import least_squares


def rot(axis, a):
    c, s = np.cos(a), np.sin(a)
    m = np.eye(4)
    i, j = {"x": (1, 2), "y": (2, 0), "z": (0, 1)}[axis]
    m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
    return m


def shift(x, y, z):
    m = np.eye(4)
    m[:3, 3] = (x, y, z)
    return m


def tool_point(model, enc_deg):
    t = np.eye(4)
    for joint, enc in zip(model["joint"], enc_deg):
        theta = np.radians(enc + joint["offset_deg"])
        alpha, beta = np.radians(joint["alpha_deg"]), np.radians(joint.get("axis_deg", 0.0))
        if model["convention"] == "classic":
            link = rot("z", theta) @ shift(0, 0, joint["d_mm"]) @ shift(joint["a_mm"], 0, 0) @ rot("x", alpha) @ rot("y", beta)
        else:
            link = rot("x", alpha) @ rot("y", beta) @ shift(joint["a_mm"], 0, 0) @ rot("z", theta) @ shift(0, 0, joint["d_mm"])
        t = t @ link
    p = t @ np.array([*model["tcp_mm"], 1.0])
    return p[:3] * (1.0 + model.get("scale_ppm", 0.0) * 1e-6)


KINDS = {"offset": "offset_deg", "length": "d_mm", "link_offset": "a_mm", "twist": "alpha_deg", "axis": "axis_deg"}


def apply(model, params, x):
    m = json.loads(json.dumps(model))
    for name, value in zip(params, x):
        if name == "scale":
            m["scale_ppm"] = value
        elif name.startswith("tcp."):
            m["tcp_mm"]["xyz".index(name[4:])] = value
        else:
            kind, joint = name.split(":")
            m["joint"][int(joint) - 1][KINDS[kind]] = value
    return m


def main():
    problem = json.load(open(sys.argv[1]))
    touches = problem["touches"]
    landmarks = np.array(problem["landmarks_mm"])
    pairs = [(a, b) for a in range(len(touches)) for b in range(a + 1, len(touches))
             if touches[a]["placement"] == touches[b]["placement"]
             and touches[a]["repeat"] == touches[b]["repeat"]
             and touches[a]["landmark"] != touches[b]["landmark"]]
    ia = np.array([p[0] for p in pairs])
    ib = np.array([p[1] for p in pairs])
    certified = np.linalg.norm(landmarks[[touches[a]["landmark"] for a in ia]] - landmarks[[touches[b]["landmark"] for b in ib]], axis=1)

    def residuals(x):
        m = apply(problem["model"], problem["params"], x)
        pts = np.array([tool_point(m, t["enc_deg"]) for t in touches])
        return np.linalg.norm(pts[ia] - pts[ib], axis=1) - certified

    starts = [problem["x0"]] + (problem.get("starts", []) if "--all-starts" in sys.argv[2:] else [])
    wall, cpu = time.perf_counter(), time.process_time()
    results = [least_squares(residuals, np.array(x0), bounds=(problem["lower"], problem["upper"]),
                             method="trf", loss="huber", f_scale=problem["huber_delta_mm"]) for x0 in starts]
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    best = min(range(len(results)), key=lambda k: (results[k].cost, k))
    result = results[best]
    print(json.dumps({"cost": float(result.cost), "x": result.x.tolist(), "seconds": wall, "cpu_seconds": cpu,
                      "nfev": sum(int(r.nfev) for r in results), "best_start": best,
                      "rms_mm": float(np.sqrt(np.mean(residuals(result.x) ** 2))),
                      "starts": [{"cost": float(r.cost), "nfev": int(r.nfev)} for r in results],
                      "scipy_version": scipy.__version__}))


if __name__ == "__main__":
    main()
