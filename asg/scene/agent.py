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
        yaw = math.atan2(math.sin(self.yaw_rad + dyaw_rad), math.cos(self.yaw_rad + dyaw_rad))
        return replace(self, x_m=self.x_m + dx_m, y_m=self.y_m + dy_m, yaw_rad=yaw)

    def to_dict(self) -> dict:
        return {
            "id": self.agent_id, "kind": self.kind, "type": self.type_id,
            "x_m": float(self.x_m), "y_m": float(self.y_m), "z_m": float(self.z_m), "yaw_rad": float(self.yaw_rad),
            "length_m": float(self.length_m), "width_m": float(self.width_m), "height_m": float(self.height_m),
            "speed_mps": float(self.speed_mps), "lane": self.lane_id,
        }

    @staticmethod
    def from_dict(d: dict) -> "Agent":
        return Agent(
            agent_id=str(d["id"]), kind=d["kind"], type_id=str(d["type"]),
            x_m=float(d["x_m"]), y_m=float(d["y_m"]), z_m=float(d["z_m"]), yaw_rad=float(d["yaw_rad"]),
            length_m=float(d["length_m"]), width_m=float(d["width_m"]), height_m=float(d["height_m"]),
            speed_mps=float(d.get("speed_mps", 0.0)), lane_id=d.get("lane"),
        )


#: a rectangle's corners in its own frame, in half lengths and half widths, counter-clockwise
#: from front-left
_CORNER_SIGNS = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])


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
