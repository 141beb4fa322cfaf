"""The recent past of a scene: where its vehicles were a few tenths of a second earlier, for the
``latency`` space (a collaborator's cloud captured before the scene's instant).

Taken from the scene's own SUMO log: a log folder the scene names (``scene.log`` an existing folder;
its recording period is the time step), or, for the scenes of the bundled data sets (whose logs are
not kept), the same log simulated again with SUMO, recording every simulation step (0.1 s) from a
little before the scene's first frame; the routes and the seed are the set's, so the traffic is the
same, and every vehicle of the scene is checked to stand where the scene has it (else refused).
Re-simulated logs are kept under the data root (``.history/LOG``) for the next scene of that log.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sumo_scenarios.errors import InputError
from sumo_scenarios.log import META_NAME

from .agent import Agent
from .from_log import agents_at, log_period_s
from .scene import Scene

#: a re-simulated log records from this long before the data set's first frame (s): the longest delay it serves
HISTORY_MARGIN_S = 1.0
#: a scene's vehicle farther than this (m) from where the re-simulated log has it: not the same traffic
MATCH_TOLERANCE_M = 0.05


@dataclass(frozen=True)
class History:
    """Vehicles of a scene's log at ``steps`` earlier instants: ``frames[k - 1]`` = k periods before."""

    period_s: float
    frames: tuple[tuple[Agent, ...], ...]


def scene_history(scene: Scene, steps: int, max_delay_s: float) -> History:
    """The ``steps`` recorded instants before the scene's (InputError if the log cannot give them)."""
    check_past(scene, max_delay_s)
    folder = _log_folder(scene, max_delay_s)
    period_s, first_s = log_period_s(folder)
    steps = min(steps, int(math.floor(max_delay_s / period_s + 1e-9)))
    _check_reach(scene, steps * period_s, first_s)
    times = [round(scene.time_s - k * period_s, 3) for k in range(steps + 1)]
    found = agents_at(folder, times)
    missing = [t for t in times if t not in found]
    if missing:
        raise InputError(f"scene {scene.scene_id}: its log has no frame at {missing[0]:g} s; is it the scene's log?")
    _check_same_traffic(scene, found[times[0]])
    return History(period_s, tuple(tuple(found[t]) for t in times[1:]))


def check_past(scene: Scene, max_delay_s: float) -> None:
    """Can the scene's log give its past at delays up to ``max_delay_s``? InputError if it names
    none (nor a data set's) or records less often than that. Reads the log's metadata only: the
    check a run makes of every scene before computing any."""
    if scene.log and (Path(scene.log) / META_NAME).is_file():
        period_s, first_s = log_period_s(scene.log)
        if period_s > max_delay_s + 1e-9:
            raise InputError(f"scene {scene.scene_id}: its log records every {period_s:g} s, longer than the largest "
                             f"delay ({max_delay_s:g} s); record the log more often (asg simulate --record-period)")
        _check_reach(scene, math.floor(max_delay_s / period_s + 1e-9) * period_s, first_s)
    elif _data_set_request(scene, max_delay_s) is None:
        raise InputError(f"scene {scene.scene_id} names no traffic log to take earlier frames from "
                         f"(log: {scene.log!r}); the latency space needs the scene's SUMO log folder")


def _check_reach(scene: Scene, reach_s: float, first_s: float) -> None:
    if scene.time_s - reach_s < first_s - 1e-6:
        raise InputError(f"scene {scene.scene_id} at {scene.time_s:g} s: a delay of {reach_s:g} s reaches "
                         f"before its log's start ({first_s:g} s); lower space.latency.max_delay_s or pick a later frame")


def _check_same_traffic(scene: Scene, now: list[Agent]) -> None:
    by_id = {a.agent_id: a for a in now}
    for a in scene.vehicles:
        b = by_id.get(a.agent_id)
        if b is None or math.hypot(a.x_m - b.x_m, a.y_m - b.y_m) > MATCH_TOLERANCE_M:
            raise InputError(f"scene {scene.scene_id}: vehicle {a.agent_id} is not where the log has it at "
                             f"{scene.time_s:g} s; the scene did not come from this log")


def _log_folder(scene: Scene, max_delay_s: float) -> Path:
    if scene.log and (Path(scene.log) / META_NAME).is_file():
        return Path(scene.log)
    request = _data_set_request(scene, max_delay_s)
    assert request is not None, "check_past refuses a scene without a log"
    import fcntl

    from sumo_scenarios.simulate import simulate_sumo

    request.out_dir.parent.mkdir(parents=True, exist_ok=True)
    with open(request.out_dir.parent / f".{request.out_dir.name}.lock", "w") as lock:
        # one worker simulates; the others wait for the whole folder (its files land one by one)
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (request.out_dir / META_NAME).is_file():
            simulate_sumo(request)
    return request.out_dir


def _data_set_request(scene: Scene, max_delay_s: float):
    """The SimulationRequest that re-simulates a data set's log ``TOWN_DENSITY_SEED`` recording every
    step from ``HISTORY_MARGIN_S`` before the set's first frame (None: no bundled set has that log)."""
    from sumo_scenarios.paths import configs_dir
    from sumo_scenarios.simulate import SimulationRequest
    from sumo_scenarios.strict import read_yaml

    from ..dataset_spec import data_root, load_spec

    if not scene.log or "/" in scene.log:
        return None
    base = SimulationRequest(out_dir=Path("."))
    margin = max(HISTORY_MARGIN_S, max_delay_s)
    for name in read_yaml(configs_dir() / "datasets.yaml") or {}:
        spec = load_spec(name)
        for town in spec.towns:
            for density in spec.densities:
                for seed in spec.seeds:
                    if f"{town}_{density}_{seed}" == scene.log:
                        out = data_root() / ".history" / f"{scene.log}_from{margin:g}s"
                        return SimulationRequest(out_dir=out, town=town, seed=seed, density=density,
                                                 duration_s=spec.duration_s + margin, warmup_s=base.warmup_s - margin,
                                                 step_s=base.step_s, record_period_s=base.step_s)
    return None


#: agents kept in a delayed message's world: within this of the collaborator then (m), the LiDAR's reach
EARLIER_RADIUS_M = 120.0


def earlier_agents(scene: Scene, history: History, agent_id: str, steps: int) -> tuple[Agent, ...]:
    """The agents around ``agent_id`` ``steps`` periods of ``history`` before ``scene`` (the log's
    vehicles then, the scene's RSUs), the world a message delayed that long was sensed in; () for
    no delay. InputError if the agent was not on the road then."""
    if steps == 0:
        return ()
    vehicles = history.frames[steps - 1]
    me = next((a for a in vehicles if a.agent_id == agent_id), None)
    if me is None:
        raise InputError(f"scene {scene.scene_id}: {agent_id} was not on the road {steps * history.period_s:g} s "
                         "earlier; no delay can be rendered")
    rsus = [a for a in scene.agents if not a.is_vehicle]
    return tuple(a for a in rsus + list(vehicles) if np.hypot(a.x_m - me.x_m, a.y_m - me.y_m) <= EARLIER_RADIUS_M)
