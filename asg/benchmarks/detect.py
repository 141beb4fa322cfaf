"""``asg bench detect``: median inference time per frame of each shipped model (3 sensing agents)."""
from __future__ import annotations

import itertools
import statistics
import time

from ..perception import build_detector
from ..datasets import scenes_of
from ..scene.neighbours import with_nearest_collaborators
from ..sensors import load_lidar_spec, simulate_frame
from .defaults import DETECT_FRAMES, DETECT_REPEATS


def models() -> list[str]:
    """A row per shipped model with a network of its own: every registered fusion but the
    fine-tuned twins (attfuse-ft runs AttFuse's network, at AttFuse's cost)."""
    from ..perception.fusion import FUSIONS

    return [n for n in FUSIONS.names() if not FUSIONS.entry(n).fine_tuned_from]


def bench_detect(frames: int = DETECT_FRAMES, repeats: int = DETECT_REPEATS, fusion: str | None = None) -> dict:
    """Median ms a frame of each shipped model (or of ``fusion`` alone) on ``frames`` normal scenes
    with 3 sensing agents, each frame timed ``repeats`` times. An OpenCOOD model (``opencood:DIR``)
    is timed beside OpenCOOD's own pipeline on the same frames (:func:`opencood_own_ms`)."""
    import torch

    from ..perception.targets import resolve_target

    torch.set_num_threads(2)
    spec = load_lidar_spec()
    scenes = [with_nearest_collaborators(s, 2) for s in itertools.islice(scenes_of("normal"), frames)]
    coop = [simulate_frame(s, spec) for s in scenes]
    out = {"frames": len(coop), "agents_per_frame": round(statistics.mean(len(f.sensing_ids) for f in coop), 2),
           "threads": torch.get_num_threads()}
    for name in [fusion] if fusion else models():
        out[f"{name}_ms_median"] = round(_median_s(build_detector(name).detect, coop, repeats) * 1e3, 1)
    if fusion and resolve_target(fusion).has_reference_pipeline:
        own = opencood_own_ms(fusion, scenes, repeats)
        out["opencood_own_ms_median"] = own
        out["adapter_overhead"] = round(out[f"{fusion}_ms_median"] / own - 1.0, 3)
        out["goal_adapter_overhead"] = 0.10
    if not fusion:
        out["goal_attfuse_ms"] = 60.0
    return out


def _median_s(call, items, repeats: int) -> float:
    """Median seconds of ``call(item)`` over ``repeats`` rounds of ``items`` (after one warm-up call)."""
    call(items[0])
    times = []
    for _ in range(repeats):
        for item in items:
            t = time.perf_counter()
            call(item)
            times.append(time.perf_counter() - t)
    return statistics.median(times)


def opencood_own_ms(fusion: str, scenes, repeats: int) -> float:
    """Median ms a frame of OpenCOOD's own pipeline as its ``tools/inference.py`` runs it: its
    dataset reading the scenes' OPV2V export (``asg export --format opv2v``), its collate, its
    model as shipped (the adapter's computes AttFuse's attention by the ego's row) and
    post-processor (the calls of ``inference_utils``)."""
    import tempfile
    from pathlib import Path

    import torch

    from ..io.export.opv2v import ScenarioWriter
    from ..perception.opencood import build_opencood_detector
    from ..perception.opencood.folder import checkpoint_of, load_checkpoint
    from ..perception.opencood.runtime import module

    det = build_opencood_detector(fusion)
    model = module("tools.train_utils").create_model(det.dataset.params)
    load_checkpoint(model, checkpoint_of(det.folder))
    model.eval()
    with tempfile.TemporaryDirectory(prefix="asg-bench-opencood-") as tmp:
        writer = ScenarioWriter(Path(tmp))
        for s in scenes:
            writer.write(s)
        dataset = type(det.dataset)(params={**det.dataset.params, "validate_dir": tmp}, visualize=False, train=False)

        def own(i: int) -> None:
            batch = dataset.collate_batch_test([dataset[i]])
            with torch.no_grad():
                det.infer(batch, model, dataset)

        return round(_median_s(own, list(range(len(dataset))), repeats) * 1e3, 1)
