"""``asg bench detect``: median inference time of each shipped model with 3 agents."""
from __future__ import annotations

import argparse

from ..cli_args import COUNT
from ..progress import print_result


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--frames", type=COUNT, default=10)
    p.add_argument("--json", action="store_true", help="print JSON only")


def run(args: argparse.Namespace) -> int:
    from ..benchmarks.detect import bench_detect

    print_result("asg bench detect", bench_detect(frames=args.frames), args.json)
    return 0
