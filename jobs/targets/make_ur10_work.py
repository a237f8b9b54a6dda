"""Work targets for the UR10 of jobs/ur10_first.toml, as a user would write them.

A cell's work is a list of tool poses in the robot's base frame. Here: eight
poses the UR10 of ../shared/realdata/ur10-ipa (Series C) was commanded to, taken
from the export's `Goal` joints (every 173rd row, so they lie where the
calibration measured), with the tool pose of each computed on UR's own
standard DH chain (fixtures/tools/ur10_fk.py's table, not egcal's robot file)
and the SMR's offset of jobs/robots/ur10.toml's [tool] (93 mm along the flange
z). Written as a semicolon-separated CSV in mm and degrees, orientation as
egcal's targets take it (base <- tool = Rot(x, rx) Rot(y, ry) Rot(z, rz)),
with the commanded joints as the branch hint.

Run from the repository root (needs numpy):
    python3 jobs/targets/make_ur10_work.py
"""
import csv
import math
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "..", "fixtures", "tools"))
from ur10_fk import standard_dh_frames, trans  # noqa: E402

SERIES_C = os.path.join(os.path.dirname(__file__), "..", "..", "..", "shared", "realdata",
                        "ur10-ipa", "Series_C", "measurements_random_poses.csv")
OUT = os.path.join(os.path.dirname(__file__), "ur10_work.csv")
TOOL_Z_MM = 93.0
JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint",
          "wrist_2_joint", "wrist_3_joint"]


def xyz_angles_deg(r):
    """rx, ry, rz with r = Rot(x, rx) Rot(y, ry) Rot(z, rz)."""
    ry = math.asin(max(-1.0, min(1.0, r[0, 2])))
    rx = math.atan2(-r[1, 2], r[2, 2])
    rz = math.atan2(-r[0, 1], r[0, 0])
    return [math.degrees(a) for a in (rx, ry, rz)]


def main():
    with open(SERIES_C, newline="") as f:
        rows = list(csv.DictReader(f, delimiter=";"))
    chosen = rows[::173][:8]
    with open(OUT, "w", newline="") as f:
        out = csv.writer(f, delimiter=";")
        out.writerow(["id", "x", "y", "z", "rx", "ry", "rz", "j1", "j2", "j3", "j4", "j5", "j6"])
        for n, row in enumerate(chosen):
            q_deg = [math.degrees(float(row[j].replace(",", "."))) for j in JOINTS]
            tool = standard_dh_frames(q_deg)[5] @ trans(0.0, 0.0, TOOL_Z_MM)
            p = tool[:3, 3]
            angles = xyz_angles_deg(tool[:3, :3])
            out.writerow([n + 1] + [f"{v:.3f}" for v in p] + [f"{v:.4f}" for v in angles]
                         + [f"{v:.4f}" for v in q_deg])
    print(f"wrote {len(chosen)} targets to {OUT}")


if __name__ == "__main__":
    main()
