"""Average precision as the cooperative-perception framework computes it, two ways.

Per frame, detections are matched greedily in score order to the unmatched ground-truth box of
highest rotated BEV IoU (a true positive if IoU >= threshold). Then the detections of all frames
are ranked, and AP is the VOC all-point interpolated area under the precision envelope. The ranking
is the AP method (``AP_METHODS``):

- ``global`` (ours, the default): detections of *all* frames sorted by score together, as AP is
  defined (OpenCOOD's later ``--global_sort_detections``);
- ``per-frame`` (the paper's yardstick): each frame's detections in its own score order, the frames'
  lists concatenated in frame order with no sort across frames, as OpenCOOD's evaluation ran when
  the V2XP-ASG paper was scored ("OPV2V paper does not perform the global sort"). It depends on the
  frame order and usually reads lower: a confident false positive of a late frame is counted after
  every detection of the frames before it.
"""
from __future__ import annotations

import enum
from typing import Iterable, Sequence

import numpy as np

from .iou import bev_iou_matrix

Frame = tuple[np.ndarray, np.ndarray, np.ndarray]  # pred_boxes (N, 7), pred_scores (N,), gt_boxes (M, 7)

#: the IoU thresholds every table reports (AP@0.3/0.5/0.7, the paper's), and their keys in results
REPORTED_THRESHOLDS = (0.3, 0.5, 0.7)
AP_KEYS = tuple(f"{t:g}" for t in REPORTED_THRESHOLDS)


def match_frame(pred_boxes: np.ndarray, pred_scores: np.ndarray, gt_boxes: np.ndarray,
                iou_threshold: float) -> np.ndarray:
    """(N,) bool: which detections are true positives, greedy in descending score."""
    return greedy_match(pred_boxes, pred_scores, gt_boxes, iou_threshold) >= 0


def greedy_match(pred_boxes: np.ndarray, pred_scores: np.ndarray, gt_boxes: np.ndarray,
                 iou_threshold: float) -> np.ndarray:
    """The greedy matching of :func:`match_frame`: (N,) int, the ground-truth box each detection
    found (index into ``gt_boxes``), -1 for a false positive."""
    pred_boxes = np.asarray(pred_boxes, dtype=float).reshape(-1, 7)
    gt_boxes = np.asarray(gt_boxes, dtype=float).reshape(-1, 7)
    if not len(pred_boxes) or not len(gt_boxes):
        return np.full(len(pred_boxes), -1, dtype=int)
    return greedy_match_iou(bev_iou_matrix(pred_boxes, gt_boxes), pred_scores, iou_threshold)


def greedy_match_iou(iou: np.ndarray, pred_scores: np.ndarray, iou_threshold: float) -> np.ndarray:
    """:func:`greedy_match` from the BEV IoU matrix (N, M) of the detections against the ground truth."""
    found = np.full(iou.shape[0], -1, dtype=int)
    if not iou.size:
        return found
    taken = np.zeros(iou.shape[1], dtype=bool)
    for i in np.argsort(-np.asarray(pred_scores), kind="stable"):
        cand = np.where(taken, -1.0, iou[i])
        j = int(np.argmax(cand))
        if cand[j] >= iou_threshold:
            found[i] = j
            taken[j] = True
    return found


#: one frame matched at several thresholds: {threshold: (scores (N,), true-positive flags (N,), ground-truth count)}
FrameMatches = dict[float, tuple[np.ndarray, np.ndarray, int]]


def frame_matches(frame: Frame, thresholds: Sequence[float] = REPORTED_THRESHOLDS) -> FrameMatches:
    """A frame's detections matched at each threshold, its IoU matrix computed once (what AP over
    many frames needs of it; see :func:`ap_by_method_from_matches`)."""
    pred_boxes, pred_scores, gt_boxes = frame
    pred = np.asarray(pred_boxes, dtype=float).reshape(-1, 7)
    gt = np.asarray(gt_boxes, dtype=float).reshape(-1, 7)
    scores = np.asarray(pred_scores, dtype=float).reshape(-1)
    iou = bev_iou_matrix(pred, gt) if len(pred) and len(gt) else np.zeros((len(pred), len(gt)))
    return {t: (scores, greedy_match_iou(iou, scores, t) >= 0, len(gt)) for t in thresholds}


def voc_ap(recall: np.ndarray, precision: np.ndarray) -> float:
    """VOC all-point interpolation: area under the monotone precision envelope."""
    mrec = np.concatenate([[0.0], recall, [1.0]])
    mpre = np.concatenate([[0.0], precision, [0.0]])
    mpre = np.maximum.accumulate(mpre[::-1])[::-1]  # each point's precision: the best at any higher recall
    idx = np.nonzero(mrec[1:] != mrec[:-1])[0]
    return float(np.sum((mrec[idx + 1] - mrec[idx]) * mpre[idx + 1]))


class Yardstick(str, enum.Enum):
    """How detections of several frames are ranked (the AP method, ``--ap-method``; see the module
    docstring). A str: its value is what flags take, messages print and result files hold."""

    __str__ = str.__str__  # (enum.StrEnum from Python 3.11 on)
    __format__ = str.__format__

    GLOBAL = "global"  # ours: one sort across frames
    PER_FRAME = "per-frame"  # the paper's: each frame's own order, frames concatenated


#: the AP methods' names, the default first
AP_METHODS = tuple(y.value for y in Yardstick)
DEFAULT_AP_METHOD = Yardstick.GLOBAL


def check_ap_method(method: str) -> str:
    """``method`` if it is one of AP_METHODS, else one line of InputError."""
    if method not in AP_METHODS:
        from sumo_scenarios.errors import InputError

        raise InputError(f"unknown AP method '{method}'; choose {' or '.join(AP_METHODS)}")
    return method


def _matched(frames: Iterable[Frame], iou_threshold: float) -> tuple[list[np.ndarray], list[np.ndarray], int]:
    """Per frame the detections' scores (N_i,) and true-positive flags (N_i,), and the ground-truth count."""
    return _gathered([frame_matches(f, (iou_threshold,)) for f in frames], iou_threshold)


def _gathered(matches: Sequence[FrameMatches], iou_threshold: float) -> tuple[list[np.ndarray], list[np.ndarray], int]:
    """:func:`_matched` of frames already matched (:func:`frame_matches`) at ``iou_threshold``."""
    return ([m[iou_threshold][0] for m in matches], [m[iou_threshold][1] for m in matches],
            sum(m[iou_threshold][2] for m in matches))


def average_precision(frames: Iterable[Frame], iou_threshold: float, method: str = DEFAULT_AP_METHOD) -> float:
    """AP in [0, 1] over frames of ``(pred_boxes (N, 7), pred_scores (N,), gt_boxes (M, 7))``,
    ranked by ``method`` (AP_METHODS; per-frame keeps the frames' order).

    Boxes are x, y, z, l, w, h, yaw in metres and radians, in one frame per scene. With no ground
    truth at all, AP is 0.0 (there is nothing to recall).
    """
    return ap_from_matches(*_matched(frames, iou_threshold), method=method)


def ap_from_matches(scores: Sequence[np.ndarray], tps: Sequence[np.ndarray], n_gt: int,
                    method: str = DEFAULT_AP_METHOD) -> float:
    """AP in [0, 1] from frames already matched: per frame the detections' scores (N_i,) and
    true-positive flags (N_i,) bool from `match_frame`, and the ground-truth count over all frames.
    Detections are ranked by ``method`` (global: one sort across frames; per-frame: each frame's
    own score order, frames in the given order), then VOC all-point interpolation."""
    check_ap_method(method)
    if n_gt == 0:
        return 0.0
    if not scores or not sum(len(s) for s in scores):
        return 0.0
    if method == Yardstick.GLOBAL:
        s = np.concatenate(scores)
        tp = np.concatenate(tps)[np.argsort(-s, kind="stable")]
    else:
        tp = np.concatenate([np.asarray(t)[np.argsort(-np.asarray(s), kind="stable")] for s, t in zip(scores, tps)])
    ctp = np.cumsum(tp)
    cfp = np.cumsum(~tp)
    recall = ctp / n_gt
    precision = ctp / np.maximum(ctp + cfp, 1)
    return voc_ap(recall, precision)


def ap_text(ap, scale: float = 100.0, digits: int = 1, missing: str = "-", keys: Sequence[str] = AP_KEYS) -> str:
    """AP@0.3 / 0.5 / 0.7 (or at ``keys``) of a result mapping as text, e.g. "90.2 / 87.2 / 73.3"
    (``scale`` 100: percent; 1: fractions); ``missing`` for None."""
    if ap is None:
        return missing
    return " / ".join(f"{scale * ap[k]:.{digits}f}" for k in keys)


def both_yardsticks(ours, per_frame, key: str = "0.7", missing: str = "-") -> str:
    """AP at ``key`` in % by both yardsticks, "ours / per frame" (e.g. "84.5 / 74.0"), from two
    result mappings; ``missing`` for one that is None (a result from before it was recorded)."""
    return f"{ap_text(ours, keys=(key,), missing=missing)} / {ap_text(per_frame, keys=(key,), missing=missing)}"


def ap_at(frames: Sequence[Frame], thresholds: Sequence[float] = REPORTED_THRESHOLDS,
          method: str = DEFAULT_AP_METHOD) -> dict[str, float]:
    """{"0.3": AP, "0.5": AP, "0.7": AP} over the same frames, ranked by ``method`` (each frame's
    IoU matrix computed once for every threshold)."""
    matches = [frame_matches(f, thresholds) for f in frames]
    return {f"{t:g}": ap_from_matches(*_gathered(matches, t), method=method) for t in thresholds}


def ap_by_method(frames: Sequence[Frame], thresholds: Sequence[float] = REPORTED_THRESHOLDS) -> dict[str, dict[str, float]]:
    """{method: {"0.3": AP, ...}} for every method of AP_METHODS over the same frames (each frame
    matched once per threshold, its IoU matrix computed once)."""
    return ap_by_method_from_matches([frame_matches(f, thresholds) for f in frames], thresholds)


def ap_by_method_from_matches(matches: Sequence[FrameMatches],
                              thresholds: Sequence[float] = REPORTED_THRESHOLDS) -> dict[str, dict[str, float]]:
    """:func:`ap_by_method` from frames already matched (:func:`frame_matches`, frames in order)."""
    out: dict[str, dict[str, float]] = {m: {} for m in AP_METHODS}
    for t in thresholds:
        gathered = _gathered(matches, t)
        for method in AP_METHODS:
            out[method][f"{t:g}"] = ap_from_matches(*gathered, method=method)
    return out
