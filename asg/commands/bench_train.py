"""``asg bench train``: seconds a training step of AttFuse takes (batch 4, 2 threads), by phase."""
from __future__ import annotations

import argparse

from ..benchmarks.defaults import TRAIN_STEPS
from ..cli_args import COUNT
from ..progress import print_result


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--steps", type=COUNT, default=TRAIN_STEPS, help="steps timed after 3 warm-up steps (median)")
    p.add_argument("--json", action="store_true", help="print JSON only")


def run(args: argparse.Namespace) -> int:
    from ..benchmarks.train import bench_train

    print_result("asg bench train", bench_train(steps=args.steps), args.json)
    return 0
