"""Pillars: points → per-pillar learned features (PointNet over each pillar) → BEV canvas.

Points (N, 4) float32 x, y, z, intensity in the detecting frame. Each point gets 9 features
(x, y, z, intensity, offsets to its pillar's point mean, offsets to the pillar centre in x, y);
a shared linear layer + BatchNorm + ReLU, then a max over the pillar's points (all of them: a
scatter-max replaces the reference's fixed 32-point buffers and gives the same function on
pillars of up to 32 points).
"""
from __future__ import annotations

import torch
from torch import nn

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


#: points whose learned features inference computes at once (4096 x 64 floats: 1 MB, a core's cache)
POINTS_A_CHUNK = 4096


def occupied_cells(flat: torch.Tensor, cells: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``torch.unique(flat, return_inverse=True)`` of pillar indices ``flat`` (K,) in [0, cells):
    the occupied pillars in ascending order (P,) and each point's position among them (K,),
    marked on the grid and counted instead of sorted (about a fifth of the time for a cloud)."""
    occupied = torch.zeros(cells, dtype=torch.bool).index_fill_(0, flat, True)
    rank = torch.cumsum(occupied, 0) - 1
    return torch.nonzero(occupied).squeeze(1), rank.index_select(0, flat)


class PillarEncoder(nn.Module):
    """A batch of clouds → BEV canvases (B, C, n, n), row = y index, column = x index, stored
    channels-last (``torch.channels_last``)."""

    def __init__(self, cfg: DetectorConfig):
        super().__init__()
        self.cfg = cfg
        self.linear = nn.Linear(9, cfg.pfn_channels, bias=False)
        self.norm = nn.BatchNorm1d(cfg.pfn_channels, eps=1e-3, momentum=0.01)

    def encode(self, clouds: list[torch.Tensor]) -> "Pillars":
        """The occupied pillars of each cloud and their learned features (see :class:`Pillars`)."""
        cfg = self.cfg
        n = cfg.grid_size
        feats = []
        for pts in clouds:
            p, flat = pillar_indices(pts, cfg)
            uniq, inv = occupied_cells(flat, n * n)
            count = torch.zeros(len(uniq), device=p.device).index_add_(0, inv, torch.ones(len(p), device=p.device))
            mean = torch.zeros(len(uniq), 3, device=p.device).index_add_(0, inv, p[:, :3]) / count.clamp(min=1)[:, None]
            cx = (flat % n).float() * cfg.pillar_m - cfg.range_m + cfg.pillar_m / 2
            cy = (flat // n).float() * cfg.pillar_m - cfg.range_m + cfg.pillar_m / 2
            f = torch.cat([p, p[:, :3] - mean.index_select(0, inv), (p[:, 0] - cx)[:, None], (p[:, 1] - cy)[:, None]], dim=1)
            feats.append((f, inv, uniq))
        all_f = torch.cat([f for f, _, _ in feats]) if feats else torch.zeros(0, 9)
        # one max over every cloud's pillars at once (pillar indices offset per cloud), then one
        # split: per-cloud slices of h would each back-propagate a zero tensor of h's full size.
        # The ReLU after the max: max_i relu(h_i) = relu(max_i h_i) (it is monotone), the same
        # bits, on a pillar's row rather than on every point's
        offsets = torch.tensor([0] + [len(u) for _, _, u in feats]).cumsum(0)
        inv_all = torch.cat([inv + offsets[k] for k, (_, inv, _) in enumerate(feats)]) if feats \
            else torch.zeros(0, dtype=torch.long)
        if self.training or torch.is_grad_enabled():  # batch statistics, or the max's gradient: one pass
            pooled_all = torch.relu(pillar_max(self.norm(self.linear(all_f)), inv_all, int(offsets[-1])))
        else:
            pooled_all = torch.relu_(self._pooled_by_chunks(all_f, inv_all, int(offsets[-1])))
        cells = [uniq for _, _, uniq in feats]
        pooled = list(torch.split(pooled_all, [len(u) for u in cells]))
        return Pillars(cells, pooled, n, stacked=pooled_all)

    def _pooled_by_chunks(self, point_feats: torch.Tensor, pillar: torch.Tensor, pillars: int) -> torch.Tensor:
        """Inference's pillar max of the points' learned features, before the ReLU: ``point_feats``
        (K, 9), ``pillar`` (K,) each point's pillar in [0, pillars) → (pillars, C). The points
        go through the linear layer POINTS_A_CHUNK at a time, each chunk's features folded into
        the running maximum while they are in the core's cache: the learned features of every
        point at once (K x 64 floats, 64 MB for ACS-A's 24 agents) would go to memory and back.
        A maximum is exact in any order: the same bits (tests/test_perception.py)."""
        out = torch.full((pillars, self.linear.out_features), float("-inf"))  # every pillar holds a point
        for start in range(0, len(point_feats), POINTS_A_CHUNK):
            h = self.norm(self.linear(point_feats[start:start + POINTS_A_CHUNK]))
            index = pillar[start:start + POINTS_A_CHUNK, None].expand(-1, h.shape[1])
            _scatter_amax(out, index, h)
        return out

    def forward(self, clouds: list[torch.Tensor]) -> torch.Tensor:
        return self.encode(clouds).canvas()


def pillar_max(h: torch.Tensor, pillar: torch.Tensor, pillars: int) -> torch.Tensor:
    """Per pillar and channel, the largest feature of its points: h (K, C), pillar (K,) index of
    each point's pillar in [0, pillars) → (pillars, C); a pillar without points is 0.

    With gradients, the maximum is taken by index (the winning point of each pillar and channel,
    found without gradients, then gathered): the gradient flows to that point alone, as in
    max-pooling, and the backward pass is one scatter instead of a reduction's tie counting
    (about 10 % of an AttFuse training step). Where several points tie, the last one wins (the
    encoder takes the maximum before its ReLU, where equal features are rare; where the maximum is
    not above 0, the ReLU passes no gradient to it either way)."""
    channels = h.shape[1]
    index = pillar[:, None].expand(-1, channels)
    if not torch.is_grad_enabled() or not h.requires_grad:
        return _scatter_amax(torch.zeros(pillars, channels), index, h, include_self=False)
    with torch.no_grad():
        best = _scatter_amax(torch.zeros(pillars, channels), index, h, include_self=False)
        point = torch.arange(len(h))[:, None].expand(-1, channels)
        winner = torch.where(h == best[pillar], point, torch.full_like(point, -1))
        winner = _scatter_amax(torch.full((pillars, channels), -1, dtype=torch.long), index, winner)
    return h.gather(0, winner.clamp(min=0)) * (winner >= 0)


def _scatter_amax(out: torch.Tensor, index: torch.Tensor, values: torch.Tensor, include_self: bool = True) -> torch.Tensor:
    """``out`` (P, C) with each row the largest of ``values`` (K, C) whose ``index`` (K, C; a
    point's pillar repeated over the channels) names it, in place. A maximum is exact in any
    order; scatter_reduce's CPU kernel is several times faster than index_reduce's (docs/results/speed.md)."""
    return out.scatter_reduce_(0, index, values, "amax", include_self=include_self)


class Pillars:
    """Per sample b: ``cells[b]`` (P_b,) the flat index (row y * n + column x) of each occupied
    pillar, ``features[b]`` (P_b, C) its learned features; every other pillar is zero.
    ``stacked``: every sample's features in one (sum P_b, C) tensor, when ``features`` are its
    slices (the encoder's), so that :meth:`all_features` copies nothing."""

    def __init__(self, cells: list[torch.Tensor], features: list[torch.Tensor], grid_size: int,
                 stacked: torch.Tensor | None = None):
        self.cells = cells
        self.features = features
        self.grid_size = grid_size
        self.stacked = stacked

    def all_features(self) -> torch.Tensor:
        """Every sample's features, sample after sample: (sum P_b, C)."""
        if self.stacked is not None:
            return self.stacked
        return torch.cat(self.features) if self.features else torch.zeros(0, 0)

    def canvas(self) -> torch.Tensor:
        """BEV canvases (B, C, n, n), channels-last in memory (each cell's C features adjacent,
        which the convolutions (oneDNN) run fastest on; the values are the contiguous layout's)."""
        n = self.grid_size
        channels = self.features[0].shape[1] if self.features else 0
        canvas = torch.zeros(len(self.cells), n * n, channels)
        for b, (cells, feats) in enumerate(zip(self.cells, self.features)):
            canvas[b, cells] = feats
        return canvas.view(len(self.cells), n, n, channels).permute(0, 3, 1, 2)


def strided_conv_of_pillars(conv: nn.Conv2d, pillars: Pillars) -> torch.Tensor:
    """``conv`` (3x3, stride 2, padding 1, with or without bias) applied to the pillars' canvas,
    computed from the occupied pillars alone: each pillar feeds the output cells whose 3x3 window
    holds it (1, 2 or 4 of them, by the parity of its row and column), so the work is about 2.25
    (C_in x C_out) products per pillar instead of 9 per output cell of a mostly empty canvas. The
    same function as ``conv(pillars.canvas())`` up to float rounding (the sums run in another
    order). Returns (B, C_out, n/2, n/2), channels-last in memory."""
    if conv.kernel_size != (3, 3) or conv.stride != (2, 2) or conv.padding != (1, 1) or conv.groups != 1:
        raise ValueError("strided_conv_of_pillars takes a 3x3 convolution of stride 2 and padding 1")
    n = pillars.grid_size
    m = (n + 1) // 2
    batch = len(pillars.cells)
    weight = conv.weight  # (C_out, C_in, 3, 3)
    c_out = weight.shape[0]
    trash = batch * m * m  # one more row: where a pillar past the last output row or column adds
    out = torch.zeros(trash + 1, c_out)
    if conv.bias is not None:
        out += conv.bias
    classes = _ParityClasses(pillars, m)
    for ky in range(3):
        for kx in range(3):
            # output row oy takes input rows 2 oy - 1 + ky: the pillars of row iy feed oy = (iy + 1 - ky) / 2,
            # an odd row for ky = 0 or 2, an even one for ky = 1 (the same for columns)
            rows = classes.rows(ky != 1, kx != 1)
            if rows.stop == rows.start:
                continue
            target = classes.target[rows] - (m if ky == 2 else 0) - (1 if kx == 2 else 0)
            past = [edge[rows] for edge, k in ((classes.past_y, ky), (classes.past_x, kx)) if k == 0]
            if past:  # the tap 0 of the last input row (column) falls past the output: into the trash row
                target = torch.where(past[0] if len(past) == 1 else past[0] | past[1], trash, target)
            out.index_add_(0, target, classes.feats[rows] @ weight[:, :, ky, kx].t())
    return out[:trash].view(batch, m, m, c_out).permute(0, 3, 1, 2)


class _ParityClasses:
    """The pillars of a batch sorted by the parity of their row and column (even-even, even-odd,
    odd-even, odd-odd), each class in the batch's order: the pillars that feed one tap of a
    stride-2 convolution are one class, a slice. ``feats`` (P, C_in) sorted; ``target`` (P,) the
    flat output cell (sample, (iy + 1) // 2, (ix + 1) // 2) each feeds through the taps ky, kx in
    {0, 1}; ``past_y`` / ``past_x`` (P,) whether that row or column is past the output's last."""

    def __init__(self, pillars: Pillars, m: int):
        n, batch = pillars.grid_size, len(pillars.cells)
        cells = torch.cat([c + b * n * n for b, c in enumerate(pillars.cells)]) if batch else torch.zeros(0, dtype=torch.long)
        feats = pillars.all_features()
        sample, local = cells // (n * n), cells % (n * n)
        iy, ix = local // n, local % n
        parity = (iy % 2) * 2 + ix % 2
        order = torch.argsort(parity, stable=True)
        oy, ox = (iy.index_select(0, order) + 1) // 2, (ix.index_select(0, order) + 1) // 2
        self.feats = feats.index_select(0, order)  # rows copied whole: several times faster than feats[order]
        self.target = sample.index_select(0, order) * m * m + oy * m + ox
        self.past_y, self.past_x = oy == m, ox == m
        self.starts = [0] + torch.bincount(parity, minlength=4).cumsum(0).tolist()

    def rows(self, odd_row: bool, odd_column: bool) -> slice:
        """The slice of the class of pillars in odd (or even) rows and odd (or even) columns."""
        k = 2 * odd_row + odd_column
        return slice(self.starts[k], self.starts[k + 1])
