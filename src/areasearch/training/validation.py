"""Validation during a training run and the final choice of its policy.

Every ``evaluation.every`` iterations (and after the last) :func:`validate` plays the validation
episodes (:func:`~areasearch.training.rollout.validation_episodes`: seeded as the evaluation harness
seeds its episodes, deterministic goals) and scores each by :func:`coverage_auc`; the loop
(:mod:`areasearch.training.train`) keeps the policy of each validation in ``snapshots/``. At the end
:func:`select_policy` plays the best smoothed validations again on fresh episodes, paired, and the
best of them becomes the run's ``policy.*`` (``selection.json``).
"""

from __future__ import annotations

import contextlib
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..config import SearchConfig
from ..runners import Runner
from .config import TrainConfig
from .rollout import play_episodes, validation_episodes
from .runfolder import CsvLog, Scalars, atomic_bytes, atomic_text, validation_scores

SNAPSHOTS = "snapshots"
"""Folder of a run with the policy of each validation (``dec-<decisions>.*``)."""
SELECTION_FILE = "selection.json"
"""What the final comparison of :func:`select_policy` measured and chose."""


def snapshot_name(decisions: int) -> str:
    """The file name (without suffix) of the snapshot taken at ``decisions``."""
    return f"dec-{int(decisions):09d}"


def coverage_auc(steps: Sequence[int], covered: Sequence[float], horizon: int) -> float:
    """Mean Cover% over the horizon (the area under the step-wise Cover% curve / horizon): higher
    when more targets are covered and when they are covered sooner."""
    area, last_step, last_value = 0.0, 0, 0.0
    for s, c in zip(steps, covered, strict=True):
        area += last_value * (min(s, horizon) - last_step)
        last_step, last_value = min(s, horizon), c
    area += last_value * (horizon - last_step)
    return area / horizon


def smoothed_scores(scores: Sequence[float]) -> list[float]:
    """Each validation's score averaged with its neighbours' (a window of 3, 2 at the ends): a
    checkpoint is judged by its stretch of the curve, not by one draw of validation noise."""
    out = []
    for i in range(len(scores)):
        window = scores[max(0, i - 1) : i + 2]
        out.append(float(np.mean(window)))
    return out


def validate(
    runner: Runner,
    network: dict[str, Any],
    weights: dict[str, np.ndarray],
    config: TrainConfig,
    maps: Sequence[str],
    env: SearchConfig,
    state: Mapping[str, Any],
    log: CsvLog,
    scalars: Scalars,
) -> float:
    """Play the validation episodes with deterministic goals; log them; return the mean coverage AUC."""
    scores, explored, covered = [], [], []
    specs = validation_episodes(config, maps, env=env)
    for traj in play_episodes(runner, network, weights, specs, config.rollout.lockstep):
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


def select_policy(
    runner: Runner,
    network: dict[str, Any],
    config: TrainConfig,
    maps: Sequence[str],
    run: Path,
    env: SearchConfig | None = None,
) -> dict[str, Any]:
    """The final checkpoint rule: the ``evaluation.finalists`` validations with the best smoothed
    score (:func:`smoothed_scores` of ``eval.csv``, ties to the later one) whose snapshots exist are
    played on ``evaluation.final_episodes`` fresh episodes per validation map and team size (seeds
    after the validation's, the same for every finalist: paired); the one with the best mean
    coverage AUC becomes ``policy.*``. Writes ``selection.json`` (every finalist's scores, the paired
    differences to the chosen one with 95 % intervals) and returns its content. Deterministic: a
    run killed during the selection makes the same choice on resume. ``env``: the episodes' world
    (:func:`~areasearch.training.rollout.episode_env` of ``config`` when not given)."""
    from ..models.weights import load_policy

    points, raw, iteration_at = validation_scores(run)
    smooth = smoothed_scores(raw)
    ranked = _by_smoothed_score(points, smooth, _snapshots(run))[: config.evaluation.finalists]
    e = config.evaluation
    specs = validation_episodes(config, maps, first=e.episodes, count=e.final_episodes, env=env)
    finals: dict[int, np.ndarray] = {}
    for i in ranked:
        model, _ = load_policy(run / SNAPSHOTS / snapshot_name(points[i]))
        weights = {k: v.detach().cpu().numpy().copy() for k, v in model.state_dict().items()}
        trajs = list(play_episodes(runner, network, weights, specs, config.rollout.lockstep))
        finals[i] = np.array([coverage_auc(t.steps, t.covered_curve, t.spec.max_steps) for t in trajs])
    if not finals:
        return {}
    best = max(ranked, key=lambda i: (float(finals[i].mean()), points[i]))
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
                "final_ci95": _interval(finals[i]),
                "minus_chosen": float((finals[i] - finals[best]).mean()),
                "minus_chosen_ci95": _interval(finals[i] - finals[best]),
            }
            for i in ranked
        ],
    }
    src = run / SNAPSHOTS / snapshot_name(points[best])
    atomic_bytes(run / "policy.safetensors", src.with_name(src.name + ".safetensors").read_bytes())
    meta = json.loads(src.with_name(src.name + ".json").read_text(encoding="utf-8"))  # the JSON last
    chosen = {"by": "final selection", "iteration": iteration_at[points[best]], "decisions": points[best]}
    meta["chosen"] = {**chosen, "final_score": float(finals[best].mean())}
    atomic_text(run / "policy.json", json.dumps(meta, indent=1) + "\n")
    atomic_text(run / SELECTION_FILE, json.dumps(doc, indent=1) + "\n")
    return doc


def _snapshots(run: Path) -> set[int]:
    """The decisions of the snapshots in ``run`` (a snapshot exists when its JSON, written last, does)."""
    found = set()
    for meta in (run / SNAPSHOTS).glob("dec-*.json"):
        with contextlib.suppress(ValueError):
            found.add(int(meta.stem.removeprefix("dec-")))
    return found


def _by_smoothed_score(points: Sequence[int], smooth: Sequence[float], have: set[int]) -> list[int]:
    """The indices of the validations whose snapshots exist, best smoothed score first (ties to the later)."""
    return sorted((i for i, d in enumerate(points) if d in have), key=lambda i: (smooth[i], points[i]), reverse=True)


def unchoosable_snapshots(run: Path, finalists: int, checkpoint_iteration: int) -> list[int]:
    """The decisions of the snapshots in ``run`` that :func:`select_policy` can no longer choose,
    whatever the rest of the run does: removing them changes nothing the run will do.

    A smoothed score (window 3) is final once the next validation exists; a snapshot is out of reach
    when ``finalists`` snapshots with final smoothed scores rank above it, since later validations
    can only add rivals. Only validations up to ``checkpoint_iteration`` count (a resumed run plays
    the later ones again); the last of them, and every snapshot ``eval.csv`` does not name, are kept.
    For a run folder to be moved or stored while it is not running: the snapshots of ~40 validations
    are ~40 MB, the ones that can still be chosen a handful."""
    points, raw, _ = validation_scores(run, checkpoint_iteration)
    smooth = smoothed_scores(raw)
    have = _snapshots(run)
    final = set(points[:-1])  # the last validation's smoothed score waits for the next validation
    ranked = [points[i] for i in _by_smoothed_score(points, smooth, have & final)]
    kept = set(ranked[:finalists])
    return sorted(d for d in have & final if d not in kept)


def _interval(x: np.ndarray) -> float:
    """Half the width of the 95 % normal interval of the mean of ``x`` (NaN for one value)."""
    return float(1.96 * x.std(ddof=1) / math.sqrt(len(x))) if len(x) > 1 else float("nan")


def selection_line(doc: Mapping[str, Any]) -> str:
    """The plain line that reports :func:`select_policy`'s comparison and choice."""
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
