"""How torch's OpenMP threads should wait: spin (long), sleep at once, or spin briefly then sleep?

    python docs/experiments/omp_wait_policy.py ROUNDS [FRAMES] [--generate]

Runs ``asg bench detect --fusion attfuse --json --frames FRAMES`` (two threads) ROUNDS times under
each way of waiting in turn, first quiet, then beside a busy process of each kind: two threads of
torch matrix products (under the runtime's default policy), and two plain Python loops. The ways
(the variables are read when torch loads, so each run is a fresh process; asg keeps a value the
user set):
  - ``runtime``: the OpenMP runtime's default (GNU OpenMP: spin about 3 ms, then sleep);
  - ``sleep``: sleep at once (``OMP_WAIT_POLICY=PASSIVE``, ``GOMP_SPINCOUNT=0``);
  - ``asg``: neither variable set, so asg's own default (asg/__init__.py).
With ``--generate``, also ``asg bench generate --json`` (BO and ``--search ga``, 5 scenes) and
``asg bench train --json``, quiet, under ``sleep`` and ``asg``, alternating.
Prints one JSON object: per way and condition, every run's median ms a frame (and seconds a
scene or a step). Run it on an otherwise idle machine.
"""
from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
ASG = str(ROOT / ".venv/bin/asg")
#: the variables of each way of waiting (None: unset)
WAYS = {
    "runtime": {"OMP_WAIT_POLICY": "", "GOMP_SPINCOUNT": None},
    "sleep": {"OMP_WAIT_POLICY": "PASSIVE", "GOMP_SPINCOUNT": "0"},
    "asg": {"OMP_WAIT_POLICY": None, "GOMP_SPINCOUNT": None},
}
TORCH_BUSY = ("import torch\ntorch.set_num_threads(2)\na = torch.randn(1500, 1500)\n"
              "while True:\n    a = (a @ a).clamp_(-1, 1)\n")
LOOP_BUSY = "while True:\n    pass\n"
CONDITIONS = {"quiet": [], "beside torch": [TORCH_BUSY], "beside two loops": [LOOP_BUSY, LOOP_BUSY]}


def run(way: str, *args: str) -> dict:
    """One ``asg ARGS`` run under ``way``; its JSON line."""
    env = dict(os.environ)
    for name, value in WAYS[way].items():
        env.pop(name, None)
        if value is not None:
            env[name] = value
    out = subprocess.run([ASG, *args], env=env, cwd=ROOT, capture_output=True, text=True, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def detect_ms(way: str, frames: int) -> float:
    return run(way, "bench", "detect", "--fusion", "attfuse", "--frames", str(frames), "--json")["attfuse_ms_median"]


def main(rounds: int, frames: int, generate: bool) -> None:
    result: dict = {"detect_attfuse_ms": {}}
    for condition, programs in CONDITIONS.items():
        busy = [subprocess.Popen([sys.executable, "-c", p], env={**os.environ, "OMP_WAIT_POLICY": ""},
                                 stderr=subprocess.DEVNULL) for p in programs]
        time.sleep(1.5 if busy else 0)
        try:
            runs: dict[str, list[float]] = {w: [] for w in WAYS}
            for _ in range(rounds):
                for way in WAYS:
                    runs[way].append(detect_ms(way, frames))
        finally:
            for p in busy:
                p.kill()
                p.wait()
        result["detect_attfuse_ms"][condition] = {w: {"runs": r, "median": statistics.median(r)} for w, r in runs.items()}
        print(condition, {w: statistics.median(r) for w, r in runs.items()}, file=sys.stderr, flush=True)
    if generate:
        benches = {"bo_s_a_scene": (["bench", "generate", "--json"], "seconds_per_scene_median"),
                   "ga_s_a_scene": (["bench", "generate", "--search", "ga", "--json"], "seconds_per_scene_median"),
                   "train_s_a_step": (["bench", "train", "--json"], "seconds_per_step")}
        for key, (args, field) in benches.items():
            runs = {w: [] for w in ("sleep", "asg")}
            for _ in range(rounds):
                for way in runs:
                    row = run(way, *args)
                    runs[way].append(row[field])
            result[key] = runs
            print(key, runs, file=sys.stderr, flush=True)
    print(json.dumps(result))


if __name__ == "__main__":
    flags = [a for a in sys.argv[1:] if a.startswith("--")]
    numbers = [a for a in sys.argv[1:] if not a.startswith("--")]
    main(int(numbers[0]), int(numbers[1]) if len(numbers) > 1 else 5, "--generate" in flags)
