"""The point stage: each final box refined from the LiDAR points inside it.

The anchor head places a box from BEV features of 1 m cells; the points on the vehicle say where
its faces are to a few centimetres. The stage takes each detection after NMS and voting, gathers
the points of the cloud the detector saw inside the box grown by GROW_M on every side, in the box's
frame, and a PointNet (a per-point MLP, a max over the points, an MLP with the box's size, score
and point count) predicts the residuals to the vehicle's box and its IoU with it (for rescoring).

Frames and units: boxes (K, 7) x, y, z, l, w, h, yaw and clouds (N, 4) x, y, z, intensity in the
detecting agent's sensor frame (metres, radians). Residuals (K, 7): the centre offset along the
box, across it and up (m), log ratios of length, width and height, the yaw offset folded into
[-pi/2, pi/2) (a box's IoU does not see its heading; the detector's direction is kept).

Its weights are a file of their own beside the detector's (``NAME.stage.pt``), trained by
``asg train --fusion F --point-stage`` on the frozen detector (asg.training.point_stage_fit).
"""
from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from sumo_scenarios.geometry import wrap_rad

from .boxes import limit_period
from .branch_boxes import best_match

#: points a box keeps (evenly spaced over those inside when more), and the margin (m) the box is
#: grown by on every side to gather them
POINTS = 64
GROW_M = 0.5
#: per-point features: along, across, up (m), the same over half the length, width, height, intensity
POINT_FEATURES = 7
#: per-box features: length, width, height (m), score, log(1 + points)
BOX_FEATURES = 5
#: a box learns residuals from the vehicle it overlaps by at least this BEV IoU
MIN_IOU = 0.3
#: typical size of each residual: the stage predicts in these units and its loss weighs the seven alike
RES_SCALE = (0.3, 0.15, 0.1, 0.08, 0.06, 0.06, 0.1)


class PointStage(nn.Module):
    """Points (K, POINTS, POINT_FEATURES), their mask (K, POINTS) and box features (K, BOX_FEATURES)
    → residuals (K, 7) and IoU logits (K,)."""

    def __init__(self):
        super().__init__()
        self.point = nn.Sequential(nn.Linear(POINT_FEATURES, 64), nn.ReLU(), nn.Linear(64, 128), nn.ReLU(),
                                   nn.Linear(128, 256))
        self.head = nn.Sequential(nn.Linear(256 + BOX_FEATURES, 256), nn.ReLU(), nn.Linear(256, 128), nn.ReLU(),
                                  nn.Linear(128, 8))
        self.register_buffer("res_scale", torch.tensor(RES_SCALE), persistent=False)

    def forward(self, feats: torch.Tensor, mask: torch.Tensor, box: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        h = self.point(feats).masked_fill(~mask[..., None], -1e4).amax(dim=1)
        h = torch.where(mask.any(dim=1, keepdim=True), h, torch.zeros_like(h))  # a box with no points
        out = self.head(torch.cat([h, box], dim=1))
        return out[:, :7] * self.res_scale, out[:, 7]


def box_points(boxes: np.ndarray, cloud: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The points of ``cloud`` (N, 4) inside each of ``boxes`` (K, 7) grown by GROW_M: features
    (K, POINTS, POINT_FEATURES) float32 in the box's frame and the mask (K, POINTS) of real points.
    Deterministic: with more than POINTS inside, evenly spaced ones in the cloud's order.

    Each box tests only the points of the grid cells (``_CELL_M``) its grown footprint's circle
    reaches (:class:`_BevGrid`), in the cloud's order: the same points, the same float32 sums.
    Every box's candidate points are tested at once (one array of (box, point) pairs), each pair
    by the float32 operations a box's own loop would do."""
    feats = np.zeros((len(boxes), POINTS, POINT_FEATURES), dtype=np.float32)
    mask = np.zeros((len(boxes), POINTS), dtype=bool)
    if not len(boxes):
        return feats, mask
    xyz = np.ascontiguousarray(cloud[:, :3], dtype=np.float32)
    part = boxes.astype(np.float32)
    reach_m = np.hypot(boxes[:, 3] / 2 + GROW_M, boxes[:, 4] / 2 + GROW_M) + _CELL_SLACK_M
    box, cand = _BevGrid(xyz).near(boxes[:, :2], reach_m)  # (M,) each: a box and a point near it
    d = xyz[cand] - part[box, :3]  # (M, 3) in the cloud's axes, from the box's centre
    c, s = np.cos(part[:, 6])[box], np.sin(part[:, 6])[box]
    along, across = c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]
    half = part[:, 3:6] / 2 + GROW_M  # (K, 3) the grown box's half length, width, height
    inside = np.flatnonzero((np.abs(along) <= half[box, 0]) & (np.abs(across) <= half[box, 1])
                            & (np.abs(d[:, 2]) <= half[box, 2]))
    inside = inside[np.argsort(box[inside] * len(xyz) + cand[inside])]  # by box, then the cloud's order
    row, slot = _kept_points(box[inside], len(boxes))
    pair = inside[row]  # the kept pairs
    k = box[pair]
    local = np.stack([along[pair], across[pair], d[pair, 2]], axis=1)
    feats[k, slot, :3] = local
    feats[k, slot, 3:6] = local / (part[k, 3:6] / 2)
    feats[k, slot, 6] = cloud[cand[pair], 3]
    mask[k, slot] = True
    return feats, mask


def _kept_points(box: np.ndarray, boxes: int) -> tuple[np.ndarray, np.ndarray]:
    """Of the points inside the boxes (``box`` (n,) ascending: each point's box, in the cloud's
    order within a box), the ones a box keeps: all of them up to POINTS, else POINTS evenly spaced
    (``np.linspace``'s picks); returns their positions in ``box`` and their slots (0..POINTS-1)."""
    counts = np.bincount(box, minlength=boxes)
    first = np.cumsum(counts) - counts
    slot = np.arange(len(box)) - first[box]  # each point's rank among its box's
    keep = slot < POINTS
    for k in np.flatnonzero(counts > POINTS):
        picked = first[k] + np.linspace(0, counts[k] - 1, POINTS).astype(int)  # strictly increasing
        keep[first[k]:first[k] + counts[k]] = False
        keep[picked] = True
        slot[picked] = np.arange(POINTS)
    row = np.flatnonzero(keep)
    return row, slot[row]


#: the side (m) of the cells :func:`box_points` sorts a cloud's points into, and the margin (m)
#: added to a box's reach so that float32 rounding at its edge cannot leave a point out
_CELL_M = 2.0
_CELL_SLACK_M = 0.05


class _BevGrid:
    """A cloud's points (N, 3) sorted by the BEV cell (``_CELL_M`` square) they fall in."""

    def __init__(self, xyz: np.ndarray):
        finite = np.flatnonzero(np.isfinite(xyz[:, 0]) & np.isfinite(xyz[:, 1]))  # no other point is inside a box
        cx, cy = self._cells(xyz[finite, 0]), self._cells(xyz[finite, 1])
        self.y0 = int(cy.min()) if len(cy) else 0
        self.rows = int(cy.max()) - self.y0 + 1 if len(cy) else 1
        key = cx * self.rows + (cy - self.y0)
        # a stable sort of 16-bit keys is numpy's radix sort (the same order, several times faster)
        small = len(key) and -2 ** 15 <= key.min() and key.max() < 2 ** 15
        order = np.argsort(key.astype(np.int16) if small else key, kind="stable")
        self.order, self.keys = finite[order], key[order]

    @staticmethod
    def _cells(v) -> np.ndarray:
        return np.floor(np.asarray(v, dtype=np.float64) / _CELL_M).astype(np.int64)

    def near(self, centres_xy: np.ndarray, reach_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The points in the cells the square of half-side ``reach_m`` (K,) around each centre
        (K, 2) touches, as pairs: (M,) the centre's index, ascending, and (M,) the point's index
        (within a centre in the order of the cells, not the cloud's)."""
        xy = np.asarray(centres_xy, dtype=np.float64)
        r = np.asarray(reach_m, dtype=np.float64)
        x0, x1 = self._cells(xy[:, 0] - r), self._cells(xy[:, 0] + r)
        y0 = np.maximum(self._cells(xy[:, 1] - r), self.y0)
        y1 = np.minimum(self._cells(xy[:, 1] + r), self.y0 + self.rows - 1)
        columns = np.where(y1 >= y0, x1 - x0 + 1, 0)  # a centre whose rows miss the grid: none
        centre = np.repeat(np.arange(len(xy)), columns)  # one entry a (centre, column)
        column = x0[centre] + _ranks(columns)
        lo = np.searchsorted(self.keys, column * self.rows + (y0[centre] - self.y0), side="left")
        hi = np.searchsorted(self.keys, column * self.rows + (y1[centre] - self.y0), side="right")
        lengths = hi - lo
        return np.repeat(centre, lengths), self.order[np.repeat(lo, lengths) + _ranks(lengths)]


def _ranks(lengths: np.ndarray) -> np.ndarray:
    """0..n-1 for each n of ``lengths``, one after the other: (sum lengths,)."""
    starts = np.cumsum(lengths) - lengths
    return np.arange(int(lengths.sum())) - np.repeat(starts, lengths)


def box_features(boxes: np.ndarray, scores: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(K, BOX_FEATURES) float32: length, width, height, score, log(1 + points inside)."""
    return np.column_stack([boxes[:, 3:6], scores, np.log1p(mask.sum(axis=1))]).astype(np.float32)


def residual_targets(boxes: np.ndarray, gt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per box of ``boxes`` (K, 7): its best BEV IoU with ``gt`` (M, 7) (K,) and the residuals (K, 7)
    from it to that vehicle's box (zeros where there is no vehicle)."""
    best, match = best_match(boxes, gt)
    if not len(gt) or not len(boxes):
        return best, np.zeros((len(boxes), 7))
    d = match[:, :3] - boxes[:, :3]
    c, s = np.cos(boxes[:, 6]), np.sin(boxes[:, 6])
    turn = limit_period(wrap_rad(match[:, 6] - boxes[:, 6]), 0.5, math.pi)
    res = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], d[:, 2],
                           np.log(match[:, 3:6] / boxes[:, 3:6]), turn])
    return best, res


def apply_residuals(boxes: np.ndarray, res: np.ndarray) -> np.ndarray:
    """``boxes`` (K, 7) moved by residuals (K, 7) (the inverse of :func:`residual_targets`), yaw
    wrapped to (-pi, pi]."""
    out = boxes.astype(np.float64, copy=True)
    c, s = np.cos(boxes[:, 6]), np.sin(boxes[:, 6])
    out[:, 0] += c * res[:, 0] - s * res[:, 1]
    out[:, 1] += s * res[:, 0] + c * res[:, 1]
    out[:, 2] += res[:, 2]
    out[:, 3:6] *= np.exp(res[:, 3:6])
    out[:, 6] = wrap_rad(boxes[:, 6] + res[:, 6])
    return out


@torch.no_grad()
def refine(stage: PointStage, boxes: np.ndarray, scores: np.ndarray, cloud: np.ndarray,
           rescore_power: float) -> tuple[np.ndarray, np.ndarray]:
    """Boxes (K, 7) and scores (K,) after the stage: each box moved by its predicted residuals, each
    score ``score ** (1 - p) * predicted IoU ** p`` with p = ``rescore_power`` (0: unchanged)."""
    if not len(boxes):
        return boxes, scores
    feats, mask = box_points(boxes, cloud)
    res, iou_logit = stage(torch.from_numpy(feats), torch.from_numpy(mask),
                           torch.from_numpy(box_features(boxes, scores, mask)))
    moved = apply_residuals(boxes, res.double().numpy())
    if rescore_power > 0:
        scores = scores ** (1 - rescore_power) * torch.sigmoid(iou_logit).double().numpy() ** rescore_power
    return moved, scores


def stage_loss(stage: PointStage, batch: dict[str, torch.Tensor]) -> torch.Tensor:
    """Smooth-L1 (beta 0.5, in RES_SCALE units) of the residuals of the boxes with a vehicle (IoU >=
    MIN_IOU) plus the IoU branch's binary cross-entropy against the boxes' IoU → scalar. ``batch``:
    feats, mask, box (the stage's inputs), iou (K,), res (K, 7)."""
    res, iou_logit = stage(batch["feats"], batch["mask"], batch["box"])
    near = batch["iou"] >= MIN_IOU
    scale = stage.res_scale
    l_res = (F.smooth_l1_loss(res[near] / scale, batch["res"][near] / scale, beta=0.5) if near.any()
             else res.sum() * 0.0)
    return l_res + F.binary_cross_entropy_with_logits(iou_logit, batch["iou"])
