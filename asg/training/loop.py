"""The training loop's parts, shared by ``asg train``, ``asg finetune``, ``asg harden`` and the
training benchmark: the examples of rendered frames (a detector's feed makes them), batches drawn
from them with a seeded generator and augmented, one optimiser step with every loss, the steps
of a chunk with checkpoints, the learning-rate schedules, and what a model card records of them.
"""
from __future__ import annotations

import time
from collections import Counter
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from sumo_scenarios.errors import InputError

from ..datasets import iter_frames
from ..perception.boxes import assign_targets
from ..perception.branch_boxes import branch_targets
from ..perception.data import Augmentation, Sample, augment, make_sample
from ..perception.feeds import Feed
from ..perception.head import detection_loss, iou_loss, refine_loss
from ..perception.model import PointPillars
from ..scene.noisy import noise_rng, noisy_scene
from ..scene.views import Views
from ..sensors import load_lidar_spec
from ..sensors.lidar_spec import DEFAULT_LIDAR
from .checkpoint import save_checkpoint
from .config import TrainConfig


def render_samples(dataset: str, split: str | None = "train", progress: Callable[[int], None] | None = None,
                   noise_seed: int | None = None, lidar: str = DEFAULT_LIDAR) -> list[Sample]:
    """Every frame of ``dataset``'s ``split`` rendered with the ``lidar`` preset; with ``noise_seed``,
    each as its ego receives it in the standard noisy V2X setting (asg.scene.noisy), the noise drawn
    from the seed and the frame's id."""
    spec = load_lidar_spec(lidar)
    out = []
    for i, scene in enumerate(iter_frames(dataset, split)):
        if noise_seed is not None:
            scene = noisy_scene(scene, noise_rng(noise_seed, scene.scene_id))
        out.append(make_sample(scene, spec))
        if progress:
            progress(i + 1)
    return out


class Batches:
    """The training examples a feed makes of some frames, drawn with a seeded generator."""

    def __init__(self, feed: Feed, samples: list[Sample], views: Views = Views.EGO, augmentation: Augmentation = Augmentation()):
        self.feed = feed
        self.augmentation = augmentation
        self.items = []
        self.add(samples, views)

    def add(self, samples: list[Sample], views: Views = Views.EGO) -> None:
        """Draw from the examples of ``samples`` (as ``views`` says) too."""
        self.items += [example for s in samples for example in self.feed.examples(s, views)]

    def draw(self, rng: np.random.Generator, batch: int, anchors: np.ndarray, cfg, timer: "PhaseTimer | None" = None):
        """A batch: the network's input (the feed's ``network_input`` of each example's clouds),
        labels (B, A), residual targets (B, A, 7), direction bins (B, A) and the augmented boxes
        (per example, (M, 7))."""
        picks = rng.integers(len(self.items), size=batch)
        return draw_examples([self.items[int(k)] for k in picks], rng, anchors, cfg, self.feed, timer, self.augmentation)


def draw_examples(examples: list, rng: np.random.Generator, anchors: np.ndarray, cfg, feed: Feed,
                  timer: "PhaseTimer | None" = None, augmentation: Augmentation = Augmentation()):
    """A batch of examples (asg.perception.feeds.Example), each transformed by a draw of ``augmentation`` from
    ``rng``, the clouds given to the network as ``feed`` says: see :meth:`Batches.draw`.
    ``timer``: where the augmentation ("draw") and the target assignment ("targets") are timed."""
    timer = timer or PhaseTimer(enabled=False)
    clouds, kinds, delays_s, labels, targets, dirs, gt = [], [], [], [], [], [], []
    for example in examples:
        cl, boxes = example.clouds, example.boxes
        kinds.append(example.kinds)
        delays_s.append(example.delays_s)
        with timer.phase("draw"):
            cl, boxes = augment(cl, boxes, rng, augmentation)
        with timer.phase("targets"):
            lab, res, d = assign_targets(anchors, boxes, cfg)
        clouds.append([torch.from_numpy(c) for c in cl])
        labels.append(lab)
        targets.append(res)
        dirs.append(d)
        gt.append(boxes)
    return (feed.network_input(clouds, kinds, delays_s), torch.from_numpy(np.stack(labels)), torch.from_numpy(np.stack(targets)),
            torch.from_numpy(np.stack(dirs)), gt)


class PhaseTimer:
    """Wall seconds spent in named phases of a training step (``enabled=False``: a no-op)."""

    def __init__(self, enabled: bool = True):
        self.enabled = enabled
        self.seconds: dict[str, float] = {}

    @contextmanager
    def phase(self, name: str):
        if not self.enabled:
            yield
            return
        t = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - t


def train_step(model: torch.nn.Module, opt, sched, batch, timer: PhaseTimer | None = None,
               corner_weight: float = 0.0) -> dict[str, torch.Tensor]:
    """One optimiser step of ``model`` on ``batch`` (what :func:`draw_examples` returns); the
    losses by name ("total" includes the branches'). ``corner_weight``: the corner loss's
    (TrainConfig.corner_loss). ``timer`` splits it into "forward" (the
    network, of which "voxelise" is the pillar encoder's part), "loss", "backward" and "optimiser"."""
    timer = timer or PhaseTimer(enabled=False)
    inputs, labels, targets, dirs, gt = batch
    encode = model.encoder.encode
    if timer.enabled:  # the encoder's share of the forward pass, timed apart
        def timed_encode(c):
            with timer.phase("voxelise"):
                return encode(c)
        model.encoder.encode = timed_encode
    try:
        with timer.phase("forward"):
            cls, box, d, features = model(inputs)
    finally:
        model.encoder.__dict__.pop("encode", None)
    with timer.phase("loss"):
        loss = detection_loss(cls, box, d, labels, targets, dirs, model.anchors, corner_weight)
        loss.update(branch_losses(model, cls, box, features, labels, gt))
        loss["total"] = loss["total"] + loss["iou"] + loss["refine"]
    with timer.phase("backward"):
        opt.zero_grad()
        loss["total"].backward()
    with timer.phase("optimiser"):
        torch.nn.utils.clip_grad_norm_(list(model.parameters()), 10.0)
        opt.step()
        if sched is not None:
            sched.step()
    return loss


@dataclass(frozen=True)
class Steps:
    """Where a chunk stands: steps done, steps in the chunk, examples a step, steps between checkpoints."""

    done: int
    total: int
    batch_size: int
    checkpoint_every: int
    #: the corner loss's weight (TrainConfig.corner_loss)
    corner_weight: float = 0.0


def run_steps(model: torch.nn.Module, opt, sched, batches, rng: np.random.Generator, steps: Steps, cfg,
              ckpt: Path, wall_s: float, previous: dict, log: Callable[[str], None],
              progress: Callable[[int, int, float], None] | None,
              curve: Callable[[int, float], None] | None = None) -> float:
    """Train ``model`` from ``steps.done`` to ``steps.total`` on batches drawn from ``batches``
    (anything with ``draw(rng, batch, anchors, cfg)``), checkpointing to ``ckpt``; returns the
    chunk's wall time so far (``wall_s`` plus this run's). ``curve(step, mean loss of the last 50
    steps)`` every 50 steps and at the last. Leaves the model in eval mode."""
    anchors = model.anchors.numpy()
    model.train()
    started = time.perf_counter()
    losses: list[float] = []
    step, total = steps.done, steps.total
    while step < total:
        loss = train_step(model, opt, sched, batches.draw(rng, steps.batch_size, anchors, cfg),
                          corner_weight=steps.corner_weight)
        step += 1
        if not bool(torch.isfinite(loss["total"].detach())):  # diverged: stop before writing such weights
            raise InputError(f"training diverged at step {step} (the loss is not finite); lower the learning "
                             "rate (lr) in train.yaml")
        losses.append(float(loss["total"].detach()))
        if progress:
            progress(step, total, losses[-1])
        if step % 50 == 0:
            parts = " ".join(f"{k} {float(v.detach()):.3f}" for k, v in loss.items() if k != "total")
            log(f"step {step}/{total} loss {np.mean(losses[-50:]):.4f} ({parts})")
        if curve and (step % 50 == 0 or step == total):
            curve(step, float(np.mean(losses[-50:])))
        if step % steps.checkpoint_every == 0 or step == total:
            save_checkpoint(ckpt, model, opt, sched, step, wall_s + time.perf_counter() - started, rng, previous)
    model.eval()
    return wall_s + time.perf_counter() - started


def init_from_weights(model: torch.nn.Module, path: Path, source: torch.nn.Module | None = None) -> None:
    """Start ``model`` from the weights ``path`` of another network: ``source``, a fresh network of
    the model those weights belong to (default PointPillars, e.g. the single-agent weights).

    Every tensor the two share is copied (what only ``source`` has, say AttFuse's attention for
    F-Cooper, is left out); what only ``model`` has must be among the parts it adds to PointPillars
    (``parts_beyond_base``, e.g. AttFuse's attention), and then ``model.start_from_base(missing)``
    initialises them. Where2comm starts from AttFuse's weights whole, attention included.
    """
    from ..perception.weights_io import load_state

    source = source if source is not None else PointPillars(model.cfg)
    load_state(source, path, allow_missing=BRANCH_KEYS)  # one clear error for a missing, corrupt or mismatched file
    missing = model.load_state_dict(source.state_dict(), strict=False).missing_keys
    beyond = tuple(getattr(model, "parts_beyond_base", ()))
    if any(not k.startswith(beyond) for k in missing):
        raise InputError(f"{path}: weights do not match this model (missing {next(k for k in missing if not k.startswith(beyond))})")
    if missing:
        model.start_from_base(missing)


def branch_losses(model, cls: torch.Tensor, box: torch.Tensor, features: torch.Tensor, labels: torch.Tensor,
                   gt: list[np.ndarray]) -> dict[str, torch.Tensor]:
    """The IoU and refinement branches' losses on a batch (outputs of ``model``, (B, ...))."""
    per_sample = branch_targets(cls.detach(), box.detach(), model.anchors, labels, gt)
    outs = [model.head.branches(features[b], idx) for b, (idx, *_) in enumerate(per_sample)]
    return {"iou": iou_loss(torch.cat([logit for logit, _ in outs]), torch.cat([t for _, t, _, _ in per_sample])),
            "refine": refine_loss(torch.cat([res[mask] for (_, res), (_, _, mask, _) in zip(outs, per_sample)]),
                                  torch.cat([r for *_, r in per_sample]))}


def augment_record(aug: Augmentation) -> dict:
    """The chunk record's augmentation entry: none for the default (cards written before the
    setting existed read the same), else its settings."""
    return {} if aug == Augmentation() else {"augment": asdict(aug)}


def corner_record(tcfg: TrainConfig) -> dict:
    """The chunk record's corner-loss entry: none when off (as in cards written before it existed)."""
    return {"corner_loss": tcfg.corner_loss} if tcfg.corner_loss > 0 else {}


#: the branches' parameters (IoU, refinement): weights trained before a branch existed load without it
BRANCH_KEYS = ("head.iou.", "head.refine.")


def make_scheduler(opt: torch.optim.Optimizer, tcfg: TrainConfig, total: int):
    if tcfg.schedule == "onecycle":
        return torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=tcfg.lr, total_steps=total, pct_start=tcfg.pct_start,
                                                   div_factor=tcfg.div_factor)
    return torch.optim.lr_scheduler.MultiStepLR(opt, milestones=[int(f * total) for f in tcfg.decay_at], gamma=0.1)


def keep_configured_length(sched, tcfg: TrainConfig, total: int) -> None:
    """After loading a checkpoint, the configured schedule length wins over the saved one.

    OneCycleLR keeps its phase boundaries (steps) in its state, so they are taken from a scheduler
    of the configured length built on a throwaway optimizer (setting ``total_steps`` alone would
    only move the final step, not where the peak and the annealing end).
    """
    if tcfg.schedule == "onecycle":
        reference = make_scheduler(torch.optim.SGD([torch.zeros(1, requires_grad=True)], lr=tcfg.lr), tcfg, total)
        sched.total_steps = reference.total_steps
        sched._schedule_phases = reference._schedule_phases
    else:
        sched.milestones = Counter(int(f * total) for f in tcfg.decay_at)
