"""Agents of a scene: vehicles and roadside units (RSUs), with pose and size.

Frame: the town's network frame (x east, y north, metres). ``x_m, y_m`` is the centre of the
vehicle's bounding box on the ground, ``z_m`` the ground height under it, ``yaw_rad`` the heading
counter-clockwise from +x. For an RSU, ``height_m`` is its pole height (where its LiDAR sits).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from sumo_scenarios import checks
from sumo_scenarios.errors import InputError
from sumo_scenarios.geometry import wrap_rad

AgentKind = Literal["vehicle", "rsu"]


@dataclass(frozen=True)
class Agent:
    agent_id: str
    kind: AgentKind
    type_id: str
    x_m: float
    y_m: float
    z_m: float
    yaw_rad: float
    length_m: float
    width_m: float
    height_m: float
    speed_mps: float = 0.0
    lane_id: str | None = None

    @property
    def is_vehicle(self) -> bool:
        return self.kind == "vehicle"

    def footprint_xy(self) -> np.ndarray:
        """The box's ground outline: (4, 2) corners, counter-clockwise, network frame."""
        return footprint_xy(self.x_m, self.y_m, self.yaw_rad, self.length_m, self.width_m)

    def box7(self) -> np.ndarray:
        """(7,) x, y, z_centre, l, w, h, yaw in the network frame (z_centre = ground + h/2)."""
        return np.array([self.x_m, self.y_m, self.z_m + self.height_m / 2, self.length_m, self.width_m,
                         self.height_m, self.yaw_rad])

    def moved(self, dx_m: float, dy_m: float, dyaw_rad: float) -> "Agent":
        """A copy displaced by (dx, dy) metres in the network frame and turned by ``dyaw_rad``."""
        return replace(self, x_m=self.x_m + dx_m, y_m=self.y_m + dy_m, yaw_rad=wrap_rad(self.yaw_rad + dyaw_rad))

    def to_dict(self) -> dict:
        return {
            "id": self.agent_id, "kind": self.kind, "type": self.type_id,
            "x_m": float(self.x_m), "y_m": float(self.y_m), "z_m": float(self.z_m), "yaw_rad": float(self.yaw_rad),
            "length_m": float(self.length_m), "width_m": float(self.width_m), "height_m": float(self.height_m),
            "speed_mps": float(self.speed_mps), "lane": self.lane_id,
        }

    @staticmethod
    def from_dict(d: dict) -> "Agent":
        """An agent from its yaml mapping; every number is checked (finite, sizes positive and within
        checks.SIZE_LIMITS_M, coordinates within checks.MAX_COORD_M), the id must be a safe file name and the
        type a name SUMO takes (checks.label)."""
        where = f"agent {str(d['id'])[:40]!r}"
        kind = d["kind"]
        if kind not in ("vehicle", "rsu"):
            raise InputError(f"{where}: kind {kind!r} is not one of vehicle, rsu")
        size = {k: checks.number(d[k], f"{where} {k}", 0.0, checks.SIZE_LIMITS_M[k], lo_open=True)
                for k in ("length_m", "width_m", "height_m")}
        lane = d.get("lane")
        return Agent(
            agent_id=checks.safe_id(d["id"], where), kind=kind, type_id=checks.label(d["type"], where),
            x_m=checks.coordinate(d["x_m"], f"{where} x_m"), y_m=checks.coordinate(d["y_m"], f"{where} y_m"),
            z_m=checks.number(d["z_m"], f"{where} z_m", -checks.MAX_ABS_Z_M, checks.MAX_ABS_Z_M),
            yaw_rad=checks.number(d["yaw_rad"], f"{where} yaw_rad", -MAX_ABS_YAW_RAD, MAX_ABS_YAW_RAD),
            speed_mps=checks.number(d.get("speed_mps", 0.0), f"{where} speed_mps", -checks.MAX_SPEED_MPS,
                                    checks.MAX_SPEED_MPS),
            lane_id=None if lane is None else str(lane), **size,
        )


#: headings are normally within [-pi, pi]; a few turns either way are accepted, nothing wilder
MAX_ABS_YAW_RAD = 8 * math.pi


#: a rectangle's corners in its own frame, in half lengths and half widths, counter-clockwise
#: from front-left
_CORNER_SIGNS = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])


def in_any_box(points: np.ndarray, boxes: np.ndarray, margin_m: float = 0.0) -> np.ndarray:
    """(N,) bool: points (N, >=3) inside any box (M, 7: x, y, z centre, l, w, h, yaw, one frame)
    grown by ``margin_m`` on every side."""
    p = np.asarray(points, dtype=np.float64)
    out = np.zeros(len(p), dtype=bool)
    for x, y, z, length, width, height, yaw in np.asarray(boxes, dtype=np.float64).reshape(-1, 7):
        d = p[:, :3] - (x, y, z)
        c, s = math.cos(yaw), math.sin(yaw)
        out |= ((np.abs(c * d[:, 0] + s * d[:, 1]) <= length / 2 + margin_m)
                & (np.abs(-s * d[:, 0] + c * d[:, 1]) <= width / 2 + margin_m)
                & (np.abs(d[:, 2]) <= height / 2 + margin_m))
    return out


def footprints_xy(x_m, y_m, yaw_rad, length_m, width_m) -> np.ndarray:
    """Corners (M, 4, 2) of M rectangles given as arrays (M,) of centre, heading and size,
    counter-clockwise from front-left."""
    x_m, y_m, yaw_rad, length_m, width_m = np.broadcast_arrays(*(np.asarray(v, dtype=float).reshape(-1) for v in
                                                               (x_m, y_m, yaw_rad, length_m, width_m)))
    u = _CORNER_SIGNS[None, :, 0] * (length_m[:, None] / 2)  # (M, 4) along the heading
    v = _CORNER_SIGNS[None, :, 1] * (width_m[:, None] / 2)  # (M, 4) to the left
    c, s = np.cos(yaw_rad)[:, None], np.sin(yaw_rad)[:, None]
    return np.stack([u * c - v * s + x_m[:, None], u * s + v * c + y_m[:, None]], axis=-1)


def footprint_xy(x_m: float, y_m: float, yaw_rad: float, length_m: float, width_m: float) -> np.ndarray:
    """Corners (4, 2) of a rectangle centred at (x, y), heading ``yaw_rad``, counter-clockwise
    (footprints_xy for one rectangle, without its array overhead: this one is on hot paths)."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    local = _CORNER_SIGNS * np.array([length_m / 2, width_m / 2])
    return local @ np.array([[c, s], [-s, c]]) + np.array([x_m, y_m])


def stacked_footprints_xy(x_m, y_m, yaw_rad, length_m, width_m) -> np.ndarray:
    """Corners (M, 4, 2) of M rectangles given as arrays (M,), the same floats as
    :func:`footprint_xy` gives one at a time (each rectangle's corners by its own 2 x 2 matrix
    product and ``math``'s cosine; :func:`footprints_xy` rounds differently in the last bits)."""
    x_m, y_m, yaw_rad, length_m, width_m = np.broadcast_arrays(*(np.asarray(v, dtype=float).reshape(-1) for v in
                                                               (x_m, y_m, yaw_rad, length_m, width_m)))
    c = np.fromiter(map(math.cos, yaw_rad), dtype=float, count=len(yaw_rad))
    s = np.fromiter(map(math.sin, yaw_rad), dtype=float, count=len(yaw_rad))
    local = _CORNER_SIGNS[None] * np.stack([length_m / 2, width_m / 2], axis=-1)[:, None, :]  # (M, 4, 2)
    rotation = np.stack([np.stack([c, s], axis=-1), np.stack([-s, c], axis=-1)], axis=1)  # (M, 2, 2)
    return np.matmul(local, rotation) + np.stack([x_m, y_m], axis=-1)[:, None, :]
