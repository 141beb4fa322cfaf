"""Hardening gain against where the model starts: for each base (a start weights file and the
`asg harden` runs made from it: the attack, its random control and, when given, the plain normal
scenes), AP@0.7 of the start on every
fixed set by both yardsticks, each round's gap over the start with its 95 % paired-bootstrap
interval (1,000 resamples of the set's frames, seed 0: asg.objective.paired, the code `asg harden`'s
guard keeps or drops a round by), and the adversarial round over each control on the same
frames; then under a new attack: each round's weights on normal-val attacked against them (the run's
`round-1/reattack`; for a round the guard averaged, its trained weights too when
reattack_trained.py attacked them) against the start on normal-val attacked against it, paired by
the normal-val scene each attacked frame came from. The paper's point (AttFuse 70.6 per frame on its
normal val split before fine-tuning; +4.0 / +8.2 / +12.4 on normal / heuristic / challenging) is
printed beside.

usage: .venv/bin/python docs/experiments/harden_curve.py WORK_DIR OUT.json BASE [BASE ...]
  BASE: LABEL=FUSION,START,ADVERSARIAL_RUN,RANDOM_RUN[,NORMAL_RUN]  (START a weights file; a run
  is an `asg harden --rounds 1 --out` folder (--data random / --data normal for the controls), '-'
  for one not at hand)
  e.g. weak=attfuse,docs/experiments/size-sequence/shipped/attfuse.pt,docs/experiments/harden-weak,docs/experiments/harden-weak-random

A round is measured by the weights it trained (`round-1/weights.pt`) and, when its guard averaged
them with the start, by the averaged weights too ("KIND-averaged"). The fixed sets: normal-val,
heuristic, holdout and challenging-FUSION-val (normal-val attacked against the shipped FUSION model,
the challenging set `asg harden` evaluates every round on); "own-attack" is the start's own attack
(a run's `round-0/reattack`, or challenging-FUSION-val for the shipped weights): the paper's
challenging set for that start. Resumable: each (model, set) evaluation is kept in WORK_DIR
(docs/experiments/weight_average.py's cache), and OUT.json is rewritten after each base; a base
already in OUT.json under another label is kept (so one base can be measured again, or added, alone).
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

from weight_average import scored  # the same cached evaluation (AP and matches in WORK_DIR)

from asg.datasets import scenes_of
from asg.generator.run import file_digest
from asg.objective.ap import Yardstick
from asg.objective.paired import paired_ap_gap
from asg.objective.pooled import PooledAP

THRESHOLD = 0.7
#: a guard-averaged round's trained weights re-attacked, in its round-1 folder (reattack_trained.py)
TRAINED_REATTACK = "reattack-trained"
ROUNDS = ("adversarial", "random", "normal")
#: the rounds the attack's round is paired with, on the same frames
CONTROLS = ROUNDS[1:]
#: the paper's AttFuse fine-tuned on its generated scenes (Table II, AP@0.7 by its per-frame yardstick)
PAPER = {"start": {"normal-val": 70.6, "heuristic": 64.9, "own-attack": 43.9},
         "gain": {"normal-val": 4.0, "heuristic": 8.2, "own-attack": 12.4}}


def built(folder: Path) -> bool:
    return (folder / "index.json").is_file()


def own_attack(fusion: str, runs: list[Path]) -> str:
    """The start's own attack: the round-0 re-attack of the first run given that made one (the
    attack's, though a control's run may hold a copy), else the shipped weights' challenging set."""
    return next((str(r / "round-0" / "reattack") for r in runs if built(r / "round-0" / "reattack")),
                f"challenging-{fusion}-val")


def parse_base(spec: str) -> dict:
    """``LABEL=FUSION,START,ADV_RUN,RANDOM_RUN[,NORMAL_RUN]`` -> {"label", "fusion", "start",
    "own_attack", "models": {name: weights}, "reattacks": {name: folder}}, every file checked."""
    label, _, rest = spec.partition("=")
    parts = rest.split(",")
    if not label or len(parts) not in (4, 5):
        raise SystemExit(f"a base is LABEL=FUSION,START,ADVERSARIAL_RUN,RANDOM_RUN[,NORMAL_RUN], got {spec!r}")
    fusion, start, *runs = parts
    if not Path(start).is_file():
        raise SystemExit(f"{label}: no weights file {start}")
    base = {"label": label, "fusion": fusion, "start": start, "models": {"start": start}, "reattacks": {}}
    for kind, run in zip(ROUNDS, runs):
        if run == "-":
            continue
        card_path = Path(run) / "card.json"
        if not card_path.is_file():
            raise SystemExit(f"{label}: {run} is not an asg harden run folder (no card.json)")
        rows = {r["round"]: r for r in json.loads(card_path.read_text())["rounds"]}
        if 1 not in rows:
            raise SystemExit(f"{label}: {run} has no finished round 1")
        trained = Path(run) / "round-1" / "weights.pt"
        evaluated = Path(run) / rows[1]["weights"]  # the trained weights, or their average with the start
        weights = {kind: trained} | ({f"{kind}-averaged": evaluated} if evaluated != trained else {})
        for name, path in weights.items():
            if not path.is_file():
                raise SystemExit(f"{label}: {path} is missing (restore it, see docs/experiments/removed.json)")
            base["models"][name] = str(path)
        reattack = Path(run) / "round-1" / "reattack"
        if built(reattack):  # the run re-attacked the weights it evaluated last
            base["reattacks"][list(weights)[-1]] = str(reattack)
        if len(weights) > 1 and built(Path(run) / "round-1" / TRAINED_REATTACK):  # reattack_trained.py's
            base["reattacks"][kind] = str(Path(run) / "round-1" / TRAINED_REATTACK)
    base["own_attack"] = own_attack(fusion, [Path(r) for r in runs if r != "-"])
    return base


def sets_of(base: dict) -> dict[str, str]:
    """{the name a set goes by in the results: what asg evaluate's --set takes}."""
    named = ["normal-val", "heuristic", f"challenging-{base['fusion']}-val", "holdout"]
    return {n: n for n in named} | {"own-attack": base["own_attack"]}


def cache_key(set_name: str, set_spec: str) -> str:
    """The cache's name for a set: a named set's own name (the shipped model's own attack is
    challenging-F-val, one evaluation under both names); a folder's carries its index's digest
    (two folders, two keys)."""
    index = Path(set_spec) / "index.json"
    return f"{set_name}-{file_digest(index)[:16]}" if index.is_file() else set_spec


def measured(fusion: str, weights: str, set_name: str, set_spec: str, work: Path) -> tuple[dict, list]:
    return scored(fusion, Path(weights), set_spec, work, file_digest(Path(weights))[:16], key=cache_key(set_name, set_spec))


def rival_of(name: str, control: str) -> str:
    """A control's model of the same kind as an adversarial one (trained or averaged)."""
    return name.replace("adversarial", control)


def pair_name(name: str, control: str) -> str:
    """The results' key of an adversarial model over a control's (``adversarial_over_random``)."""
    return f"{name}_over_{control}"


def gaps(runs: dict[str, tuple[dict, list]], before: str) -> dict:
    """Per yardstick: AP@0.7 of ``before`` and of each other model with its gap over ``before``; and
    each round over each control (the same kind of weights, trained or averaged)."""
    out = {}
    for y in Yardstick:
        row = {before: round(PooledAP.from_json(runs[before][0]).of(y)["0.7"], 4)}
        for name, (ap, matches) in runs.items():
            if name != before:
                row[name] = {"after": round(PooledAP.from_json(ap).of(y)["0.7"], 4),
                             **paired_ap_gap(runs[before][1], matches, THRESHOLD, method=y).to_dict()}
        for name in [n for n in runs if n.startswith("adversarial")]:
            for control in CONTROLS:
                rival = rival_of(name, control)
                if rival in runs:
                    row[pair_name(name, control)] = paired_ap_gap(runs[rival][1], runs[name][1], THRESHOLD, method=y).to_dict()
        out[y.value] = row
    return out


def measure(base: dict, work: Path) -> dict:
    """One base: every fixed set (start and rounds), then the re-attacks."""
    fusion, models = base["fusion"], base["models"]
    record = {"label": base["label"], "fusion": fusion,
              "weights": {k: {"path": p, "sha256": file_digest(Path(p))} for k, p in models.items()}, "sets": {}}
    for set_name, set_spec in sets_of(base).items():
        runs = {k: measured(fusion, p, set_name, set_spec, work) for k, p in models.items()}
        record["sets"][set_name] = {"set": set_spec, "frames": runs["start"][0]["frames"], **gaps(runs, "start")}
        print(f"{base['label']}: {set_name} measured", flush=True)
    if base["reattacks"]:
        runs = {"start": measured(fusion, models["start"], "own-attack", base["own_attack"], work)}
        for name, folder in base["reattacks"].items():
            runs[name] = measured(fusion, models[name], "reattack", folder, work)
        folders = {"start": base["own_attack"]} | base["reattacks"]
        ids = {k: [scene.scene_id for scene in scenes_of(f)] for k, f in folders.items()}
        if all(v == ids["start"] for v in ids.values()):  # each attack made its frame from the same scene
            record["reattack"] = {"sets": folders, "frames": len(ids["start"]), **gaps(runs, "start")}
        else:
            record["reattack"] = {"unpaired": {k: len(v) for k, v in ids.items()}}
    return record


def pct(gap: dict) -> str:
    return f"{100 * gap['gap']:+.1f} [{100 * gap['low']:+.1f}, {100 * gap['high']:+.1f}]"


def table_rows(label: str, set_name: str, row: dict) -> list[str]:
    pairs = {pair_name(n, c): (n, c) for n in row for c in CONTROLS if pair_name(n, c) in row}
    names = [n for n in row if n != "start" and n not in pairs]
    cells = [label, set_name, f"{100 * row['start']:.1f}"] + [f"{n}: {pct(row[n])}" for n in names]
    cells += [f"{n} - {rival_of(n, c)}: {pct(row[key])}" for key, (n, c) in pairs.items()]
    return ["| " + " | ".join(cells) + " |"]


def markdown(result: dict) -> str:
    """The curve as a table: a row per base and set, both yardsticks; the paper's point last."""
    lines = []
    for y in Yardstick:
        lines += [f"\nAP@0.7 ({y.value}): the start, then each model's gain over it [95 % paired interval], in points",
                  "| base | set | start | gains ... |", "|---|---|---|---|"]
        for base in sorted(result["bases"], key=lambda b: b["sets"]["normal-val"][y.value]["start"]):
            for set_name, entry in base["sets"].items():
                lines += table_rows(base["label"], set_name, entry[y.value])
            if "frames" in base.get("reattack", {}):
                lines += table_rows(base["label"], "re-attack (own attack -> each model's)", base["reattack"][y.value])
    lines.append("\nthe paper (per frame): start " + ", ".join(f"{k} {v}" for k, v in PAPER["start"].items())
                 + "; gain " + ", ".join(f"{k} +{v}" for k, v in PAPER["gain"].items()))
    return "\n".join(lines)


def measure_bases(work_dir: str, out: str, parsed: list[dict], measure_one, head: dict) -> dict:
    """``head`` with "bases": each parsed base measured by ``measure_one(base, work)`` in turn, OUT
    rewritten after each; a base already in OUT under a label not given is kept."""
    work = Path(work_dir)
    work.mkdir(parents=True, exist_ok=True)
    kept = json.loads(Path(out).read_text())["bases"] if Path(out).is_file() else []
    labels = {b["label"] for b in parsed}
    result = head | {"bases": [b for b in kept if b["label"] not in labels]}
    for base in parsed:
        result["bases"].append(measure_one(base, work))
        Path(out).parent.mkdir(parents=True, exist_ok=True)
        Path(out).write_text(json.dumps(result, indent=1))
    return result


def main(work_dir: str, out: str, *bases: str) -> None:
    parsed = [parse_base(b) for b in bases]  # every base checked before the first evaluation
    print(markdown(measure_bases(work_dir, out, parsed, measure, {"threshold": THRESHOLD, "paper": PAPER})))


if __name__ == "__main__":
    if len(sys.argv) < 4:
        raise SystemExit(__doc__)
    main(*sys.argv[1:])
