"""V2X-ViT (Xu et al., ECCV 2022) on our PointPillars: attention across agents that tells vehicles
from roadside units, then attention across BEV cells in windows of several sizes.

Each agent's cloud (in the ego frame) goes through the shared pillar net and first backbone stage,
as in AttFuse. Then, per BEV cell, V2X-ViT's heterogeneous multi-agent self-attention (HMSA,
:class:`HeteroAttention`): the query, key and value projections are the agent kind's own (vehicle
or RSU), the attention and the message each pass through a matrix of the edge's kinds (ego kind,
agent kind), and the result through a dense layer of the ego's kind. Then V2X-ViT's multi-scale
window attention (MSwin, :class:`MultiScaleWindowAttention`) on the fused map: self-attention
within windows of 4, 8 and 16 cells (4, 8 and 16 m), one head per size with a relative-position
bias, the sizes' outputs projected together and added to the map. The rest of the backbone and the
head run on the result. The kinds come with the frame (``CooperativeFrame.agent_kinds``); training
feeds them through :data:`asg.perception.feeds.KINDED_AGENT_CLOUDS`.

``v2xvit-noisy`` adds V2X-ViT's delay-aware positional encoding (:class:`DelayEncoding`: each
agent's first-stage features plus a learnt projection of a sinusoidal code of its message's delay,
``CooperativeFrame.agent_delays_s``, which the receiver knows from the message's time stamp) and
is trained on every frame twice: as sent over a perfect link and in the standard noisy setting
(asg.scene.noisy: pose error and a 100 ms delay), the way V2X-ViT learns from delayed messages.

Kept from V2X-ViT: HMSA's kind-specific projections and edge matrices, MSwin's window sizes in
cells (its 4/8/16 windows) with relative-position bias; in ``v2xvit-noisy`` its delay encoding.
Reduced: one encoder layer (V2X-ViT stacks 3), one head per attention (it uses 8), no feed-forward
blocks, at AttFuse's place (the first stage's 32 channels) rather than on a 256-channel map; no
spatial-temporal correction module (V2X-ViT's learnt warp of a delayed agent's map); ``v2xvit``
itself has no delay encoding either: it trains on perfect links, as every other shipped model,
where a delay term would only ever see 0.
At the start (``start_from_base`` after AttFuse's weights) the network computes AttFuse's
function exactly: the RSU projections are copies of the vehicle ones, the edge and dense matrices
identities and the window attention's projection zero.
"""
from __future__ import annotations

import math
from typing import Collection

import torch
from torch import nn
from torch.nn import functional as F

from .base import FUSIONS
from ..config import DetectorConfig
from ..feeds import KINDED_AGENT_CLOUDS, KindedClouds
from ..model import AttFuse
from .attfuse import AttFuseDetector

#: MSwin's window sizes (BEV cells of the fused map; 0.5 m pillars at stride 2: 1 m a cell)
WINDOWS_CELLS = (4, 8, 16)
#: the delay encoding counts a delay in steps of this (s): 0.1 s is 10 steps
DELAY_STEP_S = 0.01


def _kind_linear(vehicle: nn.Linear, rsu: nn.Linear, x: torch.Tensor, is_rsu: torch.Tensor) -> torch.Tensor:
    """x (..., C) through the vehicle or the RSU layer, as ``is_rsu`` (broadcast to x[..., 0]) says."""
    return torch.where(is_rsu[..., None], rsu(x), vehicle(x))


class HeteroAttention(nn.Module):
    """V2X-ViT's HMSA, one head, the ego's row, per BEV cell:
    a_j = softmax_j(k_j . (W_att[e_j] q) / sqrt(C)), out = D_ego(sum_j a_j W_msg[e_j] v_j), with
    q = Q_ego x_ego, k_j = K_j x_j, v_j = V_j x_j from the projections of each agent's kind and e_j
    the edge's kinds (the ego's, agent j's). ``q``, ``k``, ``v`` are the vehicle projections (named
    as AttFuse's, so its weights load into them); ``*_rsu`` the RSU ones."""

    def __init__(self, channels: int):
        super().__init__()
        self.q, self.k, self.v = (nn.Linear(channels, channels) for _ in range(3))
        self.q_rsu, self.k_rsu, self.v_rsu = (nn.Linear(channels, channels) for _ in range(3))
        eye = torch.eye(channels).repeat(2, 2, 1, 1)  # [ego kind, agent kind]: 0 vehicle, 1 RSU
        self.att_edge = nn.Parameter(eye.clone())
        self.msg_edge = nn.Parameter(eye.clone())
        self.out = nn.Parameter(torch.eye(channels).repeat(2, 1, 1))  # [ego kind]
        self.out_bias = nn.Parameter(torch.zeros(2, channels))
        self.scale = 1.0 / math.sqrt(channels)

    @torch.no_grad()
    def start_from_vehicle(self) -> None:
        """The RSU projections become copies of the vehicle ones (both kinds start as AttFuse's)."""
        for vehicle, rsu in ((self.q, self.q_rsu), (self.k, self.k_rsu), (self.v, self.v_rsu)):
            rsu.load_state_dict(vehicle.state_dict())

    def forward(self, feats: torch.Tensor, mask: torch.Tensor, rsu: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """feats (B, N, C, H, W), mask (B, N) of present agents (the ego, index 0, always), rsu (B, N)
        of the agents that are RSUs → fused ego features (B, C, H, W) and the ego row of attention
        (B, N, H, W)."""
        b, n, c, h, w = feats.shape
        x = feats.permute(0, 1, 3, 4, 2).reshape(b, n, h * w, c)  # (B, N, HW, C)
        ego_rsu = rsu[:, 0]
        q = _kind_linear(self.q, self.q_rsu, x[:, 0], ego_rsu[:, None])  # (B, HW, C)
        k = _kind_linear(self.k, self.k_rsu, x, rsu[:, :, None])  # (B, N, HW, C)
        v = _kind_linear(self.v, self.v_rsu, x, rsu[:, :, None])
        edge = (ego_rsu.long()[:, None].expand(b, n), rsu.long())
        logits = (k * torch.einsum("bnde,bpe->bnpd", self.att_edge[edge], q)).sum(dim=3) * self.scale  # (B, N, HW)
        a = torch.softmax(logits.masked_fill(~mask[:, :, None], float("-inf")), dim=1)
        ctx = (torch.einsum("bnde,bnpe->bnpd", self.msg_edge[edge], v) * a[..., None]).sum(dim=1)  # (B, HW, C)
        kind = ego_rsu.long()
        out = torch.einsum("bde,bpe->bpd", self.out[kind], ctx) + self.out_bias[kind][:, None]
        return out.view(b, h, w, c).permute(0, 3, 1, 2), a.view(b, n, h, w)


class DelayEncoding(nn.Module):
    """V2X-ViT's delay-aware positional encoding: agent i's features plus W p(t_i), where p is the
    transformer's sinusoidal code of its delay t_i in DELAY_STEP_S steps (p_2c = sin(t / 10000^(2c/C)),
    p_2c+1 = cos of the same) and W a learnt C x C projection, broadcast over the BEV cells. W
    starts at zero: the network then computes what it computed without the encoding."""

    def __init__(self, channels: int):
        super().__init__()
        self.proj = nn.Linear(channels, channels)
        nn.init.zeros_(self.proj.weight)
        nn.init.zeros_(self.proj.bias)
        half = torch.arange(0, channels, 2, dtype=torch.float32) / channels
        self.register_buffer("frequency", 1.0 / 10000.0 ** half, persistent=False)

    def code(self, delays_s: torch.Tensor) -> torch.Tensor:
        """delays_s (B, N) → the sinusoidal code (B, N, C)."""
        angle = (delays_s / DELAY_STEP_S)[..., None] * self.frequency  # (B, N, C/2)
        return torch.stack([angle.sin(), angle.cos()], dim=-1).flatten(-2)

    def forward(self, feats: torch.Tensor, delays_s: torch.Tensor) -> torch.Tensor:
        """feats (B, N, C, H, W), delays_s (B, N) → feats with each agent's encoding added."""
        return feats + self.proj(self.code(delays_s))[..., None, None]


def relative_position_index(window: int) -> torch.Tensor:
    """(w*w, w*w) index into a (2w-1)^2 bias table of each pair of a window's cells' offset (Swin's)."""
    ys, xs = torch.meshgrid(torch.arange(window), torch.arange(window), indexing="ij")
    cells = torch.stack([ys.flatten(), xs.flatten()])  # (2, w*w)
    rel = (cells[:, :, None] - cells[:, None, :]) + (window - 1)  # (2, w*w, w*w), each in [0, 2w-2]
    return rel[0] * (2 * window - 1) + rel[1]


class MultiScaleWindowAttention(nn.Module):
    """V2X-ViT's MSwin on a BEV map: per window size, single-head self-attention among the cells of
    each non-overlapping window (the map padded to a whole number of windows; padding is never
    attended to) with a learnt bias per relative offset; the sizes' outputs concatenated, projected
    to C and added to the map (a residual whose projection starts at zero)."""

    def __init__(self, channels: int, windows: tuple[int, ...] = WINDOWS_CELLS):
        super().__init__()
        self.windows = tuple(windows)
        self.norm = nn.LayerNorm(channels)
        self.qkv = nn.Linear(channels, 3 * channels * len(self.windows))
        self.bias = nn.ParameterList(nn.Parameter(torch.zeros((2 * w - 1) ** 2)) for w in self.windows)
        for k, w in enumerate(self.windows):
            self.register_buffer(f"rel_index_{k}", relative_position_index(w), persistent=False)
        self.proj = nn.Linear(channels * len(self.windows), channels)
        nn.init.zeros_(self.proj.weight)
        nn.init.zeros_(self.proj.bias)
        self.scale = 1.0 / math.sqrt(channels)

    def _attend(self, q: torch.Tensor, k: torch.Tensor, v: torch.Tensor, index: int, map_hw: tuple[int, int]) -> torch.Tensor:
        """q, k, v (B, H, W, C) padded to whole numbers of windows from the map's ``map_hw`` cells
        → (B, H, W, C)."""
        win = self.windows[index]
        b, h, w, c = q.shape
        valid = torch.zeros(1, h, w, 1, dtype=q.dtype)
        valid[:, : map_hw[0], : map_hw[1]] = 1.0

        def split(t: torch.Tensor) -> torch.Tensor:  # (B, H, W, C') -> (B * windows, win*win, C')
            t = t.reshape(t.shape[0], h // win, win, w // win, win, t.shape[-1])
            return t.permute(0, 1, 3, 2, 4, 5).reshape(-1, win * win, t.shape[-1])

        bias = self.bias[index][getattr(self, f"rel_index_{index}")]  # (win*win, win*win)
        logits = torch.matmul(split(q), split(k).transpose(1, 2)) * self.scale + bias
        padded = split(valid)[:, None, :, 0] == 0  # (windows, 1, win*win): keys outside the map
        logits = logits.view(b, -1, win * win, win * win).masked_fill(padded[None], float("-inf"))
        out = torch.matmul(torch.softmax(logits, dim=-1).view(-1, win * win, win * win), split(v))
        out = out.view(b, h // win, w // win, win, win, c).permute(0, 1, 3, 2, 4, 5)
        return out.reshape(b, h, w, c)

    def forward(self, fmap: torch.Tensor) -> torch.Tensor:
        """fmap (B, C, H, W) → (B, C, H, W): fmap plus the projected window attention."""
        b, c, h, w = fmap.shape
        qkv_all = self.qkv(self.norm(fmap.permute(0, 2, 3, 1)))  # (B, H, W, 3 C S): every size's q, k, v
        outs = []
        for k, win in enumerate(self.windows):
            ph, pw = -h % win, -w % win
            qkv = F.pad(qkv_all[..., 3 * c * k: 3 * c * (k + 1)], (0, 0, 0, pw, 0, ph))
            q, key, v = qkv.split(c, dim=-1)
            outs.append(self._attend(q, key, v, k, (h, w))[:, :h, :w])
        return fmap + self.proj(torch.cat(outs, dim=-1)).permute(0, 3, 1, 2)


class V2XViTFuse(AttFuse):
    """See the module docstring. Parameters: AttFuse's, the RSU projections and edge matrices of
    :class:`HeteroAttention`, and :class:`MultiScaleWindowAttention` (``window``)."""

    parts_beyond_base = ("fusion.", "window.", "delay.")

    def __init__(self, cfg: DetectorConfig, delay_encoding: bool = False):
        super().__init__(cfg)
        self.window = MultiScaleWindowAttention(self.backbone.stage_channels[0])
        self.delay = DelayEncoding(self.backbone.stage_channels[0]) if delay_encoding else None

    @staticmethod
    def fusion_placement(cfg: DetectorConfig) -> str:
        return "stage1"

    def make_fusion(self, cfg: DetectorConfig) -> nn.Module:
        return HeteroAttention(self.backbone.stage_channels[0])

    @torch.no_grad()
    def start_from_base(self, missing: Collection[str] = ()) -> None:
        """After AttFuse's weights were loaded: both kinds start with AttFuse's projections (the
        edge and dense matrices, the window projection and the delay encoding start as built:
        identities and zero). After V2X-ViT's weights (``missing``: the delay encoding alone), the
        RSU projections are V2X-ViT's and stay."""
        if not missing or any(k.startswith("fusion.") for k in missing):
            self.fusion.start_from_vehicle()

    def forward(self, samples: list[KindedClouds]):
        """``samples[b]``: sample b's clouds, ego first (at most 5 agents), which are RSUs and (read
        with the delay encoding) how old each is."""
        flat, present = self.agents_of([s.clouds for s in samples])
        rsu = torch.zeros_like(present)
        for b, s in enumerate(samples):
            rsu[b, : len(s.rsu)] = torch.tensor(s.rsu, dtype=torch.bool)
        first = self.backbone.first_stage(self.encoder.encode(flat))  # (B*N, C, h, w)
        feats = first.view(*present.shape, *first.shape[1:])
        if self.delay is not None:
            delays_s = torch.zeros(present.shape)  # (B, N): 0 for the current clouds and the padding
            for b, s in enumerate(samples):
                delays_s[b, : len(s.delays_s)] = torch.tensor(s.delays_s, dtype=torch.float32)
            feats = self.delay(feats, delays_s)
        fused, att = self.fusion(feats, present, rsu)
        self.last_attention = att.detach()
        return self.head(self.backbone.after_first_stage(self.window(fused)))


@FUSIONS.register("v2xvit")
class V2XViTDetector(AttFuseDetector):
    """V2X-ViT: attention across agents by kind (vehicle or RSU), then across cells in windows.
    Its attention is its own (ACS-A reads the ego row of HMSA)."""

    weights = "v2xvit"
    feed = KINDED_AGENT_CLOUDS

    @classmethod
    def card_settings(cls, cfg) -> dict:
        return {"mswin_windows_cells": list(WINDOWS_CELLS), "hmsa_heads": 1, "encoder_layers": 1}

    @classmethod
    def new_network(cls, cfg) -> nn.Module:
        return V2XViTFuse(cfg)


@FUSIONS.register("v2xvit-noisy")
class V2XViTNoisyDetector(V2XViTDetector):
    """V2X-ViT with its delay-aware positional encoding, trained on perfect and noisy links (see the
    module docstring); started from the shipped V2X-ViT."""

    weights = "v2xvit-noisy"

    @classmethod
    def card_settings(cls, cfg) -> dict:
        return super().card_settings(cfg) | {"delay_encoding_step_s": DELAY_STEP_S}

    @classmethod
    def new_network(cls, cfg) -> nn.Module:
        return V2XViTFuse(cfg, delay_encoding=True)
