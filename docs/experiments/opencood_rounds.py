"""OpenCOOD hardening rounds side by side: `asg harden --fusion opencood:DIR` run with each
`--data` (adversarial, random, normal) from the same folder, read from their output folders.

For every evaluation set: AP@0.7 (%) before (the folder) and after each round by both yardsticks, each
round's gap over the start with its 95 % paired interval (from its card), and the first round's
gap over each other round ("adversarial - random") with its paired interval over the same frames
(asg.objective.paired, 1,000 resamples, seed 0), from the per-frame matches the rounds cached
(OUT/eval/after-SET.matches.npz). Then each round's re-attack on normal-val (the paper's protocol
against the new model; no interval: each attack made its own scenes).

usage: .venv/bin/python docs/experiments/opencood_rounds.py OUT_ADVERSARIAL OUT_CONTROL [...] [--json OUT.json]
"""
import json
import sys
from pathlib import Path

from asg.objective.ap import Yardstick
from asg.objective.paired import load_matches, paired_ap_gap
from asg.objective.pooled import REATTACK_PAIR, PooledAP, pooled_pair

THRESHOLD = 0.7


def pct(gap: dict) -> str:
    return f"{100 * gap['gap']:+.1f} [{100 * gap['low']:+.1f}, {100 * gap['high']:+.1f}]"


def compare(outs: list[Path]) -> dict:
    """{"runs": [{"out", "data", "epochs"}], "sets": {set: {"frames", "before", data: {"after",
    "gap_over_start"}, "first_over": {data: {yardstick: gap}}}}, "reattack": {data: {"normal",
    "challenging"}}}."""
    cards = [json.loads((out / "card.json").read_text()) for out in outs]
    first = cards[0]
    result = {"runs": [{"out": str(o), "data": c["data"], "epochs": c["epochs"]} for o, c in zip(outs, cards)],
              "sets": {}, "reattack": {}}
    for set_name, row in first["evaluation"].items():
        entry = {"frames": row["frames"], "before": row["before"]}
        for card in cards:
            other = card["evaluation"][set_name]
            entry[card["data"]] = {"after": other["after"], "gap_over_start": other["gap"]}
        lead = load_matches(outs[0] / "eval" / f"after-{set_name}.matches.npz")
        entry["first_over"] = {}
        for out, card in zip(outs[1:], cards[1:]):
            rival = load_matches(out / "eval" / f"after-{set_name}.matches.npz")
            entry["first_over"][card["data"]] = {
                y.value: paired_ap_gap(rival, lead, THRESHOLD, method=y).to_dict() for y in Yardstick}
        result["sets"][set_name] = entry
    for card in cards:
        if card.get("reattack"):
            result["reattack"][card["data"]] = card["reattack"]["after"] | {"frames": card["reattack"]["frames"],
                                                                            "start": card["reattack"]["before"]}
    return result


def markdown(result: dict) -> str:
    kinds = [r["data"] for r in result["runs"]]
    head = ["set", "frames", "start"] + [f"{k}: after, gap" for k in kinds] + [f"{kinds[0]} - {k}" for k in kinds[1:]]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for y in Yardstick:
        for set_name, e in result["sets"].items():
            cells = [f"{set_name} ({y.value})", str(e["frames"]),
                     f"{100 * PooledAP.from_json(e['before']).of(y)['0.7']:.1f}"]
            for k in kinds:
                after = PooledAP.from_json(e[k]["after"]).of(y)["0.7"]
                cells.append(f"{100 * after:.1f}, {pct(e[k]['gap_over_start'][y.value])}")
            cells += [pct(e["first_over"][k][y.value]) for k in kinds[1:]]
            lines.append("| " + " | ".join(cells) + " |")
    for k, re in result["reattack"].items():
        start = pooled_pair(re["start"], REATTACK_PAIR)
        after = pooled_pair(re, REATTACK_PAIR)
        lines.append(f"\nre-attack on normal-val ({re['frames']} frames), {k} round: normal -> challenging "
                     f"{after['normal'].text()} -> {after['challenging'].text()} (the start: "
                     f"{start['normal'].text()} -> {start['challenging'].text()}; AP@0.7 ours / per frame)")
    return "\n".join(lines)


if __name__ == "__main__":
    args = sys.argv[1:]
    dump = None
    if "--json" in args:
        i = args.index("--json")
        dump = args[i + 1]
        del args[i:i + 2]
    result = compare([Path(a) for a in args])
    print(markdown(result))
    if dump:
        Path(dump).write_text(json.dumps(result, indent=1))
