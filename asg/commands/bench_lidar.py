"""``asg bench lidar``: cooperative-frame ray casting against Open3D, and re-rendering after moves."""
from __future__ import annotations

import argparse

from ..benchmarks.defaults import LIDAR_REPEATS
from ..cli_args import COUNT
from ..progress import print_result


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--repeats", type=COUNT, default=LIDAR_REPEATS)
    p.add_argument("--json", action="store_true", help="print JSON only")


def run(args: argparse.Namespace) -> int:
    from ..benchmarks.lidar import bench_lidar

    print_result("asg bench lidar", bench_lidar(repeats=args.repeats), args.json)
    return 0
