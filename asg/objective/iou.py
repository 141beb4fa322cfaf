"""Rotated bird's-eye-view IoU of boxes (x, y, z, l, w, h, yaw) in metres and radians."""
from __future__ import annotations

import numpy as np

from ..scene.agent import footprints_xy


def bev_footprints(boxes: np.ndarray) -> np.ndarray:
    """(M, 7) boxes → (M, 4, 2) footprint corners, counter-clockwise (scene.agent.footprints_xy)."""
    boxes = np.asarray(boxes, dtype=float).reshape(-1, 7)
    return footprints_xy(boxes[:, 0], boxes[:, 1], boxes[:, 6], boxes[:, 3], boxes[:, 4])


def bev_iou_matrix(a: np.ndarray, b: np.ndarray | None = None) -> np.ndarray:
    """(Ma, Mb) rotated BEV IoU of boxes ``a`` (Ma, 7) with ``b`` (Mb, 7) (None: ``a`` with itself,
    each pair computed once); pairs whose circumscribed circles do not meet are 0 without clipping."""
    a = np.asarray(a, dtype=float).reshape(-1, 7)
    itself = b is None
    b = a if itself else np.asarray(b, dtype=float).reshape(-1, 7)
    out = np.zeros((len(a), len(b)))
    if not len(a) or not len(b):
        return out
    ra = np.hypot(a[:, 3], a[:, 4]) / 2
    rb = np.hypot(b[:, 3], b[:, 4]) / 2
    near = np.hypot(a[:, None, 0] - b[None, :, 0], a[:, None, 1] - b[None, :, 1]) < ra[:, None] + rb[None, :]
    if itself:
        near = np.triu(near, 1)
    ii, jj = np.nonzero(near)
    if len(ii):
        fa = bev_footprints(a)
        fb = fa if itself else bev_footprints(b)
        inter = rectangle_overlap_m2(fa[ii], fb[jj])
        area_a, area_b = a[:, 3] * a[:, 4], b[:, 3] * b[:, 4]
        out[ii, jj] = inter / np.maximum(area_a[ii] + area_b[jj] - inter, 1e-9)
    if itself:
        out += out.T
        area = a[:, 3] * a[:, 4]
        out[np.diag_indices(len(a))] = area / np.maximum(area, 1e-9)  # 1, or 0 for a box of no area, as clipped
    return out


#: the most corners the overlap of two rectangles has (each of the eight edges adds at most one)
_MAX_CORNERS = 8


def rectangle_overlap_m2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Area (P,) of the overlap of rectangles ``a`` (P, 4, 2) and ``b`` (P, 4, 2), pair by pair,
    both counter-clockwise: ``a`` clipped by each edge of ``b`` in turn (Sutherland-Hodgman), every
    pair at once on fixed arrays of ``_MAX_CORNERS`` corners and a count, then the shoelace formula.
    In numpy, without a polygon object a pair (agrees with shapely's overlay to ~1e-12 m^2)."""
    p = len(a)
    poly = np.zeros((p, _MAX_CORNERS, 2))
    poly[:, :4] = a
    count = np.full(p, 4)
    slot = np.arange(_MAX_CORNERS)
    rows = np.arange(p)[:, None]
    # each slot's next corner, cyclically within the polygon's count: (P, C)
    following = lambda count: np.where(slot + 1 < count[:, None], slot + 1, 0)  # noqa: E731
    for e in range(4):
        start, edge = b[:, e], b[:, (e + 1) % 4] - b[:, e]  # (P, 2)
        valid = slot < count[:, None]  # (P, C)
        side = edge[:, None, 0] * (poly[..., 1] - start[:, None, 1]) - edge[:, None, 1] * (poly[..., 0] - start[:, None, 0])
        nxt = following(count)
        side_next, poly_next = side[rows, nxt], poly[rows, nxt]
        inside = (side >= 0) & valid
        crosses = valid & ((side >= 0) != (side_next >= 0))
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(crosses, side / (side - side_next), 0.0)
        # each corner gives itself (if inside) then the crossing (if its edge crosses), in order
        keep = np.stack([inside, crosses], axis=2).reshape(p, 2 * _MAX_CORNERS)
        cand = np.stack([poly, poly + t[..., None] * (poly_next - poly)], axis=2).reshape(p, 2 * _MAX_CORNERS, 2)
        r, c = np.nonzero(keep)
        at = np.cumsum(keep, axis=1)[r, c] - 1
        fits = at < _MAX_CORNERS
        poly = np.zeros((p, _MAX_CORNERS, 2))
        poly[r[fits], at[fits]] = cand[r[fits], c[fits]]
        count = np.minimum(keep.sum(axis=1), _MAX_CORNERS)
    poly_next = poly[rows, following(count)]
    cross = (poly[..., 0] * poly_next[..., 1] - poly_next[..., 0] * poly[..., 1]) * (slot < count[:, None])
    return np.maximum(cross.sum(axis=1) / 2, 0.0)
