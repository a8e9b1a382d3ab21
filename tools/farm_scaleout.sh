#!/bin/bash
# Scale-out on the single-node Slurm that tools/farm_slurm_up.sh starts (run it first, as root): 3 frames x N
# splits against one process rendering the 3 frames; wall time, and CPU time summed over every task (render and
# merge, measured by /usr/bin/time around each task's strata). Usage: tools/farm_scaleout.sh [RES] [SPP], from
# the repository root, after cargo build --release.
set -e
export SLURM_CONF=${T:-/tmp/farm-slurm-try}/slurm.conf
S=${STRATA:-$PWD/${CARGO_TARGET_DIR:-target}/release/strata}; SCENE=${SCENE:-$PWD/tests/in/farm/shot.usda}
RES=${1:-320x240}; SPP=${2:-64}
W=/tmp/farm-scale; rm -rf $W; mkdir -p $W; cd $W
cpu() { awk '{u += $2 + $3} END {printf "%.1f", u}' "$1"; }
uptime
mkdir -p single; t0=$(date +%s.%N)
/usr/bin/time -o single/cpu.log -f "%e %U %S %M" $S render $SCENE --frames 1-3 --spp $SPP -o single/shot.####.exr --res $RES 2>/dev/null
t1=$(date +%s.%N); echo "one process (2 threads): $(echo "$t1 - $t0" | bc) s wall, $(cpu single/cpu.log) s CPU"
for N in 1 2 4; do
  mkdir -p s$N; cd s$N
  $S farm slurm $SCENE --frames 1-3 --split-samples $N --spp $SPP -o out/shot.####.exr -- --res $RES --threads 1 >/dev/null 2>&1
  # Each task's strata runs under /usr/bin/time: elapsed, user, system seconds and peak RSS (KB), one line a task.
  for job in render merge; do
    sed -i "s|^exec $S|exec /usr/bin/time -a -o $W/s$N/$job.log -f \"%e %U %S %M\" $S|" out/shot.farm/$job.sbatch
  done
  t0=$(date +%s.%N)
  ids=$(sh out/shot.farm/submit.sh)
  # One `render ID` / `merge ID` line per array; 3 frames make one chunk, so one merge array.
  merge=$(echo "$ids" | awk '$1 == "merge" {print $2}')
  until scontrol show job $merge | grep -o 'JobState=[A-Z]*' | sort | uniq -c | grep -q "3 JobState=COMPLETED"; do sleep 0.2; done
  t1=$(date +%s.%N)
  same=yes; for f in 1 2 3; do cmp -s ../single/shot.000$f.png out/shot.000$f.png || same=no; done
  cat render.log merge.log > cpu.log
  echo "slurm 3 frames x $N split(s), tasks --threads 1 on 2 CPUs: $(echo "$t1 - $t0" | bc) s wall, $(cpu cpu.log) s CPU" \
    "over $(wc -l < render.log) render and $(wc -l < merge.log) merge tasks (PNGs equal single: $same)"
  awk '{printf "  a render task: %s s wall, %.1f s CPU, %d MB peak RSS\n", $1, $2 + $3, $4 / 1024}' render.log | head -1
  awk '{printf "  a merge: %s s wall, %.1f s CPU, %d MB peak RSS\n", $1, $2 + $3, $4 / 1024}' merge.log
  cd $W
done
du -sh s4/out/shot.farm/parts | sed 's/^/partials of 3 frames x 4 splits: /'
ls -l single/shot.0001.exr | awk '{print "a single-run EXR: " $5 " B"}'
uptime
