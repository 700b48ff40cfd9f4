"""Pipeline stage "planner" (training): the training loop of the DA-HGNN / NCM goal planners.

A run trains the DA-HGNN paper's centralised actor-critic (:mod:`areasearch.dahgnn`) with PPO
(:mod:`areasearch.ppo`) under a :class:`~areasearch.train_config.TrainConfig`
(:mod:`areasearch.train_config`, ``configs/*.toml``). Who does what:

==============================  =============================================================
:mod:`areasearch.train_config`  the config schema, its checks, the resolved ``config.json``
:mod:`areasearch.rollout`       the episodes of an iteration, played with the current weights
:mod:`areasearch.ppo`           GAE, the loss pieces, :func:`~areasearch.ppo.ppo_update`
:mod:`areasearch.runfolder`     the run folder: checkpoints, CSV logs, TensorBoard, the curve
:mod:`areasearch.runlog`        the progress report on stderr
this module                     the loop (:func:`train`), validation, the saved policies
==============================  =============================================================

**Iterations.** Each iteration plays ``rollout.episodes`` whole episodes with the current policy
(sampling goals from its per-robot categoricals; :func:`~areasearch.rollout.iteration_episodes`),
then runs ``ppo.epochs`` epochs of minibatch updates over their decisions
(:func:`~areasearch.ppo.ppo_update`). Adam at ``ppo.learning_rate`` (5e-4, the paper's), annealed
linearly to 0 over the run (``ppo.anneal_lr``); the weight c4 of the auxiliary explored-ratio loss
decays linearly from ``ppo.aux_coef`` to 0 over the first ``ppo.aux_decay`` of training, as the
paper says. Every ``evaluation.every`` iterations (and after the last) the validation episodes are
played with deterministic goals and scored by :func:`coverage_auc`; the best policy so far is kept.
Logged per iteration: the losses, ``approx_kl``, ``clipfrac``, ``explained_variance``, the learning
rate, c4, returns and the episodes' Explo% / Cover%, decisions/s and robot-steps/s (a row of
``progress.csv``, TensorBoard scalars, a plain line on stdout).

A run's numbers depend on its config alone: not on the number of workers, the backend, or on having
been killed and resumed. ``--resume`` continues from the last checkpoint; without it an existing run
is never overwritten (the run folder's files: :mod:`areasearch.runfolder`).
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

from .errors import AreaSearchError, ConfigError, TrainingDiverged
from .folderlock import hold_folder
from .ppo import episode_gae as gae  # areasearch.train.gae: GAE of one Trajectory, as it always was
from .ppo import ppo_update
from .rollout import Backend, EpisodeSpec, Trajectory, expand_maps, iteration_episodes, play, validation_episodes
from .runfolder import (
    CHECKPOINT_FILE,
    CONFIG_FILE,
    EVAL_FIELDS,
    EVAL_FILE,
    PROGRESS_FILE,
    CsvLog,
    Scalars,
    atomic_bytes,
    atomic_text,
    draw_training_curve,
    load_checkpoint,
    progress_fields,
    save_checkpoint,
)
from .runlog import Progress, duration
from .train_config import EvalConfig, PPOConfig, RolloutConfig, TrainConfig, config_to_dict, load_config


@dataclass
class RunResult:
    """What :func:`train` returns: the run's counters after this call and its best validation score."""

    iterations: int
    decisions: int
    best_score: float
    wall_s: float


def _weights(model: Any) -> dict[str, np.ndarray]:
    return {k: v.detach().cpu().numpy().copy() for k, v in model.state_dict().items()}


def _prepare_run(out: Path, config: TrainConfig, resume: bool) -> bool:
    """Check the run folder; returns True when a checkpoint should be loaded."""
    if out.exists() and not out.is_dir():
        raise ConfigError(f"{out}: the run folder is a file")
    saved = out / CONFIG_FILE
    has_checkpoint = (out / CHECKPOINT_FILE).exists()
    if saved.exists():
        if not resume:
            raise ConfigError(f"{out}: a run is already there; pass --resume to continue it (nothing was changed)")
        try:
            previous = json.loads(saved.read_text())
        except (OSError, json.JSONDecodeError) as error:
            raise ConfigError(f"{saved}: cannot read the run's config: {error}") from None
        if previous != config_to_dict(config):
            raise ConfigError(f"{out}: the run was started with another config ({saved}); use a new --out")
        return has_checkpoint
    out.mkdir(parents=True, exist_ok=True)
    atomic_text(saved, json.dumps(config_to_dict(config), indent=1) + "\n")
    return False


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
    stop_after: int | None = None,
) -> RunResult:
    """Run (or resume) PPO training into ``out``; see the module docstring. ``stop_after`` ends the
    call after that many iterations of this call (tests, time-boxed sessions); the run can be resumed.
    ``log`` takes the plain line per iteration (default: the current ``sys.stdout``), ``progress`` the
    progress report (default: the current ``sys.stderr``; :class:`areasearch.runlog.Progress`: a bar
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
            stop_after=stop_after,
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
    stop_after: int | None,
) -> RunResult:
    """:func:`train` in a run folder this process holds."""
    import torch

    from .dahgnn import DAHGNN, save_policy

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
    train_maps = expand_maps(config.rollout.maps)
    val_maps = expand_maps(config.evaluation.maps)
    run = Path(out)
    load = _prepare_run(run, config, resume)

    torch.manual_seed(config.seed)
    model = DAHGNN(config.network).to(device)
    optimizer = torch.optim.Adam(model.parameters(), lr=config.ppo.learning_rate, eps=1e-5)
    state: dict[str, Any] = {"iteration": 0, "decisions": 0, "episodes": 0, "wall_s": 0.0, "best_score": -1.0}
    if load:
        state.update(load_checkpoint(run, model, optimizer))
    model.eval()
    network = dataclasses.asdict(config.network)
    progress_log = CsvLog(run / PROGRESS_FILE, progress_fields(config.network.rounds), state["iteration"])
    eval_log = CsvLog(run / EVAL_FILE, EVAL_FIELDS, state["iteration"])
    scalars = Scalars(run / "tb", purge_step=state["decisions"] + 1 if load else None)
    pool = Backend(backend, workers, address)
    bar = Progress("train", config.total_decisions, "decisions", progress, done=state["decisions"], rate_unit="dec/s")
    threads = max(1, os.cpu_count() or 1)
    torch.set_num_threads(threads)
    ran = 0
    t_start = time.perf_counter() - float(state["wall_s"])
    try:
        if load and log is not None:
            bar.clear()
            print(f"resumed {run} at iteration {state['iteration']} ({state['decisions']:,} decisions)", file=log)
        while state["decisions"] < config.total_decisions and (stop_after is None or ran < stop_after):
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
                    _save_policy_atomic(save_policy, run / "policy", model)
            progress_log.append(row)
            scalars.add(row, state["decisions"])
            bar.clear()
            if log is not None:
                print(_line(row, config.total_decisions), file=log, flush=True)
            if iteration % config.checkpoint_every == 0 or last:
                save_checkpoint(run, model, optimizer, state)
            ran += 1
        if state["decisions"] >= config.total_decisions:
            _save_policy_atomic(save_policy, run / "final", model)
            if not (run / "policy.json").exists():
                _save_policy_atomic(save_policy, run / "policy", model)
            draw_training_curve(run)
            e = config.evaluation
            if e.episodes and e.finalists and not (run / SELECTION_FILE).exists():
                bar.clear()
                chosen = select_policy(pool, network, config, val_maps, run)
                if log is not None:
                    print(_selection_line(chosen), file=log, flush=True)
    finally:
        bar.update(state["decisions"])
        bar.close()
        pool.close()
        scalars.close()
    return RunResult(state["iteration"], state["decisions"], state["best_score"], state["wall_s"])


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
    from .dahgnn import load_policy

    by: dict[int, list[float]] = {}
    for row in _read_rows(run / EVAL_FILE):
        by.setdefault(int(row["decisions"]), []).append(float(row["coverage_auc"]))
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
    for suffix in (".safetensors", ".json"):  # weights first, the JSON that names them last
        atomic_bytes(run / f"policy{suffix}", src.with_name(src.name + suffix).read_bytes())
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


def _save_policy_atomic(save_policy: Callable[..., Any], prefix: Path, model: Any) -> None:
    """save_policy into temporary names, then rename both (JSON last)."""
    tmp = prefix.with_name(f".{prefix.name}.tmp")
    weights, meta = save_policy(tmp, model)
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
