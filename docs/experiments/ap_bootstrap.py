"""How sure are the AP gaps between the shipped models? Paired bootstrap over frames.

Each frame of SET is rendered once and detected by every model; per frame and threshold, the
detections' true-positive flags are fixed by `asg.objective.ap.match_frame` (the matching is
per frame). A resample draws SET's frames with replacement, the same draw for every model, and
recomputes the global-sort AP from those flags (exactly `average_precision` on the drawn frames).
Prints each model's AP, and for each pair the gap and its 5-95 % interval over the resamples.
usage: .venv/bin/python docs/experiments/ap_bootstrap.py SET [RESAMPLES] [MODEL ...]
  SET: any --set of asg evaluate (normal-val, heuristic, challenging-attfuse-val, a folder of scenes);
  MODEL: a shipped name, or NAME=path/to/weights.pt (AttFuse network; e.g. fine-tuned or hardened
  weights), or NAME=FUSION:path/to/weights.pt (any shipped network, e.g. early:runs/.../weights.pt,
  attfuse-wide:docs/experiments/harden-wide/round-1/weights.pt); default the four shipped models. MODEL@SET scores that model on SET instead (e.g. each
  model on its own re-attack of normal-val: frames are paired by scene id, the scenes every set
  holds). Intervals: 5-95 % and 2.5-97.5 % of the resamples.
"""
import itertools
import sys

import numpy as np

from asg.objective.ap import ap_from_matches, match_frame
from asg.perception.data import Sample
from asg.datasets import scenes_of
from asg.perception import build_detector
from asg.perception.fusion import FUSIONS
from asg.sensors import load_lidar_spec, simulate_frame

MODELS = ("none", "late", "early", "attfuse")
THRESHOLDS = (0.3, 0.5, 0.7)


def build_models(models) -> dict:
    """{label: detector} from shipped names, NAME=weights.pt (AttFuse network) or
    NAME=FUSION:weights.pt (that shipped network: any name of the fusion registry)."""
    out = {}
    for m in models:
        name, _, path = m.partition("=")
        fusion, _, rest = path.partition(":")
        fusion, path = (fusion, rest) if rest and fusion in FUSIONS else ("attfuse", path)
        out[name] = build_detector(fusion, weights_file=path) if path else build_detector(name)
    return out


def per_frame_flags(set_name: str, models=MODELS, build=build_models) -> dict:
    """{(model, threshold): [(scores (N,), tp (N,) bool, n_gt), ...] one entry per frame}, frames
    paired by scene id across the models' sets (``MODEL@SET``: that model on its own set);
    ``build(specs)``: {label: detector} (default: :func:`build_models`)."""
    spec = load_lidar_spec("v2xp")
    by_set: dict[str, list[str]] = {}
    for m in models:
        spec_m, _, own = m.partition("@")
        by_set.setdefault(own or set_name, []).append(spec_m)
    found: dict[tuple, dict] = {}
    for set_, specs in by_set.items():
        detectors = build(specs)
        for scene in scenes_of(set_):
            sample = Sample(scene.scene_id, simulate_frame(scene, spec))
            gt = sample.gt_eval()
            for m, det in detectors.items():
                boxes, scores = det.detect(sample.frame)
                for t in THRESHOLDS:
                    found.setdefault((m, t), {})[scene.scene_id] = (np.asarray(scores, float),
                                                                    match_frame(boxes, scores, gt, t), len(gt))
    common = sorted(set.intersection(*(set(v) for v in found.values())))
    return {key: [frames[i] for i in common] for key, frames in found.items()}


def ap_of(frames: list, idx: np.ndarray) -> float:
    """Global-sort VOC AP over the frames picked by idx (repeats allowed)."""
    picked = [frames[i] for i in idx]
    return ap_from_matches([f[0] for f in picked], [f[1] for f in picked], sum(f[2] for f in picked))


def main(set_name: str, resamples: int, models=MODELS, build=build_models) -> None:
    flags = per_frame_flags(set_name, models, build)
    names = [m.partition("@")[0].partition("=")[0] for m in models]
    n = len(flags[names[0], THRESHOLDS[0]])
    rng = np.random.default_rng(0)
    draws = [rng.integers(0, n, n) for _ in range(resamples)]
    print(f"{set_name}: {n} frames, {resamples} paired resamples; AP in %")
    for t in THRESHOLDS:
        full = {m: 100 * ap_of(flags[m, t], np.arange(n)) for m in names}
        boot = {m: np.array([100 * ap_of(flags[m, t], d) for d in draws]) for m in names}
        print(f"AP@{t:g}: " + ", ".join(f"{m} {full[m]:.2f}" for m in names))
        for a, b in itertools.combinations(names, 2):
            gap = boot[b] - boot[a]
            lo, hi = np.percentile(gap, [5, 95])
            lo95, hi95 = np.percentile(gap, [2.5, 97.5])
            print(f"  {b} - {a}: {full[b] - full[a]:+.2f}  [{lo:+.2f}, {hi:+.2f}] (95 %: [{lo95:+.2f}, {hi95:+.2f}])  "
                  f"{b} ahead in {100 * np.mean(gap > 0):.0f} % of resamples")


if __name__ == "__main__":
    if len(sys.argv) < 2:
        raise SystemExit(__doc__)
    main(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 1000, tuple(sys.argv[3:]) or MODELS)
