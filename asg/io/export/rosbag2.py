"""ROS 2 bags (rosbag2, MCAP storage, ROS 2 Jazzy message definitions), as ``ros2 bag play``,
RViz and Foxglove read them: ``DIR/SCENE_ID/`` holds one bag (``metadata.yaml`` and
``SCENE_ID.mcap``) with one message per topic, stamped with the scene's time:

- ``/asg/AGENT/points`` (sensor_msgs/msg/PointCloud2): each sensing agent's cloud as the detectors
  saw it (the v2xp LiDAR), in its own sensor frame ``AGENT`` (x forward, y left, z up: REP 103),
  fields x, y, z, intensity (float32, little-endian, 16 bytes a point);
- ``/tf_static`` (tf2_msgs/msg/TFMessage): ``map`` -> ``AGENT`` for each sensing agent, its
  sensor's pose; ``map`` is the town's SUMO frame (x east, y north, z up: ENU, REP 103);
- ``/asg/ground_truth`` (visualization_msgs/msg/MarkerArray): the ground truth asg's AP counts
  (every vehicle within the ego's evaluation range), a CUBE per vehicle in ``map`` at the box
  centre, scaled to its length, width and height, its text the vehicle's id.

``AGENT`` is ``agent_`` and the agent's id with each character outside ``[A-Za-z0-9_]`` written
as ``_`` (a ROS name token may not start with a digit, as SUMO's vehicle ids do; two ids that would
meet get ``_2``, ``_3``). ``DIR/ids.yaml`` maps, per scene, each agent id to its name, names the
ego and lists the ground-truth vehicles in marker-id order.

Needs the ``rosbags`` library (pure Python, no ROS install): ``pip install 'asg[ros]'``.
"""
from __future__ import annotations

import math
import os
import re
from pathlib import Path

import numpy as np
import yaml

from sumo_scenarios.atomic import atomic_dir, write_text_atomic
from sumo_scenarios.checks import inside
from sumo_scenarios.errors import InputError

from ...scene import Scene
from .base import EXPORT_FORMATS

EXTRA_HINT = "pip install 'asg[ros]'"
#: the ROS 2 release whose message definitions (and type hashes) the bags carry; its rosbag2
#: reads metadata version 9
ROS_DISTRO = "ROS2_JAZZY"
BAG_VERSION = 9
MAP_FRAME = "map"
POINTS_TOPIC = "/asg/{agent}/points"
TF_TOPIC = "/tf_static"
GROUND_TRUTH_TOPIC = "/asg/ground_truth"
#: x, y, z, intensity as float32 (sensor_msgs/msg/PointField.FLOAT32 = 7)
POINT_FIELDS = ("x", "y", "z", "intensity")
FLOAT32 = 7
#: the ground truth's colour (RGBA in [0, 1])
GROUND_TRUTH_RGBA = (0.1, 0.8, 0.2, 0.6)


def ros_names(agent_ids) -> dict[str, str]:
    """{agent id: its ROS frame and topic token}: ``agent_`` + the id with characters outside
    ``[A-Za-z0-9_]`` as ``_``; a name taken already gets ``_2``, ``_3`` (in the order given)."""
    names: dict[str, str] = {}
    taken: set[str] = set()
    for agent_id in agent_ids:
        base = "agent_" + re.sub(r"[^A-Za-z0-9_]", "_", str(agent_id))
        name, k = base, 1
        while name in taken:
            k += 1
            name = f"{base}_{k}"
        taken.add(name)
        names[agent_id] = name
    return names


def stamp_ns(time_s: float) -> int:
    """A scene's time as a bag timestamp (ns since the log's start; a bag's times are >= 0)."""
    if not math.isfinite(time_s) or time_s < 0:
        raise InputError(f"scene time {time_s!r} s cannot stamp a ROS message; a scene's time is >= 0")
    return int(round(time_s * 1e9))


@EXPORT_FORMATS.register("rosbag2")
class Rosbag2Writer:
    reads_net = False

    def __init__(self, out: Path, net: Path | None = None):
        from ...sensors import load_lidar_spec

        self.messages = _Messages()  # the library first: a missing install is refused before any scene
        self.out = out
        self.spec = load_lidar_spec()
        self.ids: dict[str, dict] = {}

    def write(self, scene: Scene) -> None:
        from ...perception.data import in_range
        from ...sensors import simulate_frame

        frame = simulate_frame(scene, self.spec)
        names = ros_names(frame.sensing_ids)
        keep = in_range(frame.ego_boxes)
        ground_truth = [vid for vid, k in zip(frame.gt_ids, keep) if k]
        stamp = stamp_ns(scene.time_s)
        folder = inside(self.out, self.out / scene.scene_id)
        with atomic_dir(folder) as work:
            bag = work / scene.scene_id
            self.messages.write_bag(bag, stamp, [(names[a], frame.poses[a], frame.clouds[a]) for a in frame.sensing_ids],
                                    frame.gt_boxes_world[keep], ground_truth)
            for item in bag.iterdir():  # the bag's files straight into DIR/SCENE_ID
                os.replace(item, work / item.name)
            bag.rmdir()
        self.ids[scene.scene_id] = {"ego": names[scene.ego_id], "agents": names, "ground_truth": ground_truth}

    def close(self) -> None:
        write_text_atomic(self.out / "ids.yaml", yaml.safe_dump(self.ids, sort_keys=False))


class _Messages:
    """The bag writer and the ROS message classes of :data:`ROS_DISTRO` (rosbags' typestore)."""

    def __init__(self):
        try:
            from rosbags.rosbag2 import StoragePlugin, Writer
            from rosbags.typesys import Stores, get_typestore
        except ImportError:
            raise InputError(f"--format rosbag2 needs the rosbags library, which is not installed; {EXTRA_HINT}") from None
        self.Writer, self.mcap = Writer, StoragePlugin.MCAP
        self.store = get_typestore(Stores[ROS_DISTRO])
        self.t = lambda name: self.store.types[name]

    def write_bag(self, path: Path, stamp: int, agents: list[tuple], boxes_world: np.ndarray, box_ids: list[str]) -> None:
        """A bag at ``path`` (which must not exist): ``agents`` as (name, SensorPose, cloud (N, 4)
        in its sensor frame), ``boxes_world`` (M, 7: x, y, z centre, l, w, h, yaw; map frame) named
        ``box_ids``; every message stamped ``stamp`` ns."""
        with self.Writer(path, version=BAG_VERSION, storage_plugin=self.mcap) as writer:
            def put(topic: str, msg) -> None:
                connection = writer.add_connection(topic, msg.__msgtype__, typestore=self.store)
                writer.write(connection, stamp, self.store.serialize_cdr(msg, msg.__msgtype__))

            put(TF_TOPIC, self.t("tf2_msgs/msg/TFMessage")(transforms=[self._transform(stamp, name, pose)
                                                                       for name, pose, _ in agents]))
            for name, _, cloud in agents:
                put(POINTS_TOPIC.format(agent=name), self._cloud(stamp, name, cloud))
            put(GROUND_TRUTH_TOPIC, self.t("visualization_msgs/msg/MarkerArray")(
                markers=[self._box(stamp, k, box, vid) for k, (box, vid) in enumerate(zip(boxes_world, box_ids))]))

    def _header(self, stamp: int, frame_id: str):
        time = self.t("builtin_interfaces/msg/Time")(sec=stamp // 10**9, nanosec=stamp % 10**9)
        return self.t("std_msgs/msg/Header")(stamp=time, frame_id=frame_id)

    def _quaternion(self, yaw_rad: float):
        return self.t("geometry_msgs/msg/Quaternion")(x=0.0, y=0.0, z=math.sin(yaw_rad / 2), w=math.cos(yaw_rad / 2))

    def _transform(self, stamp: int, name: str, pose):
        t = self.t
        transform = t("geometry_msgs/msg/Transform")(
            translation=t("geometry_msgs/msg/Vector3")(x=float(pose.x_m), y=float(pose.y_m), z=float(pose.z_m)),
            rotation=self._quaternion(float(pose.yaw_rad)))
        return t("geometry_msgs/msg/TransformStamped")(header=self._header(stamp, MAP_FRAME), child_frame_id=name,
                                                       transform=transform)

    def _cloud(self, stamp: int, name: str, cloud: np.ndarray):
        points = np.ascontiguousarray(cloud[:, :4], dtype="<f4")
        fields = [self.t("sensor_msgs/msg/PointField")(name=f, offset=4 * k, datatype=FLOAT32, count=1)
                  for k, f in enumerate(POINT_FIELDS)]
        return self.t("sensor_msgs/msg/PointCloud2")(
            header=self._header(stamp, name), height=1, width=len(points), fields=fields, is_bigendian=False,
            point_step=4 * len(POINT_FIELDS), row_step=4 * len(POINT_FIELDS) * len(points),
            data=points.view(np.uint8).ravel(), is_dense=True)

    def _box(self, stamp: int, k: int, box: np.ndarray, vehicle_id: str):
        t = self.t
        x, y, z, length, width, height, yaw = (float(v) for v in box)
        marker = t("visualization_msgs/msg/Marker")
        return marker(
            header=self._header(stamp, MAP_FRAME), ns="ground_truth", id=k, type=marker.CUBE, action=marker.ADD,
            pose=t("geometry_msgs/msg/Pose")(position=t("geometry_msgs/msg/Point")(x=x, y=y, z=z),
                                             orientation=self._quaternion(yaw)),
            scale=t("geometry_msgs/msg/Vector3")(x=length, y=width, z=height),
            color=t("std_msgs/msg/ColorRGBA")(*GROUND_TRUTH_RGBA),
            lifetime=t("builtin_interfaces/msg/Duration")(sec=0, nanosec=0), frame_locked=False,
            points=[], colors=[], texture_resource="",
            texture=t("sensor_msgs/msg/CompressedImage")(header=self._header(0, ""), format="", data=np.zeros(0, np.uint8)),
            uv_coordinates=[], text=str(vehicle_id), mesh_resource="",
            mesh_file=t("visualization_msgs/msg/MeshFile")(filename="", data=np.zeros(0, np.uint8)),
            mesh_use_embedded_materials=False)
