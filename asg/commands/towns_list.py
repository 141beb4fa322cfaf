"""``asg towns list``: name, area, lanes, junctions and buildings of each town."""
from __future__ import annotations

import argparse
import json
from dataclasses import asdict
from pathlib import Path

from rich.table import Table

from sumo_scenarios import towns as towns_mod
from sumo_scenarios.paths import nets_dir

from ..progress import stdout


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.add_argument("--dir", type=Path, default=None, help="folder of nets (default nets/)")


def run(args: argparse.Namespace) -> int:
    infos = [towns_mod.town_info(p) for p in towns_mod.list_towns(args.dir)]
    if args.json:
        print(json.dumps([asdict(i) for i in infos], indent=2))
        return 0
    table = Table(title="SUMO towns")
    for col in ("name", "area km²", "lanes/edge", "lanes", "junctions", "signals", "buildings", "where"):
        table.add_column(col, justify="left" if col in ("name", "where") else "right", no_wrap=True)
    bundled = nets_dir().resolve()
    for i in infos:
        where = "bundled" if Path(i.net).resolve().parent == bundled else "imported"
        table.add_row(i.name, f"{i.area_km2:.3f}", f"{i.lanes_min}-{i.lanes_max}", str(i.lane_count),
                      str(i.junctions), str(i.traffic_lights), str(i.buildings), where)
    stdout.print(table)
    return 0
