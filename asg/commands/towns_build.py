"""``asg towns build``: rebuild the bundled SUMO towns from configs/towns.yaml."""
from __future__ import annotations

import argparse
from pathlib import Path

from sumo_scenarios import towns as towns_mod
from sumo_scenarios.errors import InputError
from sumo_scenarios.paths import nets_dir

from ..progress import console, progress_bar


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", type=Path, default=None, help="towns yaml (default configs/towns.yaml)")
    p.add_argument("--out", type=Path, default=None, help="folder for the nets (default nets/)")
    p.add_argument("--only", nargs="*", default=None, help="build only these towns")


def run(args: argparse.Namespace) -> int:
    cfg = towns_mod.load_towns_config(args.config)
    specs = [s for s in cfg.towns if args.only is None or s.name in args.only]
    if args.only:
        unknown = sorted(set(args.only) - {s.name for s in cfg.towns})
        if unknown:
            raise InputError(f"unknown town '{unknown[0]}' in --only; towns in the config: {', '.join(s.name for s in cfg.towns)}")
    out = args.out or nets_dir()
    with progress_bar() as bar:
        task = bar.add_task("building towns", total=len(specs))
        for spec in specs:
            towns_mod.build_town(spec, out, cfg.buildings)
            bar.advance(task)
    console.print(f"built {len(specs)} towns in {out}")
    return 0
