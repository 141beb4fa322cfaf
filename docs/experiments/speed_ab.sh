#!/bin/bash
# The speed A/B: docs/experiments/speed_ab.py on commit OLD and on this tree, alternating, ROUNDS
# rounds, one JSON line each into OUT (from the repository root, after make setup).
# usage: docs/experiments/speed_ab.sh OLD_COMMIT ROUNDS OUT.jsonl
set -euo pipefail
old=$1; rounds=$2; out=$(realpath -m "$3"); here=$(pwd); tree=$(mktemp -d)/old
git worktree add -q "$tree" "$old"
trap 'git worktree remove --force "$tree"' EXIT
: > "$out"
for r in $(seq "$rounds"); do
  for side in "$tree" "$here"; do
    (cd "$side" && PYTHONPATH="$side" "$here/.venv/bin/python" "$here/docs/experiments/speed_ab.py" 5 >> "$out")
  done
done
