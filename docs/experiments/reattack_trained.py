"""A new attack on a round's trained weights when its guard kept them averaged with the start:
`asg harden` re-attacks only the weights it keeps (``round-1/reattack``), so a round the guard
averaged has no re-attack of what it trained. This runs the paper's protocol on normal-val against
``RUN/round-1/weights.pt`` (asg.workflows.challenging.build_challenging, the code `asg harden`'s
re-attack runs, on two local workers, resumable) into ``RUN/round-1/reattack-trained``, then
pairs it with the start on its own attack (the run's ``round-0/reattack``, or challenging-FUSION-val
for the shipped weights) by harden_curve.py's code, and writes the pair to
``RUN/round-1/reattack-trained.json``; harden_curve.py pairs the folder too when given the run.
The round needs to have trained (``round-1/trained.json``), not to have finished.

usage: ASG_DATA=... .venv/bin/python docs/experiments/reattack_trained.py RUN WORK_DIR
  (WORK_DIR: harden_curve.py's cache of evaluations)
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

from harden_curve import TRAINED_REATTACK, gaps, measured, own_attack, pct

from asg.datasets import scenes_of
from asg.executors import build_executor
from asg.generator.run import file_digest
from asg.objective.ap import Yardstick
from asg.perception.targets import resolve_target
from asg.workflows.challenging import build_challenging


def main(run_dir: str, work_dir: str) -> None:
    run, work = Path(run_dir), Path(work_dir)
    settings = json.loads((run / "run.json").read_text())
    fusion, start, kind = settings["fusion"], Path(settings["start_weights"]), settings["config"]["data"]
    round_dir = run / "round-1"
    weights = round_dir / "weights.pt"
    if not (weights.is_file() and (round_dir / "trained.json").is_file()):
        raise SystemExit(f"{run}: round 1 has not trained (no round-1/weights.pt and trained.json)")
    if file_digest(start) != settings["start_sha256"]:
        raise SystemExit(f"{start} is not the weights {run} started from (sha256 differs)")
    rows = {r["round"]: r for r in json.loads((run / "card.json").read_text())["rounds"]}
    if 1 in rows and run / rows[1]["weights"] == weights:
        raise SystemExit(f"{run}: the round kept its trained weights; their re-attack is round-1/reattack already")
    out = round_dir / TRAINED_REATTACK
    with build_executor("local", 2) as executor:
        build_challenging(resolve_target(fusion), "val", executor, weights_file=str(weights), out=out)
    own = own_attack(fusion, [run])
    if [s.scene_id for s in scenes_of(own)] != [s.scene_id for s in scenes_of(str(out))]:
        raise SystemExit(f"{own} and {out} were not attacked from the same normal-val scenes in order")
    pair = {"start": measured(fusion, str(start), "own-attack", own, work),
            kind: measured(fusion, str(weights), "reattack", str(out), work)}
    result = {"sets": {"start": own, kind: str(out.relative_to(run))},
              "weights": {"start": settings["start_sha256"], kind: file_digest(weights)},
              "frames": pair["start"][0]["frames"], **gaps(pair, "start")}
    (round_dir / f"{TRAINED_REATTACK}.json").write_text(json.dumps(result, indent=1))
    for y in Yardstick:
        print(f"{y.value}: start on its own attack {100 * result[y.value]['start']:.1f}, "
              f"the trained weights on theirs {pct(result[y.value][kind])}")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        raise SystemExit(__doc__)
    main(*sys.argv[1:])
