#!/usr/bin/env python3
"""Forward kinematics and tracker sessions of public URDFs with pinocchio: a peer for kincal.

Independent of kincal: pinocchio (`pip install pin`) reads the URDF and computes every transform;
this script only chooses joint readings, perturbs the URDF text, places the instrument and adds
noise. Nothing here is shared with kincal's code.

  pinocchio_peer.py fk URDF [URDF …] --base LINK --tip LINK --q-file POSES.json
      POSES.json: [[q1_deg, …], …], one reading per chain joint (base to tip; fixed joints
      skipped). Prints JSON {"joints": [names], "poses": [{"position_mm": [x, y, z] (tip in the
      base frame), "rotation": 3×3 (the last chain joint's frame in the base frame)}, …]}, or a
      list of them, one per URDF, when several are given.

  pinocchio_peer.py sessions URDF --base LINK --tip LINK --seed N[,M…] --tool on|off|on,off --out DIR
      The true arm: each revolute origin of the chain moved by 0.5–2 mm (random direction) and
      turned by 0.05–0.3° (random axis, about its own frame), written as DIR/true.urdf. The tool
      point: on the last joint's axis (`on`: 40–80 mm beyond the tip along it) or off it (`off`:
      also 20–60 mm across it), in the tip frame. Five sessions of 60 random readings within the
      joint limits, each measured from its own instrument placement (1.5–2.5 m away, any heading;
      each further placement turned by 5–10° and moved by 0.3–1 m), σ = 0.02 mm per axis: sessions
      1–4 in DIR/cal, session 5 in DIR/val, as kincal-tracker/1 CSV files. DIR/truth.json: the
      perturbations, the tool point, the bases and the true floor of the held-out session (the
      3-D RMS the true arm leaves on its noisy points after their base is refitted, Horn/Kabsch).
      Several seeds or tool points: one folder DIR/TOOL-SEED (e.g. DIR/off-2) per case.

Errors go to stderr with exit status 2.
"""
import argparse
import json
import math
import os
import sys
import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin

SIGMA_MM = 0.02
POSES = 60
SESSIONS = 5
HELD_OUT = 1


class PeerError(Exception):
    pass


def chain_joints(urdf_text, base, tip):
    """The chain's joint elements, base to tip, from the URDF's <robot>/<joint> elements."""
    root = ET.fromstring(urdf_text)
    by_child = {j.find("child").get("link"): j for j in root.findall("joint")}
    path, link = [], tip
    while link != base:
        if link not in by_child:
            raise PeerError(f"link {tip!r} is not below {base!r}")
        path.append(by_child[link])
        link = by_child[link].find("parent").get("link")
    return root, path[::-1]


class Arm:
    """A pinocchio model of a URDF and the chain base → tip in it."""

    def __init__(self, urdf_path, base, tip):
        self.model = pin.buildModelFromUrdf(urdf_path)
        self.data = self.model.createData()
        with open(urdf_path, encoding="utf-8") as f:
            _, path = chain_joints(f.read(), base, tip)
        moving = [j for j in path if j.get("type") in ("revolute", "continuous")]
        self.names = [j.get("name") for j in moving]
        axis = moving[-1].find("axis") if moving else None
        last_axis = np.array([float(v) for v in axis.get("xyz").split()]) if axis is not None else np.array([1.0, 0, 0])
        # The last joint's axis in its own frame (URDF's default is x).
        self.last_axis = last_axis / np.linalg.norm(last_axis)
        self.ids = [self.model.getJointId(n) for n in self.names]
        for name, jid in zip(self.names, self.ids):
            if jid >= self.model.njoints:
                raise PeerError(f"pinocchio has no joint {name}")
        self.base = self.model.getFrameId(base)
        self.tip = self.model.getFrameId(tip)

    def q(self, q_deg):
        """The configuration: the chain's readings, every other joint at its neutral value."""
        q = pin.neutral(self.model)
        for jid, deg in zip(self.ids, q_deg):
            joint = self.model.joints[jid]
            a = math.radians(deg)
            if joint.nq == 2:  # continuous joint: (cos, sin)
                q[joint.idx_q : joint.idx_q + 2] = [math.cos(a), math.sin(a)]
            else:
                q[joint.idx_q] = a
        return q

    def limits_deg(self):
        out = []
        for jid in self.ids:
            joint = self.model.joints[jid]
            lo, hi = -180.0, 180.0
            if joint.nq == 1:
                lo = max(lo, math.degrees(self.model.lowerPositionLimit[joint.idx_q]))
                hi = min(hi, math.degrees(self.model.upperPositionLimit[joint.idx_q]))
            out.append((lo, hi))
        return out

    def fk(self, q_deg):
        """(tip in the base frame as an SE3, the last chain joint's frame in the base frame)."""
        pin.framesForwardKinematics(self.model, self.data, self.q(q_deg))
        base = self.data.oMf[self.base]
        return base.actInv(self.data.oMf[self.tip]), base.actInv(self.data.oMi[self.ids[-1]])


def cmd_fk(args):
    with open(args.q_file) as f:
        poses = json.load(f)
    results = []
    for urdf in args.urdf:
        arm = Arm(urdf, args.base, args.tip)
        out = []
        for q in poses:
            if len(q) != len(arm.ids):
                raise PeerError(f"{len(q)} readings given, the chain has {len(arm.ids)} joints")
            tip, last = arm.fk(q)
            out.append({"position_mm": (tip.translation * 1000.0).tolist(), "rotation": last.rotation.tolist()})
        results.append({"joints": arm.names, "poses": out})
    json.dump(results[0] if len(results) == 1 else results, sys.stdout)
    print()


def random_unit(rng):
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def rotation_vector(w):
    return pin.exp3(np.asarray(w, dtype=float))


def perturbed_urdf(text, base, tip, rng):
    """The URDF text with each revolute origin of the chain moved and turned, and the moves."""
    root, path = chain_joints(text, base, tip)
    moves = []
    for joint in path:
        if joint.get("type") not in ("revolute", "continuous"):
            continue
        origin = joint.find("origin")
        if origin is None:
            origin = ET.SubElement(joint, "origin")
        xyz = np.array([float(v) for v in origin.get("xyz", "0 0 0").split()])
        rpy = np.array([float(v) for v in origin.get("rpy", "0 0 0").split()])
        shift_mm = random_unit(rng) * rng.uniform(0.5, 2.0)
        turn_deg = random_unit(rng) * rng.uniform(0.05, 0.3)
        rotation = pin.rpy.rpyToMatrix(*rpy) @ rotation_vector(np.radians(turn_deg))
        origin.set("xyz", " ".join(repr(float(v)) for v in xyz + shift_mm / 1000.0))
        origin.set("rpy", " ".join(repr(float(v)) for v in pin.rpy.matrixToRpy(rotation)))
        moves.append({"joint": joint.get("name"), "shift_mm": shift_mm.tolist(), "turn_deg": turn_deg.tolist()})
    return ET.tostring(root, encoding="unicode"), moves


def kabsch(p, x):
    """The rigid transform (R, t) minimising Σ|R p + t − x|²."""
    pc, xc = p.mean(axis=0), x.mean(axis=0)
    u, _, vt = np.linalg.svd((p - pc).T @ (x - xc))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return r, xc - r @ pc


def cmd_sessions(args):
    seeds = [int(v) for v in args.seed.split(",")]
    tools = args.tool.split(",")
    for tool in tools:
        if tool not in ("on", "off"):
            raise PeerError(f"--tool {tool}: expected on or off")
    cases = [(seed, tool) for tool in tools for seed in seeds]
    for seed, tool in cases:
        out = args.out if len(cases) == 1 else os.path.join(args.out, f"{tool}-{seed}")
        write_sessions(args.urdf, args.base, args.tip, seed, tool, out)


def write_sessions(urdf, base, tip, seed, tool_kind, out):
    """The true arm, the sessions and truth.json of one seed and tool point, in the folder `out`."""
    rng = np.random.default_rng(seed)
    with open(urdf, encoding="utf-8") as f:
        text = f.read()
    true_text, moves = perturbed_urdf(text, base, tip, rng)
    os.makedirs(out, exist_ok=True)
    true_path = os.path.join(out, "true.urdf")
    with open(true_path, "w", encoding="utf-8") as f:
        f.write(true_text)
    arm = Arm(true_path, base, tip)
    # The tool point in the tip frame: along the last joint's axis, and across it when "off".
    tip0, last0 = arm.fk([0.0] * len(arm.ids))
    axis_tip = tip0.rotation.T @ (last0.rotation @ arm.last_axis)
    tool = axis_tip * rng.uniform(40.0, 80.0)
    if tool_kind == "off":
        across = np.cross(axis_tip, random_unit(rng))
        tool = tool + across / np.linalg.norm(across) * rng.uniform(20.0, 60.0)
    limits = arm.limits_deg()
    first_r = rotation_vector([0, 0, rng.uniform(0, 2 * math.pi)]) @ rotation_vector(rng.normal(size=3) * [0.02, 0.02, 0])
    first_t = random_unit(rng) * rng.uniform(1500.0, 2500.0)
    bases = []
    for s in range(SESSIONS):
        if s == 0:
            bases.append((first_r, first_t))
        else:
            turn = rotation_vector(random_unit(rng) * math.radians(rng.uniform(5.0, 10.0)))
            bases.append((turn @ first_r, first_t + random_unit(rng) * rng.uniform(300.0, 1000.0)))
    floors = {}
    for s, (r, t) in enumerate(bases):
        name = f"session_{s + 1}"
        folder = os.path.join(out, "val" if s >= SESSIONS - HELD_OUT else "cal")
        os.makedirs(folder, exist_ok=True)
        rows, exact, measured = [], [], []
        for k in range(POSES):
            q = [round(rng.uniform(lo, hi), 6) for lo, hi in limits]
            tip_pose, _ = arm.fk(q)
            p = tip_pose.translation * 1000.0 + tip_pose.rotation @ tool
            x = r @ p + t + rng.normal(size=3) * SIGMA_MM
            exact.append(p)
            measured.append(x)
            rows.append([k + 1] + [f"{v:.6f}" for v in q] + [f"{v:.6f}" for v in x] + [f"{SIGMA_MM}"])
        header = ["pose"] + [f"q{j + 1}_deg" for j in range(len(arm.ids))] + ["x_mm", "y_mm", "z_mm", "sigma_mm"]
        with open(os.path.join(folder, f"{name}.csv"), "w") as f:
            f.write("# kincal-tracker/1\n" + ",".join(header) + "\n")
            f.writelines(",".join(str(v) for v in row) + "\n" for row in rows)
        # The floor: the true arm's residuals after the session's base is refitted. The written
        # points are rounded to 1 nm, far below σ.
        p, x = np.array(exact), np.array([[float(v) for v in row[-4:-1]] for row in rows])
        fr, ft = kabsch(p, x)
        floors[name] = float(np.sqrt(np.mean(np.sum((p @ fr.T + ft - x) ** 2, axis=1))))
    held_out = [f"session_{s + 1}" for s in range(SESSIONS - HELD_OUT, SESSIONS)]
    truth = {
        "urdf": urdf,
        "base": base,
        "tip": tip,
        "seed": seed,
        "tool": tool_kind,
        "tool_mm": tool.tolist(),
        "sigma_mm": SIGMA_MM,
        "moves": moves,
        "bases": [{"rotation": r.tolist(), "translation_mm": t.tolist()} for r, t in bases],
        "floor_mm": floors,
        "held_out": held_out,
        "held_out_floor_mm": float(np.sqrt(np.mean([floors[h] ** 2 for h in held_out]))),
    }
    with open(os.path.join(out, "truth.json"), "w") as f:
        json.dump(truth, f, indent=1)
    json.dump({"held_out_floor_mm": truth["held_out_floor_mm"], "tool_mm": truth["tool_mm"]}, sys.stdout)
    print()


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    for name in ("fk", "sessions"):
        p = sub.add_parser(name)
        p.add_argument("urdf", nargs="+" if name == "fk" else None)
        p.add_argument("--base", required=True)
        p.add_argument("--tip", required=True)
        if name == "fk":
            p.add_argument("--q-file", required=True)
        else:
            p.add_argument("--seed", required=True, help="N, or N,M,… for several")
            p.add_argument("--tool", required=True, help="on, off, or on,off for both")
            p.add_argument("--out", required=True)
    args = parser.parse_args()
    try:
        {"fk": cmd_fk, "sessions": cmd_sessions}[args.command](args)
    except (PeerError, OSError, ValueError, ET.ParseError) as e:
        print(f"pinocchio_peer: {e}", file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":
    main()
