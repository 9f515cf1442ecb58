#!/usr/bin/env python3
"""Strip the geometry a calibration never reads from a published URDF: every <visual> and
<collision> element (meshes, boxes, materials inside them). Joints, links, inertials, limits,
<transmission>, <gazebo> and <ros2_control> stay byte for byte, so the kinematics is the
published one.

Usage: strip_meshes.py PUBLISHED.urdf > STRIPPED.urdf
"""
import re
import sys

text = open(sys.argv[1], encoding="utf-8").read()
for tag in ("visual", "collision"):
    text = re.sub(rf"[ \t]*<{tag}\b[^>]*/>[ \t]*\n?", "", text)
    text = re.sub(rf"[ \t]*<{tag}\b.*?</{tag}>[ \t]*\n?", "", text, flags=re.S)
sys.stdout.write(text)
