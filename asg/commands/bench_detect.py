"""``asg bench detect``: median inference time of each shipped model with 3 agents."""
from __future__ import annotations

import argparse

from ..benchmarks.defaults import DETECT_FRAMES
from ..cli_args import COUNT
from ..progress import print_result


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--frames", type=COUNT, default=DETECT_FRAMES)
    p.add_argument("--fusion", default=None, metavar="NAME",
                   help="time this detector only (an OpenCOOD model, opencood:DIR, beside OpenCOOD's own pipeline)")
    p.add_argument("--json", action="store_true", help="print JSON only")


def run(args: argparse.Namespace) -> int:
    from ..benchmarks.detect import bench_detect
    from ..perception import check_fusion

    if args.fusion is not None:
        check_fusion(args.fusion)
    print_result("asg bench detect", bench_detect(frames=args.frames, fusion=args.fusion), args.json)
    return 0
