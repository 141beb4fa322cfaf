"""``asg bench simulate``: 10 simulated minutes of a dense town at 0.1 s steps."""
from __future__ import annotations

import argparse

from ..benchmarks.defaults import SIMULATE_MINUTES, SIMULATE_REPEATS, SIMULATE_TOWN
from ..cli_args import COUNT, real
from ..progress import print_result


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--town", default=SIMULATE_TOWN)
    p.add_argument("--minutes", type=real(0.0, 1440.0, "--minutes", lo_open=True), default=SIMULATE_MINUTES)
    p.add_argument("--repeats", type=COUNT, default=SIMULATE_REPEATS)
    p.add_argument("--json", action="store_true", help="print JSON only")


def run(args: argparse.Namespace) -> int:
    from ..benchmarks.simulate import bench_simulate

    print_result("asg bench simulate", bench_simulate(town=args.town, minutes=args.minutes, repeats=args.repeats),
                 args.json)
    return 0
