"""Meshes of the 3D world: vehicles shaped by class, buildings, RSU poles, ground.

Vehicle meshes are built in the vehicle's local frame: origin at the centre of its footprint on
the ground, x forward, y left, z up, metres; they lie strictly inside the (length, width, height)
box, ``MESH_INSET_M`` in from its sides, front, back and top (the wheels stand on the ground), as a
real car sits inside its labelled box: every LiDAR return off a vehicle lies inside its ground-truth
box, also for a reader with a strict in-box test (OpenCOOD's). Each is a union of parts (body,
cabin or cargo box, wheels), not a single box.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
import trimesh

from sumo_scenarios.buildings import Building

#: surface classes, stored per triangle; reflectivity in [0, 1] scales the intensity
SURFACES = {"ground": 0, "building": 1, "vehicle": 2, "pole": 3}
REFLECTIVITY = np.array([0.20, 0.35, 0.60, 0.50], dtype=np.float32)
#: how far a vehicle's mesh stays inside its box on every side but the bottom (m)
MESH_INSET_M = 0.02


def _box(x0: float, x1: float, y0: float, y1: float, z0: float, z1: float) -> trimesh.Trimesh:
    extents = [x1 - x0, y1 - y0, z1 - z0]
    centre = [(x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2]
    return trimesh.creation.box(extents=extents, transform=trimesh.transformations.translation_matrix(centre))


def _prism(bottom_x: tuple[float, float], top_x: tuple[float, float], bottom_w: float, top_w: float,
           z0: float, z1: float) -> trimesh.Trimesh:
    """A cabin: convex hull of a bottom and a (shorter, narrower) top rectangle."""
    pts = []
    for (xa, xb), w, z in ((bottom_x, bottom_w, z0), (top_x, top_w, z1)):
        for x in (xa, xb):
            for y in (-w / 2, w / 2):
                pts.append([x, y, z])
    return trimesh.convex.convex_hull(np.array(pts))


def _wheels(length: float, width: float, radius: float = 0.33, tyre: float = 0.24, rear_axles: int = 1) -> list[trimesh.Trimesh]:
    out = []
    front = length / 2 - max(0.8, 0.17 * length)
    rear = -length / 2 + max(0.8, 0.2 * length)
    xs = [front] + [rear + 1.3 * k for k in range(rear_axles)]
    for x in xs:
        for side in (-1, 1):
            y = side * (width / 2 - tyre / 2)
            out.append(_box(x - radius, x + radius, y - tyre / 2, y + tyre / 2, 0.0, 2 * radius))
    return out


def vehicle_parts(type_id: str, length_m: float, width_m: float, height_m: float) -> list[trimesh.Trimesh]:
    """The parts of a vehicle of class ``type_id`` (car, suv, van, truck, bus; else car-like)."""
    l, w, h = length_m, width_m, height_m
    if type_id == "truck":
        return [
            _box(-l / 2, l / 2, -w / 2 + 0.1, w / 2 - 0.1, 0.45, 1.05),                   # chassis
            _box(l / 2 - 0.24 * l, l / 2, -w / 2, w / 2, 0.45, 0.85 * h),                   # cab
            _box(-l / 2, l / 2 - 0.26 * l, -w / 2, w / 2, 1.05, h),                         # cargo box
            *_wheels(l, w, 0.5, 0.3, rear_axles=2),
        ]
    if type_id == "bus":
        return [
            _box(-l / 2, l / 2, -w / 2, w / 2, 0.35, 0.5 * h),                              # lower body
            _box(-l / 2 + 0.1, l / 2 - 0.1, -w / 2 + 0.04, w / 2 - 0.04, 0.5 * h, h),       # window band and roof
            *_wheels(l, w, 0.5, 0.3),
        ]
    if type_id == "van":
        return [
            _box(-l / 2, l / 2, -w / 2, w / 2, 0.3, 0.5 * h),                               # lower body
            _prism((-l / 2, 0.42 * l), (-l / 2, 0.22 * l), w, 0.96 * w, 0.5 * h, h),          # tall cargo cabin
            *_wheels(l, w, 0.34, 0.24),
        ]
    cabin = ((-0.42 * l, 0.25 * l), (-0.38 * l, 0.05 * l), 0.55) if type_id == "suv" else ((-0.36 * l, 0.22 * l), (-0.27 * l, 0.02 * l), 0.58)
    (bx, tx, split) = cabin
    return [
        _box(-l / 2, l / 2, -w / 2, w / 2, 0.25, split * h),                                 # body
        _prism(bx, tx, 0.94 * w, 0.84 * w, split * h, h),                                     # cabin
        *_wheels(l, w),
    ]


@lru_cache(maxsize=64)
def vehicle_template(type_id: str, length_m: float, width_m: float, height_m: float) -> trimesh.Trimesh:
    """A vehicle mesh in its local frame (cached per class and size), ``MESH_INSET_M`` inside its box."""
    mesh = trimesh.util.concatenate(vehicle_parts(type_id, length_m, width_m, height_m))
    inset = MESH_INSET_M
    mesh.apply_transform(np.diag([(length_m - 2 * inset) / length_m, (width_m - 2 * inset) / width_m,
                                  (height_m - inset) / height_m, 1.0]))
    mesh.metadata["surface"] = SURFACES["vehicle"]
    return mesh


@lru_cache(maxsize=8)
def pole_template(height_m: float) -> trimesh.Trimesh:
    """An RSU: a 0.24 m pole up to 0.35 m under its LiDAR, with a sensor housing on top."""
    pole = trimesh.creation.cylinder(radius=0.12, height=height_m - 0.35, sections=8)
    pole.apply_translation([0, 0, (height_m - 0.35) / 2])
    housing = _box(-0.2, 0.2, -0.2, 0.2, height_m - 0.35, height_m - 0.1)
    mesh = trimesh.util.concatenate([pole, housing])
    mesh.metadata["surface"] = SURFACES["pole"]
    return mesh


def agent_template(type_id: str, kind: str, length_m: float, width_m: float, height_m: float) -> trimesh.Trimesh:
    if kind == "rsu":
        return pole_template(round(height_m, 3))
    return vehicle_template(type_id, round(length_m, 3), round(width_m, 3), round(height_m, 3))


def building_mesh(b: Building) -> trimesh.Trimesh:
    """The footprint extruded from the ground to ``height_m`` (convex footprints triangulated
    directly as fans; others through trimesh's polygon extrusion)."""
    xy = np.asarray(b.footprint_xy, dtype=float)
    if not _is_convex(xy):
        from shapely.geometry import Polygon

        return trimesh.creation.extrude_polygon(Polygon(xy), b.height_m)
    (ax, ay), (bx, by) = xy[1] - xy[0], xy[2] - xy[1]
    if ax * by - ay * bx < 0:
        xy = xy[::-1]
    k = len(xy)
    verts = np.vstack([np.c_[xy, np.zeros(k)], np.c_[xy, np.full(k, b.height_m)]])
    fan = [[0, i + 1, i] for i in range(1, k - 1)] + [[k, k + i, k + i + 1] for i in range(1, k - 1)]
    sides = []
    for i in range(k):
        j = (i + 1) % k
        sides += [[i, j, k + j], [i, k + j, k + i]]
    return trimesh.Trimesh(vertices=verts, faces=np.array(fan + sides), process=False)


def _is_convex(xy: np.ndarray) -> bool:
    d = np.roll(xy, -1, axis=0) - xy
    cross = d[:, 0] * np.roll(d[:, 1], -1) - d[:, 1] * np.roll(d[:, 0], -1)
    return bool(np.all(cross >= -1e-9) or np.all(cross <= 1e-9))


def ground_mesh(center_xy: tuple[float, float], half_size_m: float) -> trimesh.Trimesh:
    """A flat square at z = 0 (two triangles); the simulator intersects the ground analytically."""
    cx, cy = center_xy
    v = np.array([[cx - half_size_m, cy - half_size_m, 0], [cx + half_size_m, cy - half_size_m, 0],
                  [cx + half_size_m, cy + half_size_m, 0], [cx - half_size_m, cy + half_size_m, 0]], dtype=float)
    return trimesh.Trimesh(vertices=v, faces=np.array([[0, 1, 2], [0, 2, 3]]), process=False)
