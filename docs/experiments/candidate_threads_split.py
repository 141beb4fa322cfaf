"""Where a batch of candidates loses its second core: AttFuse's whole detection and its network
alone on FRAMES normal frames (3 sensing agents), three ways: one torch thread frame after frame,
two frames side by side on the generator's candidate threads (one torch thread each), and one frame
at a time on two intra-op threads; medians of ROUNDS rounds of the effective ms a frame.
usage: .venv/bin/python docs/experiments/candidate_threads_split.py [FRAMES] [ROUNDS]
"""
import itertools
import json
import statistics
import sys
import time

import torch

from asg.datasets import scenes_of
from asg.executors import apply_threads
from asg.generator.candidates import CandidateThreads
from asg.perception import build_detector
from asg.perception.feeds import AGENT_CLOUDS
from asg.scene.neighbours import with_nearest_collaborators
from asg.sensors import load_lidar_spec, simulate_frame


def main(count: int, rounds: int) -> None:
    apply_threads(2)
    spec = load_lidar_spec()
    frames = [simulate_frame(with_nearest_collaborators(s, 2), spec) for s in itertools.islice(scenes_of("normal"), count)]
    det = build_detector("attfuse")
    assert det.feed is AGENT_CLOUDS
    threads = CandidateThreads(2)

    def network(frame) -> None:
        """The network's pass alone, on the sample its feed makes of the frame (as detect does)."""
        ego = frame.ego_id
        clouds = [torch.from_numpy(c) for c in frame.clouds_in_frame_of(ego)]
        sample = det.feed.network_input([clouds], [frame.kinds_in_frame_of(ego)], [frame.delays_in_frame_of(ego)])[0]
        with torch.no_grad():  # no_grad is per thread: each candidate thread sets its own
            det.model([sample])

    ways = {
        "one_thread_in_sequence": lambda call: [call(f) for f in frames],
        "two_side_by_side": lambda call: threads.map(call, frames),
        "two_intra_op_threads_in_sequence": lambda call: [call(f) for f in frames],
    }
    result = {}
    for way, run in ways.items():
        torch.set_num_threads(1 if way == "one_thread_in_sequence" else 2)
        for part, call in (("detect", det.detect), ("network", network)):
            run(call)  # warm-up
            times = []
            for _ in range(rounds):
                t = time.perf_counter()
                run(call)
                times.append((time.perf_counter() - t) / len(frames) * 1e3)
            result[f"{way}_{part}_ms"] = round(statistics.median(times), 1)
    threads.close()
    print(json.dumps({"frames": count, "rounds": rounds} | result))


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 16, int(sys.argv[2]) if len(sys.argv) > 2 else 3)
