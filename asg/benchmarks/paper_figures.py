"""The V2XP-ASG paper's published numbers (its Tables I to VI), as fractions, printed beside ours.

AP triples are AP@0.3, AP@0.5, AP@0.7; where the paper gives AP@0.7 only, the others are None.
"""
from __future__ import annotations


def _ap(a3: float | None, a5: float | None, a7: float) -> dict[str, float | None]:
    f = lambda v: None if v is None else round(v / 100.0, 4)
    return {"0.3": f(a3), "0.5": f(a5), "0.7": f(a7)}


#: Table I: each model on Normal and on its own Challenging scenes (train split)
MAIN = {"none": {"normal": _ap(55.4, 54.8, 46.3), "challenging": _ap(31.1, 30.3, 25.1)},
        "late": {"normal": _ap(73.4, 72.6, 62.6), "challenging": _ap(42.0, 40.0, 32.8)},
        "early": {"normal": _ap(80.3, 79.8, 73.5), "challenging": _ap(49.8, 48.3, 43.4)},
        "attfuse": {"normal": _ap(82.4, 81.5, 74.6), "challenging": _ap(46.6, 44.9, 40.5)}}

#: Table II: AttFuse and AttFuse fine-tuned on its challenging train scenes, val sets (AP@0.7)
FINETUNE = {("attfuse", "normal-val"): _ap(None, None, 70.6), ("attfuse-ft", "normal-val"): _ap(None, None, 74.6),
            ("attfuse", "heuristic"): _ap(None, None, 64.9), ("attfuse-ft", "heuristic"): _ap(None, None, 73.1),
            ("attfuse", "challenging-val"): _ap(None, None, 43.9),
            ("attfuse-ft", "challenging-val"): _ap(None, None, 56.3)}

#: Table III: (source the scenes were generated against, target scored), AP@0.7
TRANSFER = {("late", "late"): _ap(None, None, 32.8), ("early", "late"): _ap(None, None, 41.3),
            ("attfuse", "late"): _ap(None, None, 39.8), ("late", "early"): _ap(None, None, 51.8),
            ("early", "early"): _ap(None, None, 43.4), ("attfuse", "early"): _ap(None, None, 49.4),
            ("late", "attfuse"): _ap(None, None, 48.1), ("early", "attfuse"): _ap(None, None, 48.0),
            ("attfuse", "attfuse"): _ap(None, None, 40.5)}

#: Table IV: collaborator selection alone, AP@0.7 (normal, ACS-R, ACS-A)
ACS = {"late": (62.6, 56.1, 53.1), "early": (73.5, 66.7, 64.6), "attfuse": (74.2, 70.1, 66.5)}

#: Table V: component ablation on AttFuse, AP@0.7, keyed (ACS, APS)
ABLATION = {(False, False): 74.6, (True, False): 66.5, (False, True): 44.4, (True, True): 40.5}

#: Table VI: the black-box searches alone (APS without ACS) on AttFuse
BLACKBOX = {"normal": _ap(82.4, 81.5, 74.6), "rs": _ap(68.3, 67.4, 60.4), "ga": _ap(54.8, 52.6, 46.8),
            "bo": _ap(50.9, 49.4, 44.4)}
