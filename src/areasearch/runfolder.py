"""The files of a training run's folder (``areasearch train --out runs/NAME``), written so that a kill
at any moment leaves a folder a resume can continue from.

* ``config.json``: the resolved config (:func:`areasearch.train_config.config_to_dict`; resuming
  with another config is refused).
* ``checkpoint.json`` + ``checkpoint-<iteration>.safetensors``: weights, Adam state and counters
  (:func:`save_checkpoint`), written atomically after every ``checkpoint_every`` iterations (the
  JSON, replaced last, names the weights file; older files are removed after). ``--resume``
  continues from it (:func:`load_checkpoint`) and loses at most the iterations since; without
  ``--resume`` an existing run is never overwritten.
* ``policy.safetensors`` + ``policy.json``: the policy to use, in the format of
  :func:`areasearch.dahgnn.save_policy` (``LearnedPlanner(weights="runs/NAME/policy")``). While the
  run trains, the best validation so far (by the mean area under the Cover% curve,
  :func:`areasearch.train.coverage_auc`); at the end, the winner of the final paired comparison of
  the best smoothed validations (``selection.json``, :func:`areasearch.train.select_policy`).
  ``snapshots/dec-<decisions>.*``: the policy of each validation; ``final.*``: the policy after the
  last iteration.
* ``progress.csv`` (one row per iteration: ``charts/*``, ``losses/*``, ``perf/*`` and ``health/*``
  columns, :func:`progress_fields`), ``eval.csv`` (one row per validation episode, :data:`EVAL_FIELDS`):
  :class:`CsvLog`, cut back to the checkpoint's iteration on a resume; ``tb/`` (TensorBoard scalars
  under the same names, ``tensorboard --logdir runs``: :class:`Scalars`); ``curve.png`` (training
  curve: return, Cover% and Explo% by decisions, validation Cover% AUC:
  :func:`draw_training_curve`).

Every file but the logs is written to a temporary name, fsync'ed and renamed over the old one
(:func:`atomic_bytes`); a CSV row is one fsync'ed append; ``tb/`` is TensorBoard's own writer, told
on a resume to drop the steps past the checkpoint. Nothing is pickled to disk.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .errors import ConfigError
from .train_config import TRAIN_FORMAT

CONFIG_FILE, CHECKPOINT_FILE = "config.json", "checkpoint.json"
PROGRESS_FILE, EVAL_FILE = "progress.csv", "eval.csv"


# ---------------------------------------------------------------------------------------------- checkpoints


def atomic_bytes(path: Path, data: bytes) -> None:
    """``data`` into ``path`` whole or not at all: a temporary file, fsync'ed, renamed over it."""
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def atomic_text(path: Path, text: str) -> None:
    """:func:`atomic_bytes` of ``text`` in UTF-8."""
    atomic_bytes(path, text.encode("utf-8"))


def save_checkpoint(run: Path, model: Any, optimizer: Any, state: dict[str, Any]) -> Path:
    """Weights + Adam state in ``checkpoint-<iteration>.safetensors``, counters in ``checkpoint.json``
    (written last, atomically); then older checkpoint files are removed."""
    from safetensors.torch import save

    tensors = {f"model/{k}": v.detach().cpu().contiguous() for k, v in model.state_dict().items()}
    opt = optimizer.state_dict()
    for index, entry in opt["state"].items():
        for key, value in entry.items():
            tensors[f"optim/{index}/{key}"] = value.detach().cpu().contiguous().reshape(value.shape)
    name = f"checkpoint-{state['iteration']:06d}.safetensors"
    atomic_bytes(run / name, save(tensors))
    doc = {"format": TRAIN_FORMAT, "weights": name, "param_groups": opt["param_groups"], **state}
    atomic_text(run / CHECKPOINT_FILE, json.dumps(doc, indent=1) + "\n")
    for old in run.glob("checkpoint-*.safetensors"):
        if old.name != name:
            old.unlink(missing_ok=True)
    return run / name


def load_checkpoint(run: Path, model: Any, optimizer: Any) -> dict[str, Any]:
    """Restore what :func:`save_checkpoint` wrote; returns the counters. ConfigError names a bad file."""
    import torch
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    meta = run / CHECKPOINT_FILE
    try:
        doc = json.loads(meta.read_text())
        weights = run / str(doc["weights"])
        tensors = load_file(str(weights))
    except (OSError, ValueError, KeyError, TypeError, SafetensorError, json.JSONDecodeError) as error:
        raise ConfigError(f"{meta}: cannot read the checkpoint: {error}") from None
    prefix = "model/"
    state = {k[len(prefix) :]: v for k, v in tensors.items() if k.startswith(prefix)}
    expected = model.state_dict()
    if set(state) != set(expected) or any(state[k].shape != expected[k].shape for k in expected):
        raise ConfigError(f"{weights}: the weights do not match the run's network config")
    model.load_state_dict(state)
    opt_state: dict[int, dict[str, torch.Tensor]] = {}
    for key, value in tensors.items():
        if key.startswith("optim/"):
            _, index, name = key.split("/", 2)
            opt_state.setdefault(int(index), {})[name] = value
    try:
        optimizer.load_state_dict({"state": opt_state, "param_groups": doc["param_groups"]})
    except (ValueError, KeyError) as error:
        raise ConfigError(f"{meta}: the optimizer state does not match the network: {error}") from None
    return {k: v for k, v in doc.items() if k not in ("format", "weights", "param_groups")}


# ---------------------------------------------------------------------------------------------- logs


PROGRESS_FIELDS = (
    "iteration",
    "decisions",
    "episodes",
    "wall_s",
    "charts/episodic_return",
    "charts/explored_pct",
    "charts/covered_pct",
    "charts/episode_decisions",
    "charts/learning_rate",
    "charts/aux_coef",
    "losses/policy_loss",
    "losses/kl_penalty",
    "losses/value_loss",
    "losses/entropy",
    "losses/aux_loss",
    "losses/approx_kl",
    "losses/clipfrac",
    "losses/grad_norm",
    "losses/critic_grad_norm",
    "losses/explained_variance",
    "losses/advantage_mean",
    "perf/decisions_per_s",
    "perf/robot_steps_per_s",
    "perf/rollout_s",
    "perf/update_s",
    "losses/minibatches",
)
HEALTH_PER_ROUND = ("robot_rms", "goal_rms", "score_spread", "max_attention", "cross_saturated")
"""The per-round health columns (:func:`areasearch.dahgnn.diagnose`), ``health/round<i>_<name>``."""


def progress_fields(rounds: int) -> tuple[str, ...]:
    """The columns of ``progress.csv`` for a network of ``rounds`` rounds: :data:`PROGRESS_FIELDS`,
    then the health of the network (``health/*``): per round the features' RMS, the candidates'
    self-attention score spread and largest weight, the share of saturated MLP-attention logits;
    the final features' RMS; the gradient norm of each parameter group before clipping
    (:func:`areasearch.ppo.parameter_groups`)."""
    health = [f"health/round{i}_{name}" for i in range(rounds) for name in HEALTH_PER_ROUND]
    health += ["health/final_robot_rms", "health/final_goal_rms", "health/grad_norm_encoders"]
    health += [f"health/grad_norm_round{i}" for i in range(rounds)]
    health += ["health/grad_norm_similarity", "health/grad_norm_critic"]
    return (*PROGRESS_FIELDS, *health)


EVAL_FIELDS = (
    "iteration",
    "decisions",
    "map",
    "robots",
    "seed",
    "explored_pct",
    "covered_pct",
    "time_e",
    "time_c",
    "coverage_auc",
)


class CsvLog:
    """A CSV log, appended one fsync'ed line at a time; opening keeps only rows up to ``keep_until``
    (the checkpoint's iteration) and a complete header, so a resumed run has no duplicated row."""

    def __init__(self, path: Path, fields: Sequence[str], keep_until: int) -> None:
        self.path, self.fields = path, list(fields)
        rows: list[dict[str, str]] = []
        if path.exists():
            with open(path, newline="", encoding="utf-8") as f:
                text = f.read()
            if not text.endswith("\n"):
                text = text[: text.rfind("\n") + 1]
            reader = csv.DictReader(io.StringIO(text))
            if reader.fieldnames == self.fields:
                rows = [r for r in reader if r.get("iteration", "").isdigit() and int(r["iteration"]) <= keep_until]
        buffer = io.StringIO()
        writer = csv.DictWriter(buffer, self.fields, lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
        atomic_text(path, buffer.getvalue())

    def append(self, row: Mapping[str, Any]) -> None:
        buffer = io.StringIO()
        csv.DictWriter(buffer, self.fields, lineterminator="\n").writerow(
            {k: _fmt(row.get(k, "")) for k in self.fields}
        )
        with open(self.path, "a", encoding="utf-8") as f:
            f.write(buffer.getvalue())
            f.flush()
            os.fsync(f.fileno())


def _fmt(value: Any) -> Any:
    if isinstance(value, float):
        return f"{value:.6g}"
    return value


class Scalars:
    """TensorBoard scalars (``tb/`` of the run folder): every numeric ``charts/``, ``losses/``,
    ``perf/``, ``health/`` and ``eval/`` value of a row, by decisions."""

    def __init__(self, folder: Path, purge_step: int | None) -> None:
        from torch.utils.tensorboard import SummaryWriter

        self._writer = SummaryWriter(str(folder), purge_step=purge_step)

    def add(self, values: Mapping[str, Any], step: int) -> None:
        for key, value in values.items():
            if isinstance(value, (int, float)) and "/" in key and math.isfinite(value):
                self._writer.add_scalar(key, value, step)

    def close(self) -> None:
        self._writer.close()


def draw_training_curve(run: Path) -> Path | None:
    """``curve.png``: training return, Cover% and Explo% by decisions, and the validation score."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    progress = _read_csv(run / PROGRESS_FILE)
    if not progress:
        return None
    evals = _read_csv(run / EVAL_FILE)
    x = [float(r["decisions"]) for r in progress]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    axes[0].plot(x, _smooth([float(r["charts/episodic_return"]) for r in progress]))
    axes[0].set_title("training episodic return")
    axes[1].plot(x, _smooth([float(r["charts/covered_pct"]) for r in progress]), label="Cover%")
    axes[1].plot(x, _smooth([float(r["charts/explored_pct"]) for r in progress]), label="Explo%")
    axes[1].set_title("training episodes (end of episode)")
    axes[1].legend()
    if evals:
        by: dict[float, list[float]] = {}
        for r in evals:
            by.setdefault(float(r["decisions"]), []).append(float(r["coverage_auc"]))
        xs = sorted(by)
        axes[2].plot(xs, [float(np.mean(by[k])) for k in xs], marker="o")
    axes[2].set_title("validation: mean Cover% over the horizon")
    for ax in axes:
        ax.set_xlabel("decisions")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110)
    plt.close(fig)
    atomic_bytes(run / "curve.png", buffer.getvalue())
    return run / "curve.png"


def _smooth(values: Sequence[float], k: int = 10) -> list[float]:
    out, acc = [], []
    for v in values:
        acc.append(v)
        acc = acc[-k:]
        out.append(float(np.mean(acc)))
    return out


def _read_csv(path: Path) -> list[dict[str, str]]:
    if not path.exists():
        return []
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))
