"""PPO for the DA-HGNN topological planner: advantages, the loss, the update of one iteration.

Implements the "Policy Optimization" of the DA-HGNN paper (Zhu et al., "Dual-Attention Heterogeneous
Graph Neural Network for Multi-robot Collaborative Area Search via Deep Reinforcement Learning"): a
centralised actor-critic trained with PPO, the actor the DA-HGNN planner (:mod:`areasearch.models.dahgnn`),
the critic the map CNN, on the team reward r_t = alpha1 * explored gain + alpha2 * newly covered
targets + alpha3 per step, summed over the 40 primitive steps of each decision
(:class:`areasearch.envs.goal.AreaSearchEnv`). The loss is

    L = L_CLIP + c1 L_KL + c2 L_VF - c3 L_E + c4(t) L_Acc

with L_CLIP the clipped surrogate (clip 0.2; :func:`policy_loss`): with ``ppo.ratio = "robot"`` (the
default) one ratio per robot that chose, its conditional probability of its goal in the ordered draw
without replacement of :func:`areasearch.models.dahgnn.act`, each with the team's advantage, averaged over
those robots (MAPPO-style); with ``"team"`` one ratio per decision on the joint log-probability.
L_KL the k3 estimate ``(ratio - 1) - log ratio`` of KL(pi_old || pi) as a penalty
(:func:`approx_kl`), L_VF the value error (:func:`value_loss`: unclipped by default;
``ppo.clip_vloss`` clips it the way PPO2 does), L_E the entropy bonus (the paper's "+ c3 L_E" read
as a bonus, hence the minus sign of a minimised loss; per robot with ``ratio = "robot"``) and L_Acc
the mean squared error of the auxiliary explored-ratio prediction (:func:`aux_loss`), whose weight
c4 the training loop decays (:mod:`areasearch.training.train`). Advantages by GAE (:func:`gae`; gamma 0.99
per decision, lambda 0.95), normalised per minibatch; gradients clipped to norm
``ppo.max_grad_norm``, the actor's and the critic's apart (one shared norm would be set by the value
error and shrink the policy's steps below Adam's epsilon).

:func:`ppo_update` runs ``ppo.epochs`` epochs of minibatch updates over the decisions of an
iteration's episodes, in an order drawn from (run seed, iteration) only; with ``ppo.target_kl`` it
stops the iteration's epochs after the first minibatch whose approx_kl exceeds it. It returns the
iteration's ``losses/*`` statistics (means over the minibatches that ran): the loss terms,
``approx_kl``, ``clipfrac``, the gradient norms, ``explained_variance``. How a minibatch's gradient
is computed is passed in (a :class:`GradientStrategy`): :func:`whole_minibatch`, here on
``ppo.threads`` threads, or with ``ppo.shards`` > 1 the sum of its shards' computed in the rollout
workers while they would otherwise wait for the update
(:class:`areasearch.training.ppo_shards.ShardedGradient`, chosen by :mod:`areasearch.training.train`).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from .config import PPOConfig, TrainConfig
from .trajectory import Trajectory

if TYPE_CHECKING:
    from torch import Tensor


# ---------------------------------------------------------------------------------------------- advantages


def gae(
    rewards: np.ndarray, values: np.ndarray, dones: np.ndarray, last_value: float, gamma: float, lam: float
) -> tuple[np.ndarray, np.ndarray]:
    """(advantages, returns) of a sequence of T decisions by generalised advantage estimation:

        delta_t = r_t + gamma * (1 - done_t) * V_{t+1} - V_t
        A_t     = delta_t + gamma * lam * (1 - done_t) * A_{t+1},    returns_t = A_t + V_t

    ``rewards``, ``values`` (the critic's value of each decision's observation) and ``dones`` (True
    where the episode terminated with that decision: nothing after it counts) are (T,) arrays;
    ``last_value`` is V_T, the value of the observation after the last decision (a truncated
    episode's bootstrap). The recursion runs in float64; both arrays come back in ``values``' dtype."""
    values = np.asarray(values)
    r = np.asarray(rewards, dtype=np.float64)
    v = values.astype(np.float64)
    next_values = np.append(v[1:], last_value)
    nonterminal = 1.0 - np.asarray(dones, dtype=np.float64)
    advantages = np.zeros(len(r), dtype=values.dtype)
    running = 0.0
    for t in range(len(r) - 1, -1, -1):
        delta = r[t] + gamma * next_values[t] * nonterminal[t] - v[t]
        running = delta + gamma * lam * nonterminal[t] * running
        advantages[t] = running
    return advantages, advantages + values


def episode_gae(traj: Trajectory, gamma: float, lam: float, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`gae` of one played episode, its rewards multiplied by ``scale``. The last decision is
    terminal whether the task was done or the horizon reached: the horizon is the end of the
    mission (the observation's ``progress`` tells the critic how much of it is left), so nothing is
    bootstrapped from a state at progress 1, which the critic never trains on."""
    dones = np.zeros(len(traj.rewards), dtype=bool)
    dones[-1:] = True
    return gae(traj.rewards * scale, traj.values, dones, 0.0, gamma, lam)


# ---------------------------------------------------------------------------------------------- loss pieces


def normalize(advantages: Tensor) -> Tensor:
    """Advantages of a minibatch to mean 0, standard deviation 1."""
    return (advantages - advantages.mean()) / (advantages.std() + 1e-8)


def _mean(x: Tensor, weights: Tensor | None) -> Tensor:
    """Mean of ``x``, or its mean over the entries where ``weights`` (same shape, 0/1) is 1."""
    if weights is None:
        return x.mean()
    return (x * weights).sum() / weights.sum().clamp(min=1)


def policy_loss(ratio: Tensor, advantages: Tensor, clip_coef: float, weights: Tensor | None = None) -> Tensor:
    """L_CLIP as a loss to minimise: mean of max(-A * ratio, -A * clip(ratio, 1 - eps, 1 + eps)),
    the pessimistic one of the plain and the clipped surrogate; where the clip binds (the ratio past
    1 + eps with A > 0, below 1 - eps with A < 0) a sample gives no gradient. ``ratio`` (B, R) and
    ``advantages`` (B, 1) with ``weights`` (B, R): per-robot ratios with the team advantage, the mean
    over the robots that chose."""
    unclipped = -advantages * ratio
    clipped = -advantages * ratio.clamp(1 - clip_coef, 1 + clip_coef)
    return _mean(unclipped.maximum(clipped), weights)


def approx_kl(log_ratio: Tensor, ratio: Tensor, weights: Tensor | None = None) -> Tensor:
    """k3 estimate of KL(pi_old || pi): mean of (ratio - 1) - log ratio, >= 0 for every sample (Schulman,
    "Approximating KL divergence"); ``ratio`` is exp(``log_ratio``), passed in as the surrogate's."""
    return _mean((ratio - 1) - log_ratio, weights)


def value_loss(values: Tensor, returns: Tensor, old_values: Tensor, clip_coef: float | None) -> Tensor:
    """L_VF: half the mean squared error of the values against the returns. With ``clip_coef`` (PPO2's
    value clipping) the larger of that error and the error of the values clipped to within
    ``clip_coef`` of ``old_values``, the values under the acting policy."""
    if clip_coef is None:
        return 0.5 * ((values - returns) ** 2).mean()
    clipped = old_values + (values - old_values).clamp(-clip_coef, clip_coef)
    return 0.5 * ((values - returns) ** 2).maximum((clipped - returns) ** 2).mean()


def aux_loss(explored_ratio: Tensor, labels: Tensor) -> Tensor:
    """L_Acc: mean squared error of the predicted explored ratio."""
    return ((explored_ratio - labels) ** 2).mean()


def clip_fraction(ratio: Tensor, clip_coef: float, weights: Tensor | None = None) -> Tensor:
    """Fraction of the samples (robots that chose, with ``weights``) whose ratio is outside
    [1 - eps, 1 + eps] (logged as clipfrac)."""
    return _mean(((ratio - 1).abs() > clip_coef).float(), weights)


def explained_variance(returns: np.ndarray, values: np.ndarray) -> float:
    """1 - Var(returns - values) / Var(returns): 1 for a perfect critic, 0 for a constant one; NaN when
    the returns do not vary."""
    var = float(np.var(returns))
    return float("nan") if var == 0 else 1.0 - float(np.var(returns - values)) / var


# ---------------------------------------------------------------------------------------------- the update


MinibatchGradient = Callable[[Any, np.ndarray, float], dict[str, float]]
"""``(model, idx, aux_coef) -> losses/* terms``: the loss of the minibatch ``idx`` of an iteration's
:class:`Decisions`, its gradient left in the model's ``.grad``."""


class GradientStrategy(Protocol):
    """How the minibatches' gradients of an iteration are computed."""

    def __call__(self, data: Decisions, p: PPOConfig) -> AbstractContextManager[MinibatchGradient]:
        """The :data:`MinibatchGradient` over ``data``, valid inside the ``with`` block (which may hold
        what the iteration's minibatches share, such as its graphs sent to the workers)."""
        ...


@contextlib.contextmanager
def whole_minibatch(data: Decisions, p: PPOConfig) -> Iterator[MinibatchGradient]:
    """The :class:`GradientStrategy` of ``ppo.shards = 1``: each minibatch whole, in this process
    (:func:`minibatch_gradient`)."""

    def gradient(model: Any, idx: np.ndarray, aux_coef: float) -> dict[str, float]:
        return minibatch_gradient(model, data, idx, p, aux_coef)

    yield gradient


def ppo_update(
    model: Any,
    optimizer: Any,
    trajectories: Sequence[Trajectory],
    config: TrainConfig,
    iteration: int,
    aux_coef: float,
    gradient: GradientStrategy = whole_minibatch,
    inputs: UpdateInputs | None = None,
) -> dict[str, float]:
    """PPO epochs over the decisions of ``trajectories``, on ``ppo.threads`` PyTorch threads; returns
    the iteration's loss statistics. ``gradient`` computes each minibatch's gradient: whole, here
    (:func:`whole_minibatch`, the default), or as the sum of ``ppo.shards`` shards' computed by a
    runner (:class:`areasearch.training.ppo_shards.ShardedGradient`). ``inputs``: the decisions'
    graphs and the health numbers, already made as the trajectories came back (:class:`UpdateInputs`);
    without it they are made here. The update is the same either way."""
    with update_threads(config.ppo):
        if inputs is None:
            inputs = UpdateInputs(model, config, len(trajectories))
            for i, traj in enumerate(trajectories):
                inputs.add(i, traj)
        return _update(model, optimizer, trajectories, config, iteration, aux_coef, gradient, inputs)


@contextlib.contextmanager
def update_threads(p: PPOConfig) -> Iterator[None]:
    """PyTorch on ``ppo.threads`` threads inside the block (the number is part of a run's config: it
    changes the sums' order)."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(p.threads)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


HEALTH_DECISIONS = 64
"""The network's health numbers (``health/*``) of an iteration are those of its first 64 decisions."""


class UpdateInputs:
    """What an update needs of its iteration's trajectories before its first minibatch, made one
    trajectory at a time (:meth:`add`) so that the training loop can make it as each lockstep group
    comes back, while the other groups still play: each decision's graph
    (:func:`~areasearch.models.graph.observation_graph`; :class:`Decisions` pads them into the
    iteration's batch, the batch :func:`~areasearch.models.graph.build_graph` makes) and the network's
    health numbers (:func:`~areasearch.models.dahgnn.diagnose`) on the iteration's first
    :data:`HEALTH_DECISIONS` decisions, with the weights that played them (the update has not
    started), made as soon as those decisions' graphs are in."""

    def __init__(self, model: Any, config: TrainConfig, episodes: int) -> None:
        self.model = model
        self.config = config
        self.graph_config = config.network.graph.validate()
        self.graphs: list[list[Any] | None] = [None] * episodes
        """Each episode's decisions' graphs, by the episode's index in the iteration (None: not yet in)."""
        self.health: dict[str, float] | None = None

    def add(self, index: int, trajectory: Trajectory) -> None:
        """Make the graphs of the episode ``index`` of the iteration, and the health numbers once the
        first decisions' graphs are all in."""
        from ..models.graph import observation_graph

        cfg = self.graph_config
        self.graphs[index] = [observation_graph(_observation32(o), cfg) for o in trajectory.observations]
        if self.health is None:
            first: list[Any] = []
            for graphs in self.graphs:
                if graphs is None or len(first) >= HEALTH_DECISIONS:
                    break
                first += graphs
            if len(first) >= HEALTH_DECISIONS or all(g is not None for g in self.graphs):
                self.health = self._health(first[:HEALTH_DECISIONS])

    def _health(self, graphs: list[Any]) -> dict[str, float]:
        from ..models.dahgnn import diagnose
        from ..models.graph import collate

        training = self.model.training
        self.model.eval()
        with update_threads(self.config.ppo):
            health = diagnose(self.model, collate(graphs).trim())
        self.model.train(training)
        return {f"health/{k}": v for k, v in health.items()}

    def all_graphs(self) -> list[Any]:
        """Every decision's graph, in the iteration's order."""
        missing = [i for i, g in enumerate(self.graphs) if g is None]
        if missing:
            raise ValueError(f"the graphs of episodes {missing} were never added")
        return [graph for graphs in self.graphs if graphs is not None for graph in graphs]


@dataclass(frozen=True)
class Decisions:
    """An iteration's decisions, flat over its episodes: the graphs (built once, sliced per
    minibatch), the goals and per-robot log-probabilities (rows padded to the largest team), the
    advantages and returns by GAE per episode, the values under the acting policy, the
    explored-ratio labels."""

    graphs: Any
    actions: np.ndarray
    old_log_probs: np.ndarray
    advantages: np.ndarray
    returns: np.ndarray
    old_values: np.ndarray
    labels: np.ndarray

    @classmethod
    def gather(
        cls, trajectories: Sequence[Trajectory], config: TrainConfig, graphs: Sequence[Any] | None = None
    ) -> Decisions:
        """The decisions of ``trajectories``; ``graphs``: their graphs, already made
        (:meth:`UpdateInputs.all_graphs`), else they are made here."""
        from ..models.graph import build_graph, collate

        p = config.ppo
        parts = [episode_gae(t, p.gamma, p.gae_lambda, p.reward_scale) for t in trajectories]
        decisions = sum(len(t.observations) for t in trajectories)
        if graphs is not None and len(graphs) != decisions:
            raise ValueError(f"{len(graphs)} graphs for {decisions} decisions")
        return cls(
            collate(graphs)
            if graphs is not None
            else build_graph([_observation32(o) for t in trajectories for o in t.observations], config.network.graph),
            _pad_rows([a for t in trajectories for a in t.actions], np.int64),
            _pad_rows([row for t in trajectories for row in t.log_probs], np.float32),
            np.concatenate([a for a, _ in parts]).astype(np.float32),
            np.concatenate([r for _, r in parts]).astype(np.float32),
            np.concatenate([t.values for t in trajectories]),
            np.concatenate([t.explored for t in trajectories]),
        )

    def __len__(self) -> int:
        return len(self.advantages)


def _update(
    model: Any,
    optimizer: Any,
    trajectories: Sequence[Trajectory],
    config: TrainConfig,
    iteration: int,
    aux_coef: float,
    gradient: GradientStrategy,
    inputs: UpdateInputs,
) -> dict[str, float]:
    data = Decisions.gather(trajectories, config, inputs.all_graphs())
    assert inputs.health is not None  # made once every graph is in
    health = inputs.health
    model.train()
    with gradient(data, config.ppo) as minibatch:
        stats = _epochs(model, optimizer, len(data), minibatch, config, iteration, aux_coef)
    model.eval()
    out = {k: float(np.mean(v)) for k, v in stats.items()}
    out["losses/minibatches"] = float(len(stats["losses/policy_loss"]))
    out["losses/explained_variance"] = explained_variance(data.returns, data.old_values)
    out["losses/advantage_mean"] = float(data.advantages.mean())
    return out | health


def _epochs(
    model: Any,
    optimizer: Any,
    n: int,
    gradient: MinibatchGradient,
    config: TrainConfig,
    iteration: int,
    aux_coef: float,
) -> dict[str, list[float]]:
    """The iteration's epochs of minibatch steps over its ``n`` decisions; returns each step's
    statistics."""
    import torch

    p = config.ppo
    rng = np.random.default_rng([config.seed, iteration, 1])
    groups = parameter_groups(model)
    critic_params = groups["critic"]
    critic_ids = {id(t) for t in critic_params}
    actor_params = [t for t in model.parameters() if id(t) not in critic_ids]
    stats: dict[str, list[float]] = {}
    stop = False
    for _ in range(p.epochs):
        order = rng.permutation(n)
        for start in range(0, n, p.minibatch_size):
            idx = order[start : start + p.minibatch_size]
            optimizer.zero_grad(set_to_none=True)
            terms = gradient(model, idx, aux_coef)
            norms = {f"health/grad_norm_{name}": _grad_norm(params) for name, params in groups.items()}
            # actor and critic clipped apart: the value error's gradient (returns of tens of units)
            # would otherwise set the shared norm and shrink the policy's steps to nothing
            # foreach: the same norms and products bit for bit as the per-tensor loop, in fewer calls
            clip = torch.nn.utils.clip_grad_norm_
            terms["losses/grad_norm"] = float(clip(actor_params, p.max_grad_norm, foreach=True))
            terms["losses/critic_grad_norm"] = float(clip(critic_params, p.max_grad_norm, foreach=True))
            optimizer.step()
            for key, value in (terms | norms).items():
                stats.setdefault(key, []).append(value)
            # early stop: the minibatch that passed target_kl has taken its step; no further one runs
            if p.target_kl and terms["losses/approx_kl"] > p.target_kl:
                stop = True
                break
        if stop:
            break
    return stats


def minibatch_gradient(model: Any, data: Decisions, idx: np.ndarray, p: PPOConfig, aux_coef: float) -> dict[str, float]:
    """The loss of the minibatch ``idx`` (of ``data``) in this process, its gradient left in the
    model's ``.grad``; returns the loss terms (``losses/*``)."""
    import torch

    from ..models.dahgnn import evaluate_actions

    batch = data.graphs.index(torch.from_numpy(idx)).trim()
    width = batch.action_mask.shape[1]
    res = evaluate_actions(model, batch, torch.from_numpy(data.actions[idx, :width]))
    chose = res.has_choice.float()  # (b, R): the robots whose draws count
    log_ratio = (res.robot_log_prob - torch.from_numpy(data.old_log_probs[idx, :width])) * chose
    weights: Tensor | None = chose
    entropy = (res.robot_entropy * chose).sum() / chose.sum().clamp(min=1)  # per robot
    if p.ratio == "team":  # one ratio per decision, on the joint log-probability
        log_ratio, weights, entropy = log_ratio.sum(-1, keepdim=True), None, res.entropy.mean()
    ratio = log_ratio.exp()
    adv = torch.from_numpy(data.advantages[idx])
    if p.norm_adv and len(idx) > 1:
        adv = normalize(adv)
    pg_loss = policy_loss(ratio, adv[:, None], p.clip_coef, weights)
    kl = approx_kl(log_ratio, ratio, weights)
    v_loss = value_loss(
        res.value,
        torch.from_numpy(data.returns[idx]),
        torch.from_numpy(data.old_values[idx]),
        p.clip_coef if p.clip_vloss else None,
    )
    acc_loss = aux_loss(res.explored_ratio, torch.from_numpy(data.labels[idx]))
    loss = pg_loss + p.kl_coef * kl + p.vf_coef * v_loss - p.ent_coef * entropy + aux_coef * acc_loss
    loss.backward()
    with torch.no_grad():
        clipfrac = clip_fraction(ratio, p.clip_coef, weights)
    terms = {"policy_loss": pg_loss, "kl_penalty": kl, "value_loss": v_loss, "entropy": entropy}
    terms |= {"aux_loss": acc_loss, "approx_kl": kl, "clipfrac": clipfrac}
    return {f"losses/{k}": float(v.detach()) for k, v in terms.items()}


def parameter_groups(model: Any) -> dict[str, list[Any]]:
    """The model's parameters by part, for the per-group gradient norms (``health/grad_norm_*``):
    ``encoders``, ``round0`` ... ``round<L-1>``, ``similarity`` (with the final LayerNorms),
    ``critic``."""
    groups: dict[str, list[Any]] = {"encoders": list(model.encoders.parameters())}
    for i, layer in enumerate(model.rounds):
        groups[f"round{i}"] = list(layer.parameters())
    seen = {id(t) for ps in groups.values() for t in ps} | {id(t) for t in model.critic.parameters()}
    groups["similarity"] = [t for t in model.parameters() if id(t) not in seen]
    groups["critic"] = list(model.critic.parameters())
    return groups


def _grad_norm(params: Sequence[Any]) -> float:
    import torch

    grads = [t.grad for t in params if t.grad is not None]
    return float(torch.nn.utils.get_total_norm(grads, 2.0, foreach=True)) if grads else 0.0


def _pad_rows(rows: Sequence[np.ndarray], dtype: Any) -> np.ndarray:
    """(N, R) rows of decisions with different team sizes (actions, per-robot log-probabilities),
    padded with 0."""
    width = max(len(a) for a in rows)
    out = np.zeros((len(rows), width), dtype=dtype)
    for i, a in enumerate(rows):
        out[i, : len(a)] = a
    return out


def _observation32(obs: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """A stored observation (map as float16) as the graph builder takes it."""
    out = dict(obs)
    out["map"] = obs["map"].astype(np.float32)
    return out
