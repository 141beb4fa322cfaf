"""The field's standard noisy V2X setting (OpenCOOD, V2X-ViT): every collaborator's shared pose
off by Gaussian noise (sigma 0.2 m in x and y, 0.2 deg in yaw) and its message 100 ms late (its
cloud from the previous frame at 10 Hz, rendered from the world of that instant). Scenes keep the
noise in their ``link`` record, so a noisy set is a folder of scene yaml that any command reads.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable

import numpy as np

from sumo_scenarios.errors import InputError

from .history import earlier_agents, scene_history
from .link import LinkState
from .scene import Scene, save_scene


@dataclass(frozen=True)
class NoisyLink:
    """The noise of the standard setting; ``delay_s`` must be a whole number of the scene's log steps."""

    sigma_xy_m: float = 0.2
    sigma_yaw_deg: float = 0.2
    delay_s: float = 0.1


#: OpenCOOD's and V2X-ViT's noisy setting
STANDARD = NoisyLink()


def noisy_scene(scene: Scene, rng: np.random.Generator, noise: NoisyLink = STANDARD) -> Scene:
    """``scene`` with each collaborator's message delayed and its shared pose off (drawn from
    ``rng``); the ego's own cloud and pose are exact. A scene whose log cannot give the earlier
    frame raises InputError (see asg.scene.history)."""
    link = {}
    history = scene_history(scene, 1_000, noise.delay_s) if noise.delay_s > 0 and scene.collaborators else None
    for cid in scene.collaborators:
        earlier: tuple = ()
        delay_s = 0.0
        if history is not None:
            steps = max(1, int(round(noise.delay_s / history.period_s)))
            if abs(steps * history.period_s - noise.delay_s) > 1e-6:
                raise InputError(f"scene {scene.scene_id}: its log records every {history.period_s:g} s; "
                                 f"a {noise.delay_s:g} s delay needs a log recorded every {noise.delay_s:g} s or "
                                 "a divisor of it (asg simulate --record-period)")
            earlier = earlier_agents(scene, history, cid, steps)
            delay_s = round(steps * history.period_s, 6)
        dx, dy = rng.normal(0.0, noise.sigma_xy_m, size=2)
        dyaw = math.radians(float(rng.normal(0.0, noise.sigma_yaw_deg)))
        link[cid] = LinkState(dx_m=float(dx), dy_m=float(dy), dyaw_rad=dyaw, delay_s=delay_s, earlier_agents=earlier)
    return scene.with_link(link)


def noise_rng(seed: int, scene_id: str) -> np.random.Generator:
    """The generator of one scene's noise: from ``seed`` and the scene's id, so that a scene's noise
    does not depend on the other scenes drawn with it."""
    return np.random.default_rng([seed, *(ord(ch) for ch in scene_id)])


def write_noisy_set(scenes: Iterable[Scene], out: Path, seed: int, noise: NoisyLink = STANDARD) -> Path:
    """Write the noisy version of every scene to ``out`` (one yaml a scene, the noise of each drawn
    from ``seed`` and its id, so a scene's noise does not depend on the others); kept if complete."""
    from sumo_scenarios.atomic import atomic_dir

    done = out / ".complete"
    if done.is_file():
        return out
    with atomic_dir(out) as work:
        for scene in scenes:
            save_scene(noisy_scene(scene, noise_rng(seed, scene.scene_id), noise), work / f"{scene.scene_id}.yaml")
        (work / ".complete").write_text("")
    return out
