"""Rotated bird's-eye-view IoU of boxes (x, y, z, l, w, h, yaw) in metres and radians."""
from __future__ import annotations

import numpy as np
import shapely

from ..scene.agent import footprint_xy


def bev_polygons(boxes: np.ndarray) -> np.ndarray:
    """(M, 7) boxes → (M,) shapely polygons of their footprints."""
    if not len(boxes):
        return np.empty(0, dtype=object)
    corners = np.stack([footprint_xy(b[0], b[1], b[6], b[3], b[4]) for b in boxes])
    return shapely.polygons(corners)


def bev_iou_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(Ma, Mb) rotated BEV IoU; pairs whose circumscribed circles do not meet are 0 without clipping."""
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
    pa, pb = bev_polygons(a), bev_polygons(b)
    out[ii, jj] = polygon_iou(pa[ii], a[ii, 3] * a[ii, 4], pb[jj], b[jj, 3] * b[jj, 4])
    return out


def polygon_iou(pa, area_a, pb, area_b) -> np.ndarray:
    """Element-wise (broadcast) IoU of footprint polygons whose areas (m^2) are given."""
    inter = shapely.area(shapely.intersection(pa, pb))
    return inter / np.maximum(area_a + area_b - inter, 1e-9)
