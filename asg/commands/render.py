"""``asg render``: a scene's cooperative LiDAR frame as a bird's-eye picture (and PCD files)."""
from __future__ import annotations

import argparse
from pathlib import Path

from ..cli_args import SEED, whole
from ..progress import console


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scene", type=Path, help="scene yaml (from 'asg scenes extract')")
    p.add_argument("--out", type=Path, required=True, help="PNG to write")
    p.add_argument("--lidar", default=None, help="LiDAR preset in configs/lidar/ or a yaml path (default: the "
                   "detectors' preset, v2xp)")
    p.add_argument("--collaborators", type=whole(0, 16, "--collaborators"), default=2, help="if the scene names none: this many nearest vehicles")
    p.add_argument("--pcd-dir", type=Path, default=None, help="also write each agent's cloud as PCD and .npy here")
    p.add_argument("--seed", type=SEED, default=0, help="seed of the LiDAR noise (if the preset has any)")


def run(args: argparse.Namespace) -> int:
    from ..io.figures import bev_figure
    from ..io.pcd import write_pcd
    from ..perception.data import points_in_range_boxes
    from ..scene import load_scene
    from ..scene.neighbours import with_nearest_collaborators
    from ..sensors import load_lidar_spec, simulate_frame

    if args.pcd_dir is not None:  # before anything is written: a file in its way is one line
        from sumo_scenarios.checks import output_dir

        output_dir(args.pcd_dir, "--pcd-dir")
    spec = load_lidar_spec(args.lidar) if args.lidar else load_lidar_spec()
    scene = with_nearest_collaborators(load_scene(args.scene), args.collaborators)
    frame = simulate_frame(scene, spec, seed=args.seed)
    bev_figure(scene, frame, args.out, title=f"{scene.scene_id} ({spec.name})")
    if args.pcd_dir is not None:
        import numpy as np

        from sumo_scenarios.atomic import atomic_path
        from sumo_scenarios.checks import inside

        for aid, cloud in frame.clouds.items():
            inside(Path(args.pcd_dir), Path(args.pcd_dir) / aid)
            write_pcd(Path(args.pcd_dir) / f"{aid}.pcd", cloud)
            with atomic_path(Path(args.pcd_dir) / f"{aid}.npy") as tmp:
                np.save(tmp, cloud)
    in_range = points_in_range_boxes(frame)
    mean_pts = float(in_range.mean()) if len(in_range) else 0.0
    console.print(f"wrote {args.out}: agents {', '.join(frame.sensing_ids)}; "
                  f"{sum(len(c) for c in frame.clouds.values())} points; {len(in_range)} vehicles in range, "
                  f"{mean_pts:.1f} points per box on average")
    return 0
