"""A training checkpoint (``last.pt`` of ``asg train`` or of an ``asg harden`` round) in half
precision, so that a run spanning sittings commits the one file its resume needs under the tree's
8 MiB limit: every float32 tensor of the model becomes float16 and of the optimiser's state bfloat16
(the step counters, generator states and the rest stay as they are). The same command resumes from it:
loading casts the model's and Adam's tensors back to float32 (not bit-identical to a run that was
never stopped: the weights and moments lose their low bits once).

    .venv/bin/python docs/experiments/half_checkpoint.py SRC.pt DST.pt
"""
from __future__ import annotations

import sys
from pathlib import Path

import torch

from asg.training.checkpoint import load_checkpoint
from sumo_scenarios.atomic import atomic_path


def halved(value, dtype: torch.dtype = torch.float16):
    """``value`` with every float32 tensor inside it (dicts and lists walked) in ``dtype``."""
    if isinstance(value, torch.Tensor):
        return value.to(dtype) if value.dtype == torch.float32 else value
    if isinstance(value, dict):
        return {k: halved(v, dtype) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(halved(v, dtype) for v in value)
    return value


def half_checkpoint(src: Path, dst: Path) -> None:
    state = load_checkpoint(src)
    if state is None:
        raise SystemExit(f"{src}: no checkpoint")
    # Adam's second moments (squared gradients, 1e-12 and below) underflow to 0 in float16 and would
    # blow the next steps up: the optimiser's state keeps float32's range in bfloat16
    out = dict(state, model=halved(state["model"]), optimizer=halved(state["optimizer"], torch.bfloat16))
    with atomic_path(dst) as tmp:
        torch.save(out, tmp)
    print(f"{dst}: {dst.stat().st_size / 2**20:.1f} MiB (from {src.stat().st_size / 2**20:.1f} MiB), step {state['step']}")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        print(__doc__.strip().splitlines()[-1], file=sys.stderr)
        sys.exit(2)
    half_checkpoint(Path(sys.argv[1]), Path(sys.argv[2]))
