#!/bin/bash
# docs/experiments/same_results.py at commit OLD and at this tree; OUT.json says how many digests
# agree and names the ones that differ.
# usage: docs/experiments/same_results_ab.sh OLD_COMMIT OUT.json   (from the repository root, after make setup)
set -euo pipefail
old=$1; out=$2; here=$(pwd); tmp=$(mktemp -d); tree=$tmp/old
git worktree add -q "$tree" "$old"
trap 'git worktree remove --force "$tree"' EXIT
(cd "$tree" && PYTHONPATH="$tree" "$here/.venv/bin/python" "$here/docs/experiments/same_results.py" "$tmp/old.json")
PYTHONPATH="$here" .venv/bin/python docs/experiments/same_results.py "$tmp/new.json"
.venv/bin/python - "$tmp/old.json" "$tmp/new.json" "$old" "$(git rev-parse --short HEAD)$(git diff --quiet || echo +)" > "$out" <<'PY'
import json, sys
old, new = (json.load(open(p)) for p in sys.argv[1:3])
kinds = {k.split()[0] for k in old}
print(json.dumps({"old": sys.argv[3], "new": sys.argv[4],
                  **{kind: {"compared": sum(k.startswith(kind) for k in old),
                            "same": sum(k.startswith(kind) and new.get(k) == v for k, v in old.items())} for kind in sorted(kinds)},
                  "differ": sorted(k for k in old if new.get(k) != old[k])}, indent=1))
PY
cat "$out"
