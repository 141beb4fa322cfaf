"""Rotated non-maximum suppression and box voting: the detector's last step.

Boxes are (N, 7) x, y, z, l, w, h, yaw in the detecting frame (metres, radians); scores (N,).
"""
from __future__ import annotations

import math

import numpy as np

from sumo_scenarios.geometry import wrap_rad

from ..objective.iou import bev_iou_matrix
from .boxes import limit_period
from .config import DetectorConfig


def rotated_nms(boxes: np.ndarray, scores: np.ndarray, iou_threshold: float, max_keep: int,
                iou: np.ndarray | None = None) -> np.ndarray:
    """Indices kept by greedy NMS on rotated BEV IoU, in descending score (the first of equal
    scores first). ``iou``: the boxes' IoU matrix (N, N) (bev_iou_matrix) when already computed."""
    order = np.argsort(-np.asarray(scores, dtype=float), kind="stable")
    boxes = np.asarray(boxes, dtype=float)
    if not len(boxes):
        return order[:0]
    iou = bev_iou_matrix(boxes) if iou is None else iou
    above = iou[np.ix_(order, order)] > iou_threshold  # (N, N) in score order
    suppressed = np.zeros(len(order), dtype=bool)
    keep = []
    for i in range(len(order)):
        if suppressed[i]:
            continue
        keep.append(i)
        if len(keep) >= max_keep:
            break
        suppressed[i + 1:] |= above[i, i + 1:]
    return order[np.array(keep, dtype=np.int64)]


def vote_boxes(boxes: np.ndarray, scores: np.ndarray, keep: np.ndarray, iou_threshold: float,
               power: float, iou: np.ndarray | None = None) -> np.ndarray:
    """Box voting: each kept box (K, 7) replaced by the average of all candidates (N, 7) whose BEV
    IoU with it is at least ``iou_threshold``, weighted by score ** power.

    Yaw is averaged as the offset from the kept box's yaw folded into [-pi/2, pi/2) (a candidate
    facing the other way counts as the same heading), so the kept direction is preserved.
    ``iou``: the candidates' IoU matrix (N, N) (bev_iou_matrix) when already computed.
    """
    boxes = np.asarray(boxes, dtype=float)
    kept = boxes[keep]
    if not len(kept):
        return kept.copy()
    member = (bev_iou_matrix(kept, boxes) if iou is None else iou[keep]) >= iou_threshold  # (K, N)
    member[np.arange(len(keep)), keep] = True
    w = member * (np.asarray(scores, dtype=float)[None, :] ** power)  # (K, N)
    w /= w.sum(axis=1, keepdims=True)
    out = kept.copy()
    out[:, :6] = w @ boxes[:, :6]
    dyaw = limit_period(boxes[None, :, 6] - kept[:, None, 6], 0.5, math.pi)
    out[:, 6] = wrap_rad(kept[:, 6] + (w * dyaw).sum(axis=1))
    return out


def select_boxes(boxes: np.ndarray, scores: np.ndarray, cfg: DetectorConfig) -> tuple[np.ndarray, np.ndarray]:
    """Rotated NMS, then box voting when ``cfg.vote_iou`` > 0: (boxes (K, 7), scores (K,)). The
    candidates' IoU is computed once, for the pairs whose circles meet, and serves both."""
    boxes = np.asarray(boxes, dtype=float)
    scores = np.asarray(scores, dtype=float)
    iou = bev_iou_matrix(boxes)
    keep = rotated_nms(boxes, scores, cfg.nms_iou, cfg.max_detections, iou)
    if cfg.vote_iou <= 0:
        return boxes[keep], scores[keep]
    return vote_boxes(boxes, scores, keep, cfg.vote_iou, cfg.vote_power, iou), scores[keep]
