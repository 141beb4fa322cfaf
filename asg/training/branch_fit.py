"""``asg train --fusion F --iou-branch``: fit the refinement and IoU branches of a trained detector.

Both branches read the frozen detector's head features, so they are fitted apart from it, in two
stages:

1. *Collect.* The detector (eval mode, weights as shipped) runs over every training view, each
   ``passes`` times (first as is, then augmented by a seeded generator), and keeps every candidate
   inference could decode (class score >= ``min_score``, at most ``top_k`` a view): the head
   features of the patch around its cell (C * patch^2, float16), its anchor slot, its decoded box
   and the view's ground truth. The candidates are cached (``runs/train/NAME/branch-candidates.npz``,
   written atomically), so an interrupted run resumes at stage 2.
2. *Fit.* From a seeded initialisation, the refinement MLP learns the residuals from each candidate
   overlapping a vehicle by BEV IoU >= REFINE_MIN_IOU to that vehicle's box; then the IoU MLP learns,
   for every candidate, the best BEV IoU of its decoded box with the ground truth (``iou_target:
   refined``: of its refined box, the one rescoring scores at inference; on AttFuse that scored
   0.25 points of AP@0.7 lower on normal-val, see docs/detectors.md). Each: shuffled mini-batches
   of ``batch_size`` candidates, Adam with a one-cycle schedule (peak ``lr``), ``epochs`` passes.

Mini-batches drawn across the whole training set fit the branches better than the per-view
batches of a detector chunk (docs/detectors.md has the figures) and in a fraction of the time.
"""
from __future__ import annotations

import copy
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Literal

import numpy as np
import torch
from torch import nn

from sumo_scenarios.atomic import atomic_path
from sumo_scenarios.errors import InputError
from sumo_scenarios.npz import load_npz

from ..perception.boxes import decode_with_direction, top_candidates
from ..perception.branch_boxes import REFINE_MIN_IOU, best_match, refine_boxes, refinement_residuals
from ..perception.data import augment
from ..perception.feeds import Feed
from ..perception.head import iou_loss, patch_features, refine_loss
from ..perception.inference import fold_batch_norms
from ..scene.views import Views

CACHE_NAME = "branch-candidates.npz"


@dataclass(frozen=True)
class BranchFitConfig:
    """train.yaml's ``iou_branch`` block."""
    dataset: str = "detector-train"
    #: as TrainConfig.views: the ego's view of each frame, or each sensing agent's in turn
    views: Views = Views.ALL
    #: collection passes over the training views: the first as is, the others augmented
    passes: int = 2
    min_score: float = 0.1
    top_k: int = 300
    epochs: int = 4
    batch_size: int = 256
    lr: float = 0.003
    weight_decay: float = 0.0001
    seed: int = 11
    #: what the IoU branch learns: the best IoU of each candidate's decoded or refined box
    iou_target: Literal["decoded", "refined"] = "decoded"

    def __post_init__(self) -> None:
        for name, ok in (("passes", self.passes >= 1), ("min_score", 0 <= self.min_score < 1), ("top_k", self.top_k >= 1),
                         ("epochs", self.epochs >= 1), ("batch_size", self.batch_size >= 1), ("lr", self.lr > 0)):
            if not ok:
                raise InputError(f"train.yaml:iou_branch: {name} = {getattr(self, name)} is out of range")


@dataclass
class Candidates:
    """Collected candidates: ``features`` (N, C * patch^2) float16, ``slot`` (N,) anchor slot,
    ``boxes`` (N, 7) decoded boxes, ``view`` (N,) view index; ``gt`` (G, 7) all views' ground truth,
    view v's rows ``gt[gt_start[v]:gt_start[v + 1]]`` (``gt_start`` (V + 1,)). Boxes in the view's
    frame: x, y, z, l, w, h in metres, yaw in radians. ``collect_s``: the collection's wall time."""
    features: np.ndarray
    slot: np.ndarray
    boxes: np.ndarray
    view: np.ndarray
    gt: np.ndarray
    gt_start: np.ndarray
    collect_s: float = 0.0

    def save(self, path: Path) -> None:
        with atomic_path(path) as tmp:
            np.savez(tmp, **self.__dict__)

    @classmethod
    def load(cls, path: Path) -> "Candidates":
        try:
            data = load_npz(path)
            fields = {k: data[k] for k in cls.__dataclass_fields__ if k in data}
            return cls(**{**fields, "collect_s": float(fields.get("collect_s", 0.0))})
        except (OSError, ValueError, EOFError, TypeError, zipfile.BadZipFile) as exc:
            raise InputError(f"{path}: the cached candidates are damaged ({type(exc).__name__}); "
                             f"delete the file to collect them again") from None

    def best_iou(self, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per candidate, the best BEV IoU (N,) of ``boxes`` (N, 7) (the candidates' own or moved
        ones) with its view's ground truth and that vehicle's box (N, 7) (see boxes.best_match)."""
        best = np.zeros(len(boxes))
        match = np.zeros((len(boxes), 7))
        order = np.argsort(self.view, kind="stable")
        bounds = np.searchsorted(self.view[order], np.arange(len(self.gt_start)))
        for v in range(len(self.gt_start) - 1):
            rows = order[bounds[v]:bounds[v + 1]]
            best[rows], match[rows] = best_match(boxes[rows], self.gt[self.gt_start[v]:self.gt_start[v + 1]])
        return best, match


def view_candidates(model: nn.Module, sample: list | torch.Tensor, min_score: float, top_k: int,
                    patch: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The candidates inference would decode in one view (class score >= ``min_score``, at most
    ``top_k``): ``sample`` is what ``model`` takes for one sample (a cloud (N, 4) tensor, or AttFuse's
    list of them). Returns the head features of the ``patch`` x ``patch`` cells around each (K, C *
    patch^2) float16 (``patch``: the head's by default), anchor slots (K,), class scores (K,) and
    decoded boxes (K, 7) in the sample's frame."""
    with torch.no_grad():
        cls, box, d, feats = model([sample])
    scores = torch.sigmoid(cls[0])
    keep = top_candidates(scores, min_score, top_k)
    features = patch_features(feats[0], keep // model.head.a, patch or model.head.patch).numpy().astype(np.float16)
    return (features, (keep % model.head.a).numpy(), scores[keep].numpy().astype(np.float64),
            decode_with_direction(box[0, keep], d[0, keep], model.anchors[keep]))


def collect(model: nn.Module, feed: Feed, items: list, fcfg: BranchFitConfig,
            progress: Callable[[int, int], None] | None = None) -> Candidates:
    """Run the frozen ``model`` over ``items`` (per view, an asg.perception.feeds.Example: its clouds
    given to the network as ``feed`` says, its boxes (M, 7) the ground truth) ``fcfg.passes`` times."""
    model = fold_batch_norms(copy.deepcopy(model).eval())  # the caller's model keeps its layers
    rng = np.random.default_rng([fcfg.seed, 1])
    parts: dict[str, list] = {"features": [], "slot": [], "boxes": [], "view": []}
    gts, view = [], 0
    total = fcfg.passes * len(items)
    for p in range(fcfg.passes):
        for example in items:
            clouds, gt = example.clouds, example.boxes
            if p:
                clouds, gt = augment(clouds, gt, rng)
            tensors = [torch.from_numpy(c) for c in clouds]
            sample = feed.network_input([tensors], [example.kinds], [example.delays_s])[0]
            features, slot, _, boxes = view_candidates(model, sample, fcfg.min_score, fcfg.top_k)
            parts["features"].append(features)
            parts["slot"].append(slot.astype(np.int16))
            parts["boxes"].append(boxes)
            parts["view"].append(np.full(len(slot), view, dtype=np.int32))
            gts.append(np.asarray(gt, dtype=np.float64).reshape(-1, 7))
            view += 1
            if progress:
                progress(view, total)
    return Candidates(**{k: np.concatenate(v) for k, v in parts.items()}, gt=np.concatenate(gts),
                      gt_start=np.concatenate([[0], np.cumsum([len(g) for g in gts])]).astype(np.int64))


def fit_minibatches(module: nn.Module, n: int, fcfg: BranchFitConfig, loss_of: Callable[[torch.Tensor], torch.Tensor],
                    seed: int, log: Callable[[str], None], label: str) -> float:
    """Adam + one-cycle over ``fcfg.epochs`` passes of ``n`` examples in seeded random batches;
    ``loss_of(idx)`` is the loss of the examples ``idx`` (batch,). Returns the last 100 batches'
    mean loss."""
    steps = max(1, fcfg.epochs * n // fcfg.batch_size)
    opt = torch.optim.Adam(module.parameters(), lr=fcfg.lr / 3, weight_decay=fcfg.weight_decay)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=fcfg.lr, total_steps=steps)
    gen = torch.Generator().manual_seed(seed)
    recent: list[float] = []
    for step in range(steps):
        loss = loss_of(torch.randint(n, (fcfg.batch_size,), generator=gen))
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        recent = (recent + [float(loss.detach())])[-100:]
        if (step + 1) % 1000 == 0 or step + 1 == steps:
            log(f"{label}: step {step + 1}/{steps} loss {np.mean(recent):.4f}")
    return float(np.mean(recent))


def _reset(module: nn.Module, seed: int) -> None:
    torch.manual_seed(seed)
    for layer in module.modules():
        if isinstance(layer, nn.Linear):
            layer.reset_parameters()


def _rows(features: np.ndarray, idx: torch.Tensor) -> torch.Tensor:
    return torch.from_numpy(features[idx.numpy()].astype(np.float32))


def fit_branches(head: nn.Module, cands: Candidates, fcfg: BranchFitConfig,
                 log: Callable[[str], None] = print) -> dict:
    """Fit ``head.refine`` then ``head.iou`` (from a seeded initialisation) on ``cands``; returns
    figures for the model card: candidates, refinement examples, mean IoU before and after
    refinement (of candidates with IoU >= REFINE_MIN_IOU), the final losses."""
    best, match = cands.best_iou(cands.boxes)
    near = np.nonzero(best >= REFINE_MIN_IOU)[0]
    if not len(near):
        raise InputError("no candidate overlaps a vehicle: the detector finds nothing to refine; train it first")
    slot = torch.from_numpy(cands.slot.astype(np.int64))
    targets = torch.from_numpy(refinement_residuals(match[near], cands.boxes[near]).astype(np.float32))
    near_t = torch.from_numpy(near)

    def refine_of(idx: torch.Tensor) -> torch.Tensor:
        rows = near_t[idx]
        return refine_loss(head.refine_of_patches(_rows(cands.features, rows), slot[rows]), targets[idx])

    _reset(head.refine, fcfg.seed)
    head.refine.train()
    refine_final = fit_minibatches(head.refine, len(near), fcfg, refine_of, fcfg.seed, log, "refinement branch")
    head.refine.eval()
    refined = np.empty_like(cands.boxes)
    with torch.no_grad():
        for start in range(0, len(refined), 65536):
            rows = torch.arange(start, min(start + 65536, len(refined)))
            res = head.refine_of_patches(_rows(cands.features, rows), slot[rows])
            refined[rows.numpy()] = refine_boxes(cands.boxes[rows.numpy()], res)
    iou_after, _ = cands.best_iou(refined)
    iou_t = torch.from_numpy((iou_after if fcfg.iou_target == "refined" else best).astype(np.float32))

    def iou_of(idx: torch.Tensor) -> torch.Tensor:
        return iou_loss(head.iou_of_patches(_rows(cands.features, idx), slot[idx]), iou_t[idx])

    _reset(head.iou, fcfg.seed + 1)
    head.iou.train()
    iou_final = fit_minibatches(head.iou, len(best), fcfg, iou_of, fcfg.seed + 1, log, "IoU branch")
    head.iou.eval()
    return {"candidates": int(len(best)), "refine_examples": int(len(near)),
            "mean_iou_before": round(float(best[near].mean()), 4), "mean_iou_after": round(float(iou_after[near].mean()), 4),
            "refine_loss": round(refine_final, 4), "iou_loss": round(iou_final, 4)}


def collect_cached(model: nn.Module, feed: Feed, items: list, fcfg: BranchFitConfig, run_dir: Path,
                   log: Callable[[str], None], progress: Callable[[int, int], None] | None = None) -> Candidates:
    """The candidates of ``collect``, from ``run_dir``'s cache when a run was interrupted after stage 1."""
    path = run_dir / CACHE_NAME
    if path.is_file():
        log(f"candidates from {path}")
        return Candidates.load(path)
    t0 = time.perf_counter()
    cands = collect(model, feed, items, fcfg, progress)
    cands.collect_s = round(time.perf_counter() - t0, 1)
    cands.save(path)
    log(f"{len(cands.slot)} candidates from {len(cands.gt_start) - 1} views in {time.perf_counter() - t0:.0f} s")
    return cands
