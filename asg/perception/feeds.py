"""How each network is trained: the examples a frame gives it and how a batch of them enters its
forward pass. A shipped detector declares its feed (``V2XDetector.feed``); training, fine-tuning,
hardening and the branch fit read it and never ask which model they have.

An example (:class:`Example`) is the clouds the detecting agent's network is given, each (N, 4)
float32 x, y, z, intensity in that agent's sensor frame, its labels, boxes (M, 7) x, y, z, l, w, h,
yaw in the same frame (metres, radians), and, for the feeds that need them, the kind of each
cloud's agent and the cloud's age (its message's delay).
"""
from __future__ import annotations

from typing import NamedTuple, Sequence

import numpy as np
import torch

from ..scene.views import Views
from .data import Sample


class Example(NamedTuple):
    clouds: list[np.ndarray]
    boxes: np.ndarray
    #: the kind ("vehicle" or "rsu") of each cloud's agent, in the clouds' order; empty for the
    #: feeds whose networks do not read it
    kinds: tuple[str, ...] = ()
    #: the age of each cloud (s: how long before the labels' instant it was captured), in the
    #: clouds' order; empty for the feeds whose networks do not read it
    delays_s: tuple[float, ...] = ()


class KindedClouds(NamedTuple):
    """One sample as V2X-ViT's network takes it: every agent's cloud tensor (N_i, 4) in the
    detecting agent's frame (its own first) and, per cloud, whether its agent is an RSU and how old
    the cloud is (s; empty: all current)."""

    clouds: list[torch.Tensor]
    rsu: tuple[bool, ...]
    delays_s: tuple[float, ...] = ()


class Feed:
    """One cloud per example, the network called on a list of them (PointPillars' forward)."""

    #: the name model cards and logs use
    name: str = ""

    def examples(self, sample: Sample, views: Views = Views.EGO) -> list[Example]:
        """The training examples of one frame; ``views``: ``Views.EGO`` (the frame as its ego sees
        it) or ``Views.ALL`` (each sensing agent's view in turn), for feeds that fuse agents."""
        raise NotImplementedError

    def network_input(self, clouds: Sequence[Sequence[torch.Tensor]], kinds: Sequence[Sequence[str]] = (),
                      delays_s: Sequence[Sequence[float]] = ()) -> list:
        """A batch's clouds (per example, the list of its clouds' tensors; ``kinds`` and ``delays_s``:
        per example, its :attr:`Example.kinds` and :attr:`Example.delays_s`) as the network takes them."""
        return [c[0] for c in clouds]


class OwnCloud(Feed):
    """Each sensing agent's own cloud in its own frame, labelled with the vehicles in range that
    hold at least one of its points (a collaborator sees the ego vehicle too); ``views`` does not
    apply (every agent is an example already)."""

    name = "own-cloud"

    def examples(self, sample: Sample, views: Views = Views.EGO) -> list[Example]:
        return [Example([cloud], boxes) for cloud, boxes in sample.own_views()]


class FusedCloud(Feed):
    """Every sensing agent's cloud moved to the detecting agent's frame and stacked into one,
    labelled with the vehicles in range that hold a fused point."""

    name = "fused-cloud"

    def examples(self, sample: Sample, views: Views = Views.EGO) -> list[Example]:
        return [Example([np.vstack(clouds)], boxes) for clouds, boxes in sample.fused_views(views)]


class AgentClouds(Feed):
    """Every sensing agent's cloud moved to the detecting agent's frame, kept apart (its own
    first), labelled as :class:`FusedCloud`; the network takes each example's list of clouds."""

    name = "agent-clouds"

    def examples(self, sample: Sample, views: Views = Views.EGO) -> list[Example]:
        return [Example(clouds, boxes) for clouds, boxes in sample.fused_views(views)]

    def network_input(self, clouds: Sequence[Sequence[torch.Tensor]], kinds: Sequence[Sequence[str]] = (),
                      delays_s: Sequence[Sequence[float]] = ()) -> list:
        return [list(c) for c in clouds]


class KindedAgentClouds(AgentClouds):
    """:class:`AgentClouds` with each cloud's agent kind (vehicle or RSU) and age, for the networks
    that treat the kinds apart and read the delay (V2X-ViT); the network takes a
    :class:`KindedClouds` per example."""

    name = "kinded-agent-clouds"

    def examples(self, sample: Sample, views: Views = Views.EGO) -> list[Example]:
        frame = sample.frame
        return [Example(clouds, boxes, frame.kinds_in_frame_of(a), frame.delays_in_frame_of(a))
                for a, (clouds, boxes) in zip(sample.detecting_agents(views), sample.fused_views(views))]

    def network_input(self, clouds: Sequence[Sequence[torch.Tensor]], kinds: Sequence[Sequence[str]] = (),
                      delays_s: Sequence[Sequence[float]] = ()) -> list:
        delays_s = delays_s or [()] * len(clouds)  # none given: every cloud current
        if len(kinds) != len(clouds) or len(delays_s) != len(clouds):
            raise ValueError(f"{self.name}: {len(clouds)} examples but {len(kinds)} lists of agent kinds "
                             f"and {len(delays_s)} of delays")
        return [KindedClouds(list(c), tuple(k == "rsu" for k in ks), tuple(float(d) for d in ds))
                for c, ks, ds in zip(clouds, kinds, delays_s)]


OWN_CLOUD, FUSED_CLOUD, AGENT_CLOUDS, KINDED_AGENT_CLOUDS = OwnCloud(), FusedCloud(), AgentClouds(), KindedAgentClouds()
