"""The boxes of the IoU and refinement branches: residuals from a candidate's decoded box to its
vehicle's, applying them, and the branches' training targets.

Boxes are (K, 7) x, y, z, l, w, h, yaw in the detecting frame (metres, radians).
"""
from __future__ import annotations

import math

import numpy as np
import torch

from sumo_scenarios.geometry import wrap_rad

from ..objective.iou import bev_iou_matrix
from .boxes import decode, encode, limit_period, top_candidates


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
    out[:, 6] = wrap_rad(out[:, 6])
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
