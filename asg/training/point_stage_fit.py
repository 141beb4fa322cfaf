"""``asg train --fusion F --point-stage``: fit the point stage of F's weights on the frozen detector.

The detector (its point stage off) runs over the training split of train.yaml's ``point_stage``
block's data set, each frame as its ego sees it; each final box, and ``jitters`` copies of it moved
by seeded noise (the boxes a stage meets are sometimes further off than the training boxes), with
the points of the cloud the detector saw, is an example (asg/perception/point_stage.py). The stage
is fitted from a seeded start over ``epochs`` shuffled passes and written beside the weights
(asg/perception/weights/NAME.stage.pt) with a ``point_stage`` record in the model card.

Resumable: the collected boxes and points are cached in runs/train/NAME-stage/, and the fit
checkpoints after every epoch (loaded with ``weights_only=True``); both are removed once the stage
is written.
"""
from __future__ import annotations

import json
import math
import time
import zipfile
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable, Iterable

import numpy as np
import torch

from sumo_scenarios.atomic import atomic_path, write_text_atomic
from sumo_scenarios.errors import InputError
from sumo_scenarios.npz import load_npz
from sumo_scenarios.geometry import wrap_rad
from sumo_scenarios.paths import runs_dir
from sumo_scenarios.strict import from_mapping

from ..datasets import iter_frames
from ..perception import build_detector
from ..perception.data import Sample
from ..scene import Scene
from ..perception.branch_boxes import best_match
from ..perception.point_stage import (MIN_IOU, PointStage, box_features, box_points, refine, residual_targets,
                                      stage_loss)
from .config import train_block, weights_for
from ..perception.weights_io import seed_run_folder, stage_path_of
from ..sensors import load_lidar_spec, simulate_frame

BLOCK = "point_stage"
BOXES_CACHE = "point-stage-boxes.npz"
CHECKPOINT = "point-stage-last.pt"


@dataclass(frozen=True)
class PointStageFitConfig:
    """train.yaml's ``point_stage`` block."""
    dataset: str = "detector-train"
    #: jittered copies of each box, and the noise: centre (m, each of x and y), length and width
    #: (log-normal sigma), yaw (deg)
    jitters: int = 4
    jitter_xy_m: float = 0.3
    jitter_size: float = 0.06
    jitter_yaw_deg: float = 6.0
    epochs: int = 12
    batch_size: int = 256
    lr: float = 0.002
    weight_decay: float = 0.0001
    seed: int = 0

    def __post_init__(self) -> None:
        for name, ok in (("jitters", 0 <= self.jitters <= 32), ("jitter_xy_m", 0 <= self.jitter_xy_m <= 2),
                         ("jitter_size", 0 <= self.jitter_size <= 0.5), ("jitter_yaw_deg", 0 <= self.jitter_yaw_deg <= 45),
                         ("epochs", 1 <= self.epochs <= 1000), ("batch_size", 1 <= self.batch_size <= 65536),
                         ("lr", 0 < self.lr <= 1), ("weight_decay", 0 <= self.weight_decay <= 1)):
            if not ok:
                raise InputError(f"train.yaml:{BLOCK}: {name} = {getattr(self, name)} is out of range")


def load_point_stage_config(path: Path | None = None) -> PointStageFitConfig:
    return from_mapping(PointStageFitConfig, train_block(BLOCK, path), f"train.yaml:{BLOCK}")


Frame = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]  # boxes (K, 7), scores (K,), gt (M, 7), cloud (N, 4)


def _check_same_run(found: str, settings: str, path: Path) -> None:
    """A cache or checkpoint of another fit (other settings or weights) is refused, not reused."""
    if found != settings:
        raise InputError(f"{path} belongs to a point-stage fit with other settings or weights; delete "
                         f"{path.parent} to start this one over")


def _cached_frames(cache: Path, settings: str) -> list[Frame]:
    """The frames :func:`collect` cached in ``cache``; a cache of other settings, or damaged, is one
    InputError."""
    def damaged(exc: Exception) -> InputError:
        return InputError(f"{cache}: the cached boxes are damaged ({type(exc).__name__}); delete the file to "
                          "collect them again")

    try:
        arrays = load_npz(cache)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise damaged(exc) from None
    _check_same_run(str(arrays["settings"]) if "settings" in arrays else "", settings, cache)
    try:
        cut = lambda key, i: arrays[key][arrays["n" + key][i]:arrays["n" + key][i + 1]]  # noqa: E731
        return [(cut("boxes", i), cut("scores", i), cut("gt", i), cut("cloud", i))
                for i in range(len(arrays["nboxes"]) - 1)]
    except (KeyError, IndexError, TypeError, ValueError) as exc:
        raise damaged(exc) from None


def collect(fusion: str, scenes: Callable[[], Iterable[Scene]], what: str, run_dir: Path, log: Callable[[str], None],
            weights_file: Path | None = None, settings: str = "") -> list[Frame]:
    """The detector's final boxes (its point stage off), the vehicles in range and the cloud it saw,
    per frame of ``scenes()`` (``what`` names them in messages), ego frame; cached in ``run_dir``
    with ``settings`` (a rerun with other settings is refused)."""
    cache = run_dir / BOXES_CACHE
    if cache.is_file():
        return _cached_frames(cache, settings)
    det = build_detector(fusion, weights_file=None if weights_file is None else str(weights_file))
    det.point_stage = None
    spec = load_lidar_spec()
    frames = []
    for scene in scenes():
        sample = Sample(scene.scene_id, simulate_frame(scene, spec))
        boxes, scores = det.detect(sample.frame)
        frames.append((boxes.reshape(-1, 7), scores, sample.gt_eval().reshape(-1, 7),
                       det.seen_cloud(sample.frame).astype(np.float32)))
    log(f"collected {sum(len(f[0]) for f in frames)} boxes in {len(frames)} frames of {what}")
    arrays = {key: np.concatenate([f[i] for f in frames]) for i, key in enumerate(("boxes", "scores", "gt", "cloud"))}
    offsets = {"n" + key: np.cumsum([0] + [len(f[i]) for f in frames]) for i, key in enumerate(("boxes", "scores", "gt", "cloud"))}
    run_dir.mkdir(parents=True, exist_ok=True)
    with atomic_path(cache) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays, **offsets, settings=np.array(settings))
    return frames


def jittered(boxes: np.ndarray, fcfg: PointStageFitConfig, rng: np.random.Generator) -> np.ndarray:
    """``boxes`` (K, 7) moved by the block's noise."""
    out = boxes.copy()
    out[:, :2] += rng.normal(0, fcfg.jitter_xy_m, (len(boxes), 2))
    out[:, 3:5] *= np.exp(rng.normal(0, fcfg.jitter_size, (len(boxes), 2)))
    out[:, 6] = wrap_rad(out[:, 6] + rng.normal(0, math.radians(fcfg.jitter_yaw_deg), len(boxes)))
    return out


def examples(frames: list[Frame], fcfg: PointStageFitConfig, what: str) -> dict[str, torch.Tensor]:
    """The stage's inputs and targets over every box and its jittered copies (seeded)."""
    rng = np.random.default_rng(fcfg.seed)
    parts = []
    for boxes, scores, gt, cloud in frames:
        for copy in range(fcfg.jitters + 1):
            b = boxes if copy == 0 else jittered(boxes, fcfg, rng)
            if len(b):
                feats, mask = box_points(b, cloud)
                iou, res = residual_targets(b, gt)
                parts.append((feats, mask, box_features(b, scores, mask), iou.astype(np.float32), res.astype(np.float32)))
    if not parts:
        raise InputError(f"the detector found no boxes in {what}: nothing to fit the point stage on")
    keys = ("feats", "mask", "box", "iou", "res")
    return {k: torch.from_numpy(np.concatenate([p[i] for p in parts])) for i, k in enumerate(keys)}


def fit(data: dict[str, torch.Tensor], fcfg: PointStageFitConfig, run_dir: Path,
        log: Callable[[str], None], settings: str = "") -> PointStage:
    """The stage fitted on ``data`` (Adam, one-cycle schedule), resuming from the epoch checkpoint
    of the same ``settings``."""
    torch.manual_seed(fcfg.seed)
    stage = PointStage()
    n = len(data["iou"])
    per_epoch = math.ceil(n / fcfg.batch_size)
    opt = torch.optim.Adam(stage.parameters(), lr=fcfg.lr / 2, weight_decay=fcfg.weight_decay)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=fcfg.lr, total_steps=fcfg.epochs * per_epoch)
    gen = torch.Generator().manual_seed(fcfg.seed)
    start = 0
    checkpoint = run_dir / CHECKPOINT
    if checkpoint.is_file():
        def unreadable(exc: Exception) -> InputError:  # a damaged checkpoint: say how to start over
            return InputError(f"{checkpoint}: not a readable point-stage checkpoint ({type(exc).__name__}); "
                              "delete it to fit from the start")

        try:
            state = torch.load(checkpoint, map_location="cpu", weights_only=True)
        except Exception as exc:
            raise unreadable(exc) from None
        _check_same_run(state.get("settings", "") if isinstance(state, dict) else "", settings, checkpoint)
        try:
            stage.load_state_dict(state["stage"])
            opt.load_state_dict(state["optimizer"])
            sched.load_state_dict(state["scheduler"])
            gen.set_state(state["generator"])
            start = int(state["epoch"])
        except Exception as exc:
            raise unreadable(exc) from None
        log(f"resuming the point stage's fit after epoch {start}")
    for epoch in range(start, fcfg.epochs):
        stage.train()
        order = torch.randperm(n, generator=gen)
        total = 0.0
        for i in range(0, n, fcfg.batch_size):
            rows = order[i:i + fcfg.batch_size]
            loss = stage_loss(stage, {k: v[rows] for k, v in data.items()})
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            total += loss.item() * len(rows)
        with atomic_path(checkpoint) as tmp:
            torch.save({"stage": stage.state_dict(), "optimizer": opt.state_dict(), "scheduler": sched.state_dict(),
                        "generator": gen.get_state(), "epoch": epoch + 1, "settings": settings}, tmp)
        log(f"point stage epoch {epoch + 1}/{fcfg.epochs}: loss {total / n:.4f}")
    return stage.eval()


def mean_iou(frames: list[tuple[np.ndarray, np.ndarray, np.ndarray]]) -> float:
    """Mean best IoU of the boxes that overlap a vehicle by at least MIN_IOU."""
    ious = [iou[iou >= MIN_IOU] for boxes, _, gt in frames for iou in [best_match(boxes.reshape(-1, 7), gt)[0]]]
    ious = np.concatenate(ious) if ious else np.zeros(0)
    return round(float(ious.mean()), 4) if len(ious) else 0.0


def fit_stage_beside(fusion: str, weights: Path, run_dir: Path, log: Callable[[str], None], *,
                     fit_config: PointStageFitConfig | None = None) -> tuple[Path, dict]:
    """Fit a point stage to the frozen detector ``weights`` (a .pt of ``fusion``) and write it
    beside them (``stage_path_of(weights)``, which every detector built from that file then uses):
    its path and the fit's record. The examples: the block's data set's train split. ``run_dir``
    holds the resumable cache and checkpoint (kept only until the stage is written)."""
    fcfg = fit_config or load_point_stage_config()
    started = time.perf_counter()
    # what a cache or checkpoint must have been made with to be reused: these settings, these weights
    settings = json.dumps({"fusion": fusion, "fit": asdict(fcfg), "weights": str(weights.resolve()),
                           "weights_bytes": weights.stat().st_size}, sort_keys=True)
    what = f"{fcfg.dataset}'s train split"
    frames = collect(fusion, lambda: iter_frames(fcfg.dataset, "train"), what, run_dir, log, weights, settings)
    data = examples(frames, fcfg, what)
    log(f"{len(data['iou'])} examples, {int((data['iou'] >= MIN_IOU).sum())} on a vehicle")
    stage = fit(data, fcfg, run_dir, log, settings)
    path = stage_path_of(weights)
    with atomic_path(path) as tmp:
        torch.save(stage.state_dict(), tmp)
    before = [(b, s, g) for b, s, g, _ in frames]
    after = [(*refine(stage, b, s, c, 0.0), g) for b, s, g, c in frames]
    record = {**asdict(fcfg), "weights": path.name, "frames": len(frames),
              "boxes": int(sum(len(f[0]) for f in frames)), "examples": len(data["iou"]),
              "wall_s": round(time.perf_counter() - started, 1),
              "mean_iou_train_before": mean_iou(before), "mean_iou_train_after": mean_iou(after)}
    for leftover in (BOXES_CACHE, CHECKPOINT):
        (run_dir / leftover).unlink(missing_ok=True)
    log(f"wrote {path}: mean IoU of the training boxes on a vehicle {record['mean_iou_train_before']} -> "
        f"{record['mean_iou_train_after']} ({record['wall_s'] / 60:.1f} min)")
    return path, record


def fit_point_stage(fusion: str, log: Callable[[str], None] = print, threads: int = 2, *,
                    fit_config: PointStageFitConfig | None = None, weights_dir: Path | None = None,
                    out_dir: Path | None = None) -> Path:
    """Fit and write the point stage of ``fusion``'s weights (in ``weights_dir``, by default the
    training run folder runs/train/NAME/, filled with the installed or shipped weights), with a
    ``point_stage`` record in their card; its path."""
    name = weights_for(fusion)
    if weights_dir is None:
        weights_dir = runs_dir() / "train" / name
        seed_run_folder(weights_dir, name)
    weights = weights_dir / f"{name}.pt"
    if not weights.is_file():
        raise InputError(f"{weights}: no trained {name} weights to fit a point stage to; train them first")
    torch.set_num_threads(threads)
    path, record = fit_stage_beside(fusion, weights, out_dir or runs_dir() / "train" / f"{name}-stage", log,
                                    fit_config=fit_config)
    card_path = weights_dir / f"{name}.json"
    card = json.loads(card_path.read_text()) if card_path.is_file() else {"weights": weights.name}
    card["point_stage"] = record
    write_text_atomic(card_path, json.dumps(card, indent=1))
    return path
