"""Would other NMS and box-voting settings recover the vehicles the post-processing loses? The
settings are chosen on scenes no evaluation set holds and no shipped model trained on, then read on
the evaluation sets beside today's.

    .venv/bin/python docs/experiments/postprocess_choice.py MODEL SELECT_DIR COUNT [SET ...]

MODEL: a shipped name or NAME=weights.pt; SELECT_DIR: a data set folder (index.json) to choose on,
whose first COUNT scenes not listed in any EXCLUDE file are taken (set ASG_EXCLUDE to folders of
scene yaml whose ids to skip, separated by ':'); SET: evaluation sets (default normal-val,
heuristic, holdout, challenging-attfuse-val). Each frame is detected once; the candidates handed
to NMS are kept (miss_stages.CandidateTap) and every setting of the grid is applied to them
offline, exactly as ``select_boxes`` would. Prints AP@0.7 (and 0.5) per setting on the selection
scenes, the chosen setting, and today's against the chosen on each SET.
"""
from __future__ import annotations

import itertools
import os
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from asg.datasets import scenes_of
from asg.objective.ap import ap_at
from asg.perception.data import Sample
from asg.perception.nms import select_boxes
from asg.sensors import load_lidar_spec, simulate_frame
from ap_bootstrap import build_models  # this folder's
from miss_stages import CandidateTap  # this folder's

NMS_IOU = (0.05, 0.1, 0.15, 0.2, 0.3)
VOTE_IOU = (0.0, 0.3, 0.5, 0.7)


def candidates_of(detector, scenes) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per scene: (candidate boxes (N, 7), their scores (N,), ground truth (M, 7)), ego frame."""
    spec = load_lidar_spec()
    out = []
    with CandidateTap() as tap:
        for scene in scenes:
            sample = Sample(scene.scene_id, simulate_frame(scene, spec))
            tap.detect(detector, sample.frame)
            out.append((*tap.last(), sample.gt_eval()))
    return out


def ap_with(frames, cfg) -> dict[str, float]:
    """AP of the frames' candidates after ``select_boxes`` with ``cfg``."""
    done = []
    for cand, scores, gt in frames:
        boxes, kept = select_boxes(cand, scores, cfg) if len(cand) else (cand, scores)
        done.append((boxes, kept, gt))
    return ap_at(done)


def selection_scenes(folder: str, count: int):
    skip = set()
    for d in filter(None, os.environ.get("ASG_EXCLUDE", "").split(":")):
        skip |= {p.stem for p in Path(d).glob("*.yaml")}
    return list(itertools.islice((s for s in scenes_of(folder) if s.scene_id not in skip), count))


def main(model: str, select_dir: str, count: str, *sets: str) -> None:
    name, detector = next(iter(build_models([model]).items()))
    today = detector.cfg
    chosen_from = candidates_of(detector, selection_scenes(select_dir, int(count)))
    print(f"{name}: {len(chosen_from)} selection scenes from {select_dir}; AP@0.7 (AP@0.5) in %")
    results = {}
    for nms, vote in itertools.product(NMS_IOU, VOTE_IOU):
        cfg = replace(today, nms_iou=nms, vote_iou=vote)
        ap = ap_with(chosen_from, cfg)
        results[nms, vote] = ap
        mark = " (today)" if (nms, vote) == (today.nms_iou, today.vote_iou) else ""
        print(f"  nms_iou {nms:g}, vote_iou {vote:g}: {100 * ap['0.7']:.2f} ({100 * ap['0.5']:.2f}){mark}")
    best = max(results, key=lambda k: results[k]["0.7"])
    print(f"chosen: nms_iou {best[0]:g}, vote_iou {best[1]:g}")
    chosen = replace(today, nms_iou=best[0], vote_iou=best[1])
    for set_name in sets or ("normal-val", "heuristic", "holdout", "challenging-attfuse-val"):
        frames = candidates_of(detector, scenes_of(set_name))
        a, b = ap_with(frames, today), ap_with(frames, chosen)
        print(f"  {set_name} ({len(frames)}): today {100 * a['0.7']:.2f} -> chosen {100 * b['0.7']:.2f} AP@0.7 "
              f"({100 * a['0.5']:.2f} -> {100 * b['0.5']:.2f} AP@0.5)")


if __name__ == "__main__":
    if len(sys.argv) < 4:
        raise SystemExit(__doc__)
    main(*sys.argv[1:])
