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

import json
import time
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from sumo_scenarios.atomic import atomic_path
from sumo_scenarios.errors import InputError
from sumo_scenarios.paths import runs_dir

from ..perception.fusion import build_network, detector_config_of, feed_of
from ..perception.weights_io import seed_run_folder
from ..scene.views import Views
from ..sensors.lidar_spec import DEFAULT_LIDAR
from .branch_fit import CACHE_NAME, BranchFitConfig, collect_cached, fit_branches
from .cards import card_validation, init_record, previous_training, trained_lidar, write_card
from .checkpoint import load_checkpoint, started_from
from .config import TrainConfig, load_branch_config, load_train_config, weights_for
from .loop import (BRANCH_KEYS, Batches, Steps, augment_record, corner_record, init_from_weights,
                   keep_configured_length, make_scheduler, render_samples, run_steps)


def train(fusion: str, out_dir: Path | None = None, steps: int | None = None, log: Callable[[str], None] = print,
          progress: Callable[[int, int, float], None] | None = None, threads: int = 2, *,
          train_config: TrainConfig | None = None, detector_config=None, weights_dir: Path | None = None,
          validate: bool = True, init_from: str | None = None, iou_branch: bool = False,
          branch_config: BranchFitConfig | None = None) -> Path:
    """Train (or resume) the weights behind ``fusion``; returns the written weights file.

    Configs default to configs/detectors/{train,pointpillars}.yaml; the weights are read from and
    written to ``weights_dir``, by default the run folder ``out_dir`` (runs/train/NAME/), which
    the first run fills with the weights it continues from (the installed or shipped ones): never
    the package. ``validate`` records normal-val AP in the model card.
    ``init_from`` (a weights name, e.g. "single"): start a new sequence of chunks from those
    weights instead of continuing this model's own (see :func:`init_from_weights`).
    ``iou_branch``: fit the IoU and refinement branches alone on the frozen detector
    (:func:`fit_branch_weights`, train.yaml's ``iou_branch`` block or ``branch_config``).
    """
    name = weights_for(fusion)
    if weights_dir is None:
        weights_dir = out_dir = out_dir or runs_dir() / "train" / name
        seed_run_folder(weights_dir, name, *([init_from] if init_from else []))
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
    state = load_checkpoint(ckpt)
    if init_from and state is not None:
        # the same command rerun after an interruption resumes its chunk; another start is refused
        if started_from(state) != f"{init_from}.pt":
            raise InputError(f"{ckpt} holds an unfinished chunk that did not start from {init_from}: resume it without "
                             "--init-from, or delete it to start over")
        init_from = None
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
        init_from_weights(model, weights_dir / f"{init_from}.pt", build_network(init_from, cfg))
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
        keep_configured_length(sched, tcfg, total)
        step, wall = int(state["step"]), float(state["wall_s"])
        rng.bit_generator.state = json.loads(state["rng"])
        torch.set_rng_state(state["torch_rng"])
        log(f"resumed {name} at step {step}")
    t0 = time.perf_counter()
    log(f"rendering {tcfg.dataset} with the {tcfg.lidar} LiDAR ...")
    samples = render_samples(tcfg.dataset, "train", lidar=tcfg.lidar)
    batches = Batches(feed_of(name), samples, tcfg.views, tcfg.augment)
    if tcfg.noisy_links:
        log(f"rendering {tcfg.dataset} over noisy links ...")
        batches.add(render_samples(tcfg.dataset, "train", noise_seed=tcfg.seed, lidar=tcfg.lidar), Views.EGO)
    log(f"{len(batches.items)} training examples, {time.perf_counter() - t0:.0f} s to render")
    steps_at = Steps(step, total, tcfg.batch_size, tcfg.checkpoint_every, tcfg.corner_loss)
    wall = run_steps(model, opt, sched, batches, rng, steps_at, cfg, ckpt, wall, previous, log, progress)
    weights = weights_dir / f"{name}.pt"
    with atomic_path(weights) as tmp:
        torch.save(model.state_dict(), tmp)
    chunks = previous.get("chunks", []) + [{"steps": total, "lr": tcfg.lr, "schedule": tcfg.schedule,
                                            "seed": [tcfg.seed, chunk], "views": tcfg.views,
                                            **({"noisy_links": True} if tcfg.noisy_links else {}),
                                            **({"lidar": tcfg.lidar} if tcfg.lidar != DEFAULT_LIDAR else {}),
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


def fit_branch_weights(name: str, out_dir: Path | None = None, log: Callable[[str], None] = print,
                       progress: Callable[[int, int, float], None] | None = None, threads: int = 2, *,
                       branch_config: BranchFitConfig | None = None, detector_config=None,
                       weights_dir: Path | None = None, validate: bool = True) -> Path:
    """Fit the IoU and refinement branches of the trained ``name`` weights (frozen) and write them
    back with the model card (see :mod:`.branch_fit`); ``progress(view, views, nan)`` during the
    collection. The candidates' cache in ``out_dir`` (runs/train/NAME/) makes an interrupted
    fit resume after the collection; it is removed once the weights are written."""
    from ..perception.weights_io import load_state

    fcfg = branch_config or load_branch_config()
    cfg = detector_config or detector_config_of(name)
    if weights_dir is None:
        weights_dir = out_dir = out_dir or runs_dir() / "train" / name
        seed_run_folder(weights_dir, name)
    previous = previous_training(name, weights_dir)
    if not previous.get("chunks"):
        raise InputError(f"{weights_dir / f'{name}.pt'}: no trained {name} weights to fit the branches to; train them first")
    if trained_lidar(previous["chunks"]) != DEFAULT_LIDAR:
        raise InputError(f"{weights_dir / f'{name}.pt'}: trained for the {trained_lidar(previous['chunks'])} LiDAR; the branch "
                         f"fit renders with {DEFAULT_LIDAR}, so it would fit them to another sensor")
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
