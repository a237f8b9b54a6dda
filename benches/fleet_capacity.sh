#!/usr/bin/env bash
# Robot-nights per hour with `egcal fleet run` (README, "A fleet's nights").
#
#   benches/fleet_capacity.sh ROWS_PER_NIGHT ROBOTS [JOBS]
#
# Simulates ROBOTS robots' logs (15 days, ROWS_PER_NIGHT/14 rows a day, drawn
# from a pool of the paper's conf-wrenches large enough for a day), puts each
# robot's commissioning calibration in service, then times one night of
# jobs/nightly.toml for all of them with `egcal fleet run --jobs JOBS`.
# EGCAL names the binary (default target/release/egcal). Prints one line:
# rows per night, robots, jobs, seconds, robot-nights per hour.
set -euo pipefail
cd "$(dirname "$0")/.."
egcal=$(realpath "${EGCAL:-target/release/egcal}")
rows=${1:?rows per night}
robots=${2:?robots}
jobs=${3:-1}
per_day=$(((rows + 13) / 14))
# The 5×5×5 grid keeps ~100 poses facing the tracker: 1.3 × per_day / 100 wrenches each.
per_config=$((per_day * 13 / 1000 + 7))
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
cp -r jobs/robots jobs/cdpr jobs/truth jobs/nightly.toml "$dir"/
{
  cat <<TOML
[job]
name = "make_logs"
seed = 11
robot = "robots/irb1600_145.toml"
cable_robot = "cdpr/default.toml"

[[stages]]
id = "poses"
kind = "poses"
sampling = "grid"
points_per_axis = 5
centre_mm = [900.0, 0.0, 900.0]
edge_mm = 500.0
acceptance_half_angle_deg = 40.0

[[stages]]
id = "wrenches"
kind = "wrenches"
inputs = { poses = "poses" }
per_config = $per_config
TOML
  for i in $(seq 1 "$robots"); do
    cat <<TOML

[[stages]]
id = "logs_$i"
kind = "simulate_logs"
inputs = { conf_wrenches = "wrenches", truth = "truth/irb1600_paper.parquet" }
robot_id = "robot_$i"
first_day = "2026-11-06"
days = 15
rows_per_day = $per_day
start_hour_utc = 0.0
seconds_per_row = 1.0
offsets = { dtheta3 = 0.0$((i % 10)) }

[[stages]]
id = "commission_$i"
kind = "identify"
inputs = { measurements = "logs_$i.commissioning" }
models = ["kinematic", "elastogeometric"]
TOML
  done
} >"$dir/make_logs.toml"
cat >"$dir/fleet.toml" <<TOML
[fleet]
name = "capacity"
job = "nightly.toml"
robots_from_logs = "out/make_logs"
TOML
(cd "$dir" && "$egcal" -q run make_logs.toml >/dev/null)
for i in $(seq 1 "$robots"); do
  (cd "$dir" && "$egcal" publish "out/make_logs/commission_$i/parameters.parquet" \
    --to "calibration/robot_$i" --date 2026-11-05 >/dev/null)
done
start=$(date +%s.%N)
code=0
(cd "$dir" && "$egcal" -q fleet run fleet.toml --run-date 2026-11-20 --jobs "$jobs" >"$dir/summary.txt") || code=$?
end=$(date +%s.%N)
if [ "$code" -ne 0 ] && [ "$code" -ne 10 ] && [ "$code" -ne 11 ]; then
  cat "$dir/summary.txt" >&2
  exit "$code"
fi
awk -v s="$start" -v e="$end" -v n="$robots" -v r="$((per_day * 14))" -v j="$jobs" 'BEGIN {
  t = e - s; printf "rows per night %d, robots %d, jobs %d: %.1f s, %.0f robot-nights per hour\n", r, n, j, t, n * 3600 / t }'
