"""Targets a user would send to the calibrated robot, for jobs/compensate_sim.toml.

Writes two `targets` tables (../shared/spec/model.md §7), in the tracker (world)
frame of jobs/robots/irb1600_145.toml:

* grid.parquet: a 5 x 5 x 5 grid over the calibration cube (centre (900, 0, 900)
  mm, edge 500 mm, robot base frame), tool pointing straight down, no load;
* drilling.parquet: a 5 x 4 pattern of holes on a vertical plate at x = 1100 mm
  (base frame), tool axis along +x into the plate, a 100 N drilling thrust: the
  plate pushes the tool back along its axis, fz = -100 N in tool axes.

The world frame is the robot file's nominal [world]: world <- base =
Rot(x, -180 deg) . Trans(1326, 1362, -1476), so p_world = R (p_base + t).

    python3 jobs/targets/make_targets.py     # rewrites both files
"""
import pathlib

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

HERE = pathlib.Path(__file__).parent
R_WORLD = np.diag([1.0, -1.0, -1.0])  # Rot(x, -180 deg)
T_WORLD = np.array([1326.0, 1362.0, -1476.0])


def to_world(p_base):
    return R_WORLD @ (np.asarray(p_base, dtype=float) + T_WORLD)


def euler_xyz_deg(r):
    """rx, ry, rz (deg) with r = Rot(x, rx) Rot(y, ry) Rot(z, rz)."""
    ry = np.arcsin(np.clip(r[0, 2], -1.0, 1.0))
    rx = np.arctan2(-r[1, 2], r[2, 2])
    rz = np.arctan2(-r[0, 1], r[0, 0])
    return np.degrees([rx, ry, rz])


def rot_x(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def write(name, points_base, base_from_tool, wrench):
    rows = {k: [] for k in ["target_id", "x_mm", "y_mm", "z_mm", "rx_deg", "ry_deg", "rz_deg",
                            "fx_n", "fy_n", "fz_n", "mx_nm", "my_nm", "mz_nm"]}
    world_from_tool = R_WORLD @ base_from_tool
    rx, ry, rz = euler_xyz_deg(world_from_tool)
    for i, p in enumerate(points_base):
        x, y, z = to_world(p)
        rows["target_id"].append(i + 1)
        for key, value in zip(["x_mm", "y_mm", "z_mm", "rx_deg", "ry_deg", "rz_deg"], [x, y, z, rx, ry, rz]):
            rows[key].append(float(value))
        for key, value in zip(["fx_n", "fy_n", "fz_n", "mx_nm", "my_nm", "mz_nm"], wrench):
            rows[key].append(float(value))
    schema = pa.schema([("target_id", pa.int64())] + [(k, pa.float64()) for k in list(rows)[1:]])
    pq.write_table(pa.table(rows, schema=schema), HERE / name)


def main():
    axis = np.linspace(-250.0, 250.0, 5)
    grid = [[900.0 + dx, dy, 900.0 + dz] for dx in axis for dy in axis for dz in axis]
    write("grid.parquet", grid, rot_x(np.pi), [0.0] * 6)
    holes = [[1100.0, y, z] for z in np.linspace(750.0, 1050.0, 4) for y in np.linspace(-200.0, 200.0, 5)]
    write("drilling.parquet", holes, rot_y(np.pi / 2), [0.0, 0.0, -100.0, 0.0, 0.0, 0.0])


if __name__ == "__main__":
    main()
