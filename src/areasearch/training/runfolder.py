"""The files of a training run's folder (``areasearch train --out runs/NAME``), written so that a kill
at any moment leaves a folder a resume can continue from.

* ``config.json``: the resolved config (:func:`areasearch.training.config.config_to_dict`; resuming
  with another config is refused, naming the settings that differ: :func:`open_run`).
* ``checkpoint.json`` + ``checkpoint-<iteration>.safetensors``: weights, Adam state and counters
  (:func:`save_checkpoint`), written atomically at the start (iteration 0) and after every
  ``checkpoint_every`` iterations (the JSON, replaced last, names the weights file; older files are
  removed after). ``--resume`` continues from it and loses at most the iterations since; every
  field and tensor is checked first (:func:`read_checkpoint`, :func:`check_progress`,
  :func:`restore_checkpoint`). Since the iteration-0 checkpoint follows ``config.json`` at once, a
  folder with a run's files but no ``checkpoint.json`` has lost it, and is refused; without
  ``--resume`` an existing run is never overwritten.
* ``policy.safetensors`` + ``policy.json``: the policy to use, in the format of
  :func:`areasearch.models.dahgnn.save_policy` (``LearnedPlanner(weights="runs/NAME/policy")``), with a
  ``chosen`` record (:data:`areasearch.training.train.POLICY_CHOICES`). Until the first validation, the last
  weights; then the best validation so far (by the mean area under the Cover% curve,
  :func:`areasearch.training.validation.coverage_auc`); at the end, the winner of the final paired comparison of
  the best smoothed validations (``selection.json``, :func:`areasearch.training.validation.select_policy`).
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

from ..errors import ConfigError
from ..inputs import clip, regular_file, short
from .config import TRAIN_FORMAT

CONFIG_FILE, CHECKPOINT_FILE = "config.json", "checkpoint.json"
PROGRESS_FILE, EVAL_FILE = "progress.csv", "eval.csv"


# ---------------------------------------------------------------------------------------------- checkpoints


RUN_OUTPUTS = ("checkpoint.json", PROGRESS_FILE, EVAL_FILE, "selection.json", "curve.png", "snapshots", "tb")
"""What a run writes besides ``config.json``, the checkpoint weights and the ``policy`` / ``final`` files."""


def run_outputs(run: Path) -> list[str]:
    """The names in ``run`` that a training run writes besides ``config.json`` (hidden files aside:
    the lock, temporary files), sorted."""
    if not run.is_dir():
        return []
    found = []
    for entry in os.scandir(run):
        name = entry.name
        if name in RUN_OUTPUTS or name.startswith(("checkpoint-", "policy.", "final.")):
            found.append(name)
    return sorted(found)


def open_run(run: Path, config: Mapping[str, Any], resume: bool) -> bool:
    """Check the run folder ``run`` for a run of ``config`` (:func:`~areasearch.training.config.config_to_dict`)
    before anything is written, and start it (``config.json``) when it is new. Returns True when
    there is a checkpoint to continue from. ConfigError, nothing changed, for: a run there without
    ``resume``; a ``config.json`` that is damaged or records another config (the message names the
    settings that differ); a run's files without its ``config.json``; a run's files past its start
    without ``checkpoint.json`` (a new run would cut its logs and replace its checkpoints)."""
    from .config import config_differences, read_table

    if os.path.lexists(run) and not run.is_dir():
        raise ConfigError(f"{run}: the run folder is a file")
    saved = run / CONFIG_FILE
    if not os.path.lexists(saved):
        found = run_outputs(run)
        if found:
            raise ConfigError(
                f"{run}: holds a training run's {_names(found)} but no {CONFIG_FILE}; nothing was changed: "
                "restore its config.json to resume it, or use a new --out"
            )
        run.mkdir(parents=True, exist_ok=True)
        atomic_text(saved, json.dumps(dict(config), indent=1) + "\n")
        return False
    if not resume:
        raise ConfigError(f"{run}: a run is already there; pass --resume to continue it (nothing was changed)")
    previous = read_table(saved, "run's config")
    differ = config_differences(previous, config)
    if differ:
        more = f" and {len(differ) - 4} more" if len(differ) > 4 else ""
        older = any("(run: absent," in line for line in differ)
        raise ConfigError(
            f"{run}: the run was started with another config ({saved.name}); it differs in "
            f"{'; '.join(differ[:4])}{more}. Resume with the run's own config (leave out --config, --set and "
            "--realism), or start a new run with a new --out"
            + (
                "; a setting absent from config.json is newer than the run: resume it with the areasearch "
                "that started it"
                if older
                else ""
            )
        )
    if os.path.lexists(run / CHECKPOINT_FILE):
        return True
    kept = [name for name in run_outputs(run) if not _start_leftover(run / name)]
    if kept:
        raise ConfigError(
            f"{run}: no {CHECKPOINT_FILE}, but the run's {_names(kept)} are there; nothing was changed "
            "(starting again would cut the logs and replace the checkpoints): restore checkpoint.json, "
            "or move the folder away and start a new run"
        )
    return False


def _names(names: Sequence[str]) -> str:
    return ", ".join(names[:4]) + (f" and {len(names) - 4} more" if len(names) > 4 else "")


def _start_leftover(path: Path) -> bool:
    """Whether ``path`` is what a run killed before its first checkpoint leaves: the weights of the
    iteration-0 checkpoint, TensorBoard's folder, or a log with its header line alone."""
    if path.name in ("checkpoint-000000.safetensors", "tb"):
        return True
    if path.name not in (PROGRESS_FILE, EVAL_FILE) or not path.is_file() or path.stat().st_size > 2**16:
        return False
    return path.read_bytes().count(b"\n") <= 1


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


CHECKPOINT_COUNTERS = ("iteration", "decisions", "episodes", "wall_s", "best_score")
"""The counters of ``checkpoint.json`` (beside ``format``, ``weights`` and ``param_groups``)."""
ADAM_STATE = ("step", "exp_avg", "exp_avg_sq")
"""The tensors of Adam's state per parameter (``optim/<index>/<name>`` in the weights file)."""
ADAM_IMPLEMENTATION = ("foreach",)
"""Settings of Adam's ``param_groups`` that choose how its step is computed, not what it computes (the
multi-tensor and the per-tensor step give the same numbers): a checkpoint's are not held against the
trainer's."""


def read_checkpoint(run: Path, episodes_per_iteration: int) -> dict[str, Any]:
    """``checkpoint.json``, checked before anything is loaded or written: its format, the counters
    (iterations, decisions and episodes non-negative integers, ``episodes_per_iteration`` episodes per
    iteration, a finite wall time, a validation score of -1 (none yet) or 0-100), the weights file it
    names (``checkpoint-<iteration>.safetensors``: a name in the run folder, never a path) and
    Adam's ``param_groups``. ConfigError names the file and the field."""
    from .config import read_table

    meta = run / CHECKPOINT_FILE
    doc = read_table(meta, "checkpoint", MAX_CHECKPOINT_BYTES)
    known = {"format", "weights", "param_groups", *CHECKPOINT_COUNTERS}
    unknown = sorted(set(doc) - known)
    missing = [key for key in ("format", "weights", "param_groups", *CHECKPOINT_COUNTERS) if key not in doc]
    if unknown or missing:
        what = f"unknown field {short(unknown[0])}" if unknown else f"no field {missing[0]}"
        raise ConfigError(f"{meta}: {what}; not a checkpoint of this areasearch")
    if doc["format"] != TRAIN_FORMAT:
        raise ConfigError(f"{meta}: format must be {TRAIN_FORMAT!r}, got {short(doc['format'])}")
    for key in ("iteration", "decisions", "episodes"):
        value = doc[key]
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise ConfigError(f"{meta}: {key} must be an integer >= 0, got {short(value)}")
    if doc["episodes"] != doc["iteration"] * episodes_per_iteration:
        raise ConfigError(
            f"{meta}: episodes = {doc['episodes']:,} does not match iteration = {doc['iteration']:,} "
            f"({episodes_per_iteration} episodes per iteration, rollout.episodes)"
        )
    wall, best = doc["wall_s"], doc["best_score"]
    if isinstance(wall, bool) or not isinstance(wall, (int, float)) or not math.isfinite(wall) or wall < 0:
        raise ConfigError(f"{meta}: wall_s must be a finite number of seconds >= 0, got {short(wall)}")
    if isinstance(best, bool) or not isinstance(best, (int, float)) or not (best == -1 or 0 <= best <= 100):
        raise ConfigError(f"{meta}: best_score must be -1 (no validation yet) or in [0, 100], got {short(best)}")
    name = f"checkpoint-{doc['iteration']:06d}.safetensors"
    if doc["weights"] != name:
        raise ConfigError(f"{meta}: weights must be {name!r} (its iteration's file), got {short(doc['weights'])}")
    if not isinstance(doc["param_groups"], list) or not all(isinstance(g, dict) for g in doc["param_groups"]):
        raise ConfigError(f"{meta}: param_groups must be a list of tables, got {short(doc['param_groups'])}")
    return doc


MAX_CHECKPOINT_BYTES = 2**20
"""Largest ``checkpoint.json`` read (counters and Adam's settings: about a kilobyte)."""


def check_progress(run: Path, rows: Sequence[Mapping[str, str]], checkpoint: Mapping[str, Any]) -> None:
    """ConfigError unless ``progress.csv`` (its ``rows`` up to the checkpoint's iteration) has one row
    per iteration 1 .. the checkpoint's, the last with the checkpoint's decisions and episodes: a
    checkpoint whose counters lie about the run is refused before a row is cut."""
    meta, log = run / CHECKPOINT_FILE, run / PROGRESS_FILE
    iteration = int(checkpoint["iteration"])
    seen = [int(row["iteration"]) for row in rows]
    if seen != list(range(1, iteration + 1)):
        last = max(seen, default=0)
        what = f"rows up to iteration {last:,}" if seen == list(range(1, last + 1)) else "rows out of order"
        raise ConfigError(f"{meta}: iteration = {iteration:,}, but {log.name} has {what}; the checkpoint lies")
    if iteration:
        row = rows[-1]
        for key in ("decisions", "episodes"):
            if row.get(key) != str(checkpoint[key]):
                raise ConfigError(
                    f"{meta}: {key} = {checkpoint[key]:,}, but {log.name} says {short(row.get(key))} "
                    f"at iteration {iteration:,}; the checkpoint lies"
                )


def restore_checkpoint(run: Path, checkpoint: Mapping[str, Any], model: Any, optimizer: Any) -> dict[str, Any]:
    """Load the weights and Adam's state that :func:`read_checkpoint` found into ``model`` and
    ``optimizer``; returns the counters. Every tensor is checked first: the model's names, shapes and
    dtypes against the run's network, finite; Adam's ``optim/<index>/<name>`` for a parameter of the
    optimizer, the moments shaped as their parameter, the step a count, the second moment >= 0; and
    the ``param_groups`` against the trainer's Adam (the learning rate aside, set every iteration).
    ConfigError names the file and the tensor or field."""
    import torch
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    meta, weights = run / CHECKPOINT_FILE, run / str(checkpoint["weights"])
    groups = _param_groups(meta, checkpoint["param_groups"], optimizer.state_dict()["param_groups"])
    regular_file(weights, "checkpoint weights", ConfigError)
    try:
        tensors = load_file(str(weights))
    except (OSError, ValueError, RuntimeError, SafetensorError) as error:
        raise ConfigError(f"{weights}: cannot read the checkpoint: {clip(str(error))}") from None
    expected = model.state_dict()
    params = [p for group in optimizer.param_groups for p in group["params"]]
    model_state: dict[str, torch.Tensor] = {}
    opt_state: dict[int, dict[str, torch.Tensor]] = {}
    for key, value in tensors.items():
        kind, _, rest = key.partition("/")
        if kind == "model" and rest in expected:
            want: Any = expected[rest]
            model_state[rest] = value
        elif kind == "optim" and rest.count("/") == 1:
            index, name = rest.split("/")
            if not index.isdigit() or int(index) >= len(params) or name not in ADAM_STATE:
                raise ConfigError(f"{weights}: tensor {short(key)} is no part of the trainer's Adam state")
            want = params[int(index)] if name != "step" else torch.zeros((), dtype=torch.float32)
            opt_state.setdefault(int(index), {})[name] = value
        else:
            raise ConfigError(f"{weights}: tensor {short(key)} is not in the run's network or its optimizer")
        if value.shape != want.shape or value.dtype != want.dtype:
            raise ConfigError(
                f"{weights}: tensor {key} is {value.dtype} {list(value.shape)}; the run's network and "
                f"optimizer need {want.dtype} {list(want.shape)}"
            )
        if not bool(torch.isfinite(value).all()):
            raise ConfigError(f"{weights}: tensor {key} holds NaN or infinite values")
    absent = sorted(set(expected) - set(model_state))
    if absent:
        raise ConfigError(f"{weights}: no tensor model/{absent[0]} ({len(absent)} of the network's missing)")
    for slot, entry in sorted(opt_state.items()):
        lacking = [name for name in ADAM_STATE if name not in entry]
        if lacking:
            raise ConfigError(f"{weights}: no tensor optim/{slot}/{lacking[0]} beside the others of parameter {slot}")
        step = float(entry["step"])
        if step < 1 or step != int(step):
            raise ConfigError(f"{weights}: tensor optim/{slot}/step must be a count >= 1, got {step:g}")
        if bool((entry["exp_avg_sq"] < 0).any()):
            raise ConfigError(f"{weights}: tensor optim/{slot}/exp_avg_sq holds negative values")
    model.load_state_dict(model_state)
    optimizer.load_state_dict({"state": opt_state, "param_groups": groups})
    return {k: checkpoint[k] for k in CHECKPOINT_COUNTERS}


def _param_groups(meta: Path, given: list[dict[str, Any]], fresh: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The checkpoint's Adam ``param_groups``, checked against the trainer's own (``fresh``): the same
    parameters and settings, a finite learning rate >= 0; a setting this PyTorch has that the
    checkpoint lacks takes this PyTorch's default. ``foreach`` (:data:`ADAM_IMPLEMENTATION`) is the trainer's,
    whatever the checkpoint says."""
    if len(given) != len(fresh):
        raise ConfigError(f"{meta}: param_groups has {len(given)} groups; the trainer's Adam has {len(fresh)}")
    out = []
    for i, (group, own) in enumerate(zip(given, fresh, strict=True)):
        unknown = sorted(set(group) - set(own))
        if unknown:
            raise ConfigError(f"{meta}: param_groups[{i}] has an unknown setting {short(unknown[0])}")
        lr = group.get("lr", own["lr"])
        if isinstance(lr, bool) or not isinstance(lr, (int, float)) or not math.isfinite(lr) or lr < 0:
            raise ConfigError(f"{meta}: param_groups[{i}].lr must be a finite number >= 0, got {short(lr)}")
        for key, value in group.items():
            mine = list(own[key]) if isinstance(own[key], tuple) else own[key]
            if key not in ("lr", *ADAM_IMPLEMENTATION) and (value != mine or type(value) is not type(mine)):
                raise ConfigError(
                    f"{meta}: param_groups[{i}].{key} = {short(value)}; the trainer's Adam has {short(mine)}"
                )
        implementation = {key: own[key] for key in ADAM_IMPLEMENTATION if key in own}
        out.append({**own, **group, **({"betas": tuple(group["betas"])} if "betas" in group else {}), **implementation})
    return out


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
"""The per-round health columns (:func:`areasearch.models.dahgnn.diagnose`), ``health/round<i>_<name>``."""


def progress_fields(rounds: int) -> tuple[str, ...]:
    """The columns of ``progress.csv`` for a network of ``rounds`` rounds: :data:`PROGRESS_FIELDS`,
    then the health of the network (``health/*``): per round the features' RMS, the candidates'
    self-attention score spread and largest weight, the share of saturated MLP-attention logits;
    the final features' RMS; the gradient norm of each parameter group before clipping
    (:func:`areasearch.training.ppo.parameter_groups`)."""
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


MAX_LOG_BYTES = 2**30
"""Largest CSV log read on a resume (a 120,000-decision run's ``progress.csv`` is about 6 MB)."""


class CsvLog:
    """A CSV log, appended one fsync'ed line at a time. Opening reads the file (nothing is written:
    :meth:`start` writes) and keeps its complete rows up to ``keep_until`` (the checkpoint's
    iteration), so a resumed run has no duplicated row. ConfigError names the file when it is not a
    regular file, not UTF-8, has other columns than ``fields`` or a row whose iteration is not a count."""

    def __init__(self, path: Path, fields: Sequence[str], keep_until: int) -> None:
        self.path, self.fields = path, list(fields)
        self.rows: list[dict[str, str]] = []
        if not os.path.lexists(path):
            return
        text = read_text(path, "log", MAX_LOG_BYTES)
        if not text.endswith("\n"):  # a row cut by a kill
            text = text[: text.rfind("\n") + 1]
        if not text:
            return
        reader = csv.DictReader(io.StringIO(text))
        if reader.fieldnames != self.fields:
            header = ",".join(reader.fieldnames or [])
            raise ConfigError(
                f"{path}: its columns ({short(header)}) are not this run's ({short(','.join(self.fields))}); "
                "nothing was changed"
            )
        for line, row in enumerate(reader, start=2):
            iteration = row.get("iteration") or ""
            if not (iteration.isascii() and iteration.isdigit()) or None in row or None in row.values():
                raise ConfigError(f"{path}: line {line} is not a row of the log (iteration {short(iteration)})")
            if int(iteration) <= keep_until:
                self.rows.append(row)

    def start(self) -> None:
        """Write the file anew: the header and the rows kept."""
        buffer = io.StringIO()
        writer = csv.DictWriter(buffer, self.fields, lineterminator="\n")
        writer.writeheader()
        writer.writerows(self.rows)
        atomic_text(self.path, buffer.getvalue())

    def append(self, row: Mapping[str, Any]) -> None:
        buffer = io.StringIO()
        csv.DictWriter(buffer, self.fields, lineterminator="\n").writerow(
            {k: _fmt(row.get(k, "")) for k in self.fields}
        )
        with open(self.path, "a", encoding="utf-8") as f:
            f.write(buffer.getvalue())
            f.flush()
            os.fsync(f.fileno())


def read_text(path: Path, what: str, max_bytes: int) -> str:
    """The UTF-8 text of the regular file ``path``; ConfigError naming it otherwise."""
    info = regular_file(path, what, ConfigError)
    if info.st_size > max_bytes:
        raise ConfigError(f"{path}: {what} is larger than {max_bytes:,} bytes, the limit")
    try:
        with open(path, "rb") as f:
            return f.read(max_bytes + 1).decode("utf-8")
    except OSError as error:
        raise ConfigError(f"{path}: cannot read the {what}: {error.strerror}") from None
    except UnicodeDecodeError as error:
        raise ConfigError(f"{path}: cannot read the {what}: not UTF-8 text (byte {error.start})") from None


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

    progress = read_csv_rows(run / PROGRESS_FILE)
    if not progress:
        return None
    x = [float(r["decisions"]) for r in progress]
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6))
    axes[0].plot(x, _smooth([float(r["charts/episodic_return"]) for r in progress]))
    axes[0].set_title("training episodic return")
    axes[1].plot(x, _smooth([float(r["charts/covered_pct"]) for r in progress]), label="Cover%")
    axes[1].plot(x, _smooth([float(r["charts/explored_pct"]) for r in progress]), label="Explo%")
    axes[1].set_title("training episodes (end of episode)")
    axes[1].legend()
    xs, scores, _ = validation_scores(run)
    if xs:
        axes[2].plot(xs, scores, marker="o")
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


def read_csv_rows(path: Path) -> list[dict[str, str]]:
    """The rows of a run's CSV log (``progress.csv``, ``eval.csv``) as dicts; none when it is not there."""
    if not path.exists():
        return []
    with open(path, newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def validation_scores(run: Path, upto_iteration: int | None = None) -> tuple[list[int], list[float], dict[int, int]]:
    """The validations in ``eval.csv`` (those of iterations up to ``upto_iteration`` when given): their
    decisions in order, the mean score of each and the iteration of each. The one reading of a run's
    validation scores: the final selection (``validation.py``), a run's figures and ``curve.png`` share it."""
    by: dict[int, list[float]] = {}
    iteration_at: dict[int, int] = {}
    for row in read_csv_rows(run / EVAL_FILE):
        if upto_iteration is None or int(row["iteration"]) <= upto_iteration:
            by.setdefault(int(row["decisions"]), []).append(float(row["coverage_auc"]))
            iteration_at[int(row["decisions"])] = int(row["iteration"])
    points = sorted(by)
    return points, [float(np.mean(by[d])) for d in points], iteration_at
