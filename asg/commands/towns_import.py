"""``asg towns import``: a town of the user's own map, through SUMO's netconvert and polyconvert."""
from __future__ import annotations

import argparse
from pathlib import Path

from sumo_scenarios import towns as towns_mod

from ..progress import console


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("map", type=Path, help="the map file")
    p.add_argument("--name", required=True, help="the town's name (then --town NAME in every command)")
    p.add_argument("--force", action="store_true", help="replace an imported town of that name")


def run(args: argparse.Namespace) -> int:
    from sumo_scenarios.town_import import import_town

    net = import_town(args.map, args.name, force=args.force)
    info = towns_mod.town_info(net)
    console.print(f"imported '{info.name}' into {net.parent}: {info.lane_count} lanes, {info.junctions} junctions, "
                  f"{info.buildings} buildings; use --town {info.name}")
    return 0
