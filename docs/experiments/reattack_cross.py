"""Why a hardening round gains on the scenes found against its start but not under a new attack:
the start and the round each scored on both attacks of normal-val, the start's own (S, the paper's
challenging set) and the one made against the round (R, what `asg harden`'s re-attack builds), so
that the paper's re-attack gain splits exactly into two paired parts:

    round on R - start on S  =  (round on R - start on R)  +  (start on R - start on S)
    the re-attack gain          the round's gap on the         how much harder R is for the start
                                scenes found against it        than the scenes found against it

beside the round's gain on S (round on S - start on S, harden_curve's "own attack"). Each gap is
AP@0.7 by both yardsticks with its 95 % paired-bootstrap interval (harden_curve's code: 1,000
resamples of the frames, asg.objective.paired), the frames paired by the normal-val scene each
attacked frame came from.

usage: ASG_DATA=... .venv/bin/python docs/experiments/reattack_cross.py WORK_DIR OUT.json BASE [BASE ...]
  BASE: LABEL=FUSION,START,OWN_ATTACK,ROUND,REATTACK  (START and ROUND weights files; OWN_ATTACK the
  start's attack: a folder, or a set name such as challenging-attfuse-val; REATTACK the folder of
  normal-val attacked against ROUND: a run's round-1/reattack, or reattack_trained.py's)
  e.g. shipped=attfuse,asg/perception/weights/attfuse.pt,challenging-attfuse-val,RUN/round-1/weights.pt,RUN/round-1/reattack-trained

Resumable as harden_curve.py is: each (model, set) evaluation is cached in WORK_DIR, OUT.json is
rewritten after each base, and a base already in OUT.json under another label is kept.
"""
from __future__ import annotations

import sys
from pathlib import Path

from harden_curve import THRESHOLD, measure_bases, measured, pct

from asg.datasets import scenes_of
from asg.generator.run import file_digest
from asg.objective.ap import Yardstick
from asg.objective.paired import paired_ap_gap
from asg.objective.pooled import PooledAP

#: {a gap's name: (the model and attack after, the model and attack before)}; "S" the start's own
#: attack, "R" the attack against the round.
GAPS = {"reattack_gain": (("round", "R"), ("start", "S")),
        "own_attack_gain": (("round", "S"), ("start", "S")),
        "round_over_start_on_R": (("round", "R"), ("start", "R")),
        "start_R_over_S": (("start", "R"), ("start", "S"))}


def parse_base(spec: str) -> dict:
    """``LABEL=FUSION,START,OWN_ATTACK,ROUND,REATTACK`` -> {"label", "fusion", "weights": {"start",
    "round"}, "sets": {"S", "R"}}; a missing weights file or attack folder is refused in one line."""
    label, _, rest = spec.partition("=")
    parts = rest.split(",")
    if not label or len(parts) != 5:
        raise SystemExit(f"{spec!r}: give LABEL=FUSION,START,OWN_ATTACK,ROUND,REATTACK")
    fusion, start, own, round_weights, reattack = parts
    for weights in (start, round_weights):
        if not Path(weights).is_file():
            raise SystemExit(f"{spec!r}: no weights file {weights}")
    if not Path(reattack, "index.json").is_file():
        raise SystemExit(f"{spec!r}: {reattack} is not a finished attack (no index.json)")
    return {"label": label, "fusion": fusion, "weights": {"start": start, "round": round_weights},
            "sets": {"S": own, "R": reattack}}


def measure(base: dict, work: Path) -> dict:
    """One base: the four evaluations, then each gap of GAPS by both yardsticks."""
    fusion, weights, sets = base["fusion"], base["weights"], base["sets"]
    ids = {k: [scene.scene_id for scene in scenes_of(s)] for k, s in sets.items()}
    if ids["S"] != ids["R"]:
        raise SystemExit(f"{base['label']}: {sets['S']} and {sets['R']} were not attacked from the same "
                         "normal-val scenes in order")
    names = {"S": "own-attack", "R": "reattack"}
    runs = {(m, a): measured(fusion, weights[m], names[a], sets[a], work) for m in weights for a in sets}
    record = {"label": base["label"], "fusion": fusion, "sets": sets, "frames": len(ids["S"]),
              "weights": {m: {"path": p, "sha256": file_digest(Path(p))} for m, p in weights.items()}}
    for y in Yardstick:
        row = {f"{m}_on_{a}": round(PooledAP.from_json(ap).of(y)[str(THRESHOLD)], 4) for (m, a), (ap, _) in runs.items()}
        for name, (after, before) in GAPS.items():
            row[name] = paired_ap_gap(runs[before][1], runs[after][1], THRESHOLD, method=y).to_dict()
        record[y.value] = row
    return record


def markdown(result: dict) -> str:
    """A row per base and yardstick: the four APs, then the gaps with their intervals, in points."""
    lines = ["| base | yardstick | start on S | start on R | round on S | round on R | "
             + " | ".join(GAPS) + " |", "|" + "---|" * (6 + len(GAPS))]
    for base in result["bases"]:
        for y in Yardstick:
            row = base[y.value]
            aps = [f"{100 * row[k]:.1f}" for k in ("start_on_S", "start_on_R", "round_on_S", "round_on_R")]
            lines.append("| " + " | ".join([base["label"], y.value, *aps, *(pct(row[g]) for g in GAPS)]) + " |")
    return "\n".join(lines)


def main(work_dir: str, out: str, *bases: str) -> None:
    parsed = [parse_base(b) for b in bases]  # every base checked before the first evaluation
    print(markdown(measure_bases(work_dir, out, parsed, measure, {"threshold": THRESHOLD})))

if __name__ == "__main__":
    if len(sys.argv) < 4:
        raise SystemExit(__doc__)
    main(*sys.argv[1:])
