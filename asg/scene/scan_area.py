"""A recording's drivable area read from its scans, where no map is given: the ground the sensing
agents saw, under and around the labelled vehicles, minus every cell that holds a recorded point
that is neither ground nor a labelled vehicle (a wall, a pole, a parked bicycle).

The plausibility rule of a recorded scene without a map (``--plausibility paper``): a moved
vehicle's footprint must lie on this area (and, as everywhere, off every other vehicle). It differs
from the native rule, SUMO's lanes and junctions: a pavement the scans show as flat ground counts as
drivable, a lane the scans never reached (behind a wall, beyond the rings) does not, and lanes have
no direction (``--plausibility traffic`` needs a map).

The area is a grid of CELL_M cells around the ego's LiDAR in the scene's frame: a cell is ground if a
ground return (within the scan's fitted plane's tolerance, asg.scene.scan_ground) falls in it, or a
labelled vehicle stands on it; gaps between the LiDAR's rings are closed (CLOSE_CELLS); a cell with
an obstacle point (OBSTACLE_HEIGHTS_M above the ground, outside every labelled box grown by
BOX_MARGIN_M) is taken out with its neighbours. It is stored as the scene's lane map: each row's
runs of free cells a rectangle ("junction" of kind ``scan``), so that every check of the drivable
area (the feasible set's, the independent shapely re-check) reads it as it reads SUMO's.
"""
from __future__ import annotations

import math

import numpy as np

from sumo_scenarios.lanes import Junction, LaneMap
from sumo_scenarios.log import NEAR_RADIUS_M

from .agent import footprints_xy, in_any_box
from .scan_ground import GROUND_TOLERANCE_M, GroundPlane, ground_or_none

#: the grid's cell (m)
CELL_M = 1.0
#: the grid's half width around the ego's LiDAR (m): the evaluation range and a margin
HALF_WIDTH_M = NEAR_RADIUS_M + 12.0
#: ring gaps up to this many cells are closed
CLOSE_CELLS = 2
#: a point this high above the ground is an obstacle (below: ground roughness; above: overhangs)
OBSTACLE_HEIGHTS_M = (0.3, 2.5)
#: labelled boxes grown by this before points inside them are called the vehicle's (m)
BOX_MARGIN_M = 0.3
#: the kind of the area's rectangles in the lane map
SCAN_KIND = "scan"


def scan_area(scene, clouds: dict[str, np.ndarray], planes: dict[str, GroundPlane | None] | None = None) -> LaneMap:
    """The drivable area of a recorded ``scene`` from its sensing agents' ``clouds`` ({id: (N, 4)
    in that agent's sensor frame, the scene's handedness}) as a lane map of rectangles; ``planes``:
    each cloud's ground (asg.scene.scan_ground; fitted here where not given)."""
    from scipy import ndimage

    rec = scene.recording
    ox, oy = rec.views[scene.ego_id].sensor[:2]
    n = int(round(2 * HALF_WIDTH_M / CELL_M))
    origin = np.array([ox - HALF_WIDTH_M, oy - HALF_WIDTH_M])
    ground = np.zeros((n, n), dtype=bool)
    blocked = np.zeros((n, n), dtype=bool)
    boxes = np.array([a.box7() for a in scene.agents if a.is_vehicle]).reshape(-1, 7)
    for agent_id, cloud in clouds.items():
        plane = planes[agent_id] if planes is not None else ground_or_none(cloud)
        if plane is None:
            continue  # a scan without a road (a high RSU's narrow view) adds nothing
        height = plane.height_m(cloud)
        world = _to_scene(cloud[:, :3], rec.views[agent_id].sensor)
        _mark(ground, world[np.abs(height) <= GROUND_TOLERANCE_M], origin, n)
        tall = (height > OBSTACLE_HEIGHTS_M[0]) & (height < OBSTACLE_HEIGHTS_M[1])
        obstacles = world[tall]
        _mark(blocked, obstacles[~in_any_box(obstacles, boxes, BOX_MARGIN_M)], origin, n)
    for corners in footprints_xy(boxes[:, 0], boxes[:, 1], boxes[:, 6], boxes[:, 3], boxes[:, 4]) if len(boxes) else ():
        _fill_polygon(ground, corners, origin, n)
    if CLOSE_CELLS:
        ground = ndimage.binary_closing(ground, structure=np.ones((3, 3), bool), iterations=CLOSE_CELLS,
                                        border_value=0) | ground
    free = ground & ~ndimage.binary_dilation(blocked, structure=np.ones((3, 3), bool))
    return LaneMap([], _rectangles(free, origin))


def _to_scene(points: np.ndarray, sensor: tuple[float, float, float, float]) -> np.ndarray:
    """(N, 3) sensor-frame points in the scene's frame (the sensor's yaw only)."""
    x, y, z, yaw = sensor
    c, s = math.cos(yaw), math.sin(yaw)
    p = points.astype(np.float64)
    return np.stack([c * p[:, 0] - s * p[:, 1] + x, s * p[:, 0] + c * p[:, 1] + y, p[:, 2] + z], axis=1)


def _cells(xy: np.ndarray, origin: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    ij = np.floor((xy[:, :2] - origin) / CELL_M).astype(np.int64)
    ok = (ij >= 0).all(axis=1) & (ij < n).all(axis=1)
    return ij[ok, 0], ij[ok, 1]


def _mark(grid: np.ndarray, points: np.ndarray, origin: np.ndarray, n: int) -> None:
    i, j = _cells(points, origin, n)
    grid[i, j] = True


def _fill_polygon(grid: np.ndarray, corners: np.ndarray, origin: np.ndarray, n: int) -> None:
    """Mark the cells whose centres lie in the convex polygon ``corners`` (4, 2), counter-clockwise."""
    lo = np.floor((corners.min(axis=0) - origin) / CELL_M).astype(int)
    hi = np.ceil((corners.max(axis=0) - origin) / CELL_M).astype(int)
    lo, hi = np.clip(lo, 0, n - 1), np.clip(hi, 0, n - 1)
    ii, jj = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1), indexing="ij")
    centres = origin + (np.stack([ii, jj], axis=-1) + 0.5) * CELL_M
    inside = np.ones(ii.shape, dtype=bool)
    for k in range(len(corners)):
        a, b = corners[k], corners[(k + 1) % len(corners)]
        inside &= (b[0] - a[0]) * (centres[..., 1] - a[1]) - (b[1] - a[1]) * (centres[..., 0] - a[0]) >= -CELL_M / 2
    grid[ii[inside], jj[inside]] = True


def _rectangles(free: np.ndarray, origin: np.ndarray) -> list[Junction]:
    """Each row's runs of free cells as a rectangle, a run repeated in the next rows merged into one."""
    out, open_runs = [], {}
    for i in range(free.shape[0] + 1):
        row = free[i] if i < free.shape[0] else np.zeros(free.shape[1], bool)
        edges = np.flatnonzero(np.diff(np.concatenate([[0], row.view(np.int8), [0]])))
        runs = set(zip(edges[::2].tolist(), edges[1::2].tolist()))
        for run in list(open_runs):
            if run not in runs:
                out.append(_rectangle(open_runs.pop(run), i, run, origin, len(out)))
        for run in runs:
            open_runs.setdefault(run, i)
    return out


def _rectangle(i0: int, i1: int, run: tuple[int, int], origin: np.ndarray, k: int) -> Junction:
    x0, x1 = origin[0] + i0 * CELL_M, origin[0] + i1 * CELL_M
    y0, y1 = origin[1] + run[0] * CELL_M, origin[1] + run[1] * CELL_M
    shape = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    return Junction(f"scan{k}", shape, SCAN_KIND, ((x0 + x1) / 2, (y0 + y1) / 2))
