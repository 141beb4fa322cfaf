"""``asg scenes extract``: every N-th frame of a traffic log as a scene yaml."""
from __future__ import annotations

import argparse
from dataclasses import asdict
from pathlib import Path

from sumo_scenarios.errors import InputError
from sumo_scenarios.log import NEAR_RADIUS_M

from ..cli_args import COUNT, whole
from ..io.run_record import check_scene_folder, claim_scene_folder
from ..progress import console
from ..scene.from_log import EGO_KINDS, ExtractParams, extract_scenes
from ..scene.scene import save_scene, scene_file


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", type=Path, help="log folder written by 'asg simulate'")
    defaults = ExtractParams()
    p.add_argument("--every", type=COUNT, default=defaults.every,
                   help=f"take every N-th recorded frame (default {defaults.every})")
    p.add_argument("--ego", choices=EGO_KINDS, default=defaults.ego, help=f"ego agent kind (default {defaults.ego})")
    p.add_argument("--radius", type=float, default=defaults.radius_m,
                   help=f"keep agents within this many metres of the ego (default {defaults.radius_m:g})")
    p.add_argument("--min-vehicles", type=whole(0, 10_000, "--min-vehicles"), default=defaults.min_vehicles,
                   help=f"skip frames with fewer vehicles within {NEAR_RADIUS_M:g} m of the ego (default {defaults.min_vehicles})")
    p.add_argument("--collaborators", type=whole(0, 16, "--collaborators"), default=None,
                   help="sensing vehicles drawn at random within communication range of the ego, as the "
                        "data sets draw them (default: the generator's sensing_agents - 1, i.e. 2)")
    p.add_argument("--out", type=Path, required=True, help="folder for the scene yaml files")
    p.add_argument("--force", action="store_true",
                   help="remove the scene files of an --out written with other settings first")


def run(args: argparse.Namespace) -> int:
    from ..generator.config import GenerateConfig

    k = GenerateConfig().sensing_agents - 1 if args.collaborators is None else args.collaborators
    params = ExtractParams(every=args.every, radius_m=args.radius, ego=args.ego, min_vehicles=args.min_vehicles,
                           collaborators=k)
    n, out = 0, Path(args.out)
    settings = {"command": "scenes extract", "log": str(Path(args.log).resolve()), **asdict(params)}
    check_scene_folder(out, settings, args.force)
    for scene in extract_scenes(args.log, params):
        if n == 0:  # the log is readable: the folder becomes this extraction's
            claim_scene_folder(out, settings, args.force)
        save_scene(scene, scene_file(out, scene))
        n += 1
    if n == 0:
        raise InputError(f"{args.log}: no frame had an ego with {args.min_vehicles}+ vehicles within {NEAR_RADIUS_M:g} m; "
                         "lower --min-vehicles")
    console.print(f"wrote {n} scenes to {args.out}")
    return 0
