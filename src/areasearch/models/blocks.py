"""Building blocks of the DA-HGNN network (:mod:`areasearch.models.network`): fully connected stacks
(:func:`mlp`, run layer by layer by :func:`run_mlp`), the projections of a node set's features into what a
round needs from it (:class:`Projections`), the update MLP rho_v of eqs. 8, 10 and 13
(:class:`NodeUpdate`) and the graph embedding network (:class:`Encoders`).
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from typing import cast

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from .graph import GraphBatch, scaled_distance
from .network_config import NetworkConfig


def mlp(sizes: Sequence[int]) -> nn.Sequential:
    """Fully connected layers with ReLU between them (none after the last)."""
    layers: list[nn.Module] = []
    for i, (a, b) in enumerate(itertools.pairwise(sizes)):
        layers.append(nn.Linear(a, b))
        if i < len(sizes) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


def run_mlp(net: nn.Sequential, x: Tensor) -> Tensor:
    """An :func:`mlp` on ``x``, layer by layer without the module calls (a small MLP's time is mostly
    theirs)."""
    for layer in net:
        x = F.linear(x, layer.weight, layer.bias) if isinstance(layer, nn.Linear) else torch.relu(x)
    return x


def on_real(net: nn.Sequential, x: Tensor, mask: Tensor, width: int) -> Tensor:
    """``net`` on the real rows of ``x`` (B, N, F) only, zeros on the padded ones: (B * N, width)."""
    flat = x.flatten(0, 1)
    if bool(mask.all()):
        return run_mlp(net, flat)
    rows = mask.flatten().nonzero().squeeze(1)
    out = run_mlp(net, flat.index_select(0, rows))
    return out.new_zeros(flat.shape[0], width).index_copy(0, rows, out)


def flat_rows(idx: Tensor, per: int) -> Tensor:
    """Neighbour lists (B, N, ...) of node indices within each batch row -> rows of the flattened
    (B * per) node table; -1 stays -1."""
    if idx.shape[0] == 1:
        return idx
    base = (torch.arange(idx.shape[0], device=idx.device) * per).view(-1, *([1] * (idx.dim() - 1)))
    return torch.where(idx >= 0, idx + base, idx)


class Projections(nn.Module):
    """One linear map of a node set's features into the named parts that a round needs from it
    (queries, keys, values, MLP-attention parts, the h half of the update MLPs): one matrix product."""

    def __init__(self, dim: int, parts: Mapping[str, int]) -> None:
        super().__init__()
        self.names, self.sizes = list(parts), list(parts.values())
        self.linear = nn.Linear(dim, sum(self.sizes))

    def forward(self, h: Tensor) -> dict[str, Tensor]:
        out = F.linear(h, self.linear.weight, self.linear.bias)  # (a module call costs more than the product)
        return dict(zip(self.names, out.split(self.sizes, dim=-1), strict=True))


class NodeUpdate(nn.Module):
    """Eqs. 8, 10 and 13 for one node set: h <- h + rho_v([h || m_1 || ... || m_G]) over the messages
    of the node's G graphs. The paper sums one rho_v per graph (eq. 13); here the graphs' update MLPs
    share their hidden layer, of which that sum is the special case with a block-diagonal first layer.
    The h part of the first layer comes with the node set's :class:`Projections` (``own``); each
    message group adds its part with one product. Padded nodes are updated too (never read)."""

    def __init__(self, dim: int, message_dims: Sequence[int], hidden: int) -> None:
        super().__init__()
        self.message = nn.ParameterList(nn.Parameter(torch.empty(d, hidden)) for d in message_dims)
        self.out = nn.Linear(hidden, dim)

    def forward(self, h: Tensor, own: Tensor, messages: Sequence[Tensor]) -> Tensor:
        """h (N, D), own (N, hidden), messages (N, d_g) per group -> (N, D)."""
        z = own
        for i, m in enumerate(messages):
            z = torch.addmm(z, m, self.message[i])
        return h + F.linear(torch.relu(z), self.out.weight, self.out.bias)


# ---------------------------------------------------------------------------------------------- the network


class Encoders(nn.Module):
    """The graph embedding network ("Network Architecture and Hyperparameter Details"): node features
    of :mod:`areasearch.models.graph` -> initial node features, and distances -> edge features. Encoders run
    on the real nodes only (a batch's padding costs nothing)."""

    def __init__(self, cfg: NetworkConfig) -> None:
        super().__init__()
        g, d, hidden, layers = cfg.graph, cfg.node_dim, cfg.encoder_hidden, cfg.encoder_layers
        kinds = 2 if cfg.type_aware else 0  # the kind, one-hot, is an input only with type awareness
        self.robot = mlp([g.robot_features] + [hidden] * (layers - 1) + [d])
        self.common = mlp([g.candidate_features + kinds] + [hidden] * (layers - 1) + [d])  # frontiers, targets
        self.distance = nn.Linear(2, cfg.edge_dim)  # [d / (d + scale), unreachable]
        if cfg.history:
            dh = cfg.history_dim
            self.past_robot = mlp([g.history_features] + [dh] * layers)  # the special encoder, twice
            self.past_goal = mlp([g.history_features] + [dh] * layers)
            self.past_distance = nn.Linear(1, cfg.edge_dim)  # Euclidean distances of history edges
        self.type_aware, self.node_dim, self.history_dim = cfg.type_aware, d, cfg.history_dim

    def robots(self, batch: GraphBatch) -> Tensor:
        return on_real(self.robot, batch.robot_x, batch.robot_mask, self.node_dim).view(*batch.robot_mask.shape, -1)

    def candidates(self, batch: GraphBatch, real: Tensor) -> Tensor:
        """(P, D) for the P real candidates, rows ``real`` of the flattened (B * C) candidates."""
        x = batch.cand_x.flatten(0, 1).index_select(0, real)
        if self.type_aware:
            kind = batch.cand_kind.flatten().index_select(0, real)
            x = torch.cat([x, F.one_hot(kind, 2).to(x.dtype)], dim=-1)
        return run_mlp(self.common, x)

    def past(self, batch: GraphBatch) -> Tensor:
        """(B, 2N, Dh): historical robots, then historical goals."""
        b, n = batch.past_robot_mask.shape
        pr = on_real(self.past_robot, batch.past_robot_x, batch.past_robot_mask, self.history_dim)
        pg = on_real(self.past_goal, batch.past_goal_x, batch.past_goal_mask, self.history_dim)
        return torch.cat([pr.view(b, n, -1), pg.view(b, n, -1)], dim=1)

    def geodesic(self, batch: GraphBatch, pairs: Tensor) -> Tensor:
        """(N, E) for the N robot-candidate ``pairs`` (N, 3) (batch row, robot, candidate). The inputs
        are centred to [-1, 1]: a ReLU unit of non-negative inputs with negative weights would never fire."""
        at = pairs.unbind(1)
        x = torch.stack([batch.dist[at], (~batch.reachable[at]).to(batch.dist.dtype)], dim=-1) * 2.0 - 1.0  # (N, 2)
        return torch.relu(F.linear(x, self.distance.weight, self.distance.bias))

    def euclidean(self, a: Tensor, b: Tensor, scale_m: float, pairs: Tensor) -> Tensor:
        """(N, E) from the Euclidean distances (metres) between positions a[batch row, p] (a (B, P, 2))
        and b[batch row, q] (b (B, Q, 2)) of the N ``pairs`` (N, 3) (batch row, p, q)."""
        row, p, q = pairs.unbind(1)
        d = cast(Tensor, scaled_distance((a[row, p] - b[row, q]).pow(2).sum(-1).sqrt(), scale_m))  # (N,) in [0, 1)
        return torch.relu(F.linear(d[:, None] * 2.0 - 1.0, self.past_distance.weight, self.past_distance.bias))
