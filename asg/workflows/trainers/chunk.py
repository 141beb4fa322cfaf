"""asg's own trainer's chunk (asg.workflows.trainers.shipped): a shipped model's weights trained a
number of steps further on batches that mix given scenes with the train splits of ``mix_with``,
resumable from a checkpoint; what ``asg finetune`` and each round of ``asg harden`` train."""
from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from sumo_scenarios.atomic import atomic_path
from sumo_scenarios.errors import InputError

from ...datasets import iter_frames
from ...io.curves import LOSS_CURVE, LossCurve
from ...perception.data import Augmentation, make_sample
from ...perception.fusion import build_network, detector_config_of, feed_of
from ...perception.weights_io import load_state
from ...sensors import load_lidar_spec
from ...training.checkpoint import load_checkpoint
from ...training.config import ChunkConfig
from ...training.loop import (BRANCH_KEYS, Batches, Steps, augment_record, corner_record, draw_examples,
                              make_scheduler, run_steps)


class MixedBatches:
    """Batches whose examples come from several sources: each example's source drawn with
    ``shares`` (summing to 1), then an example of that source uniformly."""

    def __init__(self, sources: list[Batches], shares: list[float], labels: tuple[str, ...] = (),
                 augmentation: Augmentation = Augmentation()):
        if any(not s.items for s in sources):
            raise InputError("a fine-tuning source holds no training example")
        self.sources = sources
        #: each source's name, for the card's example counts
        self.labels = labels or tuple(str(i) for i in range(len(sources)))
        self.shares = np.asarray(shares, dtype=float) / float(np.sum(shares))
        self.augmentation = augmentation

    def draw(self, rng: np.random.Generator, batch: int, anchors: np.ndarray, cfg, timer=None):
        which = rng.choice(len(self.sources), size=batch, p=self.shares)
        examples = [self.sources[int(s)].items[int(rng.integers(len(self.sources[int(s)].items)))] for s in which]
        return draw_examples(examples, rng, anchors, cfg, self.sources[0].feed, timer, self.augmentation)


def mixed_sources(name: str, first: dict[str, list], fcfg: ChunkConfig, mix_with: tuple[str, ...],
                  log: Callable[[str], None]) -> MixedBatches:
    """Mixed batches of ``first`` ({label: scenes}: ``challenging_share`` of each batch, split
    evenly among the labels that hold scenes) and the train split of each ``mix_with`` set (the
    rest, in equal shares), every scene rendered with the LiDAR."""
    from ...datasets import build_dataset, dataset_path

    spec = load_lidar_spec()
    feed = feed_of(name)
    t0 = time.perf_counter()
    labels = [k for k, v in first.items() if v]
    views = fcfg.challenging_views or fcfg.views
    sources = [Batches(feed, [make_sample(s, spec) for s in first[k]], views) for k in labels]
    for mix in mix_with:
        if not (dataset_path(mix) / "index.json").is_file():
            log(f"building data set {mix} ...")
            build_dataset(mix)
        sources.append(Batches(feed, [make_sample(s, spec) for s in iter_frames(mix, "train")], fcfg.views))
    rest = (1.0 - fcfg.challenging_share) / max(len(mix_with), 1)
    shares = [fcfg.challenging_share / max(len(labels), 1)] * len(labels) + [rest] * len(mix_with)
    batches = MixedBatches(sources, shares, (*labels, *mix_with), fcfg.augment)
    counts = ", ".join(f"{n} {len(b.items)}" for n, b in zip(batches.labels, sources))
    log(f"training examples: {counts} ({time.perf_counter() - t0:.0f} s to render)")
    return batches


def fit_chunk(name: str, start: Path, weights_out: Path, ckpt: Path, fcfg: ChunkConfig, mix_with: tuple[str, ...],
              threads: int, log: Callable[[str], None], progress, sources: Callable[[], MixedBatches]) -> dict:
    """Train ``fcfg.steps`` steps from the weights ``start`` on the batches ``sources()`` draws (the
    given scenes and the train splits of ``mix_with``), resuming ``ckpt``; write ``weights_out``;
    the record of the chunk for a card."""
    total = fcfg.steps
    cfg = detector_config_of(name)
    torch.set_num_threads(threads)
    torch.manual_seed(fcfg.seed)
    rng = np.random.default_rng([fcfg.seed, 0])
    model = build_network(name, cfg)
    load_state(model, start, allow_missing=BRANCH_KEYS)
    opt = torch.optim.Adam(model.parameters(), lr=fcfg.lr, weight_decay=fcfg.weight_decay)
    sched = make_scheduler(opt, fcfg, total)
    step, wall_s = 0, 0.0
    state = load_checkpoint(ckpt)
    if state is not None:
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        sched.load_state_dict(state["scheduler"])
        step, wall_s = int(state["step"]), float(state["wall_s"])
        rng.bit_generator.state = json.loads(state["rng"])
        torch.set_rng_state(state["torch_rng"])
        log(f"resumed fine-tuning at step {step}")
    batches = sources()
    curve = LossCurve(ckpt.with_name(LOSS_CURVE), resumed_at=step)
    wall_s = run_steps(model, opt, sched, batches, rng, Steps(step, total, fcfg.batch_size, fcfg.checkpoint_every, fcfg.corner_loss),
                       cfg, ckpt, wall_s, {}, log, progress, curve.add)
    with atomic_path(weights_out) as tmp:
        torch.save(model.state_dict(), tmp)
    ckpt.unlink(missing_ok=True)
    log(f"wrote {weights_out} after {total} steps, {wall_s / 60:.1f} min of training")
    return {"mix_with": list(mix_with), "challenging_share": fcfg.challenging_share,
            "examples": {n: len(b.items) for n, b in zip(batches.labels, batches.sources)},
            "steps": total, "batch_size": fcfg.batch_size, "lr": fcfg.lr, "schedule": fcfg.schedule,
            "seed": fcfg.seed, "views": fcfg.views, "challenging_views": fcfg.challenging_views or fcfg.views,
            **augment_record(fcfg.augment), **corner_record(fcfg),
            "threads": threads, "wall_s": round(wall_s, 1)}
