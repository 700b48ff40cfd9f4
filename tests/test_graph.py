"""Graph construction: observations of the goal environment -> padded heterogeneous graph batches."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from areasearch.errors import ConfigError
from areasearch.goal_env import AreaSearchEnv, nearest_candidate
from areasearch.graph import GraphBatch, GraphConfig, build_graph, scaled_distance


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
    cfg = GraphConfig(patch_cells=4)
    obs = observation(robots=1, candidates=1, pad=0)
    obs["map"][3, 2, 3] = 1.0  # targets channel, observation cell (2, 3) = full-map cells (8..11, 12..15)
    batch = build_graph(obs, cfg)
    patch = batch.cand_x[0, 0, : cfg.patch_features].view(7, 4, 4)
    assert patch.sum() == 1.0
    assert patch[3, 2, 2] == 1.0  # the node's cell sits at (P // 2, P // 2) of its crop
    robot_patch = batch.robot_x[0, 0, : cfg.patch_features].view(7, 4, 4)  # robot at cell (1, 1): (2, 3) is off-crop
    assert robot_patch.sum() == 0.0


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
    assert batch.map.shape == (2, 7, 20, 20)
    assert batch.robot_mask.tolist() == [[True, True, False, False], [True] * 4]
    assert batch.cand_mask.sum(1).tolist() == [2, 5]
    assert batch.past_robot_mask.shape == (2, 12)
    alone = build_graph(small, cfg)
    for name, full, one in zip(GraphBatch._fields, batch, alone, strict=True):
        index = tuple(slice(0, s) for s in one.shape[1:])
        torch.testing.assert_close(full[0][index], one[0], msg=name)
    assert (batch.dist[0, 2:] == 1.0).all() and not batch.reachable[0, 2:].any() and not batch.action_mask[0, 2:].any()


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
    "change", [{"patch_cells": -1}, {"distance_scale_m": 0.0}, {"cell_m": float("nan")}, {"history": 1.5}]
)
def test_bad_config_raises(change: dict) -> None:
    with pytest.raises(ConfigError):
        build_graph(observation(), GraphConfig(**change))


def test_real_observations_build_and_are_not_modified() -> None:
    env = AreaSearchEnv(map="bormann_lab_c_rooms1", num_robots=3, seed=0)
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
