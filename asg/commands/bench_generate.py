"""``asg bench generate``: seconds per scene of AttFuse + ACS-A + a search (BO), and the search's overhead a suggestion."""
from __future__ import annotations

import argparse

from ..benchmarks.defaults import GENERATE_SCENES
from ..cli_args import COUNT
from ..generator.config import GenerateConfig
from ..progress import print_result
from ..search import SEARCHES


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenes", type=COUNT, default=GENERATE_SCENES)
    p.add_argument("--budget", type=COUNT, default=GenerateConfig.budget)
    p.add_argument("--search", choices=SEARCHES.names(), default=GenerateConfig.search,
                   help="the perturbation search (its settings: configs/search/NAME.yaml)")
    p.add_argument("--json", action="store_true", help="print JSON only")


def run(args: argparse.Namespace) -> int:
    from ..benchmarks.generate import bench_generate

    print_result("asg bench generate", bench_generate(scenes=args.scenes, budget=args.budget, search=args.search), args.json)
    return 0
