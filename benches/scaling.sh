#!/usr/bin/env bash
# Wall time and peak memory against size, whole process (docs/performance.md):
#
#   benches/scaling.sh [OUT.csv]          (default assets/scaling.csv)
#
# * identify: `egcal stage identify`, elasto-geometric model only, least squares
#   (`loss = "least_squares"`: the robust default costs the same on clean rows, but
#   among 10^7 simulated rows it finds two beyond 7σ̂ and fits twice more), on
#   10^4 … 10^7 simulated rows (examples/simulated_measurements.rs);
# * eg_residual: the same with the Gaussian-process residual rung, 10^4 and 10^5 rows;
# * detmax: one fast DETMAX selection, n = 100, over 10^3 … 10^6 random candidates
#   (examples/detmax_scaling.rs; the time is the selection's, the memory the process's).
#
# Then draw it: cargo run --release --example scaling_plot -- assets/scaling.csv assets/scaling.svg
set -euo pipefail
cd "$(dirname "$0")/.."
out=${1:-assets/scaling.csv}
cargo build --release --locked --bin egcal --example simulated_measurements --example detmax_scaling
bin=${CARGO_TARGET_DIR:-target}/release
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
echo "what,size,seconds,max_rss_mb" > "$out"
timed() { # what size command...: one row of the table
  local what=$1 size=$2
  shift 2
  /usr/bin/time -f "%e %M" -o "$dir/time" "$@" > "$dir/stdout"
  read -r seconds rss_kb < "$dir/time"
  echo "$what,$size,$seconds,$((rss_kb / 1024))" | tee -a "$out"
}
printf 'models = ["elastogeometric"]\nloss = "least_squares"\n' > "$dir/eg.toml"
echo 'models = ["eg_residual"]' > "$dir/residual.toml"
for rows in 10000 100000 1000000 10000000; do
  "$bin/examples/simulated_measurements" "$rows" "$dir/m.parquet" > /dev/null
  timed identify "$rows" "$bin/egcal" stage identify --robot jobs/robots/irb1600_145.toml \
    --input measurements="$dir/m.parquet" --settings "$dir/eg.toml" --out "$dir/out"
  if [ "$rows" -le 100000 ]; then
    timed eg_residual "$rows" "$bin/egcal" stage identify --robot jobs/robots/irb1600_145.toml \
      --input measurements="$dir/m.parquet" --settings "$dir/residual.toml" --out "$dir/out"
  fi
  rm -rf "$dir/out"
done
for candidates in 1000 10000 100000 1000000; do
  /usr/bin/time -f "%e %M" -o "$dir/time" "$bin/examples/detmax_scaling" "$candidates" > "$dir/stdout"
  IFS=, read -r _ _ select_s _ < "$dir/stdout"
  read -r _ rss_kb < "$dir/time"
  echo "detmax,$candidates,$select_s,$((rss_kb / 1024))" | tee -a "$out"
done
