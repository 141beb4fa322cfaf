"""KITTI object layout (as OpenPCDet reads it) of each scene's ego view with every sensing agent's
cloud fused: ``DIR/training/{velodyne,label_2,calib,image_2}/NNNNNN.*`` and
``DIR/ImageSets/{train,val,test}.txt``, what OpenPCDet's info builder (``create_kitti_infos``) reads.

- ``velodyne/NNNNNN.bin``: float32 x, y, z, intensity of the fused cloud in the ego's sensor frame
  (x forward, y left, z up: KITTI's velodyne frame), 360 degrees; an ego sensor standing higher than
  a car's (an RSU, a truck) is written in a frame at a car's sensor height below it (points and
  labels raised by ``ego_frame.yaml``'s ``lowered_m``, asg.sensors.ego_frame), so that OpenPCDet's
  stock point-cloud range (z in [-3, 1] m) keeps every vehicle.
- ``label_2/NNNNNN.txt``: every vehicle within the evaluation range (the ground truth the AP of
  asg counts), class ``Car`` (``Truck`` for truck and bus types), in the rectified camera frame of
  ``calib`` (x right, y down, z forward): dimensions h w l, location = the box's bottom centre,
  rotation_y = -yaw - pi/2 (OpenPCDet's conversion). There is no camera: the 2D box is the
  projection with KITTI's P2 clipped to its 1242 x 375 image, or 0 0 0 0 outside it; truncation 0;
  occlusion from the fused points in the box (0: 50 or more, 1: 10 to 49, 2: 1 to 9, 3: none).
  Labels cover 360 degrees: turn OpenPCDet's FOV_POINTS_ONLY off.
- ``calib/NNNNNN.txt``: KITTI's P0-P3, R0_rect = I, Tr_velo_to_cam the axis swap velo -> camera.
- ``image_2/NNNNNN.png``: a placeholder (there is no camera): a black 1242 x 375 image, so that the
  info builder reads KITTI's image shape (its field of view and 2D boxes follow from it).
- ``ImageSets``: ``train.txt`` and ``val.txt`` both list every frame (split them as you need;
  asg does not), ``test.txt`` is empty.
``DIR/ids.yaml`` maps each NNNNNN to its scene id; ``DIR/point_cloud_range.yaml`` gives the OpenPCDet
``POINT_CLOUD_RANGE`` that covers every label (KITTI's stock one is front-only).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import yaml

from sumo_scenarios.atomic import atomic_path, write_text_atomic
from sumo_scenarios.geometry import wrap_rad

from ...scene import Scene
from .base import EXPORT_FORMATS

#: KITTI's left colour camera intrinsics (sequence 0000 of the object benchmark) and image size
P2 = np.array([[721.5377, 0.0, 609.5593, 44.85728], [0.0, 721.5377, 172.854, 0.2163791], [0.0, 0.0, 1.0, 0.002745884]])
IMAGE_WH = (1242, 375)
#: velodyne (x forward, y left, z up) -> camera (x right, y down, z forward)
TR_VELO_TO_CAM = np.array([[0.0, -1.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [1.0, 0.0, 0.0, 0.0]])
#: fused points in a box -> KITTI occlusion level: at least 50, 10, 1 points, or none
OCCLUSION_POINTS = (50, 10, 1)
#: the OpenPCDet POINT_CLOUD_RANGE that covers every label (360 degrees, the evaluation square
#: rounded up to a grid of 0.16 m voxels divisible by 8: 640 cells), z as the stock range
POINT_CLOUD_RANGE = [-51.2, -51.2, -3.0, 51.2, 51.2, 1.0]


@EXPORT_FORMATS.register("kitti")
class KittiWriter:
    reads_net = False

    def __init__(self, out: Path, net: Path | None = None):
        from ...sensors import load_lidar_spec

        self.out = out
        self.spec = load_lidar_spec()
        for sub in ("velodyne", "label_2", "calib", "image_2"):
            (out / "training" / sub).mkdir(parents=True, exist_ok=True)
        self.placeholder_png = placeholder_image()
        (out / "ImageSets").mkdir(exist_ok=True)
        self.ids: dict[str, str] = {}
        #: per frame, how far below the ego's sensor its frame is (asg.sensors.ego_frame)
        self.lowered_m: dict[str, float] = {}

    def write(self, scene: Scene) -> None:
        from ...perception.data import in_range
        from ...sensors import simulate_frame
        from ...sensors.ego_frame import ego_frame_drop_m

        name = f"{len(self.ids):06d}"
        frame = simulate_frame(scene, self.spec)
        # the ego view in a frame at a car's sensor height (an RSU's or a truck's raised by this)
        lowered_m = ego_frame_drop_m(frame.poses[frame.ego_id].z_m, scene.ego.z_m)
        fused = np.vstack(frame.clouds_in_frame_of(frame.ego_id)).astype(np.float32)
        fused[:, 2] += lowered_m
        with atomic_path(self.out / "training" / "velodyne" / f"{name}.bin") as tmp:
            fused.tofile(tmp)
        boxes = frame.ego_boxes  # a new array each access: computed once, raised in place
        keep = in_range(boxes)
        boxes[:, 2] += lowered_m
        points = frame.points_in_boxes()["fused"][keep] if len(boxes) else np.zeros(0, int)
        types = [scene.agent(i).type_id for i, k in zip(frame.gt_ids, keep) if k]
        lines = [label_line(b, t, int(n)) for b, t, n in zip(boxes[keep], types, points)]
        write_text_atomic(self.out / "training" / "label_2" / f"{name}.txt", "".join(lines))
        write_text_atomic(self.out / "training" / "calib" / f"{name}.txt", calib_text())
        with atomic_path(self.out / "training" / "image_2" / f"{name}.png") as tmp:
            Path(tmp).write_bytes(self.placeholder_png)
        self.ids[name] = scene.scene_id
        self.lowered_m[name] = lowered_m

    def close(self) -> None:
        frames = "".join(f"{n}\n" for n in self.ids)
        for split, listed in (("train", frames), ("val", frames), ("test", "")):
            write_text_atomic(self.out / "ImageSets" / f"{split}.txt", listed)
        write_text_atomic(self.out / "ids.yaml", yaml.safe_dump(self.ids))
        write_text_atomic(self.out / "ego_frame.yaml", yaml.safe_dump({"lowered_m": self.lowered_m}))
        write_text_atomic(self.out / "point_cloud_range.yaml", yaml.safe_dump({
            "POINT_CLOUD_RANGE": POINT_CLOUD_RANGE,
            "note": ("covers every label: they are 360 degrees around the ego, within 48 m in x and y; KITTI's stock "
                     "range [0, -39.68, -3, 69.12, 39.68, 1] keeps only those in front (x >= 0). Set FOV_POINTS_ONLY: "
                     "False. Labels outside the placeholder camera's image have a 2D box of 0 0 0 0, which "
                     "OpenPCDet's KITTI evaluation rates difficulty -1 and ignores.")}, sort_keys=False))


def label_line(box: np.ndarray, type_id: str, points: int) -> str:
    """One KITTI label line for ``box`` (x, y, z, l, w, h, yaw; velodyne frame, z the centre)."""
    x, y, z, length, width, height, yaw = (float(v) for v in box)
    bottom_cam = TR_VELO_TO_CAM @ np.array([x, y, z - height / 2, 1.0])
    rotation_y = wrap_rad(-yaw - math.pi / 2)
    alpha = wrap_rad(rotation_y - math.atan2(bottom_cam[0], bottom_cam[2]))
    cls = "Truck" if any(k in type_id.lower() for k in ("truck", "bus")) else "Car"
    occluded = next((level for level, n in enumerate(OCCLUSION_POINTS) if points >= n), 3)
    left, top, right, bottom = image_box(box)
    return (f"{cls} 0.00 {occluded} {alpha:.2f} {left:.2f} {top:.2f} {right:.2f} {bottom:.2f} "
            f"{height:.2f} {width:.2f} {length:.2f} {bottom_cam[0]:.2f} {bottom_cam[1]:.2f} {bottom_cam[2]:.2f} "
            f"{rotation_y:.2f}\n")


def image_box(box: np.ndarray) -> tuple[float, float, float, float]:
    """The box's 8 corners projected with P2 and clipped to the image; zeros if any corner is
    behind the camera or the box is outside the image."""
    x, y, z, length, width, height, yaw = (float(v) for v in box)
    dx, dy, dz = np.meshgrid([-length / 2, length / 2], [-width / 2, width / 2], [-height / 2, height / 2])
    c, s = math.cos(yaw), math.sin(yaw)
    corners = np.stack([x + c * dx.ravel() - s * dy.ravel(), y + s * dx.ravel() + c * dy.ravel(), z + dz.ravel(),
                        np.ones(8)])
    cam = TR_VELO_TO_CAM @ corners
    if np.any(cam[2] <= 0.1):
        return 0.0, 0.0, 0.0, 0.0
    uvw = P2 @ np.vstack([cam, np.ones(8)])
    u, v = uvw[0] / uvw[2], uvw[1] / uvw[2]
    left, right = np.clip([u.min(), u.max()], 0, IMAGE_WH[0] - 1)
    top, bottom = np.clip([v.min(), v.max()], 0, IMAGE_WH[1] - 1)
    return (0.0, 0.0, 0.0, 0.0) if right <= left or bottom <= top else (left, top, right, bottom)


def placeholder_image() -> bytes:
    """A black PNG of KITTI's image size (IMAGE_WH): what stands in for the camera image."""
    import io

    from PIL import Image

    buffer = io.BytesIO()
    Image.new("RGB", IMAGE_WH).save(buffer, format="PNG")
    return buffer.getvalue()


def calib_text() -> str:
    row = lambda m: " ".join(f"{v:.12e}" for v in np.asarray(m).ravel())
    return "".join([f"P{i}: {row(P2)}\n" for i in range(4)] + [f"R0_rect: {row(np.eye(3))}\n",
                   f"Tr_velo_to_cam: {row(TR_VELO_TO_CAM)}\n", f"Tr_imu_to_velo: {row(np.eye(4)[:3])}\n"])

