#!/bin/sh
# Savings of what a scene does not need (results/accuracy/README.md,
# "Skipping"): each pair runs the same scene with the part skipped (as edpm
# does by default) and with it forced on by a setting that leaves the
# physics unchanged or practically so; three runs each, alternating.
# Usage: tools/skipping.sh EDPM OUT_DIR
set -eu
B=$1; OUT=$2
mkdir -p "$OUT"
HCS="scenarios/hcs-3d.toml --set particles.0.solids_fraction=0.3"
BOX="scenarios/box-walls.toml --t-end 0.2"
run() { # label scene-and-settings...
  label=$1; shift
  for rep in 1 2 3; do
    $B run "$@" --out "$OUT/run" --force 2>/dev/null
    python3 -c "import json;s=json.load(open('$OUT/run/summary.json'));print('$label',$rep,s['cpu_seconds'],s['counters']['pair_collisions'],s['rotation_tracked'])"
  done
}
# Rotation (hcs: smooth; mu = 1e-12 with beta_0 = 0 makes it rough in
# name only: tangential impulses below 1e-12 of the normal ones).
run hcs-rotation-skipped $HCS
run hcs-rotation-tracked $HCS --set 'collisions.default={ e_n = 0.9, beta_0 = 0.0, mu = 1e-12 }'
run box-rotation-skipped $BOX --set 'collisions.default={ e_n = 0.9, beta_0 = -1.0, mu = 0.0 }'
run box-rotation-tracked $BOX --set 'collisions.default={ e_n = 0.9, beta_0 = 0.0, mu = 1e-12 }'
# Gas solver: the same dry scene with a one-way gas at rest added.
run hcs-gas-skipped $HCS
run hcs-gas-one-way-at-rest $HCS --set 'gas.cells=[7,7,7]' --set gas.coupling=one-way
run box-gas-skipped $BOX
run box-gas-one-way-at-rest $BOX --set 'gas.cells=[10,20,10]' --set gas.coupling=one-way
# Collision records: one snapshot at the end turns the per-cell tally on.
run hcs-records-skipped $HCS
run hcs-records-on $HCS --set output.snapshot_interval=0.16
run box-records-skipped $BOX
run box-records-on $BOX --set output.snapshot_interval=0.2
