"""Embree's cast alone on the `asg bench lidar` frame (3 sensors, each its candidate rays against
its static view): embreex's one-ray-at-a-time `run` against our packets of 16 (asg/sensors/embree.py),
median of ROUNDS alternating rounds, one thread.
usage: .venv/bin/python docs/experiments/embree_packets.py [ROUNDS]
"""
import statistics
import sys
import time

import numpy as np

from asg.benchmarks.lidar import dense_scene
from asg.scene.neighbours import with_nearest_collaborators
from asg.sensors import load_lidar_spec
from asg.sensors.raycast import EmbreeCaster
from asg.sensors.world import World, xy_distance_to_triangles


def main(rounds: int) -> None:
    spec = load_lidar_spec("v2xp")
    scene = with_nearest_collaborators(dense_scene(), 2)
    world = World(scene, spec)
    jobs = []
    for sid in scene.sensing_ids:
        rays = world._rays(sid)
        own = world._static_index.get(sid, -1)
        facing = np.einsum("ij,ij->i", world._static_v0 - rays.pose.origin, world._static_normals) < 0.0
        near = xy_distance_to_triangles(world._static_tris, rays.pose.origin[:2]) <= spec.range_m + 1.0
        tris = world._static_tris[facing & near & (world._static_owner != own)]
        cand = world._candidates(rays, None if own < 0 else own)
        starts, dirs, far = rays.starts32[cand], rays.dirs32[cand], rays.far32[cand]
        casters = (EmbreeCaster(tris, robust=False, packets=False), EmbreeCaster(tris, robust=False))
        jobs.append((casters, starts, dirs, far))
    times = {"embreex": [], "packets": []}
    for _ in range(rounds):
        for k, name in enumerate(times):
            t = time.perf_counter()
            for casters, s, d, f in jobs:
                casters[k].first_prims(s, d, f)
            times[name].append(time.perf_counter() - t)
    other_triangle = other_distance = 0
    for casters, s, d, f in jobs:
        (t0, p0), (t1, p1) = (c.first_hits(s, d, f) for c in casters)
        other_triangle += int((p0 != p1).sum())
        both = np.isfinite(t0) & np.isfinite(t1)
        other_distance += int((np.isfinite(t0) != np.isfinite(t1)).sum() + (np.abs(t0[both] - t1[both]) > 1e-3).sum())
    rays = sum(len(f) for *_, f in jobs)
    med = {k: statistics.median(v) * 1e3 for k, v in times.items()}
    print(f"{rays} rays: embreex {med['embreex']:.3f} ms, packets {med['packets']:.3f} ms, "
          f"ratio {med['embreex'] / med['packets']:.2f}; another triangle for {other_triangle} rays, "
          f"a distance off by over 1 mm (or hit against miss) for {other_distance}")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 300)
