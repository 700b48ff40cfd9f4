"""The data-parallel PPO update (``ppo.shards`` > 1): a minibatch's gradient as the sum of its shards'.

While the learner updates, the rollout workers wait. With ``ppo.shards = k`` each minibatch of
:func:`areasearch.training.ppo.ppo_update` is cut in order into k shards (:func:`split_minibatch`); a shard's
loss is each term's sum over the shard divided by the whole minibatch's count (:func:`shard_loss`),
so the shards' losses add up to :func:`.ppo.minibatch_gradient`'s loss of the minibatch;
its gradient is computed on one PyTorch thread wherever it runs (:func:`shard_gradient`: in a worker
process, a Ray task or the learner), and :func:`sharded_gradient` adds the gradients in shard
order. So a run's numbers depend on k, not on the number of workers. The iteration's graphs go to
the workers once per update (:meth:`~areasearch.runners.Runner.share`); a shard carries only its
rows and per-decision numbers. :class:`ShardedGradient` is the update's
:class:`~areasearch.training.ppo.GradientStrategy` that does all this on a
:class:`~areasearch.runners.Runner` (the rollouts' own).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Mapping
from dataclasses import asdict, dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ..runners import Runner, shared
from .config import PPOConfig
from .ppo import Decisions, MinibatchGradient, approx_kl, aux_loss, clip_fraction, normalize, policy_loss, value_loss
from .rollout import worker_model

if TYPE_CHECKING:
    from torch import Tensor


@dataclass(frozen=True)
class ShardedGradient:
    """The :class:`~areasearch.training.ppo.GradientStrategy` of ``ppo.shards`` > 1: each minibatch's
    gradient as the sum of its shards' (:func:`sharded_gradient`), computed by ``runner``; the
    iteration's graphs are sent to its workers once (:meth:`~areasearch.runners.Runner.share`: a
    minibatch's are megabytes)."""

    runner: Runner

    @contextlib.contextmanager
    def __call__(self, data: Decisions, p: PPOConfig) -> Iterator[MinibatchGradient]:
        with self.runner.share({k: v.numpy() for k, v in data.graphs._asdict().items()}) as graphs:

            def gradient(model: Any, idx: np.ndarray, aux_coef: float) -> dict[str, float]:
                return sharded_gradient(model, data, graphs, idx, p, aux_coef, self.runner)

            yield gradient


@dataclass(frozen=True)
class Shard:
    """A consecutive part of a minibatch: the rows of its decisions in the iteration's graphs (sent
    once per update, :meth:`~areasearch.runners.Runner.share`), their goals and old log-probabilities (trimmed to the
    shard's largest team), advantages (normalised over the whole minibatch), returns, old values and
    labels, and the whole minibatch's counts that its means divide by. Nothing but numpy arrays and
    numbers crosses to a worker."""

    rows: np.ndarray
    actions: np.ndarray
    old_log_probs: np.ndarray
    advantages: np.ndarray
    returns: np.ndarray
    old_values: np.ndarray
    labels: np.ndarray
    decisions: int
    """Decisions in the whole minibatch."""
    robots: float
    """Robots that chose in the whole minibatch (at least 1)."""


def split_minibatch(data: Decisions, idx: np.ndarray, shards: int, norm_adv: bool) -> list[Shard]:
    """The minibatch ``idx`` of ``data`` cut in order into ``shards`` consecutive parts (fewer when it
    has fewer decisions)."""
    import torch

    picked = torch.from_numpy(idx)
    action_mask, robot_mask = data.graphs.action_mask[picked], data.graphs.robot_mask[picked]  # not every field's copy
    robots = float((action_mask.any(-1) & robot_mask).sum().clamp(min=1))
    adv = torch.from_numpy(data.advantages[idx])
    if norm_adv and len(idx) > 1:
        adv = normalize(adv)
    out = []
    for part in np.array_split(np.arange(len(idx)), min(shards, len(idx))):
        rows = idx[part]
        width = _last_true_column(robot_mask[torch.from_numpy(part)].numpy())
        out.append(
            Shard(
                rows,
                data.actions[rows, :width],
                data.old_log_probs[rows, :width],
                adv[torch.from_numpy(part)].numpy(),
                data.returns[rows],
                data.old_values[rows],
                data.labels[rows],
                len(idx),
                robots,
            )
        )
    return out


def _last_true_column(mask: np.ndarray) -> int:
    """1 + the last column where any row of ``mask`` is True (at least 1): the robots axis of
    :meth:`areasearch.models.graph.GraphBatch.trim`."""
    columns = np.flatnonzero(mask.any(0))
    return int(columns[-1]) + 1 if len(columns) else 1


def shard_graphs(graphs: Mapping[str, np.ndarray], rows: np.ndarray) -> Any:
    """The :class:`~areasearch.models.graph.GraphBatch` of ``rows`` of an iteration's graphs (as arrays),
    trimmed: the values :meth:`GraphBatch.index` and :meth:`GraphBatch.trim` give in the learner."""
    import torch

    from ..models.graph import GraphBatch

    return GraphBatch(**{k: torch.from_numpy(np.ascontiguousarray(v[rows])) for k, v in graphs.items()}).trim()


def shard_loss(model: Any, batch: Any, shard: Shard, p: PPOConfig, aux_coef: float) -> tuple[Tensor, dict[str, float]]:
    """The shard's part of its minibatch's loss on its graphs ``batch``: each term's sum over the
    shard divided by the whole minibatch's count (robots that chose, or decisions), so that the
    parts of a minibatch add up to the loss :func:`.ppo.minibatch_gradient` takes of it whole (up to the
    order of the sums); and the parts of the ``losses/*`` terms."""
    import torch

    from ..models.dahgnn import evaluate_actions

    res = evaluate_actions(model, batch, torch.from_numpy(shard.actions))
    chose = res.has_choice.float()
    log_ratio = (res.robot_log_prob - torch.from_numpy(shard.old_log_probs)) * chose
    b = len(shard.actions)
    weights: Tensor | None = chose
    # each term: the shard's mean over its own robots (or decisions) times its share of the minibatch's
    share = chose.sum().clamp(min=1) / shard.robots
    entropy = (res.robot_entropy * chose).sum() / shard.robots
    if p.ratio == "team":
        log_ratio, weights, share = log_ratio.sum(-1, keepdim=True), None, torch.tensor(b / shard.decisions)
        entropy = res.entropy.sum() / shard.decisions
    ratio = log_ratio.exp()
    adv = torch.from_numpy(shard.advantages)[:, None]
    pg_loss = policy_loss(ratio, adv, p.clip_coef, weights) * share
    kl = approx_kl(log_ratio, ratio, weights) * share
    v_loss = value_loss(
        res.value,
        torch.from_numpy(shard.returns),
        torch.from_numpy(shard.old_values),
        p.clip_coef if p.clip_vloss else None,
    ) * (b / shard.decisions)
    acc_loss = aux_loss(res.explored_ratio, torch.from_numpy(shard.labels)) * (b / shard.decisions)
    loss = pg_loss + p.kl_coef * kl + p.vf_coef * v_loss - p.ent_coef * entropy + aux_coef * acc_loss
    with torch.no_grad():
        clipfrac = clip_fraction(ratio, p.clip_coef, weights) * share
    terms = {"policy_loss": pg_loss, "kl_penalty": kl, "value_loss": v_loss, "entropy": entropy}
    terms |= {"aux_loss": acc_loss, "approx_kl": kl, "clipfrac": clipfrac}
    return loss, {f"losses/{k}": float(v.detach()) for k, v in terms.items()}


def shard_gradient(
    network: dict[str, Any],
    weights: Mapping[str, np.ndarray],
    graphs: Any,
    shard: Shard,
    ppo: dict[str, Any],
    aux_coef: float,
) -> tuple[dict[str, np.ndarray], dict[str, float]]:
    """Gradient of :func:`shard_loss` at ``weights`` (by parameter name; a parameter the shard does
    not reach is left out) and its ``losses/*`` parts; ``graphs`` is the iteration's graphs as
    :meth:`~areasearch.runners.Runner.share` handed them out. In a worker process, a Ray task or here, on one PyTorch
    thread, so that a shard's numbers do not depend on where it is computed."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    model = worker_model(network, weights)
    try:
        model.train()
        model.zero_grad(set_to_none=True)
        batch = shard_graphs(shared(graphs), shard.rows)
        loss, terms = shard_loss(model, batch, shard, PPOConfig(**ppo), aux_coef)
        loss.backward()
        grads = {name: t.grad.numpy().copy() for name, t in model.named_parameters() if t.grad is not None}
    finally:
        model.zero_grad(set_to_none=True)
        model.eval()
        torch.set_num_threads(threads)
    return grads, terms


def sharded_gradient(
    model: Any, data: Decisions, graphs: Any, idx: np.ndarray, p: PPOConfig, aux_coef: float, runner: Runner
) -> dict[str, float]:
    """The minibatch ``idx``'s gradient as the sum, in shard order, of its shards' (computed by
    ``runner``), left in the model's ``.grad``; returns the loss terms, summed over the shards."""
    import torch

    network = asdict(model.config)
    weights = {k: v.detach().cpu().numpy().copy() for k, v in model.state_dict().items()}
    ppo = asdict(p)
    tasks = [(network, weights, graphs, s, ppo, aux_coef) for s in split_minibatch(data, idx, p.shards, p.norm_adv)]
    results = runner.call(shard_gradient, tasks)
    for name, param in model.named_parameters():
        parts = [grads[name] for grads, _ in results if name in grads]
        if parts:
            total = parts[0].copy()
            for g in parts[1:]:
                total += g
            param.grad = torch.from_numpy(total)
    return {key: sum(terms[key] for _, terms in results) for key in results[0][1]}
