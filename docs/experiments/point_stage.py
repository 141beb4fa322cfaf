"""Does a point-based second stage sharpen the boxes? Each final box of a shipped detector refined
from the points inside it (a PointNet over the box's own points in the box's frame), scored on
normal-val and heuristic under both yardsticks (ours: global sort; the paper's: per frame).

The detector stays frozen. Its final boxes on detector-train's train split (each frame as its ego
sees it), each also jittered JITTERS times (the proposals a stage meets are off by more than the
final ones), with the points of the cloud the detector saw (No Fusion: the ego's own; the fusion
models: every sensing agent's, in the ego frame) inside the box grown by GROW_M, are the
examples. Targets: the residuals to the best-matching vehicle (BEV IoU >= 0.3) in the box's frame
(along, across, up in metres; log length, width, height ratios; yaw folded into [-90, 90) deg) and
the box's IoU with it (for rescoring). The stage is then applied to the detector's final boxes of
each evaluation set: arms "detector" (as shipped), "refined" (boxes moved), "refined+rescored"
(score**(1 - RESCORE) * predicted IoU**RESCORE).

    .venv/bin/python docs/experiments/point_stage.py OUT FUSION [EPOCHS]

Writes OUT/FUSION-SET.npz (the collected boxes and points, reused by a rerun), OUT/FUSION-stage.pt
(the fitted stage) and OUT/FUSION-result.json.
"""
from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from asg.datasets import iter_frames, scenes_of
from asg.objective.iou import bev_iou_matrix
from asg.perception import build_detector
from asg.perception.data import Sample
from asg.sensors import load_lidar_spec, simulate_frame
from asg.workflows.evaluate import scored
from sumo_scenarios.geometry import wrap_rad

#: points kept a box (sampled when more), the box grown by this on every side (m), jittered copies
#: of each training box, and the IoU from which a box gets refinement targets
POINTS, GROW_M, JITTERS, MIN_IOU = 64, 0.5, 4, 0.3
#: jitter of a training box: centre (m, each axis), length and width (relative), yaw (rad)
JITTER_XY_M, JITTER_SIZE, JITTER_YAW_RAD = 0.3, 0.06, math.radians(6)
RESCORE = 0.5
SEED = 0


def cloud_seen(detector_name: str, frame) -> np.ndarray:
    """(N, 4) the points the detector saw, in the ego sensor frame."""
    if detector_name in ("none",):
        return frame.clouds[frame.ego_id]
    return np.vstack(frame.clouds_in_frame_of(frame.ego_id))


def collect(det, name: str, scenes, path: Path) -> list[tuple]:
    """Per frame: (boxes (K, 7), scores (K,), gt (M, 7), cloud (N, 4)); cached in ``path``."""
    if path.is_file():
        z = np.load(path)
        out = []
        for i in range(len(z["nb"]) - 1):
            out.append((z["boxes"][z["nb"][i]:z["nb"][i + 1]], z["scores"][z["nb"][i]:z["nb"][i + 1]],
                        z["gt"][z["ng"][i]:z["ng"][i + 1]], z["cloud"][z["nc"][i]:z["nc"][i + 1]]))
        return out
    spec = load_lidar_spec()
    out = []
    for scene in scenes:
        sample = Sample(scene.scene_id, simulate_frame(scene, spec))
        boxes, scores = det.detect(sample.frame)
        out.append((boxes, scores, sample.gt_eval(), cloud_seen(name, sample.frame).astype(np.float32)))
    offsets = {k: np.cumsum([0] + [len(f[i]) for f in out]) for k, i in (("nb", 0), ("ng", 2), ("nc", 3))}
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, boxes=np.vstack([f[0].reshape(-1, 7) for f in out]), scores=np.concatenate([f[1] for f in out]),
             gt=np.vstack([f[2].reshape(-1, 7) for f in out]), cloud=np.vstack([f[3] for f in out]), **offsets)
    tmp.rename(path)
    return out


def box_points(boxes: np.ndarray, cloud: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Per box (K, 7): its points in the box's frame with features (K, POINTS, 7): along, across,
    up (m) and the same divided by half the length, width, height, intensity; and the mask (K,
    POINTS) of real points."""
    feats = np.zeros((len(boxes), POINTS, 7), dtype=np.float32)
    mask = np.zeros((len(boxes), POINTS), dtype=bool)
    for k, b in enumerate(boxes):
        d = cloud[:, :3] - b[:3]
        c, s = math.cos(b[6]), math.sin(b[6])
        along, across = c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]
        inside = ((np.abs(along) <= b[3] / 2 + GROW_M) & (np.abs(across) <= b[4] / 2 + GROW_M)
                  & (np.abs(d[:, 2]) <= b[5] / 2 + GROW_M))
        idx = np.flatnonzero(inside)
        if len(idx) > POINTS:
            idx = rng.choice(idx, POINTS, replace=False)
        n = len(idx)
        local = np.stack([along[idx], across[idx], d[idx, 2]], axis=1)
        feats[k, :n, :3] = local
        feats[k, :n, 3:6] = local / (b[3:6] / 2)
        feats[k, :n, 6] = cloud[idx, 3]
        mask[k, :n] = True
    return feats, mask


def box_globals(boxes: np.ndarray, scores: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(K, 5): length, width, height (m), score, log(1 + points)."""
    return np.column_stack([boxes[:, 3:6], scores, np.log1p(mask.sum(1))]).astype(np.float32)


def targets(boxes: np.ndarray, gt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per box (K, 7): its best BEV IoU (K,) and the residuals (K, 7) to that vehicle in the box's
    frame (along, across, up; log size ratios; yaw folded into [-pi/2, pi/2))."""
    if not len(gt) or not len(boxes):
        return np.zeros(len(boxes)), np.zeros((len(boxes), 7))
    iou = bev_iou_matrix(boxes, gt)
    best, match = iou.max(1), gt[iou.argmax(1)]
    d = match[:, :3] - boxes[:, :3]
    c, s = np.cos(boxes[:, 6]), np.sin(boxes[:, 6])
    res = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], d[:, 2],
                           np.log(match[:, 3:6] / boxes[:, 3:6]),
                           (wrap_rad(match[:, 6] - boxes[:, 6]) + math.pi / 2) % math.pi - math.pi / 2])
    return best, res


def apply_residuals(boxes: np.ndarray, res: np.ndarray) -> np.ndarray:
    out = boxes.copy()
    c, s = np.cos(boxes[:, 6]), np.sin(boxes[:, 6])
    out[:, 0] += c * res[:, 0] - s * res[:, 1]
    out[:, 1] += s * res[:, 0] + c * res[:, 1]
    out[:, 2] += res[:, 2]
    out[:, 3:6] *= np.exp(res[:, 3:6])
    out[:, 6] = wrap_rad(boxes[:, 6] + res[:, 6])
    return out


def jitter(boxes: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    out = boxes.copy()
    out[:, :2] += rng.normal(0, JITTER_XY_M, (len(boxes), 2))
    out[:, 3:5] *= np.exp(rng.normal(0, JITTER_SIZE, (len(boxes), 2)))
    out[:, 6] = wrap_rad(out[:, 6] + rng.normal(0, JITTER_YAW_RAD, len(boxes)))
    return out


class PointStage(nn.Module):
    """A PointNet over a box's points: per-point MLP, masked max, with the box's globals → 7
    residuals (in RES_SCALE units) and an IoU logit."""

    RES_SCALE = torch.tensor([0.3, 0.15, 0.1, 0.08, 0.06, 0.06, 0.1])

    def __init__(self):
        super().__init__()
        self.point = nn.Sequential(nn.Linear(7, 64), nn.ReLU(), nn.Linear(64, 128), nn.ReLU(), nn.Linear(128, 256))
        self.head = nn.Sequential(nn.Linear(256 + 5, 256), nn.ReLU(), nn.Linear(256, 128), nn.ReLU(), nn.Linear(128, 8))

    def forward(self, feats, mask, glob):
        h = self.point(feats)
        h = h.masked_fill(~mask[..., None], -1e4).amax(1)
        h = torch.where(mask.any(1, keepdim=True), h, torch.zeros_like(h))
        out = self.head(torch.cat([h, glob], 1))
        return out[:, :7] * self.RES_SCALE, out[:, 7]


def examples(frames: list[tuple], rng: np.random.Generator, jitters: int) -> dict[str, torch.Tensor]:
    parts = []
    for boxes, scores, gt, cloud in frames:
        boxes = boxes.reshape(-1, 7)
        for j in range(jitters + 1):
            b = boxes if j == 0 else jitter(boxes, rng)
            if not len(b):
                continue
            f, m = box_points(b, cloud, rng)
            best, res = targets(b, gt)
            parts.append((f, m, box_globals(b, scores, m), best, res))
    cat = [np.concatenate([p[i] for p in parts]) for i in range(5)]
    return {"feats": torch.from_numpy(cat[0]), "mask": torch.from_numpy(cat[1]), "glob": torch.from_numpy(cat[2]),
            "iou": torch.from_numpy(cat[3].astype(np.float32)), "res": torch.from_numpy(cat[4].astype(np.float32))}


def fit(data: dict[str, torch.Tensor], epochs: int, log) -> PointStage:
    torch.manual_seed(SEED)
    stage = PointStage()
    n = len(data["iou"])
    steps = epochs * math.ceil(n / 256)
    opt = torch.optim.Adam(stage.parameters(), lr=1e-3, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=2e-3, total_steps=steps)
    gen = torch.Generator().manual_seed(SEED)
    for epoch in range(epochs):
        order = torch.randperm(n, generator=gen)
        total = 0.0
        for i in range(0, n, 256):
            b = order[i:i + 256]
            res, iou_logit = stage(data["feats"][b], data["mask"][b], data["glob"][b])
            near = data["iou"][b] >= MIN_IOU
            l_res = (F.smooth_l1_loss(res[near] / PointStage.RES_SCALE, data["res"][b][near] / PointStage.RES_SCALE, beta=0.5)
                     if near.any() else res.sum() * 0)
            l_iou = F.binary_cross_entropy_with_logits(iou_logit, data["iou"][b])
            loss = l_res + l_iou
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            total += float(loss) * len(b)
        log(f"epoch {epoch + 1}/{epochs}: loss {total / n:.4f}")
    return stage.eval()


@torch.no_grad()
def refined_frames(stage: PointStage, frames: list[tuple], rng: np.random.Generator) -> dict[str, list]:
    arms = {"detector": [], "refined": [], "refined+rescored": []}
    for boxes, scores, gt, cloud in frames:
        boxes = boxes.reshape(-1, 7)
        arms["detector"].append((boxes, scores, gt))
        if not len(boxes):
            arms["refined"].append((boxes, scores, gt))
            arms["refined+rescored"].append((boxes, scores, gt))
            continue
        f, m = box_points(boxes, cloud, rng)
        res, iou_logit = stage(torch.from_numpy(f), torch.from_numpy(m), torch.from_numpy(box_globals(boxes, scores, m)))
        moved = apply_residuals(boxes, res.double().numpy())
        arms["refined"].append((moved, scores, gt))
        rescored = scores ** (1 - RESCORE) * torch.sigmoid(iou_logit).double().numpy() ** RESCORE
        arms["refined+rescored"].append((moved, rescored, gt))
    return arms


def mean_iou_of_matched(frames: list[tuple]) -> float:
    vals = []
    for boxes, _, gt in frames:
        best, _ = targets(boxes.reshape(-1, 7), gt)
        vals.extend(best[best >= MIN_IOU])
    return float(np.mean(vals)) if vals else 0.0


def main(out: Path, name: str, epochs: int) -> None:
    torch.set_num_threads(2)
    out.mkdir(parents=True, exist_ok=True)
    log = lambda m: print(f"[{time.strftime('%H:%M:%S')}] {m}", flush=True)  # noqa: E731
    det = build_detector(name)
    t = time.time()
    train = collect(det, name, iter_frames("detector-train", "train"), out / f"{name}-detector-train.npz")
    log(f"collected {len(train)} training frames, {sum(len(f[0]) for f in train)} boxes, {time.time() - t:.0f} s")
    rng = np.random.default_rng(SEED)
    data = examples(train, rng, JITTERS)
    log(f"{len(data['iou'])} examples, {int((data['iou'] >= MIN_IOU).sum())} with targets")
    t = time.time()
    stage = fit(data, epochs, log)
    fit_s = time.time() - t
    torch.save(stage.state_dict(), out / f"{name}-stage.pt")
    result = {"fusion": name, "epochs": epochs, "examples": len(data["iou"]), "fit_s": round(fit_s, 1),
              "settings": {"points": POINTS, "grow_m": GROW_M, "jitters": JITTERS, "rescore": RESCORE}, "sets": {}}
    for set_name in ("normal-val", "heuristic"):
        frames = collect(det, name, scenes_of(set_name), out / f"{name}-{set_name}.npz")
        arms = refined_frames(stage, frames, np.random.default_rng(SEED))
        result["sets"][set_name] = {arm: {**{k: v for k, v in scored(fr).items() if k != "frames"},
                                          "mean_iou_matched": round(mean_iou_of_matched(fr), 4)}
                                    for arm, fr in arms.items()}
        for arm, r in result["sets"][set_name].items():
            log(f"{set_name} {arm}: AP@0.7 {100 * r['ap']['0.7']:.1f} / per frame {100 * r['ap_per_frame']['0.7']:.1f}, "
                f"AP@0.5 {100 * r['ap']['0.5']:.1f}, mean IoU of matched {r['mean_iou_matched']:.3f}")
    (out / f"{name}-result.json").write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main(Path(sys.argv[1]), sys.argv[2], int(sys.argv[3]) if len(sys.argv) > 3 else 12)
