"""Where an OpenCOOD target's frame goes: cProfile over ``detect`` of the adapter on FRAMES normal
scenes (3 sensing agents, two torch threads, OMP_WAIT_POLICY as the shell sets it), after one
warm-up frame; prints the milliseconds a frame per step.
usage: .venv/bin/python docs/experiments/profile_opencood.py [FRAMES] [MODEL_DIR]
(default: 10 frames of docs/experiments/opencood-attfuse-asg)
"""
import cProfile
import itertools
import pstats
import sys
from pathlib import Path

import torch

from asg.datasets import scenes_of
from asg.perception import build_detector
from asg.scene.neighbours import with_nearest_collaborators
from asg.sensors import load_lidar_spec, simulate_frame

#: step -> (file suffix, function name) whose cumulative time it is
STEPS = {
    "the export's views (agent_views)": ("sensors/opv2v.py", "agent_views"),
    "OpenCOOD's dataset item (projection, mask, voxelise)": ("intermediate_fusion_dataset.py", "__getitem__"),
    "  of which the voxeliser": ("pre_processor/sp_voxel_preprocessor.py", "preprocess"),
    "  of which the point projection": ("intermediate_fusion_dataset.py", "get_item_single_car"),
    "its collate": ("intermediate_fusion_dataset.py", "collate_batch_test"),
    "its model forward": ("point_pillar_intermediate.py", "forward"),
    "its post-processor": ("voxel_postprocessor.py", "post_process"),
    "  of which its NMS": ("box_utils.py", "nms_rotated"),
}


def _cum(stats: dict, suffix: str, name: str) -> float:
    return max((v[3] for (f, _, n), v in stats.items() if f.endswith(suffix) and n == name), default=0.0)


def main(count: int, folder: str) -> None:
    torch.set_num_threads(2)
    spec = load_lidar_spec()
    frames = [simulate_frame(with_nearest_collaborators(s, 2), spec) for s in itertools.islice(scenes_of("normal"), count + 1)]
    det = build_detector(f"opencood:{folder}")
    det.detect(frames[0])
    prof = cProfile.Profile()
    prof.enable()
    for f in frames[1:]:
        det.detect(f)
    prof.disable()
    stats = pstats.Stats(prof).stats
    total = _cum(stats, "opencood/detector.py", "detect")
    print(f"{count} frames: {1e3 * total / count:.0f} ms a frame (under cProfile)")
    for step, (suffix, name) in STEPS.items():
        cum = _cum(stats, suffix, name)
        print(f"  {step:56s} {1e3 * cum / count:7.1f} ms  {100 * cum / total:5.1f} %")
    top = sorted(((v[2], f"{Path(f).name}:{n}") for (f, _, n), v in stats.items()), reverse=True)[:12]
    print("most time of their own:")
    for own, where in top:
        print(f"  {where:56s} {1e3 * own / count:7.1f} ms")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 10,
         sys.argv[2] if len(sys.argv) > 2 else str(Path(__file__).parent / "opencood-attfuse-asg"))
