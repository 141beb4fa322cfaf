"""A new attack on a round's trained weights when its guard kept them averaged with the start:
`asg harden` re-attacks only the weights it keeps (``round-1/reattack``), so a round the guard
averaged has no re-attack of what it trained. This runs the paper's protocol on normal-val against
``RUN/round-1/weights.pt`` (asg.workflows.challenging.build_challenging, the code `asg harden`'s
re-attack runs, on two local workers, resumable) into ``RUN/round-1/reattack-trained``, which
harden_curve.py then pairs with the start's own attack beside the kept weights' re-attack.

usage: ASG_DATA=... .venv/bin/python docs/experiments/reattack_trained.py FUSION RUN
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

from asg.executors import build_executor
from asg.workflows.challenging import build_challenging

#: the folder a run's trained weights are re-attacked into (read by harden_curve.py)
FOLDER = "reattack-trained"


def main(fusion: str, run: str) -> None:
    round_dir = Path(run) / "round-1"
    weights = round_dir / "weights.pt"
    rows = {r["round"]: r for r in json.loads((Path(run) / "card.json").read_text())["rounds"]}
    if 1 not in rows or not weights.is_file():
        raise SystemExit(f"{run}: no finished round 1 with its trained weights (round-1/weights.pt)")
    if Path(run) / rows[1]["weights"] == weights:
        raise SystemExit(f"{run}: the round kept its trained weights; their re-attack is round-1/reattack already")
    with build_executor("local", 2) as executor:
        built = build_challenging(fusion, "val", executor, weights_file=str(weights), out=round_dir / FOLDER)
    print(f"re-attacked {weights}: {json.loads((built / 'index.json').read_text())['frames']} frames in {built}")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        raise SystemExit(__doc__)
    main(*sys.argv[1:])
