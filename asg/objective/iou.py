"""Rotated bird's-eye-view IoU of boxes (x, y, z, l, w, h, yaw) in metres and radians."""
from __future__ import annotations

import numpy as np
import shapely

from ..scene.agent import footprints_xy


def bev_footprints(boxes: np.ndarray) -> np.ndarray:
    """(M, 7) boxes → (M, 4, 2) footprint corners, counter-clockwise (scene.agent.footprints_xy)."""
    boxes = np.asarray(boxes, dtype=float).reshape(-1, 7)
    return footprints_xy(boxes[:, 0], boxes[:, 1], boxes[:, 6], boxes[:, 3], boxes[:, 4])


def bev_polygons(boxes: np.ndarray) -> np.ndarray:
    """(M, 7) boxes → (M,) shapely polygons of their footprints."""
    if not len(boxes):
        return np.empty(0, dtype=object)
    return shapely.polygons(bev_footprints(boxes))


def bev_iou_matrix(a: np.ndarray, b: np.ndarray, polys_a: np.ndarray | None = None,
                   polys_b: np.ndarray | None = None) -> np.ndarray:
    """(Ma, Mb) rotated BEV IoU; pairs whose circumscribed circles do not meet are 0 without clipping.

    ``polys_a`` / ``polys_b``: the boxes' footprint polygons (bev_polygons) when already built.
    """
    a = np.asarray(a, dtype=float).reshape(-1, 7)
    b = np.asarray(b, dtype=float).reshape(-1, 7)
    out = np.zeros((len(a), len(b)))
    if not len(a) or not len(b):
        return out
    ra = np.hypot(a[:, 3], a[:, 4]) / 2
    rb = np.hypot(b[:, 3], b[:, 4]) / 2
    d = np.hypot(a[:, None, 0] - b[None, :, 0], a[:, None, 1] - b[None, :, 1])
    ii, jj = np.nonzero(d < ra[:, None] + rb[None, :])
    if not len(ii):
        return out
    pa = bev_polygons(a) if polys_a is None else polys_a
    pb = bev_polygons(b) if polys_b is None else polys_b
    out[ii, jj] = polygon_iou(pa[ii], a[ii, 3] * a[ii, 4], pb[jj], b[jj, 3] * b[jj, 4])
    return out


def polygon_iou(pa, area_a, pb, area_b) -> np.ndarray:
    """Element-wise (broadcast) IoU of footprint polygons whose areas (m^2) are given."""
    inter = shapely.area(shapely.intersection(pa, pb))
    return inter / np.maximum(area_a + area_b - inter, 1e-9)
