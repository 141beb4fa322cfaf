"""What V2X-ViT's two parts give: AP@0.3/0.5/0.7 under both yardsticks (ours: global sort; the
paper's: per frame) of the shipped V2X-ViT as it is, with every agent read as a vehicle (its RSU
projections and edge matrices unused: what telling RSUs from vehicles gives), and with its window
attention off (MSwin's projection zeroed: what the attention across cells gives), beside the
shipped AttFuse, on the same simulated frames; and the median time of a frame.

    .venv/bin/python docs/experiments/v2xvit_parts.py OUT.json [SET]      (default normal-val)
"""
from __future__ import annotations

import json
import statistics
import sys
import time
from dataclasses import replace

import torch

from asg.datasets import scenes_of
from asg.evaluation import scored
from asg.perception import build_detector
from asg.perception.data import Sample
from asg.sensors import load_lidar_spec, simulate_frame


def _variants() -> list[tuple[str, object, bool]]:
    """(row name, detector, read every agent as a vehicle)."""
    plain = build_detector("v2xvit")
    no_window = build_detector("v2xvit")
    with torch.no_grad():
        no_window.model.window.proj.weight.zero_()
        no_window.model.window.proj.bias.zero_()
    return [("attfuse", build_detector("attfuse"), False), ("v2xvit", plain, False),
            ("v2xvit, every agent a vehicle", build_detector("v2xvit"), True),
            ("v2xvit, window attention off", no_window, False)]


def main(out_path: str, set_name: str) -> None:
    torch.set_num_threads(2)
    spec = load_lidar_spec()
    samples = [Sample(s.scene_id, simulate_frame(s, spec)) for s in scenes_of(set_name)]
    rows = []
    for name, det, all_vehicles in _variants():
        frames, times = [], []
        for s in samples:
            frame = replace(s.frame, agent_kinds={}) if all_vehicles else s.frame
            start = time.perf_counter()
            boxes, scores = det.detect(frame)
            times.append(time.perf_counter() - start)
            frames.append((boxes, scores, s.gt_eval()))
        result = scored(frames)
        rows.append({"model": name, "frames": len(frames), "ap": result["ap"], "ap_per_frame": result["ap_per_frame"],
                     "ms_median": round(1e3 * statistics.median(times), 1)})
        print(json.dumps(rows[-1]), flush=True)
    rsu_collaborators = sum(k == "rsu" for s in samples for a, k in s.frame.agent_kinds.items() if a != s.frame.ego_id)
    rsu_egos = sum(s.frame.agent_kinds.get(s.frame.ego_id) == "rsu" for s in samples)
    with open(out_path, "w") as fh:
        json.dump({"set": set_name, "rsu_egos": rsu_egos, "rsu_collaborators": rsu_collaborators, "rows": rows}, fh, indent=1)


if __name__ == "__main__":
    args = sys.argv[1:]
    if not args:
        sys.exit(__doc__)
    main(args[0], args[1] if len(args) > 1 else "normal-val")
