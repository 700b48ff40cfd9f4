"""The DA-HGNN network's configuration: :class:`NetworkConfig` (the paper's widths, its ablation switches
and the NCM preset), the bounds a config read from a file must keep (:data:`NETWORK_SIZES`,
:data:`NETWORK_SCALES`, :data:`MAX_PARAMETERS`) and its dict form (:func:`config_to_dict`,
:func:`config_from_dict`), which policy files and training configs carry.

A config is checked (:meth:`NetworkConfig.validate`) before any network is built from it: the network
itself is :class:`areasearch.models.network.DAHGNN`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

from ..errors import ConfigError
from .graph import GraphConfig

NORMS = ("pre-ln", "none")
"""Values of :attr:`NetworkConfig.norm`."""


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
    """Hidden width of a node set's update MLP rho_v (eqs. 8, 10, 13; see
    :class:`~areasearch.models.blocks.NodeUpdate`)."""
    sinkhorn_iters: int = 10
    """Log-domain Sinkhorn iterations of the similarity measurement."""
    norm: str = "pre-ln"
    """Normalisation in the rounds. ``pre-ln``: every round reads its node features through a
    LayerNorm (the residual stream itself is not normalised: pre-LN, Xiong et al. 2020), the final
    features pass a LayerNorm before the similarity measurement, and the dot-product scores are
    cosine similarities of the queries and keys times ``score_scale`` (query-key normalisation,
    Henry et al. 2020), so no score can grow without bound. ``none``: unnormalised rounds (the
    network of policy files of format version 1), whose features and scores grew by
    orders of magnitude during training (docs/dahgnn.md#normalisation)."""
    score_scale: float = 4.0
    """With ``norm = "pre-ln"``: the dot-product scores are cos(q, k) * this, in [-4, 4], so one
    neighbour weighs at most e^8 ~ 3,000 times another (one-hot attention, whose gradient vanishes,
    cannot form)."""
    distance_prior: float = 8.0
    """Initial weight beta of the distance prior of the affinity, M_ij - beta * dist_ij with dist_ij
    = d / (d + distance_scale_m) the scaled geodesic distance (beta = softplus of a learned parameter).
    The first policy is then a coordinated soft nearest-goal assignment that PPO refines, instead of
    a uniform one (not in the paper; see :class:`~areasearch.models.network.Similarity`). 0: no prior
    (the paper's affinity)."""
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
                raise ConfigError(f"network.{key} must be an integer from {low} to {high:,}, got {short_repr(value)}")
        for key, bound in NETWORK_SCALES.items():
            value = getattr(self.graph, key.removeprefix("graph.")) if key.startswith("graph.") else getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ConfigError(f"network.{key} must be a finite number, got {short_repr(value)}")
            if not 0 <= value <= bound:
                raise ConfigError(f"network.{key} must be a number from 0 to {bound:g}, got {short_repr(value)}")
        for name in ("type_aware", "history"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigError(f"network.{name} must be true or false, got {short_repr(getattr(self, name))}")
        for heads in ("heads", "cross_heads"):
            if self.value_dim % getattr(self, heads):
                raise ConfigError(
                    f"network.value_dim ({self.value_dim}) must be a multiple of {heads} ({getattr(self, heads)})"
                )
        if self.critic_channels < 2:
            raise ConfigError(f"network.critic_channels must be at least 2, got {self.critic_channels}")
        if self.norm not in NORMS:
            raise ConfigError(f"network.norm must be one of {', '.join(NORMS)}, got {short_repr(self.norm)}")
        scale = self.score_scale
        if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not 0 < scale <= 100:
            raise ConfigError(f"network.score_scale must be a number in (0, 100], got {short_repr(scale)}")
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
about 250,000): counted on PyTorch's meta device, before any is allocated
(:func:`~areasearch.models.network.network_shapes`)."""


def short_repr(value: object, limit: int = 60) -> str:
    """``repr(value)`` cut to ``limit`` characters (a value from a file, quoted in a message)."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def config_to_dict(config: NetworkConfig) -> dict[str, Any]:
    """``config`` as a JSON-ready dict (the graph config nested under ``graph``)."""
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
