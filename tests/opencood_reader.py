"""How OpenCOOD reads an OPV2V frame (its ``pcd_utils.pcd_to_np``, ``x_to_world`` and
``box_utils.project_world_objects``), rewritten here without torch or OpenCOOD itself so that the
export tests read our files the way OpenCOOD does."""
import math

import numpy as np


def pcd_to_np(path) -> np.ndarray:
    """(N, 4): Open3D's legacy reader, intensity from the first colour channel."""
    import open3d as o3d

    pcd = o3d.io.read_point_cloud(str(path))
    return np.hstack([np.asarray(pcd.points), np.asarray(pcd.colors)[:, :1]]).astype(np.float32)


def boxes_from_opv2v_yaml(vehicles: dict, lidar_pose: list[float]) -> np.ndarray:
    """(M, 7) boxes x, y, z, l, w, h, yaw in the frame of ``lidar_pose``, computed as OpenCOOD's
    ``project_world_objects`` does (for checks; yaw in radians)."""
    world_to_lidar = np.linalg.inv(_x_to_world(lidar_pose))
    out = []
    for v in vehicles.values():
        loc, c, ext, ang = v["location"], v["center"], v["extent"], v["angle"]
        obj_to_world = _x_to_world([loc[0] + c[0], loc[1] + c[1], loc[2] + c[2], *ang])
        m = world_to_lidar @ obj_to_world
        yaw = math.atan2(m[1, 0], m[0, 0])
        out.append([m[0, 3], m[1, 3], m[2, 3], 2 * ext[0], 2 * ext[1], 2 * ext[2], yaw])
    return np.array(out).reshape(-1, 7)


def _x_to_world(pose: list[float]) -> np.ndarray:
    """OpenCOOD's ``x_to_world``: [x, y, z, roll, yaw, pitch] (degrees) -> (4, 4)."""
    x, y, z, roll, yaw, pitch = pose
    cy, sy = math.cos(math.radians(yaw)), math.sin(math.radians(yaw))
    cr, sr = math.cos(math.radians(roll)), math.sin(math.radians(roll))
    cp, sp = math.cos(math.radians(pitch)), math.sin(math.radians(pitch))
    return np.array([[cp * cy, cy * sp * sr - sy * cr, -cy * sp * cr - sy * sr, x],
                     [sy * cp, sy * sp * sr + cy * cr, -sy * sp * cr + cy * sr, y],
                     [sp, -cp * sr, cp * cr, z],
                     [0.0, 0.0, 0.0, 1.0]])
