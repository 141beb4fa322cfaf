"""Data sets of scenes rendered from SUMO logs: ``asg dataset build NAME`` (configs/datasets.yaml).

On disk (``runs/datasets/NAME/`` unless ``ASG_DATA`` says otherwise)::

    frames.jsonl.gz   one scene dict per line (asg.scene.Scene.to_dict), collaborators set
    index.json        {"name", "frames", "splits": {"train": [scene ids], "val": [...]}, "logs"}

LiDAR is not stored: it is re-rendered deterministically from the scenes when needed (a frame
renders in tens of milliseconds), which keeps a set at a few MB.
"""
from __future__ import annotations

import gzip
import zlib
import json
import shutil
from dataclasses import replace
from pathlib import Path
from typing import Callable, Iterable, Iterator

import numpy as np

from sumo_scenarios.atomic import atomic_dir, remove_stale_partials_of
from sumo_scenarios.errors import InputError
from sumo_scenarios.log import NEAR_RADIUS_M
from sumo_scenarios.simulate import SimulationRequest, simulate_sumo

from .dataset_spec import DatasetSpec, data_root, load_spec  # noqa: F401  (this module's API too)
from .schemas import SchemaFile, schema_of, stamped
from .scene import Scene, load_scene
from .scene.from_log import ExtractParams, extract_scenes
from .scene.neighbours import random_collaborators, vehicles_within


def _choose_agents(scene: Scene, rng: np.random.Generator, use_rsu: bool, collaborators: int) -> Scene | None:
    """Pick the ego (the scene's RSU, or a random vehicle near it) and random collaborators."""
    ego = scene.ego_id
    if not use_rsu:
        near = vehicles_within(scene, scene.ego_id, NEAR_RADIUS_M)
        if not near:
            return None
        ego = near[int(rng.integers(len(near)))].agent_id
    chosen = random_collaborators(scene, ego, collaborators, rng)
    return None if chosen is None else replace(scene, ego_id=ego, collaborators=chosen)


def _log_frames(spec: DatasetSpec, town: str, density: str, seed: int, workdir: Path) -> list[Scene]:
    log = workdir / f"{town}_{density}_{seed}"
    simulate_sumo(SimulationRequest(out_dir=log, town=town, seed=seed, duration_s=spec.duration_s, density=density))
    rng = np.random.default_rng([seed, len(town), sum(map(ord, town + density))])
    out = []
    for scene in extract_scenes(log, ExtractParams(every=spec.every, min_vehicles=3)):
        chosen = _choose_agents(scene, rng, bool(rng.random() < spec.ego_rsu_share), spec.collaborators)
        if chosen is not None and _kept(spec, chosen):
            out.append(replace(chosen, log=log.name))  # the log's name, not its temporary path
        if spec.frames_per_log and len(out) >= spec.frames_per_log:
            break
    return out


def _kept(spec: DatasetSpec, scene: Scene) -> bool:
    """The spec's frame filters: vehicles in the evaluation range, mean LiDAR points per box."""
    from .scene.feasibility import in_eval_range

    if spec.vehicles_in_range is not None:
        others = [a for a in scene.vehicles if a.agent_id != scene.ego_id]
        n = int(in_eval_range(scene.ego, others).sum())
        if not spec.vehicles_in_range[0] <= n <= spec.vehicles_in_range[1]:
            return False
    return True


def mean_points_in_box(scene: Scene) -> float:
    """Mean number of fused LiDAR points (v2xp) inside the ground-truth boxes within range."""
    from .perception.data import points_in_range_boxes
    from .sensors import load_lidar_spec, simulate_frame

    counts = points_in_range_boxes(simulate_frame(scene, load_lidar_spec()))
    return float(counts.mean()) if len(counts) else 0.0


def build_dataset(name: str, progress: Callable[[int, int], None] | None = None, executor=None) -> Path:
    """Simulate the logs of data set ``name`` and write its frames; returns the folder. The logs
    run on ``executor`` (default: this process); each log is seeded on its own, so the set does not
    depend on where they ran."""
    from .executors import Job
    from .executors.local import LocalExecutor

    spec = load_spec(name)
    runs = [(t, d, s) for t in spec.towns for d in spec.densities for s in spec.seeds][: spec.max_logs]
    out = data_root() / name
    logs_dir = out.parent / f".work-{name}"  # the simulated logs: beside the set, removed when done
    shutil.rmtree(logs_dir, ignore_errors=True)  # what a killed build left
    remove_stale_partials_of(out)
    dicts_of_log: dict[tuple, list[dict]] = {}
    try:
        job = Job(_worker_setup, _worker_run, (spec, str(logs_dir)))
        for run, dicts in (executor or LocalExecutor()).map_unordered(job, runs):
            dicts_of_log[run] = dicts
            if progress:
                progress(len(dicts_of_log), len(runs))
    finally:
        shutil.rmtree(logs_dir, ignore_errors=True)
    candidates = [(f"{t}_{d}_{s}", dicts_of_log[(t, d, s)]) for t, d, s in runs]
    kept = _fewest_points(spec, candidates)
    logs = [(name, [Scene.from_dict({k: v for k, v in d.items() if k != "mean_points_in_box"}) for d in dicts])
            for name, dicts in kept]
    splits = _split(spec, logs)
    with atomic_dir(out) as work:
        with gzip.open(work / "frames.jsonl.gz", "wt", encoding="utf-8") as fh:
            for _, scenes in logs:
                for s in scenes:
                    if any(s.scene_id in ids for ids in splits.values()):
                        fh.write(json.dumps(s.to_dict(), separators=(",", ":")) + "\n")
        index = stamped(SchemaFile.INDEX, {"name": name, "frames": sum(len(v) for v in splits.values()),
                                           "splits": splits, "logs": {k: [s.scene_id for s in v] for k, v in logs},
                                           "frames_passing_filters": sum(len(v) for _, v in candidates)})
        (work / "index.json").write_text(json.dumps(index, indent=1))
    return out


def _worker_setup(spec: DatasetSpec, logs_dir: str) -> tuple[DatasetSpec, Path]:
    return spec, Path(logs_dir)


def _worker_run(state: tuple[DatasetSpec, Path], run: tuple[str, str, int]) -> list[dict]:
    """One log of the set: simulated, its frames extracted and their agents chosen (as dicts, each
    with its mean points per box when the spec selects by them)."""
    spec, logs_dir = state
    scenes = _log_frames(spec, *run, logs_dir)
    if spec.fewest_points_share is None:
        return [s.to_dict() for s in scenes]
    return [s.to_dict() | {"mean_points_in_box": mean_points_in_box(s)} for s in scenes]


def _fewest_points(spec: DatasetSpec, logs: list[tuple[str, list[dict]]]) -> list[tuple[str, list[dict]]]:
    """Keep ``spec.fewest_points_share`` of all frames, those with the fewest mean points per box
    (ties by scene id), in their logs' order."""
    if spec.fewest_points_share is None:
        return logs
    ranked = sorted((d["mean_points_in_box"], d["scene_id"]) for _, dicts in logs for d in dicts)
    keep = {sid for _, sid in ranked[: int(round(spec.fewest_points_share * len(ranked)))]}
    return [(name, [d for d in dicts if d["scene_id"] in keep]) for name, dicts in logs]


def _split(spec: DatasetSpec, logs: list[tuple[str, list[Scene]]]) -> dict[str, list[str]]:
    """All frames in 'train', or, with ``total``/``val``: whole logs to val first, trimmed to size."""
    if spec.total is None:
        return {spec.split: [s.scene_id for _, scenes in logs for s in scenes]}
    val, train = [], []
    for _, scenes in logs:
        ids = [s.scene_id for s in scenes]
        if len(val) < (spec.val or 0):
            val += ids[: (spec.val or 0) - len(val)]
        elif len(train) < spec.total - (spec.val or 0):
            train += ids[: spec.total - (spec.val or 0) - len(train)]
    if len(train) + len(val) < spec.total:
        raise InputError(f"data set needs {spec.total} frames but the logs gave {len(train) + len(val)}; add seeds")
    return {"train": train, "val": val}


def dataset_path(name: str) -> Path:
    return data_root() / name


#: a data set's frame line longer than this is refused (a scene of 200 agents is about 60 kB)
MAX_FRAME_LINE_BYTES = 16 * 1024 * 1024
#: ...and an index.json larger than this
MAX_INDEX_BYTES = 64 * 1024 * 1024


def iter_frames(name_or_dir: str | Path, split: str | None = None) -> Iterator[Scene]:
    """Scenes of a built data set (a name under the data root, or a folder), optionally one split.
    A damaged folder (a symbolic link, a garbage, truncated or oversized file, a malformed line, a
    split naming scenes the frames lack) is one InputError naming the file. An id may repeat: the
    same town, seed and time at two densities are two scenes of one id (detector-train's)."""
    p = Path(name_or_dir)
    folder = p if (p / "index.json").is_file() else dataset_path(str(name_or_dir))
    if not (folder / "index.json").is_file():
        raise InputError(f"data set '{name_or_dir}' is not built; run 'asg dataset build {name_or_dir}'")
    index = _read_index(folder)
    wanted = None
    if split is not None:
        if split not in index["splits"]:
            raise InputError(f"data set '{name_or_dir}' has no split '{split}'; splits: {', '.join(index['splits'])}")
        wanted = set(index["splits"][split])
    frames = _regular_file(folder / "frames.jsonl.gz")
    missing = set(wanted or ())  # the split's scenes not met yet
    try:
        with gzip.open(frames, "rb") as fh:
            for number, line in enumerate(iter(lambda: fh.readline(MAX_FRAME_LINE_BYTES + 1), b""), start=1):
                if len(line) > MAX_FRAME_LINE_BYTES:
                    raise InputError(f"{frames}: line {number} is longer than {MAX_FRAME_LINE_BYTES // 2**20} MB; "
                                     "not a data set asg wrote: rebuild it")
                d = json.loads(line.decode("utf-8"))
                if not isinstance(d, dict) or not isinstance(d.get("scene_id"), str):
                    raise InputError(f"{frames}: line {number} is not a scene; rebuild the data set")
                missing.discard(d["scene_id"])
                if wanted is None or d["scene_id"] in wanted:
                    yield Scene.from_dict(d, str(folder))
    except (OSError, EOFError, zlib.error, UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise InputError(f"{frames}: damaged ({type(exc).__name__}); rebuild the data set with 'asg dataset build'") from None
    if missing:
        raise InputError(f"{folder / 'index.json'}: split '{split}' names {len(missing)} scenes that "
                         f"{frames.name} does not hold (e.g. {sorted(missing)[0][:60]!r}); rebuild the data set")


def _regular_file(path: Path) -> Path:
    """``path`` if it is a regular file, not a symbolic link (a data set's files never are)."""
    if path.is_symlink() or not path.is_file():
        raise InputError(f"{path}: not a regular file of a data set (a link, a special file or missing); "
                         "rebuild the data set")
    return path


def _read_index(folder: Path) -> dict:
    """A data set's index.json, checked: a mapping whose ``splits`` maps names to lists of ids."""
    path = _regular_file(folder / "index.json")
    try:
        if path.stat().st_size > MAX_INDEX_BYTES:
            raise ValueError("too large")
        index = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise InputError(f"{path}: damaged ({type(exc).__name__}); rebuild the data set") from None
    schema_of(SchemaFile.INDEX, index, str(path))
    splits = index.get("splits") if isinstance(index, dict) else None
    if not isinstance(splits, dict) or not all(isinstance(v, list) and all(isinstance(i, str) for i in v)
                                               for v in splits.values()):
        raise InputError(f"{path}: no splits of scene ids; rebuild the data set")
    return index


#: --set names: the normal set's splits (the paper attacks its train split, reports fine-tuning on val),
#: the other built sets whole (detector-train: what the shipped detectors trained on, e.g. to export it)
SETS = {"normal": ("normal", "train"), "normal-val": ("normal", "val"), "normal-all": ("normal", None),
        "heuristic": ("heuristic", None), "holdout": ("holdout", None), "detector-train": ("detector-train", None)}


def check_set_name(set_name: str) -> str:
    """``set_name`` if :func:`scenes_of` can take it (a named set, ``challenging-NAME-SPLIT`` or a
    folder), without building or reading it; else one InputError."""
    from sumo_scenarios.checks import safe_id

    if not set_name.strip():
        raise InputError(f"--set is empty; use {', '.join(SETS)}, challenging-MODEL-SPLIT or a folder of scenes")
    if set_name in SETS or Path(set_name).is_dir():
        return set_name
    if set_name.startswith("challenging-"):
        return safe_id(set_name, "challenging set")
    raise InputError(f"unknown set {set_name!r}; use {', '.join(SETS)}, challenging-MODEL-SPLIT or a folder of scenes")


def unique_ids(scenes: Iterable[Scene], separator: str = "-") -> Iterator[Scene]:
    """The scenes, a repeated id made unique by its repeat number (``ID-2``, ``ID-3``): a data set may
    hold two scenes of one id (the same town, seed and time at two traffic densities), which would
    otherwise be one folder or file of a run or an export. ``separator``: what stands before the
    number (a hardening pool's is ``_``: its rounds' scene folders and seeds are named so)."""
    seen: dict[str, int] = {}
    for scene in scenes:
        k = seen[scene.scene_id] = seen.get(scene.scene_id, 0) + 1
        yield scene if k == 1 else replace(scene, scene_id=f"{scene.scene_id}{separator}{k}")


def scenes_of(set_name: str) -> Iterator[Scene]:
    """Scenes of a named set (building the normal set if needed; a repeated id made unique,
    :func:`unique_ids`) or of a folder of scene yaml."""
    check_set_name(set_name)
    if set_name in SETS:
        name, split = SETS[set_name]
        if not (dataset_path(name) / "index.json").is_file():
            build_dataset(name)
        return unique_ids(iter_frames(name, split))
    if set_name.startswith("challenging-"):
        return challenging_scenes(set_name)
    p = Path(set_name)
    if (p / "index.json").is_file():
        return unique_ids(iter_frames(p))
    if p.is_dir():
        files = sorted(p.glob("*.yaml"))
        if not files:
            raise InputError(f"{p}: no scene yaml files; give a folder written by 'asg scenes extract' or 'asg generate'")
        return (load_scene(f) for f in files)
    raise InputError(f"unknown set {set_name!r}; use {', '.join(SETS)}, challenging-MODEL-SPLIT or a folder of scenes")


def _build_hint(name: str) -> str:
    """The command that builds the challenging set ``name`` (``challenging-MODEL-SPLIT``); a set
    made against a prefixed target (``challenging-opencood-NAME-DIGEST-SPLIT``) names the target's
    form, ``opencood:DIR``: its folder cannot be read back from the set's name."""
    from .registry import TARGET_PREFIXES

    parts = name.split("-")
    if len(parts) < 3:
        return "asg dataset build challenging --fusion NAME --split val"
    model = "-".join(parts[1:-1])
    prefixed = next((p.prefix for kind, p in TARGET_PREFIXES.items() if model.startswith(f"{kind}-")), None)
    return f"asg dataset build challenging --fusion {f'{prefixed}DIR' if prefixed else model} --split {parts[-1]}"


def challenging_scenes(name: str):
    """The scenes of a built challenging set, by its name (``challenging-NAME-SPLIT``)."""
    from sumo_scenarios.checks import safe_id

    if not name.startswith("challenging-"):
        raise InputError(f"'{name}' is not a challenging set name (challenging-MODEL-train|val)")
    safe_id(name, "challenging set")  # a name, never a path out of the data folder
    if not (data_root() / name / "index.json").is_file():
        raise InputError(f"challenging set '{name}' is not built; run '{_build_hint(name)}'")
    return iter_frames(data_root() / name)
