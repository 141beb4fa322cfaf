"""The 2D backbone: three strided stages, each upsampled to half the pillar resolution and concatenated."""
from __future__ import annotations

import torch
from torch import nn

from .config import DetectorConfig
from .pillars import Pillars, strided_conv_of_pillars


def _conv(cin: int, cout: int, stride: int = 1) -> list[nn.Module]:
    return [nn.Conv2d(cin, cout, 3, stride=stride, padding=1, bias=False), nn.BatchNorm2d(cout, eps=1e-3, momentum=0.01), nn.ReLU()]


class Backbone(nn.Module):
    """(B, pfn, n, n) → (B, 3 * upsample_channels, n/2, n/2)."""

    def __init__(self, cfg: DetectorConfig):
        super().__init__()
        cin = cfg.pfn_channels
        self.stages = nn.ModuleList()
        self.ups = nn.ModuleList()
        for k, (layers, cout) in enumerate(zip(cfg.layers, cfg.filters)):
            mods = _conv(cin, cout, stride=2)
            for _ in range(layers):
                mods += _conv(cout, cout)
            self.stages.append(nn.Sequential(*mods))
            up = 2 ** k
            if up == 1:
                self.ups.append(nn.Sequential(nn.Conv2d(cout, cfg.upsample_channels, 1, bias=False),
                                              nn.BatchNorm2d(cfg.upsample_channels, eps=1e-3, momentum=0.01), nn.ReLU()))
            else:
                self.ups.append(nn.Sequential(nn.ConvTranspose2d(cout, cfg.upsample_channels, up, stride=up, bias=False),
                                              nn.BatchNorm2d(cfg.upsample_channels, eps=1e-3, momentum=0.01), nn.ReLU()))
            cin = cout
        self.out_channels = 3 * cfg.upsample_channels
        self.stage_channels = tuple(cfg.filters)

    def first_stage(self, pillars: Pillars) -> torch.Tensor:
        """Stage 1 on the pillars' canvas → (B, filters[0], n/2, n/2). Its strided convolution is
        computed from the occupied pillars alone (:func:`strided_conv_of_pillars`, the same function
        as on the dense canvas up to float rounding), in inference and in training alike: no
        canvas is built, and the backward pass reaches only the occupied pillars (a training
        step of AttFuse spent about half its time scattering the canvas and back-propagating the
        dense convolution through empty cells)."""
        stage = self.stages[0]
        return stage[1:](strided_conv_of_pillars(stage[0], pillars))

    def stage_outputs(self, x: torch.Tensor, start: int = 0) -> list[torch.Tensor]:
        """(B, pfn, n, n) → each stage's output (B, filters[k], n / 2^(k+1), n / 2^(k+1)); with
        ``start`` = k > 0, ``x`` is stage k-1's output and only stages k, k+1, ... run."""
        outs = []
        for stage in self.stages[start:]:
            x = stage(x)
            outs.append(x)
        return outs

    def upsample(self, stage_outs: list[torch.Tensor]) -> torch.Tensor:
        """Stage outputs → (B, 3 * upsample_channels, n/2, n/2)."""
        return torch.cat([up(x) for up, x in zip(self.ups, stage_outs)], dim=1)

    def after_first_stage(self, first: torch.Tensor) -> torch.Tensor:
        """Stage 1's output (B, filters[0], n/2, n/2) → the later stages and the upsampling →
        (B, 3 * upsample_channels, n/2, n/2)."""
        return self.upsample([first] + self.stage_outputs(first, start=1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.upsample(self.stage_outputs(x))
