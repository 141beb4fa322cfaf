"""Weight averaging as a cure for what a hardening round loses on an unseen town: the weights
(1 - a) * START + a * HARDENED for each a, scored on each set beside START, with the AP@0.7 gap to
START and its 95 % paired-bootstrap interval by both yardsticks (asg.objective.paired: the code
`asg harden`'s guard keeps or drops a round with). a = 0 is START, a = 1 the hardened weights.

usage: .venv/bin/python docs/experiments/weight_average.py FUSION START.pt HARDENED.pt A[,A...] SET[,SET...] WORK_DIR OUT.json
  e.g. attfuse asg/perception/weights/attfuse.pt asg/perception/weights/attfuse-ft.pt 0.25,0.5,0.75,1
       holdout,normal-val,heuristic,challenging-attfuse-val runs/weight-average docs/experiments/weight-average/results.json

Resumable: each (a, set) evaluation is kept in WORK_DIR (its AP and matches), and OUT.json is
rewritten after each. The averaged weights use START's point stage (both must share it).
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

from asg.evaluation import evaluate
from asg.objective.ap import Yardstick
from asg.objective.paired import load_matches, paired_ap_gap, save_matches
from asg.objective.pooled import PooledAP
from asg.perception.targets import resolve_target
from asg.perception.weights_io import average_weights


def averaged(start: Path, hardened: Path, a: float, work: Path) -> Path:
    """The weights file of (1 - a) * start + a * hardened (asg harden's guard_average does the same)."""
    out = work / f"average-{a:g}.pt"
    return out if out.is_file() else average_weights(start, hardened, a, out)


def scored(fusion: str, weights: Path, set_name: str, work: Path, label: str, key: str | None = None) -> tuple[dict, list]:
    """(the evaluation's pooled AP and frames, its matches), cached in ``work`` under ``label`` and
    ``key`` (default ``set_name``; give one for a set named by its folder)."""
    name = f"{label}-{key or set_name}"
    hit, matches = work / f"{name}.json", work / f"{name}.matches.npz"
    if hit.is_file() and matches.is_file():
        return json.loads(hit.read_text()), load_matches(matches)
    result = evaluate(resolve_target(fusion), set_name, weights_file=str(weights), keep_matches=True)
    record = PooledAP.from_result(result).to_json(4) | {"frames": result["frames"]}
    save_matches(matches, result["matches"])
    hit.write_text(json.dumps(record))
    return record, result["matches"]


def main(fusion: str, start: str, hardened: str, alphas: str, sets: str, work_dir: str, out: str) -> None:
    work = Path(work_dir)
    work.mkdir(parents=True, exist_ok=True)
    result = {"fusion": fusion, "start": start, "hardened": hardened, "rows": []}
    for set_name in sets.split(","):
        base, base_matches = scored(fusion, Path(start), set_name, work, "start")
        for a in (float(x) for x in alphas.split(",")):
            weights = Path(hardened) if a == 1.0 else averaged(Path(start), Path(hardened), a, work)
            record, matches = scored(fusion, weights, set_name, work, f"a{a:g}")
            row = {"set": set_name, "a": a, "frames": record["frames"]}
            for yardstick in Yardstick:
                gap = paired_ap_gap(base_matches, matches, 0.7, method=yardstick)
                before = PooledAP.from_json(base).of(yardstick)["0.7"]
                after = PooledAP.from_json(record).of(yardstick)["0.7"]
                row[yardstick.value] = {"start": before, "averaged": after, **gap.to_dict()}
                print(f"{set_name} a={a:g} {yardstick.value}: AP@0.7 {100 * before:.1f} -> {100 * after:.1f}, "
                      f"gap {100 * gap.gap:+.2f} [{100 * gap.low:+.2f}, {100 * gap.high:+.2f}]", flush=True)
            result["rows"].append(row)
            Path(out).parent.mkdir(parents=True, exist_ok=True)
            Path(out).write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main(*sys.argv[1:])
