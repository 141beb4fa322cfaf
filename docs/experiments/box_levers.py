"""Which lever sharpens the boxes? Training arms of the single-agent network (No Fusion), each
scored on normal-val and heuristic: AP@0.3/0.5/0.7 under both yardsticks (ours: global sort; the
paper's: per frame), and the share of visible vehicles (10+ fused points) whose best candidate
fits at IoU 0.5-0.7 but none at 0.7 (miss_stages.py's stage "best candidate 0.5-0.7").

Arm "shipped" scores the shipped weights as they are. Arms that continue the shipped weights run one chunk of the same length, seed and batches
(the control's settings, one change each); arms "from scratch" train a fresh network of a size
for the same steps, the size's step cost measured in the log. Each arm trains into
OUT/ARM/ (weights, card, checkpoint: an interrupted arm resumes where it stopped, a finished
one is scored once and kept in OUT/ARM/result.json).

    .venv/bin/python docs/experiments/box_levers.py OUT [ARM ...]

Arms: see ARMS below (default: all).
"""
from __future__ import annotations

import json
import shutil
import sys
import time
from dataclasses import asdict, replace
from pathlib import Path

from asg.datasets import scenes_of
from asg.perception.config import load_detector_config
from asg.perception.data import Augmentation
from asg.perception.fusion.single import NoFusion
from asg.perception.weights_io import WEIGHTS_DIR
from asg.evaluation import evaluate_detector
from asg.training.config import TrainConfig
from asg.training.train import train

from miss_stages import STAGES, rows_of  # this folder's

#: a continuation chunk: one more onecycle chunk of the shipped single weights, as train.yaml's
#: single block runs them, shorter
CONTINUE = TrainConfig(steps=2000, batch_size=4, lr=0.0005, schedule="onecycle", pct_start=0.3, seed=1,
                       checkpoint_every=200)
#: a fresh network: the first chunks of the shipped recipe, one chunk at its first rate
SCRATCH = TrainConfig(steps=1000, batch_size=4, lr=0.002, schedule="onecycle", pct_start=0.3, seed=1,
                      checkpoint_every=200)
BASE = load_detector_config()
#: the paper's PointPillars (0.4 m pillars, layers [3, 5, 8], filters 64/128/256) and steps between
SIZES = {"shipped": BASE,
         "wide": replace(BASE, filters=(64, 128, 256), upsample_channels=128),
         "deep": replace(BASE, layers=(3, 5, 8)),
         "paper": replace(BASE, pillar_m=0.4, layers=(3, 5, 8), filters=(64, 128, 256), upsample_channels=128)}
#: arm: (start "continue" | "scratch", training settings, detector size)
ARMS = {
    "shipped": ("none", CONTINUE, "shipped"),
    "control": ("continue", CONTINUE, "shipped"),
    "rot10": ("continue", replace(CONTINUE, augment=Augmentation(rotate_deg=10.0)), "shipped"),
    "corner": ("continue", replace(CONTINUE, corner_loss=0.25), "shipped"),
    "scratch-shipped": ("scratch", SCRATCH, "shipped"),
    "scratch-wide": ("scratch", SCRATCH, "wide"),
    "scratch-deep": ("scratch", SCRATCH, "deep"),
    "scratch-paper": ("scratch", SCRATCH, "paper"),
}
SETS = ("normal-val", "heuristic")


def run_arm(out: Path, arm: str) -> dict:
    result_path = out / arm / "result.json"
    if result_path.is_file():
        return json.loads(result_path.read_text())
    start, tcfg, size = ARMS[arm]
    cfg = SIZES[size]
    weights_dir = out / arm
    weights_dir.mkdir(parents=True, exist_ok=True)
    if start == "continue" and not (weights_dir / "single.json").is_file():
        for f in ("single.pt", "single.json"):
            shutil.copy(WEIGHTS_DIR / f, weights_dir / f)
    t0 = time.perf_counter()
    if start == "none":  # the shipped weights as they are
        weights = WEIGHTS_DIR / "single.pt"
        for f in ("single.pt", "single.json"):
            shutil.copy(WEIGHTS_DIR / f, weights_dir / f)
    else:
        weights = train("none", out_dir=weights_dir / "run", train_config=tcfg, detector_config=cfg,
                        weights_dir=weights_dir, validate=False, log=lambda m: print(f"[{arm}] {m}", flush=True))
    train_s = time.perf_counter() - t0
    card = json.loads((weights_dir / "single.json").read_text())
    detector = NoFusion(cfg=cfg, weights_file=str(weights))
    result = {"arm": arm, "start": start, "size": size, "train": asdict(tcfg), "detector": asdict(cfg),
              "chunk_wall_s": card["chunks"][-1]["wall_s"] if start != "none" else 0.0, "run_s": round(train_s, 1), "sets": {}}
    for set_name in SETS:
        t = time.perf_counter()
        scores = evaluate_detector(detector, scenes_of(set_name))
        rows = rows_of(set_name, detector, cfg)
        stage = {s: round(100 * float((rows[:, 1] == k).mean()), 1) for k, s in enumerate(STAGES)}
        result["sets"][set_name] = {"ap": scores["ap"], "ap_per_frame": scores["ap_per_frame"],
                                    "frames": scores["frames"], "visible": len(rows), "stage_pct": stage,
                                    "eval_s": round(time.perf_counter() - t, 1)}
        print(f"[{arm}] {set_name}: AP {scores['ap']} per-frame {scores['ap_per_frame']} stages {stage}", flush=True)
    result_path.write_text(json.dumps(result, indent=1))
    return result


def main(out: str, *arms: str) -> None:
    for arm in arms or ARMS:
        run_arm(Path(out), arm)
    rows = [json.loads(p.read_text()) for a in (arms or ARMS) if (p := Path(out) / a / "result.json").is_file()]
    print("| arm | set | AP@0.5 | AP@0.7 | AP@0.7 per frame | best candidate 0.5-0.7 (%) | chunk (min) |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        for s, v in r["sets"].items():
            print(f"| {r['arm']} | {s} | {100 * v['ap']['0.5']:.1f} | {100 * v['ap']['0.7']:.1f} | "
                  f"{100 * v['ap_per_frame']['0.7']:.1f} | {v['stage_pct'][STAGES[2]]} | {r['chunk_wall_s'] / 60:.1f} |")


if __name__ == "__main__":
    main(*sys.argv[1:])
