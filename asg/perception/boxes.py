"""Anchors, box encoding (SECOND residuals) and target assignment (NMS: nms.py; the IoU and
refinement branches' boxes: branch_boxes.py).

Boxes are (M, 7) x, y, z, l, w, h, yaw in the detecting frame (metres, radians). Anchors lie on
the head grid (cell centres), ``len(anchors) x len(rotations)`` per cell, ordered
(cell row y, cell column x, size, rotation).
"""
from __future__ import annotations

import math

import numpy as np
import torch

from sumo_scenarios.geometry import wrap_rad

from .config import DetectorConfig

#: the direction classifier's bin boundary is at this yaw (rad)
DIR_OFFSET = math.pi / 4


def make_anchors(cfg: DetectorConfig) -> np.ndarray:
    """(H * W * A, 7) anchors in the detecting frame."""
    n = cfg.head_size
    step = 2 * cfg.range_m / n
    centres = -cfg.range_m + step * (np.arange(n) + 0.5)
    yy, xx = np.meshgrid(centres, centres, indexing="ij")
    per_cell = [(l, w, h, math.radians(r)) for (l, w, h) in cfg.anchors for r in cfg.anchor_rotations_deg]
    a = np.zeros((n, n, len(per_cell), 7))
    for k, (l, w, h, r) in enumerate(per_cell):
        a[:, :, k] = np.stack(np.broadcast_arrays(xx, yy, cfg.anchor_z_m, l, w, h, r), axis=-1)
    return a.reshape(-1, 7)


def limit_period(x, offset: float = 0.5, period: float = math.pi):
    return x - np.floor(x / period + offset) * period if isinstance(x, np.ndarray) else x - torch.floor(x / period + offset) * period


def encode(gt: np.ndarray, anchors: np.ndarray) -> np.ndarray:
    """Residuals (M, 7) of boxes against their anchors."""
    diag = np.hypot(anchors[:, 3], anchors[:, 4])
    return np.stack([
        (gt[:, 0] - anchors[:, 0]) / diag, (gt[:, 1] - anchors[:, 1]) / diag, (gt[:, 2] - anchors[:, 2]) / anchors[:, 5],
        np.log(gt[:, 3] / anchors[:, 3]), np.log(gt[:, 4] / anchors[:, 4]), np.log(gt[:, 5] / anchors[:, 5]),
        gt[:, 6] - anchors[:, 6],
    ], axis=1)


def decode(res: torch.Tensor, anchors: torch.Tensor) -> torch.Tensor:
    """Boxes (..., 7) from residuals (..., 7) and anchors (..., 7)."""
    diag = torch.sqrt(anchors[..., 3] ** 2 + anchors[..., 4] ** 2)
    return torch.stack([
        res[..., 0] * diag + anchors[..., 0], res[..., 1] * diag + anchors[..., 1],
        res[..., 2] * anchors[..., 5] + anchors[..., 2],
        torch.exp(res[..., 3].clamp(max=4)) * anchors[..., 3], torch.exp(res[..., 4].clamp(max=4)) * anchors[..., 4],
        torch.exp(res[..., 5].clamp(max=4)) * anchors[..., 5], res[..., 6] + anchors[..., 6],
    ], dim=-1)


def top_candidates(scores: torch.Tensor, min_score: float, top_k: int) -> torch.Tensor:
    """Indices of the anchors whose score (A,) is at least ``min_score``, at most ``top_k`` of them
    (the highest): the candidates inference decodes."""
    keep = torch.nonzero(scores >= min_score).squeeze(1)
    if len(keep) > top_k:
        keep = keep[torch.topk(scores[keep], top_k).indices]
    return keep


def decode_with_direction(res: torch.Tensor, dir_logits: torch.Tensor, anchors: torch.Tensor) -> np.ndarray:
    """Boxes (K, 7) float64 from residuals (K, 7), direction logits (K, 2) and anchors (K, 7): yaw
    from the residual folded to [0, pi) past DIR_OFFSET, turned by pi where the direction bin says
    so, wrapped to (-pi, pi]."""
    boxes = decode(res, anchors)
    rot = limit_period(boxes[:, 6] - DIR_OFFSET, 0.0, math.pi)
    boxes[:, 6] = rot + DIR_OFFSET + math.pi * torch.argmax(dir_logits, dim=-1).float()
    bx = boxes.numpy().astype(np.float64)
    bx[:, 6] = wrap_rad(bx[:, 6])
    return bx


def _aligned_iou(anchors: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """Axis-aligned BEV IoU (A, M): each ground-truth box turned to the nearer of 0 / 90 degrees."""
    yaw = np.abs(limit_period(gt[:, 6], 0.5, math.pi))
    swap = yaw > math.pi / 4
    gl = np.where(swap, gt[:, 4], gt[:, 3])
    gw = np.where(swap, gt[:, 3], gt[:, 4])
    a_swap = np.abs(limit_period(anchors[:, 6], 0.5, math.pi)) > math.pi / 4
    al = np.where(a_swap, anchors[:, 4], anchors[:, 3])
    aw = np.where(a_swap, anchors[:, 3], anchors[:, 4])
    ix = np.minimum(anchors[:, None, 0] + al[:, None] / 2, gt[None, :, 0] + gl[None] / 2) - np.maximum(
        anchors[:, None, 0] - al[:, None] / 2, gt[None, :, 0] - gl[None] / 2)
    iy = np.minimum(anchors[:, None, 1] + aw[:, None] / 2, gt[None, :, 1] + gw[None] / 2) - np.maximum(
        anchors[:, None, 1] - aw[:, None] / 2, gt[None, :, 1] - gw[None] / 2)
    inter = np.clip(ix, 0, None) * np.clip(iy, 0, None)
    return inter / (al[:, None] * aw[:, None] + gl[None] * gw[None] - inter)


def assign_targets(anchors: np.ndarray, gt: np.ndarray, cfg: DetectorConfig):
    """Per anchor: label (1 positive, 0 negative, -1 ignored), box residuals (A, 7), direction bin.

    Positive: IoU > pos_iou with a box, or the best anchor of a box; negative: IoU < neg_iou with all.
    """
    n = len(anchors)
    labels = np.zeros(n, dtype=np.int64)
    res = np.zeros((n, 7), dtype=np.float32)
    dirs = np.zeros(n, dtype=np.int64)
    if not len(gt):
        return labels, res, dirs
    # only anchors near some box can overlap it
    near = np.zeros(n, dtype=bool)
    reach = np.hypot(gt[:, 3], gt[:, 4]).max() / 2 + 6.0
    for g in gt:
        near |= (np.abs(anchors[:, 0] - g[0]) < reach) & (np.abs(anchors[:, 1] - g[1]) < reach)
    idx = np.flatnonzero(near)
    iou = _aligned_iou(anchors[idx], gt)
    best_gt = iou.argmax(axis=1)
    best_iou = iou.max(axis=1)
    lab = np.where(best_iou >= cfg.pos_iou, 1, np.where(best_iou < cfg.neg_iou, 0, -1))
    forced = iou.argmax(axis=0)
    ok = iou[forced, np.arange(len(gt))] > 0
    lab[forced[ok]] = 1
    best_gt[forced[ok]] = np.arange(len(gt))[ok]
    labels[idx] = lab
    pos = idx[lab == 1]
    matched = gt[best_gt[lab == 1]]
    res[pos] = encode(matched, anchors[pos])
    dirs[pos] = (limit_period(matched[:, 6] - DIR_OFFSET, 0.0, 2 * math.pi) >= math.pi).astype(np.int64)
    return labels, res, dirs
