"""``asg report``: one self-contained HTML page of a run folder or an ``asg bench paper`` folder."""
from __future__ import annotations

import argparse
from pathlib import Path

from sumo_scenarios.errors import InputError

from ..cli_args import whole
from ..progress import console


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run_dir", type=Path, help="a folder written by 'asg generate' or 'asg bench paper'")
    p.add_argument("--out", type=Path, default=None, help="HTML file to write (default RUN_DIR/report.html)")
    p.add_argument("--scenes", type=whole(0, 10_000, "--scenes"), default=6,
                   help="scenes drawn as bird's-eye views per run (default 6; the tables list all)")


def run(args: argparse.Namespace) -> int:
    from ..report.page import write_report

    if not args.run_dir.is_dir():
        raise InputError(f"{args.run_dir}: not a folder; give a folder written by 'asg generate' or 'asg bench paper'")
    console.print(f"wrote {write_report(args.run_dir, args.out, args.scenes)}")
    return 0
