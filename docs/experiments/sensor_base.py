"""A base trained on another sensor than the one it is hardened and tested with: does the attack pay
more when the gap between a model's training data and the scenes it is tuned on is wide?

The single-agent network is trained from scratch on detector-train rendered with the LiDAR preset
PRESET (configs/lidar/; vlp16: 16 channels over +15 to -15 deg, against v2xp's 32 over +2 to -25),
by the first chunk of size_sequence.py's SEQUENCE; AttFuse then from it by the first chunk of its
ATTFUSE_SEQUENCE, on the same frames (train.yaml's blocks otherwise, with ``lidar: PRESET``). Every
chunk resumes from its checkpoint (runs/sensor-base/PRESET/...); the weights and cards go to
DIR/ (single.pt, attfuse.pt), so a committed DIR continues on an empty machine; with attfuse.pt
and its card there, nothing is trained again (single.pt need not be kept). The base is
then scored on normal-val rendered both ways, the sensor it was trained for and v2xp, the sensor
every round of ``asg harden`` attacks, trains and evaluates with (DIR/scores.json: AP@0.3/0.5/0.7
under both yardsticks). Harden it as the other bases were:

    asg harden --fusion attfuse --rounds 1 --weights DIR/attfuse.pt --workers 2 --out OUT [--data random]

    .venv/bin/python docs/experiments/sensor_base.py DIR PRESET
"""
from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path

from asg.datasets import scenes_of
from asg.evaluation import evaluate_detector
from asg.perception.fusion.attfuse import AttFuseDetector
from asg.sensors.lidar_spec import DEFAULT_LIDAR
from asg.training.config import check_train_config, load_train_config
from asg.training.train import train
from sumo_scenarios.atomic import write_text_atomic

from size_sequence import ATTFUSE_SEQUENCE, SEQUENCE  # this folder's

THREADS = 2
#: the models trained, in order: (fusion, weights name, its chunk (steps, peak lr), started from)
STAGES = (("none", "single", SEQUENCE[0], None), ("attfuse", "attfuse", ATTFUSE_SEQUENCE[0], "single"))
SET = "normal-val"


def trained(out: Path, weights: str) -> bool:
    """Whether OUT holds ``weights`` with a card recording a finished chunk."""
    card = out / f"{weights}.json"
    return (out / f"{weights}.pt").is_file() and card.is_file() and bool(json.loads(card.read_text()).get("chunks"))


def train_stage(out: Path, preset: str, fusion: str, weights: str, chunk: tuple[int, float], init_from: str | None) -> Path:
    steps, lr = chunk
    tcfg = check_train_config(replace(load_train_config(weights), steps=steps, lr=lr, schedule="onecycle", lidar=preset),
                              f"sensor_base:{weights}")
    return train(fusion, out_dir=Path("runs") / "sensor-base" / preset / weights, train_config=tcfg, weights_dir=out,
                 validate=False, threads=THREADS, init_from=init_from, log=lambda m: print(f"[{weights}] {m}", flush=True))


def score(out: Path, preset: str) -> dict:
    """AttFuse of OUT on SET rendered with ``preset`` and with the shipped LiDAR."""
    detector = AttFuseDetector(weights_file=str(out / "attfuse.pt"))
    frames = list(scenes_of(SET))  # scored twice: a one-pass iterator would leave the second pass no frames
    result = {"set": SET, "weights": str(out / "attfuse.pt"), "trained_lidar": preset}
    for lidar in (preset, DEFAULT_LIDAR):
        r = evaluate_detector(detector, frames, lidar=lidar)
        result[lidar] = {"ap": r["ap"], "ap_per_frame": r["ap_per_frame"], "frames": r["frames"]}
        print(f"{SET} rendered with {lidar}: AP@0.7 {100 * r['ap']['0.7']:.1f} / {100 * r['ap_per_frame']['0.7']:.1f} "
              "(ours / per frame)", flush=True)
    return result


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print(__doc__.strip().splitlines()[-1], file=sys.stderr)
        return 2
    out, preset = Path(argv[0]), argv[1]
    out.mkdir(parents=True, exist_ok=True)
    # the base trained is the last stage: with it in OUT the earlier ones are not needed (nor kept)
    pending = [] if trained(out, STAGES[-1][1]) else [s for s in STAGES if not trained(out, s[1])]
    for fusion, weights, chunk, init_from in pending:
        # a stage that starts from another's weights takes them from OUT (train's weights_dir)
        train_stage(out, preset, fusion, weights, chunk, init_from)
    assert json.loads((out / "attfuse.json").read_text()).get("lidar") == preset, "the card does not record the training LiDAR"
    write_text_atomic(out / "scores.json", json.dumps(score(out, preset), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
