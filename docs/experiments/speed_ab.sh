#!/bin/bash
# The speed A/B: docs/experiments/speed_ab.py (or SCRIPT, e.g. bo_scene_ab.py) on commit OLD and on
# this tree, alternating, ROUNDS rounds, one JSON line each into OUT (from the repository root,
# after make setup). The script is this tree's, run with PYTHONPATH set to each tree.
# usage: docs/experiments/speed_ab.sh OLD_COMMIT ROUNDS OUT.jsonl [SCRIPT [ARGS...]]
# (ARGS after the scene count, e.g. speed_ab.py's --scenes-only)
set -euo pipefail
old=$1; rounds=$2; out=$(realpath -m "$3"); script=$(realpath "${4:-docs/experiments/speed_ab.py}")
here=$(pwd); tree=$(mktemp -d)/old
git worktree add -q "$tree" "$old"
trap 'git worktree remove --force "$tree"' EXIT
: > "$out"
for r in $(seq "$rounds"); do
  for side in "$tree" "$here"; do
    (cd "$side" && PYTHONPATH="$side" "$here/.venv/bin/python" "$script" 5 "${@:5}" >> "$out")
  done
done
