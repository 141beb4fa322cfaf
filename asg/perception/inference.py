"""Inference-only rewrites of a trained detector: the same function, fewer operations."""
from __future__ import annotations

from torch import nn
from torch.nn.utils.fusion import fuse_conv_bn_eval, fuse_linear_bn_eval

from .numerics import zero_subnormals_
from .pillars import PillarEncoder


def fold_batch_norms(model: nn.Module) -> nn.Module:
    """Fold every BatchNorm that follows a convolution (in a Sequential) or the pillar net's linear
    layer into that layer's weights, in place; the model must be in eval mode (running statistics)."""
    if model.training:
        raise ValueError("fold_batch_norms needs a model in eval mode")
    for module in model.modules():
        if isinstance(module, nn.Sequential):
            for i in range(len(module) - 1):
                layer, norm = module[i], module[i + 1]
                if isinstance(norm, nn.BatchNorm2d) and isinstance(layer, (nn.Conv2d, nn.ConvTranspose2d)):
                    module[i] = fuse_conv_bn_eval(layer, norm, transpose=isinstance(layer, nn.ConvTranspose2d))
                    module[i + 1] = nn.Identity()
        elif isinstance(module, PillarEncoder) and isinstance(module.norm, nn.BatchNorm1d):
            module.linear = fuse_linear_bn_eval(module.linear, module.norm)
            module.norm = nn.Identity()
    zero_subnormals_(model)  # folding scales dead filters below float32's normal range (numerics.py)
    return relus_in_place(model)


def relus_in_place(model: nn.Module) -> nn.Module:
    """Every ReLU of a Sequential that follows a convolution or a linear layer (past folded
    norms) works in place on that layer's fresh output: the same values, one tensor fewer to
    allocate and write (neither layer's backward pass reads its output)."""
    for module in model.modules():
        if isinstance(module, nn.Sequential):
            layers = [m for m in module if not isinstance(m, nn.Identity)]
            for before, layer in zip(layers, layers[1:]):
                if isinstance(layer, nn.ReLU) and isinstance(before, (nn.Conv2d, nn.ConvTranspose2d, nn.Linear)):
                    layer.inplace = True
    return model
