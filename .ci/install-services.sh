#!/usr/bin/env bash
# Installs the test-only servers that .ci/services.sh starts, when missing:
#   - Slurm and munge from Debian packages (slurm-wlm, munge); needs root;
#   - Garage v2.5.0 (S3) with `cargo install`, into ${CARGO_HOME:-~/.cargo}/bin.
# Prints how long each installation took.
set -euo pipefail

GARAGE_VERSION=2.5.0

log() { echo "install-services: $*" >&2; }

# Milliseconds since the epoch.
now_ms() {
  local t=${EPOCHREALTIME/[.,]/}
  echo $((t / 1000))
}

took() {
  local ms=$(($(now_ms) - $1))
  log "$2 took $((ms / 1000)).$(printf %01d $((ms / 100 % 10)))s"
}

need=()
for p in sbatch slurmctld slurmd; do
  if ! command -v "$p" >/dev/null 2>&1; then
    need+=(slurm-wlm)
    break
  fi
done
command -v munged >/dev/null 2>&1 || need+=(munge)
if [ ${#need[@]} -gt 0 ]; then
  t0=$(now_ms)
  log "installing ${need[*]} with apt-get"
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
  took "$t0" "apt-get install ${need[*]}"
else
  log "slurm and munge already installed"
fi

cargo_bin="${CARGO_HOME:-$HOME/.cargo}/bin"
if command -v garage >/dev/null 2>&1 || [ -x "$cargo_bin/garage" ]; then
  log "garage already installed"
else
  t0=$(now_ms)
  log "installing garage $GARAGE_VERSION with cargo install (this takes a while)"
  cargo install garage --version "$GARAGE_VERSION" --locked \
    --no-default-features --features bundled-libs,sqlite
  took "$t0" "cargo install garage"
fi
