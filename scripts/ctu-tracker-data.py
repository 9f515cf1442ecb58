#!/usr/bin/env python3
"""Prepare the CTU Motoman MA1400 laser-tracker data (see /work/shared/data/real/motoman-ma1400-ctu/
README.md; NOT part of this repository, never commit it) as kincal-tracker/1 folders and a
kincal-arm/1 model, in OUT (default /tmp/ctu):

  OUT/model.toml            nominal classic DH of the right arm, every DH value free, tool point
  OUT/train/aug_train.csv   right_aug2019.csv rows with split == train (the seeded 70 %)
  OUT/test/aug_test.csv     right_aug2019.csv rows with split == test (30 %, same session)
  OUT/grid/right_grid.csv   right_grid_2019.csv (another session, months earlier)

The August train and test rows are one tracker session split in two; kincal refits the base of
every held-out session (the reference's protocol A).

Usage: python3 scripts/ctu-tracker-data.py [SRC_DIR] [OUT]
"""
import csv
import json
import os
import sys

SRC = sys.argv[1] if len(sys.argv) > 1 else "/work/shared/data/real/motoman-ma1400-ctu"
OUT = sys.argv[2] if len(sys.argv) > 2 else "/tmp/ctu"
COLUMNS = ["pose"] + [f"q{j}_deg" for j in range(1, 7)] + ["x_mm", "y_mm", "z_mm"]


def write(rows, path):
    os.makedirs(os.path.dirname(path), exist_ok=True)
    with open(path, "w", newline="") as f:
        f.write("# kincal-tracker/1\n")
        w = csv.writer(f, lineterminator="\n")
        w.writerow(COLUMNS)
        for r in rows:
            w.writerow([r[c] for c in COLUMNS])


def rows(name):
    with open(os.path.join(SRC, name), newline="") as f:
        return list(csv.DictReader(f))


aug = rows("right_aug2019.csv")
write([r for r in aug if r["split"] == "train"], os.path.join(OUT, "train", "aug_train.csv"))
write([r for r in aug if r["split"] == "test"], os.path.join(OUT, "test", "aug_test.csv"))
write(rows("right_grid_2019.csv"), os.path.join(OUT, "grid", "right_grid.csv"))

with open(os.path.join(SRC, "nominal.json")) as f:
    nom = json.load(f)
tool = nom["tool_point_mm"]
lines = ['format = "kincal-arm/1"', 'name = "Motoman MA1400 right arm (CTU), nominal"',
         'convention = "classic"', f"tcp_mm = [{tool[0]}, {tool[1]}, {tool[2]}]"]
free = []
for row in nom["dh"]:
    j = row["joint"]
    lines += ["", "[[joint]]", f"offset_deg = {row['theta_offset_deg']}", f"d_mm = {row['d_mm']}",
              f"a_mm = {row['a_mm']}", f"alpha_deg = {row['alpha_deg']}"]
    free += [f'"offset:{j}" = [{row["theta_offset_deg"] - 5}, {row["theta_offset_deg"] + 5}]',
             f'"length:{j}" = [{row["d_mm"] - 20}, {row["d_mm"] + 20}]',
             f'"link_offset:{j}" = [{row["a_mm"] - 20}, {row["a_mm"] + 20}]',
             f'"twist:{j}" = [{row["alpha_deg"] - 5}, {row["alpha_deg"] + 5}]']
lines += ["", "[free]"] + free
with open(os.path.join(OUT, "model.toml"), "w") as f:
    f.write("\n".join(lines) + "\n")
print(f"written {OUT}/model.toml, train/, test/, grid/")
