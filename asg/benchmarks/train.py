"""``asg bench train``: seconds a training step of AttFuse takes (batch 4, two threads), median over
repeated steps on detector-train frames, and each phase's share of it: data drawing (picking and
augmenting the examples), voxelisation (the pillar encoder), the rest of the forward pass, target
assignment, the losses, the backward pass and the optimiser step."""
from __future__ import annotations

import itertools
import statistics
import time

import numpy as np

from .defaults import TRAIN_STEPS

#: warm-up steps before the timed ones (allocator, oneDNN kernels)
WARMUP = 3


def bench_frames(frames: int, seed: int = 0) -> tuple[list, str]:
    """(``frames`` scenes to train on, where they came from): the built detector-train set's train
    split, or, on a fresh machine where it is not built, the scenes of a minute of traffic in its
    first town (SUMO, a few seconds), so that the benchmark needs no data set built first."""
    import tempfile
    from dataclasses import replace
    from pathlib import Path

    from sumo_scenarios.errors import InputError

    from ..dataset_spec import load_spec
    from ..datasets import iter_frames

    try:
        return list(itertools.islice(iter_frames("detector-train", "train"), frames)), "detector-train"
    except InputError:  # not built
        pass
    from sumo_scenarios.simulate import SimulationRequest, simulate_sumo

    from ..scene.from_log import ExtractParams, extract_scenes

    spec = load_spec("detector-train")
    town = spec.towns[0]
    with tempfile.TemporaryDirectory(prefix="asg-bench-train-") as tmp:
        request = SimulationRequest(out_dir=Path(tmp) / "log", town=town, seed=seed + 1, duration_s=60.0, density="normal")
        simulate_sumo(request)
        params = ExtractParams(every=2, min_vehicles=5, collaborators=spec.collaborators)  # a scene a second
        # the log is removed with the folder: the scenes name none
        scenes = [replace(s, log=None) for s in itertools.islice(extract_scenes(request.out_dir, params), frames)]
    return scenes, f"town {town} (detector-train not built)"


def bench_train(steps: int = TRAIN_STEPS, frames: int = 24, batch_size: int = 4, threads: int = 2, seed: int = 0) -> dict:
    import torch

    from ..perception.config import load_detector_config
    from ..perception.data import make_sample
    from ..perception.model import AttFuse
    from ..perception.feeds import AGENT_CLOUDS
    from ..scene.views import Views
    from ..training.loop import BRANCH_KEYS, Batches, PhaseTimer, train_step
    from ..perception.weights_io import WEIGHTS_DIR, load_state
    from ..sensors import load_lidar_spec

    torch.set_num_threads(threads)
    torch.manual_seed(seed)
    cfg = load_detector_config()
    spec = load_lidar_spec()
    scenes, frames_from = bench_frames(frames, seed)
    samples = [make_sample(s, spec) for s in scenes]
    batches = Batches(AGENT_CLOUDS, samples, Views.ALL)
    model = AttFuse(cfg)
    load_state(model, WEIGHTS_DIR / "attfuse.pt", allow_missing=BRANCH_KEYS)  # the shipped weights' real activations
    model.train()
    opt = torch.optim.Adam(model.parameters(), lr=1e-5)
    anchors = model.anchors.numpy()
    rng = np.random.default_rng(seed)
    totals, phases = [], []
    for k in range(WARMUP + steps):
        timer = PhaseTimer()
        t = time.perf_counter()
        batch = batches.draw(rng, batch_size, anchors, cfg, timer)
        train_step(model, opt, None, batch, timer)
        if k >= WARMUP:
            totals.append(time.perf_counter() - t)
            phases.append(timer.seconds)
    median = statistics.median(totals)
    share = {name: statistics.median(p[name] for p in phases) for name in ("draw", "targets", "voxelise", "forward",
                                                                          "loss", "backward", "optimiser")}
    share["forward"] -= share["voxelise"]  # "forward" was timed around the encoder too
    return {"model": "attfuse", "batch_size": batch_size, "threads": threads, "steps": len(totals), "frames_from": frames_from,
            "examples": len(batches.items), "seconds_per_step": round(median, 3),
            "seconds_per_step_min": round(min(totals), 3),
            "phase_share": {k: round(v / median, 3) for k, v in share.items()},
            "goal_seconds_per_step": 0.7}
