"""OpenCOOD's pillar feature net at inference (``models/sub_modules/pillar_vfe.py``, ``PFNLayer``): its
batch norm, ReLU and max over a pillar's points taken in the other order, a slice of pillars at a
time, with the same bits.

OpenCOOD's last PFN layer maps each of a pillar's T point slots to C features (a linear map), puts
every one of them through the batch norm and a ReLU, and keeps each feature's largest value over the
slots (the empty ones included). For the few thousand pillars of a frame the (P, T, C) map is tens
of MB, written and read several times over, and the batch norm runs on a transposed view of it, which
torch's CPU kernels take by their slow element-by-element path.

At inference the batch norm is, for each channel c, the float operations
``((x - mean_c) * invstd_c) * weight_c + bias_c`` (torch's kernel for such a view, with
``invstd_c = 1 / sqrt(var_c + eps)``), and ReLU follows. Each of those rounded operations is
monotonic in x: non-decreasing, except the product by a negative weight, which is non-increasing.
So the largest value over the points equals the batch norm and ReLU of the largest linear
output where weight_c >= 0 and of the smallest where weight_c < 0, to the bit; here they are
computed on (P, 1, C) instead of (P, T, C). The linear map and the max or min run on
:data:`SLICE_PILLARS` pillars at a time, whose map stays in the cache (OpenCOOD's own forward maps
more than 50,000 pillars in parts of 50,000 the same way; the bits are tested against its layer).
Training, a layer that is not the last, or one without a batch norm runs OpenCOOD's own
code.
"""
from __future__ import annotations

import torch

from .runtime import compute_instances_by, module

#: pillars a slice: the linear map's output of a slice (512 x 32 x 64 floats for OpenCOOD's usual
#: T and C, 4 MiB) stays in the cache between the product and the max
SLICE_PILLARS = 512


def pillar_max(inputs: torch.Tensor, linear: torch.nn.Linear, norm: torch.nn.BatchNorm1d) -> torch.Tensor:
    """inputs (P, T, F) -> (P, 1, C): the max over T of ReLU(``norm`` (eval mode, C channels) of
    ``linear(inputs)``), computed from the max (or, where the norm's weight is negative, the min)
    over T of the linear map, :data:`SLICE_PILLARS` pillars at a time; the same bits as OpenCOOD's
    order (module docstring)."""
    rising = norm.weight >= 0
    extremes = []
    for start in range(0, inputs.shape[0], SLICE_PILLARS):
        mapped = linear(inputs[start:start + SLICE_PILLARS])
        extremes.append(torch.where(rising, mapped.amax(dim=1, keepdim=True), mapped.amin(dim=1, keepdim=True)))
    var = norm.running_var + norm.eps
    invstd = torch.ones_like(var).div_(var.sqrt_())  # ATen's 1 / sqrt(var + eps)
    return torch.cat(extremes).sub_(norm.running_mean).mul_(invstd).mul_(norm.weight).add_(norm.bias).relu_()


def pfn_forward(self, inputs: torch.Tensor) -> torch.Tensor:
    """``PFNLayer.forward``: inputs (P, T, F) -> (P, 1, C) for the last layer; by :func:`pillar_max`
    at inference, OpenCOOD's own code otherwise (and for a frame without pillars)."""
    norm = getattr(self, "norm", None)
    if (self.training or torch.is_grad_enabled() or not (self.use_norm and self.last_vfe) or norm is None
            or norm.training or not norm.affine or norm.running_var is None or inputs.shape[0] == 0):
        return type(self).forward(self, inputs)
    return pillar_max(inputs, self.linear, norm)


def pfn_layer_type() -> type:
    return module("models.sub_modules.pillar_vfe").PFNLayer


def use_pillar_max(model: torch.nn.Module) -> list[torch.nn.Module]:
    """Every ``PFNLayer`` of ``model`` computes its inference by :func:`pfn_forward` (this instance
    only: OpenCOOD's class stays as shipped); returns them."""
    return compute_instances_by(model, pfn_layer_type(), pfn_forward)
