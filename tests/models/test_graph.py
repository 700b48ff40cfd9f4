"""Graph construction: observations of the goal environment -> padded heterogeneous graph batches."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from areasearch.envs.goal import AreaSearchEnv, nearest_candidate
from areasearch.errors import ConfigError
from areasearch.models.graph import GraphBatch, GraphConfig, build_graph, pool_channels, scaled_distance
from areasearch.models.neighbours import nearest


def observation(robots: int = 2, candidates: int = 3, history: int = 2, side: int = 16, pad: int = 2) -> dict:
    """A small hand-made observation: ``candidates`` real candidates followed by ``pad`` padded slots."""
    c = candidates + pad
    grid = np.zeros((7, side, side), dtype=np.float32)
    cand = np.zeros((c, 5), dtype=np.float32)
    cand[:candidates, 0] = 8 + 4 * np.arange(candidates)
    cand[:candidates, 1] = 12
    cand[:candidates, 2] = np.arange(candidates) % 2
    cand[:candidates, 3] = 5
    cand[:candidates, 4] = 100
    mask = np.zeros(c, dtype=np.int8)
    mask[:candidates] = 1
    dist = np.full((robots, c), np.inf, dtype=np.float32)
    dist[:, :candidates] = 1.0 + np.arange(robots * candidates, dtype=np.float32).reshape(robots, candidates)
    return {
        "map": grid,
        "map_scale": np.array([4.0], dtype=np.float32),
        "robots": np.array([[4.0 + 8 * i, 4.0, 0.5] for i in range(robots)], dtype=np.float32),
        "candidates": cand,
        "candidate_mask": mask,
        "distances": dist,
        "action_mask": np.isfinite(dist).astype(np.int8),
        "history_robots": np.full((history, robots, 2), 6.0, dtype=np.float32),
        "history_goals": np.full((history, robots, 2), -1.0, dtype=np.float32),
        "history_mask": np.array([1] + [0] * (history - 1), dtype=np.int8),
        "progress": np.array([0.25], dtype=np.float32),
    }


def test_patch_is_centred_on_the_node_cell() -> None:
    cfg = GraphConfig(patch_cells=4, patch_pool=1)
    obs = observation(robots=1, candidates=1, pad=0)
    obs["map"][3, 2, 3] = 1.0  # targets channel, observation cell (2, 3) = full-map cells (8..11, 12..15)
    batch = build_graph(obs, cfg)
    patch = batch.cand_x[0, 0, : cfg.patch_features].view(7, 4, 4)
    assert patch.sum() == 1.0
    assert patch[3, 2, 2] == 1.0  # the node's cell sits at (P // 2, P // 2) of its crop
    robot_patch = batch.robot_x[0, 0, : cfg.patch_features].view(7, 4, 4)  # robot at cell (1, 1): (2, 3) is off-crop
    assert robot_patch.sum() == 0.0


def test_pooled_patch_max_pools_and_averages_the_explored_channel() -> None:
    cfg = GraphConfig(patch_cells=4, patch_pool=2)
    obs = observation(robots=1, candidates=1, pad=0)
    obs["map"][3, 2, 3] = 1.0  # a target at the node's own cell: crop cell (2, 2), pooled cell (1, 1)
    obs["map"][5, 2, 3] = 1.0  # explored: one cell of the 2 x 2 block
    obs["map"][5, 0, 1] = 1.0  # crop cell (0, 0): the node's cell is (2, 3), the crop starts at (0, 1)
    batch = build_graph(obs, cfg)
    patch = batch.cand_x[0, 0, : cfg.patch_features].view(7, 2, 2)
    assert cfg.patch_features == 7 * 2 * 2
    assert patch[3].tolist() == [[0.0, 0.0], [0.0, 1.0]]
    assert patch[5].tolist() == [[0.25, 0.0], [0.0, 0.25]]
    grid = np.zeros((7, 5, 5), dtype=np.float32)
    grid[2, 4, 4] = 1.0
    grid[5, :2, :2] = 1.0
    pooled = pool_channels(grid, 2)  # a side of 5 pools to 3, the last block half off the map
    assert pooled.shape == (7, 3, 3)
    assert pooled[2, 2, 2] == 1.0 and pooled[2].sum() == 1.0
    assert pooled[5, 0, 0] == 1.0 and pooled[5].sum() == 1.0


def test_features_units_and_masks() -> None:
    cfg = GraphConfig(patch_cells=2, distance_scale_m=5.0, cell_m=0.05)
    obs = observation(robots=2, candidates=3, pad=2)
    batch = build_graph(obs, cfg)
    assert isinstance(batch, GraphBatch) and batch.batch_size == 1
    assert batch.cand_mask.shape == (1, 3)  # trimmed after the last real candidate
    assert batch.cand_kind.tolist() == [[0, 1, 0]]
    np.testing.assert_allclose(batch.dist[0].numpy(), obs["distances"][:, :3] / (obs["distances"][:, :3] + 5.0))
    np.testing.assert_allclose(batch.cand_xy[0, 1].numpy(), [(12 + 0.5) * 0.05, (12 + 0.5) * 0.05])
    position = batch.cand_x[0, 0, cfg.patch_features : cfg.patch_features + 2]
    np.testing.assert_allclose(position.numpy(), (np.array([8.0, 12.0]) + 0.5) / (16 * 4.0))
    size_gain = batch.cand_x[0, 0, -2:].numpy()
    np.testing.assert_allclose(size_gain, [np.log1p(5 / cfg.size_scale_cells), np.log1p(100 / cfg.gain_scale_cells)])
    # history: one decision of two robots; goals (-1, -1) are not nodes
    assert batch.past_robot_mask.tolist() == [[True, True, False, False]]
    assert not batch.past_goal_mask.any()
    assert batch.progress.item() == pytest.approx(0.25)


def test_observation_cell_size_overrides_the_config() -> None:
    obs = observation()
    obs["cell_m"] = np.array([0.1], dtype=np.float32)
    batch = build_graph(obs, GraphConfig(cell_m=0.05))
    np.testing.assert_allclose(batch.robot_xy[0, 0].numpy(), [0.45, 0.45])


def test_collate_pads_every_node_axis_and_keeps_each_graph() -> None:
    cfg = GraphConfig(patch_cells=2)
    small = observation(robots=2, candidates=2, history=2, side=16)
    large = observation(robots=4, candidates=5, history=3, side=20)
    small["map"][:, 3, 3] = 1.0
    batch = build_graph([small, large], cfg)
    assert batch.map.shape == (2, 7, 5, 5)  # the critic's map, pooled by map_pool = 4
    assert batch.robot_mask.tolist() == [[True, True, False, False], [True] * 4]
    assert batch.cand_mask.sum(1).tolist() == [2, 5]
    assert batch.past_robot_mask.shape == (2, 12)
    alone = build_graph(small, cfg)
    for name, full, one in zip(GraphBatch._fields, batch, alone, strict=True):
        index = tuple(slice(0, s) for s in one.shape[1:])
        torch.testing.assert_close(full[0][index], one[0], msg=name)
    assert (batch.dist[0, 2:] == 1.0).all() and not batch.reachable[0, 2:].any() and not batch.action_mask[0, 2:].any()


def test_actor_only_collation_leaves_the_critic_map_out_and_nothing_else() -> None:
    cfg = GraphConfig(patch_cells=2)
    obs = [observation(robots=2, candidates=2, history=2, side=16), observation(robots=3, candidates=5, side=20)]
    full, actor = build_graph(obs, cfg), build_graph(obs, cfg, critic=False)
    assert actor.map.shape == (2, 7, 0, 0)
    for name, a, b in zip(GraphBatch._fields, full, actor, strict=True):
        if name != "map":
            torch.testing.assert_close(a, b, rtol=0, atol=0, msg=name)


def test_no_candidates_and_no_history_still_give_one_masked_slot() -> None:
    obs = observation(candidates=0, pad=3)
    obs["history_mask"][:] = 0
    batch = build_graph(obs)
    assert batch.cand_mask.shape == (1, 1) and not batch.cand_mask.any()
    assert batch.past_robot_mask.shape[1] >= 1 and not batch.past_robot_mask.any()
    assert not batch.action_mask.any()
    assert all(torch.isfinite(t.float()).all() for t in batch)


def test_history_config_keeps_the_newest_decisions() -> None:
    obs = observation(history=4)
    obs["history_mask"][:] = 1
    assert build_graph(obs, GraphConfig(history=2)).past_robot_mask.shape == (1, 2 * 2)
    assert build_graph(obs, GraphConfig(history=0)).past_robot_mask.shape == (1, 1)


def test_scaled_distance() -> None:
    d = np.array([0.0, 5.0, np.inf], dtype=np.float32)
    np.testing.assert_allclose(scaled_distance(d, 5.0), [0.0, 0.5, 1.0])
    torch.testing.assert_close(scaled_distance(torch.from_numpy(d), 5.0), torch.tensor([0.0, 0.5, 1.0]))


@pytest.mark.parametrize(
    "change",
    [
        {"patch_cells": -1},
        {"distance_scale_m": 0.0},
        {"cell_m": float("nan")},
        {"history": 1.5},
        {"neighbours": 0},
        {"patch_pool": 3},
        {"map_pool": True},
    ],
)
def test_bad_config_raises(change: dict) -> None:
    with pytest.raises(ConfigError):
        build_graph(observation(), GraphConfig(**change))


def test_real_observations_build_and_are_not_modified(small_map: str) -> None:
    env = AreaSearchEnv(map=small_map, num_robots=3, seed=0)
    obs, _ = env.reset(seed=0)
    observations = [obs]
    for _ in range(2):
        obs, *_ = env.step(nearest_candidate(obs))
        observations.append(obs)
    copies = [{k: v.copy() for k, v in o.items()} for o in observations]
    cfg = GraphConfig()
    batch = build_graph(observations, cfg)
    for o, c in zip(observations, copies, strict=True):
        for key in o:
            np.testing.assert_array_equal(o[key], c[key])
    real = [int(o["candidate_mask"].sum()) for o in observations]
    assert batch.cand_mask.sum(1).tolist() == real and batch.cand_mask.shape[1] == max(real)
    assert batch.robot_x.shape == (3, 3, cfg.robot_features)
    assert batch.cand_x.shape[2] == cfg.candidate_features
    assert all(torch.isfinite(t.float()).all() for t in batch)
    assert (batch.action_mask <= batch.reachable).all()
    assert batch.past_robot_mask.sum(1).tolist() == [0, 3, 6]
    # the crops read the map: somewhere around the robots there is explored space
    assert batch.robot_x[:, :, : cfg.patch_features].sum() > 0


def test_nearest_matches_a_sort_and_breaks_ties_by_rank() -> None:
    rng = np.random.default_rng(0)
    for _ in range(100):
        q = rng.integers(0, 6, (5, 2)).astype(np.float32)  # small grid: many equal distances
        src = rng.integers(0, 6, (8, 2)).astype(np.float32)
        rank = rng.permutation(8).astype(np.float64)
        q_ok, s_ok = rng.random(5) > 0.2, rng.random(8) > 0.3
        q_group, s_group = rng.integers(0, 2, 5), rng.integers(0, 2, 8)
        k = int(rng.integers(1, 10))
        got = nearest(q, src, rank, q_ok, s_ok, k, q_group, s_group)
        for i in range(5):
            pool = [j for j in range(8) if q_ok[i] and s_ok[j] and s_group[j] == q_group[i]]
            pool.sort(key=lambda j: (float(((q[i] - src[j]) ** 2).sum()), rank[j]))
            assert got[i].tolist() == (pool + [-1] * k)[:k]


def test_neighbour_lists_are_the_nearest_real_nodes() -> None:
    cfg = GraphConfig(neighbours=2, patch_cells=0)
    obs = observation(robots=2, candidates=4, pad=2, history=2)  # candidates at rows 8, 12, 16, 20, column 12
    obs["history_mask"][:] = 1
    obs["history_robots"][1] = [[40.0, 12.0], [9.0, 12.0]]
    batch = build_graph(obs, cfg)
    assert batch.cand_nbr.shape == (1, 4, 2)
    assert batch.cand_nbr[0].tolist() == [[0, 1], [1, 0], [2, 1], [3, 2]]  # itself first; ties to the lower rank
    assert batch.cand_kin[0].tolist() == [[0, 2], [1, 3], [2, 0], [3, 1]]  # kinds alternate 0, 1, 0, 1
    # historical robots at (6, 6), (6, 6), (40, 12), (9, 12): nearest frontiers (8, 12), (16, 12)
    assert batch.past_cand[0, 3].tolist() == [[0, 2], [1, 3]]
    assert batch.past_cand[0, 2, 1].tolist() == [3, 1]
    assert batch.past_robot_nbr[0, 3].tolist() == [3, 0]  # (6, 6) twice: the younger first (age ranks)
    assert batch.past_goal_nbr[0].tolist() == [[-1, -1]] * 4  # goals (-1, -1) are no nodes
    wide = build_graph(obs, GraphConfig(neighbours=9, patch_cells=0))
    assert (wide.cand_nbr[0, :, 4:] == -1).all() and (wide.cand_nbr[0, :, :4] >= 0).all()


def test_permuting_candidates_permutes_the_neighbour_lists() -> None:
    rng = np.random.default_rng(3)
    obs = observation(robots=2, candidates=12, pad=0)
    obs["candidates"][:12, :2] = rng.integers(0, 12, (12, 2))  # coarse grid: many ties
    perm = rng.permutation(12)
    moved = dict(obs)
    for key in ("candidates", "candidate_mask"):
        moved[key] = obs[key][perm]
    for key in ("distances", "action_mask"):
        moved[key] = obs[key][:, perm]
    cfg = GraphConfig(neighbours=4, patch_cells=0)
    a, b = build_graph(obs, cfg), build_graph(moved, cfg)
    for name in ("cand_nbr", "cand_kin"):
        mapped = perm[getattr(b, name)[0].numpy()]  # b's candidate i is a's candidate perm[i]
        assert np.array_equal(np.sort(mapped, axis=1), np.sort(getattr(a, name)[0].numpy()[perm], axis=1)), name


def test_index_trim_and_to_select_rows_of_every_field() -> None:
    cfg = GraphConfig(patch_cells=2)
    obs = [
        observation(robots=2, candidates=2),
        observation(robots=3, candidates=5),
        observation(robots=2, candidates=1),
    ]
    batch = build_graph(obs, cfg)
    picked = batch.index(torch.tensor([0, 2]))
    assert picked.batch_size == 2
    for full, part in zip(batch, picked, strict=True):
        assert torch.equal(part, full[[0, 2]])
    assert picked.cand_mask.shape[1] == 5  # padding kept
    trimmed = picked.trim()
    alone = build_graph([obs[0], obs[2]], cfg).trim()  # the second history decision is masked: trimmed too
    assert trimmed.past_robot_mask.shape == (2, 2)
    for name, t, ref in zip(GraphBatch._fields, trimmed, alone, strict=True):
        assert torch.equal(t, ref), name
    assert batch.index(slice(1, 2)).trim().cand_mask.shape == (1, 5)
    assert trimmed.trim() is trimmed  # nothing left to cut
    assert all(t.device.type == "cpu" for t in batch.to("cpu"))
