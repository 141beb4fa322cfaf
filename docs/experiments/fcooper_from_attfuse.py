"""Is F-Cooper's gap to AttFuse its max fusion or its training? F-Cooper (maxout where AttFuse
attends, no parameters of its own) trained from the shipped AttFuse weights, as Where2comm and
V2X-ViT were, with their first chunk (1,000 steps at one-cycle 2.5e-4; train.yaml's ``fcooper``
block otherwise: its seed, data and views), where the shipped F-Cooper is a sequence from the
single-agent weights (4,000 steps). Writes OUT/fcooper.pt (and its card); resumable (OUT/run/last.pt).

    .venv/bin/python docs/experiments/fcooper_from_attfuse.py OUT
    asg evaluate --fusion fcooper --weights OUT/fcooper.pt --set normal-val --json    (both yardsticks)
"""
from __future__ import annotations

import shutil
import sys
from dataclasses import replace
from pathlib import Path

from asg.perception.weights_io import WEIGHTS_DIR
from asg.training.config import load_train_config
from asg.training.train import train

STEPS = 1000  # Where2comm's chunk from AttFuse (train.yaml's where2comm block)
LR = 0.00025


def main(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    resuming = (out / "run" / "last.pt").is_file()
    if not resuming:  # the start: the shipped AttFuse and its card, where init_from reads them
        for name in ("attfuse.pt", "attfuse.json"):
            shutil.copy(WEIGHTS_DIR / name, out / name)
    chunk = replace(load_train_config("fcooper"), steps=STEPS, lr=LR)
    train("fcooper", out_dir=out / "run", train_config=chunk, weights_dir=out,
          init_from=None if resuming else "attfuse", validate=False, threads=1)


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    main(Path(sys.argv[1]))
