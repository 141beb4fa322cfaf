"""Can the detector fit a handful of challenging scenes? An overfitting check for hardening.

Fine-tunes AttFuse from the shipped weights on K adversarial training scenes alone (every
sensing agent's view, no normal frames mixed in) for STEPS steps of batch 4 at peak LR (one-cycle),
with the training augmentation AUG ("FLIP,ROTATE_DEG,SCALE": 1,45,0.05 is train.yaml's default,
0,0,0 none), and reports AP of the ego's view on those K scenes
(the training scenes) and on the next K scenes of the same round (held out), before and after,
beside the mean training loss of the first and last 50 steps. A detector that can learn what the
attack does to it should reach a high AP on its own K training scenes; one that cannot is limited
by its network or its training, not by the data it is fed.

    .venv/bin/python docs/experiments/overfit_check.py ROUND_ATTACK_DIR K STEPS LR AUG OUT.json

ROUND_ATTACK_DIR: a harden round's attack folder (runs/harden/NAME/round-1/attack), whose
scenes/*/final.yaml are the attacked training scenes.
"""
from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

import asg  # noqa: F401  (first: it sets OMP_WAIT_POLICY=PASSIVE before torch loads OpenMP)
import numpy as np
import torch

from asg.objective.ap import ap_from_matches, greedy_match
from asg.perception.config import load_detector_config
from asg.perception.data import Augmentation, make_sample
from asg.perception.fusion import build_network
from asg.perception.weights_io import WEIGHTS_DIR, load_state
from asg.perception import build_detector
from asg.scene import load_scene
from asg.sensors import load_lidar_spec
from asg.training.config import ChunkConfig
from asg.perception.feeds import AGENT_CLOUDS
from asg.training.loop import BRANCH_KEYS, Batches, Steps, make_scheduler, run_steps

THRESHOLDS = (0.3, 0.5, 0.7)


def ap_of(weights: Path, samples: list) -> dict:
    det = build_detector("attfuse", weights_file=str(weights))
    per_t = {t: ([], []) for t in THRESHOLDS}
    n_gt = 0
    for s in samples:
        gt = s.gt_eval()
        n_gt += len(gt)
        boxes, scores = det.detect(s.frame)
        for t in THRESHOLDS:
            per_t[t][0].append(np.asarray(scores, float))
            per_t[t][1].append(greedy_match(boxes, scores, gt, t) >= 0)
    return {f"{t:g}": round(100 * ap_from_matches(sc, tp, n_gt), 2) for t, (sc, tp) in per_t.items()}


def main(attack_dir: str, k: int, steps: int, lr: float, aug: str, out: str) -> None:
    torch.set_num_threads(2)
    spec = load_lidar_spec()
    finals = sorted(Path(attack_dir, "scenes").glob("*/final.yaml"))
    scenes = [load_scene(p) for p in finals[:2 * k]]
    samples = [make_sample(s, spec) for s in scenes]
    train_s, held_s = samples[:k], samples[k:]
    start = WEIGHTS_DIR / "attfuse.pt"
    flip, rotate_deg, scale = aug.split(",")
    augmentation = Augmentation(flip=flip == "1", rotate_deg=float(rotate_deg), scale=float(scale))
    report = {"k": k, "steps": steps, "lr": lr, "augment": aug,
              "before": {"train": ap_of(start, train_s), "held_out": ap_of(start, held_s)}}
    cfg = load_detector_config()
    torch.manual_seed(0)
    model = build_network("attfuse", cfg)
    load_state(model, start, allow_missing=BRANCH_KEYS)
    fcfg = ChunkConfig(steps=steps, lr=lr, schedule="onecycle", pct_start=0.3, checkpoint_every=10 ** 9)
    opt = torch.optim.Adam(model.parameters(), lr=lr, weight_decay=fcfg.weight_decay)
    sched = make_scheduler(opt, fcfg, steps)
    batches = Batches(AGENT_CLOUDS, train_s, "all", augmentation)
    curve: list[tuple[int, float]] = []
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        run_steps(model, opt, sched, batches, np.random.default_rng(0), Steps(0, steps, 4, 10 ** 9), cfg,
                  Path(tmp) / "last.pt", 0.0, {}, lambda m: None, None, lambda s, l: curve.append((s, l)))
        weights = Path(tmp) / "w.pt"
        torch.save(model.state_dict(), weights)
        report["train_s"] = round(time.perf_counter() - t0, 1)
        report["loss_curve"] = curve
        report["after"] = {"train": ap_of(weights, train_s), "held_out": ap_of(weights, held_s)}
    Path(out).write_text(json.dumps(report, indent=1))
    print(json.dumps(report))


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4]), sys.argv[5], sys.argv[6])
