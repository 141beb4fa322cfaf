"""How much IoU-aware rescoring can lift AP@0.7, and which IoU-branch shape: a fast offline fit.

usage: python docs/experiments/iou_branch.py WEIGHTS PATCH HIDDEN EPOCHS
       (WEIGHTS: single | early | attfuse; e.g. attfuse 3 256 4)

Runs the shipped detector (frozen) once over the detector-train views (each view as is, then once
augmented) and over normal-val and `normal`, and caches, per candidate anchor, the head features of
the PATCH x PATCH cells around it, the class score, the decoded box and its best BEV IoU with the
ground truth. Then it fits an MLP (HIDDEN units) to those IoUs on the training views, EPOCHS passes,
and reports AP on normal-val and `normal` for rescoring powers 0 (the class score alone) to 1 (the
predicted IoU alone), rescoring before NMS as the package does. Caches go to runs/exp-iou/.
`asg train --iou-branch` now fits the package's branches this way (asg/training/branch_fit.py).
"""
from __future__ import annotations

import pickle
import sys
from pathlib import Path

import numpy as np
import torch
from torch import nn

from asg.datasets import iter_frames
from asg.objective.ap import ap_at
from asg.objective.iou import bev_iou_matrix
from asg.perception.nms import select_boxes
from asg.training.branch_fit import BranchFitConfig, fit_minibatches, view_candidates
from asg.perception.config import load_detector_config
from asg.perception.data import Sample, augment, in_range
from asg.perception.inference import fold_batch_norms
from asg.perception.model import AttFuse, PointPillars
from asg.perception.fusion import feed_of
from asg.training.loop import BRANCH_KEYS, Batches, render_samples
from asg.perception.weights_io import load_state, weights_path
from asg.sensors import load_lidar_spec, simulate_frame

OUT = Path("runs/exp-iou")


def load_frozen(name: str):
    cfg = load_detector_config()
    model = AttFuse(cfg) if name == "attfuse" else PointPillars(cfg)
    load_state(model, weights_path(name), allow_missing=BRANCH_KEYS)  # the branches are not used here
    return fold_batch_norms(model.eval()), cfg


def candidates(model, name: str, clouds: list[np.ndarray], patch: int, min_score: float) -> dict:
    """The anchors inference keeps for one view: features (K, C * patch^2), anchor slot (K,),
    class score (K,), decoded boxes (K, 7) (the package's branch_fit.view_candidates)."""
    tensors = [torch.from_numpy(c) for c in clouds]
    f, a, s, bx = view_candidates(model, tensors if name == "attfuse" else torch.from_numpy(np.vstack(clouds)),
                                  min_score, 300, patch)
    return {"f": f, "a": a, "s": s, "bx": bx}


def best_iou(bx: np.ndarray, gt: np.ndarray) -> np.ndarray:
    return bev_iou_matrix(bx, gt).max(axis=1) if len(bx) and len(gt) else np.zeros(len(bx))


def cache_train(model, name: str, patch: int) -> dict:
    path = OUT / f"{name}-p{patch}-train.npz"
    if path.is_file():
        return dict(np.load(path))
    items = Batches(feed_of(name), render_samples("detector-train", "train"), "all").items
    rng = np.random.default_rng(7)
    parts = {"f": [], "a": [], "t": []}
    for aug in (False, True):
        for clouds, gt in items:
            if aug:
                clouds, gt = augment(clouds, gt, rng)
            c = candidates(model, name, clouds, patch, 0.1)
            parts["f"].append(c["f"])
            parts["a"].append(c["a"])
            parts["t"].append(best_iou(c["bx"], gt).astype(np.float32))
    out = {k: np.concatenate(v) for k, v in parts.items()}
    np.savez(path, **out)
    return out


def cache_eval(model, name: str, patch: int, split: str) -> list[dict]:
    path = OUT / f"{name}-p{patch}-{split}.pkl"
    if path.is_file():
        return pickle.loads(path.read_bytes())
    spec = load_lidar_spec("v2xp")
    frames = []
    for scene in iter_frames("normal", {"normal-val": "val", "normal": "train"}[split]):
        sample = Sample(scene.scene_id, simulate_frame(scene, spec))
        f = sample.frame
        clouds = [f.clouds[f.ego_id]] if name == "single" else f.clouds_in_frame_of(f.ego_id)  # single: No Fusion
        frames.append({**candidates(model, name, clouds, patch, 0.2), "gt": sample.gt_eval()})
    path.write_bytes(pickle.dumps(frames))
    return frames


def fit(data: dict, hidden: int, epochs: int, slots: int) -> nn.Module:
    torch.manual_seed(0)
    f = torch.from_numpy(data["f"].astype(np.float32))
    a = torch.from_numpy(data["a"]).long()
    t = torch.from_numpy(data["t"])
    net = nn.Sequential(nn.Linear(f.shape[1], hidden), nn.ReLU(), nn.Linear(hidden, slots))
    return fit_loop(net, len(t), epochs, lambda idx: nn.functional.binary_cross_entropy_with_logits(
        net(f[idx]).gather(1, a[idx][:, None])[:, 0], t[idx]))


def fit_loop(net: nn.Module, n: int, epochs: int, loss_of) -> nn.Module:
    """Adam + one-cycle (peak 3e-3) over EPOCHS passes of N examples, batches of 256 drawn with a
    seeded generator; ``loss_of(idx)`` is the loss of the examples ``idx`` (256,): the package's
    branch fit (asg.training.branch_fit.fit_minibatches) with its default settings, seed 0."""
    fit_minibatches(net, n, BranchFitConfig(epochs=epochs), loss_of, 0, lambda _: None, "")
    return net


def report(net: nn.Module, frames: list[dict], split: str, cfg) -> None:
    with torch.no_grad():
        preds = [torch.sigmoid(net(torch.from_numpy(fr["f"].astype(np.float32)))
                               .gather(1, torch.from_numpy(fr["a"]).long()[:, None])[:, 0]).numpy() for fr in frames]
    truth = np.concatenate([best_iou(fr["bx"], fr["gt"]) for fr in frames])
    print(f"{split}: correlation with the true IoU: predicted {np.corrcoef(np.concatenate(preds), truth)[0, 1]:.3f}, "
          f"class score {np.corrcoef(np.concatenate([fr['s'] for fr in frames]), truth)[0, 1]:.3f}")
    for power in (0.0, 0.25, 0.5, 0.75, 1.0):
        out = []
        for fr, p in zip(frames, preds):
            if not len(fr["s"]):
                out.append((np.zeros((0, 7)), np.zeros(0), fr["gt"]))
                continue
            b, s = select_boxes(fr["bx"], fr["s"] ** (1 - power) * np.clip(p, 1e-6, 1) ** power, cfg)
            k = in_range(b)
            out.append((b[k], s[k], fr["gt"]))
        print(f"  power {power}: AP@0.3/0.5/0.7 " + " / ".join(f"{100 * v:.1f}" for v in ap_at(out).values()))


def main() -> None:
    name, patch, hidden, epochs = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
    torch.set_num_threads(2)
    OUT.mkdir(parents=True, exist_ok=True)
    model, cfg = load_frozen(name)
    net = fit(cache_train(model, name, patch), hidden, epochs, model.head.a)
    for split in ("normal-val", "normal"):
        report(net, cache_eval(model, name, patch, split), split, cfg)


if __name__ == "__main__":
    main()
