"""Where a scene's time goes: cProfile over AttFuse + ACS-A + BO (budget 50), one thread, on SCENES
scenes of the `normal` set (every 10th) after one warm-up scene; prints the seconds per stage.
usage: .venv/bin/python docs/experiments/profile_generate.py [SCENES]
"""
import cProfile
import itertools
import pstats
import sys

from asg.executors import apply_threads
from asg.perception import build_detector
from asg.datasets import scenes_of
from asg.generator.pipeline import Generator, load_generate_config

#: stage -> the function whose cumulative time it is (file suffix, function name)
STAGES = {
    "network (pillars, backbone, head)": ("perception/model.py", "forward"),
    "  of which pillar features": ("perception/pillars.py", "encode"),
    "  of which the first convolution (from the pillars)": ("perception/pillars.py", "strided_conv_of_pillars"),
    "post-processing (decode, NMS, voting)": ("perception/model.py", "postprocess"),
    "  of which NMS and voting": ("perception/nms.py", "select_boxes"),
    "point stage": ("perception/point_stage.py", "refine"),
    "render (LiDAR)": ("sensors/frame.py", "render_frame"),
    "AP": ("objective/ap.py", "ap_at"),
    "optimiser ask + tell": (None, None),
    "feasible set Q": ("search/space.py", "__init__"),
    "the scene's world (built once a scene)": ("sensors/renderers.py", "world_for"),
}


def _outermost(stats: dict, suffix: str, name: str) -> float:
    """The largest cumulative time among the functions ``name`` of files ending in ``suffix`` (the
    outermost of nested ones, e.g. AttFuse's forward around its attention's)."""
    return max((v[3] for (f, _, n), v in stats.items() if f.endswith(suffix) and n == name), default=0.0)


def main(count: int) -> None:
    apply_threads(1)
    cfg = load_generate_config(fusion="attfuse", search="bo", acs="attention", budget=50)
    det = build_detector("attfuse")
    gen = Generator(cfg, det, det)
    scenes = list(itertools.islice(scenes_of("normal"), 0, 10 * (count + 1), 10))
    gen.attack(scenes[0], 1)  # warm-up: compiled kernels, caches
    prof = cProfile.Profile()
    prof.enable()
    for scene in scenes[1:]:
        gen.attack(scene, 1)
    prof.disable()
    stats = pstats.Stats(prof).stats
    total = max(v[3] for (f, _, n), v in stats.items() if f.endswith("generator/pipeline.py") and n == "_generate")
    print(f"{count} scenes, {total:.1f} s: {total / count:.2f} s a scene")
    for stage, (suffix, name) in STAGES.items():
        if suffix is None:
            cum = sum(_outermost(stats, "search/bayesian.py", n) for n in ("ask", "tell"))
        else:
            cum = _outermost(stats, suffix, name)
        print(f"  {stage:52s} {cum:6.2f} s  {100 * cum / total:5.1f} %")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 3)
