"""The hardening guard's comparison for any two models on any set: AP@0.7 of each by both
yardsticks, and the gap AFTER - BEFORE with its 95 % paired-bootstrap interval (1,000 resamples of
the set's frames, seed 0: asg.objective.paired, the code `asg harden` keeps or drops a round by).

usage: .venv/bin/python docs/experiments/guard_gap.py SET BEFORE AFTER [OUT.json]
  SET: any --set of asg evaluate (holdout, normal-val, ...); BEFORE, AFTER: a shipped model name
  (attfuse, attfuse-ft, ...), FUSION:path/to/weights.pt (e.g. attfuse:runs/harden/attfuse/round-1/weights.pt)
  or an OpenCOOD model folder, opencood:DIR.
"""
import json
import sys

from asg.evaluation import evaluate
from asg.objective.ap import Yardstick
from asg.objective.paired import paired_ap_gap
from asg.objective.pooled import PooledAP
from asg.perception.targets import resolve_target
from asg.registry import prefixed_kind


def scored(spec: str, set_name: str) -> dict:
    if prefixed_kind(spec):  # a model folder (opencood:DIR) is a target by itself
        return evaluate(resolve_target(spec), set_name, keep_matches=True)
    fusion, _, weights = spec.partition(":")
    return evaluate(resolve_target(fusion), set_name, weights_file=weights or None, keep_matches=True)


def main(set_name: str, before: str, after: str, out: str | None = None) -> None:
    a, b = scored(before, set_name), scored(after, set_name)
    result = {"set": set_name, "frames": a["frames"], "before": before, "after": after}
    for yardstick in Yardstick:
        gap = paired_ap_gap(a["matches"], b["matches"], 0.7, method=yardstick)
        ap_a, ap_b = (PooledAP.from_result(r).of(yardstick)["0.7"] for r in (a, b))
        result[yardstick.value] = {"before": round(ap_a, 4), "after": round(ap_b, 4), **gap.to_dict()}
        print(f"{set_name} ({a['frames']} frames), {yardstick.value}: AP@0.7 {100 * ap_a:.1f} -> "
              f"{100 * ap_b:.1f}, gap {100 * gap.gap:+.2f} [{100 * gap.low:+.2f}, {100 * gap.high:+.2f}]")
    if out:
        with open(out, "w") as f:
            json.dump(result, f, indent=1)


if __name__ == "__main__":
    main(*sys.argv[1:])
