"""Pipeline stage "planner" (training): the training loop of the DA-HGNN / NCM goal planners.

A run trains the DA-HGNN paper's centralised actor-critic (:mod:`areasearch.models.dahgnn`) with PPO
(:mod:`areasearch.training.ppo`) under a :class:`~areasearch.training.config.TrainConfig`
(:mod:`areasearch.training.config`, ``configs/*.toml``). Who does what:

=======================================  =====================================================
:mod:`areasearch.training.config`        the config schema, its checks, the resolved ``config.json``
:mod:`areasearch.training.trajectory`    an episode to play, and what playing it recorded
:mod:`areasearch.training.rollout`       the episodes of an iteration, played with the current weights
:mod:`areasearch.training.ppo`           GAE, the loss pieces, :func:`~areasearch.training.ppo.ppo_update`
:mod:`areasearch.training.ppo_shards`    the update's minibatches cut into shards for the workers
:mod:`areasearch.training.validation`    validation, the snapshots' final selection
:mod:`areasearch.training.runfolder`     the run folder: checkpoints, CSV logs, TensorBoard, the curve
:mod:`areasearch.runners`                where the episodes and the shards run (processes, Ray, here)
:mod:`areasearch.progress`               the progress report on stderr
this module                              the loop (:func:`train`), the saved policies
=======================================  =====================================================

The loop (:func:`_train`) reads top to bottom: start or resume the run (:func:`_start`), then per
iteration the schedule (:func:`_schedule`), the rollouts (:func:`_rollouts`), the update
(:func:`~areasearch.training.ppo.ppo_update`), the record of the iteration (:func:`_record`), the
validation with its snapshot (:func:`_validation`), the log line and the checkpoint
(:func:`_checkpoint`); at the end the policy and the final selection (:func:`_finish`).

**Iterations.** Each iteration plays ``rollout.episodes`` whole episodes with the current policy
(sampling goals from its per-robot categoricals; :func:`~areasearch.training.rollout.iteration_episodes`),
then runs ``ppo.epochs`` epochs of minibatch updates over their decisions
(:func:`~areasearch.training.ppo.ppo_update`). Adam at ``ppo.learning_rate`` (5e-4, the paper's), annealed
linearly to 0 over the run (``ppo.anneal_lr``); the weight c4 of the auxiliary explored-ratio loss
decays linearly from ``ppo.aux_coef`` to 0 over the first ``ppo.aux_decay`` of training, as the
paper says. Every ``evaluation.every`` iterations (and after the last) the validation episodes are
played with deterministic goals and scored by :func:`coverage_auc`; the best policy so far is kept.
Logged per iteration: the losses, ``approx_kl``, ``clipfrac``, ``explained_variance``, the learning
rate, c4, returns and the episodes' Explo% / Cover%, decisions/s and robot-steps/s (a row of
``progress.csv``, TensorBoard scalars, a plain line on stdout).

A run's numbers depend on its config alone: not on the number of workers, the backend, or on having
been killed and resumed. ``--resume`` continues from the last checkpoint, under the config the run
recorded (another is refused, naming the settings that differ); without it an existing run is never
overwritten (the run folder's files and their checks: :mod:`areasearch.training.runfolder`). ``iterations``
(``--iterations``) counts the run's iterations from its start. ``policy.*`` always holds a policy:
the last weights until the first validation, then the validated choice (:data:`POLICY_CHOICES`).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from ..config import SearchConfig
from ..errors import AreaSearchError, ConfigError, TrainingDiverged
from ..folderlock import hold_folder
from ..progress import Progress, duration
from ..runners import Runner, make_runner
from .config import (
    EvalConfig,
    PPOConfig,
    RolloutConfig,
    TrainConfig,
    config_to_dict,
    load_config,
    training_comm_note,
)
from .ppo import GradientStrategy, UpdateInputs, ppo_update, whole_minibatch
from .ppo import episode_gae as gae  # areasearch.training.train.gae: GAE of one Trajectory
from .ppo_shards import ShardedGradient
from .rollout import episode_env, expand_maps, iteration_episodes, play, play_groups, validation_episodes
from .runfolder import (
    EVAL_FIELDS,
    EVAL_FILE,
    PROGRESS_FILE,
    CsvLog,
    Scalars,
    atomic_text,
    check_progress,
    draw_training_curve,
    open_run,
    progress_fields,
    read_checkpoint,
    restore_checkpoint,
    save_checkpoint,
)
from .trajectory import EpisodeSpec, Trajectory
from .validation import (
    SELECTION_FILE,
    SNAPSHOTS,
    coverage_auc,
    select_policy,
    selection_line,
    smoothed_scores,
    snapshot_name,
    validate,
)


@dataclass
class RunResult:
    """What :func:`train` returns: the run's counters after this call, its best validation score and
    what its ``policy.*`` holds."""

    iterations: int
    decisions: int
    best_score: float | None
    """The best validation's mean coverage AUC so far; None: no validation yet."""
    wall_s: float
    policy: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    """The ``chosen`` record of ``policy.json`` (:data:`POLICY_CHOICES`; empty: no policy written)."""
    finished: bool = False
    """The run has reached ``total_decisions``."""


POLICY_CHOICES = ("last", "best validation", "final selection")
"""What a run's ``policy.*`` can hold, recorded in ``policy.json`` as ``"chosen": {"by": ..., "iteration":
..., "decisions": ...}``: ``last``, the weights after the latest iteration, while no validation has
run (or none is configured: ``evaluation.episodes = 0``); ``best validation``, the best validation so
far (and at the end with ``evaluation.finalists = 0``); ``final selection``, the winner of the final
paired comparison (``selection.json``)."""


def _weights(model: Any) -> dict[str, np.ndarray]:
    return {k: v.detach().cpu().numpy().copy() for k, v in model.state_dict().items()}


def policy_choice(run: str | Path) -> dict[str, Any]:
    """The ``chosen`` record of a run's ``policy.json`` (:data:`POLICY_CHOICES`); empty when there is
    no policy, or for a policy written before runs recorded it (a validated one)."""
    path = Path(run) / "policy.json"
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    chosen = doc.get("chosen") if isinstance(doc, dict) else None
    return dict(chosen) if isinstance(chosen, dict) else ({"by": "best validation"} if isinstance(doc, dict) else {})


def train(
    config: TrainConfig,
    out: str | Path,
    *,
    resume: bool = False,
    device: str = "cpu",
    workers: int | None = None,
    backend: str = "local",
    address: str | None = None,
    log: TextIO | str | None = "stdout",
    progress: TextIO | str | None = "stderr",
    iterations: int | None = None,
) -> RunResult:
    """Run (or resume) PPO training into ``out``; see the module docstring. ``iterations`` ends the
    call once the run has that many iterations in total (counted from its start, not from this call:
    the same call after a kill finishes the same run, a larger number extends it); the run can be
    resumed. The run always ends at ``total_decisions``, whatever ``iterations`` says.
    ``log`` takes the plain line per iteration (default: the current ``sys.stdout``), ``progress`` the
    progress report (default: the current ``sys.stderr``; :class:`areasearch.progress.Progress`: a bar
    on a terminal, a plain line at most every 10 s and at the end otherwise); None: nothing.

    The run folder is held by this process while it trains (:func:`areasearch.folderlock.hold_folder`:
    a second process is refused, naming this one's pid). A loss or a parameter that becomes NaN or
    infinite stops the run with :class:`~areasearch.errors.TrainingDiverged` before anything of that
    iteration is saved: the last checkpoint and the best policy stay as they were."""
    with hold_folder(out, "run folder path"):
        return _train(
            config,
            out,
            resume=resume,
            device=device,
            workers=workers,
            backend=backend,
            address=address,
            log=log,
            progress=progress,
            iterations=iterations,
        )


def _train(
    config: TrainConfig,
    out: str | Path,
    *,
    resume: bool,
    device: str,
    workers: int | None,
    backend: str,
    address: str | None,
    log: TextIO | str | None,
    progress: TextIO | str | None,
    iterations: int | None,
) -> RunResult:
    """:func:`train` in a run folder this process holds."""
    import torch

    log = sys.stdout if log == "stdout" else log
    progress = sys.stderr if progress == "stderr" else progress
    assert not isinstance(log, str) and not isinstance(progress, str)
    config, workers = _checked(config, device, workers, iterations)
    s = _start(config, Path(out), resume, device)
    runner = make_runner(backend, workers, address)
    gradient: GradientStrategy = ShardedGradient(runner) if config.ppo.shards > 1 else whole_minibatch
    state, run, model = s.state, s.run, s.model
    bar = Progress("train", config.total_decisions, "decisions", progress, done=state["decisions"], rate_unit="dec/s")
    torch.set_num_threads(max(1, os.cpu_count() or 1))
    t_start = time.perf_counter() - float(state["wall_s"])
    try:
        if s.resumed and log is not None:
            bar.clear()
            print(f"resumed {run} at iteration {state['iteration']} ({state['decisions']:,} decisions)", file=log)
        note = training_comm_note(config)
        if note is not None and log is not None:
            bar.clear()
            print(note, file=log, flush=True)
        while state["decisions"] < config.total_decisions and (iterations is None or state["iteration"] < iterations):
            iteration = state["iteration"] + 1
            lr, aux = _schedule(config, s.optimizer, state)
            t0 = time.perf_counter()
            trajectories, inputs = _rollouts(s, runner, iteration, bar)
            t1 = time.perf_counter()
            stats = ppo_update(model, s.optimizer, trajectories, config, iteration, aux, gradient, inputs)
            _check_finite(run, iteration, stats, model, lr)
            t2 = time.perf_counter()
            row = _record(state, trajectories, t_start, lr, aux, stats, (t0, t1, t2))
            last = state["decisions"] >= config.total_decisions
            if config.evaluation.episodes and (iteration % config.evaluation.every == 0 or last):
                row["eval/coverage_auc"] = _validation(s, runner)
            s.progress_log.append(row)
            s.scalars.add(row, state["decisions"])
            bar.clear()
            if log is not None:
                print(_line(row, config.total_decisions), file=log, flush=True)
            _checkpoint(s, due=iteration % config.checkpoint_every == 0 or last or iteration == iterations)
        _finish(s, runner, bar, log)
    finally:
        bar.update(state["decisions"])
        bar.close()
        runner.close()
        s.scalars.close()
    best = float(state["best_score"])
    return RunResult(
        state["iteration"],
        state["decisions"],
        None if best < 0 else best,
        state["wall_s"],
        policy_choice(run),
        state["decisions"] >= config.total_decisions,
    )


def _checked(config: TrainConfig, device: str, workers: int | None, iterations: int | None) -> tuple[TrainConfig, int]:
    """The validated config and the number of workers (default: one per core); ConfigError for a
    device, a number of workers or of iterations :func:`train` does not take."""
    import torch

    config = config.validate()
    if device not in ("cpu", "cuda"):
        raise ConfigError(f"device must be 'cpu' or 'cuda', got {device!r}")
    if device == "cuda" and not torch.cuda.is_available():
        raise ConfigError("device 'cuda' asked for, but PyTorch sees no CUDA device")
    if device != "cpu" and config.ppo.shards > 1:
        raise ConfigError(
            f"ppo.shards = {config.ppo.shards} computes the update's shards on CPU workers; "
            f"use ppo.shards = 1 with --device {device}"
        )
    workers = (os.cpu_count() or 1) if workers is None else workers
    if workers < 0:
        raise ConfigError(f"workers must be >= 0, got {workers}")
    if iterations is not None and (isinstance(iterations, bool) or not isinstance(iterations, int) or iterations < 1):
        raise ConfigError(f"iterations must be an integer >= 1, got {iterations!r}")
    return config, workers


@dataclass
class _Session:
    """A run being trained by this process: its folder, config and maps, the model and optimizer,
    the counters (``state``: what a checkpoint records), the logs."""

    run: Path
    config: TrainConfig
    train_maps: list[str]
    val_maps: list[str]
    env: SearchConfig
    network: dict[str, Any]
    model: Any
    optimizer: Any
    state: dict[str, Any]
    progress_log: CsvLog
    eval_log: CsvLog
    scalars: Scalars
    resumed: bool


def _start(config: TrainConfig, run: Path, resume: bool, device: str) -> _Session:
    """The run in ``run``: a new one (its folder made, the checkpoint of iteration 0 saved) or, with
    ``resume``, the one there restored from its last checkpoint."""
    import torch

    from ..models.network import DAHGNN

    train_maps = expand_maps(config.rollout.maps)
    val_maps = expand_maps(config.evaluation.maps)
    env = episode_env(config)
    load = open_run(run, config_to_dict(config), resume)
    checkpoint = read_checkpoint(run, config.rollout.episodes) if load else None
    keep = int(checkpoint["iteration"]) if checkpoint else 0
    progress_log = CsvLog(run / PROGRESS_FILE, progress_fields(config.network.rounds), keep)
    eval_log = CsvLog(run / EVAL_FILE, EVAL_FIELDS, keep)

    torch.manual_seed(config.seed)
    model = DAHGNN(config.network).to(device)
    # foreach: the multi-tensor step (on the CPU PyTorch would pick the per-tensor loop), fewer calls for
    # the same numbers bit for bit (tests/training/test_ppo.py)
    optimizer = torch.optim.Adam(model.parameters(), lr=config.ppo.learning_rate, eps=1e-5, foreach=True)
    state: dict[str, Any] = {"iteration": 0, "decisions": 0, "episodes": 0, "wall_s": 0.0, "best_score": -1.0}
    if checkpoint:
        check_progress(run, progress_log.rows, checkpoint)
        state.update(restore_checkpoint(run, checkpoint, model, optimizer))
    else:  # iteration 0: from here on a run folder without checkpoint.json is one that lost it
        save_checkpoint(run, model, optimizer, state)
    progress_log.start()
    eval_log.start()
    model.eval()
    scalars = Scalars(run / "tb", purge_step=state["decisions"] + 1 if load else None)
    network = dataclasses.asdict(config.network)
    return _Session(
        run, config, train_maps, val_maps, env, network, model, optimizer, state, progress_log, eval_log, scalars, load
    )


def _schedule(config: TrainConfig, optimizer: Any, state: Mapping[str, Any]) -> tuple[float, float]:
    """The learning rate (set in ``optimizer``) and the auxiliary loss's weight c4 of the next
    iteration: annealed over the run's decisions (``ppo.anneal_lr``, ``ppo.aux_decay``)."""
    p = config.ppo
    fraction = state["decisions"] / config.total_decisions
    lr = p.learning_rate * (1.0 - fraction if p.anneal_lr else 1.0)
    for group in optimizer.param_groups:
        group["lr"] = lr
    aux = p.aux_coef * max(0.0, 1.0 - fraction / p.aux_decay) if p.aux_decay else 0.0
    return lr, aux


def _rollouts(s: _Session, runner: Runner, iteration: int, bar: Progress) -> tuple[list[Trajectory], UpdateInputs]:
    """The episodes of ``iteration``, played with the current weights, and what the update needs of
    them before its first minibatch (:class:`~areasearch.training.ppo.UpdateInputs`), made as each
    lockstep group comes back: the learner would otherwise wait while the last group plays. The bar
    follows the decisions."""
    specs = iteration_episodes(s.config, s.train_maps, iteration, s.env)
    inputs = UpdateInputs(s.model, s.config, len(specs))
    played: dict[int, Trajectory] = {}
    for start, group in play_groups(runner, s.network, _weights(s.model), specs, s.config.rollout.lockstep):
        played |= {start + k: traj for k, traj in enumerate(group)}
        bar.update(s.state["decisions"] + sum(len(t.rewards) for t in played.values()))
        for k, traj in enumerate(group):
            inputs.add(start + k, traj)
    return [played[i] for i in range(len(specs))], inputs


def _record(
    state: dict[str, Any],
    trajectories: list[Trajectory],
    t_start: float,
    lr: float,
    aux: float,
    stats: Mapping[str, float],
    times: tuple[float, float, float],
) -> dict[str, Any]:
    """Count the iteration into ``state``; its row of ``progress.csv`` (``times``: the rollouts' start,
    the update's start and end)."""
    t0, t1, t2 = times
    decisions = sum(len(t.rewards) for t in trajectories)
    state["iteration"] += 1
    state["decisions"] += decisions
    state["episodes"] += len(trajectories)
    state["wall_s"] = time.perf_counter() - t_start
    return {
        "iteration": state["iteration"],
        "decisions": state["decisions"],
        "episodes": state["episodes"],
        "wall_s": state["wall_s"],
        "charts/episodic_return": float(np.mean([t.rewards.sum() for t in trajectories])),
        "charts/explored_pct": float(np.mean([t.info["explored_pct"] for t in trajectories])),
        "charts/covered_pct": float(np.mean([t.info["covered_pct"] for t in trajectories])),
        "charts/episode_decisions": float(np.mean([len(t.rewards) for t in trajectories])),
        "charts/learning_rate": lr,
        "charts/aux_coef": aux,
        **stats,
        "perf/decisions_per_s": decisions / (t2 - t0),
        "perf/robot_steps_per_s": sum(t.robot_steps for t in trajectories) / (t2 - t0),
        "perf/rollout_s": t1 - t0,
        "perf/update_s": t2 - t1,
    }


def _validation(s: _Session, runner: Runner) -> float:
    """Validate the current weights (:func:`~areasearch.training.validation.validate`), keep them as
    a snapshot and, when they beat the best so far, as the run's policy; return the score."""
    from ..models.weights import save_policy

    state, run, model = s.state, s.run, s.model
    score = validate(runner, s.network, _weights(model), s.config, s.val_maps, s.env, state, s.eval_log, s.scalars)
    (run / SNAPSHOTS).mkdir(exist_ok=True)
    _save_policy_atomic(save_policy, run / SNAPSHOTS / snapshot_name(state["decisions"]), model)
    if score > state["best_score"]:
        state["best_score"] = score
        chosen = {"by": "best validation", "validation_score": score}
        _save_policy_atomic(save_policy, run / "policy", model, _chosen(state, chosen))
    return score


def _checkpoint(s: _Session, due: bool) -> None:
    """Save the checkpoint (model, optimizer, counters) when it is ``due``."""
    if due:
        save_checkpoint(s.run, s.model, s.optimizer, s.state)


def _finish(s: _Session, runner: Runner, bar: Progress, log: TextIO | None) -> None:
    """After the loop: ``policy.*`` holds the last weights when no validation chose any; a run that
    reached ``total_decisions`` gets ``final.*``, its curve and the final selection."""
    from ..models.weights import save_policy

    run, state, config = s.run, s.state, s.config
    current = policy_choice(run)
    if not current or (current.get("by") == "last" and current.get("iteration") != state["iteration"]):
        # no validation yet (or none configured): the last weights, labelled as such
        _save_policy_atomic(save_policy, run / "policy", s.model, _chosen(state, {"by": "last"}))
    if state["decisions"] < config.total_decisions:
        return
    _save_policy_atomic(save_policy, run / "final", s.model)
    draw_training_curve(run)
    e = config.evaluation
    if e.episodes and e.finalists and not (run / SELECTION_FILE).exists():
        bar.clear()
        selection = select_policy(runner, s.network, config, s.val_maps, run, s.env)
        if log is not None:
            print(selection_line(selection), file=log, flush=True)


def _chosen(state: Mapping[str, Any], record: Mapping[str, Any]) -> dict[str, Any]:
    """The ``chosen`` record of ``policy.json`` for the weights after ``state``'s iteration."""
    return {"by": record["by"], "iteration": int(state["iteration"]), "decisions": int(state["decisions"]), **record}


def summary_line(out: str | Path, result: RunResult, config: TrainConfig) -> str:
    """What ``areasearch train`` prints at the end: how far the run is, its validation, and which
    weights ``policy.*`` holds."""
    plural = "" if result.iterations == 1 else "s"
    head = f"{out}: {result.iterations:,} iteration{plural}, {result.decisions:,} of {config.total_decisions:,}"
    head += " decisions"
    head += f" ({'finished' if result.finished else 'resumable'}), {result.wall_s / 60:.1f} min"
    e = config.evaluation
    if result.best_score is not None:
        validation = f"best validation Cover% AUC {result.best_score:.2f}"
    elif not e.episodes:
        validation = "no validation (evaluation.episodes = 0)"
    else:
        first = e.every if result.iterations < e.every else result.iterations
        validation = f"no validation yet (the first after iteration {first}, or at the end)"
    chosen = result.policy
    if not chosen:
        return f"{head}; {validation}; no policy written"
    at = f"iteration {chosen.get('iteration', '?')}, {chosen.get('decisions', 0):,} decisions"
    label = "the last weights" if chosen.get("by") == "last" else f"the {chosen.get('by')}"
    return f"{head}; {validation}; policy = {label} ({at}): {Path(out) / 'policy'}"


def _check_finite(run: Path, iteration: int, stats: Mapping[str, Any], model: Any, lr: float) -> None:
    """TrainingDiverged when a loss of this iteration's update (``losses/*`` but the explained
    variance, NaN when the returns do not vary) or a parameter of the model is NaN or infinite."""
    import torch

    losses = [
        key
        for key, value in stats.items()
        if key.startswith("losses/")
        and key != "losses/explained_variance"
        and isinstance(value, (int, float))
        and not math.isfinite(value)
    ]
    params = [name for name, p in model.named_parameters() if not bool(torch.isfinite(p).all())]
    if not losses and not params:
        return
    what = ", ".join(losses[:3]) if losses else f"parameter {params[0]}"
    raise TrainingDiverged(
        f"{run}: training diverged at iteration {iteration}: {what} became NaN or infinite "
        f"({len(params)} parameter tensors non-finite, learning rate {lr:g}); nothing of this iteration was saved, "
        "the last checkpoint and policy are kept; start a new run with a lower ppo.learning_rate"
    )


def _save_policy_atomic(
    save_policy: Callable[..., Any], prefix: Path, model: Any, chosen: Mapping[str, Any] | None = None
) -> None:
    """save_policy into temporary names, then rename both (JSON last); ``chosen`` is recorded in the
    JSON (:data:`POLICY_CHOICES`)."""
    tmp = prefix.with_name(f".{prefix.name}.tmp")
    weights, meta = save_policy(tmp, model)
    if chosen is not None:
        doc = json.loads(meta.read_text(encoding="utf-8"))
        atomic_text(meta, json.dumps({**doc, "chosen": dict(chosen)}, indent=1) + "\n")
    os.replace(weights, prefix.with_name(prefix.name + ".safetensors"))
    os.replace(meta, prefix.with_name(prefix.name + ".json"))


def _line(row: Mapping[str, Any], total: int) -> str:
    """The plain line per iteration on stdout."""
    text = (
        f"iter {row['iteration']:4d}  decisions {row['decisions']:>7,}/{total:,}  "
        f"return {row['charts/episodic_return']:6.2f}  Explo {row['charts/explored_pct']:5.1f}%  "
        f"Cover {row['charts/covered_pct']:5.1f}%  "
        f"vloss {row.get('losses/value_loss', float('nan')):.3f}  "
        f"kl {row.get('losses/approx_kl', float('nan')):.4f}  clip {row.get('losses/clipfrac', float('nan')):.2f}  "
        f"ev {row.get('losses/explained_variance', float('nan')):.2f}  "
        f"{row['perf/decisions_per_s']:.1f} dec/s  {row['perf/robot_steps_per_s']:,.0f} r-st/s  "
        f"elapsed {duration(row['wall_s'], hours=True)}"
    )
    if "eval/coverage_auc" in row:
        text += f"  val AUC {row['eval/coverage_auc']:.2f}"
    return text


__all__ = [
    "SELECTION_FILE",
    "SNAPSHOTS",
    "AreaSearchError",
    "EpisodeSpec",
    "EvalConfig",
    "PPOConfig",
    "RolloutConfig",
    "TrainConfig",
    "Trajectory",
    "config_to_dict",
    "coverage_auc",
    "expand_maps",
    "gae",
    "iteration_episodes",
    "load_config",
    "play",
    "select_policy",
    "smoothed_scores",
    "train",
    "validation_episodes",
]
