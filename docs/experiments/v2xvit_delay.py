"""What V2X-ViT's delay encoding and training over noisy links give: AP@0.3/0.5/0.7 under both
yardsticks (ours: global sort; the paper's: per frame) on normal-val and on normal-val-noisy (the
standard noisy setting: each collaborator's pose off by 0.2 m / 0.2 deg, its message 100 ms late)
of the shipped AttFuse, V2X-ViT and v2xvit-noisy (its delay encoding, trained over perfect and
noisy links), v2xvit-noisy with the delays hidden from it (every cloud read as current: what
knowing the delay gives), and any extra weights named NAME=FUSION:PATH (say V2X-ViT trained over
noisy links without the encoding, docs/experiments/v2xvit_noisy_plain.py), all on the same
simulated frames.

    .venv/bin/python docs/experiments/v2xvit_delay.py OUT.json [NAME=FUSION:WEIGHTS ...]
"""
from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path

import torch

from asg.datasets import data_root, scenes_of
from asg.evaluation import scored
from asg.perception import build_detector
from asg.perception.data import Sample
from asg.sensors import load_lidar_spec, simulate_frame
from asg.workflows.harden import noisy_val_set


def _variants(extra: list[str]) -> list[tuple[str, object, bool]]:
    """(row name, detector, hide the delays)."""
    rows = [("attfuse", build_detector("attfuse"), False), ("v2xvit", build_detector("v2xvit"), False),
            ("v2xvit-noisy", build_detector("v2xvit-noisy"), False),
            ("v2xvit-noisy, delays hidden", build_detector("v2xvit-noisy"), True)]
    for item in extra:
        name, spec = item.split("=", 1)
        fusion, path = spec.split(":", 1)
        rows.append((name, build_detector(fusion, weights_file=Path(path)), False))
    return rows


def main(out_path: str, extra: list[str]) -> None:
    torch.set_num_threads(2)
    spec = load_lidar_spec()
    noisy_val_set()
    sets = {"normal-val": "normal-val", "normal-val-noisy": str(data_root() / "normal-val-noisy")}
    samples = {name: [Sample(s.scene_id, simulate_frame(s, spec)) for s in scenes_of(where)] for name, where in sets.items()}
    rows = []
    for name, det, hidden in _variants(extra):
        for set_name, frames_of in samples.items():
            frames = []
            for s in frames_of:
                frame = replace(s.frame, agent_delays_s={}) if hidden else s.frame
                boxes, scores = det.detect(frame)
                frames.append((boxes, scores, s.gt_eval()))
            result = scored(frames)
            rows.append({"model": name, "set": set_name, "frames": len(frames), "ap": result["ap"],
                         "ap_per_frame": result["ap_per_frame"]})
            print(json.dumps(rows[-1]), flush=True)
    with open(out_path, "w") as fh:
        json.dump({"rows": rows}, fh, indent=1)


if __name__ == "__main__":
    args = sys.argv[1:]
    if not args:
        sys.exit(__doc__)
    main(args[0], args[1:])
