"""``asg scenes import``: a recording in OPV2V's layout (a scenario folder, or a split of them) as
scene yaml files, one per timestamp (asg.scene.from_opv2v; docs/recordings.md)."""
from __future__ import annotations

import argparse
from dataclasses import asdict
from pathlib import Path

from ..cli_args import COUNT
from ..io.run_record import check_scene_folder, claim_scene_folder
from ..progress import console, progress_bar
from ..scene.from_opv2v import ImportParams, import_scenes, planned_count
from ..scene.recording import RecordingFormat
from ..scene.scene import save_scene, scene_file


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("source", type=Path, help="a scenario folder (agent folders of TIMESTAMP.yaml and .pcd) or a "
                                             "split of them")
    p.add_argument("--format", choices=[f.value for f in RecordingFormat], default=RecordingFormat.OPV2V.value,
                   help="the recording's layout (opv2v: OPV2V, V2XSet and V2V4Real)")
    p.add_argument("--every", type=COUNT, default=ImportParams.every,
                   help=f"take every N-th timestamp of each scenario (default {ImportParams.every})")
    p.add_argument("--limit", type=COUNT, default=None, help="at most this many scenes in all")
    p.add_argument("--map", type=Path, default=None, metavar="FILE",
                   help="the recording's town (OpenDRIVE .xodr, e.g. the CARLA town's, or a SUMO .net.xml): moves "
                        "obey its lanes (both --plausibility levels); without it, the drivable area is read from "
                        "the scans (--plausibility paper only)")
    p.add_argument("--out", type=Path, required=True, help="folder for the scene yaml files")
    p.add_argument("--force", action="store_true",
                   help="remove the scene files of an --out written with other settings first")


def run(args: argparse.Namespace) -> int:
    """Every scene is read (and refused in one line) before the first file is written."""
    params = ImportParams(every=args.every, limit=args.limit, map=args.map)
    out = Path(args.out)
    settings = {"command": "scenes import", "format": args.format, "source": str(Path(args.source).resolve()),
                **asdict(params), "map": str(args.map.resolve()) if args.map else None}
    check_scene_folder(out, settings, args.force)
    scenes = []
    with progress_bar() as bar:
        task = bar.add_task("reading the recording", total=planned_count(args.source, params))
        for scene in import_scenes(args.source, params):
            scenes.append(scene)
            bar.update(task, completed=len(scenes))
    paths = [scene_file(out, s) for s in scenes]
    claim_scene_folder(out, settings, args.force)
    for scene, path in zip(scenes, paths):
        save_scene(scene, path)
    agents = sum(len(s.sensing_ids) for s in scenes)
    console.print(f"wrote {len(scenes)} scenes ({agents} recorded scans, referenced by path and sha256) to {out}")
    return 0
