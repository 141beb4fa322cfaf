"""``pose-error``: each collaborator's shared pose is off by (dx, dy) within +-xy_m (network frame)
and dyaw within +-yaw_deg, while its sensor sees the true world: the localisation error of a real
V2X link. Three dimensions per collaborator.

Defaults +-0.5 m and +-1 deg: OpenCOOD and V2X-ViT test pose noise of sigma 0.2 m and 0.2 deg, CoAlign
up to 0.6 m and 0.6 deg; SAE J2945/1 asks a V2V sender for 1.5 m (one sigma) absolute position
accuracy, so the default bound stays inside what deployed links allow.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sumo_scenarios import checks

from .base import SPACES, PerturbationSpace, collaborators


@dataclass(frozen=True)
class PoseErrorConfig:
    xy_m: float = 0.5
    yaw_deg: float = 1.0

    def __post_init__(self) -> None:
        checks.number(self.xy_m, "space.pose_error.xy_m (metres)", 0.0, 10.0, lo_open=True)
        checks.number(self.yaw_deg, "space.pose_error.yaw_deg (degrees)", 0.0, 30.0, lo_open=True)


@SPACES.register("pose-error")
class PoseErrorSpace(PerturbationSpace):
    @property
    def _scale(self) -> np.ndarray:
        c = self.cfg.pose_error
        return np.array([c.xy_m, c.xy_m, math.radians(c.yaw_deg)])

    @property
    def width(self) -> int:
        return 3 * len(collaborators(self.ctx))

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        return rng.uniform(-1.0, 1.0, size=(n, self.width))

    def identity(self) -> np.ndarray:
        return np.zeros(self.width)

    def link_fields(self, x: np.ndarray) -> dict[str, dict]:
        d = np.asarray(x).reshape(-1, 3) * self._scale
        return {cid: {"dx_m": float(v[0]), "dy_m": float(v[1]), "dyaw_rad": float(v[2])}
                for cid, v in zip(collaborators(self.ctx), d)}

    def link_columns(self) -> list[str]:
        return [f"{c}_pose_{k}" for c in collaborators(self.ctx) for k in ("dx_m", "dy_m", "dyaw_deg")]

    def link_readable(self, x: np.ndarray) -> list[float]:
        d = np.asarray(x).reshape(-1, 3) * self._scale
        return [round(float(v), 4) for dx, dy, dyaw in d for v in (dx, dy, math.degrees(dyaw))]

    def bounds(self) -> dict:
        return {"xy_m": self.cfg.pose_error.xy_m, "yaw_deg": self.cfg.pose_error.yaw_deg}
