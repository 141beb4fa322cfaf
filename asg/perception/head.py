"""Anchor head and its losses: focal classification, smooth-L1 residuals with the sine yaw
difference, a direction classifier, an IoU branch that predicts how well each box fits and a
refinement branch that corrects each box."""
from __future__ import annotations

import math

import torch
from torch import nn
from torch.nn import functional as F

from .config import DetectorConfig


class AnchorHead(nn.Module):
    """(B, C, H, W) → cls (B, H*W*A), box (B, H*W*A, 7), dir (B, H*W*A, 2) in anchor order, and
    the features (B, C, H, W), detached, for the IoU branch.

    The IoU branch (an MLP over the ``cfg.iou_patch`` x ``cfg.iou_patch`` cells around an anchor's
    cell, ``cfg.iou_hidden`` units) predicts the BEV IoU of the anchor's decoded box with the
    vehicle it covers. It runs only on the anchors asked for (:meth:`iou_logits`: the few hundred
    candidates inference keeps), and reads the features detached, so its loss never changes the
    detector: it learns to tell well-fitted boxes from loose ones, and ``cfg.iou_rescore`` mixes it
    into the score (IoU-aware rescoring, see :func:`rescore`). The refinement branch (the same
    input and shape) predicts the residuals (SECOND encoding, :func:`..boxes.refinement_residuals`)
    from the anchor's decoded box to that vehicle's box: ``cfg.box_refine`` applies them.
    """

    def __init__(self, cfg: DetectorConfig, channels: int):
        super().__init__()
        a = cfg.anchors_per_cell
        self.a = a
        self.patch = cfg.iou_patch
        self.cls = nn.Conv2d(channels, a, 1)
        self.box = nn.Conv2d(channels, a * 7, 1)
        self.dir = nn.Conv2d(channels, a * 2, 1)
        self.iou = nn.Sequential(nn.Linear(channels * self.patch ** 2, cfg.iou_hidden), nn.ReLU(),
                                 nn.Linear(cfg.iou_hidden, a))
        self.refine = nn.Sequential(nn.Linear(channels * self.patch ** 2, cfg.iou_hidden), nn.ReLU(),
                                    nn.Linear(cfg.iou_hidden, a * 7))
        nn.init.constant_(self.cls.bias, -math.log((1 - 0.01) / 0.01))

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        b = x.shape[0]
        cls = self.cls(x).permute(0, 2, 3, 1).reshape(b, -1)
        box = self.box(x).permute(0, 2, 3, 1).reshape(b, -1, 7)
        d = self.dir(x).permute(0, 2, 3, 1).reshape(b, -1, 2)
        return cls, box, d, x.detach()

    def branches(self, features: torch.Tensor, anchor_idx: torch.Tensor,
                 refine: bool = True) -> tuple[torch.Tensor, torch.Tensor | None]:
        """IoU logits (K,) and refinement residuals (K, 7) (None unless ``refine``) of anchors
        ``anchor_idx`` (K,) (indices in anchor order) of one sample whose head features are
        ``features`` (C, H, W); cells beyond the grid's edge repeat it."""
        patch = patch_features(features, anchor_idx // self.a, self.patch)
        slot = anchor_idx % self.a
        return self.iou_of_patches(patch, slot), (self.refine_of_patches(patch, slot) if refine else None)

    def iou_of_patches(self, patch: torch.Tensor, slot: torch.Tensor) -> torch.Tensor:
        """IoU logits (K,) from the candidates' patch features (K, C * patch^2) and anchor slots (K,)."""
        return self.iou(patch).gather(1, slot[:, None])[:, 0]

    def refine_of_patches(self, patch: torch.Tensor, slot: torch.Tensor) -> torch.Tensor:
        """Refinement residuals (K, 7), in box units (REFINE_SCALE applied), from the candidates'
        patch features (K, C * patch^2) and anchor slots (K,)."""
        return self.refine(patch).view(len(slot), self.a, 7)[torch.arange(len(slot)), slot] * REFINE_SCALE

    def iou_logits(self, features: torch.Tensor, anchor_idx: torch.Tensor) -> torch.Tensor:
        """IoU logits (K,) alone (see :meth:`branches`)."""
        return self.branches(features, anchor_idx, refine=False)[0]


def patch_features(features: torch.Tensor, cell_idx: torch.Tensor, patch: int) -> torch.Tensor:
    """The feature vectors of the ``patch`` x ``patch`` cells around each cell ``cell_idx`` (K,)
    (row-major in the (H, W) grid of ``features`` (C, H, W)), concatenated row by row: (K, C *
    patch^2); cells beyond the grid's edge repeat it."""
    c, h, w = features.shape
    cy, cx = cell_idx // w, cell_idx % w
    r = patch // 2
    cells = torch.stack([(cy + dy).clamp(0, h - 1) * w + (cx + dx).clamp(0, w - 1)
                         for dy in range(-r, r + 1) for dx in range(-r, r + 1)], dim=1)  # (K, patch^2)
    # one copy of whole rows from the cell-major map (a view of the channels-last features)
    rows = features.permute(1, 2, 0).reshape(h * w, c).index_select(0, cells.reshape(-1))
    return rows.view(len(cell_idx), patch * patch * c)


def rescore(cls_prob: torch.Tensor, iou_logit: torch.Tensor, power: float) -> torch.Tensor:
    """IoU-aware score: cls_prob ** (1 - power) * predicted_iou ** power (power 0: the class score)."""
    if power <= 0:
        return cls_prob
    return cls_prob ** (1 - power) * torch.sigmoid(iou_logit) ** power


def iou_loss(iou_logit: torch.Tensor, target_iou: torch.Tensor) -> torch.Tensor:
    """Binary cross-entropy of the IoU branch against soft targets in [0, 1], mean over the anchors
    given (K,) → scalar; 0 when there are none."""
    if not len(target_iou):
        return iou_logit.sum() * 0.0
    return F.binary_cross_entropy_with_logits(iou_logit, target_iou)


#: typical size of each refinement residual (x, y, z, l, w, h, yaw; the std over detector-train's
#: candidates with IoU >= 0.3 under the AttFuse weights): the branch predicts residuals in these
#: units, and its loss weighs the seven alike
REFINE_SCALE = torch.tensor([0.11, 0.10, 0.10, 0.2, 0.075, 0.16, 0.13])


def refine_loss(residuals: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Smooth-L1 (beta 0.5, in units of REFINE_SCALE) of predicted residuals (K, 7) against their
    targets (K, 7), mean over anchors and the seven → scalar; 0 when there are none."""
    if not len(target):
        return residuals.sum() * 0.0
    return F.smooth_l1_loss(residuals / REFINE_SCALE, target / REFINE_SCALE, beta=0.5)


def focal_loss(logits: torch.Tensor, labels: torch.Tensor, alpha: float = 0.25, gamma: float = 2.0) -> torch.Tensor:
    """Sum of the sigmoid focal loss over anchors with label >= 0 (1 positive, 0 negative)."""
    valid = labels >= 0
    t = (labels == 1).float()
    p = torch.sigmoid(logits)
    ce = F.binary_cross_entropy_with_logits(logits, t, reduction="none")
    pt = p * t + (1 - p) * (1 - t)
    w = (alpha * t + (1 - alpha) * (1 - t)) * (1 - pt) ** gamma
    return (w * ce * valid).sum()


def bev_corners(boxes: torch.Tensor) -> torch.Tensor:
    """The four BEV corners (K, 4, 2) of boxes (K, 7) (x, y, z, l, w, h, yaw; metres, radians), in
    the boxes' frame, counter-clockwise from the front left."""
    half_l, half_w = boxes[:, 3] / 2, boxes[:, 4] / 2
    local = torch.stack([torch.stack([half_l, half_w], -1), torch.stack([-half_l, half_w], -1),
                         torch.stack([-half_l, -half_w], -1), torch.stack([half_l, -half_w], -1)], dim=1)
    c, s = torch.cos(boxes[:, 6])[:, None], torch.sin(boxes[:, 6])[:, None]
    return torch.stack([boxes[:, None, 0] + c * local[..., 0] - s * local[..., 1],
                        boxes[:, None, 1] + s * local[..., 0] + c * local[..., 1]], dim=-1)


def corner_loss(residuals: torch.Tensor, targets: torch.Tensor, anchors: torch.Tensor) -> torch.Tensor:
    """Orientation-aware box loss: the smooth-L1 distance (beta 0.1 m) between the BEV corners of
    the decoded predictions and of the targets, summed over the four corners, per box (K,), taking
    the nearer of the target and the target turned by pi (a box's IoU does not see its heading;
    the direction classifier does). ``residuals``, ``targets``: (K, 7) SECOND residuals against
    ``anchors`` (K, 7). Unlike the per-coordinate residual loss it weighs an error by what it does
    to the box's outline: a yaw error costs more on a long box, a centre error the same anywhere."""
    from .boxes import decode

    pred = bev_corners(decode(residuals, anchors))
    target = bev_corners(decode(targets, anchors))
    turned = target.roll(2, dims=1)  # the same outline, corners named from the back
    per_box = [F.smooth_l1_loss(pred, t, beta=0.1, reduction="none").sum(dim=(1, 2)) for t in (target, turned)]
    return torch.minimum(*per_box)


def detection_loss(cls: torch.Tensor, box: torch.Tensor, d: torch.Tensor, labels: torch.Tensor,
                   targets: torch.Tensor, dirs: torch.Tensor, anchors: torch.Tensor | None = None,
                   corner_weight: float = 0.0) -> dict[str, torch.Tensor]:
    """Losses normalised by the number of positives: cls x1.0, box x2.0, direction x0.2 and, with
    ``corner_weight`` > 0 (and ``anchors`` (A, 7)), the corner loss (:func:`corner_loss`) x corner_weight."""
    if corner_weight > 0 and anchors is None:
        raise ValueError("the corner loss needs the anchors")
    pos = labels == 1
    n_pos = pos.sum().clamp(min=1).float()
    l_cls = focal_loss(cls, labels) / n_pos
    if pos.any():
        p, t = box[pos], targets[pos]
        # sine of the yaw difference: replace yaw by sin(p)cos(t) and cos(p)sin(t)
        p_enc = torch.cat([p[:, :6], (torch.sin(p[:, 6]) * torch.cos(t[:, 6]))[:, None]], dim=1)
        t_enc = torch.cat([t[:, :6], (torch.cos(p[:, 6]) * torch.sin(t[:, 6]))[:, None]], dim=1)
        l_box = F.smooth_l1_loss(p_enc, t_enc, beta=1 / 9, reduction="sum") / n_pos
        l_dir = F.cross_entropy(d[pos], dirs[pos], reduction="sum") / n_pos
        if corner_weight > 0:
            l_corner = corner_loss(p, t, anchors.expand(box.shape[0], -1, -1)[pos]).sum() / n_pos
    else:
        l_box = box.sum() * 0.0
        l_dir = d.sum() * 0.0
        l_corner = box.sum() * 0.0
    total = l_cls + 2.0 * l_box + 0.2 * l_dir
    out = {"cls": l_cls, "box": l_box, "dir": l_dir}
    if corner_weight > 0:
        total = total + corner_weight * l_corner
        out["corner"] = l_corner
    return {"total": total, **out}
