"""Inference beside a busy process: does OpenMP's spin-waiting cost the shared machine?

    python docs/experiments/omp_wait_policy.py ROUNDS [FRAMES]

Runs ``asg bench detect --json`` (two threads) ROUNDS times under each OpenMP wait policy in turn
(the runtime's default and PASSIVE, asg's; OMP_WAIT_POLICY, read when torch loads), first
quiet, then beside a busy process (two threads of torch matrix products, the issue's setting).
Prints one JSON line: per policy and condition, the median over rounds of each model's median
ms a frame, and the busy/quiet ratio. Run it on an otherwise idle machine.
"""
from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: OMP_WAIT_POLICY's value ("": the runtime's default; asg sets PASSIVE only where it is unset)
POLICIES = {"default": "", "passive": "PASSIVE"}
MODELS = ("none", "late", "early", "attfuse")
BUSY = ("import torch\ntorch.set_num_threads(2)\na = torch.randn(1500, 1500)\n"
        "while True:\n    a = (a @ a).clamp_(-1, 1)\n")


def bench(policy: str, frames: int) -> dict:
    env = dict(os.environ, OMP_WAIT_POLICY=policy)
    out = subprocess.run([str(ROOT / ".venv/bin/asg"), "bench", "detect", "--json", "--frames", str(frames)],
                         env=env, cwd=ROOT, capture_output=True, text=True, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main(rounds: int, frames: int) -> None:
    result: dict = {}
    for condition in ("quiet", "busy"):
        busy = subprocess.Popen([sys.executable, "-c", BUSY]) if condition == "busy" else None
        try:
            runs = {name: [] for name in POLICIES}
            for _ in range(rounds):
                for name, policy in POLICIES.items():
                    runs[name].append(bench(policy, frames))
        finally:
            if busy is not None:
                busy.kill()
        for name in POLICIES:
            result.setdefault(name, {})[condition] = {
                m: round(statistics.median(r[f"{m}_ms_median"] for r in runs[name]), 1) for m in MODELS}
    for name in POLICIES:
        q, b = result[name]["quiet"], result[name]["busy"]
        result[name]["busy_over_quiet"] = {m: round(b[m] / q[m], 2) for m in MODELS}
    print(json.dumps(result))


if __name__ == "__main__":
    main(int(sys.argv[1]), int(sys.argv[2]) if len(sys.argv) > 2 else 5)
