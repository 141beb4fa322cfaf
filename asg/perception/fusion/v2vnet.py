"""V2VNet (Wang et al., ECCV 2020) on our PointPillars: each agent's points in the ego frame through
the shared pillar net and first backbone stage, then rounds of message passing between the agents
on those feature maps, and the rest of the backbone and the head on the ego's updated map. No
attention: ACS-A borrows the shipped AttFuse's.

A round, for every agent i (all maps already in the ego frame, so no warping):
  m_ij = conv3x3([h_j, h_i])          the message from agent j (OpenCOOD's ``msg_cnn``)
  a_i  = mean of m_ij over the agents j present (i itself included, as OpenCOOD's V2VNet does)
  h_i  = ConvGRU(input a_i, hidden h_i)   (the paper's update; OpenCOOD's starts the GRU from zero
                                           state every round, with [h_i, a_i] as its input)
then the ego's map through a 1x1 convolution (OpenCOOD's final ``mlp``). The message is linear in
[h_j, h_i], so m_ij = W_j * h_j + W_i * h_i + b and the mean is mean_j(W_j * h_j) + W_i * h_i + b:
two convolutions an agent instead of one a pair, the same function.
"""
from __future__ import annotations

from typing import Collection

import torch
import torch.nn.functional as F
from torch import nn

from ..model import AttFuse
from .base import FUSIONS, AgentCloudsDetector


class ConvGRUCell(nn.Module):
    """A convolutional GRU cell (3x3 gates), OpenCOOD's ``ConvGRUCell``: input (B, C, H, W), hidden
    (B, C, H, W) -> the next hidden (B, C, H, W)."""

    def __init__(self, channels: int):
        super().__init__()
        self.gates = nn.Conv2d(2 * channels, 2 * channels, 3, padding=1)
        self.candidate = nn.Conv2d(2 * channels, channels, 3, padding=1)

    def forward(self, x: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
        if not torch.is_grad_enabled():
            return self._step_in_place(x, h)
        reset, update = torch.sigmoid(self.gates(torch.cat([x, h], dim=1))).chunk(2, dim=1)
        candidate = torch.tanh(self.candidate(torch.cat([x, reset * h], dim=1)))
        return (1 - update) * h + update * candidate

    def _step_in_place(self, x: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
        """:meth:`forward` at inference: the same operations on the same values (1 - u is -u + 1
        exactly; products and sums commute), written into the tensors the step makes instead of a
        new tensor for each: the candidate's input [x, reset * h] is the gates' input [x, h] with
        its h half multiplied by the reset gate in place (one concatenation a step, not two)."""
        xh = torch.cat([x, h], dim=1)
        reset, update = self.gates(xh).sigmoid_().chunk(2, dim=1)
        xh[:, x.shape[1]:].mul_(reset)
        candidate = self.candidate(xh).tanh_()
        return update.neg().add_(1).mul_(h).add_(candidate.mul_(update))


class MessagePassing(nn.Module):
    """V2VNet's fusion (module docstring): ``rounds`` of messages and GRU updates over the agents
    present, then the ego's map through a 1x1 convolution. No attention."""

    def __init__(self, channels: int, rounds: int = 2):
        super().__init__()
        self.rounds = rounds
        self.message = nn.Conv2d(2 * channels, channels, 3, padding=1)
        self.gru = ConvGRUCell(channels)
        self.out = nn.Conv2d(channels, channels, 1)

    def messages(self, h: torch.Tensor, mask: torch.Tensor, receivers: int | None = None) -> torch.Tensor:
        """h (B, N, C, H, W), mask (B, N) of present agents -> a_i (B, R, C, H, W) of the first R =
        ``receivers`` agents (all N if None): the mean over the present agents j of the message
        conv3x3([h_j, h_i])."""
        b, n, c, height, width = h.shape
        r = n if receivers is None else receivers
        w_from, w_to = (_maps(w) for w in (self.message.weight[:, :c], self.message.weight[:, c:]))
        sent = F.conv2d(_maps(h.reshape(b * n, c, height, width)), w_from, padding=1).view(b, n, c, height, width)
        received = F.conv2d(_maps(h[:, :r].reshape(b * r, c, height, width)), w_to, self.message.bias,
                            padding=1).view(b, r, c, height, width)
        present = mask.to(h.dtype)[:, :, None, None, None]
        weighted = sent if bool(mask.all()) else sent * present  # every agent present: x * 1 is x
        mean_sent = _sum_over_agents(weighted) / present.sum(dim=1, keepdim=True)
        return mean_sent + received if torch.is_grad_enabled() else received.add_(mean_sent)

    def forward(self, feats: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, None]:
        """feats (B, N, C, H, W), mask (B, N) of present agents (the ego, index 0, always) -> the
        ego's fused features (B, C, H, W), None (no attention). Only the ego's map is read after
        the last round, so that round updates the ego alone (the same maps, a third of the work)."""
        b, n, c, height, width = feats.shape
        h = feats
        for k in range(self.rounds):
            r = 1 if k == self.rounds - 1 else n
            a = self.messages(h, mask, r)
            h = self.gru(_maps(a.reshape(b * r, c, height, width)),
                         _maps(h[:, :r].reshape(b * r, c, height, width))).view(b, r, c, height, width)
        return self.out(h[:, 0]), None


def _sum_over_agents(x: torch.Tensor) -> torch.Tensor:
    """x (B, N, C, H, W) -> (B, 1, C, H, W): ((x_0 + x_1) + x_2) + ..., the order in which torch's sum
    over dim 1 adds them (the same bits), in the layout of x's maps. torch's sum over the agents of
    channels-last maps, and the sum's layout in the add after it, took 1.4 ms each a round for three
    agents at 96 x 96 cells; these adds 0.05 ms."""
    total = x[:, 0].clone()
    for j in range(1, x.shape[1]):
        total = total + x[:, j] if torch.is_grad_enabled() else total.add_(x[:, j])
    return total.unsqueeze(1)


def _maps(x: torch.Tensor) -> torch.Tensor:
    """``x`` (B, C, H, W) channels-last in memory, the detector's layout (its weights' too): a
    convolution then needs no reorder of its input, and gives the same values. A single map cut
    from a batch (B = 1, its batch stride that of the batch) is given the batch stride C x H x W, a
    view of the same memory: torch.cat laid out such maps channel-first, and each convolution after
    it then reordered its input (1-1.5 ms a GRU convolution at 96 x 96 cells)."""
    x = x.contiguous(memory_format=torch.channels_last)
    if x.shape[0] == 1 and x.stride(0) != x.numel():
        _, c, _, width = x.shape
        x = x.as_strided(x.shape, (x.numel(), 1, width * c, c))
    return x


class V2VNet(AttFuse):
    """V2VNet's message passing at AttFuse's place (after the first backbone stage), so that the two
    differ only in how they fuse; starts from AttFuse's or the single model's weights (its
    ``fusion.`` parameters fresh)."""

    parts_beyond_base = ("fusion.",)

    @staticmethod
    def fusion_placement(cfg) -> str:
        return "stage1"

    def make_fusion(self, cfg) -> nn.Module:
        return MessagePassing(self.backbone.stage_channels[0])

    def attentions(self) -> list:
        return []

    #: the GRU's update-gate bias at the start: sigmoid(-3) = 0.047 of the update taken
    START_UPDATE_BIAS = -3.0

    @torch.no_grad()
    def start_from_base(self, missing: Collection[str] = ()) -> None:
        """After AttFuse's or the single model's weights were loaded: the network starts close to
        the ego alone through those weights (each round keeps 95 % of an agent's map, the last 1x1
        convolution is the identity), so that training opens the GRU to the messages from a
        working detector instead of a scrambled map."""
        fusion = self.fusion
        c = fusion.out.weight.shape[0]
        fusion.out.weight.copy_(torch.eye(c)[:, :, None, None])
        fusion.out.bias.zero_()
        fusion.gru.gates.bias[c:].fill_(self.START_UPDATE_BIAS)


@FUSIONS.register("v2vnet")
class V2VNetDetector(AgentCloudsDetector):
    weights = "v2vnet"

    @classmethod
    def new_network(cls, cfg) -> torch.nn.Module:
        return V2VNet(cfg)
