"""Pipeline stage "graph": observations of the goal environment -> batched heterogeneous graphs.

Follows DA-HGNN "Relational-Aware Graph Construction" (paper/da-hgnn.tex, section "Topological
Planner"): the nodes of the graph are the robots, the candidate goals (frontier nodes, kind 0, and
target nodes, kind 1), the historical robot positions and the historical goals of the last H
decisions. Each node gets a feature vector from the observation map around it (the paper's 7-channel
map, downsampled by ``map_scale``) and from what the observation says about it (heading, frontier
size, information gain, age); the robot-candidate edges carry the geodesic (FMM) distances of the
observation. The encoders that turn these raw features into node embeddings live in
:mod:`areasearch.dahgnn`.

:func:`build_graph` collates observations of different sizes (robots, candidates, history, map side)
into one :class:`GraphBatch`, padded to the largest and with masks for the real nodes. Candidate
columns keep the observation's indices, so an action index is an index into ``obs["candidates"]``.
Every node axis has at least one (masked) slot, so a decision with no candidate or no history yet
still makes well-formed tensors.

Axes: B batch, R robots, C candidates, N history nodes (H decisions x R robots), S map side.
Units: positions in metres (``cell_m`` metres per full-map cell); the observation map is sampled at
``cell / map_scale``; distances are fed to the network as ``d / (d + distance_scale_m)`` in [0, 1)
(1 where unreachable), so no magic normaliser and no clipping constant is needed.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import torch
from numpy.lib.stride_tricks import sliding_window_view
from torch import Tensor

from .errors import ConfigError

MAP_CHANNEL_COUNT = 7
"""Channels of the observation map (see :data:`areasearch.goal_env.MAP_CHANNELS`)."""


@dataclass(frozen=True)
class GraphConfig:
    """How observations become node and edge features."""

    patch_cells: int = 8
    """Side of the square crop of the 7-channel observation map around each node, in observation-map
    cells (each ``map_scale`` full-map cells; 8 cells = 1.6 m at 5 cm cells and map_scale 4).
    0: nodes get no map features (the NCM baseline encodes positions and types only)."""
    distance_scale_m: float = 5.0
    """Distances d (metres) enter the network as d / (d + distance_scale_m): 0.5 at this distance."""
    size_scale_cells: float = 20.0
    """Frontier sizes (full-map cells) enter as log(1 + size / size_scale_cells)."""
    gain_scale_cells: float = 2000.0
    """Information gains (unknown full-map cells within sensor range) enter as log(1 + gain / gain_scale_cells)."""
    cell_m: float = 0.05
    """Metres per full-map cell, for the Euclidean distances of history edges, used when an observation
    has no ``cell_m`` entry of its own (the bundled maps are 0.05 m)."""
    history: int = 8
    """Past decisions used as history nodes (at most the observation's H; the newest ones)."""

    def validate(self) -> GraphConfig:
        if not isinstance(self.patch_cells, int) or isinstance(self.patch_cells, bool) or self.patch_cells < 0:
            raise ConfigError(f"graph.patch_cells must be an integer >= 0, got {self.patch_cells!r}")
        if not isinstance(self.history, int) or isinstance(self.history, bool) or self.history < 0:
            raise ConfigError(f"graph.history must be an integer >= 0, got {self.history!r}")
        for name in ("distance_scale_m", "size_scale_cells", "gain_scale_cells", "cell_m"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or value <= 0:
                raise ConfigError(f"graph.{name} must be a positive number, got {value!r}")
        return self

    @property
    def patch_features(self) -> int:
        """Map features per node: the flattened 7 x P x P crop."""
        return MAP_CHANNEL_COUNT * self.patch_cells**2

    @property
    def robot_features(self) -> int:
        """Robot node: map crop, position (2), sin and cos of the heading."""
        return self.patch_features + 4

    @property
    def candidate_features(self) -> int:
        """Candidate node: map crop, position (2), frontier size, information gain (the kind is kept apart)."""
        return self.patch_features + 4

    @property
    def history_features(self) -> int:
        """Historical robot position or goal: map crop, position (2), age (0 newest .. 1 oldest)."""
        return self.patch_features + 3


class GraphBatch(NamedTuple):
    """A batch of padded heterogeneous graphs; ``*_mask`` is True for real nodes.

    Positions (``*_xy``) are in metres in the map frame (row, column order); node features
    (``*_x``) are the raw inputs of the encoders of :mod:`areasearch.dahgnn`.
    """

    map: Tensor  # (B, 7, S, S) observation maps (the critic's input)
    progress: Tensor  # (B, 1) steps taken / horizon
    robot_x: Tensor  # (B, R, Fr)
    robot_xy: Tensor  # (B, R, 2) metres
    robot_mask: Tensor  # (B, R) bool
    cand_x: Tensor  # (B, C, Fc)
    cand_xy: Tensor  # (B, C, 2) metres
    cand_kind: Tensor  # (B, C) int64: 0 frontier, 1 target
    cand_mask: Tensor  # (B, C) bool
    dist: Tensor  # (B, R, C) geodesic robot-candidate distance, d / (d + scale), 1 where unreachable
    reachable: Tensor  # (B, R, C) bool: finite geodesic distance to a real candidate
    action_mask: Tensor  # (B, R, C) bool: the observation's action mask
    past_robot_x: Tensor  # (B, N, Fh)
    past_robot_xy: Tensor  # (B, N, 2) metres
    past_robot_mask: Tensor  # (B, N) bool
    past_goal_x: Tensor  # (B, N, Fh)
    past_goal_xy: Tensor  # (B, N, 2) metres
    past_goal_mask: Tensor  # (B, N) bool

    def to(self, device: torch.device | str) -> GraphBatch:
        """The same batch on ``device``."""
        return GraphBatch(*(t.to(device) for t in self))

    @property
    def batch_size(self) -> int:
        return int(self.map.shape[0])


def scaled_distance(d_m: Tensor | np.ndarray, scale_m: float) -> Tensor | np.ndarray:
    """d / (d + scale_m): 0 at the node, 0.5 at ``scale_m`` metres, 1 for an infinite distance."""
    if isinstance(d_m, np.ndarray):
        with np.errstate(invalid="ignore"):
            return np.where(np.isfinite(d_m), d_m / (d_m + scale_m), 1.0).astype(np.float32)
    return torch.where(torch.isfinite(d_m), d_m / (d_m + scale_m), torch.ones_like(d_m))


class _Graph(NamedTuple):
    """One observation's graph arrays before padding (same field order as GraphBatch)."""

    map: np.ndarray
    progress: np.ndarray
    robot_x: np.ndarray
    robot_xy: np.ndarray
    robot_mask: np.ndarray
    cand_x: np.ndarray
    cand_xy: np.ndarray
    cand_kind: np.ndarray
    cand_mask: np.ndarray
    dist: np.ndarray
    reachable: np.ndarray
    action_mask: np.ndarray
    past_robot_x: np.ndarray
    past_robot_xy: np.ndarray
    past_robot_mask: np.ndarray
    past_goal_x: np.ndarray
    past_goal_xy: np.ndarray
    past_goal_mask: np.ndarray


def _patches(padded: np.ndarray, cells: np.ndarray, scale: float, p: int) -> np.ndarray:
    """(N, 7 * p * p) crops of the padded map around full-map ``cells`` (N, 2): the node's observation
    cell sits at (p // 2, p // 2) of its crop (the map is padded by p // 2 before, p - p // 2 after)."""
    n = len(cells)
    if p == 0 or n == 0:
        return np.zeros((n, MAP_CHANNEL_COUNT * p * p), dtype=np.float32)
    side = padded.shape[1] - p
    at = np.clip(np.floor(cells / scale).astype(np.int64), 0, side - 1)  # (N, 2) observation cells
    windows = sliding_window_view(padded, (p, p), axis=(1, 2))  # (7, S + 1, S + 1, p, p), a view
    return windows[:, at[:, 0], at[:, 1]].transpose(1, 0, 2, 3).reshape(n, -1)  # (N, 7 * p * p)


def _one(obs: Mapping[str, np.ndarray], cfg: GraphConfig) -> _Graph:
    """The unpadded graph of one observation (candidates trimmed after the last real one)."""
    grid = np.asarray(obs["map"], dtype=np.float32)  # (7, S, S)
    if grid.ndim != 3 or grid.shape[0] != MAP_CHANNEL_COUNT:
        raise ConfigError(f"observation map must be ({MAP_CHANNEL_COUNT}, S, S), got {grid.shape}")
    s = grid.shape[1]
    scale = float(np.asarray(obs["map_scale"]).reshape(-1)[0])
    cell_m = float(np.asarray(obs["cell_m"]).reshape(-1)[0]) if "cell_m" in obs else cfg.cell_m
    extent = s * scale  # full-map cells covered by the observation map
    p = cfg.patch_cells
    padded = np.pad(grid, ((0, 0), (p // 2, p - p // 2), (p // 2, p - p // 2))) if p else grid

    robots = np.asarray(obs["robots"], dtype=np.float32)  # (R, 3)
    r = len(robots)
    robot_cells = robots[:, :2]
    cand_mask_full = np.asarray(obs["candidate_mask"]).astype(bool)
    c = int(np.flatnonzero(cand_mask_full)[-1]) + 1 if cand_mask_full.any() else 0
    cand = np.asarray(obs["candidates"], dtype=np.float32)[:c]  # (C, 5)
    cand_mask = cand_mask_full[:c]
    h_all = np.asarray(obs["history_mask"]).astype(bool)
    h = min(cfg.history, len(h_all))
    past_mask = h_all[:h, None].repeat(r, axis=1).reshape(-1)  # (N,)
    past_cells, past_masks = [], []
    for key in ("history_robots", "history_goals"):
        cells = np.asarray(obs[key], dtype=np.float32)[:h].reshape(-1, 2)  # (N, 2)
        mask = past_mask & (cells >= 0).all(axis=1)  # goals are (-1, -1) where a robot had none
        past_cells.append(np.where(mask[:, None], cells, 0.0).astype(np.float32))
        past_masks.append(mask)
    n = len(past_mask)
    crops = _patches(padded, np.concatenate([robot_cells, cand[:, :2], *past_cells]), scale, p)  # every node at once

    robot_x = np.concatenate(
        [crops[:r], (robot_cells + 0.5) / extent, np.sin(robots[:, 2:3]), np.cos(robots[:, 2:3])], axis=1
    )
    cand_x = np.concatenate(
        [
            crops[r : r + c],
            (cand[:, :2] + 0.5) / extent,
            np.log1p(np.maximum(cand[:, 3:4], 0.0) / cfg.size_scale_cells),
            np.log1p(np.maximum(cand[:, 4:5], 0.0) / cfg.gain_scale_cells),
        ],
        axis=1,
    )
    cand_x[~cand_mask] = 0.0
    d_m = np.asarray(obs["distances"], dtype=np.float32)[:, :c]  # (R, C)
    reachable = np.isfinite(d_m) & cand_mask[None, :]
    action_mask = np.asarray(obs["action_mask"]).astype(bool)[:, :c] & cand_mask[None, :]

    age = (np.arange(h, dtype=np.float32) / max(len(h_all) - 1, 1))[:, None].repeat(r, axis=1).reshape(-1, 1)
    past: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    for i, key in enumerate(("history_robots", "history_goals")):
        cells, mask = past_cells[i], past_masks[i]
        start = r + c + i * n
        x = np.concatenate([crops[start : start + n], (cells + 0.5) / extent, age], axis=1)
        x[~mask] = 0.0
        past[key] = (x, (cells + 0.5) * cell_m, mask)

    return _Graph(
        map=grid,
        progress=np.asarray(obs["progress"], dtype=np.float32).reshape(1),
        robot_x=robot_x.astype(np.float32),
        robot_xy=((robot_cells + 0.5) * cell_m).astype(np.float32),
        robot_mask=np.ones(r, dtype=bool),
        cand_x=cand_x.astype(np.float32),
        cand_xy=((cand[:, :2] + 0.5) * cell_m).astype(np.float32),
        cand_kind=np.where(cand_mask, cand[:, 2], 0).astype(np.int64),
        cand_mask=cand_mask,
        dist=np.asarray(scaled_distance(np.where(reachable, d_m, np.inf), cfg.distance_scale_m), dtype=np.float32),
        reachable=reachable,
        action_mask=action_mask,
        past_robot_x=past["history_robots"][0],
        past_robot_xy=past["history_robots"][1].astype(np.float32),
        past_robot_mask=past["history_robots"][2],
        past_goal_x=past["history_goals"][0],
        past_goal_xy=past["history_goals"][1].astype(np.float32),
        past_goal_mask=past["history_goals"][2],
    )


# Padding of each field: which axes are node axes, and the fill value (1.0 for distances: unreachable).
_NODE_AXES: dict[str, tuple[str, ...]] = {
    "map": ("", "S", "S"),
    "progress": ("",),
    "robot_x": ("R", ""),
    "robot_xy": ("R", ""),
    "robot_mask": ("R",),
    "cand_x": ("C", ""),
    "cand_xy": ("C", ""),
    "cand_kind": ("C",),
    "cand_mask": ("C",),
    "dist": ("R", "C"),
    "reachable": ("R", "C"),
    "action_mask": ("R", "C"),
    "past_robot_x": ("N", ""),
    "past_robot_xy": ("N", ""),
    "past_robot_mask": ("N",),
    "past_goal_x": ("N", ""),
    "past_goal_xy": ("N", ""),
    "past_goal_mask": ("N",),
}


def build_graph(
    observations: Sequence[Mapping[str, np.ndarray]] | Mapping[str, np.ndarray],
    config: GraphConfig | None = None,
    device: torch.device | str = "cpu",
) -> GraphBatch:
    """Collate one observation or a sequence of them into a padded :class:`GraphBatch` on ``device``.

    Sizes may differ between observations (robots, candidates, history length, map side); each node
    axis is padded to the largest (at least 1) and masked. Observations are never modified.
    """
    cfg = (config or GraphConfig()).validate()
    obs_list = [observations] if isinstance(observations, Mapping) else list(observations)
    if not obs_list:
        raise ConfigError("build_graph needs at least one observation")
    graphs = [_one(o, cfg) for o in obs_list]
    sizes = {
        "S": max(g.map.shape[1] for g in graphs),
        "R": max(len(g.robot_mask) for g in graphs),
        "C": max(1, max(len(g.cand_mask) for g in graphs)),
        "N": max(1, max(len(g.past_robot_mask) for g in graphs)),
    }
    fields = {}
    for name, axes in _NODE_AXES.items():
        fill = 1.0 if name == "dist" else 0
        parts = []
        for g in graphs:
            a = getattr(g, name)
            pad = [(0, sizes[ax] - a.shape[i]) if ax else (0, 0) for i, ax in enumerate(axes)]
            parts.append(np.pad(a, pad, constant_values=fill) if any(w for _, w in pad) else a)
        fields[name] = torch.from_numpy(np.stack(parts)).to(device)  # a copy: never shares the caller's arrays
    return GraphBatch(**fields)
