"""``asg export``: scenes in other tools' formats (``asg.io.export.EXPORT_FORMATS``, docs/export.md)."""
from __future__ import annotations

import argparse
from pathlib import Path

from ..io.export import EXPORT_FORMATS
from ..progress import console, progress_bar
from ..scene.views import Views


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("source", help="a run folder of 'asg generate', a data set (name or folder) or a folder of scene yaml")
    p.add_argument("--format", required=True, choices=EXPORT_FORMATS.names())
    p.add_argument("--out", type=Path, required=True, help="folder to write (nothing is written outside it)")
    p.add_argument("--net", type=Path, default=None,
                   help="openscenario, sumo: the SUMO net of scenes from a net that is not a bundled town")
    p.add_argument("--views", choices=[v.value for v in Views], default=Views.EGO.value,
                   help="ego: each scene as its ego sees it (default); all: and once more as each collaborator "
                        "sees it (SCENE-as-AGENT), a training set for a trainer that learns from its ego's view only")


def run(args: argparse.Namespace) -> int:
    from ..io.export import export

    with progress_bar() as bar:
        task = bar.add_task(f"exporting {args.format}", total=None)
        n = export(args.source, args.format, args.out, net=args.net, progress=lambda i: bar.update(task, completed=i),
                   views=Views(args.views))
    console.print(f"wrote {n} scenes as {args.format} to {args.out}")
    return 0
