"""Training and held-out loss curves of one fine-tuning chunk (the `harden` block's recipe): every
EVERY steps, the mean detection loss (classification, box and direction terms, without
augmentation, as the ego sees each frame) over held-out frames of normal-val and
challenging-attfuse-val, beside the training loss of the last EVERY steps (which also holds the
IoU and refinement branches' terms: compare its trend, not its level). Trains on the round's scenes of a finished `asg harden` run (ROUND_DIR/scenes)
mixed as the run did, from the shipped AttFuse weights; writes nothing but OUT.json.

usage: .venv/bin/python docs/experiments/finetune_curves.py ROUND_DIR OUT.json [EVERY] [HELD_OUT]
  (e.g. runs/harden/attfuse/round-1 curves.json 50 40: the first 40 frames of each held-out set)
"""
import itertools
import json
import sys
from pathlib import Path

import numpy as np
import torch

from asg.datasets import scenes_of
from asg.perception.config import load_detector_config
from asg.perception.data import make_sample
from asg.workflows.finetune import mixed_sources
from asg.perception.model import AttFuse
from asg.perception.feeds import AGENT_CLOUDS
from asg.training.loop import BRANCH_KEYS, Batches, make_scheduler, train_step
from asg.perception.weights_io import WEIGHTS_DIR, load_state
from asg.scene import load_scene
from asg.sensors import load_lidar_spec
from asg.workflows.harden import load_harden_config


def held_out_loss(model, items, anchors, cfg) -> float:
    """Mean loss over ``items`` (no augmentation: a fixed rng makes no difference as none is drawn)."""
    from asg.perception.boxes import assign_targets
    from asg.perception.head import detection_loss

    model.eval()
    losses = []
    with torch.no_grad():
        for clouds, boxes in items:
            lab, res, d = assign_targets(anchors, boxes, cfg)
            cls, box, dd, _ = model([[torch.from_numpy(c) for c in clouds]])
            loss = detection_loss(cls, box, dd, torch.from_numpy(lab[None]), torch.from_numpy(res[None]),
                                  torch.from_numpy(d[None]))
            losses.append(float(loss["total"]))
    model.train()
    return float(np.mean(losses))


def main(round_dir: str, out: str, every: int = 50, held: int = 40) -> None:
    torch.set_num_threads(2)
    harden_cfg = load_harden_config()
    hcfg = harden_cfg.asg  # asg's trainer's chunk a round
    cfg = load_detector_config()
    spec = load_lidar_spec("v2xp")
    torch.manual_seed(hcfg.seed)
    rng = np.random.default_rng([hcfg.seed, 0])
    model = AttFuse(cfg)
    load_state(model, WEIGHTS_DIR / "attfuse.pt", allow_missing=BRANCH_KEYS)
    opt = torch.optim.Adam(model.parameters(), lr=hcfg.lr, weight_decay=hcfg.weight_decay)
    sched = make_scheduler(opt, hcfg, hcfg.steps)
    scenes = [load_scene(p) for p in sorted((Path(round_dir) / "scenes").glob("*.yaml"))]
    batches = mixed_sources("attfuse", {"round": scenes}, hcfg, harden_cfg.mix_with, print)
    anchors = model.anchors.numpy()
    held_out = {name: Batches(AGENT_CLOUDS, [make_sample(s, spec) for s in itertools.islice(scenes_of(name), held)]).items
                for name in ("normal-val", "challenging-attfuse-val")}
    curve = [{"step": 0, **{n: held_out_loss(model, it, anchors, cfg) for n, it in held_out.items()}}]
    train_losses = []
    for step in range(1, hcfg.steps + 1):
        loss = train_step(model, opt, sched, batches.draw(rng, hcfg.batch_size, anchors, cfg))
        train_losses.append(float(loss["total"].detach()))
        if step % every == 0:
            row = {"step": step, "train": float(np.mean(train_losses[-every:])),
                   **{n: held_out_loss(model, it, anchors, cfg) for n, it in held_out.items()}}
            curve.append(row)
            print(json.dumps(row))
    Path(out).write_text(json.dumps({"recipe": "harden block", "held_out_frames": held, "curve": curve}, indent=1))


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], *(int(a) for a in sys.argv[3:]))
