"""How each network is trained: the examples a frame gives it and how a batch of them enters its
forward pass. A shipped detector declares its feed (``V2XDetector.feed``); training, fine-tuning,
hardening and the branch fit read it and never ask which model they have.

An example is ``(clouds, boxes)``: the clouds the detecting agent's network is given, each (N, 4)
float32 x, y, z, intensity in that agent's sensor frame, and its labels, boxes (M, 7) x, y, z, l,
w, h, yaw in the same frame (metres, radians).
"""
from __future__ import annotations

from typing import Sequence

import numpy as np
import torch

from .data import Sample

Example = tuple[list[np.ndarray], np.ndarray]


class Feed:
    """One cloud per example, the network called on a list of them (PointPillars' forward)."""

    #: the name model cards and logs use
    name: str = ""

    def examples(self, sample: Sample, views: str = "ego") -> list[Example]:
        """The training examples of one frame; ``views``: "ego" (the frame as its ego sees it) or
        "all" (each sensing agent's view in turn), for feeds that fuse agents."""
        raise NotImplementedError

    def network_input(self, clouds: Sequence[Sequence[torch.Tensor]]) -> list:
        """A batch's clouds (per example, the list of its clouds' tensors) as the network takes them."""
        return [c[0] for c in clouds]


class OwnCloud(Feed):
    """Each sensing agent's own cloud in its own frame, labelled with the vehicles in range that
    hold at least one of its points (a collaborator sees the ego vehicle too); ``views`` does not
    apply (every agent is an example already)."""

    name = "own-cloud"

    def examples(self, sample: Sample, views: str = "ego") -> list[Example]:
        return [([cloud], boxes) for cloud, boxes in sample.own_views()]


class FusedCloud(Feed):
    """Every sensing agent's cloud moved to the detecting agent's frame and stacked into one,
    labelled with the vehicles in range that hold a fused point."""

    name = "fused-cloud"

    def examples(self, sample: Sample, views: str = "ego") -> list[Example]:
        return [([np.vstack(clouds)], boxes) for clouds, boxes in sample.fused_views(views)]


class AgentClouds(Feed):
    """Every sensing agent's cloud moved to the detecting agent's frame, kept apart (its own
    first), labelled as :class:`FusedCloud`; the network takes each example's list of clouds."""

    name = "agent-clouds"

    def examples(self, sample: Sample, views: str = "ego") -> list[Example]:
        return sample.fused_views(views)

    def network_input(self, clouds: Sequence[Sequence[torch.Tensor]]) -> list:
        return [list(c) for c in clouds]


OWN_CLOUD, FUSED_CLOUD, AGENT_CLOUDS = OwnCloud(), FusedCloud(), AgentClouds()
