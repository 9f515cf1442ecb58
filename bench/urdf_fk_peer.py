#!/usr/bin/env python3
"""Independent URDF forward kinematics (stdlib xml + numpy), a peer for kincal's URDF output.

Written from the URDF specification (wiki.ros.org/urdf/XML/joint), sharing no code with kincal:
the chain from --base to --tip is found by walking the joints' parent/child links; each joint's
transform is origin(xyz, rpy) followed by its motion about/along its axis. rpy is fixed-axis
roll-pitch-yaw, R = Rz(yaw)·Ry(pitch)·Rx(roll); lengths in metres, angles in radians in the file.

Usage:
  urdf_fk_peer.py ROBOT.urdf --base LINK --tip LINK --q 10,20,30,...      (one pose)
  urdf_fk_peer.py ROBOT.urdf --base LINK --tip LINK --q-file poses.csv   (one pose per row)
  urdf_fk_peer.py ROBOT.urdf --base LINK --tip LINK --q-file poses.json  ([[...], ...] or
                                                                          {"q_deg": [[...], ...]})
Joint values are in degrees for revolute/continuous joints and mm for prismatic ones, in chain
order (base to tip, fixed joints skipped). A CSV may have a header; then the columns named
q1_deg … qN_deg are used, else every column.

Prints JSON: {"base", "tip", "joints": [names], "poses": [{"position_mm": [x, y, z],
"rotation": [[3], [3], [3]]}, ...]}; with --q also "position_mm" and "rotation" at the top.
Errors go to stderr with exit status 2.
"""
import argparse
import csv
import json
import sys
import xml.etree.ElementTree as ET

import numpy as np


class UrdfError(Exception):
    pass


def numbers(text, count, what):
    try:
        values = [float(v) for v in (text or "").split()]
    except ValueError:
        raise UrdfError(f"{what}: expected {count} numbers, got {text!r}")
    if len(values) != count or not all(np.isfinite(values)):
        raise UrdfError(f"{what}: expected {count} finite numbers, got {text!r}")
    return values


def rpy_matrix(roll, pitch, yaw):
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def axis_rotation(axis, angle):
    """Rodrigues: rotation by angle (rad) about the unit axis."""
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * (k @ k)


def homogeneous(rotation, translation):
    t = np.eye(4)
    t[:3, :3] = rotation
    t[:3, 3] = translation
    return t


class Joint:
    def __init__(self, element):
        self.name = element.get("name")
        self.kind = element.get("type")
        if self.kind not in ("revolute", "continuous", "prismatic", "fixed"):
            raise UrdfError(f"joint {self.name}: type {self.kind!r} is not supported")
        parent, child = element.find("parent"), element.find("child")
        if parent is None or child is None:
            raise UrdfError(f"joint {self.name}: needs <parent> and <child>")
        self.parent, self.child = parent.get("link"), child.get("link")
        origin = element.find("origin")
        xyz = numbers(origin.get("xyz", "0 0 0"), 3, f"joint {self.name} origin xyz") if origin is not None else [0, 0, 0]
        rpy = numbers(origin.get("rpy", "0 0 0"), 3, f"joint {self.name} origin rpy") if origin is not None else [0, 0, 0]
        self.origin = homogeneous(rpy_matrix(*rpy), np.array(xyz))
        axis = element.find("axis")
        a = np.array(numbers(axis.get("xyz"), 3, f"joint {self.name} axis") if axis is not None else [1.0, 0, 0])
        if self.kind != "fixed":
            n = np.linalg.norm(a)
            if n == 0:
                raise UrdfError(f"joint {self.name}: axis is zero")
            a = a / n
        self.axis = a

    def motion(self, value):
        """Transform of the joint's motion; value in deg (revolute) or mm (prismatic)."""
        if self.kind in ("revolute", "continuous"):
            return homogeneous(axis_rotation(self.axis, np.radians(value)), np.zeros(3))
        if self.kind == "prismatic":
            return homogeneous(np.eye(3), self.axis * value / 1000.0)
        return np.eye(4)


def chain(root, base, tip):
    joints = {}
    for element in root.findall("joint"):
        joint = Joint(element)
        if joint.child in joints:
            raise UrdfError(f"link {joint.child} is the child of two joints")
        joints[joint.child] = joint
    links = {link.get("name") for link in root.findall("link")}
    for name, what in ((base, "base"), (tip, "tip")):
        if name not in links:
            raise UrdfError(f"{what} link {name!r} is not in the URDF")
    path, link = [], tip
    while link != base:
        if link not in joints:
            raise UrdfError(f"link {tip!r} is not below {base!r}")
        path.append(joints[link])
        link = joints[link].parent
    return path[::-1]


def forward(path, values_deg):
    moving = [j for j in path if j.kind != "fixed"]
    if len(values_deg) != len(moving):
        raise UrdfError(f"{len(values_deg)} joint values given, the chain has {len(moving)} moving joints")
    t = np.eye(4)
    it = iter(values_deg)
    for joint in path:
        t = t @ joint.origin
        if joint.kind != "fixed":
            t = t @ joint.motion(next(it))
    return t


def read_poses(path):
    if path.endswith(".json"):
        with open(path) as f:
            data = json.load(f)
        if isinstance(data, dict):
            data = data.get("q_deg")
        if not isinstance(data, list) or not data:
            raise UrdfError(f"{path}: expected a list of joint-value lists or {{\"q_deg\": [...]}}")
        rows = data if isinstance(data[0], list) else [data]
        return [[float(v) for v in row] for row in rows]
    with open(path, newline="") as f:
        lines = [row for row in csv.reader(line for line in f if not line.startswith("#")) if row]
    if not lines:
        raise UrdfError(f"{path}: no rows")
    try:
        [float(v) for v in lines[0]]
        columns, body, first = list(range(len(lines[0]))), lines, 1
    except ValueError:
        header = [h.strip() for h in lines[0]]
        named = sorted((int(h[1:-4]), i) for i, h in enumerate(header)
                       if h.startswith("q") and h.endswith("_deg") and h[1:-4].isdigit())
        columns = [i for _, i in named] or list(range(len(header)))
        body, first = lines[1:], 2
    poses = []
    for n, row in enumerate(body):
        try:
            poses.append([float(row[i]) for i in columns])
        except (ValueError, IndexError):
            raise UrdfError(f"{path}:{n + first}: expected numbers in columns {columns}")
    return poses


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("urdf")
    parser.add_argument("--base", required=True)
    parser.add_argument("--tip", required=True)
    group = parser.add_mutually_exclusive_group(required=True)
    group.add_argument("--q", help="joint values, deg, comma-separated")
    group.add_argument("--q-file", help="CSV or JSON of joint values, deg")
    args = parser.parse_args()
    try:
        try:
            root = ET.parse(args.urdf).getroot()
        except (ET.ParseError, OSError) as e:
            raise UrdfError(f"{args.urdf}: {e}")
        path = chain(root, args.base, args.tip)
        if args.q is not None:
            try:
                poses = [[float(v) for v in args.q.split(",")]]
            except ValueError:
                raise UrdfError(f"--q: expected comma-separated numbers, got {args.q!r}")
        else:
            poses = read_poses(args.q_file)
        out = []
        for q in poses:
            t = forward(path, q)
            out.append({"position_mm": (t[:3, 3] * 1000.0).tolist(), "rotation": t[:3, :3].tolist()})
    except (UrdfError, OSError) as e:
        print(f"urdf_fk_peer: {e}", file=sys.stderr)
        sys.exit(2)
    result = {"base": args.base, "tip": args.tip, "joints": [j.name for j in path if j.kind != "fixed"]}
    if args.q is not None:
        result.update(out[0])
    result["poses"] = out
    json.dump(result, sys.stdout)
    print()


if __name__ == "__main__":
    main()
