#!/usr/bin/env bash
# Issue 27's comparison in one command: equal-error CPU time against Mitsuba 3 on four scenes
# (with its default independent sampler, then with its stratified multijitter) and against Cycles
# on the matte ball, one-thread samples per CPU second, and variance per spp against spp
# (docs/charts/variance_per_spp.svg). Writes the CSVs under docs/ and the printed tables to
# docs/performance_run.md, which docs/PERFORMANCE.md quotes. Not part of CI.
#
#   apt-get install libllvm19                       # Mitsuba's llvm_ad_rgb (else scalar_rgb)
#   python3 -m venv /tmp/venv && /tmp/venv/bin/pip install mitsuba==3.9.1 numpy bpy matplotlib OpenEXR
#   cargo build --release
#   PYTHON=/tmp/venv/bin/python tools/measure_performance.sh     # about 25 min on 2 busy cores
#
# Environment: PYTHON (the venv's python), STRATA (default: $CARGO_TARGET_DIR or target, /release/strata).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
STRATA=${STRATA:-${CARGO_TARGET_DIR:-target}/release/strata}
LOG=docs/performance_run.md
start=$(date +%s)
{
  echo "# strata vs Mitsuba 3 and Cycles: one run of tools/measure_performance.sh"
  echo
  echo '```'
  "$PY" tools/compare_mitsuba.py measure --strata "$STRATA" --csv docs/equal_error_mitsuba.csv
  echo
  "$PY" tools/compare_mitsuba.py measure --strata "$STRATA" --mitsuba-sampler multijitter \
    --csv docs/equal_error_mitsuba_multijitter.csv
  echo
  "$PY" tools/compare_cycles.py measure --strata "$STRATA" --csv docs/equal_error_cycles.csv
  echo
  "$PY" tools/compare_cycles.py throughput --strata "$STRATA"
  echo
  "$PY" tools/variance_per_spp.py --strata "$STRATA" --scene matte --res 96x72 --spp 1,4,16,64,256 \
    --mitsuba independent,multijitter,ldsampler --cycles \
    --csv docs/variance_per_spp.csv --svg docs/charts/variance_per_spp.svg
  echo
  echo "whole run: $(( $(date +%s) - start )) s"
  echo '```'
} | tee "$LOG"
