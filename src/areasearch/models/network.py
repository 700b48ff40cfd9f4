"""The DA-HGNN network, the dual-attention heterogeneous graph network (the learned planner's actor-critic).

Implements the DA-HGNN paper's "Topological Planner" (Zhu et al., "Dual-Attention Heterogeneous
Graph Neural Network for Multi-robot Collaborative Area Search via Deep Reinforcement Learning",
eqs. 6-12) and its "Network Architecture and Hyperparameter Details" on the graphs of
:mod:`areasearch.models.graph`, with the critic and the auxiliary exploration-ratio head of "Policy
Optimization". The policy that acts with it is :mod:`areasearch.models.dahgnn`. Which class
implements what:

=====================  ==========================================================================
:class:`~areasearch.models.blocks.Encoders`
                       the graph embedding network: common encoder (5 FC -> 64-d) for frontier and
                       target nodes, special encoder (2 x 5 FC -> 32-d) for historical robot
                       positions and historical goals, distance encoder (1 FC) for the
                       robot-candidate distances; robots get an encoder of the common encoder's shape
:func:`~areasearch.models.self_attention.sparse_attention`
                       multi-head dot-product attention of a self-graph (eq. 6), heads concatenated
                       (eq. 7): G_r, G_g, G_r', G_g', the type-aware G_e and G_c (eq. 11)
:func:`~areasearch.models.cross_attention.cross_attention`
                       MLP attention of a cross-graph, logits rho([k || q || d]) per head (eq. 9): the
                       robot-goal graph G_rg both ways, G_re and G_rc (eq. 12), robots <- history
:class:`~areasearch.models.blocks.NodeUpdate`
                       h + rho_v([h || message]) (eqs. 8, 10), summed over the graphs of a node:
                       robot = self + robot-goal + robot-frontier + robot-target + history (eq. 13)
:class:`~areasearch.models.rounds.Round`
                       one of the six rounds over every graph (its docstring lists them)
:class:`Similarity`    the affinity matrix M between robots and candidates and its log-domain
                       Sinkhorn normalisation S = Sinkhorn(M) (:func:`log_sinkhorn`) with a slack
                       row and column (section "Similarity Measurement")
:class:`Critic`        embedding CNN (5 conv -> 32-d) on the observation map, 3 FC -> state value,
                       and the auxiliary exploration-ratio head (the L^Acc loss)
:class:`DAHGNN`        the actor-critic; :class:`~areasearch.models.network_config.NetworkConfig` switches
                       ``type_aware`` ("w/o type semantic") and ``history`` ("w/o history module");
                       :meth:`~areasearch.models.network_config.NetworkConfig.ncm` is the NCM baseline
                       (Ye et al., CVPR 2022) from the same modules
=====================  ==========================================================================

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

import math
from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ..errors import ConfigError
from .affinity import pair_mlp, sinkhorn
from .blocks import Encoders, NodeUpdate, mlp
from .graph import GraphBatch
from .network_config import MAX_PARAMETERS, NetworkConfig
from .rounds import Context, Round, State, build_context, padded, probe_features

_NEG = -1e4
"""Log-coupling of forbidden pairs in Sinkhorn: exp(-1e4) is 0 in float32, yet no -inf enters a
logsumexp (whose gradient would be NaN on an all -inf row)."""


def network_shapes(config: NetworkConfig, source: str = "config") -> dict[str, list[int]]:
    """The name and shape of every tensor of the network ``config`` describes, found on PyTorch's meta
    device (nothing is allocated); ConfigError naming ``source`` when it has more than
    :data:`~areasearch.models.network_config.MAX_PARAMETERS` parameters."""
    with torch.device("meta"):
        skeleton = DAHGNN(config)
    count = sum(p.numel() for p in skeleton.parameters())
    if count > MAX_PARAMETERS:
        raise ConfigError(f"{source}: the network has {count:,} parameters, more than the limit of {MAX_PARAMETERS:,}")
    return {k: list(v.shape) for k, v in skeleton.state_dict().items()}


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

    def forward(self, r: Tensor, g: Tensor, ctx: Context, batch: GraphBatch) -> Tensor:
        affinity = pair_mlp(  # on the pairs the action mask allows: the affinity of another is never read
            F.linear(ctx.pair_edges, self.edge.weight), ctx.similarity_rows, self.robot(r),
            padded(self.candidate(g), ctx), self.score.weight, self.score.bias,
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
        a dict that receives the health numbers of this pass (:func:`~areasearch.models.dahgnn.diagnose`)."""
        cfg, enc = self.config, self.encoders
        ctx = build_context(cfg, enc, batch)
        real = ctx.real if ctx.real is not None else torch.arange(ctx.b * ctx.c, device=batch.cand_mask.device)
        state = State(enc.robots(batch), enc.candidates(batch, real), enc.past(batch) if cfg.history else None)
        for step, layer in enumerate(self.rounds):
            state = layer(state, ctx, step, probe)
        if probe is not None:
            probe_features(probe, "final", state.robots, state.goals, ctx)
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
