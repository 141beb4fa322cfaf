#!/bin/bash
# The BO scene A/B: docs/experiments/bo_scene_ab.py on commit OLD and on this tree, alternating,
# ROUNDS rounds, one JSON line each into OUT (from the repository root, after make setup).
# usage: docs/experiments/bo_scene_ab.sh OLD_COMMIT ROUNDS OUT.jsonl
set -euo pipefail
old=$1; rounds=$2; out=$(realpath -m "$3"); here=$(pwd); tree=$(mktemp -d)/old
git worktree add -q "$tree" "$old"
trap 'git worktree remove --force "$tree"' EXIT
: > "$out"
for r in $(seq "$rounds"); do
  (cd "$tree" && PYTHONPATH="$tree" "$here/.venv/bin/python" "$here/docs/experiments/bo_scene_ab.py" "$old" >> "$out")
  PYTHONPATH="$here" .venv/bin/python docs/experiments/bo_scene_ab.py "$(git rev-parse --short HEAD)" >> "$out"
done
