"""How much a box-refinement branch can lift AP@0.7: a fast offline fit.

usage: python docs/experiments/box_refine.py WEIGHTS HIDDEN EPOCHS
       (WEIGHTS: single | early | attfuse; e.g. attfuse 256 4)

Runs the frozen shipped detector once over the detector-train views (each as is, then once
augmented) and caches, per candidate anchor whose decoded box overlaps a vehicle by BEV IoU >= 0.2,
the head features of the 3 x 3 cells around it and the residuals (boxes.refinement_residuals) from
its box to that vehicle's. Then it fits an MLP (HIDDEN units, one output of 7 per anchor slot) to
the residuals of the candidates with IoU >= 0.3, EPOCHS passes, smooth-L1 in units of
head.REFINE_SCALE, and reports on normal-val and `normal` (the candidate caches of iou_branch.py):
the candidates' mean IoU and share >= 0.7 before and after refinement, and AP with the decoded
and the refined boxes, each scored by the class score and by the shipped IoU branch (which
predicts the IoU of the decoded box). Caches go to runs/exp-iou/.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch
from torch import nn

sys.path.insert(0, str(Path(__file__).parent))
from iou_branch import OUT, best_iou, cache_eval, candidates, fit_loop, load_frozen  # noqa: E402

from asg.objective.ap import ap_at  # noqa: E402
from asg.objective.iou import bev_iou_matrix  # noqa: E402
from asg.perception.branch_boxes import refine_boxes, refinement_residuals  # noqa: E402
from asg.perception.nms import select_boxes  # noqa: E402
from asg.perception.data import augment, in_range  # noqa: E402
from asg.perception.head import REFINE_SCALE  # noqa: E402
from asg.perception.fusion import feed_of  # noqa: E402
from asg.training.loop import Batches, render_samples  # noqa: E402
from asg.perception.weights_io import weights_path  # noqa: E402

PATCH = 3


def cache_train(model, name: str) -> dict:
    """f (N, C * 9) float16, a (N,) anchor slot, t (N,) best IoU, r (N, 7) residuals."""
    path = OUT / f"{name}-refine-train.npz"
    if path.is_file():
        return dict(np.load(path))
    items = Batches(feed_of(name), render_samples("detector-train", "train"), "all").items
    rng = np.random.default_rng(7)
    parts = {"f": [], "a": [], "t": [], "r": []}
    for aug in (False, True):
        for clouds, gt in items:
            if aug:
                clouds, gt = augment(clouds, gt, rng)
            c = candidates(model, name, clouds, PATCH, 0.1)
            if not len(c["bx"]) or not len(gt):
                continue
            iou = bev_iou_matrix(c["bx"], gt)
            near = iou.max(axis=1) >= 0.2
            parts["f"].append(c["f"][near])
            parts["a"].append(c["a"][near])
            parts["t"].append(iou.max(axis=1)[near].astype(np.float32))
            parts["r"].append(refinement_residuals(gt[iou.argmax(axis=1)[near]], c["bx"][near]).astype(np.float32))
    out = {k: np.concatenate(v) for k, v in parts.items()}
    np.savez(path, **out)
    return out


def fit(data: dict, hidden: int, epochs: int, slots: int, min_iou: float = 0.3) -> nn.Module:
    torch.manual_seed(0)
    k = data["t"] >= min_iou
    f = torch.from_numpy(data["f"][k].astype(np.float32))
    a = torch.from_numpy(data["a"][k]).long()
    r = torch.from_numpy(data["r"][k])
    print(f"{len(r)} training candidates; residual std {np.round(r.std(0).numpy(), 3)}")
    net = nn.Sequential(nn.Linear(f.shape[1], hidden), nn.ReLU(), nn.Linear(hidden, slots * 7))
    return fit_loop(net, len(r), epochs, lambda idx: nn.functional.smooth_l1_loss(
        net(f[idx]).view(len(idx), slots, 7)[torch.arange(len(idx)), a[idx]], r[idx] / REFINE_SCALE, beta=0.5))


def refined_boxes(net: nn.Module, frames: list[dict], slots: int) -> list[np.ndarray]:
    out = []
    with torch.no_grad():
        for fr in frames:
            if not len(fr["s"]):
                out.append(fr["bx"])
                continue
            pred = net(torch.from_numpy(fr["f"].astype(np.float32))).view(len(fr["s"]), slots, 7)
            res = pred[torch.arange(len(fr["s"])), torch.from_numpy(fr["a"]).long()] * REFINE_SCALE
            out.append(refine_boxes(fr["bx"], res))
    return out


def shipped_iou(model, frames: list[dict]) -> list[np.ndarray]:
    with torch.no_grad():
        return [torch.sigmoid(model.head.iou(torch.from_numpy(fr["f"].astype(np.float32)))
                              .gather(1, torch.from_numpy(fr["a"]).long()[:, None])[:, 0]).numpy() for fr in frames]


def report(frames: list[dict], refined: list[np.ndarray], iou_pred: list[np.ndarray], split: str, cfg) -> None:
    before = np.concatenate([best_iou(fr["bx"], fr["gt"]) for fr in frames])
    after = np.concatenate([best_iou(b, fr["gt"]) for b, fr in zip(refined, frames)])
    m = before >= 0.3
    print(f"{split}: candidates with IoU >= 0.3: mean IoU {before[m].mean():.3f} -> {after[m].mean():.3f}, "
          f"share >= 0.7 {np.mean(before[m] >= 0.7):.3f} -> {np.mean(after[m] >= 0.7):.3f}")
    for label, boxes in (("decoded", [fr["bx"] for fr in frames]), ("refined", refined)):
        for score in ("class", "iou"):
            out = []
            for fr, b, p in zip(frames, boxes, iou_pred):
                if not len(fr["s"]):
                    out.append((np.zeros((0, 7)), np.zeros(0), fr["gt"]))
                    continue
                kept, sc = select_boxes(b, fr["s"] if score == "class" else np.clip(p, 1e-6, 1), cfg)
                k = in_range(kept)
                out.append((kept[k], sc[k], fr["gt"]))
            print(f"  {label} boxes, {score} score: AP@0.3/0.5/0.7 " + " / ".join(f"{100 * v:.1f}" for v in ap_at(out).values()))


def main() -> None:
    name, hidden, epochs = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    torch.set_num_threads(2)
    OUT.mkdir(parents=True, exist_ok=True)
    model, cfg = load_frozen(name)
    state = torch.load(weights_path(name), weights_only=True)  # the shipped IoU branch
    model.head.iou.load_state_dict({k[len("head.iou."):]: v for k, v in state.items() if k.startswith("head.iou.")})
    net = fit(cache_train(model, name), hidden, epochs, model.head.a)
    for split in ("normal-val", "normal"):
        frames = cache_eval(model, name, PATCH, split)
        report(frames, refined_boxes(net, frames, model.head.a), shipped_iou(model, frames), split, cfg)


if __name__ == "__main__":
    main()
