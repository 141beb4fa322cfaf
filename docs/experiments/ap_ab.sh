#!/bin/bash
# AP of every shipped model on normal-val at commit OLD and at this tree, to every digit.
# usage: docs/experiments/ap_ab.sh OLD_COMMIT OUT.json   (from the repository root, after make setup)
set -euo pipefail
old=$1; out=$2; here=$(pwd); tree=$(mktemp -d)/old
git worktree add -q "$tree" "$old"
trap 'git worktree remove --force "$tree"' EXIT
models=$(.venv/bin/python -c "from asg.perception.fusion import FUSIONS; print(' '.join(FUSIONS.names()))")
{
  echo "{\"old\": \"$old\", \"new\": \"$(git rev-parse --short HEAD)$(git diff --quiet || echo +)\", \"models\": {"
  sep=""
  for m in $models; do
    n=$(cd "$here" && .venv/bin/python -m asg evaluate --fusion "$m" --set normal-val --json --workers 1)
    o=$(cd "$tree" && "$here/.venv/bin/python" -m asg evaluate --fusion "$m" --set normal-val --json --workers 1)
    echo "$sep\"$m\": {\"new\": $n, \"old\": $o}"; sep=","
  done
  echo "}}"
} > "$out"
