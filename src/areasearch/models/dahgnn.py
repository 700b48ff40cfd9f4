"""Pipeline stage "planner" (learned): the DA-HGNN policy, acting on observations with the network of
:mod:`areasearch.models.network` (the DA-HGNN paper's actor-critic, or its ablations and the NCM
baseline; configured by :mod:`areasearch.models.network_config`, saved and loaded by
:mod:`areasearch.models.weights`): sampled goals for training (:func:`act`), the evaluation-time
assignment (:func:`decide`, :func:`assign_goals`), PPO's re-evaluation of stored actions
(:func:`evaluate_actions`) and the health numbers of a pass (:func:`diagnose`).

**Policy.** Robot r's action is a candidate index, drawn from row r of S over the candidates
``action_mask[r]`` allows (``logits = log S[r, :C]``, -inf where not allowed; the slack column, "no
match", is dropped). The robots draw in index order without replacement: robot r's draw leaves out
the goals robots 0..r-1 took, while any of its allowed goals is left (:func:`sequential_mask`). So
training samples what evaluation plays: :func:`assign_goals` solves the linear assignment on log S
(no two robots share a goal while there are enough allowed goals, the paper's "argmax on each row
and column"), and the sampled team is a stochastic version of it (with independent draws from the
rows, 16 % of 3-robot and 36 % of 5-robot decisions send two robots to one goal, measured on
training runs of the unnormalised network). PPO's ratios are per robot, on these conditional probabilities
(:mod:`areasearch.training.ppo`); joint log-probability = their sum. A robot with no allowed candidate (or a
padded one) takes action 0 with probability 1 and adds nothing.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import NamedTuple

import numpy as np
import torch
import torch.nn.functional as F
from scipy.optimize import linear_sum_assignment
from torch import Tensor

from .graph import GraphBatch, build_graph
from .network import DAHGNN, PolicyOutput


class ActResult(NamedTuple):
    actions: Tensor  # (B, R) int64 candidate indices (observation indices)
    log_prob: Tensor  # (B,) joint log-probability: sum of robot_log_prob
    entropy: Tensor  # (B,) sum of robot_entropy
    value: Tensor  # (B,)
    explored_ratio: Tensor  # (B,) auxiliary prediction
    robot_log_prob: Tensor  # (B, R) log pi(a_r | a_1..a_r-1) of each robot with a choice, 0 for the others
    robot_entropy: Tensor  # (B, R) entropy of each such robot's conditional distribution, 0 for the others
    has_choice: Tensor  # (B, R) bool: real robot with at least one allowed candidate


def sequential_mask(allowed: Tensor, actions: Tensor, has_choice: Tensor) -> Tensor:
    """(B, R, C) the goals robot r may draw when the robots draw in index order without replacement:
    its ``allowed`` goals less those robots 0..r-1 (with a choice) took, or all its allowed goals
    when none of them is left (more robots than goals). ``actions`` (B, R) are the draws."""
    c = allowed.shape[-1]
    took = F.one_hot(actions, c).bool() & has_choice[..., None]  # (B, R, C)
    before = (took.long().cumsum(1) - took.long()) > 0  # taken by a robot earlier in the order
    free = allowed & ~before
    return torch.where(free.any(-1, keepdim=True), free, allowed)


def log_prob_entropy(out: PolicyOutput, actions: Tensor) -> tuple[Tensor, Tensor]:
    """Per-robot log-probabilities (B, R) of ``actions`` under the sequential draw (:func:`act`) and
    per-robot entropies (B, R), 0 for robots without a choice. Their sums over robots are the
    joint log-probability and an upper bound of the joint entropy's chain-rule terms."""
    mask = sequential_mask(torch.isfinite(out.logits), actions, out.has_choice)
    log_p = torch.log_softmax(out.logits.masked_fill(~mask, float("-inf")), dim=-1)  # (B, R, C)
    picked = torch.gather(log_p, -1, actions[..., None]).squeeze(-1)  # (B, R)
    p = log_p.exp()
    per_robot = -(p * log_p.masked_fill(p == 0, 0.0)).sum(-1)  # (B, R)
    zero = torch.zeros_like(picked)
    return torch.where(out.has_choice, picked, zero), torch.where(out.has_choice, per_robot, zero)


def _result(out: PolicyOutput, actions: Tensor) -> ActResult:
    log_p, ent = log_prob_entropy(out, actions)
    return ActResult(actions, log_p.sum(-1), ent.sum(-1), out.value, out.explored_ratio, log_p, ent, out.has_choice)


def assign_goals(log_s: Tensor, action_mask: Tensor, robot_mask: Tensor) -> Tensor:
    """Evaluation-time assignment on S: the linear assignment that maximises the summed log S over
    allowed pairs, with as many robots as possible on distinct allowed goals; a robot left over (more
    robots than allowed goals) takes its own best allowed goal, and a robot with none takes 0.
    Returns (B, R) int64 on the device of ``log_s``."""
    b, nr, nc = action_mask.shape
    scores = log_s[:, :nr, :nc].detach().cpu().double().numpy()
    allowed = action_mask.cpu().numpy() & robot_mask.cpu().numpy()[:, :, None]
    out = np.zeros((b, nr), dtype=np.int64)
    for i in range(b):
        ok = allowed[i]
        if not ok.any():
            continue
        big = 1.0 + np.abs(scores[i][ok]).sum()  # more than any sum of allowed costs
        cost = np.where(ok, -scores[i], big)
        rows, cols = linear_sum_assignment(cost)
        done = np.zeros(nr, dtype=bool)
        for rr, cc in zip(rows, cols, strict=True):
            if ok[rr, cc]:
                out[i, rr], done[rr] = cc, True
        for rr in np.flatnonzero(~done & ok.any(axis=1)):
            out[i, rr] = int(np.argmax(np.where(ok[rr], scores[i, rr], -np.inf)))
    return torch.from_numpy(out).to(log_s.device)


def act(
    model: DAHGNN,
    observations: Sequence[Mapping[str, np.ndarray]] | Mapping[str, np.ndarray],
    deterministic: bool = False,
    generator: torch.Generator | Sequence[torch.Generator] | None = None,
) -> ActResult:
    """Goals for a batch of observations (no gradient): drawn from the rows of S (training), or the
    :func:`assign_goals` assignment (``deterministic``, evaluation).

    The draw is what evaluation plays, made stochastic: the robots draw in index order, each from its
    row of S over its allowed goals less those already taken (while any is left; :func:`sequential_mask`),
    so no two robots share a goal while there are enough goals, as in the assignment. The ordered
    draws' conditional log-probabilities are what PPO's ratios compare (:func:`log_prob_entropy`).

    ``generator``: one for the whole batch, or one per observation (a vectorised rollout, each
    episode with its own): each observation's goals are then drawn from its own rows and candidates
    only, so its draws do not depend on what else is in the batch (its probabilities may, in their
    last bits: batched arithmetic)."""
    device = next(model.parameters()).device
    batch = build_graph(observations, model.config.graph, device)
    with torch.inference_mode():  # no autograd bookkeeping at all (less than no_grad), the same numbers
        out = model(batch)
        if deterministic:
            actions = assign_goals(out.log_s, batch.action_mask, batch.robot_mask)
        elif generator is None or isinstance(generator, torch.Generator):
            actions = _draw(out.logits, out.has_choice, generator)
        else:
            actions = _sample_rows(out, batch, list(generator))
        result = _result(out, actions)
    return ActResult(*(t.clone() for t in result))  # ordinary tensors: a caller may take them into autograd


def _draw(logits: Tensor, has_choice: Tensor, generator: torch.Generator | None) -> Tensor:
    """(B, R) goals drawn robot by robot without replacement (see :func:`act`) from ``logits`` (B, R, C)."""
    b, nr, nc = logits.shape
    actions = torch.zeros((b, nr), dtype=torch.int64, device=logits.device)
    taken = torch.zeros((b, nc), dtype=torch.bool, device=logits.device)
    for r in range(nr):
        row = logits[:, r]
        allowed = torch.isfinite(row)
        free = allowed & ~taken
        use = torch.where(free.any(-1, keepdim=True), free, allowed)
        probs = torch.softmax(row.masked_fill(~use, float("-inf")), dim=-1)
        actions[:, r] = torch.multinomial(probs, 1, generator=generator).view(-1)
        taken |= F.one_hot(actions[:, r], nc).bool() & has_choice[:, r, None]
    return actions


def _sample_rows(out: PolicyOutput, batch: GraphBatch, generators: list[torch.Generator]) -> Tensor:
    """(B, R) goals drawn for each observation of the batch with its own generator, from its own
    robots and candidates (the batch's padding cut off: the draws equal those of the observation
    alone); padded robots get candidate 0."""
    if len(generators) != out.logits.shape[0]:
        raise ValueError(f"{len(generators)} generators for a batch of {out.logits.shape[0]} observations")
    actions = torch.zeros(out.logits.shape[:2], dtype=torch.int64, device=out.logits.device)
    robots = batch.robot_mask.sum(1).tolist()
    for i, g in enumerate(generators):
        real = batch.cand_mask[i].nonzero()
        c = int(real[-1, 0]) + 1 if len(real) else 1
        r = int(robots[i])
        actions[i, :r] = _draw(out.logits[i : i + 1, :r, :c], out.has_choice[i : i + 1, :r], g)[0]
    return actions


def decide(model: DAHGNN, observations: Sequence[Mapping[str, np.ndarray]] | Mapping[str, np.ndarray]) -> Tensor:
    """Evaluation-time goals (B, R) int64 for a batch of observations: the actor (no critic) and the
    :func:`assign_goals` assignment on S. What a learned goal planner calls every decision."""
    device = next(model.parameters()).device
    batch = build_graph(observations, model.config.graph, device, critic=False)
    with torch.inference_mode():
        log_s = model.actor(batch)
    return assign_goals(log_s, batch.action_mask, batch.robot_mask)


def evaluate_actions(model: DAHGNN, batch: GraphBatch, actions: Tensor) -> ActResult:
    """PPO's re-evaluation of stored ``actions`` (B, R) on ``batch`` (with gradient)."""
    return _result(model(batch), actions)


def diagnose(model: DAHGNN, batch: GraphBatch) -> dict[str, float]:
    """Health numbers of one actor pass over ``batch`` (no gradient), as ``round<i>_*`` and ``final_*``:
    the RMS of the robot and candidate features each round reads (before its LayerNorm), the spread of
    the candidates' self-attention logits and their largest weight (1.0: one-hot attention), the share
    of saturated robot-candidate MLP-attention logits. Logged as ``health/*`` every training iteration."""
    probe: dict[str, float] = {}
    with torch.no_grad():
        model.actor(batch, probe)
    return probe
