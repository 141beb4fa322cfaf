"""Seconds a training step of an OpenCOOD model takes, under asg's OpenMP wait policy (PASSIVE) and
the spinning one (ACTIVE), and with AttFuse's fusion computing the ego's attention row alone
(asg.perception.opencood.trainer.ego_row_attention): what made asg run OpenCOOD's trainer in a child
process with ``OMP_WAIT_POLICY=ACTIVE`` and that attention (asg/perception/opencood/trainer.py).

    python docs/experiments/opencood_step_time.py MODEL_DIR [--steps 8] [--out FILE.json]

MODEL_DIR is an OpenCOOD model folder whose config names its exported training set (``root_dir``),
e.g. docs/experiments/opencood-attfuse/ copied beside its data. Each configuration runs in its own
process (the wait policy is read when torch loads), one after the other, on the same batches (the
loader's order is seeded): the steps of OpenCOOD's trainer (forward, its loss, backward, Adam),
the first step left out of the median (warm-up). Nothing is written into MODEL_DIR.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

#: (wait policy, ego-row attention) of each configuration, in the order they run
CONFIGS = [("PASSIVE", False), ("ACTIVE", False), ("ACTIVE", True)]


def measure(model_dir: Path, steps: int, ego_row: bool) -> dict:
    """In this process: ``steps`` training steps from MODEL_DIR's latest checkpoint; seconds each."""
    import torch

    from asg.perception.opencood.folder import checkpoint_of
    from asg.perception.opencood.runtime import module, opencood
    from asg.perception.opencood.trainer import ego_row_attention

    opencood()
    if ego_row:
        ego_row_attention()

    config = str(model_dir / "config.yaml")

    class Options:  # what OpenCOOD's load_yaml reads of its command line (no model_dir: this config as given)
        model_dir = ""
        hypes_yaml = config

    hypes = module("hypes_yaml.yaml_utils").load_yaml(config, Options)
    train_utils = module("tools.train_utils")
    dataset = module("data_utils.datasets").build_dataset(hypes, visualize=False, train=True)
    torch.manual_seed(0)
    loader = torch.utils.data.DataLoader(dataset, batch_size=hypes["train_params"]["batch_size"], num_workers=4,
                                         collate_fn=dataset.collate_batch_train, shuffle=True, drop_last=True)
    model = train_utils.create_model(hypes)
    state = torch.load(checkpoint_of(model_dir), map_location="cpu", weights_only=True)
    model.load_state_dict({k: v.float() if v.is_floating_point() else v for k, v in state.items()})
    criterion, optimizer = train_utils.create_loss(hypes), train_utils.setup_optimizer(hypes, model)
    seconds = []
    batches = iter(loader)
    start = time.perf_counter()
    for _ in range(steps):
        batch = next(batches)
        model.train()
        optimizer.zero_grad()
        loss = criterion(model(batch["ego"]), batch["ego"]["label_dict"])
        loss.backward()
        optimizer.step()
        seconds.append(time.perf_counter() - start)
        start = time.perf_counter()
    return {"threads": torch.get_num_threads(), "seconds": [round(s, 2) for s in seconds],
            "median_s": round(statistics.median(seconds[1:]), 2), "last_loss": round(float(loss), 4)}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("model_dir", type=Path)
    p.add_argument("--steps", type=int, default=8)
    p.add_argument("--out", type=Path, default=None)
    p.add_argument("--one", nargs=2, metavar=("POLICY", "EGO_ROW"), help=argparse.SUPPRESS)  # a child's configuration
    args = p.parse_args()
    if args.one:
        print(json.dumps(measure(args.model_dir, args.steps, args.one[1] == "1")))
        return
    rows = []
    for policy, ego_row in CONFIGS:
        env = {**os.environ, "OMP_WAIT_POLICY": policy}
        out = subprocess.run([sys.executable, __file__, str(args.model_dir), "--steps", str(args.steps),
                              "--one", policy, str(int(ego_row))], env=env, capture_output=True, text=True)
        if out.returncode:
            sys.exit(f"{policy}, ego-row attention {ego_row}: exit {out.returncode}\n{out.stderr[-2000:]}")
        row = {"omp_wait_policy": policy, "ego_row_attention": ego_row, **json.loads(out.stdout.splitlines()[-1])}
        rows.append(row)
        print(json.dumps(row), flush=True)
    if args.out:
        args.out.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
