"""Pipeline stage "planner" (training): the training loop of the DA-HGNN / NCM goal planners.

A run trains the DA-HGNN paper's centralised actor-critic (:mod:`areasearch.models.dahgnn`) with PPO
(:mod:`areasearch.training.ppo`) under a :class:`~areasearch.training.config.TrainConfig`
(:mod:`areasearch.training.config`, ``configs/*.toml``). Who does what:

==============================  =============================================================
:mod:`areasearch.training.config`  the config schema, its checks, the resolved ``config.json``
:mod:`areasearch.training.rollout`       the episodes of an iteration, played with the current weights
:mod:`areasearch.training.ppo`           GAE, the loss pieces, :func:`~areasearch.training.ppo.ppo_update`
:mod:`areasearch.training.runfolder`     the run folder: checkpoints, CSV logs, TensorBoard, the curve
:mod:`areasearch.progress`        the progress report on stderr
this module                     the loop (:func:`train`), validation, the saved policies
==============================  =============================================================

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
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from ..errors import AreaSearchError, ConfigError, TrainingDiverged
from ..folderlock import hold_folder
from ..progress import Progress, duration
from .config import EvalConfig, PPOConfig, RolloutConfig, TrainConfig, config_to_dict, load_config
from .ppo import episode_gae as gae  # areasearch.training.train.gae: GAE of one Trajectory
from .ppo import ppo_update
from .rollout import Backend, EpisodeSpec, Trajectory, expand_maps, iteration_episodes, play, validation_episodes
from .runfolder import (
    EVAL_FIELDS,
    EVAL_FILE,
    PROGRESS_FILE,
    CsvLog,
    Scalars,
    atomic_bytes,
    atomic_text,
    check_progress,
    draw_training_curve,
    open_run,
    progress_fields,
    read_checkpoint,
    restore_checkpoint,
    save_checkpoint,
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

    from ..models.dahgnn import DAHGNN, save_policy

    log = sys.stdout if log == "stdout" else log
    progress = sys.stderr if progress == "stderr" else progress
    assert not isinstance(log, str) and not isinstance(progress, str)
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
    train_maps = expand_maps(config.rollout.maps)
    val_maps = expand_maps(config.evaluation.maps)
    run = Path(out)
    load = open_run(run, config_to_dict(config), resume)
    checkpoint = read_checkpoint(run, config.rollout.episodes) if load else None
    keep = int(checkpoint["iteration"]) if checkpoint else 0
    progress_log = CsvLog(run / PROGRESS_FILE, progress_fields(config.network.rounds), keep)
    eval_log = CsvLog(run / EVAL_FILE, EVAL_FIELDS, keep)

    torch.manual_seed(config.seed)
    model = DAHGNN(config.network).to(device)
    optimizer = torch.optim.Adam(model.parameters(), lr=config.ppo.learning_rate, eps=1e-5)
    state: dict[str, Any] = {"iteration": 0, "decisions": 0, "episodes": 0, "wall_s": 0.0, "best_score": -1.0}
    if checkpoint:
        check_progress(run, progress_log.rows, checkpoint)
        state.update(restore_checkpoint(run, checkpoint, model, optimizer))
    else:  # iteration 0: from here on a run folder without checkpoint.json is one that lost it
        save_checkpoint(run, model, optimizer, state)
    progress_log.start()
    eval_log.start()
    model.eval()
    network = dataclasses.asdict(config.network)
    scalars = Scalars(run / "tb", purge_step=state["decisions"] + 1 if load else None)
    pool = Backend(backend, workers, address)
    bar = Progress("train", config.total_decisions, "decisions", progress, done=state["decisions"], rate_unit="dec/s")
    threads = max(1, os.cpu_count() or 1)
    torch.set_num_threads(threads)
    t_start = time.perf_counter() - float(state["wall_s"])
    try:
        if load and log is not None:
            bar.clear()
            print(f"resumed {run} at iteration {state['iteration']} ({state['decisions']:,} decisions)", file=log)
        while state["decisions"] < config.total_decisions and (iterations is None or state["iteration"] < iterations):
            iteration = state["iteration"] + 1
            fraction = state["decisions"] / config.total_decisions
            lr = config.ppo.learning_rate * (1.0 - fraction if config.ppo.anneal_lr else 1.0)
            for group in optimizer.param_groups:
                group["lr"] = lr
            aux = config.ppo.aux_coef * max(0.0, 1.0 - fraction / config.ppo.aux_decay) if config.ppo.aux_decay else 0.0
            t0 = time.perf_counter()
            weights = _weights(model)
            trajectories: list[Trajectory] = []
            specs = iteration_episodes(config, train_maps, iteration)
            for traj in pool.map(network, weights, specs, config.rollout.lockstep):
                trajectories.append(traj)
                bar.update(state["decisions"] + sum(len(t.rewards) for t in trajectories))
            t1 = time.perf_counter()
            stats = ppo_update(model, optimizer, trajectories, config, iteration, aux, pool)
            _check_finite(run, iteration, stats, model, lr)
            t2 = time.perf_counter()
            decisions = sum(len(t.rewards) for t in trajectories)
            state["iteration"] = iteration
            state["decisions"] += decisions
            state["episodes"] += len(trajectories)
            state["wall_s"] = time.perf_counter() - t_start
            row: dict[str, Any] = {
                "iteration": iteration,
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
            last = state["decisions"] >= config.total_decisions
            if config.evaluation.episodes and (iteration % config.evaluation.every == 0 or last):
                score = _validate(pool, network, _weights(model), config, val_maps, state, eval_log, scalars)
                row["eval/coverage_auc"] = score
                (run / SNAPSHOTS).mkdir(exist_ok=True)
                _save_policy_atomic(save_policy, run / SNAPSHOTS / _snapshot_name(state["decisions"]), model)
                if score > state["best_score"]:
                    state["best_score"] = score
                    chosen = {"by": "best validation", "validation_score": score}
                    _save_policy_atomic(save_policy, run / "policy", model, _chosen(state, chosen))
            progress_log.append(row)
            scalars.add(row, state["decisions"])
            bar.clear()
            if log is not None:
                print(_line(row, config.total_decisions), file=log, flush=True)
            if iteration % config.checkpoint_every == 0 or last or iteration == iterations:
                save_checkpoint(run, model, optimizer, state)
        current = policy_choice(run)
        if not current or (current.get("by") == "last" and current.get("iteration") != state["iteration"]):
            # no validation yet (or none configured): the last weights, labelled as such
            _save_policy_atomic(save_policy, run / "policy", model, _chosen(state, {"by": "last"}))
        if state["decisions"] >= config.total_decisions:
            _save_policy_atomic(save_policy, run / "final", model)
            draw_training_curve(run)
            e = config.evaluation
            if e.episodes and e.finalists and not (run / SELECTION_FILE).exists():
                bar.clear()
                selection = select_policy(pool, network, config, val_maps, run)
                if log is not None:
                    print(_selection_line(selection), file=log, flush=True)
    finally:
        bar.update(state["decisions"])
        bar.close()
        pool.close()
        scalars.close()
    best = float(state["best_score"])
    return RunResult(
        state["iteration"],
        state["decisions"],
        None if best < 0 else best,
        state["wall_s"],
        policy_choice(run),
        state["decisions"] >= config.total_decisions,
    )


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


SNAPSHOTS = "snapshots"
"""Folder of a run with the policy of each validation (``dec-<decisions>.*``)."""
SELECTION_FILE = "selection.json"
"""What the final comparison of :func:`select_policy` measured and chose."""


def _snapshot_name(decisions: int) -> str:
    return f"dec-{int(decisions):09d}"


def smoothed_scores(scores: Sequence[float]) -> list[float]:
    """Each validation's score averaged with its neighbours' (a window of 3, 2 at the ends): a
    checkpoint is judged by its stretch of the curve, not by one draw of validation noise."""
    out = []
    for i in range(len(scores)):
        window = scores[max(0, i - 1) : i + 2]
        out.append(float(np.mean(window)))
    return out


def select_policy(
    pool: Backend, network: dict[str, Any], config: TrainConfig, maps: Sequence[str], run: Path
) -> dict[str, Any]:
    """The final checkpoint rule: the ``evaluation.finalists`` validations with the best smoothed
    score (:func:`smoothed_scores` of ``eval.csv``, ties to the later one) whose snapshots exist are
    played on ``evaluation.final_episodes`` fresh episodes per validation map and team size (seeds
    after the validation's, the same for every finalist: paired); the one with the best mean
    coverage AUC becomes ``policy.*``. Writes ``selection.json`` (every finalist's scores, the paired
    differences to the chosen one with 95 % intervals) and returns its content. Deterministic: a
    run killed during the selection makes the same choice on resume."""
    from ..models.dahgnn import load_policy

    by: dict[int, list[float]] = {}
    iteration_at: dict[int, int] = {}
    for row in _read_rows(run / EVAL_FILE):
        by.setdefault(int(row["decisions"]), []).append(float(row["coverage_auc"]))
        iteration_at[int(row["decisions"])] = int(row["iteration"])
    points = sorted(by)
    raw = [float(np.mean(by[d])) for d in points]
    smooth = smoothed_scores(raw)
    ranked = sorted(
        (i for i, d in enumerate(points) if (run / SNAPSHOTS / f"{_snapshot_name(d)}.json").exists()),
        key=lambda i: (smooth[i], points[i]),
        reverse=True,
    )[: config.evaluation.finalists]
    e = config.evaluation
    specs = validation_episodes(config, maps, first=e.episodes, count=e.final_episodes)
    finals: dict[int, np.ndarray] = {}
    for i in ranked:
        model, _ = load_policy(run / SNAPSHOTS / _snapshot_name(points[i]))
        trajs = list(pool.map(network, _weights(model), specs, config.rollout.lockstep))
        finals[i] = np.array([coverage_auc(t.steps, t.covered_curve, t.spec.max_steps) for t in trajs])
    if not finals:
        return {}
    best = max(ranked, key=lambda i: (float(finals[i].mean()), points[i]))

    def interval(x: np.ndarray) -> float:
        return float(1.96 * x.std(ddof=1) / math.sqrt(len(x))) if len(x) > 1 else float("nan")

    doc = {
        "rule": (
            f"top {e.finalists} validations by the smoothed score (window 3), each played on "
            f"{e.final_episodes} fresh episodes per map and team size (paired); best mean coverage AUC"
        ),
        "episodes": len(specs),
        "chosen_decisions": points[best],
        "finalists": [
            {
                "decisions": points[i],
                "validation_score": raw[i],
                "smoothed_score": smooth[i],
                "final_score": float(finals[i].mean()),
                "final_ci95": interval(finals[i]),
                "minus_chosen": float((finals[i] - finals[best]).mean()),
                "minus_chosen_ci95": interval(finals[i] - finals[best]),
            }
            for i in ranked
        ],
    }
    src = run / SNAPSHOTS / _snapshot_name(points[best])
    atomic_bytes(run / "policy.safetensors", src.with_name(src.name + ".safetensors").read_bytes())
    meta = json.loads(src.with_name(src.name + ".json").read_text(encoding="utf-8"))  # the JSON last
    chosen = {"by": "final selection", "iteration": iteration_at[points[best]], "decisions": points[best]}
    meta["chosen"] = {**chosen, "final_score": float(finals[best].mean())}
    atomic_text(run / "policy.json", json.dumps(meta, indent=1) + "\n")
    atomic_text(run / SELECTION_FILE, json.dumps(doc, indent=1) + "\n")
    return doc


def _selection_line(doc: Mapping[str, Any]) -> str:
    if not doc:
        return "final selection: no snapshot to choose from"
    parts = [
        f"{f['decisions']:,} dec: val {f['validation_score']:.2f} (smoothed {f['smoothed_score']:.2f}), "
        f"final {f['final_score']:.2f} ± {f['final_ci95']:.2f}"
        for f in doc["finalists"]
    ]
    return (
        f"final selection ({doc['episodes']} episodes each): "
        + "; ".join(parts)
        + (f" -> policy = {doc['chosen_decisions']:,} decisions")
    )


def _read_rows(path: Path) -> list[dict[str, str]]:
    import csv

    if not path.exists():
        return []
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


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


def _validate(
    pool: Backend,
    network: dict[str, Any],
    weights: dict[str, np.ndarray],
    config: TrainConfig,
    maps: Sequence[str],
    state: Mapping[str, Any],
    log: CsvLog,
    scalars: Scalars,
) -> float:
    """Play the validation episodes with deterministic goals; log them; return the mean coverage AUC."""
    scores, explored, covered = [], [], []
    for traj in pool.map(network, weights, validation_episodes(config, maps), config.rollout.lockstep):
        auc = coverage_auc(traj.steps, traj.covered_curve, traj.spec.max_steps)
        scores.append(auc)
        explored.append(float(traj.info["explored_pct"]))
        covered.append(float(traj.info["covered_pct"]))
        log.append(
            {
                "iteration": state["iteration"],
                "decisions": state["decisions"],
                "map": traj.spec.map,
                "robots": traj.spec.robots,
                "seed": traj.spec.seed,
                "explored_pct": float(traj.info["explored_pct"]),
                "covered_pct": float(traj.info["covered_pct"]),
                "time_e": int(traj.info["time_e"]),
                "time_c": int(traj.info["time_c"]),
                "coverage_auc": auc,
            }
        )
    score = float(np.mean(scores))
    scalars.add(
        {
            "eval/coverage_auc": score,
            "eval/explored_pct": float(np.mean(explored)),
            "eval/covered_pct": float(np.mean(covered)),
        },
        int(state["decisions"]),
    )
    return score


def coverage_auc(steps: Sequence[int], covered: Sequence[float], horizon: int) -> float:
    """Mean Cover% over the horizon (the area under the step-wise Cover% curve / horizon): higher
    when more targets are covered and when they are covered sooner."""
    area, last_step, last_value = 0.0, 0, 0.0
    for s, c in zip(steps, covered, strict=True):
        area += last_value * (min(s, horizon) - last_step)
        last_step, last_value = min(s, horizon), c
    area += last_value * (horizon - last_step)
    return area / horizon


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
    "train",
    "validation_episodes",
]
