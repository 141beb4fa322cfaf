"""``asg evaluate``: AP of a fusion model on a data set or a folder of scenes."""
from __future__ import annotations

import argparse
from typing import Callable, Iterable

from sumo_scenarios.errors import InputError

from ..cli_args import COUNT, executor_args, fusion_arg, weights_arg
from ..datasets import SETS, scenes_of  # noqa: F401  (scenes_of, SETS: also this module's API)
from ..objective.ap import ap_by_method
from ..scene import Scene, load_scene
from ..sensors import LidarSpec, load_lidar_spec, simulate_frame
from ..perception.data import Sample
from ..perception.fusion import V2XDetector, build_detector

def scored(frames: list[tuple]) -> dict:
    """{"ap": AP by threshold with the global sort (ours), "ap_per_frame": the paper's yardstick
    (no sort across frames, the frames in the given order), "frames": N} of detected frames."""
    both = ap_by_method(frames)
    return {"ap": both["global"], "ap_per_frame": both["per-frame"], "frames": len(frames)}


def evaluate_detector(detector: V2XDetector, scenes: Iterable[Scene], progress: Callable[[int], None] | None = None) -> dict:
    """{"ap": {"0.3", "0.5", "0.7"}, "ap_per_frame": the same without the global sort, "frames": N,
    "without_collaborators": M} with ground truth = every vehicle in range; M counts the scenes
    that name no collaborator (scored single-agent)."""
    spec = load_lidar_spec()
    frames = []
    alone = 0
    for i, scene in enumerate(scenes):
        alone += not scene.collaborators
        frames.append(_detect(detector, spec, scene))
        if progress:
            progress(i + 1)
    return scored(frames) | {"without_collaborators": alone}


def _detect(detector: V2XDetector, spec: LidarSpec, scene: Scene) -> tuple:
    """(boxes (K, 7), scores (K,), ground truth in range (M, 7)) of ``detector`` on ``scene``, ego frame."""
    sample = Sample(scene.scene_id, simulate_frame(scene, spec))
    boxes, scores = detector.detect(sample.frame)
    return boxes, scores, sample.gt_eval()


def target_detector(fusion: str, weights_file: str | None = None, detector_factory: str | None = None) -> V2XDetector:
    """The detector scored as ``fusion``: its shipped weights (or ``weights_file``), or the target
    that ``detector_factory`` ("module:function", as for ``asg generate --detector``) returns for it."""
    if detector_factory:
        from ..generator.run import factory_models
        from ..generator.config import GenerateConfig

        return factory_models(detector_factory, GenerateConfig(fusion=fusion))[0]
    return build_detector(fusion, weights_file=weights_file)


def _worker_setup(fusion: str, weights_file: str | None, detector_factory: str | None) -> tuple[V2XDetector, LidarSpec]:
    return target_detector(fusion, weights_file, detector_factory), load_lidar_spec()


def _worker_run(state: tuple[V2XDetector, LidarSpec], item: tuple[int, dict]) -> tuple:
    return _detect(*state, Scene.from_dict(item[1]))


def evaluate(fusion: str, set_name: str, limit: int | None = None, progress=None,
             weights_file: str | None = None, executor=None, detector_factory: str | None = None) -> dict:
    """AP of detector ``fusion`` (its shipped weights, or ``weights_file``, or what
    ``detector_factory`` returns) on a set (see scenes_of), its scenes on ``executor`` (default:
    this process); the frames are pooled in the set's order."""
    import itertools

    from ..executors import Job

    scenes = list(itertools.islice(scenes_of(set_name), limit))
    if executor is None:
        result = evaluate_detector(target_detector(fusion, weights_file, detector_factory), scenes, progress)
    else:
        frames: dict[int, tuple] = {}
        job = Job(_worker_setup, _worker_run, (fusion, weights_file, detector_factory))
        for (i, _), detected in executor.map_unordered(job, [(i, s.to_dict()) for i, s in enumerate(scenes)]):
            frames[i] = detected
            if progress:
                progress(len(frames))
        ordered = [frames[i] for i in range(len(scenes))]
        result = scored(ordered) | {"without_collaborators": sum(not s.collaborators for s in scenes)}
    result["fusion"] = fusion
    result["set"] = set_name
    return result


# ``asg evaluate``: this workflow's command (asg.cli's COMMAND_MODULES)

def add_arguments(p: argparse.ArgumentParser) -> None:
    fusion_arg(p, "the model scored", required=True)
    p.add_argument("--set", default="normal", help="normal (train split), normal-val, normal-all, or a folder of scenes")
    p.add_argument("--limit", type=COUNT, default=None, help="only the first N scenes")
    weights_arg(p)
    p.add_argument("--json", action="store_true", help="print JSON only")
    executor_args(p)


def run(args: argparse.Namespace) -> int:
    import contextlib
    import json

    from ..executors import build_executor
    from ..perception import check_fusion, check_weights_file
    from ..progress import console, print_result, progress_bar

    check_fusion(args.fusion)
    weights = None if args.weights is None else str(args.weights)
    if weights:
        check_weights_file(args.fusion, weights)
    # without --workers or --executor: this process on every thread; else workers of one thread
    spread = args.workers is not None or args.executor != "local"
    with progress_bar() as bar, (build_executor(args.executor, args.workers or 1, threads=1, address=args.address)
                                 if spread else contextlib.nullcontext()) as executor:
        task = bar.add_task(f"evaluating {args.fusion}", total=args.limit)
        result = evaluate(args.fusion, args.set, args.limit, lambda n: bar.update(task, completed=n),
                          weights_file=weights, executor=executor)
    if result["without_collaborators"]:
        console.print(f"[yellow]note: {result['without_collaborators']} of {result['frames']} scenes name no "
                      "collaborator, so cooperation is off there (every model scores as single-agent); "
                      "extract scenes with 'asg scenes extract --collaborators K'")
    if args.json:
        print(json.dumps({"ap": result["ap"], "ap_per_frame": result["ap_per_frame"], "frames": result["frames"],
                          "without_collaborators": result["without_collaborators"]}))
    else:
        print_result(f"asg evaluate --fusion {args.fusion} --set {args.set}",
                     {**{f"AP@{k}": round(v, 4) for k, v in result["ap"].items()},
                      **{f"AP@{k} per frame (paper)": round(v, 4) for k, v in result["ap_per_frame"].items()},
                      "frames": result["frames"]}, False)
    return 0
