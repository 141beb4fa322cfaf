"""A markdown table of `asg harden` cards: one row per round of each card, AP@0.7 (%) on every
evaluation set and under the round's own re-attack, and the training wall time.
usage: .venv/bin/python docs/experiments/harden_table.py runs/harden/attfuse/card.json [CARD ...]
"""
import json
import sys

from asg.objective.pooled import REATTACK_PAIR, PooledAP, pooled_pair


def rows(path: str) -> list[list[str]]:
    card = json.load(open(path))
    out = []
    for row in card["rounds"]:
        ev = {s: PooledAP.from_json(v).ap for s, v in row["evaluation"].items()}  # any card's form
        cells = [card["data"], str(row["round"])] + [f"{100 * ev[s]['0.7']:.1f}" for s in SETS if s in ev]
        re = pooled_pair(row["reattack"], REATTACK_PAIR) if row.get("reattack") else None
        cells.append(f"{100 * re['normal'].ap['0.7']:.1f} -> {100 * re['challenging'].ap['0.7']:.1f}" if re else "")
        trained = row.get("trained") or {}
        cells.append(f"{trained['steps']} steps, {trained['wall_s'] / 60:.1f} min" if trained
                     else ("start weights" if row["round"] == 0 else "not recorded"))
        out.append(cells)
    return out


SETS = ("normal-val", "heuristic", "challenging-attfuse-val", "holdout", "normal-val-noisy")

if __name__ == "__main__":
    print("| data | round | " + " | ".join(SETS) + " | re-attack on normal-val | training |")
    print("|" + "---|" * (len(SETS) + 4))
    for p in sys.argv[1:]:
        for r in rows(p):
            print("| " + " | ".join(r) + " |")
