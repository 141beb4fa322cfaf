"""Ship the shipped hardened model averaged with the model it was hardened from, as ``attfuse-ft``:
the weights (1 - a) * attfuse + a * attfuse-ft (the guard's cure: asg.perception.weights_io.
average_weights, as weight_average.py wrote them) and their card, from weight_average.py's
measurement of that average (each set before, i.e. attfuse, and after, with the paired gap at
AP@0.7) and the paper's protocol on normal-val against the averaged weights (built here into
WORK_DIR/reattack, resumable). The card keeps what the hardened weights were trained on
(``trained``, ``earlier``, ``command``) and says how they were averaged (``averaged``).

    ASG_DATA=... .venv/bin/python docs/experiments/ship_averaged.py RESULTS.json WORK_DIR A
"""
from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

from asg.datasets import data_root
from asg.executors import build_executor
from asg.generator.run import file_digest
from asg.objective.pooled import REATTACK_PAIR, pair_json, pooled_pair
from asg.perception.targets import resolve_target
from asg.perception.weights_io import WEIGHTS_DIR
from asg.workflows.challenging import build_challenging


def main(results: str, work_dir: str, share: str) -> None:
    measured, work, a = json.loads(Path(results).read_text()), Path(work_dir), float(share)
    card_path, shipped = WEIGHTS_DIR / "attfuse-ft.json", WEIGHTS_DIR / "attfuse-ft.pt"
    card = json.loads(card_path.read_text())
    if card.get("averaged") or file_digest(shipped) != file_digest(Path(measured["hardened"])):
        raise SystemExit("the shipped attfuse-ft is not the hardened model the results measured")
    averaged = work / f"average-{a:g}.pt"
    evaluation = {}
    for row in (r for r in measured["rows"] if r["a"] == a):
        before, after = (json.loads((work / f"{label}-{row['set']}.json").read_text()) for label in ("start", f"a{a:g}"))
        evaluation[row["set"]] = {"before": {k: before[k] for k in ("ap", "ap_per_frame")},
                                  "after": {k: after[k] for k in ("ap", "ap_per_frame")}, "frames": row["frames"],
                                  "gap": {y: {k: row[y][k] for k in ("threshold", "gap", "low", "high", "frames")}
                                          for y in ("global", "per-frame")}}
    with build_executor("local", 2) as executor:
        built = build_challenging(resolve_target("attfuse"), "val", executor, weights_file=str(averaged), out=work / "reattack")
    index = json.loads((built / "index.json").read_text())
    card["averaged"] = {"with": "attfuse.pt", "share_of_hardened": a, "hardened_sha256": file_digest(shipped),
                        "why": "the hardened weights lost AP@0.7 on holdout (a town no model trained on) beyond their "
                               "95 % interval; averaged with attfuse, holdout is level within it (asg harden's "
                               "guard_average does the same for a round its guard would drop)"}
    card["evaluation"] = evaluation
    own = json.loads((data_root() / "challenging-attfuse-val" / "index.json").read_text())  # attfuse's own attack, today
    card["reattack"] = {"frames": index["frames"], "finetuned": pair_json(pooled_pair(index, REATTACK_PAIR)),
                        "original": {"weights": "shipped", **pair_json(pooled_pair(own, REATTACK_PAIR))}}
    card["command"] += f"; then docs/experiments/ship_averaged.py {results} {work_dir} {share} (averaged with attfuse)"
    shutil.copyfile(averaged, shipped)
    card_path.write_text(json.dumps(card, indent=1))
    print(f"shipped {averaged} as attfuse-ft ({file_digest(shipped)[:16]})")


if __name__ == "__main__":
    main(*sys.argv[1:])
