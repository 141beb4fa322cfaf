"""Behaviour unchanged across a restructuring: two ``asg bench paper --scenes N --json --out DIR`` runs
(one per commit, same seed and config) compared. Equal must be the printed table (apart from its
timings), every run folder's scenes after ACS and final (byte for byte), each scene's stored
detections and search history, and each summary's scene entries and aggregate apart from timings.

    .venv/bin/python docs/experiments/run_identity.py BEFORE.json BEFORE_DIR AFTER.json AFTER_DIR

Prints what differs (nothing when identical) and a one-line verdict; exit 1 if anything differs.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

#: keys whose values are wall-clock measurements (differ run to run)
TIMING_KEYS = {"seconds", "seconds_per_scene_median", "scenes_per_hour", "wall_s", "started", "finished"}


def without_timings(value):
    if isinstance(value, dict):
        return {k: without_timings(v) for k, v in value.items() if k not in TIMING_KEYS}
    if isinstance(value, list):
        return [without_timings(v) for v in value]
    return value


def folder_files(root: Path) -> dict[str, object]:
    """{relative path: content} of what a run's outcome is: the scenes after ACS and final, the search
    history (bytes) and the stored detections (their arrays: an .npz's zip entries carry the time
    they were written)."""
    import numpy as np

    out: dict[str, object] = {}
    for pattern in ("*/scenes/*/after_acs.yaml", "*/scenes/*/final.yaml", "*/scenes/*/history.csv"):
        for p in root.glob(pattern):
            out[str(p.relative_to(root))] = p.read_bytes()
    for p in root.glob("*/scenes/*/detections.npz"):
        with np.load(p, allow_pickle=False) as z:
            out[str(p.relative_to(root))] = {k: z[k].tobytes() + str(z[k].shape).encode() for k in z.files}
    return out


def main(before_json: str, before_dir: str, after_json: str, after_dir: str) -> int:
    diffs = []
    a, b = (without_timings(json.loads(Path(p).read_text())) for p in (before_json, after_json))
    if a != b:
        diffs.append("the printed table differs")
    fa, fb = folder_files(Path(before_dir)), folder_files(Path(after_dir))
    diffs += [f"only in one run: {k}" for k in sorted(set(fa) ^ set(fb))]
    diffs += [f"differs: {k}" for k in sorted(set(fa) & set(fb)) if fa[k] != fb[k]]
    for summary in sorted(Path(before_dir).glob("*/summary.json")):
        other = Path(after_dir) / summary.relative_to(before_dir)
        s1, s2 = (without_timings(json.loads(p.read_text())) for p in (summary, other))
        for key in ("scenes", "aggregate"):
            if s1.get(key) != s2.get(key):
                diffs.append(f"{summary.parent.name}/summary.json: {key} differ")
    print("\n".join(diffs) or f"identical: the table, {len(fa)} scene files and every summary's scenes and aggregate")
    return 1 if diffs else 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:]))
