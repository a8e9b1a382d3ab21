#!/bin/bash
# Scale-out on the single-node Slurm that tools/farm_slurm_up.sh starts (run it first): 3 frames x N splits
# against one process rendering the 3 frames. Usage: tools/farm_scaleout.sh [RES] [SPP], from the repository root, after cargo build --release
set -e
export SLURM_CONF=${T:-/tmp/farm-slurm-try}/slurm.conf
S=${STRATA:-$PWD/${CARGO_TARGET_DIR:-target}/release/strata}; SCENE=${SCENE:-$PWD/tests/in/farm/shot.usda}
RES=${1:-320x240}; SPP=${2:-64}
W=/tmp/farm-scale; rm -rf $W; mkdir -p $W; cd $W
uptime
mkdir -p single; t0=$(date +%s.%N); $S render $SCENE --frames 1-3 --spp $SPP -o single/shot.####.exr --res $RES 2>/dev/null
t1=$(date +%s.%N); echo "one process (2 threads): $(echo "$t1 - $t0" | bc) s"
for N in 1 2 4; do
  t0=$(date +%s.%N)
  ids=$($S farm slurm $SCENE --frames 1-3 --split-samples $N --spp $SPP -o s$N/shot.####.exr --submit -- --res $RES --threads 1 2>/dev/null)
  # One `render ID` / `merge ID` line per array; 3 frames make one chunk, so one merge array.
  merge=$(echo "$ids" | awk '$1 == "merge" {print $2}')
  until scontrol show job $merge | grep -o 'JobState=[A-Z]*' | sort | uniq -c | grep -q "3 JobState=COMPLETED"; do sleep 0.2; done
  t1=$(date +%s.%N)
  same=yes; for f in 1 2 3; do cmp -s single/shot.000$f.png s$N/shot.000$f.png || same=no; done
  echo "slurm 3 frames x $N split(s), tasks --threads 1 on 2 CPUs: $(echo "$t1 - $t0" | bc) s (PNGs equal single: $same)"
done
uptime
