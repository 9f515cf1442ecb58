#!/usr/bin/env python3
"""Held-out RMS against the true floor, per public arm, seed and tool point: a measurement, not a test.

For each arm of tests/data/urdf/arms.csv, each seed and each tool point (on and off the last
axis): pinocchio_peer.py writes the true arm (origins off by 0.5–2 mm and 0.05–0.3°) and five
tracker sessions (σ = 0.02 mm, session 5 held out); `kincal model from-urdf` makes the nominal
model of the published URDF; `kincal calibrate` fits sessions 1–4 and scores session 5. Prints a
Markdown table: held-out RMS (mm), the true floor of the held-out session (mm, from the peer's
truth) and their ratio, and the parameters kincal held.

Usage: bench/public_arms.py [--kincal target/release/kincal] [--seeds 1,2,3] [--work DIR]
"""
import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
URDFS = os.path.join(ROOT, "tests", "data", "urdf")


def arms():
    with open(os.path.join(URDFS, "arms.csv")) as f:
        return list(csv.DictReader(line for line in f if not line.startswith("#")))


def run(args, cwd):
    done = subprocess.run(args, cwd=cwd, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(args)}: exit {done.returncode}\n{done.stderr}")
    return done.stdout


def measure(kincal, arm, seed, tool, work):
    folder = os.path.join(work, f"{arm['file'][:-5]}-{seed}-{tool}")
    urdf = os.path.join(URDFS, arm["file"])
    chain = ["--base", arm["base"], "--tip", arm["tip"]]
    peer = [sys.executable, os.path.join(HERE, "pinocchio_peer.py"), "sessions", urdf, *chain]
    run([*peer, "--seed", str(seed), "--tool", tool, "--out", folder], work)
    run([kincal, "model", "from-urdf", urdf, *chain, "--out", "model.toml"], folder)
    run([kincal, "calibrate", "--model", "model.toml", "--data", "cal", "--validate", "val", "--out", "run"], folder)
    with open(os.path.join(folder, "truth.json")) as f:
        floor = json.load(f)["held_out_floor_mm"]
    with open(os.path.join(folder, "run", "summary.json")) as f:
        summary = json.load(f)
    held_out = summary["validation"]["sessions"]["overall"]["rms_mm"]
    return held_out, floor, len(summary["identifiability"]["report"]["fixed"])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kincal", default=os.path.join(ROOT, "target", "release", "kincal"))
    parser.add_argument("--seeds", default="1,2,3")
    parser.add_argument("--work", default=None, help="keep the generated data here")
    args = parser.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    work = args.work or tempfile.mkdtemp(prefix="kincal-public-arms-")
    os.makedirs(work, exist_ok=True)
    print("| arm | tool point | seed | held-out RMS mm | true floor mm | ratio | parameters held |")
    print("|---|---|---|---|---|---|---|")
    worst = {}
    for arm in arms():
        for tool in ("on", "off"):
            for seed in seeds:
                try:
                    rms, floor, held = measure(args.kincal, arm, seed, tool, work)
                except RuntimeError as e:
                    print(f"| {arm['arm']} | {tool} axis | {seed} | failed: {str(e).splitlines()[0]} | | | |")
                    continue
                ratio = rms / floor
                worst[arm["arm"]] = max(worst.get(arm["arm"], 0.0), ratio)
                print(f"| {arm['arm']} | {tool} axis | {seed} | {rms:.4f} | {floor:.4f} | {ratio:.2f}× | {held} |")
                sys.stdout.flush()
    print()
    print("| arm | worst ratio |")
    print("|---|---|")
    for name, ratio in worst.items():
        print(f"| {name} | {ratio:.2f}× |")
    print(f"\n(data in {work})", file=sys.stderr)


if __name__ == "__main__":
    main()
