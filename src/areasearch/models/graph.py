"""Pipeline stage "graph": observations of the goal environment -> batched heterogeneous graphs.

Follows DA-HGNN "Relational-Aware Graph Construction" (the DA-HGNN paper, Zhu et al., section
"Topological Planner"): the nodes of the graph are the robots, the candidate goals (frontier nodes, kind 0, and
target nodes, kind 1), the historical robot positions and the historical goals of the last H
decisions. Each node gets a feature vector from the observation map around it (the paper's 7-channel
map, downsampled by ``map_scale``; the crop is pooled by ``patch_pool``) and from what the
observation says about it (heading, frontier size, information gain, age); the robot-candidate edges
carry the geodesic (FMM) distances of the observation. The encoders that turn these raw features
into node embeddings live in :mod:`areasearch.models.blocks`.

**Neighbour lists.** The large graphs of the network are sparse, K = ``neighbours``: each node attends to
its K nearest of a node set (:mod:`areasearch.models.neighbours` lists them, once per observation).

The critic's map (``GraphBatch.map``) is the observation map pooled by ``map_pool`` (max-pooling; the
explored channel averaged, as the environment downsamples), so that a rollout buffer of batches stays
small and the critic's CNN starts at a coarse grid.

:func:`build_graph` collates observations of different sizes (robots, candidates, history, map side)
into one :class:`GraphBatch` (each observation's graph by :func:`observation_graph`, padded by
:func:`collate`), padded to the largest and with masks for the real nodes. Candidate
columns keep the observation's indices, so an action index is an index into ``obs["candidates"]``.
Every node axis has at least one (masked) slot, so a decision with no candidate or no history yet
still makes well-formed tensors.

Axes: B batch, R robots, C candidates, N history nodes (H decisions x R robots), K neighbours, S map
side (of the pooled critic map).
Units: positions in metres (``cell_m`` metres per full-map cell); the observation map is sampled at
``cell / map_scale``; distances are fed to the network as ``d / (d + distance_scale_m)`` in [0, 1)
(1 where unreachable), so no magic normaliser and no clipping constant is needed.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numba
import numpy as np
import torch
from torch import Tensor

from ..errors import ConfigError
from .neighbours import neighbour_lists

MAP_CHANNEL_COUNT = 7
"""Channels of the observation map (see :data:`areasearch.envs.observation.MAP_CHANNELS`)."""
EXPLORED_CHANNEL = 5
"""The explored channel: averaged, not max-pooled, when a map is pooled."""


@dataclass(frozen=True)
class GraphConfig:
    """How observations become node and edge features."""

    patch_cells: int = 8
    """Side of the square crop of the 7-channel observation map around each node, in observation-map
    cells (each ``map_scale`` full-map cells; 8 cells = 1.6 m at 5 cm cells and map_scale 4).
    0: nodes get no map features (position and scalars only)."""
    patch_pool: int = 2
    """The crop is pooled by this factor before it enters the encoders (max-pooling, the explored
    channel averaged): 8 x 8 cells -> 4 x 4, 112 features instead of 448. Must divide ``patch_cells``."""
    map_pool: int = 4
    """The critic's map is the observation map pooled by this factor (128 x 128 -> 32 x 32)."""
    neighbours: int = 8
    """K of the sparse candidate self-graphs and of the candidate <- historical robot graphs: each
    candidate's K nearest (itself included), see the module docstring."""
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
        for name in ("patch_pool", "map_pool", "neighbours"):
            value = getattr(self, name)
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ConfigError(f"graph.{name} must be a positive integer, got {value!r}")
        if self.patch_cells % self.patch_pool:
            raise ConfigError(
                f"graph.patch_pool ({self.patch_pool}) must divide graph.patch_cells ({self.patch_cells})"
            )
        if not isinstance(self.history, int) or isinstance(self.history, bool) or self.history < 0:
            raise ConfigError(f"graph.history must be an integer >= 0, got {self.history!r}")
        for name in ("distance_scale_m", "size_scale_cells", "gain_scale_cells", "cell_m"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or value <= 0:
                raise ConfigError(f"graph.{name} must be a positive number, got {value!r}")
        return self

    @property
    def patch_features(self) -> int:
        """Map features per node: the flattened 7 x P x P crop, P = patch_cells / patch_pool."""
        return MAP_CHANNEL_COUNT * (self.patch_cells // self.patch_pool) ** 2

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
    (``*_x``) are the raw inputs of the encoders of :mod:`areasearch.models.blocks`.
    """

    map: Tensor  # (B, 7, S, S) observation maps pooled by map_pool (the critic's input)
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
    cand_nbr: Tensor  # (B, C, K) int64: nearest real candidates (G_g), -1 where none
    cand_kin: Tensor  # (B, C, K) int64: nearest real candidates of the same kind (G_e, G_c), -1 where none
    past_cand: Tensor  # (B, N, 2, K) int64: a historical robot's nearest frontiers, nearest targets (G_r'e, G_r'c)
    past_robot_nbr: Tensor  # (B, N, K) int64: nearest real historical robot positions (G_r')
    past_goal_nbr: Tensor  # (B, N, K) int64: nearest real historical goals (G_g')

    def to(self, device: torch.device | str) -> GraphBatch:
        """The same batch on ``device``."""
        return GraphBatch(*(t.to(device) for t in self))

    def index(self, idx: Tensor | slice) -> GraphBatch:  # type: ignore[override]  # (not tuple.index)
        """The batch rows ``idx`` (an index tensor, a boolean mask of length B, or a slice) of every
        field: a PPO minibatch. Node axes keep their padding (see :meth:`trim`)."""
        if isinstance(idx, Tensor):
            idx = idx.to(self.map.device)
        return GraphBatch(*(t[idx] for t in self))

    def trim(self) -> GraphBatch:
        """The same graphs with every node axis cut after its last real node in any row (at least one
        slot): a minibatch drawn from a larger batch carries that batch's padding."""
        keep = {
            "R": _last_true(self.robot_mask),
            "C": _last_true(self.cand_mask),
            "N": max(_last_true(self.past_robot_mask), _last_true(self.past_goal_mask)),
        }
        if (
            keep["R"] == self.robot_mask.shape[1]
            and keep["C"] == self.cand_mask.shape[1]
            and keep["N"] == (self.past_robot_mask.shape[1])
        ):
            return self
        fields = []
        for name, t in zip(self._fields, self, strict=True):
            index = tuple(slice(0, keep[ax]) if ax in keep else slice(None) for ax in _NODE_AXES[name])
            fields.append(t[(slice(None), *index)])
        return GraphBatch(*fields)

    @property
    def batch_size(self) -> int:
        return int(self.map.shape[0])


def _last_true(mask: Tensor) -> int:
    """1 + the last index along axis 1 where any row is True (at least 1)."""
    any_row = mask.any(0)
    return max(1, int(any_row.nonzero()[-1, 0]) + 1) if bool(any_row.any()) else 1


def scaled_distance(d_m: Tensor | np.ndarray, scale_m: float) -> Tensor | np.ndarray:
    """d / (d + scale_m): 0 at the node, 0.5 at ``scale_m`` metres, 1 for an infinite distance."""
    if isinstance(d_m, np.ndarray):
        with np.errstate(invalid="ignore"):
            return np.where(np.isfinite(d_m), d_m / (d_m + scale_m), 1.0).astype(np.float32)
    return torch.where(torch.isfinite(d_m), d_m / (d_m + scale_m), torch.ones_like(d_m))


class ObservationGraph(NamedTuple):
    """One observation's graph arrays before padding (same field order as GraphBatch): what
    :func:`observation_graph` makes and :func:`collate` pads into a batch."""

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
    cand_nbr: np.ndarray
    cand_kin: np.ndarray
    past_cand: np.ndarray
    past_robot_nbr: np.ndarray
    past_goal_nbr: np.ndarray


def pool_channels(grid: np.ndarray, f: int) -> np.ndarray:
    """A (7, H, W) map pooled by ``f``: max-pooling, the explored channel averaged (the environment's own
    downsampling); a side that is not a multiple of f is zero-padded at its end. (7, ceil(H / f), ceil(W / f))."""
    c, h, w = grid.shape
    if f == 1:
        return grid
    out = np.empty((c, -(-h // f), -(-w // f)), dtype=np.float32)
    _pool_kernel(np.ascontiguousarray(grid, dtype=np.float32), f, out)
    return out


@numba.njit(cache=True, nogil=True)
def _pool_kernel(grid: np.ndarray, f: int, out: np.ndarray) -> None:
    c, h, w = grid.shape
    for ch in range(c):
        mean = ch == EXPLORED_CHANNEL
        for y in range(out.shape[1]):
            for x in range(out.shape[2]):
                acc = np.float32(0.0)
                for i in range(f):
                    for j in range(f):
                        yy, xx = y * f + i, x * f + j
                        value = grid[ch, yy, xx] if yy < h and xx < w else np.float32(0.0)
                        acc = acc + value if mean else max(acc, value)
                out[ch, y, x] = acc / (f * f) if mean else acc


def _patches(grid: np.ndarray, cells: np.ndarray, scale: float, p: int, pool: int) -> np.ndarray:
    """(N, 7 * (p / pool)^2) crops of the map around full-map ``cells`` (N, 2), pooled by ``pool`` (as
    :func:`pool_channels`): the node's observation cell sits at (p // 2, p // 2) of its crop before
    pooling; cells off the map read 0."""
    n = len(cells)
    out = np.empty((n, MAP_CHANNEL_COUNT, p // pool, p // pool), dtype=np.float32)
    if p and n:
        padded = np.pad(np.asarray(grid, dtype=np.float32), ((0, 0), (p // 2, p - p // 2), (p // 2, p - p // 2)))
        at = np.clip(np.floor(cells / scale).astype(np.int64), 0, grid.shape[1] - 1)  # (N, 2) observation cells
        _crop_kernel(padded, at, p, pool, out)
    return out.reshape(n, -1)


@numba.njit(cache=True, nogil=True)
def _crop_kernel(padded: np.ndarray, at: np.ndarray, p: int, pool: int, out: np.ndarray) -> None:
    """Crop k starts at padded cell ``at[k]`` (the padding shifts it by p // 2)."""
    c = padded.shape[0]
    side = p // pool
    inv = np.float32(1.0 / (pool * pool))
    for k in range(at.shape[0]):
        y0, x0 = at[k, 0], at[k, 1]
        for ch in range(c):
            for a in range(side):
                for b in range(side):
                    y, x = y0 + a * pool, x0 + b * pool
                    if ch == EXPLORED_CHANNEL:
                        acc = np.float32(0.0)
                        for i in range(pool):
                            for j in range(pool):
                                acc += padded[ch, y + i, x + j]
                        out[k, ch, a, b] = acc * inv
                    else:
                        acc = padded[ch, y, x]
                        for i in range(pool):
                            for j in range(pool):
                                acc = max(acc, padded[ch, y + i, x + j])
                        out[k, ch, a, b] = acc


def _history_nodes(
    obs: Mapping[str, np.ndarray], cfg: GraphConfig, r: int
) -> tuple[list[np.ndarray], list[np.ndarray], np.ndarray]:
    """The history nodes of the last ``cfg.history`` decisions of ``r`` robots, N = decisions x r: the
    cells (N, 2) of the historical robots and of the historical goals (0 where none), their masks
    (N,), and the nodes' ages (N, 1) (0 newest .. 1 oldest)."""
    h_all = np.asarray(obs["history_mask"]).astype(bool)
    h = min(cfg.history, len(h_all))
    past_mask = h_all[:h, None].repeat(r, axis=1).reshape(-1)  # (N,)
    past_cells, past_masks = [], []
    for key in ("history_robots", "history_goals"):
        cells = np.asarray(obs[key], dtype=np.float32)[:h].reshape(-1, 2)  # (N, 2)
        mask = past_mask & (cells >= 0).all(axis=1)  # goals are (-1, -1) where a robot had none
        past_cells.append(np.where(mask[:, None], cells, 0.0).astype(np.float32))
        past_masks.append(mask)
    age = (np.arange(h, dtype=np.float32) / max(len(h_all) - 1, 1))[:, None].repeat(r, axis=1).reshape(-1, 1)
    return past_cells, past_masks, age


def _history_features(
    crops: np.ndarray, cells: np.ndarray, mask: np.ndarray, age: np.ndarray, extent: float, cell_m: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(features, positions in metres, mask) of one set of history nodes; features 0 where masked."""
    x = np.concatenate([crops, (cells + 0.5) / extent, age], axis=1)
    x[~mask] = 0.0
    return x, (cells + 0.5) * cell_m, mask


def observation_graph(obs: Mapping[str, np.ndarray], cfg: GraphConfig, critic: bool = True) -> ObservationGraph:
    """The unpadded graph of one observation (candidates trimmed after the last real one); ``cfg``
    validated (:meth:`GraphConfig.validate`)."""
    grid = np.asarray(obs["map"], dtype=np.float32)  # (7, S, S)
    if grid.ndim != 3 or grid.shape[0] != MAP_CHANNEL_COUNT:
        raise ConfigError(f"observation map must be ({MAP_CHANNEL_COUNT}, S, S), got {grid.shape}")
    s = grid.shape[1]
    scale = float(np.asarray(obs["map_scale"]).reshape(-1)[0])
    cell_m = float(np.asarray(obs["cell_m"]).reshape(-1)[0]) if "cell_m" in obs else cfg.cell_m
    extent = s * scale  # full-map cells covered by the observation map
    p = cfg.patch_cells
    critic_map = pool_channels(grid, cfg.map_pool) if critic else np.zeros((MAP_CHANNEL_COUNT, 0, 0), np.float32)

    robots = np.asarray(obs["robots"], dtype=np.float32)  # (R, 3)
    r = len(robots)
    robot_cells = robots[:, :2]
    cand_mask_full = np.asarray(obs["candidate_mask"]).astype(bool)
    c = int(np.flatnonzero(cand_mask_full)[-1]) + 1 if cand_mask_full.any() else 0
    cand = np.asarray(obs["candidates"], dtype=np.float32)[:c]  # (C, 5)
    cand_mask = cand_mask_full[:c]
    past_cells, past_masks, age = _history_nodes(obs, cfg, r)
    n = len(age)
    crops = _patches(grid, np.concatenate([robot_cells, cand[:, :2], *past_cells]), scale, p, cfg.patch_pool)

    robot_x = np.concatenate(
        [crops[:r], (robot_cells + 0.5) / extent, np.sin(robots[:, 2:3]), np.cos(robots[:, 2:3])], axis=1
    )
    size = np.log1p(np.maximum(cand[:, 3:4], 0.0) / cfg.size_scale_cells)
    gain = np.log1p(np.maximum(cand[:, 4:5], 0.0) / cfg.gain_scale_cells)
    cand_x = np.concatenate([crops[r : r + c], (cand[:, :2] + 0.5) / extent, size, gain], axis=1)
    cand_x[~cand_mask] = 0.0
    kind = np.where(cand_mask, cand[:, 2], 0).astype(np.int64)
    d_m = np.asarray(obs["distances"], dtype=np.float32)[:, :c]  # (R, C)
    reachable = np.isfinite(d_m) & cand_mask[None, :]
    action_mask = np.asarray(obs["action_mask"]).astype(bool)[:, :c] & cand_mask[None, :]
    past_robot, past_goal = (
        _history_features(crops[r + c + i * n : r + c + (i + 1) * n], past_cells[i], past_masks[i], age, extent, cell_m)
        for i in (0, 1)
    )
    # neighbour lists of the sparse graphs (module neighbours): ties broken by the nodes' own features
    lists = neighbour_lists(
        cand[:, :2], kind, size[:, 0], gain[:, 0], cand_mask, past_cells, past_masks, age[:, 0], cfg.neighbours
    )
    return ObservationGraph(
        map=critic_map,
        progress=np.asarray(obs["progress"], dtype=np.float32).reshape(1),
        robot_x=robot_x.astype(np.float32),
        robot_xy=((robot_cells + 0.5) * cell_m).astype(np.float32),
        robot_mask=np.ones(r, dtype=bool),
        cand_x=cand_x.astype(np.float32),
        cand_xy=((cand[:, :2] + 0.5) * cell_m).astype(np.float32),
        cand_kind=kind,
        cand_mask=cand_mask,
        dist=np.asarray(scaled_distance(np.where(reachable, d_m, np.inf), cfg.distance_scale_m), dtype=np.float32),
        reachable=reachable,
        action_mask=action_mask,
        past_robot_x=past_robot[0],
        past_robot_xy=past_robot[1].astype(np.float32),
        past_robot_mask=past_robot[2],
        past_goal_x=past_goal[0],
        past_goal_xy=past_goal[1].astype(np.float32),
        past_goal_mask=past_goal[2],
        cand_nbr=lists[0],
        cand_kin=lists[1],
        past_cand=lists[2],
        past_robot_nbr=lists[3],
        past_goal_nbr=lists[4],
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
    "cand_nbr": ("C", ""),
    "cand_kin": ("C", ""),
    "past_cand": ("N", "", ""),
    "past_robot_nbr": ("N", ""),
    "past_goal_nbr": ("N", ""),
}
_FILL = {"dist": 1.0, "cand_nbr": -1, "cand_kin": -1, "past_cand": -1, "past_robot_nbr": -1, "past_goal_nbr": -1}
"""Padding values other than 0: distances 1 (unreachable), neighbour lists -1 (none)."""


def build_graph(
    observations: Sequence[Mapping[str, np.ndarray]] | Mapping[str, np.ndarray],
    config: GraphConfig | None = None,
    device: torch.device | str = "cpu",
    critic: bool = True,
) -> GraphBatch:
    """Collate one observation or a sequence of them into a padded :class:`GraphBatch` on ``device``.

    Sizes may differ between observations (robots, candidates, history length, map side); each node
    axis is padded to the largest (at least 1) and masked. Observations are never modified. Every
    tensor is a fresh copy (never a view of the caller's arrays). ``critic=False`` leaves the critic's
    map out (``map`` is then (B, 7, 0, 0)): what the actor alone needs.
    """
    cfg = (config or GraphConfig()).validate()
    obs_list = [observations] if isinstance(observations, Mapping) else list(observations)
    if not obs_list:
        raise ConfigError("build_graph needs at least one observation")
    return collate([observation_graph(o, cfg, critic) for o in obs_list], device)


def collate(graphs: Sequence[ObservationGraph], device: torch.device | str = "cpu") -> GraphBatch:
    """Pad the graphs of observations (:func:`observation_graph`) into one :class:`GraphBatch` on
    ``device``, as :func:`build_graph` does: the same batch whether the graphs were made here or
    elsewhere (e.g. as each episode of an iteration came back)."""
    if not graphs:
        raise ConfigError("collate needs at least one graph")
    sizes = {
        "S": max(g.map.shape[1] for g in graphs),
        "R": max(len(g.robot_mask) for g in graphs),
        "C": max(1, max(len(g.cand_mask) for g in graphs)),
        "N": max(1, max(len(g.past_robot_mask) for g in graphs)),
    }
    fields = {}
    for name, axes in _NODE_AXES.items():
        first = getattr(graphs[0], name)
        shape = (len(graphs), *(sizes[ax] if ax else first.shape[i] for i, ax in enumerate(axes)))
        out = np.full(shape, _FILL.get(name, 0), dtype=first.dtype)  # padded, filled in below
        for b, g in enumerate(graphs):
            a = getattr(g, name)
            index: tuple[int | slice, ...] = (b, *[slice(0, n) for n in a.shape])
            out[index] = a
        fields[name] = torch.from_numpy(out).to(device)  # a copy: never shares the caller's arrays
    return GraphBatch(**fields)
