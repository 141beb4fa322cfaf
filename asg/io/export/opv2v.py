"""OPV2V layout, as OpenCOOD's loaders read it: ``DIR/SCENE/AGENT/000000.pcd`` and ``000000.yaml``.

One scenario folder per scene, one timestamp (``000000``), one agent folder per sensing agent (the
ego and its collaborators). Agent ids are integers, numbered so that OpenCOOD's ego rule takes our
ego (:func:`opv2v_ids`): the ego 0, other vehicles ``1000 + i``, a collaborating RSU -1 (further
ones ``9001, ...``). ``DIR/SCENE/ids.yaml`` maps our ids to these and names our ego and the one
OpenCOOD will take (the same). ``DIR/SCENE/data_protocol.yaml`` describes the LiDAR the clouds were
cast with, in CARLA's attribute names (``lidar: channels, upper_fov, lower_fov, range,
points_per_second, rotation_frequency``), as OpenCDA's recordings do; ``asg scenes import`` reads it.

Every view is written in a frame at a car's sensor height (asg.sensors.ego_frame): an RSU's or a
truck's cloud is raised and its ``lidar_pose`` lowered by the same (ids.yaml: the ego's
``ego_frame_lowered_m``, every agent's ``frames_lowered_m``), so that OpenCOOD's fixed ground-truth
range (z in [-3, 1] m around each agent's LiDAR) keeps every vehicle, for the ego and, under late
fusion, for each collaborator in its own frame.

Frames: OPV2V's worlds are CARLA's, left-handed (x forward, y right); ours are right-handed (SUMO's
x east, y north; sensors x forward, y left). The export mirrors y: world ``(x, y, z)`` is written as
``(x, -y, z)``, every yaw as ``-yaw`` (degrees), and every point's sensor-frame y as ``-y``, so that
OpenCOOD's ``x_to_world`` and ``project_world_objects`` put each box where our ground truth has it
(mirrored). ``lidar_pose`` and a vehicle's ``angle`` are [roll, yaw, pitch] in degrees (roll and
pitch 0: our towns are flat per scene); ``location`` is the box's ground point, ``center`` its
offset to the box centre ``[0, 0, h/2]``, ``extent`` half-sizes; speeds in km/h as OPV2V's.
"""
from __future__ import annotations

from pathlib import Path

import yaml

from sumo_scenarios.atomic import write_text_atomic
from sumo_scenarios.checks import inside
from sumo_scenarios.errors import InputError

from ...scene import Scene
from ...scene.from_opv2v import EXPORT_IDS_NAME, PROTOCOL_NAME
from .base import EXPORT_FORMATS

TIMESTAMP = "000000"


@EXPORT_FORMATS.register("opv2v")
class ScenarioWriter:
    reads_net = False

    def __init__(self, out: Path, net: Path | None = None):
        from ...sensors import load_lidar_spec

        self.out = out
        self.spec = load_lidar_spec()

    def write(self, scene: Scene) -> None:
        from ...sensors import render_frame, world_for
        from ...sensors.opv2v import agent_views, opencood_ego, opv2v_ids
        from ..pcd import write_pcd_rgb_intensity

        if scene.is_empty:
            raise InputError(f"scene {scene.scene_id}: empty scene (no vehicles, no buildings); pick another frame")
        world = world_for(scene, self.spec)
        frame = render_frame(world)
        ids = opv2v_ids(scene, frame.sensing_ids)
        folder = inside(self.out, self.out / scene.scene_id)
        views, drops = agent_views(frame, ids, scene)
        for agent_id, (meta, cloud) in views.items():
            agent_dir = folder / str(ids[agent_id])
            agent_dir.mkdir(parents=True, exist_ok=True)
            write_pcd_rgb_intensity(agent_dir / f"{TIMESTAMP}.pcd", cloud)
            write_text_atomic(agent_dir / f"{TIMESTAMP}.yaml", yaml.safe_dump(meta, sort_keys=False))
        write_text_atomic(folder / PROTOCOL_NAME, yaml.safe_dump({"lidar": world.lidar_protocol()}, sort_keys=False))
        picked = int(opencood_ego([str(ids[a]) for a in frame.sensing_ids]))
        write_text_atomic(folder / EXPORT_IDS_NAME, yaml.safe_dump(
            {"scene_id": scene.scene_id, "ego": ids[scene.ego_id], "opencood_ego": picked,
             "sensing": [ids[a] for a in frame.sensing_ids],
             "ids": dict(ids), "frame": "CARLA left-handed: y and yaw mirrored from SUMO",
             "ego_frame_lowered_m": drops[scene.ego_id],
             "frames_lowered_m": {ids[a]: d for a, d in drops.items()}},
            sort_keys=False))

    def close(self) -> None:
        pass
