"""Pipeline stage "planner" (learned): DA-HGNN, the dual-attention heterogeneous graph network.

Implements the paper's "Topological Planner" (paper/da-hgnn.tex, eqs. 6-12) and its "Network
Architecture and Hyperparameter Details" on the graphs of :mod:`areasearch.graph`, with the critic
and the auxiliary exploration-ratio head of "Policy Optimization". Which class implements what:

=====================  ==========================================================================
:class:`Encoders`      the graph embedding network: common encoder (5 FC -> 64-d) for frontier and
                       target nodes, special encoder (2 x 5 FC -> 32-d) for historical robot
                       positions and historical goals, distance encoder (1 FC) for the
                       robot-candidate distances; robots get an encoder of the common encoder's shape
:func:`attend`         multi-head dot-product attention of a self-graph (eq. 6), heads concatenated
                       (eq. 7): G_r, G_g, G_r', G_g', the type-aware G_e and G_c (eq. 11)
:func:`pair_attend`    MLP attention of a cross-graph, logits rho([k || q || d]) per head (eq. 9): the
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

**Policy.** Robot r's action is a candidate index. Its distribution is a categorical over the
candidates ``action_mask[r]`` allows, with probabilities proportional to row r of S (``logits =
log S[r, :C]``, masked to -inf where not allowed; the slack column, "no match", is dropped). Robots
are sampled independently given S; the coordination lives in S, whose columns share one unit of
mass among the robots. Joint log-probability = sum over the robots that have an allowed candidate;
entropy = sum of the per-robot entropies. A robot with no allowed candidate (or a padded one) takes
action 0 with probability 1 and adds nothing. For evaluation, :func:`assign_goals` solves the
linear assignment on log S: no two robots share a goal while there are enough allowed goals (the
paper's "argmax on each row and column").

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
  :mod:`areasearch.graph`) plus what the observation says of the node; the paper's "7 x 64" map
  embedding is read as this per-node encoding.
* Widths are the paper's (64-d nodes, 32-d history, six rounds); heads, the attention hidden layer
  and the update MLPs are not in the paper.

Axes: B batch, R robots, C candidates, N history nodes, K key nodes, Q query nodes, D width,
E edge width, A attention hidden width, M heads.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import torch
import torch.nn.functional as F
from scipy.optimize import linear_sum_assignment
from torch import Tensor, nn

from .errors import ConfigError
from .graph import GraphBatch, GraphConfig, build_graph, scaled_distance

FORMAT = "areasearch.dahgnn"
"""``format`` entry of a saved policy's JSON file."""
FORMAT_VERSION = 1

_NEG = -1e4
"""Log-coupling of forbidden pairs in Sinkhorn: exp(-1e4) is 0 in float32, yet no -inf enters a
logsumexp (whose gradient would be NaN on an all -inf row)."""


@dataclass(frozen=True)
class NetworkConfig:
    """The DA-HGNN actor-critic. Widths are the paper's where it gives them."""

    graph: GraphConfig = field(default_factory=GraphConfig)
    """How observations become node and edge features."""
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
    """Fully connected layers of the common and special encoders (paper: 5)."""
    heads: int = 4
    """Attention heads of every graph."""
    attention_hidden: int = 32
    """Hidden width of the MLP attention of the cross-graphs (eq. 9) and of the affinity MLP."""
    edge_dim: int = 16
    """Output width of the distance encoder (one FC layer + ReLU)."""
    update_hidden: int = 64
    """Hidden width of the update MLPs rho_v (eqs. 8, 10)."""
    sinkhorn_iters: int = 10
    """Log-domain Sinkhorn iterations of the similarity measurement."""
    critic_channels: int = 32
    """Channels of the critic's CNN; its output embedding has this width (paper: 32-d)."""
    critic_hidden: int = 64
    """Hidden width of the critic's 3 FC layers and of the auxiliary head."""

    def validate(self) -> NetworkConfig:
        self.graph.validate()
        for name in ("rounds", "node_dim", "history_dim", "encoder_layers", "heads", "attention_hidden"):
            _positive_int(name, getattr(self, name))
        for name in ("edge_dim", "update_hidden", "sinkhorn_iters", "critic_channels", "critic_hidden"):
            _positive_int(name, getattr(self, name))
        for name in ("type_aware", "history"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"network.{name} must be true or false, got {getattr(self, name)!r}")
        for name in ("node_dim", "history_dim"):
            if getattr(self, name) % self.heads:
                raise ConfigError(f"network.{name} ({getattr(self, name)}) must be a multiple of heads ({self.heads})")
        return self

    @classmethod
    def ncm(cls, **changes: Any) -> NetworkConfig:
        """The NCM baseline (Ye et al., CVPR 2022, "Multi-robot active mapping via neural bipartite graph
        matching") from the same modules: no type distinction (targets are plain candidates), history
        nodes, three rounds of self/cross attention, 32-d features as in its code, nodes encoded from
        their position and observation scalars only (no map crop), Sinkhorn bipartite matching."""
        base = cls(
            graph=GraphConfig(patch_cells=0),
            type_aware=False,
            history=True,
            rounds=3,
            node_dim=32,
            history_dim=32,
        )
        return dataclasses.replace(base, **changes).validate()


def _positive_int(name: str, value: object) -> None:
    if not isinstance(value, int) or isinstance(value, bool) or value < 1:
        raise ConfigError(f"network.{name} must be a positive integer, got {value!r}")


# ---------------------------------------------------------------------------------------------- building blocks


def mlp(sizes: Sequence[int]) -> nn.Sequential:
    """Fully connected layers with ReLU between them (none after the last)."""
    layers: list[nn.Module] = []
    for i, (a, b) in enumerate(itertools.pairwise(sizes)):
        layers.append(nn.Linear(a, b))
        if i < len(sizes) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


def masked_softmax(logits: Tensor, mask: Tensor, dim: int) -> Tensor:
    """Softmax over ``dim`` where ``mask``; exactly 0 elsewhere, and all 0 on a row with nothing allowed
    (no NaN in the forward or the backward pass)."""
    filled = logits.masked_fill(~mask, torch.finfo(logits.dtype).min)
    return torch.softmax(filled, dim=dim) * mask


class Graph(NamedTuple):
    """Which nodes a dot-product graph connects, prepared once per forward for :func:`attend`."""

    allowed: Tensor  # (B, 1, Q, K) bool: the edges; a query with none may attend everywhere (then zeroed)
    has: Tensor  # (B, Q, 1) float: 1 where the query node has an edge

    @staticmethod
    def of(mask: Tensor) -> Graph:
        has = mask.any(-1, keepdim=True)  # (B, Q, 1)
        return Graph((mask | ~has)[:, None], has.to(torch.get_default_dtype()))


def attend(qkv: Tensor, graph: Graph, heads: int, kv: Tensor | None = None) -> Tensor:
    """Multi-head scaled dot-product attention (eq. 6), heads concatenated (eq. 7): the message
    sum_u W_iu h_u of each query node. ``qkv`` (B, Q, 3D) holds queries, keys and values of one node
    set (a self-graph); or ``qkv`` (B, Q, D) the queries and ``kv`` (B, K, 2D) the keys and values of
    another. A query with no edge gets 0. Returns (B, Q, D)."""
    b, nq = qkv.shape[:2]
    if kv is None:
        q, k, v = qkv.view(b, nq, 3, heads, -1).permute(2, 0, 3, 1, 4)  # (B, M, Q, D/M) each
    else:
        q = qkv.view(b, nq, heads, -1).transpose(1, 2)
        k, v = kv.view(b, kv.shape[1], 2, heads, -1).permute(2, 0, 3, 1, 4)
    out = F.scaled_dot_product_attention(q, k, v, attn_mask=graph.allowed)  # (B, M, Q, D/M)
    return out.transpose(1, 2).flatten(2) * graph.has  # (B, Q, D)


def pair_attend(logits: Tensor, mask: Tensor, values: Tensor, dim: int) -> Tensor:
    """Messages of MLP-attention cross-graphs (eq. 9) from pair logits (B, P, Q, X, M) of X relations
    that share a hidden layer: with ``dim`` = 2 the P nodes attend to the Q nodes, with ``dim`` = 1
    the Q nodes to the P nodes. mask (B, P, Q, X); values (B, K, X, D) of the attended nodes per
    relation. Returns (X, B, receivers, D), heads concatenated (eq. 7)."""
    w = masked_softmax(logits, mask[..., None], dim)  # (B, P, Q, X, M)
    v = values.unflatten(-1, (logits.shape[-1], -1))  # (B, K, X, M, D/M)
    if dim == 2:
        return torch.einsum("bpqxm,bqxmd->xbpmd", w, v).flatten(3)
    return torch.einsum("bpqxm,bpxmd->xbqmd", w, v).flatten(3)


def by_kind(x: Tensor, kind: Tensor, kinds: int) -> Tensor:
    """(..., kinds * D) -> (..., D): the slice of each node's kind (one weight per kind)."""
    if kinds == 1:
        return x
    x = x.unflatten(-1, (kinds, -1))  # (..., kinds, D)
    return torch.gather(x, -2, kind[..., None, None].expand(*kind.shape, 1, x.shape[-1])).squeeze(-2)


class Projections(nn.Module):
    """One linear map of a node set's features into the named queries, keys, values and MLP-attention
    parts that a round's graphs need from it (one matrix product instead of one per graph)."""

    def __init__(self, dim: int, parts: Mapping[str, int]) -> None:
        super().__init__()
        self.names, self.sizes = list(parts), list(parts.values())
        self.linear = nn.Linear(dim, sum(self.sizes))

    def forward(self, h: Tensor) -> dict[str, Tensor]:
        return dict(zip(self.names, self.linear(h).split(self.sizes, dim=-1), strict=True))


class NodeUpdate(nn.Module):
    """Eqs. 8, 10 and 13 for one node set: h <- h + sum over the node's graphs g of rho_v^g([h || m_g]),
    each rho_v^g a two-layer MLP of its own (computed as one batched product over the graphs)."""

    def __init__(self, dim: int, graphs: int, hidden: int) -> None:
        super().__init__()
        self.w_h = nn.Parameter(torch.empty(dim, graphs * hidden))  # the h half of every first layer
        self.w_m = nn.Parameter(torch.empty(graphs, dim, hidden))  # the message half
        self.b1 = nn.Parameter(torch.zeros(graphs * hidden))
        self.w2 = nn.Parameter(torch.empty(graphs, hidden, dim))
        self.b2 = nn.Parameter(torch.zeros(dim))
        self.graphs, self.hidden = graphs, hidden
        self.reset_parameters()

    def reset_parameters(self) -> None:
        """Orthogonal, gain sqrt 2 into the hidden layer and 0.1 out of it: six rounds of residual sums
        of several graphs stay in scale at the start."""
        w1 = torch.empty(self.graphs, 2 * self.w_h.shape[0], self.hidden)
        for i in range(self.graphs):
            nn.init.orthogonal_(w1[i], math.sqrt(2))
            nn.init.orthogonal_(self.w2.data[i], 0.1)
        with torch.no_grad():
            d = self.w_h.shape[0]
            self.w_h.copy_(w1[:, :d].permute(1, 0, 2).reshape(d, -1))
            self.w_m.copy_(w1[:, d:])

    def forward(self, h: Tensor, messages: Tensor, mask: Tensor) -> Tensor:
        """h (B, N, D), messages (graphs, B, N, D) -> (B, N, D)."""
        b, n, d = h.shape
        own = torch.addmm(self.b1, h.reshape(b * n, d), self.w_h).view(b * n, self.graphs, -1).transpose(0, 1)
        z = torch.relu(torch.baddbmm(own, messages.reshape(self.graphs, b * n, d), self.w_m))  # (graphs, B*N, hidden)
        delta = torch.bmm(z, self.w2).sum(0) + self.b2  # (B*N, D)  eq. 13: the graphs' terms summed
        return h + delta.view(b, n, d) * mask[..., None]


# ---------------------------------------------------------------------------------------------- the network


class Encoders(nn.Module):
    """The graph embedding network ("Network Architecture and Hyperparameter Details"): node features
    of :mod:`areasearch.graph` -> initial node features, and distances -> edge features."""

    def __init__(self, cfg: NetworkConfig) -> None:
        super().__init__()
        g, d, layers = cfg.graph, cfg.node_dim, cfg.encoder_layers
        kinds = 2 if cfg.type_aware else 0  # the kind, one-hot, is an input only with type awareness
        self.robot = mlp([g.robot_features] + [d] * layers)
        self.common = mlp([g.candidate_features + kinds] + [d] * layers)  # frontier and target nodes
        self.distance = nn.Linear(2, cfg.edge_dim)  # [d / (d + scale), unreachable]
        if cfg.history:
            self.past_robot = mlp([g.history_features] + [cfg.history_dim] * layers)  # special encoder, twice
            self.past_goal = mlp([g.history_features] + [cfg.history_dim] * layers)
            self.past_distance = nn.Linear(1, cfg.edge_dim)  # Euclidean distances of history edges
        self.type_aware = cfg.type_aware

    def candidates(self, batch: GraphBatch) -> Tensor:
        x = batch.cand_x
        if self.type_aware:
            x = torch.cat([x, F.one_hot(batch.cand_kind, 2).to(x.dtype)], dim=-1)
        return self.common(x) * batch.cand_mask[..., None]  # (B, C, D)

    def geodesic(self, batch: GraphBatch) -> Tensor:
        x = torch.stack([batch.dist, (~batch.reachable).to(batch.dist.dtype)], dim=-1)  # (B, R, C, 2)
        return torch.relu(self.distance(x))  # (B, R, C, E)

    def euclidean(self, a: Tensor, b: Tensor, scale_m: float) -> Tensor:
        d = torch.cdist(a, b)  # (B, P, Q) metres
        return torch.relu(self.past_distance(scaled_distance(d, scale_m)[..., None]))  # (B, P, Q, E)


class _State(NamedTuple):
    robots: Tensor  # (B, R, D)
    goals: Tensor  # (B, C, D)
    past_robots: Tensor | None  # (B, N, Dh)
    past_goals: Tensor | None  # (B, N, Dh)


class _Masks(NamedTuple):
    """Which nodes each graph connects (computed once per forward)."""

    robots: Graph  # G_r
    goals: Graph  # G_g
    same_kind: Graph | None  # G_e and G_c
    to_goals: Tensor  # (B, R, C, X) robots <- candidates: G_rg [, G_re, G_rc]
    from_robots: Tensor  # (B, R, C, 1) candidates <- robots: G_rg
    to_past: Tensor | None  # (B, R, 2N, 2) robots <- historical robots, robots <- historical goals
    goal_past_robot: Graph | None  # G_r'e, G_r'c (or G_r'g)
    past_robots: Graph | None  # G_r'
    past_goals: Graph | None  # G_g'

    @staticmethod
    def of(batch: GraphBatch, type_aware: bool, history: bool) -> _Masks:
        r, g, kind = batch.robot_mask, batch.cand_mask, batch.cand_kind
        pair = r[:, :, None] & g[:, None, :]  # (B, R, C)
        goals = _square(g)
        same_kind = Graph.of(goals & (kind[:, :, None] == kind[:, None, :])) if type_aware else None
        frontier = (kind == 0)[:, None, :]
        to_goals = torch.stack([pair, pair & frontier, pair & ~frontier], -1) if type_aware else pair[..., None]
        past: tuple[Tensor | Graph | None, ...] = (None,) * 4
        if history:
            p, q = batch.past_robot_mask, batch.past_goal_mask
            none = torch.zeros_like(p)
            to_past = torch.stack([torch.cat([p, none], 1), torch.cat([none, q], 1)], -1)  # (B, 2N, 2)
            past = (
                r[:, :, None, None] & to_past[:, None],
                Graph.of(g[:, :, None] & p[:, None]),
                Graph.of(_square(p)),
                Graph.of(_square(q)),
            )
        return _Masks(Graph.of(_square(r)), Graph.of(goals), same_kind, to_goals, pair[..., None], *past)  # type: ignore[arg-type]


class _Edges(NamedTuple):
    robot_goal: Tensor  # (B, R, C, E) geodesic distances
    robot_past: Tensor | None  # (B, R, 2N, E) Euclidean distances to historical robots, then historical goals


class Round(nn.Module):
    """One round of attention over every graph (all messages read the features of the previous round).

    * eqs. 6-8: self-graphs G_r (robots), G_g (candidates), G_r', G_g' (historical robots, goals);
    * eqs. 9-10: the robot-goal cross-graph G_rg both ways, MLP attention over [robot || candidate ||
      distance]; with type awareness G_re and G_rc (eq. 12: robots <- frontiers, robots <- targets)
      read the same hidden layer with logits, values and updates of their own;
    * eq. 11: the type-aware self-graphs G_e and G_c: dot-product attention among candidates of the
      same kind (one projection, shared by both: the graphs share no edge);
    * history: robots <- historical robots and <- historical goals (the h_rr' and h_r* terms of eq. 13)
      by MLP attention with Euclidean distances (one hidden layer, logits of their own); candidates <-
      historical robots (G_r'e and G_r'c, a query projection per kind; G_r'g without type awareness)
      by dot-product attention;
    * eq. 13: each node set adds the sum of its graphs' rho_v terms (:class:`NodeUpdate`).
    """

    def __init__(self, cfg: NetworkConfig, last: bool = False) -> None:
        super().__init__()
        d, dh, a, e, m = cfg.node_dim, cfg.history_dim, cfg.attention_hidden, cfg.edge_dim, cfg.heads
        self.heads, self.type_aware, self.history = m, cfg.type_aware, cfg.history
        self.kinds = 2 if cfg.type_aware else 1
        self.robot_proj = Projections(d, {"qkv": 3 * d, "pair": a, "value": d})  # G_r, G_rg
        self.goal_proj = Projections(d, {"qkv": 3 * d, "pair": a, "value": d})  # G_g, G_rg
        self.pair_edge = nn.Linear(e, a, bias=False)  # distance part of eq. 9's MLP
        to_goals = 3 if cfg.type_aware else 1  # G_rg robots <- candidates [, G_re, G_rc]
        self.pair_logits = nn.Linear(a, (to_goals + 1) * m)  # the last: G_rg candidates <- robots
        if cfg.type_aware:
            self.typed_proj = Projections(d, {"qkv": 3 * d, "values": 2 * d})  # G_e, G_c; G_re, G_rc values
        self.update_past = cfg.history and not last  # history features after the last round are not read
        if cfg.history:
            own = {"qkv": 3 * dh} if self.update_past else {}
            self.past_robot_proj = Projections(dh, {**own, "pair": a, "value": d, "kv": 2 * d})
            self.past_goal_proj = Projections(dh, {**own, "pair": a, "value": d})
            self.robot_past_query = nn.Linear(d, a)  # robot part of the MLP attention to history nodes
            self.goal_past_query = nn.Linear(d, self.kinds * d)  # G_r'e, G_r'c queries (one per kind)
            self.past_edge = nn.Linear(e, a, bias=False)
            self.past_logits = nn.Linear(a, 2 * m)  # robots <- historical robots, <- historical goals
        if self.update_past:
            self.past_robot_update = NodeUpdate(dh, 1, cfg.update_hidden)
            self.past_goal_update = NodeUpdate(dh, 1, cfg.update_hidden)
        robot_graphs = 2 + 2 * cfg.type_aware + 2 * cfg.history
        goal_graphs = 2 + cfg.type_aware + cfg.history
        self.robot_update = NodeUpdate(d, robot_graphs, cfg.update_hidden)
        self.goal_update = NodeUpdate(d, goal_graphs, cfg.update_hidden)

    def forward(self, state: _State, batch: GraphBatch, masks: _Masks, edges: _Edges) -> _State:
        r, g, pr, pg = state
        m = self.heads
        b, nr, _ = r.shape
        nc = g.shape[1]
        rp, gp = self.robot_proj(r), self.goal_proj(g)
        to_r = [attend(rp["qkv"], masks.robots, m)[None]]  # G_r, eqs. 6-7
        to_g = [attend(gp["qkv"], masks.goals, m)[None]]  # G_g

        # eq. 9: one hidden layer over the robot-candidate pairs, logits per relation and head
        z = torch.relu(rp["pair"][:, :, None] + gp["pair"][:, None] + self.pair_edge(edges.robot_goal))  # (B,R,C,A)
        logits = self.pair_logits(z).view(b, nr, nc, -1, m)  # (B, R, C, X + 1, M)
        values = gp["value"][:, :, None]  # (B, C, 1, D)
        if self.type_aware:
            assert masks.same_kind is not None
            tp = self.typed_proj(g)
            to_g.append(attend(tp["qkv"], masks.same_kind, m)[None])  # G_e, G_c (eq. 11)
            values = torch.cat([values, tp["values"].unflatten(-1, (2, -1))], dim=2)  # (B, C, 3, D)
        to_r.append(pair_attend(logits[:, :, :, :-1], masks.to_goals, values, dim=2))  # G_rg [, G_re, G_rc]
        to_g.append(pair_attend(logits[:, :, :, -1:], masks.from_robots, rp["value"][:, :, None], dim=1))  # G_rg

        if self.history:
            assert pr is not None and pg is not None and edges.robot_past is not None and masks.to_past is not None
            assert masks.goal_past_robot is not None and masks.past_robots is not None and masks.past_goals is not None
            pp, qp = self.past_robot_proj(pr), self.past_goal_proj(pg)
            keys = torch.cat([pp["pair"], qp["pair"]], dim=1)  # (B, 2N, A)
            z = torch.relu(self.robot_past_query(r)[:, :, None] + keys[:, None] + self.past_edge(edges.robot_past))
            logits = self.past_logits(z).unflatten(-1, (2, m))  # (B, R, 2N, 2, M)
            past_values = torch.cat([pp["value"], qp["value"]], dim=1)[:, :, None].expand(-1, -1, 2, -1)  # (B,2N,2,D)
            to_r.append(pair_attend(logits, masks.to_past, past_values, dim=2))  # h_rr', h_r* of eq. 13
            query = by_kind(self.goal_past_query(g), batch.cand_kind, self.kinds)  # (B, C, D)
            to_g.append(attend(query, masks.goal_past_robot, m, kv=pp["kv"])[None])  # G_r'e, G_r'c
            if self.update_past:
                pr = self.past_robot_update(pr, attend(pp["qkv"], masks.past_robots, m)[None], batch.past_robot_mask)
                pg = self.past_goal_update(pg, attend(qp["qkv"], masks.past_goals, m)[None], batch.past_goal_mask)
        r = self.robot_update(r, torch.cat(to_r), batch.robot_mask)
        return _State(r, self.goal_update(g, torch.cat(to_g), batch.cand_mask), pr, pg)


def _square(mask: Tensor) -> Tensor:
    return mask[:, :, None] & mask[:, None, :]


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
    one = scores.new_zeros(())
    log_mu = torch.where(row_mask, one, one + _NEG)  # (B, R) log marginals: 1 per real row
    log_nu = torch.where(col_mask, one, one + _NEG)  # (B, C)
    if slack is not None:
        m = row_mask.sum(-1, keepdim=True).to(scores.dtype)  # (B, 1) real robots
        n = col_mask.sum(-1, keepdim=True).to(scores.dtype)  # (B, 1) real candidates
        col = torch.where(row_mask, slack, one + _NEG)[:, :, None]  # (B, R, 1)
        row = torch.cat([torch.where(col_mask, slack, one + _NEG), slack.expand(b, 1)], dim=-1)[:, None]  # (B, 1, C+1)
        z = torch.cat([torch.cat([z, col], dim=-1), row], dim=1)  # (B, R+1, C+1)
        log_mu = torch.cat([log_mu, torch.where(n > 0, n.clamp(min=1).log(), one + _NEG)], dim=-1)  # slack row: n
        log_nu = torch.cat([log_nu, torch.where(m > 0, m.clamp(min=1).log(), one + _NEG)], dim=-1)  # slack col: m
    rows_on = log_mu > _NEG / 2  # (B, R[+1])
    cols_on = log_nu > _NEG / 2
    u = torch.zeros_like(log_mu)
    v = torch.zeros_like(log_nu)
    for _ in range(iters):
        u = torch.where(rows_on, log_mu - torch.logsumexp(z + v[:, None, :], dim=2), one + _NEG)
        v = torch.where(cols_on, log_nu - torch.logsumexp(z + u[:, :, None], dim=1), one + _NEG)
    return z + u[:, :, None] + v[:, None, :]


class Similarity(nn.Module):
    """Similarity measurement: affinity M_ij = rho_s([W r_i || W g_j || e_ij]) between robot i and
    candidate j (an MLP with the distance features, as eq. 9), S = Sinkhorn(M) with a learned slack
    score, over the pairs the action mask allows."""

    def __init__(self, dim: int, edge_dim: int, hidden: int, iters: int) -> None:
        super().__init__()
        self.robot = nn.Linear(dim, hidden)
        self.candidate = nn.Linear(dim, hidden, bias=False)
        self.edge = nn.Linear(edge_dim, hidden, bias=False)
        self.score = nn.Linear(hidden, 1)
        self.slack = nn.Parameter(torch.tensor(1.0))
        self.iters = iters

    def forward(self, r: Tensor, g: Tensor, edge: Tensor, batch: GraphBatch) -> Tensor:
        z = torch.relu(self.robot(r)[:, :, None] + self.candidate(g)[:, None] + self.edge(edge))  # (B, R, C, A)
        affinity = self.score(z).squeeze(-1)  # (B, R, C)  M
        return log_sinkhorn(affinity, batch.action_mask, batch.robot_mask, batch.cand_mask, self.slack, self.iters)


class Critic(nn.Module):
    """Embedding CNN (5 conv layers -> 32-d, global average pooled, so any map side works) on the
    7-channel observation map, then 3 FC layers -> state value ("Network Architecture"). The progress
    (steps / horizon) joins the embedding: the value of a state depends on the time left. The
    auxiliary head (2 FC, sigmoid) predicts the explored ratio from the same embedding (L^Acc)."""

    def __init__(self, channels: int, hidden: int) -> None:
        super().__init__()
        c = channels
        self.embed = nn.Sequential(
            nn.MaxPool2d(2),  # S/2: halves the cost of the whole CNN; thin frontier lines survive max-pooling
            nn.Conv2d(7, c // 2, kernel_size=4, stride=4),  # S/8 (the first layer patchifies)
            nn.ReLU(),
            nn.Conv2d(c // 2, c, kernel_size=3, stride=2, padding=1),  # S/16
            nn.ReLU(),
            nn.Conv2d(c, c, kernel_size=3, stride=2, padding=1),  # S/32
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
        self.similarity = Similarity(cfg.node_dim, cfg.edge_dim, cfg.attention_hidden, cfg.sinkhorn_iters)
        self.critic = Critic(cfg.critic_channels, cfg.critic_hidden)
        self.reset_parameters()

    def reset_parameters(self) -> None:
        """Orthogonal initialisation (gain sqrt 2, zero biases; the update MLPs see
        :meth:`NodeUpdate.reset_parameters`), the affinity score at gain 0.01 (a near-uniform first
        policy), the value output at 1."""
        for module in self.modules():
            if isinstance(module, (nn.Linear, nn.Conv2d)):
                nn.init.orthogonal_(module.weight, math.sqrt(2))
                if module.bias is not None:
                    nn.init.zeros_(module.bias)
            elif isinstance(module, NodeUpdate):
                module.reset_parameters()
        nn.init.orthogonal_(self.similarity.score.weight, 0.01)
        value_out = self.critic.value[-1]
        assert isinstance(value_out, nn.Linear)
        nn.init.orthogonal_(value_out.weight, 1.0)

    def forward(self, batch: GraphBatch) -> PolicyOutput:
        """Actor and critic on a batch of graphs."""
        log_s = self.actor(batch)
        value, explored = self.critic(batch.map, batch.progress)
        return PolicyOutput(*policy_logits(log_s, batch), value, explored, batch.action_mask.any(-1) & batch.robot_mask)

    def actor(self, batch: GraphBatch) -> Tensor:
        """The topological planner alone: log S (B, R+1, C+1), slack row and column last."""
        cfg, enc = self.config, self.encoders
        scale = cfg.graph.distance_scale_m
        r = enc.robot(batch.robot_x) * batch.robot_mask[..., None]  # (B, R, D)
        g = enc.candidates(batch)  # (B, C, D)
        geodesic = enc.geodesic(batch)  # (B, R, C, E)
        if cfg.history:
            pr = enc.past_robot(batch.past_robot_x) * batch.past_robot_mask[..., None]  # (B, N, Dh)
            pg = enc.past_goal(batch.past_goal_x) * batch.past_goal_mask[..., None]  # (B, N, Dh)
            past_xy = torch.cat([batch.past_robot_xy, batch.past_goal_xy], dim=1)  # (B, 2N, 2)
            edges = _Edges(geodesic, enc.euclidean(batch.robot_xy, past_xy, scale))
            state = _State(r, g, pr, pg)
        else:
            edges = _Edges(geodesic, None)
            state = _State(r, g, None, None)
        masks = _Masks.of(batch, cfg.type_aware, cfg.history)
        for layer in self.rounds:
            state = layer(state, batch, masks, edges)
        return self.similarity(state.robots, state.goals, geodesic, batch)  # (B, R+1, C+1)


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
    log_prob: Tensor  # (B,) joint log-probability: sum over robots with a choice
    entropy: Tensor  # (B,) sum of the per-robot entropies
    value: Tensor  # (B,)
    explored_ratio: Tensor  # (B,) auxiliary prediction


def log_prob_entropy(out: PolicyOutput, actions: Tensor) -> tuple[Tensor, Tensor]:
    """Joint log-probability of ``actions`` (B, R) and joint entropy, both (B,)."""
    log_p = torch.log_softmax(out.logits, dim=-1)  # (B, R, C)
    picked = torch.gather(log_p, -1, actions[..., None]).squeeze(-1)  # (B, R)
    p = log_p.exp()
    per_robot = -(p * log_p.masked_fill(p == 0, 0.0)).sum(-1)  # (B, R)
    zero = torch.zeros_like(picked)
    return torch.where(out.has_choice, picked, zero).sum(-1), torch.where(out.has_choice, per_robot, zero).sum(-1)


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
    generator: torch.Generator | None = None,
) -> ActResult:
    """Goals for a batch of observations (no gradient): sampled from the per-robot categoricals of S
    (training), or the :func:`assign_goals` assignment (``deterministic``, evaluation)."""
    device = next(model.parameters()).device
    batch = build_graph(observations, model.config.graph, device)
    with torch.no_grad():
        out = model(batch)
        if deterministic:
            actions = assign_goals(out.log_s, batch.action_mask, batch.robot_mask)
        else:
            probs = torch.softmax(out.logits, dim=-1)  # (B, R, C)
            flat = torch.multinomial(probs.flatten(0, 1), 1, generator=generator)  # (B * R, 1)
            actions = flat.view(probs.shape[:2])
        log_prob, entropy = log_prob_entropy(out, actions)
    return ActResult(actions, log_prob, entropy, out.value, out.explored_ratio)


def decide(model: DAHGNN, observations: Sequence[Mapping[str, np.ndarray]] | Mapping[str, np.ndarray]) -> Tensor:
    """Evaluation-time goals (B, R) int64 for a batch of observations: the actor (no critic) and the
    :func:`assign_goals` assignment on S. What a learned goal planner calls every decision."""
    device = next(model.parameters()).device
    batch = build_graph(observations, model.config.graph, device)
    with torch.inference_mode():
        log_s = model.actor(batch)
    return assign_goals(log_s, batch.action_mask, batch.robot_mask)


def evaluate_actions(model: DAHGNN, batch: GraphBatch, actions: Tensor) -> ActResult:
    """PPO's re-evaluation of stored ``actions`` (B, R) on ``batch`` (with gradient)."""
    out = model(batch)
    log_prob, entropy = log_prob_entropy(out, actions)
    return ActResult(actions, log_prob, entropy, out.value, out.explored_ratio)


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


def load_policy(path_prefix: str | Path, device: torch.device | str = "cpu") -> tuple[DAHGNN, NetworkConfig]:
    """Read what :func:`save_policy` wrote (never unpickles) and return (model in eval mode, config).
    Raises ConfigError, naming the file and what is wrong, for a missing, truncated or corrupted
    file, an unknown config, or tensors whose names or shapes do not match the config."""
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    prefix = Path(path_prefix)
    weights, meta = prefix.with_name(prefix.name + ".safetensors"), prefix.with_name(prefix.name + ".json")
    try:
        doc = json.loads(meta.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ConfigError(f"{meta}: cannot read the policy config: {error}") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ConfigError(f"{meta}: not a DA-HGNN policy file (format must be {FORMAT!r})")
    if doc.get("version") != FORMAT_VERSION:
        raise ConfigError(f"{meta}: format version {doc.get('version')!r}, this areasearch reads {FORMAT_VERSION}")
    config = config_from_dict(doc.get("config"), str(meta))
    model = DAHGNN(config)
    expected = {k: list(v.shape) for k, v in model.state_dict().items()}
    listed = doc.get("tensors")
    if listed != expected:
        raise ConfigError(f"{meta}: tensor list does not match the config: {_mismatch(expected, listed)}")
    try:
        tensors = load_file(str(weights), device="cpu")
    except (OSError, SafetensorError, ValueError, RuntimeError) as error:
        raise ConfigError(f"{weights}: cannot read the weights (truncated or not safetensors): {error}") from None
    found = {k: list(v.shape) for k, v in tensors.items()}
    if found != expected:
        raise ConfigError(f"{weights}: tensors do not match {meta.name}: {_mismatch(expected, found)}")
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
