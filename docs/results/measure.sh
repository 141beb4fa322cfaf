#!/usr/bin/env bash
# Re-measure every figure in docs/results/ (from the project root, after `make demo`):
#   docs/results/measure.sh [OUT]        (OUT default runs/results; about 45 minutes on 2 cores,
#                                        plus the paper's tables: several hours, resumable)
# Each command writes its JSON to OUT/NAME.json; the commit is recorded in OUT/commit.
set -euo pipefail
OUT=${1:-runs/results}
ASG=.venv/bin/asg
mkdir -p "$OUT"
git rev-parse --short HEAD > "$OUT/commit"
for set in normal-val normal holdout; do
  for fusion in none late early attfuse attfuse-ft fcooper; do
    $ASG evaluate --fusion "$fusion" --set "$set" --json > "$OUT/evaluate-$fusion-$set.json"
  done
done
for run in 1 2 3; do
  $ASG bench detect --json > "$OUT/bench-detect-$run.json"
  $ASG bench generate --json > "$OUT/bench-generate-$run.json"
  $ASG bench lidar --json > "$OUT/bench-lidar-$run.json"
  $ASG bench simulate --json > "$OUT/bench-simulate-$run.json"
done
$ASG bench paper --scenes 30 --workers 2 --json --out "$OUT/paper" > "$OUT/bench-paper.json"
# the paper's tables at the paper's sizes (builds the challenging sets once; resumable)
$ASG bench paper --table all --workers 2 --out "$OUT/tables" --json > "$OUT/tables.jsonl"
