"""A training run's figures, read back from its folder or its published copy: what its policy card
(``scripts/ship_policy.py``) and a campaign's table of runs (``scripts/train_campaign.py --table``) say
of it. Reads the files the trainer writes (``checkpoint.json``, ``progress.csv``, ``eval.csv``,
``selection.json``); writes nothing.
"""

from __future__ import annotations

import json
import statistics
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import ConfigError
from .runfolder import EVAL_FILE, PROGRESS_FILE, read_csv_rows, validation_scores
from .validation import SELECTION_FILE


@dataclass(frozen=True)
class Validation:
    """One validation of a run: when, and its mean coverage AUC over its episodes."""

    iteration: int
    decisions: int
    score: float


@dataclass(frozen=True)
class RunFigures:
    """A run's counters, time and validations."""

    iteration: int
    decisions: int
    episodes: int
    wall_s: float
    """Seconds its processes ran (the time between sessions not counted)."""
    iterations_s: float
    """Seconds of it its iterations (rollouts and updates) took; 0 without ``progress.csv``."""
    median_rate: float | None
    """The median of its iterations' decisions/s (None without ``progress.csv``): a pause or a busy
    moment of the machine moves it less than the wall time."""
    validations: tuple[Validation, ...]
    selection: dict[str, Any] | None
    """Its final selection (``selection.json``), None before it."""

    @property
    def iterations_share(self) -> float | None:
        """The share of the wall time its iterations took (the rest: validations, checkpoints, whatever
        else held the run); None without ``progress.csv``."""
        if self.median_rate is None or self.wall_s <= 0:
            return None
        return min(1.0, self.iterations_s / self.wall_s)

    @property
    def best(self) -> Validation:
        """The validation of the highest score (the first of equals)."""
        return max(self.validations, key=lambda v: v.score)


def run_figures(run: Path) -> RunFigures:
    """The figures of the run in ``run``. The counters are its checkpoint's or, in a published copy
    (no checkpoint), those of the last row of its ``progress.csv``, which the trainer writes with the
    same counters at each iteration's end. ConfigError when neither is there, or no validation is."""
    progress = read_csv_rows(run / PROGRESS_FILE)
    if (run / "checkpoint.json").is_file():
        counters = json.loads((run / "checkpoint.json").read_text(encoding="utf-8"))
    elif progress:
        counters = progress[-1]
    else:
        raise ConfigError(f"{run}: no checkpoint.json and no progress.csv rows; is this a finished run?")
    points, scores, iteration_at = validation_scores(run)
    if not points:
        raise ConfigError(f"{run / EVAL_FILE} has no validation rows")
    rates = [float(r["perf/decisions_per_s"]) for r in progress]
    selection = run / SELECTION_FILE
    return RunFigures(
        iteration=int(counters["iteration"]),
        decisions=int(counters["decisions"]),
        episodes=int(counters["episodes"]),
        wall_s=float(counters["wall_s"]),
        iterations_s=sum(float(r["perf/rollout_s"]) + float(r["perf/update_s"]) for r in progress),
        median_rate=statistics.median(rates) if rates else None,
        validations=tuple(Validation(iteration_at[d], d, score) for d, score in zip(points, scores, strict=True)),
        selection=json.loads(selection.read_text(encoding="utf-8")) if selection.is_file() else None,
    )
