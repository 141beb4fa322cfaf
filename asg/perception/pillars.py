"""Pillars: points → per-pillar learned features (PointNet over each pillar) → BEV canvas.

Points (N, 4) float32 x, y, z, intensity in the detecting frame. Each point gets 9 features
(x, y, z, intensity, offsets to its pillar's point mean, offsets to the pillar centre in x, y);
a shared linear layer + BatchNorm + ReLU, then a max over the pillar's points (all of them: a
scatter-max replaces the reference's fixed 32-point buffers and gives the same function on
pillars of up to 32 points).
"""
from __future__ import annotations

import warnings

import torch
from torch import nn

warnings.filterwarnings("ignore", message="index_reduce", category=UserWarning)

from .config import DetectorConfig


def pillar_indices(points: torch.Tensor, cfg: DetectorConfig) -> tuple[torch.Tensor, torch.Tensor]:
    """Keep points inside the grid; returns (kept points (K, 4), flat pillar index (K,))."""
    r = cfg.range_m
    z0, z1 = cfg.z_range_m
    keep = (points[:, 0].abs() < r) & (points[:, 1].abs() < r) & (points[:, 2] >= z0) & (points[:, 2] < z1)
    p = points[keep]
    n = cfg.grid_size
    ix = ((p[:, 0] + r) / cfg.pillar_m).long().clamp_(0, n - 1)
    iy = ((p[:, 1] + r) / cfg.pillar_m).long().clamp_(0, n - 1)
    return p, iy * n + ix


class PillarEncoder(nn.Module):
    """A batch of clouds → BEV canvases (B, C, n, n), row = y index, column = x index, stored
    channels-last (``torch.channels_last``)."""

    def __init__(self, cfg: DetectorConfig):
        super().__init__()
        self.cfg = cfg
        self.linear = nn.Linear(9, cfg.pfn_channels, bias=False)
        self.norm = nn.BatchNorm1d(cfg.pfn_channels, eps=1e-3, momentum=0.01)

    def forward(self, clouds: list[torch.Tensor]) -> torch.Tensor:
        cfg = self.cfg
        n = cfg.grid_size
        cells = n * n
        feats = []
        for pts in clouds:
            p, flat = pillar_indices(pts, cfg)
            uniq, inv = torch.unique(flat, return_inverse=True)
            count = torch.zeros(len(uniq), device=p.device).index_add_(0, inv, torch.ones(len(p), device=p.device))
            mean = torch.zeros(len(uniq), 3, device=p.device).index_add_(0, inv, p[:, :3]) / count.clamp(min=1)[:, None]
            cx = (flat % n).float() * cfg.pillar_m - cfg.range_m + cfg.pillar_m / 2
            cy = (flat // n).float() * cfg.pillar_m - cfg.range_m + cfg.pillar_m / 2
            f = torch.cat([p, p[:, :3] - mean[inv], (p[:, 0] - cx)[:, None], (p[:, 1] - cy)[:, None]], dim=1)
            feats.append((f, inv, uniq))
        batch = len(clouds)
        canvas = torch.zeros(batch, cells, cfg.pfn_channels)
        all_f = torch.cat([f for f, _, _ in feats]) if feats else torch.zeros(0, 9)
        h = torch.relu(self.norm(self.linear(all_f)))
        start = 0
        for b, (f, inv, uniq) in enumerate(feats):
            hh = h[start:start + len(f)]
            start += len(f)
            canvas[b, uniq] = torch.zeros(len(uniq), cfg.pfn_channels).index_reduce_(0, inv, hh, "amax",
                                                                                      include_self=False)
        # (B, C, n, n) in channels-last memory: each cell's C features adjacent, which the
        # convolutions (oneDNN) run fastest on; the values are those of the contiguous layout
        return canvas.view(batch, n, n, cfg.pfn_channels).permute(0, 3, 1, 2)
