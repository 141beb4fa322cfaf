"""V2X-ViT trained exactly as v2xvit-noisy (train.yaml's ``v2xvit-noisy`` block: the same frames,
noisy links, seed and steps, from the shipped V2X-ViT) but without the delay encoding: with
docs/experiments/v2xvit_delay.py, what the encoding gives apart from training over noisy links.
Writes OUT/v2xvit.pt (and its card); resumable (OUT/run/last.pt).

    .venv/bin/python docs/experiments/v2xvit_noisy_plain.py OUT
    .venv/bin/python docs/experiments/v2xvit_delay.py RESULT.json plain=v2xvit:OUT/v2xvit.pt
"""
from __future__ import annotations

import shutil
import sys
from pathlib import Path

from asg.perception.weights_io import WEIGHTS_DIR
from asg.training.config import load_train_config
from asg.training.train import train


def main(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    resuming = (out / "run" / "last.pt").is_file()
    if not resuming:  # the start: the shipped V2X-ViT and its card, where init_from reads them
        for name in ("v2xvit.pt", "v2xvit.json"):
            shutil.copy(WEIGHTS_DIR / name, out / name)
    train("v2xvit", out_dir=out / "run", train_config=load_train_config("v2xvit-noisy"), weights_dir=out,
          init_from=None if resuming else "v2xvit", validate=False, threads=1)


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    main(Path(sys.argv[1]))
