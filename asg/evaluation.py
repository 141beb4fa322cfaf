"""The evaluation core: AP of a detector on scenes (every vehicle in range is ground truth), under
both yardsticks (ours: one sort across frames; the paper's: per frame), on a set or on an
executor's workers. ``asg evaluate`` (asg.workflows.evaluate), training's model cards, fine-tuning,
hardening and the tables score with it.
"""
from __future__ import annotations

import enum
from pathlib import Path
from typing import Callable, Iterable

from sumo_scenarios.errors import InputError

from .datasets import scenes_of
from .objective.ap import Yardstick, ap_by_method_from_matches, frame_matches
from .objective.pooled import PooledAP
from .perception.data import Sample
from .perception import V2XDetector
from .perception.targets import Target
from .scene import Scene
from .sensors import LidarSpec, load_lidar_spec, simulate_frame
from .sensors.lidar_spec import DEFAULT_LIDAR


class GroundTruth(str, enum.Enum):
    """What a detector is scored against (``asg evaluate --ground-truth``)."""
    #: every vehicle of the scene but the ego whose centre lies within asg's evaluation range of the
    #: ego (|x|, |y| <= 48 m), the detections likewise
    ASG = "asg"
    #: OpenCOOD's own test-time rule, for an OpenCOOD model: what its tools/inference.py scores (its
    #: fixed range, the ego's own car where a collaborator lists it; docs/opencood.md)
    OPENCOOD = "opencood"


def check_ground_truth(truth: GroundTruth, target: Target) -> GroundTruth:
    """``truth`` if ``target`` can be scored by it; one InputError otherwise."""
    if truth is GroundTruth.OPENCOOD and not target.own_ground_truth:
        raise InputError(f"--ground-truth opencood scores an OpenCOOD model folder by OpenCOOD's own test-time rule; "
                         f"'{target.name}' is not one (use --ground-truth asg)")
    return truth


def scored(frames: list[tuple], keep_matches: bool = False) -> dict:
    """{"ap": AP by threshold with the global sort (ours), "ap_per_frame": the paper's yardstick
    (no sort across frames, the frames in the given order), "frames": N} of detected frames; with
    ``keep_matches`` also "matches": each frame's FrameMatches (for a paired interval). No frames is
    a ValueError, never an AP of 0 on 0 frames (a one-pass iterator read twice)."""
    if not frames:
        raise ValueError("given no scenes to score (an empty set, or an iterator already read)")
    matches = [frame_matches(f) for f in frames]
    both = ap_by_method_from_matches(matches)
    result = PooledAP(both[Yardstick.GLOBAL], both[Yardstick.PER_FRAME]).to_json() | {"frames": len(frames)}
    return result | {"matches": matches} if keep_matches else result


def evaluate_detector(detector: V2XDetector, scenes: Iterable[Scene], progress: Callable[[int], None] | None = None,
                      keep_matches: bool = False, lidar: str = DEFAULT_LIDAR, truth: GroundTruth = GroundTruth.ASG) -> dict:
    """{"ap": {"0.3", "0.5", "0.7"}, "ap_per_frame": the same without the global sort, "frames": N,
    "without_collaborators": M} against ground truth ``truth`` (every vehicle in range by default);
    M counts the scenes that name no collaborator (scored single-agent); every frame rendered with
    the ``lidar`` preset. No scenes is a ValueError (see :func:`scored`)."""
    spec = load_lidar_spec(lidar)
    frames = []
    alone = 0
    for i, scene in enumerate(scenes):
        alone += not scene.collaborators
        frames.append(_detect(detector, spec, scene, truth))
        if progress:
            progress(i + 1)
    return scored(frames, keep_matches) | {"without_collaborators": alone}


def _detect(detector: V2XDetector, spec: LidarSpec, scene: Scene, truth: GroundTruth = GroundTruth.ASG) -> tuple:
    """(boxes (K, 7), scores (K,), ground truth (M, 7)) of ``detector`` on ``scene``, ego frame, by
    the ground-truth rule ``truth``."""
    sample = Sample(scene.scene_id, simulate_frame(scene, spec))
    if truth is GroundTruth.OPENCOOD:
        return detector.opencood_frame(sample.frame)
    boxes, scores = detector.detect(sample.frame)
    return boxes, scores, sample.gt_eval()


def target_detector(target: Target, weights_file: str | None = None, detector_factory: str | None = None) -> V2XDetector:
    """The detector scored as ``target``: its shipped weights (or ``weights_file``), or the one
    that ``detector_factory`` ("module:function", as for ``asg generate --detector``) returns for it."""
    if detector_factory:
        from .generator.config import GenerateConfig
        from .generator.run import factory_models

        return factory_models(detector_factory, GenerateConfig(fusion=target.name))[0]
    return target.detector(weights_file)


def _worker_setup(target: Target, weights_file: str | None, detector_factory: str | None,
                  truth: str = GroundTruth.ASG.value) -> tuple[V2XDetector, LidarSpec, GroundTruth]:
    return target_detector(target, weights_file, detector_factory), load_lidar_spec(), GroundTruth(truth)


def _worker_run(state: tuple[V2XDetector, LidarSpec, GroundTruth], item: tuple[int, dict]) -> tuple:
    detector, spec, truth = state
    return _detect(detector, spec, Scene.from_dict(item[1]), truth)


def evaluate(target: Target, set_name: str, limit: int | None = None, progress=None,
             weights_file: str | None = None, executor=None, detector_factory: str | None = None,
             keep_matches: bool = False, truth: GroundTruth = GroundTruth.ASG) -> dict:
    """AP of ``target``'s detector (its shipped weights, or ``weights_file``, or what
    ``detector_factory`` returns) on a set (see scenes_of), its scenes on ``executor`` (default:
    this process), against the ground truth ``truth``; the frames are pooled in the set's order
    (``keep_matches``: see :func:`scored`). A set with no scenes is one InputError."""
    import itertools

    from .executors import Job

    check_ground_truth(truth, target)
    scenes = list(itertools.islice(scenes_of(set_name), limit))
    if not scenes:
        raise InputError(f"set {set_name!r} has no scenes to score; rebuild it ('asg dataset build') or pick another set")
    if executor is None:
        result = evaluate_detector(target_detector(target, weights_file, detector_factory), scenes, progress, keep_matches,
                                   truth=truth)
    else:
        frames: dict[int, tuple] = {}
        job = Job(_worker_setup, _worker_run, (target, weights_file, detector_factory, truth.value))
        for (i, _), detected in executor.map_unordered(job, [(i, s.to_dict()) for i, s in enumerate(scenes)]):
            frames[i] = detected
            if progress:
                progress(len(frames))
        ordered = [frames[i] for i in range(len(scenes))]
        result = scored(ordered, keep_matches) | {"without_collaborators": sum(not s.collaborators for s in scenes)}
    result["fusion"] = target.name
    result["set"] = set_name
    result["ground_truth"] = truth.value
    return result


def scoring_digest() -> str:
    """sha256 of what decides a set's AP besides the weights: the LiDAR simulation and the
    detectors' code (asg/sensors, asg/perception, asg/objective), the LiDAR presets and the
    detector config. A cached evaluation made by other code (say, other vehicle meshes) is not
    reused."""
    import hashlib

    from sumo_scenarios.paths import configs_dir

    root = Path(__file__).resolve().parent
    files = sorted(p for part in ("sensors", "perception", "objective") for p in (root / part).rglob("*.py"))
    files += sorted((configs_dir() / "lidar").glob("*.yaml")) + [configs_dir() / "detectors" / "pointpillars.yaml"]
    h = hashlib.sha256()
    for path in files:
        h.update(str(path.relative_to(path.parents[1])).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def start_evaluations_dir(model_digest: str) -> Path:
    """Where a hardening run caches the evaluations of the model it starts from: a folder of the data
    root named by ``model_digest`` (what identifies the model's files) and :func:`scoring_digest`,
    shared by every run and control that starts from the same model with the same code."""
    from .datasets import data_root

    return data_root() / ".harden-start" / f"{model_digest}-{scoring_digest()[:12]}"
