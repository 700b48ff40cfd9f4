"""PPO's pieces (:mod:`areasearch.training.ppo`) on numbers worked out by hand: GAE, the clipped surrogate and
its gradient, the value loss with and without clipping, the k3 KL estimate, and ``target_kl``'s early
stop of :func:`~areasearch.training.ppo.ppo_update` on the real network."""

from __future__ import annotations

import dataclasses
import math
import unittest.mock
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
import torch

from areasearch.training.config import PPOConfig, TrainConfig
from areasearch.training.ppo import (
    approx_kl,
    clip_fraction,
    episode_gae,
    explained_variance,
    gae,
    normalize,
    policy_loss,
    ppo_update,
    value_loss,
)
from areasearch.training.rollout import play
from areasearch.training.trajectory import EpisodeSpec, Trajectory

# ---------------------------------------------------------------------------------------------- GAE


def _recursion(
    rewards: list[float], values: list[float], dones: list[bool], last_value: float, gamma: float, lam: float
) -> list[float]:
    """GAE written out: A_t = delta_t + gamma lam A_{t+1}, nothing after a terminal decision."""
    out, after = [], 0.0
    for t in reversed(range(len(rewards))):
        next_value = last_value if t == len(rewards) - 1 else values[t + 1]
        if dones[t]:
            next_value, after = 0.0, 0.0
        after = rewards[t] + gamma * next_value - values[t] + gamma * lam * after
        out.append(after)
    return out[::-1]


def test_gae_three_steps_by_hand() -> None:
    rewards, values = np.array([1.0, 2.0, 3.0], np.float32), np.array([1.0, 1.0, 1.0], np.float32)
    # gamma = lam = 0.5 keeps every number exact: deltas 0.5, 1.5, then 2 (terminal) or 4 (bootstrap 4)
    adv, ret = gae(rewards, values, np.array([False, False, True]), 4.0, 0.5, 0.5)
    assert adv.tolist() == [1.0, 2.0, 2.0]  # 2; 1.5 + 0.25 * 2; 0.5 + 0.25 * 2
    assert ret.tolist() == [2.0, 3.0, 3.0]
    adv, ret = gae(rewards, values, np.array([False, False, False]), 4.0, 0.5, 0.5)
    assert adv.tolist() == [1.125, 2.5, 4.0]  # 3 + 0.5 * 4 - 1; 1.5 + 0.25 * 4; 0.5 + 0.25 * 2.5
    assert ret.tolist() == [2.125, 3.5, 5.0]
    assert adv.dtype == ret.dtype == np.float32


@pytest.mark.parametrize("last_done", [True, False])
def test_gae_four_steps_against_the_recursion(last_done: bool) -> None:
    rewards, values = [1.0, 0.0, -2.0, 0.5], [0.3, -0.7, 1.1, 0.4]
    dones = [False, False, False, last_done]
    adv, ret = gae(np.array(rewards), np.array(values), np.array(dones), 2.5, 0.9, 0.8)
    expected = _recursion(rewards, values, dones, 2.5, 0.9, 0.8)
    assert adv == pytest.approx(expected, abs=1e-12)
    assert ret == pytest.approx(np.array(expected) + values, abs=1e-12)


def test_gae_does_not_look_past_a_terminal_decision() -> None:
    rewards, values = np.array([1.0, 2.0, 3.0, 4.0]), np.array([0.5, 0.25, 2.0, 1.0])
    both, _ = gae(rewards, values, np.array([False, True, False, False]), 3.0, 0.9, 0.7)
    first, _ = gae(rewards[:2], values[:2], np.array([False, True]), 99.0, 0.9, 0.7)
    second, _ = gae(rewards[2:], values[2:], np.array([False, False]), 3.0, 0.9, 0.7)
    assert both == pytest.approx(np.concatenate([first, second]), abs=1e-12)
    assert first[1] == 2.0 - 0.25  # the terminal decision: its reward less its value


def test_gae_lambda_one_is_the_discounted_return_and_zero_the_td_error() -> None:
    rewards, values, gamma = np.array([1.0, -1.0, 2.0]), np.array([0.5, 0.2, -0.3]), 0.9
    dones = np.array([False, False, False])
    _, ret = gae(rewards, values, dones, 1.5, gamma, 1.0)
    mc = [1.0 - 0.9 + 0.81 * 2.0 + 0.729 * 1.5, -1.0 + 0.9 * 2.0 + 0.81 * 1.5, 2.0 + 0.9 * 1.5]
    assert ret == pytest.approx(mc, abs=1e-12)
    td, _ = gae(rewards, values, dones, 1.5, gamma, 0.0)
    assert td == pytest.approx([1.0 + 0.9 * 0.2 - 0.5, -1.0 + 0.9 * -0.3 - 0.2, 2.0 + 0.9 * 1.5 + 0.3], abs=1e-12)


def test_episode_gae_scales_rewards_and_ends_at_the_horizon(hand_trajectory: Callable[..., Trajectory]) -> None:
    """The horizon is the end of the mission: a truncated episode is not bootstrapped (the stored
    last value is never read), exactly like a terminated one."""
    spec = EpisodeSpec("wrs2020_arena", 2, 0, 80)  # 40 steps a decision
    for terminated in (True, False):
        adv, _ = episode_gae(hand_trajectory([2.0, 4.0], [1.0, 1.0], terminated, 8.0, spec, [], []), 0.5, 0.5, 0.5)
        assert adv.tolist() == [0.5 + 0.25 * 1.0, 1.0]  # deltas 1 + 0.5 - 1 and 2 - 1; the 8 unused


# ---------------------------------------------------------------------------------------------- losses

RATIOS = [0.5, 0.9, 1.1, 1.5]  # two outside [0.8, 1.2], two inside


def test_clipped_surrogate_values_and_where_its_gradient_vanishes() -> None:
    ratio = torch.tensor(RATIOS * 2, dtype=torch.float64, requires_grad=True)
    adv = torch.tensor([1.0] * 4 + [-1.0] * 4, dtype=torch.float64)
    loss = policy_loss(ratio, adv, 0.2)
    # A > 0: -min(r, clip(r)) = -0.5, -0.9, -1.1, -1.2; A < 0: max(r, clip(r)) = 0.8, 0.9, 1.1, 1.5
    per_decision = [-0.5, -0.9, -1.1, -1.2, 0.8, 0.9, 1.1, 1.5]
    assert loss.item() == pytest.approx(sum(per_decision) / 8, abs=1e-12)
    loss.backward()
    assert ratio.grad is not None
    # -A / N where the unclipped term is the pessimistic one, 0 where the clip binds: r = 1.5 with A > 0
    # and r = 0.5 with A < 0; r = 0.5 with A > 0 and r = 1.5 with A < 0 are outside but not clipped
    n = 8
    assert ratio.grad.tolist() == pytest.approx([-1 / n, -1 / n, -1 / n, 0.0, 0.0, 1 / n, 1 / n, 1 / n], abs=1e-12)


def test_clipped_surrogate_with_other_advantages_and_clip() -> None:
    ratio = torch.tensor([0.6, 1.0, 1.6], dtype=torch.float64, requires_grad=True)
    adv = torch.tensor([2.0, -3.0, 0.5], dtype=torch.float64)
    loss = policy_loss(ratio, adv, 0.3)
    # -min(2 * 0.6, 2 * 0.7) = -1.2; -min(-3, -3) = 3; -min(0.8, 0.65) = -0.65
    assert loss.item() == pytest.approx((-1.2 + 3.0 - 0.65) / 3, abs=1e-12)
    loss.backward()
    assert ratio.grad is not None
    assert ratio.grad.tolist() == pytest.approx([-2 / 3, 1.0, 0.0], abs=1e-12)


def test_value_loss_unclipped_and_clipped() -> None:
    returns = torch.tensor([0.0, 4.0], dtype=torch.float64)
    old = torch.tensor([1.0, 1.0], dtype=torch.float64)
    values = torch.tensor([1.0, 2.0], dtype=torch.float64, requires_grad=True)
    plain = value_loss(values, returns, old, None)
    assert plain.item() == pytest.approx(0.5 * (1.0 + 4.0) / 2, abs=1e-12)
    plain.backward()
    assert values.grad is not None
    assert values.grad.tolist() == pytest.approx([0.5, -1.0], abs=1e-12)  # (v - R) / N

    values = torch.tensor([1.5, 2.0], dtype=torch.float64, requires_grad=True)
    clipped = value_loss(values, returns, old, 0.2)
    # clipped values 1.2, 1.2; errors max(1.5^2, 1.2^2) = 2.25 and max(2^2, 2.8^2) = 7.84
    assert clipped.item() == pytest.approx(0.5 * (2.25 + 7.84) / 2, abs=1e-12)
    clipped.backward()
    assert values.grad is not None
    # the first from the unclipped error, (1.5 - 0) / 2; the second's clipped value does not move
    assert values.grad.tolist() == pytest.approx([0.75, 0.0], abs=1e-12)


def test_k3_kl_estimate_on_given_log_ratios() -> None:
    log_ratio = torch.tensor([0.0, math.log(2.0), -math.log(2.0)], dtype=torch.float64)
    kl = approx_kl(log_ratio, log_ratio.exp())
    # 0; (2 - 1) - ln 2; (0.5 - 1) + ln 2: the ln 2 cancel, 0.5 over 3 samples
    assert float(kl) == pytest.approx(0.5 / 3, abs=1e-12)
    small = torch.tensor([0.01, -0.02], dtype=torch.float64)
    assert float(approx_kl(small, small.exp())) == pytest.approx((0.01**2 + 0.02**2) / 4, rel=0.02)  # ~ x^2 / 2


def test_clip_fraction_normalize_and_explained_variance() -> None:
    assert float(clip_fraction(torch.tensor([0.7, 0.9, 1.0, 1.3]), 0.2)) == 0.5
    adv = normalize(torch.tensor([1.0, 2.0, 3.0, 6.0], dtype=torch.float64))
    assert float(adv.mean()) == pytest.approx(0.0, abs=1e-12) and float(adv.std()) == pytest.approx(1.0, abs=1e-7)
    returns = np.array([1.0, 2.0, 3.0])
    assert explained_variance(returns, returns) == 1.0
    assert explained_variance(returns, np.zeros(3)) == 0.0
    assert explained_variance(returns, returns + 1.0) == 1.0  # an offset is not variance
    assert explained_variance(returns, np.array([3.0, 2.0, 1.0])) == pytest.approx(1 - (8 / 3) / (2 / 3))
    assert math.isnan(explained_variance(np.ones(3), np.zeros(3)))


# ---------------------------------------------------------------------------------------------- target_kl


class CountingAdam(torch.optim.Adam):
    """Adam that counts its steps: one per minibatch :func:`ppo_update` runs."""

    def __init__(self, params: Any, lr: float) -> None:
        super().__init__(params, lr=lr)
        self.steps = 0

    def step(self, closure: Any = None) -> Any:
        self.steps += 1
        return super().step(closure)


@pytest.fixture(scope="module")
def played() -> tuple[TrainConfig, dict[str, np.ndarray], Trajectory]:
    """A tiny network's config and weights and a 3-decision episode it played."""
    from areasearch.models.network import DAHGNN
    from areasearch.models.network_config import NetworkConfig

    network = NetworkConfig(rounds=1, node_dim=16, history_dim=16).validate()
    config = TrainConfig(seed=1, network=network, ppo=PPOConfig(epochs=2, minibatch_size=1)).validate()
    torch.manual_seed(0)
    weights = {k: v.detach().numpy().copy() for k, v in DAHGNN(network).state_dict().items()}
    traj = play(dataclasses.asdict(network), weights, EpisodeSpec("wrs2020_arena", 2, 5, 120))
    assert len(traj.rewards) == 3
    return config, weights, traj


def _update_steps(
    played: tuple[TrainConfig, dict[str, np.ndarray], Trajectory], target_kl: float, shifted: list[int]
) -> int:
    """Optimizer steps of one ppo_update (learning rate 0: the policy stays the acting one) when the
    stored log-probabilities of the decisions ``shifted`` are 0.5 below the acting policy's, so that
    those decisions' minibatches have log ratio 0.5 and approx_kl e^0.5 - 1.5 = 0.149, the others 0."""
    from areasearch.models.network import DAHGNN

    config, weights, traj = played
    config = dataclasses.replace(config, ppo=dataclasses.replace(config.ppo, target_kl=target_kl))
    model = DAHGNN(config.network)
    model.load_state_dict({k: torch.from_numpy(v) for k, v in weights.items()})
    log_probs = traj.log_probs.copy()
    log_probs[shifted] -= 0.5
    optimizer = CountingAdam(model.parameters(), lr=0.0)
    stats = ppo_update(model, optimizer, [dataclasses.replace(traj, log_probs=log_probs)], config, 1, 0.0)
    if len(shifted) == 3:
        assert stats["losses/approx_kl"] == pytest.approx(math.exp(0.5) - 1.5, rel=1e-3)
    return optimizer.steps


def test_target_kl_stops_after_the_first_minibatch_past_it(played: Any) -> None:
    # every minibatch is past target_kl: the first one takes its step, then nothing more runs
    assert _update_steps(played, 0.01, [0, 1, 2]) == 1
    # none is: all 2 epochs x 3 minibatches of 1 decision
    assert _update_steps(played, 0.01, []) == 6
    # the same KL, but target_kl 0 (off) or above it: never stops
    assert _update_steps(played, 0.0, [0, 1, 2]) == 6
    assert _update_steps(played, 0.2, [0, 1, 2]) == 6
    # one decision past it: the epoch stops at its minibatch, wherever the shuffle put it
    assert sorted(_update_steps(played, 0.01, [k]) for k in range(3)) == [1, 2, 3]


# ---------------------------------------------------------------------------------------------- learning


def _two_goal_task(base: dict[str, np.ndarray], rng: np.random.Generator) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """An observation of 2 robots and 2 candidates (frontiers at random, each near one robot), and
    the right goals: each robot to the candidate *farther* from it (distinct by construction). The
    untrained network sends each robot to its nearer candidate (distance is an input of its
    attention), so the task has to be learnt, from the reward alone."""
    obs = {k: np.array(v, copy=True) for k, v in base.items()}
    side = obs["map"].shape[1] * float(obs["map_scale"][0])  # full-map cells the observation spans
    robots = rng.uniform(0.2 * side, 0.8 * side, size=(2, 2))
    order = rng.permutation(2)
    cands = (robots + rng.uniform(-0.1 * side, 0.1 * side, size=(2, 2)))[order]  # row k is near robot order[k]
    obs["robots"][:, :2] = robots
    obs["robots"][:, 2] = rng.uniform(-np.pi, np.pi, 2)
    obs["candidates"][:] = 0.0
    obs["candidates"][:2] = np.column_stack([cands, np.zeros(2), np.full(2, 10.0), np.full(2, 100.0)])
    obs["candidate_mask"][:] = False
    obs["candidate_mask"][:2] = True
    obs["distances"][:] = np.inf
    obs["distances"][:, :2] = np.hypot(*(robots[:, None] - cands[None]).transpose(2, 0, 1)) * float(obs["cell_m"][0])
    obs["action_mask"][:] = False
    obs["action_mask"][:, :2] = True
    return obs, 1 - np.argsort(order)


@pytest.mark.slow
def test_ppo_with_the_real_network_learns_a_two_goal_assignment() -> None:
    """In the spirit of Stable-Baselines3's identity tests: one-decision episodes of the task above,
    team reward = the share of robots sent to their right goal; the DA-HGNN network (2 rounds, the
    rest of its default config), goals sampled by :func:`~areasearch.models.dahgnn.act`, advantages by
    :func:`~areasearch.training.ppo.gae`, updates by :func:`~areasearch.training.ppo.ppo_update`. The evaluation-time
    assignment must reach >= 95 % exact assignments on 200 held-out tasks within 60 iterations of 64
    episodes (it starts at 0.5 %; 95 % after 45 iterations here, 23 s of one core)."""
    from areasearch.envs.goal import AreaSearchEnv
    from areasearch.models.dahgnn import act
    from areasearch.models.network import DAHGNN
    from areasearch.models.network_config import NetworkConfig

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        base, _ = AreaSearchEnv(map="wrs2020_arena", num_robots=2, seed=0).reset(seed=0)
        network = NetworkConfig(rounds=2).validate()
        ppo = PPOConfig(epochs=4, minibatch_size=32, learning_rate=3e-3, ent_coef=0.0, target_kl=0.0)
        config = TrainConfig(seed=0, network=network, ppo=ppo).validate()
        torch.manual_seed(0)
        model = DAHGNN(network)
        optimizer = torch.optim.Adam(model.parameters(), lr=ppo.learning_rate, eps=1e-5)
        held_out = [_two_goal_task(base, np.random.default_rng(10_000 + i)) for i in range(200)]

        def accuracy() -> float:
            model.eval()
            goals = act(model, [o for o, _ in held_out], deterministic=True).actions.numpy()
            return float(np.mean([(goals[i] == right).all() for i, (_, right) in enumerate(held_out)]))

        assert accuracy() < 0.05
        rng = np.random.default_rng(0)
        scores = []
        for iteration in range(1, 61):
            tasks = [_two_goal_task(base, rng) for _ in range(64)]
            model.eval()
            res = act(model, [o for o, _ in tasks], generator=torch.Generator().manual_seed(iteration))
            trajectories = []
            for i, (obs, right) in enumerate(tasks):
                goals = res.actions[i].numpy()
                reward = float((goals == right).mean())
                stored = dict(obs, map=obs["map"].astype(np.float16))
                trajectories.append(
                    Trajectory(
                        EpisodeSpec("task", 2, i, 40),
                        [stored],
                        [goals],
                        res.robot_log_prob[i : i + 1].numpy(),
                        res.value[i : i + 1].numpy(),
                        np.array([reward], np.float32),
                        np.zeros(1, np.float32),
                        True,
                        0.0,
                        {"steps": 40},
                        [0, 40],
                        [0.0, 0.0],
                        0.0,
                    )
                )
            ppo_update(model, optimizer, trajectories, config, iteration, 0.0)
            if iteration % 5 == 0:
                scores.append(accuracy())
                if scores[-1] >= 0.95:
                    break
        assert scores[-1] >= 0.95, scores
    finally:
        torch.set_num_threads(threads)


def test_per_robot_surrogate_kl_and_clipfrac_by_hand() -> None:
    """ratio = "robot": each robot that chose has its own ratio and the team's advantage; the loss, the
    KL and the clip fraction are means over those robots (a padded or choiceless robot counts for
    nothing, whatever its ratio)."""
    ratio = torch.tensor([[1.5, 0.9, 7.0], [0.5, 1.1, 1.0]], dtype=torch.float64)
    weights = torch.tensor([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0]], dtype=torch.float64)
    adv = torch.tensor([[2.0], [-1.0]], dtype=torch.float64)
    # A = 2: max(-3, -2.4) = -2.4 (clipped at 1.2), max(-1.8, -1.8) = -1.8; A = -1: max(0.5, 0.8) = 0.8, 1.1
    assert policy_loss(ratio, adv, 0.2, weights).item() == pytest.approx((-2.4 - 1.8 + 0.8 + 1.1) / 4)
    log_ratio = ratio.log()
    expected = sum(float(r - 1 - math.log(r)) for r in (1.5, 0.9, 0.5, 1.1)) / 4
    assert float(approx_kl(log_ratio, ratio, weights)) == pytest.approx(expected)
    assert float(clip_fraction(ratio, 0.2, weights)) == 0.5  # 1.5 and 0.5; the 7.0 is not a robot's


# ---------------------------------------------------------------------------------------------- sharded update


@pytest.fixture(scope="module")
def two_episodes() -> tuple[TrainConfig, dict[str, np.ndarray], list[Trajectory]]:
    """A tiny network and two short episodes it played, of 3 and 4 robots (rows of two widths)."""
    from areasearch.models.network import DAHGNN
    from areasearch.models.network_config import NetworkConfig

    network = NetworkConfig(rounds=2, node_dim=16, history_dim=16).validate()
    config = TrainConfig(seed=3, network=network, ppo=PPOConfig(epochs=2, minibatch_size=4, target_kl=0.0)).validate()
    torch.manual_seed(1)
    weights = {k: v.detach().numpy().copy() for k, v in DAHGNN(network).state_dict().items()}
    trajs = [
        play(dataclasses.asdict(network), weights, EpisodeSpec("wrs2020_arena", robots, seed, 240))
        for robots, seed in ((3, 5), (4, 6))
    ]
    # stored log-probabilities off the acting policy's, so that ratios differ from 1 and some clip
    rng = np.random.default_rng(0)
    trajs = [
        dataclasses.replace(t, log_probs=t.log_probs + rng.normal(0, 0.3, t.log_probs.shape).astype(np.float32))
        for t in trajs
    ]
    return config, weights, trajs


def _model(config: TrainConfig, weights: dict[str, np.ndarray]) -> Any:
    from areasearch.models.network import DAHGNN

    model = DAHGNN(config.network)
    model.load_state_dict({k: torch.from_numpy(v) for k, v in weights.items()})
    return model.train()


@pytest.mark.parametrize(("ratio", "clip_vloss"), [("robot", False), ("team", True)])
def test_the_shards_gradients_add_up_to_the_minibatch_gradient(two_episodes: Any, ratio: str, clip_vloss: bool) -> None:
    from areasearch.runners import InProcess
    from areasearch.training.ppo import Decisions, minibatch_gradient
    from areasearch.training.ppo_shards import sharded_gradient

    config, weights, trajs = two_episodes
    p = dataclasses.replace(config.ppo, ratio=ratio, clip_vloss=clip_vloss, shards=3)
    config = dataclasses.replace(config, ppo=p)
    data = Decisions.gather(trajs, config)
    idx = np.random.default_rng(2).permutation(len(data))  # the whole iteration as one minibatch, shuffled
    assert len(idx) >= 6
    whole, sharded = _model(config, weights), _model(config, weights)
    terms = minibatch_gradient(whole, data, idx, p, 0.5)
    graphs = {k: v.numpy() for k, v in data.graphs._asdict().items()}
    shard_terms = sharded_gradient(sharded, data, graphs, idx, p, 0.5, InProcess())
    assert shard_terms.keys() == terms.keys()
    for key in terms:
        assert shard_terms[key] == pytest.approx(terms[key], rel=1e-4, abs=1e-6), key
    assert 0 < terms["losses/clipfrac"] < 1  # the clipped and the unclipped branch both taken
    reached = 0
    for (name, a), b in zip(whole.named_parameters(), sharded.parameters(), strict=True):
        assert (a.grad is None) == (b.grad is None), name
        if a.grad is not None:
            reached += 1
            torch.testing.assert_close(b.grad, a.grad, rtol=1e-4, atol=1e-6, msg=name)
    assert reached > 10


def test_a_shards_graphs_are_the_learners_rows(two_episodes: Any) -> None:
    from areasearch.training.ppo import Decisions
    from areasearch.training.ppo_shards import shard_graphs

    config, _, trajs = two_episodes
    data = Decisions.gather(trajs, config)
    rows = np.array([len(data) - 1, 0, 2])
    expected = data.graphs.index(torch.from_numpy(rows)).trim()
    got = shard_graphs({k: v.numpy() for k, v in data.graphs._asdict().items()}, rows)
    for name, a, b in zip(expected._fields, expected, got, strict=True):
        assert torch.equal(a, b), name


def test_a_sharded_update_is_the_same_in_worker_processes_and_here(two_episodes: Any) -> None:
    from areasearch.runners import InProcess, ProcessPool
    from areasearch.training.ppo_shards import ShardedGradient

    config, weights, trajs = two_episodes
    config = dataclasses.replace(config, ppo=dataclasses.replace(config.ppo, shards=2))
    results = []
    pool = ProcessPool(2)
    try:
        for runner in (InProcess(), pool):
            model = _model(config, weights)
            optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
            stats = ppo_update(model, optimizer, trajs, config, 1, 0.5, ShardedGradient(runner))
            results.append((model.state_dict(), stats))
    finally:
        pool.close()
    (here, here_stats), (there, there_stats) = results
    assert here_stats == there_stats
    assert all(torch.equal(here[k], there[k]) for k in here)
    assert any(not torch.equal(here[k], torch.from_numpy(weights[k])) for k in here)  # the update moved them


def test_update_inputs_made_as_episodes_come_back_give_the_same_update(two_episodes: Any) -> None:
    """The training loop makes the update's graphs and health numbers episode by episode, in the order
    the lockstep groups come back (UpdateInputs): the same update, bit for bit, as one that makes them
    itself; the health numbers are made as soon as the first decisions' graphs are in."""
    from areasearch.models.graph import build_graph
    from areasearch.training.ppo import HEALTH_DECISIONS, Decisions, UpdateInputs, _observation32

    config, weights, trajs = two_episodes
    assert len(trajs[0].rewards) < HEALTH_DECISIONS  # the health numbers need the second episode too
    results = []
    for order in ([0, 1], [1, 0]):
        model = _model(config, weights).eval()
        inputs = UpdateInputs(model, config, len(trajs))
        for i in order:
            assert inputs.health is None
            inputs.add(i, trajs[i])
        assert inputs.health is not None and all(k.startswith("health/") for k in inputs.health)
        optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
        stats = ppo_update(model, optimizer, trajs, config, 1, 0.5, inputs=inputs)
        results.append((model.state_dict(), stats))
    model = _model(config, weights).eval()
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3)
    results.append((model.state_dict(), ppo_update(model, optimizer, trajs, config, 1, 0.5)))
    (first, first_stats), *others = results
    for state, stats in others:
        assert stats == first_stats
        assert all(torch.equal(first[k], state[k]) for k in first)
    assert any(not torch.equal(first[k], torch.from_numpy(weights[k])) for k in first)  # the update moved them
    # the iteration's batch from the graphs made one by one is build_graph's, field by field
    inputs = UpdateInputs(_model(config, weights), config, len(trajs))
    inputs.add(1, trajs[1])
    with pytest.raises(ValueError, match=r"episodes \[0\] were never added"):
        inputs.all_graphs()
    inputs.add(0, trajs[0])
    made = Decisions.gather(trajs, config, inputs.all_graphs()).graphs
    built = build_graph([_observation32(o) for t in trajs for o in t.observations], config.network.graph)
    for name, a, b in zip(made._fields, made, built, strict=True):
        assert torch.equal(a, b), name


def test_health_numbers_wait_for_the_first_decisions_only(two_episodes: Any) -> None:
    from areasearch.training.ppo import HEALTH_DECISIONS, UpdateInputs

    config, weights, trajs = two_episodes
    copies = -(-HEALTH_DECISIONS // len(trajs[1].observations))
    long = dataclasses.replace(trajs[1], observations=trajs[1].observations * copies)
    inputs = UpdateInputs(_model(config, weights), config, 3)
    inputs.add(0, long)  # the first episode alone holds the first HEALTH_DECISIONS decisions
    assert inputs.health is not None
    late = UpdateInputs(_model(config, weights), config, 3)
    late.add(2, long)
    late.add(1, trajs[0])
    assert late.health is None  # episode 0 is not in yet
    late.add(0, long)
    assert late.health == inputs.health


def _clip_with(foreach: bool) -> Callable[..., Any]:
    """``clip_grad_norm_`` on the per-tensor (False) or the multi-tensor (True) path, whatever its caller asks."""
    real = torch.nn.utils.clip_grad_norm_

    def clip(params: Any, max_norm: float, **_: Any) -> Any:
        return real(params, max_norm, foreach=foreach)

    return clip


def test_the_multi_tensor_adam_and_clipping_give_the_per_tensor_numbers(two_episodes: Any) -> None:
    """The trainer's Adam (foreach) and gradient clipping take the multi-tensor path for speed: the
    same weights, bit for bit, as the per-tensor loop over a whole update of the real network."""
    config, weights, trajs = two_episodes
    states = []
    for foreach in (False, True):
        model = _model(config, weights)
        optimizer = torch.optim.Adam(model.parameters(), lr=1e-3, eps=1e-5, foreach=foreach)
        with unittest.mock.patch.object(torch.nn.utils, "clip_grad_norm_", _clip_with(foreach)):
            stats = ppo_update(model, optimizer, trajs, config, 1, 0.5)
        states.append((model.state_dict(), stats))
    (loop, loop_stats), (multi, multi_stats) = states
    assert loop_stats == multi_stats and loop_stats["losses/minibatches"] >= 2
    assert all(torch.equal(loop[k], multi[k]) for k in loop)
    assert any(not torch.equal(loop[k], torch.from_numpy(weights[k])) for k in loop)  # the update moved them


def test_shards_must_be_positive() -> None:
    from areasearch.errors import ConfigError

    with pytest.raises(ConfigError, match=r"ppo\.shards"):
        TrainConfig(ppo=PPOConfig(shards=0)).validate()
