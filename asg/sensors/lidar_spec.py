"""LiDAR sensor specification and its ray pattern.

Sensor frame: origin at the LiDAR, x forward (the agent's heading), y left, z up, metres.
Rays: ``channels`` rows of elevation from ``fov_up_deg`` down to ``fov_down_deg`` (row 0 is the top),
``azimuth_steps`` columns from -180 deg (behind) counter-clockwise; one sweep casts
``channels x azimuth_steps`` rays, with ``azimuth_steps = points_per_s / rotation_hz / channels``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

import numpy as np

from sumo_scenarios import checks
from sumo_scenarios.errors import InputError
from sumo_scenarios.paths import configs_dir
from sumo_scenarios.strict import load_dataclass

Backend = Literal["embree", "trimesh"]
#: the largest range noise a preset may give (std, m), and the highest mount above a roof (m)
MAX_NOISE_STD_M = 10.0
MAX_MOUNT_M = 5.0
#: the preset of configs/lidar/ the shipped detectors were trained on: every stage renders with it
#: unless told otherwise (``asg render --lidar``, the generate config's ``lidar``)
DEFAULT_LIDAR = "v2xp"


@dataclass(frozen=True)
class LidarSpec:
    name: str = DEFAULT_LIDAR
    channels: int = 32
    fov_up_deg: float = 2.0
    fov_down_deg: float = -25.0
    points_per_s: float = 250_000
    rotation_hz: float = 20.0
    range_m: float = 70.0
    #: std of Gaussian range noise (m); 0 = none (the paper's setting)
    noise_std_m: float = 0.0
    #: probability that a return is dropped; 0 = none
    dropoff: float = 0.0
    #: vehicle LiDAR height above the roof (m); RSU LiDARs sit on top of their pole
    vehicle_mount_above_roof_m: float = 0.4
    backend: Backend = "embree"
    #: Embree's robust (watertight) traversal; off, casts are faster and a ray can slip through a
    #: shared triangle edge (the measured trade-off: docs/lidar.md)
    embree_robust: bool = False

    def validate(self) -> "LidarSpec":
        """``self`` if every setting is one a sensor can have (sumo_scenarios.checks.LIDAR_LIMITS: a
        sweep's rays fit in memory); else one InputError naming the first that is not."""
        limits, where = checks.LIDAR_LIMITS, f"lidar '{str(self.name)[:40]}'"
        for key in ("channels", "points_per_s", "rotation_hz", "range_m"):
            checks.number(getattr(self, key), f"{where}: {key}", *limits[key])
        for key in ("fov_up_deg", "fov_down_deg"):
            checks.number(getattr(self, key), f"{where}: {key}", *limits["elevation_deg"])
        if self.fov_up_deg < self.fov_down_deg:
            raise InputError(f"{where}: fov_up_deg must be >= fov_down_deg")
        low, high = limits["returns_per_ring"]
        if not low <= self.azimuth_steps <= high:
            raise InputError(f"{where}: {self.azimuth_steps} returns a channel and sweep (points_per_s / rotation_hz "
                             f"/ channels) must lie in {low}..{high}")
        checks.number(self.noise_std_m, f"{where}: noise_std_m", 0.0, MAX_NOISE_STD_M)
        checks.number(self.vehicle_mount_above_roof_m, f"{where}: vehicle_mount_above_roof_m", 0.0, MAX_MOUNT_M)
        if not 0 <= self.dropoff < 1:
            raise InputError(f"{where}: dropoff must lie in [0, 1), got {self.dropoff:g}")
        if self.backend not in ("embree", "trimesh"):
            raise InputError(f"lidar '{self.name}': backend must be embree or trimesh, got {self.backend!r}")
        if not isinstance(self.embree_robust, bool):
            raise InputError(f"lidar '{self.name}': embree_robust must be true or false, got {self.embree_robust!r}")
        return self

    @property
    def azimuth_steps(self) -> int:
        return int(self.points_per_s / self.rotation_hz / self.channels)

    @property
    def rays_per_sweep(self) -> int:
        return self.channels * self.azimuth_steps

    def elevations_rad(self) -> np.ndarray:
        """(C,) elevation of each channel, top first."""
        if self.channels == 1:
            return np.array([math.radians(self.fov_up_deg)])
        return np.radians(np.linspace(self.fov_up_deg, self.fov_down_deg, self.channels))

    def azimuths_rad(self) -> np.ndarray:
        """(A,) azimuth of each column in the sensor frame, from -pi, counter-clockwise."""
        return -math.pi + np.arange(self.azimuth_steps) * (2 * math.pi / self.azimuth_steps)

    def directions(self) -> np.ndarray:
        """(C*A, 3) float64 unit ray directions in the sensor frame, row-major (channel, azimuth)."""
        el = self.elevations_rad()[:, None]
        az = self.azimuths_rad()[None, :]
        d = np.stack(np.broadcast_arrays(np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)), axis=-1)
        return d.reshape(-1, 3)

    def carla_protocol(self) -> dict:
        """The sensor in CARLA's attribute names (an OPV2V scenario's data_protocol.yaml)."""
        return {"channels": self.channels, "upper_fov": self.fov_up_deg, "lower_fov": self.fov_down_deg,
                "range": self.range_m, "points_per_second": self.points_per_s, "rotation_frequency": self.rotation_hz}

    def with_overrides(self, **kw) -> "LidarSpec":
        return replace(self, **kw).validate()


def load_lidar_spec(name_or_path: str | Path = DEFAULT_LIDAR) -> LidarSpec:
    """A preset name from configs/lidar/ (``v2xp``, ``dense64``) or a yaml path."""
    p = Path(name_or_path)
    if not p.suffix:
        p = configs_dir() / "lidar" / f"{name_or_path}.yaml"
        if not p.is_file():
            known = ", ".join(sorted(q.stem for q in (configs_dir() / "lidar").glob("*.yaml")))
            raise InputError(f"unknown lidar preset '{name_or_path}'; presets: {known}")
    return load_dataclass(LidarSpec, p).validate()
