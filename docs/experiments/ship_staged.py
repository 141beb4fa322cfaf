"""Ship the hardened AttFuse with a point stage of its own as ``attfuse-ft``, in place of its average
with attfuse: the weights and stage stage_refit.py fitted (``WORK_DIR/LABEL/weights.pt`` and
``weights.stage.pt``) become attfuse-ft.pt and attfuse-ft.stage.pt, and the card is rewritten from
stage_refit.py's measurement: each set before (attfuse as shipped) and after (the weights with
their stage), with the paired gap at AP@0.7 by both yardsticks, and the paper's protocol on
normal-val against them (``WORK_DIR/LABEL/reattack``) beside attfuse's own attack. The card keeps
what the weights were trained on (``trained``, ``earlier``, ``command``), records the stage's fit
(``point_stage``) and what it replaces (``replaces``: the averaged weights' sha256 and why).
Refused unless the weights are the hardened ones the shipped card averaged.

    ASG_DATA=... .venv/bin/python docs/experiments/ship_staged.py WORK_DIR LABEL SET[,SET]
"""
from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

from harden_curve import measured

from asg.datasets import data_root
from asg.generator.run import file_digest
from asg.objective.ap import Yardstick
from asg.objective.paired import paired_ap_gap
from asg.objective.pooled import REATTACK_PAIR, pair_json, pooled_pair
from asg.perception.weights_io import WEIGHTS_DIR, stage_path_of


def main(work_dir: str, label: str, sets: str) -> None:
    work = Path(work_dir)
    weights = work / label / "weights.pt"
    card_path, shipped = WEIGHTS_DIR / "attfuse-ft.json", WEIGHTS_DIR / "attfuse-ft.pt"
    card = json.loads(card_path.read_text())
    if file_digest(weights) != card.get("averaged", {}).get("hardened_sha256"):
        raise SystemExit(f"{weights} are not the hardened weights the shipped attfuse-ft averaged")
    start = str(WEIGHTS_DIR / "attfuse.pt")
    evaluation = {}
    for set_name in sets.split(","):
        (before, before_m), (after, after_m) = (
            measured("attfuse", start, set_name, set_name, work / "cache" / "start"),
            measured("attfuse", str(weights), set_name, set_name, work / "cache" / f"{label}+stage"))
        evaluation[set_name] = {"before": {k: before[k] for k in ("ap", "ap_per_frame")},
                                "after": {k: after[k] for k in ("ap", "ap_per_frame")}, "frames": after["frames"],
                                "gap": {y.value: paired_ap_gap(before_m, after_m, 0.7, method=y).to_dict()
                                        for y in Yardstick}}
    index = json.loads((work / label / "reattack" / "index.json").read_text())
    own = json.loads((data_root() / "challenging-attfuse-val" / "index.json").read_text())  # attfuse's own attack
    averaged = card.pop("averaged")
    card["replaces"] = {"sha256": file_digest(shipped), "averaged": averaged,
                        "why": "with a point stage fitted to them, the hardened weights are level on holdout within "
                               "their interval without averaging, and gain more on every other set and under a new "
                               "attack than their average with attfuse did (docs/results/hardening.md)"}
    card["point_stage"] = json.loads((work / label / "weights.stage.json").read_text()) | {"weights": "attfuse-ft.stage.pt"}
    card["evaluation"] = evaluation
    if "normal-val" in evaluation:
        card["validation"] = {"attfuse-ft": {"set": "normal-val", "frames": evaluation["normal-val"]["frames"],
                                             "ap": evaluation["normal-val"]["after"]["ap"]}}
    card["reattack"] = {"frames": index["frames"], "finetuned": pair_json(pooled_pair(index, REATTACK_PAIR)),
                        "original": {"weights": "shipped", **pair_json(pooled_pair(own, REATTACK_PAIR))}}
    card["command"] = card["command"].split("; then docs/experiments/ship_averaged.py")[0] + (
        f"; then docs/experiments/stage_refit.py (a point stage fitted to the weights) and "
        f"docs/experiments/ship_staged.py {work_dir} {label} {sets}")
    shutil.copyfile(weights, shipped)
    shutil.copyfile(stage_path_of(weights), stage_path_of(shipped))
    card_path.write_text(json.dumps(card, indent=1))
    print(f"shipped {weights} with its point stage as attfuse-ft ({file_digest(shipped)[:16]})")


if __name__ == "__main__":
    if len(sys.argv) != 4:
        raise SystemExit(__doc__)
    main(*sys.argv[1:])
