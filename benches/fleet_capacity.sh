#!/usr/bin/env bash
# Robot-nights per hour with `egcal fleet run` (docs/fleet.md).
#
#   benches/fleet_capacity.sh ROWS_PER_NIGHT ROBOTS [JOBS] [slurm]
#
# Simulates ROBOTS robots' logs (a window of W = max(14, ROWS_PER_NIGHT / 10000)
# days, as simulate_logs writes at most 10 000 rows a day, plus one; about
# ROWS_PER_NIGHT / W rows a day drawn from a pool of the paper's conf-wrenches
# large enough for a day), puts each robot's commissioning calibration in
# service, then times one night of jobs/nightly.toml (its `last` set to the W
# days for every robot) for all of them with `egcal fleet run --jobs JOBS`.
# EGCAL names the binary (default target/release/egcal). Prints one line:
# rows per night, robots, jobs, seconds, robot-nights per hour.
#
# With `slurm` (a cluster running, SLURM_CONF set: `.ci/services.sh`), the same
# night is then submitted as an array of one night per task, one task at a time;
# every night is already decided, so each task only starts, reads the manifest
# and skips: the wall time per task is Slurm's per-task overhead (scheduling,
# launch, egcal's start).
set -euo pipefail
cd "$(dirname "$0")/.."
egcal=$(realpath "${EGCAL:-target/release/egcal}")
rows=${1:?rows per night}
robots=${2:?robots}
jobs=${3:-1}
window=$(((rows + 9999) / 10000))
[ "$window" -ge 14 ] || window=14
per_day=$(((rows + window - 1) / window))
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
first_day = "$(date -u -d "2026-11-20 - $window days" +%F)"
days = $((window + 1))
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
{
  cat <<TOML
[fleet]
name = "capacity"
job = "nightly.toml"
robots_from_logs = "out/make_logs"
TOML
  for i in $(seq 1 "$robots"); do
    printf '[robots.robot_%s.stages.logs]\nlast = "%sd"\n' "$i" "$window"
  done
} >"$dir/fleet.toml"
(cd "$dir" && "$egcal" -q run make_logs.toml >/dev/null)
for i in $(seq 1 "$robots"); do
  (cd "$dir" && "$egcal" publish "out/make_logs/commission_$i/parameters.parquet" \
    --to "calibration/robot_$i" --date 2026-01-01 >/dev/null)
done
start=$(date +%s.%N)
code=0
(cd "$dir" && "$egcal" -q fleet run fleet.toml --run-date 2026-11-20 --jobs "$jobs" >"$dir/summary.txt") || code=$?
end=$(date +%s.%N)
if [ "$code" -ne 0 ] && [ "$code" -ne 10 ] && [ "$code" -ne 11 ]; then
  cat "$dir/summary.txt" >&2
  exit "$code"
fi
awk -v s="$start" -v e="$end" -v n="$robots" -v r="$((per_day * window))" -v j="$jobs" 'BEGIN {
  t = e - s; printf "rows per night %d, robots %d, jobs %d: %.1f s, %.0f robot-nights per hour\n", r, n, j, t, n * 3600 / t }'
if [ "${4:-}" = slurm ]; then
  sed -i '1i [slurm]\nnights_per_task = 1' "$dir/fleet.toml"
  start=$(date +%s.%N)
  code=0
  (cd "$dir" && "$egcal" -q fleet submit fleet.toml --run-date 2026-11-20 --max-parallel 1 --wait >"$dir/slurm.txt") || code=$?
  end=$(date +%s.%N)
  if [ "$code" -ne 0 ] && [ "$code" -ne 10 ] && [ "$code" -ne 11 ]; then
    cat "$dir/slurm.txt" >&2
    exit "$code"
  fi
  awk -v s="$start" -v e="$end" -v n="$robots" 'BEGIN {
    t = e - s; printf "slurm: %d empty tasks one at a time in %.1f s: %.2f s per task\n", n, t, t / n }'
fi
