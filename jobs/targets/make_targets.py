"""Targets a user would send to the calibrated robot, for jobs/compensate_sim.toml.

Writes two `targets` tables (../shared/spec/model.md §7), in the tracker (world)
frame of jobs/robots/irb1600_145.toml. The loop measures the achieved tool
(SMR) positions with the tracker, so every target faces the tracker as the
calibration campaign's poses do (tool z towards the tracker, upright roll as
the `poses` stage builds it); that also keeps the targets in the configurations
the calibration measured.

* grid.parquet: a 5 x 5 x 5 grid with a 400 mm edge inside the calibration
  cube (centre (900, 0, 900) mm, robot base frame), no load;
* drilling.parquet: a 5 x 4 pattern of holes, 100 mm apart, on a plate through
  the cube's centre, square to the tracker's line of sight; the tool axis along
  the plate's normal and a 100 N drilling thrust: the plate pushes the tool back
  along its axis, fz = -100 N in tool axes;
* track_grid.parquet, for jobs/track_sim.toml (the same arm on a 3 m linear
  track along the base x axis): a 3 x 3 x 3 grid with a 400 mm edge around the
  calibration cube's centre, with the carriage at 375, 1125, 1875 and 2625 mm
  (between the campaign's stations), each target facing the tracker and giving
  its carriage position in `e1_mm`. The world frame is the base's with the
  carriage at 0, so a point p of the base at the carriage position e is at
  p + (e, 0, 0) in the base at 0 (the carriage nominally only translates).
* positioner_work.parquet, for jobs/positioner_sim.toml (the same arm with the
  tilt-and-turn positioner of jobs/robots/irb1600_145_positioner.toml): a
  3 x 3 pattern of points 100 mm apart, 40 mm above the positioner's table,
  at three table configurations (tilt, turn) = (0, 0), (-20, 45) and
  (20, -90) deg: targets in the frame `positioner` with their `p1_deg`,
  `p2_deg`. The tool points down onto the table (rx = 180 deg in the
  table's frame), as the work does: the tracker, behind the robot, cannot
  see the arm's SMR there.

The world frame is the robot file's nominal [world]: world <- base =
Rot(x, -180 deg) . Trans(1326, 1362, -1476), so p_world = R (p_base + t) and the
tracker (the world origin) is at -t in the base frame.

    python3 jobs/targets/make_targets.py     # rewrites all four files
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


TRACKER_BASE = -T_WORLD
CENTRE_BASE = np.array([900.0, 0.0, 900.0])


def upright_facing(facing):
    """Tool frame (base) with z along `facing` and y as close to base z as it
    can be: the poses stage's upright_tool_frame with no roll."""
    z = facing / np.linalg.norm(facing)
    up = np.array([0.0, 0.0, 1.0])
    y = up - z * (up @ z)
    y /= np.linalg.norm(y)
    return np.column_stack([np.cross(y, z), y, z])


def write(name, points_base, wrench, track_mm=None):
    """`points_base` in the base frame at the carriage positions `track_mm`
    (one per point; none without a track)."""
    rows = {k: [] for k in ["target_id", "x_mm", "y_mm", "z_mm", "rx_deg", "ry_deg", "rz_deg",
                            "fx_n", "fy_n", "fz_n", "mx_nm", "my_nm", "mz_nm"]}
    if track_mm is not None:
        rows["e1_mm"] = []
        points_base = [np.asarray(p) + [e, 0.0, 0.0] for p, e in zip(points_base, track_mm)]
    for i, p in enumerate(points_base):
        base_from_tool = upright_facing(TRACKER_BASE - np.asarray(p))
        rx, ry, rz = euler_xyz_deg(R_WORLD @ base_from_tool)
        x, y, z = to_world(p)
        rows["target_id"].append(i + 1)
        for key, value in zip(["x_mm", "y_mm", "z_mm", "rx_deg", "ry_deg", "rz_deg"], [x, y, z, rx, ry, rz]):
            rows[key].append(float(value))
        for key, value in zip(["fx_n", "fy_n", "fz_n", "mx_nm", "my_nm", "mz_nm"], wrench):
            rows[key].append(float(value))
        if track_mm is not None:
            rows["e1_mm"].append(float(track_mm[i]))
    schema = pa.schema([("target_id", pa.int64())] + [(k, pa.float64()) for k in list(rows)[1:]])
    pq.write_table(pa.table(rows, schema=schema), HERE / name)


def main():
    axis = np.linspace(-200.0, 200.0, 5)
    grid = [CENTRE_BASE + [dx, dy, dz] for dx in axis for dy in axis for dz in axis]
    write("grid.parquet", grid, [0.0] * 6)
    plate = upright_facing(TRACKER_BASE - CENTRE_BASE)
    holes = [CENTRE_BASE + u * plate[:, 0] + v * plate[:, 1]
             for v in np.linspace(-150.0, 150.0, 4) for u in np.linspace(-200.0, 200.0, 5)]
    write("drilling.parquet", holes, [0.0, 0.0, -100.0, 0.0, 0.0, 0.0])
    write_track_grid()
    write_positioner_work()


def write_positioner_work():
    stands = [(0.0, 0.0), (-20.0, 45.0), (20.0, -90.0)]
    pattern = [(u, v) for v in (-100.0, 0.0, 100.0) for u in (-100.0, 0.0, 100.0)]
    rows = {"target_id": [], "x_mm": [], "y_mm": [], "z_mm": [], "rx_deg": [], "ry_deg": [],
            "rz_deg": [], "frame": [], "p1_deg": [], "p2_deg": []}
    for p1, p2 in stands:
        for u, v in pattern:
            rows["target_id"].append(len(rows["target_id"]) + 1)
            for key, value in zip(["x_mm", "y_mm", "z_mm", "rx_deg", "ry_deg", "rz_deg"],
                                  [u, v, 40.0, 180.0, 0.0, 0.0]):
                rows[key].append(value)
            rows["frame"].append("positioner")
            rows["p1_deg"].append(p1)
            rows["p2_deg"].append(p2)
    schema = pa.schema([("target_id", pa.int64())]
                       + [(k, pa.float64()) for k in list(rows)[1:7]]
                       + [("frame", pa.string()), ("p1_deg", pa.float64()), ("p2_deg", pa.float64())])
    pq.write_table(pa.table(rows, schema=schema), HERE / "positioner_work.parquet")


def write_track_grid():
    axis = np.linspace(-200.0, 200.0, 3)
    stations = [375.0, 1125.0, 1875.0, 2625.0]
    cube = [CENTRE_BASE + [dx, dy, dz] for dx in axis for dy in axis for dz in axis]
    points = [p for _ in stations for p in cube]
    track = [e for e in stations for _ in cube]
    write("track_grid.parquet", points, [0.0] * 6, track)


if __name__ == "__main__":
    main()
