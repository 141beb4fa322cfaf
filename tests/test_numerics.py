"""Subnormal floats computed as zeros: the same detections, at full speed (asg/perception/numerics.py)."""
from __future__ import annotations

import subprocess
import sys

import torch
from torch import nn

from asg.perception import build_detector
from asg.perception.numerics import subnormal_mask, zero_subnormals_
from asg.perception.weights_io import weights_path
import pytest

#: torch's kernels decide these outcomes: CI runs this file again on AVX2 and default kernels
pytestmark = pytest.mark.numeric

TINY = torch.finfo(torch.float32).tiny


def _floats(*bits: int) -> torch.Tensor:
    """float32 values from their bits: written as floats, subnormals would be flushed to zero on the
    way in (this process computes them as zeros)."""
    return torch.tensor(bits, dtype=torch.int32).view(torch.float32)


SUB, NEG_SUB, SMALLEST = 0x000AE398, -0x7FF51C68, 0x00000001  # 1e-39, -1e-39 (sign bit set), 1.4e-45


def _subnormals(module: nn.Module) -> int:
    return sum(int(subnormal_mask(t).sum()) for t in (*module.parameters(), *module.buffers()))


def test_subnormals_are_found_by_their_bits():
    x = torch.cat([torch.tensor([0.0, -0.0]), _floats(SUB, NEG_SUB, SMALLEST),
                   torch.tensor([TINY, -TINY, 1.0, float("inf"), float("nan")])])
    assert subnormal_mask(x).tolist() == [False, False, True, True, True, False, False, False, False, False]
    assert subnormal_mask(torch.tensor([1], dtype=torch.int64).view(torch.float64)).tolist() == [True]
    assert subnormal_mask(torch.tensor([1e-300], dtype=torch.float64)).tolist() == [False]


def test_zero_subnormals_changes_only_the_subnormal_values():
    layer = nn.Linear(3, 2)
    with torch.no_grad():
        layer.weight.view(torch.int32).copy_(torch.tensor([[SUB, NEG_SUB, 0x3F000000], [0x00800000, SMALLEST, 0]]))
        layer.bias.view(torch.int32).copy_(torch.tensor([SUB, -0x40800000]))  # 1e-39, -1.0
    assert zero_subnormals_(layer) == 4
    assert layer.weight.view(torch.int32).tolist() == [[0, 0, 0x3F000000], [0x00800000, 0, 0]]  # 0.5, TINY kept
    assert layer.bias.view(torch.int32).tolist() == [0, -0x40800000]
    assert zero_subnormals_(layer) == 0


def test_shipped_weights_hold_subnormals_and_the_loaded_detector_none():
    state = torch.load(weights_path(build_detector("none").weights), weights_only=True)
    state = state.get("model", state)
    assert sum(int(subnormal_mask(v).sum()) for v in state.values() if v.is_floating_point()) > 1000
    assert _subnormals(build_detector("none").model) == 0  # loaded, then folded: none left


@pytest.mark.slow
def test_a_fresh_process_with_asg_perception_loaded_computes_subnormals_as_zeros_on_every_thread():
    """The OpenMP pool's threads inherit the mode, so a parallel operation on two threads gives zeros."""
    code = ("import asg.perception, torch; torch.set_num_threads(2); "
            "x = torch.full((4_000_000,), 0x000AE398, dtype=torch.int32).view(torch.float32); "  # 1e-39
            "print(int((x * 3.0).view(torch.int32).ne(0).sum()))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["0"]
