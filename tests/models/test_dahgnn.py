"""The DA-HGNN network: equivariance, masks, Sinkhorn, batching, gradients, ablations, files, a real episode."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from areasearch.envs.goal import AreaSearchEnv
from areasearch.errors import ConfigError
from areasearch.models.affinity import pair_mlp, pair_mlp_reference, sinkhorn, sinkhorn_reference
from areasearch.models.blocks import mlp, run_mlp
from areasearch.models.cross_attention import cross_attention, cross_attention_reference
from areasearch.models.dahgnn import act, assign_goals, decide, diagnose, evaluate_actions, sequential_mask
from areasearch.models.graph import GraphConfig, build_graph
from areasearch.models.kernels import pair_rows
from areasearch.models.network import DAHGNN, log_sinkhorn
from areasearch.models.network_config import NetworkConfig
from areasearch.models.self_attention import sparse_attention, sparse_attention_reference
from areasearch.models.weights import load_policy, save_policy

SMALL = NetworkConfig(
    graph=GraphConfig(patch_cells=4),
    rounds=2,
    node_dim=16,
    history_dim=8,
    heads=2,
    attention_hidden=8,
    edge_dim=4,
    update_hidden=8,
    critic_channels=8,
    critic_hidden=8,
)


def observation(
    rng: np.random.Generator, robots: int = 3, candidates: int = 12, history: int = 3, pad: int = 2
) -> dict:
    """A random observation shaped like the goal environment's (both candidate kinds, history)."""
    s, c = 24, candidates + pad
    grid = (rng.random((7, s, s)) > 0.7).astype(np.float32)
    cand = np.zeros((c, 5), dtype=np.float32)
    cand[:candidates, :2] = rng.integers(0, 4 * s, (candidates, 2))
    cand[:candidates, 2] = np.arange(candidates) % 3 == 0
    cand[:candidates, 3] = rng.integers(1, 50, candidates)
    cand[:candidates, 4] = rng.integers(0, 3000, candidates)
    mask = np.zeros(c, dtype=np.int8)
    mask[:candidates] = 1
    dist = np.full((robots, c), np.inf, dtype=np.float32)
    dist[:, :candidates] = rng.uniform(0.2, 15.0, (robots, candidates))
    dist[0, 1] = np.inf
    action = np.isfinite(dist).astype(np.int8)
    if candidates > 2:
        action[1, 2] = 0
    goals = rng.integers(0, 4 * s, (history, robots, 2)).astype(np.float32)
    goals[0, 0] = -1.0
    return {
        "map": grid,
        "map_scale": np.array([4.0], dtype=np.float32),
        "robots": np.concatenate([rng.integers(0, 4 * s, (robots, 2)), rng.uniform(-3, 3, (robots, 1))], 1).astype(
            np.float32
        ),
        "candidates": cand,
        "candidate_mask": mask,
        "distances": dist,
        "action_mask": action,
        "history_robots": rng.integers(0, 4 * s, (history, robots, 2)).astype(np.float32),
        "history_goals": goals,
        "history_mask": np.array([1] * (history - 1) + [0], dtype=np.int8),
        "progress": np.array([0.4], dtype=np.float32),
    }


def model(config: NetworkConfig = SMALL, seed: int = 0) -> DAHGNN:
    """A seeded network whose first policy is far from uniform (the affinity score at gain 3 instead
    of 0.01), so that the distribution reacts to every upstream change."""
    torch.manual_seed(seed)
    net = DAHGNN(config).eval()
    torch.nn.init.orthogonal_(net.similarity.score.weight, 3.0)
    return net


def forward(net: DAHGNN, obs: dict | list[dict]):  # type: ignore[no-untyped-def]
    with torch.no_grad():
        return net(build_graph(obs, net.config.graph))


def probabilities(out) -> torch.Tensor:  # type: ignore[no-untyped-def]
    return torch.softmax(out.logits, dim=-1)


SPARSE = dataclasses.replace(SMALL, graph=dataclasses.replace(SMALL.graph, neighbours=3))
"""Each candidate attends to 3 of the 12: the neighbour lists matter."""


@pytest.mark.parametrize("config", [SMALL, SPARSE, dataclasses.replace(SMALL, type_aware=False, history=False)])
def test_permuting_candidates_permutes_the_distribution(config: NetworkConfig) -> None:
    rng = np.random.default_rng(0)
    obs = observation(rng, pad=0)
    perm = rng.permutation(len(obs["candidates"]))
    moved = dict(obs)
    moved["candidates"] = obs["candidates"][perm]
    moved["candidate_mask"] = obs["candidate_mask"][perm]
    moved["distances"] = obs["distances"][:, perm]
    moved["action_mask"] = obs["action_mask"][:, perm]
    net = model(config)
    a, b = forward(net, obs), forward(net, moved)
    torch.testing.assert_close(probabilities(b), probabilities(a)[:, :, perm], atol=1e-5, rtol=1e-4)
    torch.testing.assert_close(b.log_s[:, :-1, :-1], a.log_s[:, :-1, :-1][:, :, perm], atol=1e-4, rtol=1e-4)
    torch.testing.assert_close(b.value, a.value)


def test_permuting_robots_permutes_the_distribution() -> None:
    rng = np.random.default_rng(1)
    obs = observation(rng, pad=0)
    perm = np.array([2, 0, 1])
    moved = dict(obs)
    for key in ("robots", "distances", "action_mask"):
        moved[key] = obs[key][perm]
    for key in ("history_robots", "history_goals"):
        moved[key] = obs[key][:, perm]
    net = model()
    a, b = forward(net, obs), forward(net, moved)
    torch.testing.assert_close(probabilities(b), probabilities(a)[:, perm], atol=1e-5, rtol=1e-4)
    torch.testing.assert_close(b.value, a.value)


@pytest.mark.parametrize("config", [SMALL, SPARSE])
def test_masked_and_padded_nodes_change_nothing(config: NetworkConfig) -> None:
    rng = np.random.default_rng(2)
    obs = observation(rng, candidates=8, pad=0)
    extra = observation(rng, candidates=11, pad=0)
    noisy = dict(obs)
    # three masked candidates with arbitrary features and finite distances, in the middle
    noisy["candidates"] = np.concatenate([obs["candidates"][:4], extra["candidates"][:3], obs["candidates"][4:]])
    noisy["candidate_mask"] = np.concatenate([np.ones(4), np.zeros(3), np.ones(4)]).astype(np.int8)
    noisy["distances"] = np.concatenate([obs["distances"][:, :4], np.ones((3, 3)), obs["distances"][:, 4:]], axis=1)
    noisy["action_mask"] = np.concatenate([obs["action_mask"][:, :4], np.ones((3, 3)), obs["action_mask"][:, 4:]], 1)
    keep = [0, 1, 2, 3, 7, 8, 9, 10]
    net = model(config)
    a, b = forward(net, obs), forward(net, noisy)
    torch.testing.assert_close(probabilities(b)[:, :, keep], probabilities(a), atol=1e-5, rtol=1e-4)
    assert (probabilities(b)[:, :, 4:7] == 0).all()
    torch.testing.assert_close(b.value, a.value)


def test_masked_candidates_get_probability_zero_and_are_never_sampled() -> None:
    rng = np.random.default_rng(3)
    obs = observation(rng)
    out = forward(model(), obs)
    p = probabilities(out)[0]
    allowed = torch.from_numpy(obs["action_mask"][:, : p.shape[1]].astype(bool))
    assert (p[~allowed] == 0).all() and (p[allowed] > 0).all()
    torch.testing.assert_close(p.sum(-1), torch.ones(3))
    net = model()
    for seed in range(20):
        result = act(net, [obs], generator=torch.Generator().manual_seed(seed))
        picked = result.actions[0].numpy()
        assert obs["action_mask"][np.arange(3), picked].all()


@pytest.mark.parametrize("case", ["no frontiers", "no targets", "no candidates", "no history", "no choice"])
@pytest.mark.parametrize("config", [SMALL, NetworkConfig.ncm(rounds=1)])
def test_degenerate_decisions_give_no_nan(case: str, config: NetworkConfig) -> None:
    obs = observation(np.random.default_rng(4))
    kinds = obs["candidates"][:, 2]
    if case == "no frontiers":
        obs["candidates"][:, 2] = 1.0
    elif case == "no targets":
        obs["candidates"][:, 2] = 0.0
    elif case == "no candidates":
        obs["candidate_mask"][:] = 0
        obs["distances"][:] = np.inf
        obs["action_mask"][:] = 0
    elif case == "no history":
        obs["history_mask"][:] = 0
    else:
        obs["action_mask"][1] = 0
    assert kinds is not None
    net = model(config).train()
    batch = build_graph(obs, config.graph)
    out = net(batch)
    for name, tensor in zip(out._fields, out, strict=True):
        if tensor.is_floating_point() and name != "logits":
            assert torch.isfinite(tensor).all(), name
    assert not torch.isnan(out.logits).any()
    result = act(net, [obs], deterministic=True)
    assert torch.isfinite(result.log_prob).all() and torch.isfinite(result.entropy).all()
    res = evaluate_actions(net, batch, result.actions)
    (res.log_prob.sum() + res.entropy.sum() + res.value.sum() + res.explored_ratio.sum()).backward()
    for name, p in net.named_parameters():
        assert p.grad is None or torch.isfinite(p.grad).all(), name
    if case in ("no candidates", "no choice"):
        robots = [0, 1, 2] if case == "no candidates" else [1]
        assert (result.actions[0, robots] == 0).all() and (result.entropy == result.entropy).all()


def sums(log_s: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    s = log_s.exp()
    return s.sum(-1), s.sum(-2)


def test_sinkhorn_square_is_doubly_stochastic() -> None:
    scores = torch.randn(2, 4, 4) * 3
    ones = torch.ones(2, 4, dtype=torch.bool)
    rows, cols = sums(log_sinkhorn(scores, torch.ones(2, 4, 4, dtype=torch.bool), ones, ones, None, iters=100))
    torch.testing.assert_close(rows, torch.ones(2, 4), atol=1e-4, rtol=0)
    torch.testing.assert_close(cols, torch.ones(2, 4), atol=1e-4, rtol=0)


@pytest.mark.parametrize("shape", [(3, 3), (2, 7), (6, 3)])
def test_sinkhorn_with_slack_gives_unit_rows_and_columns(shape: tuple[int, int]) -> None:
    r, c = shape
    torch.manual_seed(0)
    scores = torch.randn(2, r, c) * 3
    pair = torch.rand(2, r, c) > 0.3
    pair[0, 0] = False  # a robot with no allowed candidate: all its mass goes to the slack column
    row_mask = torch.ones(2, r, dtype=torch.bool)
    col_mask = torch.ones(2, c, dtype=torch.bool)
    row_mask[1, -1] = False  # a padded robot and a padded candidate carry no mass
    col_mask[1, -1] = False
    log_s = log_sinkhorn(scores, pair, row_mask, col_mask, torch.tensor(0.5), iters=200)
    assert log_s.shape == (2, r + 1, c + 1)
    rows, cols = sums(log_s)
    torch.testing.assert_close(rows[:, :r][row_mask], torch.ones(int(row_mask.sum())), atol=1e-4, rtol=0)
    torch.testing.assert_close(cols[:, :c][col_mask], torch.ones(int(col_mask.sum())), atol=1e-4, rtol=0)
    s = log_s.exp()
    assert (s[:, :r, :c][~pair] < 1e-6).all()
    assert s[0, 0, c] == pytest.approx(1.0, abs=1e-4)
    assert s[1, r - 1].sum() < 1e-6 and s[1, :, c - 1].sum() < 1e-6


@pytest.mark.parametrize("grad", [False, True])
def test_batch_of_different_sizes_equals_one_by_one(grad: bool) -> None:
    rng = np.random.default_rng(5)
    observations = [
        observation(rng, robots=3, candidates=12, history=3),
        observation(rng, robots=2, candidates=5, history=2, pad=0),
        observation(rng, robots=5, candidates=20, history=4, pad=5),
    ]
    net = model()
    run = (lambda o: net(build_graph(o, net.config.graph))) if grad else (lambda o: forward(net, o))
    together = run(observations)  # with gradient: the autograd kernels and the torch Sinkhorn
    for i, obs in enumerate(observations):
        alone = run(obs)
        r, c = alone.logits.shape[1:]
        p_together, p_alone = probabilities(together)[i, :r, :c].detach(), probabilities(alone)[0].detach()
        torch.testing.assert_close(p_together, p_alone, atol=1e-5, rtol=1e-4)
        torch.testing.assert_close(together.value[i], alone.value[0], atol=1e-5, rtol=1e-4)
        torch.testing.assert_close(together.explored_ratio[i], alone.explored_ratio[0], atol=1e-5, rtol=1e-4)
    assert (probabilities(together)[1, 2:] == torch.eye(1, together.logits.shape[2])).all()  # padded robots: action 0


@pytest.mark.parametrize("config", [SMALL, NetworkConfig.ncm(rounds=2)])
def test_gradients_reach_every_parameter(config: NetworkConfig) -> None:
    rng = np.random.default_rng(6)
    net = model(config).train()
    batch = build_graph([observation(rng), observation(rng, robots=2)], config.graph)
    actions = torch.tensor([[0, 3, 4], [5, 6, 0]])
    res = evaluate_actions(net, batch, actions)
    (res.log_prob.sum() + res.entropy.sum() + res.value.sum() + res.explored_ratio.sum()).backward()
    dead = [name for name, p in net.named_parameters() if p.grad is None or not p.grad.abs().sum() > 0]
    assert dead == []


def test_ablation_switches_remove_their_parameters() -> None:
    def names(cfg: NetworkConfig) -> set[str]:
        return {n for n, _ in DAHGNN(cfg).named_parameters()}

    def count(cfg: NetworkConfig) -> int:
        return sum(p.numel() for p in DAHGNN(cfg).parameters())

    no_type, no_history = dataclasses.replace(SMALL, type_aware=False), dataclasses.replace(SMALL, history=False)
    assert {n for n in names(SMALL) if "past" in n} and not {n for n in names(no_history) if "past" in n}
    assert count(no_type) < count(SMALL) and count(no_history) < count(SMALL)
    full, plain = DAHGNN(SMALL), DAHGNN(no_type)
    assert full.encoders.common[0].in_features == plain.encoders.common[0].in_features + 2  # the kind as input
    # G_e / G_c: queries and keys of their own; G_re, G_rc: messages of their own into the update
    assert full.rounds[0].goal_proj.sizes[0] == 2 * plain.rounds[0].goal_proj.sizes[0]
    assert full.rounds[0].robot_update.message[0].shape[0] == plain.rounds[0].robot_update.message[0].shape[0] + 2 * 16
    ncm = NetworkConfig.ncm()
    assert (ncm.type_aware, ncm.history, ncm.rounds, ncm.node_dim) == (False, True, 3, 32)
    ncm_net = DAHGNN(ncm)
    assert len(ncm_net.rounds) == 3 and ncm_net.encoders.common[-1].out_features == 32
    # the NCM preset is the type-blind model at 32-d: half the goal projections of the type-aware one
    typed = DAHGNN(dataclasses.replace(ncm, type_aware=True))
    assert 2 * ncm_net.rounds[0].goal_proj.sizes[0] == typed.rounds[0].goal_proj.sizes[0]
    # 125,235 without normalisation; pre-LN adds a LayerNorm (weight and bias) per node set and round
    # (robots, candidates, history: 3 x 2 x 32 x 3 = 576) and the two final ones (2 x 2 x 32 = 128)
    assert sum(p.numel() for p in ncm_net.parameters()) == 125_235 + 576 + 128
    plain_ncm = DAHGNN(dataclasses.replace(ncm, norm="none"))
    assert sum(p.numel() for p in plain_ncm.parameters()) == 125_235


def test_assignment_sends_robots_to_distinct_goals_while_there_are_enough() -> None:
    log_s = torch.log(torch.tensor([[[0.9, 0.5, 0.1, 0], [0.8, 0.1, 0.6, 0], [0.7, 0.2, 0.1, 0], [0, 0, 0, 0]]]) + 1e-9)
    allowed = torch.ones(1, 3, 3, dtype=torch.bool)
    robots = torch.ones(1, 3, dtype=torch.bool)
    goals = assign_goals(log_s, allowed, robots)[0].tolist()
    assert sorted(goals) == [0, 1, 2] and goals[2] == 0  # robot 2 wins candidate 0: 0.7 * 0.5 * 0.6 is best
    allowed[0, :, 1:] = False  # one allowed goal for three robots: all take it
    assert assign_goals(log_s, allowed, robots)[0].tolist() == [0, 0, 0]
    allowed[0] = torch.tensor([[True, True, False], [True, False, False], [False, False, False]])
    assert assign_goals(log_s, allowed, robots)[0].tolist() == [1, 0, 0]  # robot 2 has none: 0


def test_act_is_deterministic_under_a_seed() -> None:
    obs = observation(np.random.default_rng(7))
    torch.manual_seed(3)
    a = act(model(), [obs]).actions
    torch.manual_seed(3)
    b = act(model(), [obs]).actions
    assert torch.equal(a, b)


def test_save_load_round_trip(tmp_path: Path) -> None:
    net = model(NetworkConfig.ncm(rounds=1))
    weights, meta = save_policy(tmp_path / "policy", net, net.config)
    assert weights.name == "policy.safetensors" and meta.name == "policy.json"
    loaded, config = load_policy(tmp_path / "policy")
    assert config == net.config and not loaded.training
    obs = observation(np.random.default_rng(8))
    a, b = forward(net, obs), forward(loaded, obs)
    for x, y in zip(a, b, strict=True):
        torch.testing.assert_close(x, y, rtol=0, atol=0)


def test_corrupted_or_mismatched_files_raise_config_error(tmp_path: Path) -> None:
    net = model()
    weights, meta = save_policy(tmp_path / "p", net)
    good_weights, good_meta = weights.read_bytes(), meta.read_text()

    def expect(*words: str) -> None:
        with pytest.raises(ConfigError) as info:
            load_policy(tmp_path / "p")
        for word in words:
            assert word in str(info.value)
        weights.write_bytes(good_weights)
        meta.write_text(good_meta)

    weights.write_bytes(good_weights[: len(good_weights) // 2])
    expect("p.safetensors", "truncated")
    weights.write_bytes(b"\x00" * 8)
    expect("p.safetensors")
    meta.write_text(good_meta[:40])
    expect("p.json")
    doc = json.loads(good_meta)
    doc["config"]["node_dim"] = 32  # the config no longer matches the tensors
    meta.write_text(json.dumps(doc))
    expect("p.json", "shape")
    doc = json.loads(good_meta)
    doc["config"]["colour"] = "red"
    meta.write_text(json.dumps(doc))
    expect("p.json", "colour")
    doc = json.loads(good_meta)
    doc["format"] = "pickle"
    meta.write_text(json.dumps(doc))
    expect("p.json", "format")
    other = model(dataclasses.replace(SMALL, node_dim=32, history_dim=16))
    save_policy(tmp_path / "q", other)
    weights.write_bytes((tmp_path / "q.safetensors").read_bytes())  # right names, wrong shapes
    expect("p.safetensors", "shape")
    weights.unlink()
    expect("p.safetensors")
    with pytest.raises(ConfigError):
        load_policy(tmp_path / "missing")


def test_config_validation() -> None:
    with pytest.raises(ConfigError):
        DAHGNN(dataclasses.replace(SMALL, value_dim=15))  # not a multiple of the heads
    with pytest.raises(ConfigError):
        DAHGNN(dataclasses.replace(SMALL, key_dim=0))
    with pytest.raises(ConfigError):
        DAHGNN(dataclasses.replace(SMALL, rounds=0))
    with pytest.raises(ConfigError):
        NetworkConfig.ncm(type_aware="no")


def test_random_weights_pick_allowed_goals_for_five_real_decisions(small_map: str) -> None:
    torch.manual_seed(0)
    net = DAHGNN(NetworkConfig()).eval()
    env = AreaSearchEnv(map=small_map, num_robots=3, seed=0)
    obs, _ = env.reset(seed=0)
    for step in range(5):
        result = act(net, [obs], deterministic=step % 2 == 1)
        actions = result.actions[0].numpy()
        if step % 2 == 1:
            assert np.array_equal(decide(net, obs)[0].numpy(), actions)  # the planner's call: actor + assignment
        assert actions.shape == (3,)
        assert obs["action_mask"][np.arange(3), actions].all()
        if step % 2 == 1 and obs["action_mask"].any(axis=0).sum() >= 3:
            assert len(set(actions.tolist())) == 3
        assert torch.isfinite(result.value).all() and torch.isfinite(result.log_prob).all()
        obs, _, terminated, truncated, info = env.step(actions)
        assert info["invalid_goals"] == 0
        assert not (terminated or truncated)


def sparse_case(rng: torch.Generator, rows: int, graphs: int, heads: int, key_heads: int, value_heads: int):  # type: ignore[no-untyped-def]
    """Random inputs of sparse_attention: groups of 50 rows whose neighbours are their own, some missing."""
    q = torch.randn(rows, heads, 3, generator=rng, requires_grad=True)
    k = torch.randn(rows, key_heads, 3, generator=rng, requires_grad=True)
    v = torch.randn(rows, value_heads, 5, generator=rng, requires_grad=True)
    idx = torch.randint(0, 50, (rows, graphs, 6), generator=rng) + (torch.arange(rows) // 50 * 50)[:, None, None]
    idx[torch.rand(idx.shape, generator=rng) < 0.3] = -1
    idx[:3] = -1  # rows with no neighbour at all
    return q, k, v, idx


@pytest.mark.parametrize(("graphs", "heads", "key_heads", "value_heads"), [(2, 4, 4, 2), (1, 2, 1, 2), (2, 2, 2, 1)])
@pytest.mark.parametrize("threads", [1, 2])
def test_sparse_attention_kernels_match_plain_torch(
    graphs: int, heads: int, key_heads: int, value_heads: int, threads: int
) -> None:
    rows = 10_000 if threads == 2 else 500  # two threads only above 2 x 4096 rows
    q, k, v, idx = sparse_case(torch.Generator().manual_seed(heads), rows, graphs, heads, key_heads, value_heads)
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        out = sparse_attention(q, k, v, idx, 50)
        with torch.no_grad():
            torch.testing.assert_close(sparse_attention(q, k, v, idx, 50), out)  # the no-gradient path
    finally:
        torch.set_num_threads(before)
    ref = sparse_attention_reference(q, k, v, idx)
    torch.testing.assert_close(out, ref, atol=1e-5, rtol=1e-4)
    assert (out[:3] == 0).all()
    grad = torch.randn_like(out)
    for a, b in zip(torch.autograd.grad(out, (q, k, v), grad), torch.autograd.grad(ref, (q, k, v), grad), strict=True):
        torch.testing.assert_close(a, b, atol=1e-4, rtol=1e-4)


@pytest.mark.parametrize(("kinds", "heads", "both_ways"), [(2, 1, True), (2, 2, False), (1, 1, True)])
@pytest.mark.parametrize("threads", [1, 2])
def test_cross_attention_kernels_match_plain_torch(kinds: int, heads: int, both_ways: bool, threads: int) -> None:
    g = torch.Generator().manual_seed(kinds + heads)
    b, p, q, a, dv = (80, 5, 120, 4, 6) if threads == 2 else (3, 4, 7, 4, 6)
    allowed = torch.rand(b, p, q, generator=g) > 0.3
    allowed[0, 0] = False  # a node with no pair
    rows, index = pair_rows(allowed)
    assert (rows[allowed].sort().values == torch.arange(len(index))).all() and (rows[~allowed] == -1).all()
    assert allowed[tuple(index.t())].all()
    edge = torch.randn(len(index), a, generator=g, requires_grad=True)  # the pair table
    p_part = torch.randn(b, p, a, generator=g, requires_grad=True)
    q_part = torch.randn(b, q, a, generator=g, requires_grad=True)
    weight = (3 * torch.randn(heads, a, generator=g)).requires_grad_()
    bias = torch.randn(heads, generator=g, requires_grad=True)
    kind = torch.randint(-1, kinds, (b, q), generator=g)
    vq = torch.randn(b, q, dv * heads, generator=g, requires_grad=True)
    vp = torch.randn(b, p, dv * heads, generator=g, requires_grad=True) if both_ways else None
    args = (edge, rows, p_part, q_part, weight, bias, kind, vq, vp, kinds, 2.0)
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        out_p, out_q = cross_attention(*args)
    finally:
        torch.set_num_threads(before)
    ref_p, ref_q = cross_attention_reference(*args)
    torch.testing.assert_close(out_p, ref_p, atol=1e-5, rtol=1e-4)
    assert (out_p[0, 0] == 0).all()
    loss, ref_loss = (out_p * ref_p.detach()).sum(), (ref_p * ref_p.detach()).sum()
    if both_ways:
        assert out_q is not None and ref_q is not None
        torch.testing.assert_close(out_q, ref_q, atol=1e-5, rtol=1e-4)
        loss, ref_loss = loss + (out_q * ref_q.detach()).sum(), ref_loss + (ref_q * ref_q.detach()).sum()
    leaves = [t for t in (edge, p_part, q_part, weight, bias, vq, vp) if t is not None]
    for x, y in zip(torch.autograd.grad(loss, leaves), torch.autograd.grad(ref_loss, leaves), strict=True):
        torch.testing.assert_close(x, y, atol=1e-4, rtol=1e-3)


@pytest.mark.parametrize("threads", [1, 2])
def test_pair_mlp_kernels_match_plain_torch(threads: int) -> None:
    g = torch.Generator().manual_seed(3)
    b, p, q, a = (200, 5, 60, 8) if threads == 2 else (3, 4, 7, 4)
    pairs = torch.rand(b, p, q, generator=g) > 0.2
    table, index = pair_rows(pairs)
    allowed = pairs & (torch.rand(b, p, q, generator=g) > 0.3)  # a subset of the table's pairs, as the affinity's
    rows = torch.where(allowed, table, -1)
    inputs = [
        torch.randn(len(index), a, generator=g),
        torch.randn(b, p, a, generator=g),
        torch.randn(b, q, a, generator=g),
        torch.randn(2, a, generator=g),
        torch.randn(2, generator=g),
    ]
    inputs = [t.requires_grad_() for t in inputs]
    args = (inputs[0], rows, *inputs[1:])
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        out = pair_mlp(*args)
        with torch.no_grad():
            torch.testing.assert_close(pair_mlp(*args), out)  # the no-gradient path
    finally:
        torch.set_num_threads(before)
    ref = pair_mlp_reference(*args)
    torch.testing.assert_close(out, ref, atol=1e-5, rtol=1e-4)
    assert (out[~allowed] == 0).all()
    grad = torch.randn_like(out)
    got, want = torch.autograd.grad(out, inputs, grad), torch.autograd.grad(ref, inputs, grad)
    for x, y in zip(got, want, strict=True):
        torch.testing.assert_close(x, y, atol=1e-4, rtol=1e-3)
    assert (got[0][table[pairs & ~allowed]] == 0).all()  # table rows of pairs left out get no gradient


@pytest.mark.parametrize("threads", [1, 2])
def test_sinkhorn_kernels_match_plain_torch(threads: int) -> None:
    g = torch.Generator().manual_seed(4)
    b, r, c = (300, 6, 40) if threads == 2 else (4, 4, 9)
    rows_on, cols_on = torch.rand(b, r, generator=g) > 0.2, torch.rand(b, c, generator=g) > 0.2
    rows_on[0], cols_on[1] = False, False  # a decision with no row on, one with no column on
    on = rows_on[:, :, None] & cols_on[:, None, :]
    forbidden = (torch.rand(b, r, c, generator=g) < 0.2) | ~on  # as log_sinkhorn gives them: log-coupling -1e4
    z = (3 * torch.randn(b, r, c, generator=g)).masked_fill(forbidden, -1e4).requires_grad_()
    log_mu = torch.where(rows_on, torch.rand(b, r, generator=g), -1e4)
    log_nu = torch.where(cols_on, torch.rand(b, c, generator=g), -1e4)
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        out = sinkhorn(z, log_mu, log_nu, rows_on, cols_on, 7)
        with torch.no_grad():
            torch.testing.assert_close(sinkhorn(z, log_mu, log_nu, rows_on, cols_on, 7), out)
    finally:
        torch.set_num_threads(before)
    ref = sinkhorn_reference(z, log_mu, log_nu, rows_on, cols_on, 7)
    torch.testing.assert_close(out[on], ref[on], atol=1e-4, rtol=1e-5)
    grad = torch.randn_like(out) * on  # what reaches the pairs that are on
    torch.testing.assert_close(
        torch.autograd.grad(out, z, grad)[0], torch.autograd.grad(ref, z, grad)[0], atol=1e-4, rtol=1e-3
    )


def test_run_mlp_is_the_module() -> None:
    torch.manual_seed(2)
    net, x = mlp([5, 7, 7, 3]), torch.randn(11, 5)
    torch.testing.assert_close(run_mlp(net, x), net(x), rtol=0, atol=0)


def test_sinkhorn_without_gradient_matches_the_autograd_path() -> None:
    torch.manual_seed(1)
    scores = torch.randn(3, 4, 9) * 3
    pair = torch.rand(3, 4, 9) > 0.3
    rows, cols = torch.ones(3, 4, dtype=torch.bool), torch.ones(3, 9, dtype=torch.bool)
    rows[1, -1], cols[2, -2:] = False, False
    fast = log_sinkhorn(scores, pair, rows, cols, torch.tensor(0.5), iters=10)
    slow = log_sinkhorn(scores.clone().requires_grad_(), pair, rows, cols, torch.tensor(0.5), iters=10)
    torch.testing.assert_close(fast, slow.detach(), atol=1e-5, rtol=1e-5)


# ---------------------------------------------------------------------------------------------- the sequential draw


def test_sequential_draw_sends_robots_to_distinct_goals_while_there_are_enough() -> None:
    """Rollouts draw what evaluation plays: no two robots with a choice share a goal while each has a
    free allowed one; when a robot has none left, it draws among all its allowed goals."""
    net = model()
    obs = observation(np.random.default_rng(11), robots=5, candidates=12)
    generator = torch.Generator().manual_seed(0)
    for _ in range(50):
        goals = act(net, [obs], generator=generator).actions[0].tolist()
        assert len(set(goals)) == 5, goals
    # 3 robots, 2 allowed goals for all: the first two take both, the third takes one of them again
    few = observation(np.random.default_rng(12), robots=3, candidates=2)
    few["action_mask"][:] = 0
    few["action_mask"][:, :2] = 1
    for _ in range(20):
        goals = act(net, [few], generator=generator).actions[0].tolist()
        assert sorted(goals[:2]) == [0, 1] and goals[2] in (0, 1)


def test_sequential_log_probability_is_the_chain_rule_and_matches_the_draws() -> None:
    """2 robots, 3 goals: P(a0, a1) = p0(a0) * p1(a1 | a1 != a0), written out from the rows of S; the
    per-robot log-probabilities of :func:`act` are its two factors, and 20,000 draws follow it."""
    net = model()
    obs = observation(np.random.default_rng(13), robots=2, candidates=3, pad=0)
    obs["action_mask"][:] = 1
    obs["distances"][:] = np.abs(obs["distances"]).clip(max=10.0)
    out = forward(net, obs)
    p = torch.softmax(out.logits[0].double(), dim=-1)  # (2, 3) rows of S over the allowed goals
    joint = {}
    for a0 in range(3):
        rest = p[1].clone()
        rest[a0] = 0
        for a1 in range(3):
            joint[(a0, a1)] = float(p[0, a0] * rest[a1] / rest.sum())
    generator = torch.Generator().manual_seed(1)
    res = act(net, [obs] * 20_000, generator=generator)
    pairs = [tuple(a) for a in res.actions.tolist()]
    for key, prob in joint.items():
        assert pairs.count(key) / len(pairs) == pytest.approx(prob, abs=0.015), key
    for i in range(20):
        a0, a1 = pairs[i]
        assert float(res.robot_log_prob[i, 0]) == pytest.approx(float(torch.log(p[0, a0])), abs=1e-5)
        assert float(res.log_prob[i]) == pytest.approx(np.log(joint[(a0, a1)]), abs=1e-5)


def test_sequential_mask_by_hand() -> None:
    allowed = torch.tensor([[[1, 1, 0], [1, 1, 1], [1, 0, 0], [0, 0, 0]]], dtype=torch.bool)
    actions = torch.tensor([[1, 0, 0, 0]])
    has = torch.tensor([[True, True, True, False]])
    mask = sequential_mask(allowed, actions, has)[0].int().tolist()
    # robot 1 loses goal 1 (robot 0's); robot 2's only goal 0 was taken by robot 1: it keeps it
    assert mask == [[1, 1, 0], [1, 0, 1], [1, 0, 0], [0, 0, 0]]


# ---------------------------------------------------------------------------------------------- normalisation


def _blown_up(config: NetworkConfig) -> DAHGNN:
    """A network whose residual updates are 30x their initial scale, as unnormalised rounds become during
    training (feature RMS 0.5 -> 35 by round 6)."""
    net = model(config)
    with torch.no_grad():
        for layer in net.rounds:
            for update in (layer.robot_update, layer.goal_update):
                update.out.weight.mul_(300.0)
    return net


def test_pre_ln_keeps_every_rounds_scores_bounded_and_attention_soft() -> None:
    obs = [observation(np.random.default_rng(20 + i), robots=3, candidates=12) for i in range(4)]
    cfg = dataclasses.replace(SMALL, rounds=4)
    normed = diagnose(_blown_up(cfg), build_graph(obs, cfg.graph))
    plain = diagnose(_blown_up(dataclasses.replace(cfg, norm="none")), build_graph(obs, cfg.graph))
    for i in range(4):
        assert normed[f"round{i}_score_spread"] <= 2 * cfg.score_scale + 1e-4
        assert normed[f"round{i}_max_attention"] < 0.99
    # without normalisation the same weights give runaway features and one-hot attention
    assert plain["round3_robot_rms"] > 10 * plain["round0_robot_rms"]
    assert plain["round3_score_spread"] > 2 * cfg.score_scale
    assert all(np.isfinite(v) for v in [*normed.values(), *plain.values()])


def test_a_version_1_policy_is_read_as_the_unnormalised_network(tmp_path: Path) -> None:
    net = model(dataclasses.replace(NetworkConfig.ncm(rounds=1), norm="none"))
    save_policy(tmp_path / "old", net)
    doc = json.loads((tmp_path / "old.json").read_text())
    doc["version"] = 1
    del doc["config"]["norm"], doc["config"]["score_scale"]
    (tmp_path / "old.json").write_text(json.dumps(doc))
    loaded, config = load_policy(tmp_path / "old")
    assert config.norm == "none"
    obs = observation(np.random.default_rng(9))
    torch.testing.assert_close(forward(net, obs).log_s, forward(loaded, obs).log_s, rtol=0, atol=0)
    doc["config"]["norm"] = "pre-ln"
    (tmp_path / "old.json").write_text(json.dumps(doc))
    with pytest.raises(ConfigError, match="version-1 policy config cannot name norm"):
        load_policy(tmp_path / "old")
