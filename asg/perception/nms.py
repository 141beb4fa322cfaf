"""Rotated non-maximum suppression and box voting: the detector's last step.

Boxes are (N, 7) x, y, z, l, w, h, yaw in the detecting frame (metres, radians); scores (N,).
"""
from __future__ import annotations

import math

import numpy as np

from sumo_scenarios.geometry import wrap_rad

from ..objective.iou import bev_iou_matrix, bev_polygons, polygon_iou
from .boxes import limit_period
from .config import DetectorConfig


def rotated_nms(boxes: np.ndarray, scores: np.ndarray, iou_threshold: float, max_keep: int,
                polys: np.ndarray | None = None) -> np.ndarray:
    """Indices kept by greedy NMS on rotated BEV IoU, in descending score.

    Each kept box is clipped (shapely) only against the later, not yet suppressed boxes whose
    circumscribed circles meet its own, so the cost follows the number of kept boxes rather than
    all pairs. ``polys``: the boxes' footprint polygons (bev_polygons) when already built.
    """
    order = np.argsort(-scores, kind="stable")
    boxes = np.asarray(boxes, dtype=float)[order]
    n = len(boxes)
    if not n:
        return order[:0]
    polys = bev_polygons(boxes) if polys is None else np.asarray(polys)[order]
    radius = np.hypot(boxes[:, 3], boxes[:, 4]) / 2
    area = boxes[:, 3] * boxes[:, 4]
    suppressed = np.zeros(n, dtype=bool)
    keep = []
    for i in range(n):
        if suppressed[i]:
            continue
        keep.append(i)
        if len(keep) >= max_keep:
            break
        rest = np.arange(i + 1, n)
        near = ~suppressed[i + 1:] & (np.hypot(boxes[i + 1:, 0] - boxes[i, 0], boxes[i + 1:, 1] - boxes[i, 1])
                                      < radius[i] + radius[i + 1:])
        cand = rest[near]
        if len(cand):
            iou = polygon_iou(polys[i], area[i], polys[cand], area[cand])
            suppressed[cand[iou > iou_threshold]] = True
    return order[np.array(keep, dtype=np.int64)]


def vote_boxes(boxes: np.ndarray, scores: np.ndarray, keep: np.ndarray, iou_threshold: float,
               power: float, polys: np.ndarray | None = None) -> np.ndarray:
    """Box voting: each kept box (K, 7) replaced by the average of all candidates (N, 7) whose BEV
    IoU with it is at least ``iou_threshold``, weighted by score ** power.

    Yaw is averaged as the offset from the kept box's yaw folded into [-pi/2, pi/2) (a candidate
    facing the other way counts as the same heading), so the kept direction is preserved.
    ``polys``: the candidates' footprint polygons (bev_polygons) when already built.
    """
    boxes = np.asarray(boxes, dtype=float)
    kept = boxes[keep]
    if not len(kept):
        return kept.copy()
    polys = bev_polygons(boxes) if polys is None else polys
    member = bev_iou_matrix(kept, boxes, polys[keep], polys) >= iou_threshold  # (K, N)
    member[np.arange(len(keep)), keep] = True
    w = member * (np.asarray(scores, dtype=float)[None, :] ** power)  # (K, N)
    w /= w.sum(axis=1, keepdims=True)
    out = kept.copy()
    out[:, :6] = w @ boxes[:, :6]
    dyaw = limit_period(boxes[None, :, 6] - kept[:, None, 6], 0.5, math.pi)
    out[:, 6] = wrap_rad(kept[:, 6] + (w * dyaw).sum(axis=1))
    return out


def select_boxes(boxes: np.ndarray, scores: np.ndarray, cfg: DetectorConfig) -> tuple[np.ndarray, np.ndarray]:
    """Rotated NMS, then box voting when ``cfg.vote_iou`` > 0: (boxes (K, 7), scores (K,))."""
    boxes = np.asarray(boxes, dtype=float)
    scores = np.asarray(scores, dtype=float)
    polys = bev_polygons(boxes)
    keep = rotated_nms(boxes, scores, cfg.nms_iou, cfg.max_detections, polys)
    if cfg.vote_iou <= 0:
        return boxes[keep], scores[keep]
    return vote_boxes(boxes, scores, keep, cfg.vote_iou, cfg.vote_power, polys), scores[keep]
