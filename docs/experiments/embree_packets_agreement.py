"""Do Embree's packets (asg/sensors/embree.py) render what embreex's one-ray-at-a-time cast
renders? Every scene of the given sets with its 2 nearest collaborators, the 3 vehicles nearest
the ego moved at random (up to 2 m, 0.7 rad), every sensor rendered both ways; counts points that
differ by more than 1 cm (or 0.01 intensity).
usage: .venv/bin/python docs/experiments/embree_packets_agreement.py normal normal-val
"""
import sys

import numpy as np

import asg.sensors.embree as embree
from asg.datasets import scenes_of
from asg.scene.neighbours import vehicles_within, with_nearest_collaborators
from asg.sensors import load_lidar_spec
from asg.sensors.world import World

PACKETS = embree.packet_library


def render(scene, packets: bool, movable: list, moved: dict, spec) -> dict:
    embree.packet_library = PACKETS if packets else (lambda: None)
    try:
        world = World(scene, spec, movable_ids=movable)
        world.render_many(scene.sensing_ids)
        return world.render_many(scene.sensing_ids, moved)
    finally:
        embree.packet_library = PACKETS


def main(sets: list[str]) -> None:
    spec = load_lidar_spec("v2xp")
    rng = np.random.default_rng(0)
    sensors = points = differing = other_count = 0
    for name in sets:
        for scene in scenes_of(name):
            scene = with_nearest_collaborators(scene, 2)
            movable = [a.agent_id for a in vehicles_within(scene, scene.ego_id)
                       if a.agent_id not in scene.sensing_ids][:3]
            moved = {m: scene.agent(m).moved(*rng.uniform(-2, 2, 2), rng.uniform(-0.7, 0.7)) for m in movable}
            a = render(scene, True, movable, moved, spec)
            b = render(scene, False, movable, moved, spec)
            for sid in a:
                sensors += 1
                if a[sid].shape != b[sid].shape:
                    other_count += 1
                    continue
                d = np.abs(a[sid] - b[sid]).max(axis=1)
                points += len(d)
                differing += int((d > 0.01).sum())
    print(f"{sensors} sensors, {points} points: {differing} differ by more than 1 cm; "
          f"{other_count} sensors with another number of points")


if __name__ == "__main__":
    main(sys.argv[1:] or ["normal", "normal-val"])
