"""The ground under a recorded scan: a plane fitted by RANSAC (scikit-learn's RANSACRegressor) to the
scan's low points, in the sensor's frame. It stands in for the road when a scan is edited (a removed
vehicle's rays re-cast against it) and tells ground returns from obstacles (a drivable area read
from the scans).

Frame: the scan's sensor frame (x forward, y left, z up, metres); the plane is z = a x + b y + c.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sumo_scenarios.errors import InputError

#: points further than this horizontally are left out of the fit (the road near the sensor is flattest)
FIT_RADIUS_M = 40.0
#: a point within this of the plane is ground (RANSAC's residual threshold)
GROUND_TOLERANCE_M = 0.15
#: only points this far below the sensor are candidates (a car's roof-mounted LiDAR: about 1.9 m)
BELOW_SENSOR_M = 1.0
#: fewer candidate points than this: no plane is fitted
MIN_GROUND_POINTS = 50


@dataclass(frozen=True)
class GroundPlane:
    """z = a x + b y + c in a sensor's frame; ``inliers``: how many points the fit kept."""
    a: float
    b: float
    c: float
    inliers: int

    def height_m(self, points: np.ndarray) -> np.ndarray:
        """(N,) height of points (N, >=3) above the plane (along z)."""
        p = np.asarray(points, dtype=np.float64)
        return p[:, 2] - (self.a * p[:, 0] + self.b * p[:, 1] + self.c)

    def ray_distance(self, dirs: np.ndarray, origin: np.ndarray = np.zeros(3)) -> np.ndarray:
        """(N,) distance along unit rays (N, 3) from ``origin`` (3,; the sensor: the frame's origin)
        to the plane (inf: parallel or upward of it)."""
        d = np.asarray(dirs, dtype=np.float64)
        o = np.asarray(origin, dtype=np.float64)
        denom = d[:, 2] - self.a * d[:, 0] - self.b * d[:, 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (self.c + self.a * o[0] + self.b * o[1] - o[2]) / denom
        return np.where((denom < -1e-9) & (t > 0), t, np.inf)


def fit_ground(points: np.ndarray, seed: int = 0) -> GroundPlane:
    """The ground plane of a scan (N, >=3) in its sensor frame; InputError if the scan holds too
    few low points to fit one (a scan that sees no road)."""
    from sklearn.linear_model import LinearRegression, RANSACRegressor

    p = np.asarray(points[:, :3], dtype=np.float64)
    near = (np.hypot(p[:, 0], p[:, 1]) <= FIT_RADIUS_M) & (p[:, 2] <= -BELOW_SENSOR_M)
    cand = p[near]
    if len(cand) < MIN_GROUND_POINTS:
        raise InputError(f"the scan holds {len(cand)} points low enough to be ground (at least {MIN_GROUND_POINTS}); "
                         "no road to fit")
    fit = RANSACRegressor(LinearRegression(), residual_threshold=GROUND_TOLERANCE_M, max_trials=200,
                          random_state=seed).fit(cand[:, :2], cand[:, 2])
    a, b = (float(v) for v in fit.estimator_.coef_)
    return GroundPlane(a, b, float(fit.estimator_.intercept_), int(fit.inlier_mask_.sum()))


def ground_or_none(points: np.ndarray) -> GroundPlane | None:
    """:func:`fit_ground`, or None for a scan that shows no road (a high RSU's narrow view)."""
    try:
        return fit_ground(points)
    except InputError:
        return None
