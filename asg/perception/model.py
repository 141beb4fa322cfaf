"""Detectors: a single-pass PointPillars (No / Late / Early fusion use it) and AttFuse.

Inputs are clouds (N, 4) float32 in the frame the boxes come out in. Both networks return the
head's (cls, box, dir, features) tensors; ``postprocess`` turns them into numpy boxes (K, 7) and scores
(K,) after the score threshold, IoU-aware rescoring, rotated NMS and box voting.
"""
from __future__ import annotations

import math
from typing import Collection

import numpy as np
import torch
from torch import nn

from .backbone import Backbone
from .boxes import decode_with_direction, make_anchors, top_candidates
from .branch_boxes import refine_boxes
from .nms import select_boxes
from .config import DetectorConfig
from .head import AnchorHead, rescore
from .pillars import PillarEncoder


class PointPillars(nn.Module):
    """Pillars → backbone → anchor head, one cloud per sample."""

    #: parameter name prefixes a network adds to PointPillars: what a start from PointPillars
    #: weights (``asg train --init-from single``) may lack, and :meth:`start_from_base` sets
    parts_beyond_base: tuple[str, ...] = ()

    def __init__(self, cfg: DetectorConfig):
        super().__init__()
        self.cfg = cfg
        self.encoder = PillarEncoder(cfg)
        self.backbone = Backbone(cfg)
        self.head = AnchorHead(cfg, self.backbone.out_channels)
        self.register_buffer("anchors", torch.from_numpy(make_anchors(cfg)).float(), persistent=False)

    def features(self, clouds: list[torch.Tensor]) -> torch.Tensor:
        return self.backbone.after_first_stage(self.backbone.first_stage(self.encoder.encode(clouds)))

    def forward(self, clouds: list[torch.Tensor]):
        return self.head(self.features(clouds))

    def start_from_base(self, missing: Collection[str] = ()) -> None:
        """After PointPillars weights were loaded (``missing``: the tensors they lacked): nothing
        more to set."""


class ScaledDotAttention(nn.Module):
    """Per BEV cell, attention across agents: a = softmax(q k^T / sqrt(C)), out = a v, with linear
    q, k, v projections of each agent's feature vector (the ego's row only).

    Computed without projecting every agent: q . k_j = (W_k^T q) . x_j + q . b_k, and the second
    term is the same for every j, so softmax ignores it; sum_j a_j v_j = W_v (sum_j a_j x_j) + b_v
    because the ego row sums to 1. Same function, about half the multiply-adds of the direct form,
    and everything stays channel-first (no permutes of the BEV tensors).
    """

    def __init__(self, channels: int):
        super().__init__()
        self.q = nn.Linear(channels, channels)
        self.k = nn.Linear(channels, channels)
        self.v = nn.Linear(channels, channels)
        self.scale = 1.0 / math.sqrt(channels)

    def forward(self, feats: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """feats (B, N, C, H, W), mask (B, N) of present agents (the ego, index 0, always), or
        (B, N, H*W) of the cells each agent contributes (Where2comm's; the ego's all) → fused ego
        features (B, C, H, W) (channels-last memory) and the ego row of attention (B, N, H, W).
        Works cell-major: with channels-last ``feats`` (what the backbone gives) no copy is made."""
        b, n, c, h, w = feats.shape
        x = feats.permute(0, 1, 3, 4, 2).reshape(b, n, h * w, c)  # (B, N, HW, C)
        q = torch.addmm(self.q.bias, x[:, 0].reshape(-1, c), self.q.weight.t())  # (B*HW, C)
        qk = torch.matmul(q, self.k.weight).view(b, 1, h * w, c)  # rows: W_k^T q
        logits = (x * qk).sum(dim=3) * self.scale  # (B, N, HW)
        logits = logits.masked_fill(~(mask if mask.dim() == 3 else mask[:, :, None]), float("-inf"))
        a = torch.softmax(logits, dim=1)
        ctx = (x * a[..., None]).sum(dim=1)  # (B, HW, C)
        out = torch.addmm(self.v.bias, ctx.view(-1, c), self.v.weight.t())  # (B*HW, C)
        return out.view(b, h, w, c).permute(0, 3, 1, 2), a.view(b, n, h, w)


class AttFuse(nn.Module):
    """Each agent's cloud (already in the ego frame) → shared pillars (+ backbone) → per-cell
    attention across agents → the ego's fused features → (rest of the backbone →) anchor head.

    ``cfg.attfuse_fusion`` places the fusion: "output" fuses the backbone's upsampled output
    (``fusion`` is one attention); "stages" fuses each stage before its upsampling block
    (``fusion`` holds one attention per stage); "stage1" fuses the first stage's output and runs
    the later stages and the upsampling on the fused map; "pillars" fuses the pillar canvases and
    runs the backbone once. ``last_attention`` (B, N, h, w): the ego row at the fusion's resolution
    (n/2 for output, stages (its first) and stage1; n for pillars), row = y, column = x.
    """

    def __init__(self, cfg: DetectorConfig):
        super().__init__()
        self.cfg = cfg
        self.placement = self.fusion_placement(cfg)
        self.encoder = PillarEncoder(cfg)
        self.backbone = Backbone(cfg)
        self.fusion = self.make_fusion(cfg)
        self.head = AnchorHead(cfg, self.backbone.out_channels)
        self.register_buffer("anchors", torch.from_numpy(make_anchors(cfg)).float(), persistent=False)
        self.last_attention: torch.Tensor | None = None

    parts_beyond_base = ("fusion.",)

    @staticmethod
    def fusion_placement(cfg: DetectorConfig) -> str:
        """Where the agents are fused (see the class docstring)."""
        return cfg.attfuse_fusion

    def make_fusion(self, cfg: DetectorConfig) -> nn.Module:
        """The module fusing the agents at ``self.placement`` (``self.backbone`` built): one
        attention, or one per stage for "stages"."""
        if self.placement == "stages":
            return nn.ModuleList(ScaledDotAttention(c) for c in self.backbone.stage_channels)
        channels = {"output": self.backbone.out_channels, "stage1": self.backbone.stage_channels[0],
                    "pillars": cfg.pfn_channels}[self.placement]
        return ScaledDotAttention(channels)

    def attentions(self) -> list[ScaledDotAttention]:
        return list(self.fusion) if isinstance(self.fusion, nn.ModuleList) else [self.fusion]

    @torch.no_grad()
    def start_from_base(self, missing: Collection[str] = ()) -> None:
        """After PointPillars weights were loaded: the attention starts as (nearly) a plain average
        of the agents' features: v = identity, k scaled by 0.1 so the first attention is close to
        uniform while q and k still get gradients."""
        for att in self.attentions():
            att.v.weight.copy_(torch.eye(att.v.weight.shape[0]))
            att.v.bias.zero_()
            att.k.weight.mul_(0.1)

    @staticmethod
    def agents_of(agent_clouds: list[list[torch.Tensor]]) -> tuple[list[torch.Tensor], torch.Tensor]:
        """The batch's clouds flat, B x N (sample by sample, ego first; an absent agent an empty
        cloud), and the mask (B, N) of the agents present."""
        n = max(len(c) for c in agent_clouds)
        flat, mask = [], torch.zeros(len(agent_clouds), n, dtype=torch.bool)
        empty = torch.zeros(0, 4)
        for b, clouds in enumerate(agent_clouds):
            for j in range(n):
                flat.append(clouds[j] if j < len(clouds) else empty)
                mask[b, j] = j < len(clouds)
        return flat, mask

    def forward(self, agent_clouds: list[list[torch.Tensor]]):
        """``agent_clouds[b]`` lists sample b's clouds, ego first (at most 5 agents)."""
        fused, att = self._fused(agent_clouds)
        self.last_attention = None if att is None else att.detach()
        return self.head(fused)

    def ego_attention(self, agent_clouds: list) -> torch.Tensor | None:
        """What :meth:`forward` leaves in ``last_attention`` (B, N, h, w), the same values, computed
        only as far as the fusion that makes it: the layers after it and the head do not run. A
        subclass with a forward pass of its own (V2X-ViT, Where2comm) runs that pass whole."""
        if type(self).forward is not AttFuse.forward:
            self(agent_clouds)
            return self.last_attention
        return self._fused(agent_clouds, attention_only=True)[1]

    def _fused(self, agent_clouds: list[list[torch.Tensor]],
               attention_only: bool = False) -> tuple[torch.Tensor | None, torch.Tensor | None]:
        """The ego's fused features (B, C, n/2, n/2) for the head (None with ``attention_only``)
        and the fusion's ego-row attention (B, N, h, w) (None for a fusion without one)."""
        flat, mask = self.agents_of(agent_clouds)
        pillars = self.encoder.encode(flat)
        per_sample = lambda f: f.view(*mask.shape, *f.shape[1:])
        backbone = self.backbone
        if self.placement == "pillars":
            canvas, att = self.fusion(per_sample(pillars.canvas()), mask)
            return (None if attention_only else backbone(canvas)), att
        first = backbone.first_stage(pillars)
        if self.placement == "stages":
            if attention_only:  # the first stage's attention is the one kept
                return None, self.fusion[0](per_sample(first), mask)[1]
            fused_stages, atts = [], []
            for att_module, f in zip(self.fusion, [first] + backbone.stage_outputs(first, start=1)):
                fused, att = att_module(per_sample(f), mask)
                fused_stages.append(fused)
                atts.append(att)
            return backbone.upsample(fused_stages), atts[0]
        if self.placement == "stage1":
            first, att = self.fusion(per_sample(first), mask)
            return (None if attention_only else backbone.after_first_stage(first)), att
        return self.fusion(per_sample(backbone.after_first_stage(first)), mask)


class MaxOverAgents(nn.Module):
    """F-Cooper's maxout fusion: per BEV cell and channel, the largest feature of the agents present.
    No parameters, no attention."""

    def forward(self, feats: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, None]:
        """feats (B, N, C, H, W), mask (B, N) of present agents → fused features (B, C, H, W), None."""
        absent = ~mask[:, :, None, None, None]
        return feats.masked_fill(absent, float("-inf")).amax(dim=1), None


class MaxFuse(AttFuse):
    """F-Cooper (Chen et al., 2019) on our PointPillars: each agent's cloud (in the ego frame) through
    the shared pillar net and first backbone stage, the agents' feature maps fused by maxout
    (:class:`MaxOverAgents`, F-Cooper's spatial-feature fusion), the rest of the backbone and the
    head on the fused map. Where AttFuse places its attention (``stage1``), so the two differ only
    in how they fuse. No parameters beyond PointPillars': it starts from ``single`` as it is.
    ``last_attention`` stays None."""

    parts_beyond_base = ()

    @staticmethod
    def fusion_placement(cfg: DetectorConfig) -> str:
        return "stage1"

    def make_fusion(self, cfg: DetectorConfig) -> nn.Module:
        return MaxOverAgents()

    def attentions(self) -> list:
        return []  # so start_from_base has nothing to set


@torch.no_grad()
def postprocess(outputs: tuple[torch.Tensor, ...], model: PointPillars | AttFuse, cfg: DetectorConfig,
                top_k: int = 300) -> list[tuple[np.ndarray, np.ndarray]]:
    """``outputs``: what ``model`` returned (cls, box, dir, features). Per sample: (boxes (K, 7),
    scores (K,)) of the anchors whose class score passes the score threshold (at most ``top_k``),
    their boxes corrected by the refinement branch (``cfg.box_refine``), rescored with the
    predicted IoU (``cfg.iou_rescore``), after rotated NMS and box voting (both in the order of the
    rescored scores)."""
    cls, box, d, features = outputs
    out = []
    for b in range(cls.shape[0]):
        scores = torch.sigmoid(cls[b])
        keep = top_candidates(scores, cfg.score_threshold, top_k)
        if not len(keep):
            out.append((np.zeros((0, 7)), np.zeros(0)))
            continue
        bx = decode_with_direction(box[b, keep], d[b, keep], model.anchors[keep])
        sc = scores[keep]
        if cfg.iou_rescore > 0 or cfg.box_refine:
            iou_logit, residuals = model.head.branches(features[b], keep, refine=cfg.box_refine)
            if cfg.box_refine:
                bx = refine_boxes(bx, residuals)
            if cfg.iou_rescore > 0:
                sc = rescore(sc, iou_logit, cfg.iou_rescore)
        out.append(select_boxes(bx, sc.numpy().astype(np.float64), cfg))
    return out
