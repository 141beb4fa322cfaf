"""Subnormal numbers and the CPU's speed on them.

Trained weights hold many float32 values below the smallest normal number (1.2e-38): 11-31 % of
each shipped model's weights, mostly filters that training drove to zero, and folding batch norms
into the convolutions makes more. x86 cores compute on such numbers through a slow microcode path,
so a convolution over them ran up to 40x slower than over zeros, and inference and training paid
3-4x and 2.5x (docs/results/speed.md). Their contribution to any output is below 1e-37: computing
them as zeros (the CPU's flush-to-zero and denormals-are-zero modes) gives the same detections.
"""
from __future__ import annotations

import torch
from torch import nn

#: per float type: the integer type of its bits, its exponent bits, its fraction bits
_BITS = {torch.float32: (torch.int32, 0x7F800000, 0x007FFFFF),
         torch.float64: (torch.int64, 0x7FF0000000000000, 0x000FFFFFFFFFFFFF)}


def flush_subnormals_in_all_threads() -> bool:
    """Have this thread, and the threads the OpenMP pool starts afterwards, treat subnormal floats
    as zero; False where the CPU cannot. A pool's threads inherit the mode of the thread that
    starts them, so this runs before the first parallel torch operation (asg.perception sets it
    when it loads); threads already running keep theirs, which :func:`zero_subnormals_` covers for
    the weights."""
    return bool(torch.set_flush_denormal(True))


def subnormal_mask(tensor: torch.Tensor) -> torch.Tensor:
    """Where ``tensor`` (float32 or float64, any shape) holds a subnormal number: its exponent bits
    all zero and its fraction not. Read from the bits, because with denormals-are-zero on a
    comparison sees a subnormal as 0."""
    int_type, exponent, fraction = _BITS[tensor.dtype]
    bits = tensor.view(int_type)
    return ((bits & exponent) == 0) & ((bits & fraction) != 0)


@torch.no_grad()
def zero_subnormals_(module: nn.Module) -> int:
    """Set every subnormal float32 or float64 parameter and buffer of ``module`` to zero, in place;
    how many values changed."""
    changed = 0
    for tensor in (*module.parameters(), *module.buffers()):
        if tensor.dtype in _BITS:
            small = subnormal_mask(tensor)
            count = int(small.sum())
            if count:
                tensor.masked_fill_(small, 0.0)
                changed += count
    return changed
