"""glibc's malloc as it is against asg's setting (asg.perception.allocator: freed blocks kept for
the next frame): ms and page faults a frame of AttFuse, V2VNet and the OpenCOOD folder
``opencood-attfuse-asg``, two threads, the two ways alternating in child processes, ROUNDS rounds.

A child measures glibc's own behaviour when it is given a neutral malloc setting of the user's
(``GLIBC_TUNABLES=glibc.malloc.tcache_count=7``, glibc's default value), which asg leaves alone.
usage: .venv/bin/python docs/experiments/freed_memory.py [ROUNDS] [FRAMES]
"""
import itertools
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

MODELS = ("attfuse", "v2vnet", f"opencood:{Path(__file__).resolve().parent / 'opencood-attfuse-asg'}")
#: a user's malloc setting that changes nothing (glibc's default count), so asg keeps glibc's own behaviour
GLIBC_AS_IT_IS = "glibc.malloc.tcache_count=7"


def child(frames_count: int) -> dict:
    """Median ms a frame (5 rounds of the frames after one warm-up pass), minor page faults a frame
    and the process's peak memory, for each model."""
    from asg.datasets import scenes_of
    from asg.executors import apply_threads
    from asg.perception import build_detector
    from asg.scene.neighbours import with_nearest_collaborators
    from asg.sensors import load_lidar_spec, simulate_frame

    apply_threads(2)
    spec = load_lidar_spec()
    frames = [simulate_frame(with_nearest_collaborators(s, 2), spec)
              for s in itertools.islice(scenes_of("normal"), frames_count)]
    out = {}
    for name in MODELS:
        det = build_detector(name)
        for f in frames:
            det.detect(f)
        faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        times = []
        for _ in range(5):
            t = time.perf_counter()
            for f in frames:
                det.detect(f)
            times.append((time.perf_counter() - t) / len(frames) * 1e3)
        label = name.split(":")[0] if name.startswith("opencood:") else name
        out[label] = {"ms": round(statistics.median(times), 1),
                      "faults": round((resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults) / (5 * len(frames)))}
    out["peak_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024
    return out


def main(rounds: int, frames_count: int) -> None:
    for r in range(rounds):
        for way in ("glibc", "asg"):
            env = {k: v for k, v in os.environ.items() if k != "GLIBC_TUNABLES" and not k.startswith("MALLOC_")}
            if way == "glibc":
                env["GLIBC_TUNABLES"] = GLIBC_AS_IT_IS
            done = subprocess.run([sys.executable, __file__, "--child", str(frames_count)], env=env,
                                  capture_output=True, text=True, check=True)
            print(json.dumps({"round": r + 1, "way": way, **json.loads(done.stdout.splitlines()[-1])}), flush=True)


if __name__ == "__main__":
    if sys.argv[1:2] == ["--child"]:
        print(json.dumps(child(int(sys.argv[2]))))
    else:
        main(int(sys.argv[1]) if len(sys.argv) > 1 else 3, int(sys.argv[2]) if len(sys.argv) > 2 else 16)
