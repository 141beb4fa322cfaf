"""Anchors, box encoding (SECOND residuals), target assignment and rotated NMS.

Boxes are (M, 7) x, y, z, l, w, h, yaw in the detecting frame (metres, radians). Anchors lie on
the head grid (cell centres), ``len(anchors) x len(rotations)`` per cell, ordered
(cell row y, cell column x, size, rotation).
"""
from __future__ import annotations

import math

import numpy as np
import torch

from ..objective.iou import bev_iou_matrix, bev_polygons, polygon_iou
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
    bx[:, 6] = np.angle(np.exp(1j * bx[:, 6]))
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
    out[:, 6] = np.angle(np.exp(1j * (kept[:, 6] + (w * dyaw).sum(axis=1))))
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


def refinement_residuals(gt: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Residuals (K, 7) from decoded boxes (K, 7) to their vehicles' boxes gt (K, 7): the SECOND
    encoding with the boxes as anchors, the yaw difference folded into [-pi/2, pi/2) (BEV IoU and
    the kept direction do not depend on which way a box faces)."""
    res = encode(gt, boxes)
    res[:, 6] = limit_period(res[:, 6], 0.5, math.pi)
    return res


def refine_boxes(boxes: np.ndarray, residuals: torch.Tensor) -> np.ndarray:
    """Boxes (K, 7) float64 moved by the refinement branch's residuals (K, 7), yaw wrapped to
    (-pi, pi]."""
    out = decode(residuals.float(), torch.from_numpy(boxes).float()).numpy().astype(np.float64)
    out[:, 6] = np.angle(np.exp(1j * out[:, 6]))
    return out


#: the refinement branch learns from candidates whose decoded box overlaps a vehicle at least this
REFINE_MIN_IOU = 0.3


def best_match(boxes: np.ndarray, gt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per box of ``boxes`` (N, 7), its best BEV IoU (N,) with the ground-truth boxes ``gt`` (M, 7)
    and that vehicle's box (N, 7); IoU 0 and zero boxes when there is no ground truth."""
    if not len(boxes) or not len(gt):
        return np.zeros(len(boxes)), np.zeros((len(boxes), 7))
    iou = bev_iou_matrix(boxes, gt)
    return iou.max(axis=1), gt[iou.argmax(axis=1)]


def branch_targets(cls: torch.Tensor, box: torch.Tensor, anchors: torch.Tensor, labels: torch.Tensor,
                   gt_boxes: list[np.ndarray], min_score: float = 0.1,
                   top_k: int = 300) -> list[tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]]:
    """Training anchors of the IoU and refinement branches and their targets, per sample of a batch.

    ``cls`` (B, A) logits, ``box`` (B, A, 7) residuals, ``anchors`` (A, 7), ``labels`` (B, A) from
    :func:`assign_targets`, ``gt_boxes[b]`` (M_b, 7) the sample's boxes. Per sample the anchors are
    those inference keeps (class score >= ``min_score``, at most ``top_k``) and the positives; each
    IoU target is the best BEV IoU of the anchor's decoded box with a ground-truth box (0 with
    none); where that IoU is at least REFINE_MIN_IOU the anchor also gets the refinement residuals
    to that box. Returns per sample (anchor indices (K,), IoU targets (K,) float32, refinement
    mask (K,) bool, residuals (R, 7) float32 of the R masked anchors).
    """
    out = []
    with torch.no_grad():
        for b in range(cls.shape[0]):
            cand = top_candidates(torch.sigmoid(cls[b]), min_score, top_k)
            idx = torch.unique(torch.cat([cand, torch.nonzero(labels[b] == 1).squeeze(1)]))
            gt = np.asarray(gt_boxes[b], dtype=float).reshape(-1, 7)
            decoded = decode(box[b, idx], anchors[idx]).numpy().astype(np.float64)
            best, match = best_match(decoded, gt)
            near = best >= REFINE_MIN_IOU
            res = refinement_residuals(match[near], decoded[near])
            mask = torch.from_numpy(near)
            out.append((idx, torch.from_numpy(best.astype(np.float32)), mask, torch.from_numpy(res.astype(np.float32))))
    return out
