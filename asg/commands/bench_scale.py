"""``asg bench scale``: scenes per hour of the generator benchmark on 1 worker (1 thread, all
threads), 2 workers and 2 Ray actors."""
from __future__ import annotations

import argparse
from pathlib import Path

from ..benchmarks.defaults import SCALE_SCENES
from ..cli_args import COUNT
from ..generator.config import GenerateConfig
from ..progress import print_result


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenes", type=COUNT, default=SCALE_SCENES)
    p.add_argument("--budget", type=COUNT, default=GenerateConfig.budget)
    p.add_argument("--out", type=Path, default=Path("runs/bench-scale"))
    p.add_argument("--json", action="store_true", help="print JSON only")


def run(args: argparse.Namespace) -> int:
    from ..benchmarks.scale import bench_scale

    print_result("asg bench scale", bench_scale(Path(args.out), scenes=args.scenes, budget=args.budget), args.json)
    return 0
