"""A training step of AttFuse before and after a change: seconds a step and the loss of the first
steps, from the same weights on the same batches, each version in its own process.

    python docs/experiments/train_step_before_after.py BEFORE_COMMIT [STEPS] [ROUNDS]

BEFORE_COMMIT is checked out into a temporary git worktree; the current checkout is "after".
Both run STEPS (default 20) steps of batch 4 on two threads from the shipped AttFuse weights
(Adam, lr 2.5e-4, the fine-tuning rate) on the same seeded batches of detector-train frames
(built once: `asg dataset build detector-train`), ROUNDS times alternately (default 3). Prints
one JSON line: median seconds a step of each version, their ratio, and the largest relative
difference of the loss per step (first 5 and all STEPS).
"""
from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

# run inside each version's process: only the parts both versions have (model, losses, batches)
STEP_SCRIPT = r'''
import itertools, json, sys, time
import numpy as np, torch
from asg.datasets import iter_frames
from asg.perception.config import load_detector_config
from asg.perception.data import make_sample
from asg.perception.head import detection_loss
from asg.perception.model import AttFuse
try:  # the feeds since they exist
    from asg.perception.feeds import AGENT_CLOUDS
    try:
        from asg.training.loop import BRANCH_KEYS, Batches, branch_losses as _branch_losses
    except ImportError:  # the loop's home before the training wing
        from asg.workflows.train import BRANCH_KEYS, Batches, branch_losses as _branch_losses

    def attfuse_batches(samples, views):
        return Batches(AGENT_CLOUDS, samples, views)
except ImportError:  # the network's name before; asg.perception.train before the workflows layer
    try:
        from asg.workflows.train import BRANCH_KEYS, _Batches, _branch_losses
    except ImportError:
        from asg.perception.train import BRANCH_KEYS, _Batches, _branch_losses

    def attfuse_batches(samples, views):
        return _Batches("attfuse", samples, views)
from asg.perception.weights_io import WEIGHTS_DIR, load_state
from asg.sensors import load_lidar_spec
steps = int(sys.argv[1])
torch.set_num_threads(2)
torch.manual_seed(0)
cfg = load_detector_config()
spec = load_lidar_spec("v2xp")
batches = attfuse_batches([make_sample(s, spec) for s in itertools.islice(iter_frames("detector-train", "train"), 24)], "all")
model = AttFuse(cfg)
load_state(model, WEIGHTS_DIR / "attfuse.pt", allow_missing=BRANCH_KEYS)
model.train()
opt = torch.optim.Adam(model.parameters(), lr=2.5e-4, weight_decay=1e-4)
rng = np.random.default_rng(0)
anchors = model.anchors.numpy()
losses, seconds = [], []
for _ in range(steps):
    t = time.perf_counter()
    clouds, labels, targets, dirs, gt = batches.draw(rng, 4, anchors, cfg)
    cls, box, d, f = model(clouds)
    loss = detection_loss(cls, box, d, labels, targets, dirs)
    loss.update(_branch_losses(model, cls, box, f, labels, gt))
    total = loss["total"] + loss["iou"] + loss["refine"]
    opt.zero_grad()
    total.backward()
    torch.nn.utils.clip_grad_norm_(list(model.parameters()), 10.0)
    opt.step()
    seconds.append(time.perf_counter() - t)
    losses.append(float(total))
print(json.dumps({"losses": losses, "seconds": seconds}))
'''


def run_version(source: Path, steps: int) -> dict:
    env = dict(os.environ, PYTHONPATH=str(source), ASG_DATA=str(ROOT / "runs" / "datasets"))
    out = subprocess.run([sys.executable, "-c", STEP_SCRIPT, str(steps)], capture_output=True, text=True,
                         env=env, cwd=source, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    before_commit = sys.argv[1]
    steps = int(sys.argv[2]) if len(sys.argv) > 2 else 20
    rounds = int(sys.argv[3]) if len(sys.argv) > 3 else 3
    with tempfile.TemporaryDirectory() as tmp:
        before = Path(tmp) / "before"
        subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "-q", "--detach", str(before), before_commit], check=True)
        try:
            runs = {"before": [], "after": []}
            for _ in range(rounds):
                runs["before"].append(run_version(before, steps))
                runs["after"].append(run_version(ROOT, steps))
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(before)], check=True)
    warm = 3  # the first steps pay for the allocator and oneDNN's kernel choice
    sec = {k: statistics.median(s for r in v for s in r["seconds"][warm:]) for k, v in runs.items()}
    b, a = runs["before"][0]["losses"], runs["after"][0]["losses"]
    rel = [abs(x - y) / abs(x) for x, y in zip(b, a)]
    print(json.dumps({"before_commit": before_commit, "steps": steps, "rounds": rounds,
                      "seconds_per_step": {k: round(v, 3) for k, v in sec.items()},
                      "speed_up": round(sec["before"] / sec["after"], 2),
                      "loss_rel_diff_max_first5": float(f"{max(rel[:5]):.2e}"),
                      "loss_rel_diff_max_all": float(f"{max(rel):.2e}"),
                      "losses_before": [round(x, 5) for x in b], "losses_after": [round(x, 5) for x in a]}))


if __name__ == "__main__":
    main()
