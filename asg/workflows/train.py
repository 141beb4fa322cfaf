"""``asg train --fusion NAME``: seeded, resumable CPU training of the shipped detectors.

Weights: ``single`` (No and Late Fusion share it: one agent's cloud, its own labels), ``early``
(the fused cloud in the ego frame), ``attfuse`` (each agent's cloud in the ego frame). Labels are
the vehicles in range with at least one LiDAR point (in the agent's own cloud for ``single``, in
the fused cloud otherwise). Checkpoints go to ``runs/train/NAME/last.pt`` (model, optimiser,
step, generator state, the earlier chunks: plain tensors, numbers and strings, loaded with
``weights_only=True``); a rerun resumes from there. At the end the weights and a model card are
written to asg/perception/weights/ and the checkpoint is removed, so the next run trains one more
chunk starting from those weights.
"""
from __future__ import annotations

import argparse
import json
import time
from contextlib import contextmanager
from collections import Counter
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from sumo_scenarios.atomic import atomic_path
from sumo_scenarios.errors import InputError
from sumo_scenarios.paths import runs_dir

from ..cli_args import COUNT, THREADS, fusion_arg
from ..datasets import iter_frames
from ..sensors import load_lidar_spec
from ..perception.boxes import assign_targets
from ..perception.branch_boxes import branch_targets
from ..perception.branch_fit import CACHE_NAME, BranchFitConfig, collect_cached, fit_branches
from ..perception.data import Augmentation, Sample, augment, make_sample
from ..perception.head import detection_loss, iou_loss, refine_loss
from ..perception.feeds import Feed
from ..perception.fusion import build_network, detector_config_of, feed_of
from ..perception.model import PointPillars
from .cards import card_validation, init_record, previous_training, write_card
from ..perception.checkpoint import load_checkpoint, save_checkpoint
from ..perception.train_config import TrainConfig, load_branch_config, load_train_config, weights_for  # noqa: F401  (asg train's API)
from ..perception.weights_io import WEIGHTS_DIR

def render_samples(dataset: str, split: str | None = "train", progress: Callable[[int], None] | None = None) -> list[Sample]:
    spec = load_lidar_spec()
    out = []
    for i, scene in enumerate(iter_frames(dataset, split)):
        out.append(make_sample(scene, spec))
        if progress:
            progress(i + 1)
    return out


class Batches:
    """The training examples a feed makes of some frames, drawn with a seeded generator."""

    def __init__(self, feed: Feed, samples: list[Sample], views: str = "ego", augmentation: Augmentation = Augmentation()):
        self.feed = feed
        self.augmentation = augmentation
        self.items = [example for s in samples for example in feed.examples(s, views)]

    def draw(self, rng: np.random.Generator, batch: int, anchors: np.ndarray, cfg, timer: "PhaseTimer | None" = None):
        """A batch: the network's input (the feed's ``network_input`` of each example's clouds),
        labels (B, A), residual targets (B, A, 7), direction bins (B, A) and the augmented boxes
        (per example, (M, 7))."""
        picks = rng.integers(len(self.items), size=batch)
        return draw_examples([self.items[int(k)] for k in picks], rng, anchors, cfg, self.feed, timer, self.augmentation)


def draw_examples(examples: list, rng: np.random.Generator, anchors: np.ndarray, cfg, feed: Feed,
                  timer: "PhaseTimer | None" = None, augmentation: Augmentation = Augmentation()):
    """A batch of (clouds, boxes) examples, each transformed by a draw of ``augmentation`` from
    ``rng``, the clouds given to the network as ``feed`` says: see :meth:`Batches.draw`.
    ``timer``: where the augmentation ("draw") and the target assignment ("targets") are timed."""
    timer = timer or PhaseTimer(enabled=False)
    clouds, labels, targets, dirs, gt = [], [], [], [], []
    for cl, boxes in examples:
        with timer.phase("draw"):
            cl, boxes = augment(cl, boxes, rng, augmentation)
        with timer.phase("targets"):
            lab, res, d = assign_targets(anchors, boxes, cfg)
        clouds.append([torch.from_numpy(c) for c in cl])
        labels.append(lab)
        targets.append(res)
        dirs.append(d)
        gt.append(boxes)
    return (feed.network_input(clouds), torch.from_numpy(np.stack(labels)), torch.from_numpy(np.stack(targets)),
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


def train(fusion: str, out_dir: Path | None = None, steps: int | None = None, log: Callable[[str], None] = print,
          progress: Callable[[int, int, float], None] | None = None, threads: int = 2, *,
          train_config: TrainConfig | None = None, detector_config=None, weights_dir: Path = WEIGHTS_DIR,
          validate: bool = True, init_from: str | None = None, iou_branch: bool = False,
          branch_config: BranchFitConfig | None = None) -> Path:
    """Train (or resume) the weights behind ``fusion``; returns the written weights file.

    Configs default to configs/detectors/{train,pointpillars}.yaml and the weights to the shipped
    ones (asg/perception/weights/); ``validate`` records normal-val AP in the model card.
    ``init_from`` (a weights name, e.g. "single"): start a new sequence of chunks from those
    weights instead of continuing this model's own (see :func:`init_from_weights`).
    ``iou_branch``: fit the IoU and refinement branches alone on the frozen detector
    (:func:`fit_branch_weights`, train.yaml's ``iou_branch`` block or ``branch_config``).
    """
    name = weights_for(fusion)
    if iou_branch:
        if init_from:
            raise InputError("--iou-branch fits the branches of this model's own weights; it cannot be combined with --init-from")
        return fit_branch_weights(name, out_dir, log, progress, threads, branch_config=branch_config,
                                  detector_config=detector_config, weights_dir=weights_dir, validate=validate)
    tcfg = train_config or load_train_config(name)
    total = steps or tcfg.steps
    cfg = detector_config or detector_config_of(name)
    torch.set_num_threads(threads)
    run_dir = out_dir or runs_dir() / "train" / name
    ckpt = run_dir / "last.pt"
    if init_from and ckpt.is_file():
        raise InputError(f"{ckpt} holds an unfinished chunk: resume it without --init-from, or delete it to start over")
    state = load_checkpoint(ckpt)
    # the chunks before this one: from the checkpoint when resuming, else from the shipped card
    if init_from:
        previous = {"init_from": init_record(init_from, weights_dir), "chunks": []}
    elif state is None:
        previous = previous_training(name, weights_dir)
    else:
        previous = json.loads(state.get("previous", "{}"))
    chunk = len(previous.get("chunks", []))  # a continuation chunk draws other batches than the first
    torch.manual_seed(tcfg.seed + 1000 * chunk)
    rng = np.random.default_rng([tcfg.seed, chunk])
    model = build_network(name, cfg)
    params = list(model.parameters())
    opt = torch.optim.Adam(params, lr=tcfg.lr, weight_decay=tcfg.weight_decay)
    sched = make_scheduler(opt, tcfg, total)
    step, wall = 0, 0.0
    if init_from:
        init_from_weights(model, weights_dir / f"{init_from}.pt")
        model.train()
        log(f"starting {name} from the {init_from} weights ({previous['init_from']['steps']} steps)")
    elif previous.get("chunks") and state is None:
        from ..perception.weights_io import load_state

        load_state(model, weights_dir / f"{name}.pt", allow_missing=BRANCH_KEYS)
        model.train()
        log(f"continuing from the shipped {name} weights ({previous['steps_total']} steps so far)")
    if state is not None:
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["optimizer"])
        sched.load_state_dict(state["scheduler"])
        _keep_configured_length(sched, tcfg, total)
        step, wall = int(state["step"]), float(state["wall_s"])
        rng.bit_generator.state = json.loads(state["rng"])
        torch.set_rng_state(state["torch_rng"])
        log(f"resumed {name} at step {step}")
    t0 = time.perf_counter()
    log(f"rendering {tcfg.dataset} ...")
    samples = render_samples(tcfg.dataset, "train")
    batches = Batches(feed_of(name), samples, tcfg.views, tcfg.augment)
    log(f"{len(batches.items)} training examples, {time.perf_counter() - t0:.0f} s to render")
    steps_at = Steps(step, total, tcfg.batch_size, tcfg.checkpoint_every, tcfg.corner_loss)
    wall = run_steps(model, opt, sched, batches, rng, steps_at, cfg, ckpt, wall, previous, log, progress)
    weights = weights_dir / f"{name}.pt"
    with atomic_path(weights) as tmp:
        torch.save(model.state_dict(), tmp)
    chunks = previous.get("chunks", []) + [{"steps": total, "lr": tcfg.lr, "schedule": tcfg.schedule,
                                            "seed": [tcfg.seed, chunk], "views": tcfg.views,
                                            **augment_record(tcfg.augment), **corner_record(tcfg),
                                            "wall_s": round(wall, 1), "part": "all"}]
    write_card(name, weights_dir, cfg, chunks, previous, threads, dataset=tcfg.dataset,
                examples=len(batches.items), batch_size=tcfg.batch_size)
    ckpt.unlink(missing_ok=True)  # the chunk is complete: the next run starts a new one from these weights
    (run_dir / CACHE_NAME).unlink(missing_ok=True)  # candidates of an unfinished branch fit belong to the old weights
    log(f"wrote {weights} after {total} steps, {wall / 60:.1f} min of training")
    if validate:
        card_validation(name, log, weights_dir=weights_dir)
    return weights


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


def fit_branch_weights(name: str, out_dir: Path | None = None, log: Callable[[str], None] = print,
                       progress: Callable[[int, int, float], None] | None = None, threads: int = 2, *,
                       branch_config: BranchFitConfig | None = None, detector_config=None,
                       weights_dir: Path = WEIGHTS_DIR, validate: bool = True) -> Path:
    """Fit the IoU and refinement branches of the trained ``name`` weights (frozen) and write them
    back with the model card (see :mod:`.branch_fit`); ``progress(view, views, nan)`` during the
    collection. The candidates' cache in ``out_dir`` (runs/train/NAME/) makes an interrupted
    fit resume after the collection; it is removed once the weights are written."""
    from ..perception.weights_io import load_state

    fcfg = branch_config or load_branch_config()
    cfg = detector_config or detector_config_of(name)
    previous = previous_training(name, weights_dir)
    if not previous.get("chunks"):
        raise InputError(f"{weights_dir / f'{name}.pt'}: no trained {name} weights to fit the branches to; train them first")
    torch.set_num_threads(threads)
    run_dir = out_dir or runs_dir() / "train" / name
    model = build_network(name, cfg)
    load_state(model, weights_dir / f"{name}.pt", allow_missing=BRANCH_KEYS)
    started = time.perf_counter()
    log(f"rendering {fcfg.dataset} ...")
    feed = feed_of(name)
    items = Batches(feed, render_samples(fcfg.dataset, "train"), fcfg.views).items
    t_collect = time.perf_counter()
    cands = collect_cached(model, feed, items, fcfg, run_dir, log,
                           (lambda i, n: progress(i, n, float("nan"))) if progress else None)
    collect_or_load_s = time.perf_counter() - t_collect
    figures = fit_branches(model.head, cands, fcfg, log)
    weights = weights_dir / f"{name}.pt"
    with atomic_path(weights) as tmp:
        torch.save(model.state_dict(), tmp)
    # the collection's own time, also when an interrupted run left it in the cache
    wall = time.perf_counter() - started - collect_or_load_s + cands.collect_s
    fit = {"part": "branches", "passes": fcfg.passes, "epochs": fcfg.epochs, "batch_size": fcfg.batch_size,
           "lr": fcfg.lr, "seed": fcfg.seed, "views": fcfg.views, "iou_target": fcfg.iou_target,
           "wall_s": round(wall, 1), **figures}
    write_card(name, weights_dir, cfg, previous["chunks"] + [fit], previous, threads,
                dataset=previous.get("dataset", fcfg.dataset), examples=previous.get("examples", len(items)),
                batch_size=previous.get("batch_size", 0), branch_fit=fit)
    (run_dir / CACHE_NAME).unlink(missing_ok=True)
    log(f"wrote {weights}: branches fitted on {figures['candidates']} candidates in {wall / 60:.1f} min "
        f"(mean IoU of the candidates on a vehicle {figures['mean_iou_before']} -> {figures['mean_iou_after']} refined)")
    if validate:
        card_validation(name, log, weights_dir=weights_dir)
    return weights


def init_from_weights(model: torch.nn.Module, path: Path) -> None:
    """Load a PointPillars state_dict (e.g. the single-agent weights) into ``model``.

    Every tensor must match; only the parts ``model`` adds to PointPillars (``parts_beyond_base``,
    e.g. AttFuse's attention) may be missing, and ``model.start_from_base()`` initialises them.
    """
    from ..perception.weights_io import load_state

    base = PointPillars(model.cfg)
    load_state(base, path, allow_missing=BRANCH_KEYS)  # one clear error for a missing, corrupt or mismatched file
    missing = model.load_state_dict(base.state_dict(), strict=False).missing_keys
    beyond = tuple(getattr(model, "parts_beyond_base", ()))
    if any(not k.startswith(beyond) for k in missing):
        raise InputError(f"{path}: weights do not match this model (missing {next(k for k in missing if not k.startswith(beyond))})")
    model.start_from_base()


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


def _keep_configured_length(sched, tcfg: TrainConfig, total: int) -> None:
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


# ``asg train``: this workflow's command (asg.cli's COMMAND_MODULES)

def add_arguments(p: argparse.ArgumentParser) -> None:
    fusion_arg(p, "the model trained (none and late share weights)", required=True)
    p.add_argument("--steps", type=COUNT, default=None, help="override the configured number of steps")
    p.add_argument("--threads", type=THREADS, default=2)
    p.add_argument("--validate-only", action="store_true",
                   help="no training: re-measure the shipped weights on normal-val and update their model card "
                        "(after changing configs/detectors/pointpillars.yaml)")
    p.add_argument("--init-from", default=None, metavar="WEIGHTS",
                   help="start a new sequence of chunks from other shipped weights (e.g. single) instead of "
                        "continuing this model's own")
    p.add_argument("--iou-branch", action="store_true",
                   help="fit only the IoU and box-refinement branches on the frozen shipped weights "
                        "(train.yaml's iou_branch block; about 10 minutes)")
    p.add_argument("--point-stage", action="store_true",
                   help="fit only the point stage (each final box refined from its points) on the frozen shipped "
                        "weights (train.yaml's point_stage block; about 5 minutes)")


def run(args: argparse.Namespace) -> int:
    from ..progress import console, loss_progress, progress_bar

    if args.validate_only and (args.init_from or args.iou_branch or args.point_stage):
        raise InputError("--validate-only measures the shipped weights; it cannot be combined with --init-from, "
                         "--iou-branch or --point-stage")
    if args.point_stage and (args.init_from or args.iou_branch or args.steps is not None):
        raise InputError("--point-stage fits the stage of the shipped weights alone; it cannot be combined with "
                         "--init-from, --iou-branch or --steps (set epochs in train.yaml's point_stage block)")
    if args.validate_only:
        card = card_validation(weights_for(args.fusion), console.print)
        console.print(f"updated the model card of {card['weights']}")
        return 0
    if args.steps is not None and args.iou_branch:
        raise InputError("--steps does not apply to --iou-branch (a fit of epochs over the collected candidates: "
                         "set epochs in train.yaml's iou_branch block)")
    if args.point_stage:
        from .point_stage_fit import fit_point_stage

        console.print(f"weights: {fit_point_stage(args.fusion, console.print, args.threads)}")
        card_validation(weights_for(args.fusion), console.print)
        return 0
    with progress_bar() as bar:
        report = loss_progress(bar, bar.add_task(f"training {args.fusion}", total=None), f"training {args.fusion}",
                               without_loss=f"collecting {args.fusion}'s candidates")
        out = train(args.fusion, steps=args.steps, progress=report, threads=args.threads, log=console.print,
                    init_from=args.init_from, iou_branch=args.iou_branch)
    console.print(f"weights: {out}")
    return 0
