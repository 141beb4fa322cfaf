"""``asg dataset build``: simulate and extract a data set of configs/datasets.yaml, or generate a
challenging set (a split of ``normal`` attacked against a shipped model)."""
from __future__ import annotations

import argparse
import json

from sumo_scenarios.errors import InputError

from ..cli_args import COUNT, executor_args, executor_from_args, fusion_arg
from ..objective import ap_text
from ..objective.pooled import REATTACK_PAIR, pooled_pair
from ..progress import console, progress_bar


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("name", help="detector-train, normal, or challenging (with --fusion and --split)")
    fusion_arg(p, "challenging: the shipped model attacked")
    p.add_argument("--split", default=None, help="challenging: train or val (of the normal set)")
    p.add_argument("--count", type=COUNT, default=None, help="challenging: only the first N scenes of the split")
    executor_args(p)


def run(args: argparse.Namespace) -> int:
    from ..datasets import build_dataset, load_spec

    if args.name == "challenging":
        return _build_challenging(args)
    if args.fusion or args.split or args.count:
        raise InputError("--fusion, --split and --count apply to 'asg dataset build challenging' only")
    spec = load_spec(args.name)
    logs = len(spec.towns) * len(spec.densities) * len(spec.seeds)
    with progress_bar() as bar, executor_from_args(args, logs) as executor:
        task = bar.add_task(f"building {args.name}", total=logs)
        out = build_dataset(args.name, lambda done, total: bar.update(task, completed=done), executor)
    console.print(f"wrote {out}")
    return 0


def _build_challenging(args: argparse.Namespace) -> int:
    from ..perception.targets import resolve_target
    from ..workflows.challenging import build_challenging

    if not args.fusion or not args.split:
        raise InputError("give --fusion NAME and --split train|val, e.g. 'asg dataset build challenging "
                         "--fusion attfuse --split val'")
    target = resolve_target(args.fusion)
    with progress_bar() as bar, executor_from_args(args, args.count or 10**6) as executor:
        task = bar.add_task(f"challenging {args.fusion} {args.split}", total=None)
        out = build_challenging(target, args.split, executor, args.count,
                                on_scene=lambda done, total, sid: bar.update(task, completed=done, total=total))
    index = json.loads((out / "index.json").read_text())
    pair = pooled_pair(index, REATTACK_PAIR)
    console.print(f"wrote {out}: {index['frames']} scenes; AP normal {ap_text(pair['normal'].ap)} -> "
                  f"challenging {ap_text(pair['challenging'].ap)}")
    console.print(f"  by the paper's yardstick (per frame): {ap_text(pair['normal'].ap_per_frame)} -> "
                  f"{ap_text(pair['challenging'].ap_per_frame)}")
    return 0
