"""Pipeline stage "planner" (learned): DA-HGNN, the dual-attention heterogeneous graph network.

Implements the DA-HGNN paper's "Topological Planner" (Zhu et al., "Dual-Attention Heterogeneous
Graph Neural Network for Multi-robot Collaborative Area Search via Deep Reinforcement Learning",
eqs. 6-12) and its "Network Architecture and Hyperparameter Details" on the graphs of
:mod:`areasearch.models.graph`, with the critic and the auxiliary exploration-ratio head of "Policy
Optimization". Which class implements what:

=====================  ==========================================================================
:class:`Encoders`      the graph embedding network: common encoder (5 FC -> 64-d) for frontier and
                       target nodes, special encoder (2 x 5 FC -> 32-d) for historical robot
                       positions and historical goals, distance encoder (1 FC) for the
                       robot-candidate distances; robots get an encoder of the common encoder's shape
:func:`~areasearch.models.attention.sparse_attention`
                       multi-head dot-product attention of a self-graph (eq. 6), heads concatenated
                       (eq. 7): G_r, G_g, G_r', G_g', the type-aware G_e and G_c (eq. 11)
:func:`~areasearch.models.attention.cross_attention`
                       MLP attention of a cross-graph, logits rho([k || q || d]) per head (eq. 9): the
                       robot-goal graph G_rg both ways, G_re and G_rc (eq. 12), robots <- history
:class:`NodeUpdate`    h + rho_v([h || message]) (eqs. 8, 10), summed over the graphs of a node:
                       robot = self + robot-goal + robot-frontier + robot-target + history (eq. 13)
:class:`Round`         one of the six rounds over every graph (its docstring lists them)
:class:`Similarity`    the affinity matrix M between robots and candidates and its log-domain
                       Sinkhorn normalisation S = Sinkhorn(M) (:func:`log_sinkhorn`) with a slack
                       row and column (section "Similarity Measurement")
:class:`Critic`        embedding CNN (5 conv -> 32-d) on the observation map, 3 FC -> state value,
                       and the auxiliary exploration-ratio head (the L^Acc loss)
:class:`DAHGNN`        the actor-critic; :class:`NetworkConfig` switches ``type_aware`` ("w/o type
                       semantic") and ``history`` ("w/o history module"); :meth:`NetworkConfig.ncm`
                       is the NCM baseline (Ye et al., CVPR 2022) from the same modules
=====================  ==========================================================================

**Policy.** Robot r's action is a candidate index, drawn from row r of S over the candidates
``action_mask[r]`` allows (``logits = log S[r, :C]``, -inf where not allowed; the slack column, "no
match", is dropped). The robots draw in index order without replacement: robot r's draw leaves out
the goals robots 0..r-1 took, while any of its allowed goals is left (:func:`sequential_mask`). So
training samples what evaluation plays: :func:`assign_goals` solves the linear assignment on log S
(no two robots share a goal while there are enough allowed goals, the paper's "argmax on each row
and column"), and the sampled team is a stochastic version of it (with independent draws from the
rows, 16 % of 3-robot and 36 % of 5-robot decisions sent two robots to one goal, measured on the
first release's training runs). PPO's ratios are per robot, on these conditional probabilities
(:mod:`areasearch.training.ppo`); joint log-probability = their sum. A robot with no allowed candidate (or a
padded one) takes action 0 with probability 1 and adds nothing.

Readings of the paper where it is not explicit, and deviations (also in the class docstrings):

* eqs. 8, 10, 11, 12 and 13: each graph contributes rho_v([h || message]); a node adds the sum of the
  contributions of all graphs it belongs to to its feature (one residual), so eq. 13's sum of six
  terms does not count h six times. Updates are synchronous: every message of round l reads the
  features of round l. The scaled dot product (1/sqrt(D/M)) of eq. 6 is the usual one.
* eq. 9's MLP attention is multi-head (one logit per head from one hidden layer); the four
  robot-candidate cross-graphs (G_rg both ways, G_re, G_rc) share that hidden layer (their R x C x
  hidden pair tensor is the costliest part of a round) and have their own logits, values and
  update MLPs; likewise robots <- historical robots and robots <- historical goals.
* G_e and G_c share one projection (they share no edge, so they stay two graphs); G_r'e and G_r'c
  (candidates <- historical robots, C x H R pairs) use dot-product attention with a query projection
  per kind instead of an MLP over distances, for speed; node positions are in the node features.
* Historical nodes are updated by their self-graphs only; they pass information to the robots
  (eq. 13) and to the candidates. Robot-history edges carry Euclidean distances (the observation has
  geodesic distances for the current robots only).
* Node features come from a crop of the observation map around each node (see
  :mod:`areasearch.models.graph`) plus what the observation says of the node; the paper's "7 x 64" map
  embedding is read as this per-node encoding.
* Widths are the paper's (64-d nodes, 32-d history, six rounds); heads, the attention hidden layer
  and the update MLPs are not in the paper.
* The affinity has a learned distance prior, M_ij - beta * d_ij / (d_ij + 5 m) (``distance_prior``,
  beta learned from 8): the untrained policy is then a coordinated soft nearest-goal assignment,
  which PPO refines within a one-hour CPU budget; ``distance_prior = 0`` is the paper's affinity.
* Self-graphs over candidates (and history) are sparse: each node attends to its K nearest (K = 8,
  :mod:`areasearch.models.graph`); the robot graphs and the robot-candidate cross-graphs are dense.

Axes: B batch, R robots, C candidates, N history nodes, K key nodes, Q query nodes, D width,
E edge width, A attention hidden width, M heads.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple, cast

import numpy as np
import torch
import torch.nn.functional as F
from scipy.optimize import linear_sum_assignment
from torch import Tensor, nn

from ..errors import ConfigError
from .attention import cross_attention, pair_mlp, pair_rows, sinkhorn, sparse_attention
from .graph import GraphBatch, GraphConfig, build_graph, scaled_distance

FORMAT = "areasearch.dahgnn"  # the policy file format's name (not a module path): every policy JSON carries it
"""``format`` entry of a saved policy's JSON file."""
FORMAT_VERSION = 2
"""Version 2 added ``norm`` and ``score_scale`` to the config; a version-1 file is read with
``norm = "none"`` (the architecture it was trained with)."""
NORMS = ("pre-ln", "none")
"""Values of :attr:`NetworkConfig.norm`."""

_NEG = -1e4
"""Log-coupling of forbidden pairs in Sinkhorn: exp(-1e4) is 0 in float32, yet no -inf enters a
logsumexp (whose gradient would be NaN on an all -inf row)."""
_OFF = -1e9
"""Additive attention logit of a missing edge among a handful of robots: its weight is 0 next to any
real edge; a padded robot (no edge at all) gets finite weights, and its update is masked."""
_CAP = 10.0
"""MLP-attention logits are soft-capped to +-_CAP (tanh), so that their exponentials need no
max-subtraction: one exponential per pair serves every normalisation of the pair's score."""
_TINY = 1e-30
"""Floor of an attention normaliser: a node with no neighbour gets a 0 message, not 0 / 0."""


@dataclass(frozen=True)
class NetworkConfig:
    """The DA-HGNN actor-critic. Widths are the paper's where it gives them, unless said otherwise."""

    graph: GraphConfig = field(default_factory=GraphConfig)
    """How observations become node and edge features (and the K of the sparse graphs)."""
    type_aware: bool = True
    """Type-aware graph augmentation (eqs. 11-13): frontier and target self-graphs, robot-frontier,
    robot-target, historical-robot-frontier and -target cross-graphs, and the node kind as an input
    feature. False: the paper's "w/o type semantic" ablation."""
    history: bool = True
    """History nodes (historical robot positions and goals), their special encoder and graphs.
    False: the paper's "w/o history module" ablation."""
    rounds: int = 6
    """Rounds of attention over all graphs (paper: six)."""
    node_dim: int = 64
    """Width of robot and candidate features (paper: the common encoder's 64-d)."""
    history_dim: int = 32
    """Width of history node features (paper: the special encoder's 32-d)."""
    encoder_layers: int = 5
    """Fully connected layers of the encoders (paper: 5)."""
    encoder_hidden: int = 32
    """Width of the hidden layers of the robot and common encoders (the special encoder's are
    ``history_dim`` wide)."""
    heads: int = 2
    """Attention heads of the dot-product self-graphs (multi-head attention, eqs. 6-7)."""
    cross_heads: int = 1
    """Attention heads of the MLP-attention cross-graphs (eq. 9)."""
    key_dim: int = 4
    """Query and key width per head of the dot-product graphs."""
    value_dim: int = 16
    """Width of a graph's message: every node set projects its features to values of this width
    (split among the heads), which all the graphs it sends to read."""
    attention_hidden: int = 8
    """Hidden width of the MLP attention of the cross-graphs (eq. 9) and of the affinity MLP."""
    edge_dim: int = 8
    """Output width of the distance encoder (one FC layer + ReLU)."""
    update_hidden: int = 32
    """Hidden width of a node set's update MLP rho_v (eqs. 8, 10, 13; see :class:`NodeUpdate`)."""
    sinkhorn_iters: int = 10
    """Log-domain Sinkhorn iterations of the similarity measurement."""
    norm: str = "pre-ln"
    """Normalisation in the rounds. ``pre-ln``: every round reads its node features through a
    LayerNorm (the residual stream itself is not normalised: pre-LN, Xiong et al. 2020), the final
    features pass a LayerNorm before the similarity measurement, and the dot-product scores are
    cosine similarities of the queries and keys times ``score_scale`` (query-key normalisation,
    Henry et al. 2020), so no score can grow without bound. ``none``: the unnormalised rounds of
    the first release (policy files of format version 1), whose features and scores grew by
    orders of magnitude during training (docs/dahgnn.md#normalisation)."""
    score_scale: float = 4.0
    """With ``norm = "pre-ln"``: the dot-product scores are cos(q, k) * this, in [-4, 4], so one
    neighbour weighs at most e^8 ~ 3,000 times another (one-hot attention, whose gradient vanishes,
    cannot form)."""
    distance_prior: float = 8.0
    """Initial weight beta of the distance prior of the affinity, M_ij - beta * dist_ij with dist_ij
    = d / (d + distance_scale_m) the scaled geodesic distance (beta = softplus of a learned parameter).
    The first policy is then a coordinated soft nearest-goal assignment that PPO refines, instead of
    a uniform one (not in the paper; see :class:`Similarity`). 0: no prior (the paper's affinity)."""
    critic_channels: int = 32
    """Channels of the critic's CNN; its output embedding has this width (paper: 32-d)."""
    critic_hidden: int = 64
    """Hidden width of the critic's 3 FC layers and of the auxiliary head."""

    def validate(self) -> NetworkConfig:
        """Self, or ConfigError naming the first field that cannot work: every size and count within
        :data:`NETWORK_SIZES` (the graph's too), every scale finite and within its bound."""
        self.graph.validate()
        for key, high in NETWORK_SIZES.items():
            value: Any = self
            for part in key.split("."):
                value = getattr(value, part)
            low = 0 if key in ("graph.patch_cells", "graph.history") else 1
            if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
                raise ConfigError(f"network.{key} must be an integer from {low} to {high:,}, got {_short(value)}")
        for key, bound in NETWORK_SCALES.items():
            value = getattr(self.graph, key.removeprefix("graph.")) if key.startswith("graph.") else getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ConfigError(f"network.{key} must be a finite number, got {_short(value)}")
            if not 0 <= value <= bound:
                raise ConfigError(f"network.{key} must be a number from 0 to {bound:g}, got {_short(value)}")
        for name in ("type_aware", "history"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"network.{name} must be true or false, got {_short(getattr(self, name))}")
        for heads in ("heads", "cross_heads"):
            if self.value_dim % getattr(self, heads):
                raise ConfigError(
                    f"network.value_dim ({self.value_dim}) must be a multiple of {heads} ({getattr(self, heads)})"
                )
        if self.critic_channels < 2:
            raise ConfigError(f"network.critic_channels must be at least 2, got {self.critic_channels}")
        if self.norm not in NORMS:
            raise ConfigError(f"network.norm must be one of {', '.join(NORMS)}, got {_short(self.norm)}")
        scale = self.score_scale
        if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not 0 < scale <= 100:
            raise ConfigError(f"network.score_scale must be a number in (0, 100], got {_short(scale)}")
        return self

    @classmethod
    def ncm(cls, **changes: Any) -> NetworkConfig:
        """The NCM baseline (Ye et al., CVPR 2022, "Multi-robot active mapping via neural bipartite graph
        matching") from the same modules: no type distinction (targets are plain candidates), history
        nodes, three rounds of self/cross attention, 32-d features as in its code, Sinkhorn bipartite
        matching. Its nodes are encoded like DA-HGNN's, from the map around them: from their position,
        size and gain alone (``GraphConfig(patch_cells=0)``) the candidates' embeddings are so alike
        that PPO barely moves the policy (a tenth of DA-HGNN's log-probability change per Adam step,
        measured; a first training run stayed at approx_kl ~1e-6), which would compare training
        failures rather than architectures."""
        base = cls(
            type_aware=False,
            history=True,
            rounds=3,
            node_dim=32,
            history_dim=32,
            encoder_hidden=32,
        )
        return dataclasses.replace(base, **changes).validate()


NETWORK_SIZES = {
    **dict.fromkeys(("rounds", "encoder_layers", "heads", "cross_heads"), 64),
    **dict.fromkeys(("node_dim", "history_dim", "encoder_hidden", "key_dim", "value_dim"), 4_096),
    **dict.fromkeys(("attention_hidden", "edge_dim", "update_hidden", "critic_channels", "critic_hidden"), 4_096),
    "sinkhorn_iters": 1_000,
    **{f"graph.{name}": 256 for name in ("patch_cells", "patch_pool", "map_pool", "neighbours")},
    "graph.history": 1_000,
}
"""Largest value of each size and count of a network (tensor widths, rounds, loop counts, the crop
and neighbour counts of its graphs), in a policy file as in a training config: the paper's network
uses at most 64 of each, 10 Sinkhorn iterations and 8 history steps. A policy's JSON names them
beside its weights, and the fields that shape no tensor (Sinkhorn iterations, neighbours, crop sizes
with a pooling that cancels them) cannot be checked against the weights: unbounded, a 9 KB file made
every decision allocate until the kernel killed the process."""
NETWORK_SCALES = {
    "graph.distance_scale_m": 1e6,
    "graph.size_scale_cells": 1e9,
    "graph.gain_scale_cells": 1e9,
    "graph.cell_m": 10.0,
    "distance_prior": 1e3,
}
"""Largest value of each scale of a network (all must also be finite and >= 0)."""
MAX_PARAMETERS = 50_000_000
"""Most parameters of a network built from a config (200 MB of float32; the shipped policies have
about 250,000): counted on PyTorch's meta device, before any is allocated (:func:`network_shapes`)."""


def _short(value: object, limit: int = 60) -> str:
    """``repr(value)`` cut to ``limit`` characters (a value from a file, quoted in a message)."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def network_shapes(config: NetworkConfig, source: str = "config") -> dict[str, list[int]]:
    """The name and shape of every tensor of the network ``config`` describes, found on PyTorch's meta
    device (nothing is allocated); ConfigError naming ``source`` when it has more than
    :data:`MAX_PARAMETERS` parameters."""
    with torch.device("meta"):
        skeleton = DAHGNN(config)
    count = sum(p.numel() for p in skeleton.parameters())
    if count > MAX_PARAMETERS:
        raise ConfigError(f"{source}: the network has {count:,} parameters, more than the limit of {MAX_PARAMETERS:,}")
    return {k: list(v.shape) for k, v in skeleton.state_dict().items()}


# ---------------------------------------------------------------------------------------------- building blocks


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


def _on_real(net: nn.Sequential, x: Tensor, mask: Tensor, width: int) -> Tensor:
    """``net`` on the real rows of ``x`` (B, N, F) only, zeros on the padded ones: (B * N, width)."""
    flat = x.flatten(0, 1)
    if bool(mask.all()):
        return run_mlp(net, flat)
    rows = mask.flatten().nonzero().squeeze(1)
    out = run_mlp(net, flat.index_select(0, rows))
    return out.new_zeros(flat.shape[0], width).index_copy(0, rows, out)


def _heads(x: Tensor, heads: int) -> Tensor:
    """(B, N, heads * w) -> (B, heads, N, w)."""
    return x.unflatten(-1, (heads, -1)).transpose(1, 2)


def _flat_rows(idx: Tensor, per: int) -> Tensor:
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
        return _on_real(self.robot, batch.robot_x, batch.robot_mask, self.node_dim).view(*batch.robot_mask.shape, -1)

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
        pr = _on_real(self.past_robot, batch.past_robot_x, batch.past_robot_mask, self.history_dim)
        pg = _on_real(self.past_goal, batch.past_goal_x, batch.past_goal_mask, self.history_dim)
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


class _State(NamedTuple):
    robots: Tensor  # (B, R, D)
    goals: Tensor  # (P, D): the real candidates only (see _Context.real)
    past: Tensor | None  # (B, 2N, Dh): historical robots, then historical goals


class _Context(NamedTuple):
    """What every round reads, computed once per forward: masks, neighbour rows, edge features (each
    round's attention kernels project them with its own weights, on the real pairs only)."""

    b: int
    r: int
    c: int
    n: int
    real: Tensor | None  # (P,) rows of the real candidates in the flattened (B * C) ones; None: all are
    cand_groups: list[int]  # first (packed) candidate row of each decision
    robot_rows: Tensor  # (B * R, 1, R) neighbour rows of G_r
    robot_mask: Tensor  # (B, R) bool: real robots
    kind: Tensor  # (B, C) int64: a real candidate's kind (0 frontier, 1 target), -1 for padding
    cand_rows: Tensor  # (P, G, K) neighbour rows (packed) of G_g [then of G_e / G_c]
    pair_rows: Tensor  # (B, R, C) row of each robot-candidate pair in the pair table, -1: not a pair
    pair_edges: Tensor  # (N, E) the pair table's edge features (distance encoder)
    similarity_rows: Tensor  # (B, R, C) pair_rows of the pairs the action mask allows, -1 elsewhere
    past_rows: Tensor | None  # (B * 2N, 1, K) neighbour rows of G_r' and G_g'
    past_cand_rows: Tensor | None  # (B * N, G, K) neighbour rows (packed candidates) of G_r'e [then G_r'c]
    past_kind: Tensor | None  # (B, 2N) int64: 0 historical robot, 1 historical goal
    past_pair_rows: Tensor | None  # (B, R, 2N) row of each robot-history pair in its table, -1: none
    past_edges: Tensor | None  # (N', E) that table's edge features (Euclidean distances)


def _context(net: DAHGNN, batch: GraphBatch) -> _Context:
    cfg, enc = net.config, net.encoders
    rm, cm = batch.robot_mask, batch.cand_mask
    b, nr = rm.shape
    nc = cm.shape[1]
    counts = cm.sum(1)
    real = None if bool((counts == nc).all()) else cm.flatten().nonzero().squeeze(1)
    packed = None
    if real is not None:  # flat candidate row -> packed row
        packed = torch.full((b * nc,), -1, dtype=torch.long, device=cm.device)
        packed[real] = torch.arange(real.numel(), device=cm.device)

    def to_packed(idx: Tensor) -> Tensor:
        return idx if packed is None else torch.where(idx >= 0, packed[idx.clamp(min=0)], -1)

    rows = _flat_rows(batch.cand_nbr, nc)[:, :, None]  # (B, C, 1, K)
    if cfg.type_aware:
        rows = torch.cat([rows, _flat_rows(batch.cand_kin, nc)[:, :, None]], dim=2)
    rows = rows.flatten(0, 1)
    robot_rows = _flat_rows(torch.where(rm, torch.arange(nr, device=rm.device), -1)[:, None].expand(b, nr, nr), nr)
    past_rows = past_cand_rows = to_past = past_kind = past_pair = past_edges = None
    if cfg.history:
        p, q = batch.past_robot_mask, batch.past_goal_mask
        n = p.shape[1]
        goal_nbr = torch.where(batch.past_goal_nbr >= 0, batch.past_goal_nbr + n, -1)
        both = _flat_rows(torch.cat([batch.past_robot_nbr, goal_nbr], dim=1), 2 * n)  # (B, 2N, K)
        past_rows = both.flatten(0, 1)[:, None]  # (B * 2N, 1, K)
        cand = to_packed(_flat_rows(batch.past_cand, nc))  # (B, N, 2, K)
        if not cfg.type_aware:
            cand = cand.flatten(2, 3)[:, :, None]  # G_r'g: the nearest frontiers and the nearest targets
        past_cand_rows = cand.flatten(0, 1)  # (B * N, typed, K)
        to_past = rm[:, :, None] & torch.cat([p, q], dim=1)[:, None]  # (B, R, 2N)
        past_kind = (torch.arange(2 * n, device=p.device) >= n).long().expand(b, -1)
        xy = torch.cat([batch.past_robot_xy, batch.past_goal_xy], dim=1)  # (B, 2N, 2)
        past_pair, index = pair_rows(to_past)
        past_edges = enc.euclidean(batch.robot_xy, xy, cfg.graph.distance_scale_m, index)
    pair = rm[:, :, None] & cm[:, None, :]
    rows_of_pairs, index = pair_rows(pair)
    return _Context(
        b=b,
        r=nr,
        c=nc,
        n=batch.past_robot_mask.shape[1],
        real=real,
        cand_groups=[0, *torch.cumsum(counts, 0)[:-1].tolist()],
        robot_rows=robot_rows.flatten(0, 1)[:, None],
        robot_mask=rm,
        kind=torch.where(cm, batch.cand_kind, -1),
        cand_rows=to_packed(rows if real is None else rows.index_select(0, real)),
        pair_rows=rows_of_pairs,
        pair_edges=enc.geodesic(batch, index),
        similarity_rows=torch.where(batch.action_mask, rows_of_pairs, -1),
        past_rows=past_rows,
        past_cand_rows=past_cand_rows,
        past_kind=past_kind,
        past_pair_rows=past_pair,
        past_edges=past_edges,
    )


def _padded(x: Tensor, ctx: _Context) -> Tensor:
    """Packed candidate rows (P, w) -> (B, C, w), zeros on the padded candidates."""
    if ctx.real is not None:
        x = x.new_zeros(ctx.b * ctx.c, x.shape[1]).index_copy(0, ctx.real, x)
    return x.view(ctx.b, ctx.c, -1)


def _packed(x: Tensor, ctx: _Context) -> Tensor:
    """(B, C, w) -> the packed candidate rows (P, w)."""
    x = x.flatten(0, 1)
    return x if ctx.real is None else x.index_select(0, ctx.real)


# ---------------------------------------------------------------------------------------------- health probes
# What :func:`diagnose` records of a forward pass (plain torch, on the side of the kernels): the scale of
# the features each round reads, how peaked the candidates' self-attention is, how many robot-goal
# MLP-attention logits sit on the flat part of their tanh cap. Unnormalised rounds let all three
# run away during training (docs/dahgnn.md#normalisation); these are the numbers that show it.


def _rms(x: Tensor) -> float:
    return float(x.pow(2).mean().sqrt()) if x.numel() else 0.0


def _probe_features(probe: dict[str, float], name: str, r: Tensor, g: Tensor, ctx: _Context) -> None:
    probe[f"{name}_robot_rms"] = _rms(r[ctx.robot_mask])
    probe[f"{name}_goal_rms"] = _rms(g)


def _probe_scores(probe: dict[str, float], name: str, q: Tensor, k: Tensor, idx: Tensor) -> None:
    """Spread (largest less smallest logit) and largest weight of the candidates' dot-product
    self-attention, averaged over the (row, head) pairs with at least two neighbours."""
    h = q.shape[1]
    rows = idx.repeat_interleave(h // idx.shape[1], dim=1)  # (P, H, K)
    ok = rows >= 0
    heads = torch.arange(h)[None, :, None].expand_as(rows)
    logits = (k[rows.clamp(min=0), heads % k.shape[1]] * q[:, :, None]).sum(-1)  # (P, H, K)
    many = ok.sum(-1) >= 2
    if not bool(many.any()):
        probe[f"{name}_score_spread"] = probe[f"{name}_max_attention"] = 0.0
        return
    spread = logits.masked_fill(~ok, -math.inf).amax(-1) - logits.masked_fill(~ok, math.inf).amin(-1)
    weights = torch.softmax(logits.masked_fill(~ok, -math.inf), dim=-1).amax(-1)
    probe[f"{name}_score_spread"] = float(spread[many].mean())
    probe[f"{name}_max_attention"] = float(weights[many].mean())


def _probe_saturation(
    probe: dict[str, float], name: str, edges: Tensor, rows: Tensor, p_part: Tensor, q_part: Tensor, logits: nn.Linear
) -> None:
    """Share of the robot-candidate MLP-attention logits (eq. 9) whose tanh cap is saturated (|tanh| > 0.99)."""
    ok = rows >= 0
    if not bool(ok.any()):
        probe[f"{name}_cross_saturated"] = 0.0
        return
    b, p, q = ok.nonzero().unbind(1)
    z = torch.relu(edges[rows[ok]] + p_part[b, p] + q_part[b, q])
    t = torch.tanh(F.linear(z, logits.weight, logits.bias) / _CAP)
    probe[f"{name}_cross_saturated"] = float((t.abs() > 0.99).float().mean())


class Round(nn.Module):
    """One round of attention over every graph (all messages read the features of the previous round).

    * eqs. 6-8: dot-product self-graphs G_r (robots, dense), G_g (each candidate over its K nearest
      candidates), G_r', G_g' (each history node over its K nearest of its own set);
    * eqs. 9-10: the robot-goal cross-graph G_rg both ways, MLP attention over [robot || candidate ||
      distance]; with type awareness G_re and G_rc (eq. 12: robots <- frontiers, robots <- targets);
    * eq. 11: the type-aware self-graphs G_e and G_c: each candidate over its K nearest candidates of
      its own kind (one projection for both: they share no edge);
    * history: robots <- historical robots and <- historical goals (the h_rr' and h_r* terms of eq. 13)
      by MLP attention with Euclidean distances; historical robots <- their K nearest frontiers and
      targets (G_r'e, G_r'c; G_r'g over both without type awareness) by dot-product attention;
    * eq. 13: each node set adds its graphs' messages through its update MLP (:class:`NodeUpdate`).

    The robot-candidate score of eq. 9 is one per pair and head: G_rg normalises it over a robot's
    candidates and over a candidate's robots, G_re and G_rc over a robot's frontiers and its targets.
    """

    def __init__(self, cfg: NetworkConfig, last: bool = False) -> None:
        super().__init__()
        d, dh, a, m, dk, dv, hid = (
            cfg.node_dim, cfg.history_dim, cfg.attention_hidden, cfg.heads, cfg.key_dim, cfg.value_dim,
            cfg.update_hidden,
        )  # fmt: skip
        self.heads, self.cross_heads, self.key_dim, self.value_dim = m, cfg.cross_heads, dk, dv
        self.type_aware, self.history = cfg.type_aware, cfg.history
        self.typed = typed = 2 if cfg.type_aware else 1  # G_g [and G_e / G_c]
        robot_parts = {"qk": 2 * m * dk, "value": dv, "pair": a} | ({"past": a} if cfg.history else {})
        goal_parts = {"qk": 2 * typed * m * dk, "value": dv, "pair": a} | ({"key": m * dk} if cfg.history else {})
        self.robot_proj = Projections(d, robot_parts | {"own": hid})
        self.goal_proj = Projections(d, goal_parts | {"own": hid})
        self.pair_edge = nn.Linear(cfg.edge_dim, a, bias=False)  # the distance part of eq. 9's MLP
        self.pair_logits = nn.Linear(a, cfg.cross_heads)
        self.update_past = cfg.history and not last  # history features after the last round are not read
        self.normed, self.score_scale = cfg.norm == "pre-ln", float(cfg.score_scale)
        if self.normed:  # pre-LN: the round reads normalised features; the residual stream is left as it is
            self.robot_norm, self.goal_norm = nn.LayerNorm(d), nn.LayerNorm(d)
            if cfg.history:
                self.past_norm = nn.LayerNorm(dh)
        if cfg.history:
            mine = {"qk": 2 * m * dk, "own": hid} if self.update_past else {}
            query = {"query": typed * m * dk} if self.update_past else {}
            self.past_robot_proj = Projections(dh, mine | query | {"value": dv, "pair": a})
            self.past_goal_proj = Projections(dh, mine | {"value": dv, "pair": a})
            self.past_edge = nn.Linear(cfg.edge_dim, a, bias=False)
            self.past_logits = nn.Linear(a, cfg.cross_heads)
        if self.update_past:
            self.past_robot_update = NodeUpdate(dh, [dv, typed * dv], hid)  # G_r'; G_r'e [, G_r'c]
            self.past_goal_update = NodeUpdate(dh, [dv], hid)  # G_g'
        # robots: G_r, G_rg [, G_re, G_rc] [, historical robots, historical goals]; candidates: G_g [, G_e/c], G_rg
        self.robot_update = NodeUpdate(d, [(2 + 2 * cfg.type_aware + 2 * cfg.history) * dv], hid)
        self.goal_update = NodeUpdate(d, [typed * dv, dv], hid)

    def _norm(self, x: Tensor, which: str) -> Tensor:
        """The round's view of a node set's features: LayerNorm'ed (``pre-ln``) or as they are."""
        if not self.normed:
            return x
        ln = cast(nn.LayerNorm, getattr(self, which))
        return F.layer_norm(x, ln.normalized_shape, ln.weight, ln.bias, ln.eps)

    def _scores(self, q: Tensor, k: Tensor) -> tuple[Tensor, Tensor]:
        """(queries, keys) whose dot products are the attention logits: q . k / sqrt(dk), or with
        ``pre-ln`` cos(q, k) * score_scale (query-key normalisation: bounded scores)."""
        if not self.normed:
            return q * self.key_dim**-0.5, k
        return F.normalize(q, dim=-1) * self.score_scale, F.normalize(k, dim=-1)

    def forward(self, state: _State, ctx: _Context, step: int, probe: dict[str, float] | None = None) -> _State:
        r, g, past = state
        m, dk, dv, typed = self.heads, self.key_dim, self.value_dim, self.typed
        b, nr = ctx.b, ctx.r
        if probe is not None:
            _probe_features(probe, f"round{step}", r, g, ctx)
        rp, gp = self.robot_proj(self._norm(r, "robot_norm")), self.goal_proj(self._norm(g, "goal_norm"))

        # G_r, eqs. 6-8 (every robot of the decision)
        qk = rp["qk"].view(-1, 2, m, dk)
        robot_values = rp["value"].reshape(-1, m, dv // m)
        q, k = self._scores(qk[:, 0], qk[:, 1])
        to_r = [sparse_attention(q, k, robot_values, ctx.robot_rows, nr).view(b, nr, dv)]

        # G_g [and G_e / G_c], eqs. 6-8, 11: each candidate over its K nearest candidates [of its kind]
        qk = gp["qk"].view(-1, 2, typed * m, dk)
        values = gp["value"].view(-1, m, dv // m)
        q, k = self._scores(qk[:, 0], qk[:, 1])
        to_g = [sparse_attention(q, k, values, ctx.cand_rows, ctx.cand_groups).view(-1, typed * dv)]
        if probe is not None:
            _probe_scores(probe, f"round{step}", q, k, ctx.cand_rows)

        # eqs. 9-10, 12: G_rg both ways [and G_re, G_rc], one hidden layer over the robot-candidate pairs
        pair_edges = F.linear(ctx.pair_edges, self.pair_edge.weight)
        goal_pairs = _padded(gp["pair"], ctx)
        out_r, out_g = cross_attention(
            pair_edges, ctx.pair_rows, rp["pair"], goal_pairs, self.pair_logits.weight, self.pair_logits.bias,
            ctx.kind, _padded(gp["value"], ctx), rp["value"], typed, _CAP,
        )  # fmt: skip
        if probe is not None:
            _probe_saturation(
                probe, f"round{step}", pair_edges, ctx.pair_rows, rp["pair"], goal_pairs, self.pair_logits
            )
        to_r.append(out_r.flatten(2))  # G_rg [, G_re, G_rc]
        assert out_g is not None
        to_g.append(_packed(out_g.flatten(2), ctx))  # G_rg

        if self.history:
            assert past is not None and ctx.past_pair_rows is not None and ctx.past_edges is not None
            assert ctx.past_kind is not None
            n = ctx.n
            normed_past = self._norm(past, "past_norm")
            hp, qp = self.past_robot_proj(normed_past[:, :n]), self.past_goal_proj(normed_past[:, n:])
            past_values = torch.cat([hp["value"], qp["value"]], dim=1)  # (B, 2N, dv)
            out_past, _ = cross_attention(
                F.linear(ctx.past_edges, self.past_edge.weight), ctx.past_pair_rows, rp["past"],
                torch.cat([hp["pair"], qp["pair"]], dim=1), self.past_logits.weight, self.past_logits.bias,
                ctx.past_kind, past_values, None, 2, _CAP,
            )  # fmt: skip
            to_r.append(out_past[:, :, 1:].flatten(2))  # h_rr', h_r* of eq. 13
            if self.update_past:
                assert ctx.past_rows is not None and ctx.past_cand_rows is not None
                qk = torch.cat([hp["qk"], qp["qk"]], dim=1).view(-1, 2, m, dk)  # G_r', G_g'
                q, k = self._scores(qk[:, 0], qk[:, 1])
                mine = sparse_attention(q, k, past_values.view(-1, m, dv // m), ctx.past_rows, 2 * n).view(b, 2 * n, dv)
                # G_r'e [, G_r'c]
                q, k = self._scores(hp["query"].reshape(-1, typed * m, dk), gp["key"].view(-1, m, dk))
                found = sparse_attention(q, k, values, ctx.past_cand_rows, n)
                robots_past = self.past_robot_update(
                    past[:, :n].flatten(0, 1),
                    hp["own"].flatten(0, 1),
                    [mine[:, :n].flatten(0, 1), found.view(-1, typed * dv)],
                )
                goals_past = self.past_goal_update(
                    past[:, n:].flatten(0, 1), qp["own"].flatten(0, 1), [mine[:, n:].flatten(0, 1)]
                )
                past = torch.cat([robots_past.view(b, n, -1), goals_past.view(b, n, -1)], dim=1)
        r = self.robot_update(r.flatten(0, 1), rp["own"].flatten(0, 1), [torch.cat(to_r, dim=-1).flatten(0, 1)])
        g = self.goal_update(g, gp["own"], to_g)
        return _State(r.view(b, nr, -1), g, past)


def log_sinkhorn(
    scores: Tensor,
    pair_mask: Tensor,
    row_mask: Tensor,
    col_mask: Tensor,
    slack: Tensor | None,
    iters: int,
) -> Tensor:
    """Log-domain Sinkhorn normalisation of ``scores`` (B, R, C) into log S.

    With ``slack`` (a scalar log-score) a slack column and row are appended ("no match"): every real
    row (robot) has mass 1 over its allowed columns and the slack column, every real column
    (candidate) mass 1 over its allowed rows and the slack row; the slack row and column absorb the
    difference, so R != C works. Returns (B, R+1, C+1). Without slack, returns (B, R, C) with mass 1
    per real row and per real column (a square problem with allowed pairs everywhere it needs them).
    Forbidden pairs (``pair_mask`` False) and padded rows and columns get log-mass about -1e4
    (probability 0). The last half-iteration normalises the columns: columns are exact, rows
    converge with ``iters``.
    """
    b = scores.shape[0]
    z = scores.masked_fill(~pair_mask, _NEG)
    one, off = scores.new_zeros(()), scores.new_full((), _NEG)
    log_mu = torch.where(row_mask, one, off)  # (B, R) log marginals: 1 per real row
    log_nu = torch.where(col_mask, one, off)  # (B, C)
    if slack is not None:
        m = row_mask.sum(-1, keepdim=True).to(scores.dtype)  # (B, 1) real robots
        n = col_mask.sum(-1, keepdim=True).to(scores.dtype)  # (B, 1) real candidates
        col = torch.where(row_mask, slack, off)[:, :, None]  # (B, R, 1)
        row = torch.cat([torch.where(col_mask, slack, off), slack.expand(b, 1)], dim=-1)[:, None]  # (B, 1, C+1)
        z = torch.cat([torch.cat([z, col], dim=-1), row], dim=1)  # (B, R+1, C+1)
        log_mu = torch.cat([log_mu, torch.where(n > 0, n.clamp(min=1).log(), off)], dim=-1)  # slack row: n
        log_nu = torch.cat([log_nu, torch.where(m > 0, m.clamp(min=1).log(), off)], dim=-1)  # slack col: m
    return sinkhorn(z, log_mu, log_nu, log_mu > _NEG / 2, log_nu > _NEG / 2, iters)


class Similarity(nn.Module):
    """Similarity measurement: affinity M_ij = rho_s([W r_i || W g_j || e_ij]) between robot i and
    candidate j (an MLP with the distance features, as eq. 9), S = Sinkhorn(M) with a learned slack
    score, over the pairs the action mask allows.

    With ``distance_prior`` > 0 the affinity is M_ij - beta * dist_ij (dist_ij = d / (d + scale), the
    scaled geodesic distance, beta = softplus(a learned scalar), initialised to ``distance_prior``):
    an inductive bias towards near goals, so that the untrained policy is a coordinated soft
    nearest-goal assignment (Sinkhorn spreads the robots) and PPO's first updates refine a sensible
    behaviour rather than a uniform one. The network can weaken or strengthen it (beta is learned)
    and override it per pair through M. The paper's affinity has no such term."""

    def __init__(self, dim: int, edge_dim: int, hidden: int, iters: int, distance_prior: float = 0.0) -> None:
        super().__init__()
        self.robot = nn.Linear(dim, hidden)
        self.candidate = nn.Linear(dim, hidden, bias=False)
        self.edge = nn.Linear(edge_dim, hidden, bias=False)  # applied in the pair kernel
        self.score = nn.Linear(hidden, 1)
        self.slack = nn.Parameter(torch.tensor(1.0))
        self.iters = iters
        self.prior: nn.Parameter | None = None
        if distance_prior > 0:  # softplus^-1(beta), stable for large beta
            raw = distance_prior + math.log(-math.expm1(-distance_prior))
            self.prior = nn.Parameter(torch.tensor(float(raw)))

    def forward(self, r: Tensor, g: Tensor, ctx: _Context, batch: GraphBatch) -> Tensor:
        affinity = pair_mlp(  # on the pairs the action mask allows: the affinity of another is never read
            F.linear(ctx.pair_edges, self.edge.weight), ctx.similarity_rows, self.robot(r),
            _padded(self.candidate(g), ctx), self.score.weight, self.score.bias,
        ).squeeze(-1)  # (B, R, C)  M  # fmt: skip
        if self.prior is not None:
            affinity = affinity - F.softplus(self.prior) * batch.dist
        return log_sinkhorn(affinity, batch.action_mask, batch.robot_mask, batch.cand_mask, self.slack, self.iters)


class Critic(nn.Module):
    """Embedding CNN (5 conv layers -> 32-d, global average pooled, so any map side works) on the
    7-channel critic map of :mod:`areasearch.models.graph` (the observation map pooled by ``map_pool``), then
    3 FC layers -> state value ("Network Architecture"). The progress (steps / horizon) joins the
    embedding: the value of a state depends on the time left. The auxiliary head (2 FC, sigmoid)
    predicts the explored ratio from the same embedding (L^Acc)."""

    def __init__(self, channels: int, hidden: int) -> None:
        super().__init__()
        c = channels
        self.embed = nn.Sequential(
            nn.Conv2d(7, c // 2, kernel_size=3, stride=2, padding=1),  # S/2
            nn.ReLU(),
            nn.Conv2d(c // 2, c, kernel_size=3, stride=2, padding=1),  # S/4
            nn.ReLU(),
            nn.Conv2d(c, c, kernel_size=3, stride=2, padding=1),  # S/8
            nn.ReLU(),
            nn.Conv2d(c, c, kernel_size=3, stride=1, padding=1),
            nn.ReLU(),
            nn.Conv2d(c, c, kernel_size=3, stride=1, padding=1),
            nn.AdaptiveAvgPool2d(1),
            nn.Flatten(),
        )
        self.value = mlp([c + 1, hidden, hidden, 1])
        self.explored = mlp([c + 1, hidden, 1])

    def forward(self, grid: Tensor, progress: Tensor) -> tuple[Tensor, Tensor]:
        x = torch.cat([self.embed(grid), progress], dim=-1)  # (B, 32 + 1)
        return self.value(x).squeeze(-1), torch.sigmoid(self.explored(x).squeeze(-1))  # (B,), (B,)


class PolicyOutput(NamedTuple):
    """What one forward pass gives."""

    logits: Tensor  # (B, R, C) per-robot logits, log S masked to -inf where not allowed (see module docstring)
    log_s: Tensor  # (B, R+1, C+1) log correspondence matrix, slack row and column last
    value: Tensor  # (B,) state value
    explored_ratio: Tensor  # (B,) auxiliary prediction of the explored ratio, in (0, 1)
    has_choice: Tensor  # (B, R) bool: real robot with at least one allowed candidate


class DAHGNN(nn.Module):
    """The DA-HGNN actor-critic (or, by configuration, its ablations and the NCM baseline)."""

    def __init__(self, config: NetworkConfig | None = None) -> None:
        super().__init__()
        cfg = (config or NetworkConfig()).validate()
        self.config = cfg
        self.encoders = Encoders(cfg)
        self.rounds = nn.ModuleList(Round(cfg, last=i == cfg.rounds - 1) for i in range(cfg.rounds))
        self.similarity = Similarity(
            cfg.node_dim, cfg.edge_dim, cfg.attention_hidden, cfg.sinkhorn_iters, cfg.distance_prior
        )
        if cfg.norm == "pre-ln":  # the residual stream's last state, normalised before the similarity step
            self.final_robot_norm, self.final_goal_norm = nn.LayerNorm(cfg.node_dim), nn.LayerNorm(cfg.node_dim)
        self.critic = Critic(cfg.critic_channels, cfg.critic_hidden)
        self.reset_parameters()

    def reset_parameters(self) -> None:
        """Orthogonal initialisation (gain sqrt 2, zero biases), the update MLPs' output layers at gain
        0.1 (six rounds of residual sums of several graphs stay in scale at the start), the affinity
        score at gain 0.01 (a near-uniform first policy), the value output at 1."""
        for module in self.modules():
            if isinstance(module, (nn.Linear, nn.Conv2d)):
                nn.init.orthogonal_(module.weight, math.sqrt(2))
                if module.bias is not None:
                    nn.init.zeros_(module.bias)
        for module in self.modules():
            if isinstance(module, NodeUpdate):
                for weight in module.message:
                    nn.init.orthogonal_(weight, math.sqrt(2))
                nn.init.orthogonal_(module.out.weight, 0.1)
        nn.init.orthogonal_(self.similarity.score.weight, 0.01)
        value_out = self.critic.value[-1]
        assert isinstance(value_out, nn.Linear)
        nn.init.orthogonal_(value_out.weight, 1.0)

    def forward(self, batch: GraphBatch) -> PolicyOutput:
        """Actor and critic on a batch of graphs."""
        log_s = self.actor(batch)
        value, explored = self.critic(batch.map, batch.progress)
        return PolicyOutput(*policy_logits(log_s, batch), value, explored, batch.action_mask.any(-1) & batch.robot_mask)

    def actor(self, batch: GraphBatch, probe: dict[str, float] | None = None) -> Tensor:
        """The topological planner alone: log S (B, R+1, C+1), slack row and column last. ``probe``:
        a dict that receives the health numbers of this pass (:func:`diagnose`)."""
        cfg, enc = self.config, self.encoders
        ctx = _context(self, batch)
        real = ctx.real if ctx.real is not None else torch.arange(ctx.b * ctx.c, device=batch.cand_mask.device)
        state = _State(enc.robots(batch), enc.candidates(batch, real), enc.past(batch) if cfg.history else None)
        for step, layer in enumerate(self.rounds):
            state = layer(state, ctx, step, probe)
        if probe is not None:
            _probe_features(probe, "final", state.robots, state.goals, ctx)
        robots, goals = state.robots, state.goals
        if cfg.norm == "pre-ln":
            robots, goals = self.final_robot_norm(robots), self.final_goal_norm(goals)
        return self.similarity(robots, goals, ctx, batch)  # (B, R+1, C+1)


def policy_logits(log_s: Tensor, batch: GraphBatch) -> tuple[Tensor, Tensor]:
    """(logits (B, R, C), log_s): rows of log S over the allowed candidates; a robot with none gets
    logit 0 on candidate 0 and -inf elsewhere (action 0 with probability 1)."""
    nr, nc = batch.action_mask.shape[1:]
    allowed = batch.action_mask
    has = allowed.any(-1, keepdim=True)  # (B, R, 1)
    first = torch.zeros_like(allowed)
    first[..., 0] = True
    keep = torch.where(has, allowed, first)
    logits = torch.where(has, log_s[:, :nr, :nc], torch.zeros_like(log_s[:, :nr, :nc]))
    return logits.masked_fill(~keep, float("-inf")), log_s


# ---------------------------------------------------------------------------------------------- policy helpers


class ActResult(NamedTuple):
    actions: Tensor  # (B, R) int64 candidate indices (observation indices)
    log_prob: Tensor  # (B,) joint log-probability: sum of robot_log_prob
    entropy: Tensor  # (B,) sum of robot_entropy
    value: Tensor  # (B,)
    explored_ratio: Tensor  # (B,) auxiliary prediction
    robot_log_prob: Tensor  # (B, R) log pi(a_r | a_1..a_r-1) of each robot with a choice, 0 for the others
    robot_entropy: Tensor  # (B, R) entropy of each such robot's conditional distribution, 0 for the others
    has_choice: Tensor  # (B, R) bool: real robot with at least one allowed candidate


def sequential_mask(allowed: Tensor, actions: Tensor, has_choice: Tensor) -> Tensor:
    """(B, R, C) the goals robot r may draw when the robots draw in index order without replacement:
    its ``allowed`` goals less those robots 0..r-1 (with a choice) took, or all its allowed goals
    when none of them is left (more robots than goals). ``actions`` (B, R) are the draws."""
    c = allowed.shape[-1]
    took = F.one_hot(actions, c).bool() & has_choice[..., None]  # (B, R, C)
    before = (took.long().cumsum(1) - took.long()) > 0  # taken by a robot earlier in the order
    free = allowed & ~before
    return torch.where(free.any(-1, keepdim=True), free, allowed)


def log_prob_entropy(out: PolicyOutput, actions: Tensor) -> tuple[Tensor, Tensor]:
    """Per-robot log-probabilities (B, R) of ``actions`` under the sequential draw (:func:`act`) and
    per-robot entropies (B, R), 0 for robots without a choice. Their sums over robots are the
    joint log-probability and an upper bound of the joint entropy's chain-rule terms."""
    mask = sequential_mask(torch.isfinite(out.logits), actions, out.has_choice)
    log_p = torch.log_softmax(out.logits.masked_fill(~mask, float("-inf")), dim=-1)  # (B, R, C)
    picked = torch.gather(log_p, -1, actions[..., None]).squeeze(-1)  # (B, R)
    p = log_p.exp()
    per_robot = -(p * log_p.masked_fill(p == 0, 0.0)).sum(-1)  # (B, R)
    zero = torch.zeros_like(picked)
    return torch.where(out.has_choice, picked, zero), torch.where(out.has_choice, per_robot, zero)


def _result(out: PolicyOutput, actions: Tensor) -> ActResult:
    log_p, ent = log_prob_entropy(out, actions)
    return ActResult(actions, log_p.sum(-1), ent.sum(-1), out.value, out.explored_ratio, log_p, ent, out.has_choice)


def assign_goals(log_s: Tensor, action_mask: Tensor, robot_mask: Tensor) -> Tensor:
    """Evaluation-time assignment on S: the linear assignment that maximises the summed log S over
    allowed pairs, with as many robots as possible on distinct allowed goals; a robot left over (more
    robots than allowed goals) takes its own best allowed goal, and a robot with none takes 0.
    Returns (B, R) int64 on the device of ``log_s``."""
    b, nr, nc = action_mask.shape
    scores = log_s[:, :nr, :nc].detach().cpu().double().numpy()
    allowed = action_mask.cpu().numpy() & robot_mask.cpu().numpy()[:, :, None]
    out = np.zeros((b, nr), dtype=np.int64)
    for i in range(b):
        ok = allowed[i]
        if not ok.any():
            continue
        big = 1.0 + np.abs(scores[i][ok]).sum()  # more than any sum of allowed costs
        cost = np.where(ok, -scores[i], big)
        rows, cols = linear_sum_assignment(cost)
        done = np.zeros(nr, dtype=bool)
        for rr, cc in zip(rows, cols, strict=True):
            if ok[rr, cc]:
                out[i, rr], done[rr] = cc, True
        for rr in np.flatnonzero(~done & ok.any(axis=1)):
            out[i, rr] = int(np.argmax(np.where(ok[rr], scores[i, rr], -np.inf)))
    return torch.from_numpy(out).to(log_s.device)


def act(
    model: DAHGNN,
    observations: Sequence[Mapping[str, np.ndarray]] | Mapping[str, np.ndarray],
    deterministic: bool = False,
    generator: torch.Generator | Sequence[torch.Generator] | None = None,
) -> ActResult:
    """Goals for a batch of observations (no gradient): drawn from the rows of S (training), or the
    :func:`assign_goals` assignment (``deterministic``, evaluation).

    The draw is what evaluation plays, made stochastic: the robots draw in index order, each from its
    row of S over its allowed goals less those already taken (while any is left; :func:`sequential_mask`),
    so no two robots share a goal while there are enough goals, as in the assignment. The ordered
    draws' conditional log-probabilities are what PPO's ratios compare (:func:`log_prob_entropy`).

    ``generator``: one for the whole batch, or one per observation (a vectorised rollout, each
    episode with its own): each observation's goals are then drawn from its own rows and candidates
    only, so its draws do not depend on what else is in the batch (its probabilities may, in their
    last bits: batched arithmetic)."""
    device = next(model.parameters()).device
    batch = build_graph(observations, model.config.graph, device)
    with torch.no_grad():
        out = model(batch)
        if deterministic:
            actions = assign_goals(out.log_s, batch.action_mask, batch.robot_mask)
        elif generator is None or isinstance(generator, torch.Generator):
            actions = _draw(out.logits, out.has_choice, generator)
        else:
            actions = _sample_rows(out, batch, list(generator))
        return _result(out, actions)


def _draw(logits: Tensor, has_choice: Tensor, generator: torch.Generator | None) -> Tensor:
    """(B, R) goals drawn robot by robot without replacement (see :func:`act`) from ``logits`` (B, R, C)."""
    b, nr, nc = logits.shape
    actions = torch.zeros((b, nr), dtype=torch.int64, device=logits.device)
    taken = torch.zeros((b, nc), dtype=torch.bool, device=logits.device)
    for r in range(nr):
        row = logits[:, r]
        allowed = torch.isfinite(row)
        free = allowed & ~taken
        use = torch.where(free.any(-1, keepdim=True), free, allowed)
        probs = torch.softmax(row.masked_fill(~use, float("-inf")), dim=-1)
        actions[:, r] = torch.multinomial(probs, 1, generator=generator).view(-1)
        taken |= F.one_hot(actions[:, r], nc).bool() & has_choice[:, r, None]
    return actions


def _sample_rows(out: PolicyOutput, batch: GraphBatch, generators: list[torch.Generator]) -> Tensor:
    """(B, R) goals drawn for each observation of the batch with its own generator, from its own
    robots and candidates (the batch's padding cut off: the draws equal those of the observation
    alone); padded robots get candidate 0."""
    if len(generators) != out.logits.shape[0]:
        raise ValueError(f"{len(generators)} generators for a batch of {out.logits.shape[0]} observations")
    actions = torch.zeros(out.logits.shape[:2], dtype=torch.int64, device=out.logits.device)
    robots = batch.robot_mask.sum(1).tolist()
    for i, g in enumerate(generators):
        real = batch.cand_mask[i].nonzero()
        c = int(real[-1, 0]) + 1 if len(real) else 1
        r = int(robots[i])
        actions[i, :r] = _draw(out.logits[i : i + 1, :r, :c], out.has_choice[i : i + 1, :r], g)[0]
    return actions


def decide(model: DAHGNN, observations: Sequence[Mapping[str, np.ndarray]] | Mapping[str, np.ndarray]) -> Tensor:
    """Evaluation-time goals (B, R) int64 for a batch of observations: the actor (no critic) and the
    :func:`assign_goals` assignment on S. What a learned goal planner calls every decision."""
    device = next(model.parameters()).device
    batch = build_graph(observations, model.config.graph, device, critic=False)
    with torch.inference_mode():
        log_s = model.actor(batch)
    return assign_goals(log_s, batch.action_mask, batch.robot_mask)


def evaluate_actions(model: DAHGNN, batch: GraphBatch, actions: Tensor) -> ActResult:
    """PPO's re-evaluation of stored ``actions`` (B, R) on ``batch`` (with gradient)."""
    return _result(model(batch), actions)


def diagnose(model: DAHGNN, batch: GraphBatch) -> dict[str, float]:
    """Health numbers of one actor pass over ``batch`` (no gradient), as ``round<i>_*`` and ``final_*``:
    the RMS of the robot and candidate features each round reads (before its LayerNorm), the spread of
    the candidates' self-attention logits and their largest weight (1.0: one-hot attention), the share
    of saturated robot-candidate MLP-attention logits. Logged as ``health/*`` every training iteration."""
    probe: dict[str, float] = {}
    with torch.no_grad():
        model.actor(batch, probe)
    return probe


# ---------------------------------------------------------------------------------------------- files


def config_to_dict(config: NetworkConfig) -> dict[str, Any]:
    return dataclasses.asdict(config)


def config_from_dict(data: object, source: str = "config") -> NetworkConfig:
    """A validated :class:`NetworkConfig` from a dict such as :func:`config_to_dict` writes; a missing
    field takes its default, an unknown one or a value of the wrong type raises ConfigError."""
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: the network config must be a JSON object, got {type(data).__name__}")
    graph_data = data.get("graph", {})
    if not isinstance(graph_data, dict):
        raise ConfigError(f"{source}: network config field 'graph' must be an object")
    known = {f.name: f for f in dataclasses.fields(NetworkConfig)}
    graph_known = {f.name: f for f in dataclasses.fields(GraphConfig)}
    for key in data:
        if key not in known:
            raise ConfigError(f"{source}: unknown network config field {key!r}")
    for key in graph_data:
        if key not in graph_known:
            raise ConfigError(f"{source}: unknown network config field 'graph.{key}'")
    try:
        graph = GraphConfig(**graph_data).validate()
        cfg = NetworkConfig(graph=graph, **{k: v for k, v in data.items() if k != "graph"}).validate()
    except ConfigError as error:
        raise ConfigError(f"{source}: {error}") from None
    return cfg


def save_policy(path_prefix: str | Path, model: DAHGNN, config: NetworkConfig | None = None) -> tuple[Path, Path]:
    """Write ``<prefix>.safetensors`` (the weights) and ``<prefix>.json`` (format, config, tensor
    names and shapes). Returns both paths."""
    from safetensors.torch import save_file

    cfg = config or model.config
    if cfg != model.config:
        raise ConfigError("save_policy: the config differs from the model's")
    prefix = Path(path_prefix)
    weights, meta = prefix.with_name(prefix.name + ".safetensors"), prefix.with_name(prefix.name + ".json")
    tensors = {k: v.detach().to("cpu").contiguous() for k, v in model.state_dict().items()}
    save_file(tensors, str(weights), metadata={"format": FORMAT})
    doc = {
        "format": FORMAT,
        "version": FORMAT_VERSION,
        "config": config_to_dict(cfg),
        "tensors": {k: list(v.shape) for k, v in tensors.items()},
    }
    meta.write_text(json.dumps(doc, indent=1) + "\n")
    return weights, meta


MAX_POLICY_JSON_BYTES = 4 * 2**20
"""Largest policy JSON read, bytes (a six-round network's file lists its 2,245 tensors in ~110 KB)."""


def load_policy(path_prefix: str | Path, device: torch.device | str = "cpu") -> tuple[DAHGNN, NetworkConfig]:
    """Read what :func:`save_policy` wrote (never unpickles) and return (model in eval mode, config).
    Raises ConfigError, naming the file and what is wrong, for a missing, truncated or corrupted
    file, an unknown config, or tensors whose names or shapes do not match the config.

    Nothing is allocated before the files are checked: the JSON is read up to
    :data:`MAX_POLICY_JSON_BYTES` and its config validated (every size and count bounded,
    :data:`NETWORK_SIZES`); the network's tensor shapes are found on the meta device
    (:func:`network_shapes`, at most :data:`MAX_PARAMETERS`) and compared with the JSON's tensor list
    and the safetensors file's own header; only then is the network built and the weights read."""
    from safetensors import SafetensorError, safe_open
    from safetensors.torch import load_file

    from ..inputs import check_path, parse_json, read_bytes

    prefix = check_path(path_prefix, "policy weights", ConfigError)
    weights, meta = prefix.with_name(prefix.name + ".safetensors"), prefix.with_name(prefix.name + ".json")
    if not os.path.lexists(meta):
        raise ConfigError(f"{meta}: cannot read the policy config: no such file")
    data_bytes = read_bytes(meta, "policy config", MAX_POLICY_JSON_BYTES, None, ConfigError)
    doc = parse_json(data_bytes, f"{meta}: cannot read the policy config", ConfigError)
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ConfigError(f"{meta}: not a DA-HGNN policy file (format must be {FORMAT!r})")
    version = doc.get("version")
    if version not in (1, FORMAT_VERSION) or isinstance(version, bool):
        raise ConfigError(f"{meta}: format version {_short(version)}, this areasearch reads 1 and {FORMAT_VERSION}")
    data = doc.get("config")
    if version == 1 and isinstance(data, dict):
        if "norm" in data or "score_scale" in data:
            raise ConfigError(f"{meta}: a version-1 policy config cannot name norm or score_scale")
        data = {**data, "norm": "none"}  # version 1: the unnormalised rounds it was trained with
    config = config_from_dict(data, str(meta))
    expected = network_shapes(config, str(meta))
    listed = doc.get("tensors")
    if listed != expected:
        raise ConfigError(f"{meta}: tensor list does not match the config: {_mismatch(expected, listed)}")
    try:
        with safe_open(str(weights), framework="pt", device="cpu") as header:  # reads the header only
            found = {k: list(header.get_slice(k).get_shape()) for k in header.keys()}
            dtypes = {k: header.get_slice(k).get_dtype() for k in header.keys()}
    except (OSError, SafetensorError, ValueError, RuntimeError) as error:
        raise ConfigError(f"{weights}: cannot read the weights (truncated or not safetensors): {error}") from None
    if found != expected:
        raise ConfigError(f"{weights}: tensors do not match {meta.name}: {_mismatch(expected, found)}")
    for name, dtype in dtypes.items():
        if dtype != "F32":
            raise ConfigError(f"{weights}: tensor {name!r} has dtype {dtype}, expected float32")
    try:
        tensors = load_file(str(weights), device="cpu")
    except (OSError, SafetensorError, ValueError, RuntimeError) as error:
        raise ConfigError(f"{weights}: cannot read the weights (truncated or not safetensors): {error}") from None
    model = DAHGNN(config)
    for name, tensor in tensors.items():
        if tensor.dtype != model.state_dict()[name].dtype:
            raise ConfigError(f"{weights}: tensor {name!r} has dtype {tensor.dtype}, expected float32")
        if not torch.isfinite(tensor).all():
            raise ConfigError(f"{weights}: tensor {name!r} holds NaN or infinite values")
    model.load_state_dict(tensors, strict=True)
    return model.to(device).eval(), config


def _mismatch(expected: dict[str, list[int]], found: object) -> str:
    if not isinstance(found, dict):
        return "no tensor list"
    missing = sorted(set(expected) - set(found))
    extra = sorted(set(found) - set(expected))
    shapes = [f"{k} {found[k]} != {expected[k]}" for k in sorted(set(expected) & set(found)) if found[k] != expected[k]]
    parts = []
    if missing:
        parts.append(f"missing {', '.join(missing[:5])}{' ...' if len(missing) > 5 else ''}")
    if extra:
        parts.append(f"unexpected {', '.join(extra[:5])}{' ...' if len(extra) > 5 else ''}")
    if shapes:
        parts.append(f"shape {'; '.join(shapes[:5])}{' ...' if len(shapes) > 5 else ''}")
    return "; ".join(parts) or "different"
