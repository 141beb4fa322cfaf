"""Ship a hardening round's weights as ``--fusion attfuse-ft``: copy ``OUT/round-K/weights.pt`` to
asg/perception/weights/attfuse-ft.pt and write its card, attfuse-ft.json, from the harden card
(what the round trained on, each evaluation set after, the re-attack of the round's weights) and
the shipped attfuse measured again here on every set ("before"; the original's own attack is
challenging-attfuse-val): the card's round 0 may be a cached evaluation made by older code.
A run started from the shipped attfuse-ft (a further round: ``asg harden --weights`` its run's
card) keeps the chain: the new card's start is still attfuse.pt, and ``earlier`` lists what the
rounds before trained on and the commands that ran them.

    .venv/bin/python docs/experiments/ship_hardened.py runs/harden/NAME/card.json K "COMMAND"

COMMAND: the asg harden command line that made the run (recorded in the card).
"""
from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

from asg.generator.run import file_digest
from asg.objective.pooled import FINETUNE_PAIR, REATTACK_PAIR, PooledAP, pair_json, pooled_pair
from asg.perception.targets import resolve_target
from asg.perception.weights_io import WEIGHTS_DIR


def main(card_path: str, k: str, command: str) -> None:
    card = json.loads(Path(card_path).read_text())
    rounds = {r["round"]: r for r in card["rounds"]}
    done = rounds[int(k)]
    weights = Path(card_path).parent / done["weights"]
    start = file_digest(Path(card["start"]["weights"]))
    earlier = []
    if start == file_digest(WEIGHTS_DIR / "attfuse-ft.pt"):
        previous = json.loads((WEIGHTS_DIR / "attfuse-ft.json").read_text())
        earlier = previous.get("earlier", []) + [{"trained": previous["trained"], "command": previous["command"]}]
    elif start != file_digest(WEIGHTS_DIR / "attfuse.pt"):
        raise SystemExit("the run did not start from the shipped attfuse or attfuse-ft weights")
    from asg.evaluation import evaluate
    from asg.workflows.harden import noisy_val_set

    evaluation = {}
    for set_name, record in done["evaluation"].items():
        where = str(noisy_val_set()) if set_name == "normal-val-noisy" else set_name
        before, after = PooledAP.from_result(evaluate(resolve_target("attfuse"), where)), PooledAP.from_json(record)
        print(f"{set_name}: attfuse AP@0.7 ours / per frame {before.text()} -> {after.text()}")
        evaluation[set_name] = pair_json(dict(zip(FINETUNE_PAIR, (before, after))), 4) | {"frames": record["frames"]}
    shipped = {
        "weights": "attfuse-ft.pt", "fusion": "attfuse",
        "start": {"weights": "attfuse.pt", "sha256": file_digest(WEIGHTS_DIR / "attfuse.pt")},
        "trained": {"on": (f"asg harden round {k}" + (f" from attfuse-ft ({len(earlier)} earlier round{'s' * (len(earlier) > 1)})" if earlier else "")
                           + f": {done['data']['scenes']} training scenes, {done['data']['kind']}"),
                    "data": done["data"], **done["trained"]},
        **({"earlier": earlier} if earlier else {}),
        "evaluation": evaluation,
        "reattack": {"frames": done["reattack"]["frames"],
                     "finetuned": pair_json(pooled_pair(done["reattack"], REATTACK_PAIR)),
                     "original": {"weights": "shipped", "normal": evaluation["normal-val"]["before"],
                                  "challenging": evaluation["challenging-attfuse-val"]["before"]}},
        "command": command,
    }
    shutil.copyfile(weights, WEIGHTS_DIR / "attfuse-ft.pt")
    (WEIGHTS_DIR / "attfuse-ft.json").write_text(json.dumps(shipped, indent=1))
    print(f"shipped {weights} as attfuse-ft ({file_digest(weights)[:16]})")


if __name__ == "__main__":
    main(*sys.argv[1:])
