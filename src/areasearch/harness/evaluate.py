"""Evaluation harness: the paper's test protocol (DA-HGNN "Experiments", Tables 3-5 and 7).

Every (map, team size, episode index) is played once by every method on
:class:`~areasearch.envs.goal.AreaSearchEnv` (one long-term goal per robot per decision, the
``max_steps`` horizon, 3600 primitive steps in the paper). Seeds are **paired**: the episode seed
comes from (run seed, map id, team size, episode index) only (:func:`episode_seed`), never from the
method, so every method meets the same start poses and targets; the planner's generator is derived
from the same seed (:func:`planner_rng`). An episode's numbers depend on its seed alone, so any
number of worker processes gives the same results.

Outputs in the run folder (``areasearch eval --out DIR``):

* ``episodes.csv``: one row per episode (:data:`CSV_FIELDS`); ``collisions`` and ``path_length_m``
  are team sums. ``time_e`` / ``time_c`` are the first steps at 80 % explored / covered, the horizon
  ``max_steps`` when never reached (also when the episode ended early, having run out of candidates).
* ``curves.jsonl``: explored % and covered % after each decision with its step index, one JSON line
  per episode.
* ``config.json``: the run seed, the ``--set`` settings (``settings``, when there are any), the
  resolved environment configuration and the SHA-256 of each map's content (``maps``, by map id:
  :attr:`areasearch.sim.scene.Scene.content_sha256`); resuming into a folder made with other settings, or
  on a map whose content has changed since its episodes were played, is refused. A folder whose
  ``config.json`` has no ``maps`` (written before maps were pinned) is resumed, and the hashes are
  added when the run next writes episodes there.
* ``summary.md``, ``summary.json``, ``summary.tex``, ``curves.png``: :mod:`areasearch.harness.report` over the
  episodes of this command; when ``greedy`` is among several methods, ``summary.md`` and
  ``summary.json`` also hold every other method's paired differences against it (same episodes).

Each CSV row and curve line is appended with one write, flushed and fsync'ed (the curve first), so an
interrupted run, even one killed with SIGKILL, leaves at most a partial last line and a curve whose
row is missing; re-running the same command truncates that line, drops such curves, keeps the
finished episodes and plays only the missing ones: no episode is lost or written twice, and the
files end up as an uninterrupted run writes them (``wall_s`` aside). Rows are written by the parent
process in plan order. Nothing is pickled to disk. One process at a time works in a run folder (an
``fcntl.flock`` on its ``.areasearch.lock``, :mod:`areasearch.folderlock`): a second one started on
the same folder is refused, naming the first one's pid; and the summary counts each (method, map,
robots, episode) once, whatever ``episodes.csv`` holds (:func:`unique_rows`).

A resumed folder is read with the checks of a user's input: a file that is a folder or a named pipe,
bytes that are not UTF-8, a ``config.json`` that is not a JSON object, an integer beyond Python's
conversion limit, a row with a value no episode can have (a percentage outside 0-100, a negative or
non-finite time, length or count) is refused with one message naming the file and the row; nothing is
summarised from such a folder. A failed write (file too large, disk full, read-only file system) ends
with one message; an append that failed is cut back to the last whole line, and every other file is
written atomically, so nothing already written is lost. A re-run that has nothing to play writes only
the files whose content changes, so a finished folder on read-only media is summarised as it is.

Backends: ``local`` plays the episodes in this process (``workers=1``) or in a pool of ``workers``
processes; ``ray`` plays each episode as a Ray task, on a local Ray instance of ``workers`` CPUs or
on an existing cluster (``address``, whose nodes have areasearch installed). Results come back in
plan order either way, so every backend writes the same files.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import hashlib
import io
import json
import logging
import math
import os
import socket
import sys
import time
from collections.abc import Callable, Generator, Mapping, Sequence
from concurrent.futures import Future
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from ..config import MAX_ROBOTS, MAX_STEPS, SearchConfig, search_config, search_settings
from ..envs.goal import AreaSearchEnv
from ..errors import AreaSearchError, ConfigError, MapError
from ..folderlock import hold_folder
from ..inputs import (
    clip,
    int_digits_message,
    is_int_digits_error,
    parse_json,
    read_bytes,
    regular_file,
    short,
    write_error,
)
from ..planners import PLANNERS, GoalPlanner, make_planner
from ..progress import Progress
from ..sim.scene import SIZE_CLASSES, bundled_index, load_scene, scene_source
from ..sim.world import draw_targets, sample_start_poses
from ..workers import worker_pool
from .report import (
    DECIMALS,
    SIZE_ORDER,
    Summary,
    draw_curves,
    json_ready,
    paired_differences,
    paired_markdown,
    summarize,
    to_latex,
    to_markdown,
    write_text,
)

BACKENDS = ("local", "ray")
"""Where episodes run: local processes, or Ray tasks (``pip install 'areasearch[ray]'``)."""

CSV_FIELDS = (
    "method",
    "map",
    "size_class",
    "robots",
    "episode",
    "seed",
    "explored_pct",
    "covered_pct",
    "covered_of_discovered_pct",
    "time_e",
    "time_c",
    "reached_e",
    "reached_c",
    "collisions",
    "path_length_m",
    "decisions",
    "wall_s",
)
"""Columns of ``episodes.csv``."""

_FIELD_TYPES: dict[str, Callable[[str], Any]] = {
    "method": str,
    "map": str,
    "size_class": str,
    "robots": int,
    "episode": int,
    "seed": int,
    "explored_pct": float,
    "covered_pct": float,
    "covered_of_discovered_pct": float,
    "time_e": int,
    "time_c": int,
    "reached_e": lambda s: {"True": True, "False": False}[s],
    "reached_c": lambda s: {"True": True, "False": False}[s],
    "collisions": int,
    "path_length_m": float,
    "decisions": int,
    "wall_s": float,
}

EPISODES_FILE, CURVES_FILE, CONFIG_FILE = "episodes.csv", "curves.jsonl", "config.json"
PAIRED_REFERENCE = "greedy"
"""The method every other one is compared with, episode by episode, in the summary (when present)."""
RUN_FORMAT = "areasearch-eval/2"


# ---------------------------------------------------------------------------------- seeds


def stable_hash(text: str) -> int:
    """A 64-bit integer from ``text`` that is the same in every process and Python version."""
    return int.from_bytes(hashlib.sha256(text.encode("utf-8")).digest()[:8], "little")


def episode_seed(seed: int, map_id: str, robots: int, episode: int) -> int:
    """The seed of one episode, shared by every method: from (run seed, map, team size, index) only."""
    state = np.random.SeedSequence([seed, stable_hash(map_id), robots, episode]).generate_state(1, np.uint64)
    return int(state[0] >> np.uint64(1))  # 63 bits: a non-negative int64


def planner_rng(seed: int) -> np.random.Generator:
    """The planner's generator for an episode: a stream of the episode seed apart from the env's."""
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(1,)))


# ---------------------------------------------------------------------------------- maps


@dataclass(frozen=True)
class MapEntry:
    """One map of the evaluation."""

    id: str
    """Scene name: bundled id, index id or file stem; part of the episode seed."""
    spec: str
    """What ``AreaSearchEnv(map=...)`` is given."""
    size_class: str
    free_area_m2: float
    sha256: str = ""
    """SHA-256 of the map's content (:attr:`areasearch.sim.scene.Scene.content_sha256`), pinned in config.json."""


def resolve_maps(
    specs: Sequence[str], sizes: Sequence[str] | None = None, per_size: int | None = None
) -> list[MapEntry]:
    """The single maps named by ``specs``: ``bundled`` (all bundled maps), bundled ids, folders in the
    bundled format (each listed map), PNGs in such folders, ROS YAML files. Each is loaded once (so a
    bad map fails here). ``sizes`` keeps those size classes; ``per_size`` keeps that many maps per
    class, evenly spaced in id order. Sorted by size class, then id. MapError when none is left."""
    found: dict[str, MapEntry] = {}
    for spec in specs:
        for single in _single_specs(spec):
            scene = load_scene(single)
            entry = MapEntry(scene.name, single, scene.size_class, scene.free_area_m2, scene.content_sha256)
            if entry.id in found and found[entry.id].spec != single:
                raise MapError(f"{single}: map id {entry.id!r} is also the id of {found[entry.id].spec}")
            found[entry.id] = entry
    if not found:
        raise MapError(f"{' '.join(specs)}: no maps")
    chosen = [e for e in found.values() if not sizes or e.size_class in sizes]
    if not chosen:
        raise MapError(f"{' '.join(specs)}: no maps of size class {', '.join(sizes or ())}")
    if per_size is not None:
        picked: list[MapEntry] = []
        for size in SIZE_CLASSES:
            picked += pick_evenly(sorted((e for e in chosen if e.size_class == size), key=lambda e: e.id), per_size)
        chosen = picked
    return sorted(chosen, key=lambda e: (_size_rank(e.size_class), e.id))


def check_teams(
    entries: Sequence[MapEntry], robots: Sequence[int], seed: int, config: SearchConfig | None = None
) -> None:
    """ConfigError, naming the map, unless every map can take every team size and the targets of
    ``config`` (default: :class:`SearchConfig`): start poses and targets are drawn as
    :class:`~areasearch.sim.world.World` draws them, for the first episode (so a run never fails after it
    has started writing)."""
    world_config = (config or SearchConfig()).world
    radius = world_config.robot.radius_m
    for entry in entries:
        scene = load_scene(entry.spec)
        reachable = scene.reachable(radius)
        for r in robots:
            sample_start_poses(scene, reachable, r, radius, np.random.default_rng(episode_seed(seed, entry.id, r, 0)))
        draw_targets(scene, reachable, world_config, np.random.default_rng(seed))


def _single_specs(spec: str) -> list[str]:
    if spec == "bundled":
        return [e["id"] for e in bundled_index()]
    if spec.startswith("bundled:"):  # a split: bundled:train, bundled:val, bundled:test
        from ..sim.splits import split_maps

        return split_maps(spec.split(":", 1)[1])
    if spec.startswith("procedural:"):
        raise MapError(f"{spec}: procedural layouts change every episode; evaluate on fixed maps")
    source = scene_source(spec)  # validates the spec
    path = Path(spec).expanduser()
    if path.is_dir():
        return [str(path / name) for name in source.names]
    return [spec]


def pick_evenly(items: Sequence[Any], n: int) -> list[Any]:
    """``n`` items evenly spaced through ``items`` (all of them when n >= len): the centres of n equal
    slices, so one item is the middle one."""
    if n >= len(items):
        return list(items)
    return [items[math.floor((i + 0.5) * len(items) / n)] for i in range(n)]


def _size_rank(size: str) -> int:
    return SIZE_ORDER.index(size) if size in SIZE_ORDER else len(SIZE_ORDER)


# ---------------------------------------------------------------------------------- episodes


@dataclass(frozen=True)
class Episode:
    """One episode to play: a method on a map with a team size and a seed."""

    method: str
    map: MapEntry
    robots: int
    index: int
    seed: int
    max_steps: int
    settings: tuple[tuple[str, Any], ...] = ()
    """World settings of the run (:func:`areasearch.config.search_settings` keys and values)."""
    weights: str | None = None
    """A learned method given by ``--policy NAME=PREFIX``: its weights' path prefix."""

    @property
    def key(self) -> tuple[str, str, int, int, int]:
        return (self.method, self.map.id, self.robots, self.index, self.seed)


def plan_episodes(
    methods: Sequence[str],
    robots: Sequence[int],
    maps: Sequence[MapEntry],
    episodes: int,
    seed: int,
    max_steps: int,
    settings: Mapping[str, Any] | None = None,
    policies: Mapping[str, str] | None = None,
) -> list[Episode]:
    """Every (map, team size, episode index) x method, methods innermost so that paired episodes
    finish together. ``policies``: learned methods by name -> weights prefix (``--policy``)."""
    pairs = tuple(search_settings(settings or {}).items())
    policies = policies or {}
    plan = []
    for entry in maps:
        for r in robots:
            for k in range(episodes):
                s = episode_seed(seed, entry.id, r, k)
                plan += [Episode(m, entry, r, k, s, max_steps, pairs, policies.get(m)) for m in methods]
    return plan


POLICIES_FILE = "policies.json"
"""Of an evaluation folder: each ``--policy`` method's weights (path and SHA-256), so that a resume
with other weights under the same name is refused."""


def check_policies(policies: Mapping[str, str], methods: Sequence[str]) -> dict[str, dict[str, str]]:
    """``--policy NAME=PREFIX`` entries checked: NAME a new name listed in ``methods`` (no registered
    planner is shadowed), PREFIX a loadable policy (:func:`areasearch.models.dahgnn.load_policy`, never
    unpickled). Returns name -> {"weights": prefix, "sha256": of its safetensors}."""
    out: dict[str, dict[str, str]] = {}
    for name, prefix in policies.items():
        if not isinstance(name, str) or not name or any(c in name for c in ",= \t\n"):
            raise ConfigError(f"--policy: a method name must be a plain word, got {name!r}")
        if name in PLANNERS:
            raise ConfigError(f"--policy {name}=...: {name!r} is a registered planner; give the policy another name")
        if name not in methods:
            raise ConfigError(f"--policy {name}=...: add {name} to --methods to evaluate it")
        from ..models.dahgnn import load_policy
        from ..planners.learned import weights_sha256

        load_policy(prefix)  # ConfigError naming the file when it is missing or damaged
        out[name] = {"weights": str(prefix), "sha256": weights_sha256(prefix)}
    return out


def episode_metrics(info: dict[str, Any]) -> dict[str, Any]:
    """The paper's metrics of a finished episode from the env's last ``info``. Time_E / Time_C are the
    horizon when 80 % was never reached, also for an episode that ended early (``World.metrics``)."""
    return {
        "explored_pct": round(float(info["explored_pct"]), 6),
        "covered_pct": round(float(info["covered_pct"]), 6),
        "covered_of_discovered_pct": round(float(info["covered_of_discovered_pct"]), 6),
        "time_e": int(info["time_e"]),
        "time_c": int(info["time_c"]),
        "reached_e": bool(info["reached_e"]),
        "reached_c": bool(info["reached_c"]),
        "collisions": int(sum(info["collisions"])),
        "path_length_m": round(float(sum(info["path_length_m"])), 6),
    }


@dataclass
class EpisodeTrace:
    """What :func:`play_episode` saw: explored / covered after each decision, the last info."""

    steps: list[int]
    explored_pct: list[float]
    covered_pct: list[float]
    info: dict[str, Any]

    @property
    def decisions(self) -> int:
        return len(self.steps) - 1


def play_episode(
    env: AreaSearchEnv, planner: GoalPlanner, seed: int, progress: TextIO | None = None, label: str = "episode"
) -> EpisodeTrace:
    """Reset ``env`` and ``planner`` from ``seed`` and step ``planner.assign(obs)`` until terminated or
    truncated. ``progress``: a stream for the steps played so far (:class:`areasearch.progress.Progress`,
    headed ``label``: a bar on a terminal, a plain line every 10 s otherwise), None for silence."""
    obs, info = env.reset(seed=seed)
    planner.reset(planner_rng(seed))
    trace = EpisodeTrace([int(info["steps"])], [float(info["explored_pct"])], [float(info["covered_pct"])], info)
    bar = Progress(label, env.config.world.max_steps, "steps", progress, rate_unit="steps/s")
    done = False
    try:
        while not done:
            obs, _, terminated, truncated, info = env.step(planner.assign(obs))
            trace.steps.append(int(info["steps"]))
            trace.explored_pct.append(float(info["explored_pct"]))
            trace.covered_pct.append(float(info["covered_pct"]))
            bar.update(int(info["steps"]))
            done = terminated or truncated
    except BaseException:
        bar.clear()  # the error's own line follows alone
        raise
    bar.close()
    trace.info = info
    return trace


def make_env(
    map_spec: str, robots: int, seed: int, max_steps: int, settings: Mapping[str, Any] | None = None
) -> AreaSearchEnv:
    """The environment of one episode: one map, one team size, the harness's horizon, and world
    ``settings`` (:func:`areasearch.config.search_settings` keys, e.g. ``{"targets.count": 50}``)."""
    config = search_config(settings) if settings else None
    return AreaSearchEnv(map=map_spec, num_robots=robots, seed=seed, config=config, max_steps=max_steps)


def run_episode(ep: Episode) -> tuple[dict[str, Any], dict[str, Any]]:
    """Play one episode (in a worker process or here): its CSV row and its curve record."""
    t0 = time.perf_counter()
    env = make_env(ep.map.spec, ep.robots, ep.seed, ep.max_steps, dict(ep.settings))
    if ep.weights is not None:
        from ..planners.learned import LearnedPlanner

        planner: GoalPlanner = LearnedPlanner(weights=ep.weights, name=ep.method)
    else:
        planner = make_planner(ep.method)
    trace = play_episode(env, planner, ep.seed)
    ident = {"method": ep.method, "map": ep.map.id}
    row = {
        **ident,
        "size_class": ep.map.size_class,
        "robots": ep.robots,
        "episode": ep.index,
        "seed": ep.seed,
        **episode_metrics(trace.info),
        "decisions": trace.decisions,
        "wall_s": round(time.perf_counter() - t0, 3),
    }
    curve = {
        **ident,
        "robots": ep.robots,
        "episode": ep.index,
        "seed": ep.seed,
        "steps": trace.steps,
        "explored_pct": [round(v, 4) for v in trace.explored_pct],
        "covered_pct": [round(v, 4) for v in trace.covered_pct],
    }
    return row, curve


# ---------------------------------------------------------------------------------- files


def _key(record: dict[str, Any]) -> tuple[str, str, int, int, int]:
    return (
        str(record["method"]),
        str(record["map"]),
        int(record["robots"]),
        int(record["episode"]),
        int(record["seed"]),
    )


def csv_line(row: dict[str, Any]) -> str:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow([row[f] for f in CSV_FIELDS])
    return buf.getvalue()


LOG_NAMES = {EPISODES_FILE: "episodes file", CURVES_FILE: "curve log"}
"""What each line log of a results folder is called in a message."""


def _complete_lines(path: Path) -> tuple[list[str], int]:
    """The complete (newline-terminated) lines of a log file and the byte length they span; a
    trailing partial line (an interrupted append) is not among them. AreaSearchError naming the file
    for a folder or named pipe there (never opened) or bytes that are not UTF-8 (naming the line)."""
    if not os.path.lexists(path):
        return [], 0
    what = LOG_NAMES.get(path.name, "log")
    regular_file(path, what, AreaSearchError)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise AreaSearchError(f"{path}: cannot read the {what}: {exc.strerror}") from None
    end = data.rfind(b"\n") + 1
    try:
        text = data[:end].decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise AreaSearchError(f"{path}: line {line}: not UTF-8 text (byte {exc.start})") from None
    return text.splitlines(), end


MAX_EPISODE_SEED = 2**64 - 1
"""Largest episode seed (:func:`episode_seed` gives 63 bits)."""


def _row_problem(row: Mapping[str, Any]) -> str | None:
    """What makes a typed ``episodes.csv`` row impossible for an episode, or None: a percentage outside
    0-100 or not finite, a time outside 0 to the longest horizon, a negative count, length or duration,
    a team size outside 1-8."""
    for key in ("explored_pct", "covered_pct", "covered_of_discovered_pct"):
        if not (math.isfinite(row[key]) and 0.0 <= row[key] <= 100.0):
            return f"{key} = {row[key]:g} is not a percentage from 0 to 100"
    for key in ("time_e", "time_c"):
        if not 0 <= row[key] <= MAX_STEPS:
            return f"{key} = {row[key]} is not a step from 0 to {MAX_STEPS:,}"
    for key in ("path_length_m", "wall_s"):
        if not (math.isfinite(row[key]) and row[key] >= 0.0):
            return f"{key} = {row[key]:g} is not a finite number >= 0"
    for key in ("episode", "collisions", "decisions"):
        if row[key] < 0:
            return f"{key} = {row[key]} is negative"
    if not 0 <= row["seed"] <= MAX_EPISODE_SEED:
        return f"seed = {row['seed']} is not a 64-bit seed"
    if not 1 <= row["robots"] <= MAX_ROBOTS:
        return f"robots = {row['robots']} is not a team size from 1 to {MAX_ROBOTS}"
    return None


def read_episodes(path: Path) -> list[dict[str, Any]]:
    """Rows of an ``episodes.csv`` (ignoring a trailing partial line), typed. AreaSearchError naming the
    file and the row for a malformed row or one no episode can have (:func:`_row_problem`): it is
    refused, never summarised."""
    lines, _ = _complete_lines(path)
    if not lines:
        return []
    header = next(csv.reader([lines[0]]))
    if tuple(header) != CSV_FIELDS:
        raise AreaSearchError(f"{path}: not an episodes file of this version (header {short(','.join(header))})")
    rows = []
    for number, values in enumerate(csv.reader(lines[1:]), start=2):
        try:
            if len(values) != len(CSV_FIELDS):
                raise ValueError(f"{len(values)} fields")
            row = {f: _FIELD_TYPES[f](v) for f, v in zip(CSV_FIELDS, values, strict=True)}
        except (ValueError, KeyError) as exc:
            reason = int_digits_message() if is_int_digits_error(exc) else clip(str(exc), 100)
            raise AreaSearchError(f"{path}:{number}: malformed row ({reason})") from None
        problem = _row_problem(row)
        if problem is not None:
            raise AreaSearchError(f"{path}:{number}: impossible row: {problem}; no episode gives it")
        rows.append(row)
    return rows


def _curve_problem(record: Mapping[str, Any]) -> str | None:
    """What makes a ``curves.jsonl`` record unusable for the curve figure, or None."""
    steps, explored, covered = record.get("steps"), record.get("explored_pct"), record.get("covered_pct")
    if not all(isinstance(v, list) for v in (steps, explored, covered)) or not steps:
        return "steps, explored_pct and covered_pct must be non-empty lists"
    assert isinstance(steps, list) and isinstance(explored, list) and isinstance(covered, list)
    if not len(steps) == len(explored) == len(covered):
        return "steps, explored_pct and covered_pct must be as long as each other"
    if not all(isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= MAX_STEPS for v in steps):
        return f"steps must be steps from 0 to {MAX_STEPS:,}"
    for name, values in (("explored_pct", explored), ("covered_pct", covered)):
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and 0 <= v <= 100 for v in values):
            return f"{name} must be percentages from 0 to 100"
    return None


def read_curves(path: Path) -> dict[tuple[str, str, int, int, int], dict[str, Any]]:
    """Curve records of a ``curves.jsonl`` by episode key (the last one wins), ignoring a trailing
    partial line; AreaSearchError naming the file and the line for one that is malformed or holds
    values no episode has."""
    lines, _ = _complete_lines(path)
    curves = {}
    for number, line in enumerate(lines, start=1):
        try:
            record = json.loads(line)
            key = _key(record)
        except (json.JSONDecodeError, KeyError, TypeError, ValueError, AttributeError) as exc:
            reason = int_digits_message() if is_int_digits_error(exc) else clip(str(exc), 100)
            raise AreaSearchError(f"{path}:{number}: malformed curve line ({reason})") from None
        problem = _curve_problem(record)
        if problem is not None:
            raise AreaSearchError(f"{path}:{number}: impossible curve: {problem}")
        curves[key] = record
    return curves


class AppendLog:
    """A line log where each line is appended with one write, then fsync'ed. Opening it truncates a
    trailing partial line left by an interrupted write and writes ``header`` into an empty file. A
    write that fails (file too large, disk full) is cut back to the last whole line and raises one
    AreaSearchError naming the file: the lines already there are kept."""

    def __init__(self, path: Path, header: str | None = None) -> None:
        _, end = _complete_lines(path)
        self.path = path
        try:
            self._fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_CLOEXEC, 0o644)
            if os.fstat(self._fd).st_size != end:
                os.ftruncate(self._fd, end)
        except OSError as exc:
            raise AreaSearchError(write_error(path, exc, LOG_NAMES.get(path.name, "log"))) from None
        self._end = end
        if end == 0 and header is not None:
            self.append(header)

    def append(self, line: str) -> None:
        data = line.encode("utf-8")
        try:
            while data:
                data = data[os.write(self._fd, data) :]
            os.fsync(self._fd)
        except OSError as exc:
            with contextlib.suppress(OSError):
                os.ftruncate(self._fd, self._end)  # no partial line is left behind
            raise AreaSearchError(write_error(self.path, exc, LOG_NAMES.get(self.path.name, "log"))) from None
        self._end += len(line.encode("utf-8"))

    def close(self) -> None:
        os.close(self._fd)


# ---------------------------------------------------------------------------------- the harness


@dataclass(frozen=True)
class RunPlan:
    """A validated evaluation: what to play and where to write. Built by :func:`prepare`."""

    out: Path
    methods: tuple[str, ...]
    robots: tuple[int, ...]
    maps: tuple[MapEntry, ...]
    episodes: int
    seed: int
    max_steps: int
    workers: int
    plan: tuple[Episode, ...]
    done: frozenset[tuple[str, str, int, int, int]]
    """Keys of planned episodes already in ``episodes.csv``."""
    run_config: dict[str, Any]
    backend: str = "local"
    """:data:`BACKENDS`: local processes or Ray tasks."""
    address: str | None = None
    """With the ``ray`` backend: the address of an existing Ray cluster (None: start a local one)."""
    settings: tuple[tuple[str, Any], ...] = ()
    """World settings of every episode (:func:`areasearch.config.search_settings` keys and values)."""
    policies: tuple[tuple[str, dict[str, str]], ...] = ()
    """``--policy`` methods: name -> weights prefix and SHA-256 (:func:`check_policies`)."""
    maps_record: tuple[tuple[str, str], ...] = ()
    """``config.json``'s ``maps``: the SHA-256 of each map's content by id, those recorded before and this run's."""
    config_current: bool = False
    """``config.json`` already holds :attr:`run_config` and :attr:`maps_record`: a resume writes it only
    when it plays episodes and the map hashes are new."""


RESERVED_SETTINGS = {"world.num_robots": "robots", "world.max_steps": "max_steps"}
"""World settings that an evaluation takes as arguments of their own, not as ``settings``."""


def run_config(seed: int, max_steps: int, settings: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """What ``config.json`` holds: the settings every episode's numbers depend on besides its key:
    the run seed, the horizon, the world ``settings`` given (``settings``, only when there are any),
    the resolved configuration."""
    given = search_settings(settings or {})
    for key, argument in RESERVED_SETTINGS.items():
        if key in given:
            raise ConfigError(f"setting {key} is set by the {argument} argument, not among the settings")
    config = dataclasses.asdict(search_config({**given, "world.max_steps": max_steps}))
    del config["world"]["num_robots"]  # set per episode
    record = {"format": RUN_FORMAT, "seed": seed, "max_steps": max_steps, **({"settings": given} if given else {})}
    record["config"] = config
    return dict(json.loads(json.dumps(record)))  # as it reads back from config.json


def prepare(
    methods: Sequence[str],
    robots: Sequence[int],
    maps: Sequence[str],
    episodes: int,
    seed: int,
    max_steps: int,
    out: str | Path,
    *,
    workers: int = 1,
    sizes: Sequence[str] | None = None,
    maps_per_size: int | None = None,
    backend: str = "local",
    address: str | None = None,
    settings: Mapping[str, Any] | None = None,
    policies: Mapping[str, str] | None = None,
) -> RunPlan:
    """Check every argument and the output folder without writing anything; AreaSearchError (one
    message) on bad input. ``settings``: world settings of every episode (``--set``, keys as
    :func:`areasearch.config.search_settings` takes them); ``policies``: learned methods given by
    their weights, name -> path prefix (``--policy NAME=PREFIX``)."""
    if not methods:
        raise ConfigError("no methods given")
    policies = dict(policies or {})
    unknown = [m for m in methods if m not in PLANNERS and m not in policies]
    if unknown:
        raise ConfigError(f"unknown method(s) {', '.join(unknown)}; choose from {', '.join(PLANNERS)}")
    for method in methods:
        if method not in policies and PLANNERS.plugin(method) is not None:
            make_planner(method)  # a plug-in that fails: its one error now, before any episode
    if len(set(methods)) != len(methods):
        raise ConfigError(f"a method is listed twice: {' '.join(methods)}")
    if not robots:
        raise ConfigError("no team sizes given")
    for r in robots:
        if isinstance(r, bool) or not isinstance(r, int) or not 1 <= r <= MAX_ROBOTS:
            raise ConfigError(f"robots must be from 1 to {MAX_ROBOTS}, got {r!r}")
    if len(set(robots)) != len(robots):
        raise ConfigError(f"a team size is listed twice: {' '.join(map(str, robots))}")
    for name, value, low in (("episodes", episodes, 1), ("max-steps", max_steps, 1), ("workers", workers, 1)):
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise ConfigError(f"{name} must be an integer >= {low}, got {value!r}")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ConfigError(f"seed must be a non-negative integer, got {seed!r}")
    if maps_per_size is not None and (isinstance(maps_per_size, bool) or maps_per_size < 1):
        raise ConfigError(f"maps-per-size must be an integer >= 1, got {maps_per_size!r}")
    for size in sizes or ():
        if size not in SIZE_CLASSES:
            raise ConfigError(f"unknown size class {size!r}; use {', '.join(SIZE_CLASSES)}")
    if backend not in BACKENDS:
        raise ConfigError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    if address is not None and backend != "ray":
        raise ConfigError("--address is for --backend ray (the address of a Ray cluster)")
    if address is not None and (not isinstance(address, str) or not address.strip()):
        raise ConfigError(f"address must be a Ray cluster address such as 10.0.0.5:6379, got {address!r}")
    if backend == "ray":
        try:
            import ray  # noqa: F401
        except ImportError:
            raise ConfigError("--backend ray needs Ray: pip install 'areasearch[ray]'") from None
        if address is not None:
            check_ray_address(address)
    out = Path(out).expanduser()
    if out.exists() and not out.is_dir():
        raise AreaSearchError(f"{out}: output path is an existing file; give a folder")
    config = run_config(seed, max_steps, settings)
    given = search_settings(settings or {})
    entries = resolve_maps(maps, sizes, maps_per_size)
    check_teams(entries, robots, seed, search_config(given))

    done: set[tuple[str, str, int, int, int]] = set()
    maps_record = {e.id: e.sha256 for e in entries}
    config_current = False
    if out.is_dir():
        config_path = out / CONFIG_FILE
        if os.path.lexists(config_path):
            old = read_record(config_path, "results config")
            recorded_maps = _recorded_maps(config_path, old)
            if {k: v for k, v in old.items() if k != "maps"} != config:
                keys = ("format", "seed", "max_steps", "settings", "config")
                changed = [k for k in keys if old.get(k) != config.get(k)]
                raise AreaSearchError(
                    f"{out}: holds episodes of a run with other settings ({', '.join(changed)} differ); "
                    "use another --out folder or the same settings"
                )
            _check_maps_unchanged(config_path, recorded_maps, maps_record, entries)
            merged = {**recorded_maps, **maps_record}
            config_current = "maps" in old and merged == recorded_maps
            maps_record = merged
        elif os.path.lexists(out / EPISODES_FILE):
            raise AreaSearchError(f"{out}: has {EPISODES_FILE} but no {CONFIG_FILE}; use another --out folder")
        done = {_key(row) for row in read_episodes(out / EPISODES_FILE)}
        read_curves(out / CURVES_FILE)  # a malformed curve file fails now, not after the episodes
    checked = check_policies(policies, methods)
    if checked and os.path.lexists(out / POLICIES_FILE):
        recorded = read_record(out / POLICIES_FILE, "policies record")
        for name, entry in checked.items():
            old_entry = recorded.get(name) if isinstance(recorded, dict) else None
            if isinstance(old_entry, dict) and old_entry.get("sha256") != entry["sha256"]:
                raise AreaSearchError(
                    f"{out}: method {name} was evaluated with other weights ({old_entry.get('weights')}); "
                    "use another --out folder or another name"
                )
    plan = plan_episodes(methods, robots, entries, episodes, seed, max_steps, given, policies)
    return RunPlan(
        out=out,
        methods=tuple(methods),
        robots=tuple(robots),
        maps=tuple(entries),
        episodes=episodes,
        seed=seed,
        max_steps=max_steps,
        workers=workers,
        plan=tuple(plan),
        done=frozenset(done & {ep.key for ep in plan}),
        run_config=config,
        backend=backend,
        address=address,
        settings=tuple(given.items()),
        policies=tuple(checked.items()),
        maps_record=tuple(sorted(maps_record.items())),
        config_current=config_current,
    )


MAX_RECORD_BYTES = 16 * 2**20
"""Largest ``config.json`` or ``policies.json`` of a results folder read, bytes (they hold a few KB)."""


def read_record(path: Path, what: str) -> dict[str, Any]:
    """The JSON object in a results folder's ``config.json`` or ``policies.json``; AreaSearchError
    naming the file for a folder or named pipe there (never opened), a file over
    :data:`MAX_RECORD_BYTES`, bytes that are not UTF-8, text that does not parse (an integer beyond
    Python's conversion limit too), or a document that is not an object."""
    data = read_bytes(path, what, MAX_RECORD_BYTES, None, AreaSearchError)
    doc = parse_json(data, str(path), AreaSearchError)
    if not isinstance(doc, dict):
        raise AreaSearchError(f"{path}: the {what} must be a JSON object, got {type(doc).__name__}")
    return doc


def _recorded_maps(path: Path, record: Mapping[str, Any]) -> dict[str, str]:
    """The ``maps`` of a results ``config.json`` (map id -> SHA-256 of its content); {} in a folder
    written before maps were pinned. AreaSearchError naming the file when it is malformed."""
    maps = record.get("maps", {})
    if not isinstance(maps, dict) or not all(
        isinstance(k, str) and isinstance(v, str) and len(v) == 64 for k, v in maps.items()
    ):
        raise AreaSearchError(f"{path}: field 'maps' must map each map id to the SHA-256 of its content")
    return dict(maps)


def _check_maps_unchanged(
    path: Path, recorded: Mapping[str, str], current: Mapping[str, str], entries: Sequence[MapEntry]
) -> None:
    """AreaSearchError naming the first map whose content differs from the one its episodes were played on."""
    for entry in entries:
        old = recorded.get(entry.id)
        if old is not None and old != current[entry.id]:
            raise AreaSearchError(
                f"{path}: map {entry.id} has changed since its episodes were played (SHA-256 {old[:12]}... "
                f"recorded, {current[entry.id][:12]}... now in {entry.spec}); a resume would mix episodes of two "
                "maps: use another --out folder, or restore the map"
            )


def execute(run: RunPlan, progress: TextIO | None = sys.stderr) -> Summary:
    """Play the missing episodes of ``run`` (in ``run.workers`` processes), append their rows and
    curves, then write the summary tables and the curve figure over all planned episodes. The
    folder is held by this process meanwhile (:func:`areasearch.folderlock.hold_folder`); the
    episodes to play are those not in ``episodes.csv`` when it is taken (a row found twice there is
    dropped, :func:`drop_duplicate_rows`)."""
    with hold_folder(run.out, "output path"):
        return _execute(run, progress)


def _execute(run: RunPlan, progress: TextIO | None) -> Summary:
    run.out.mkdir(parents=True, exist_ok=True)
    config_path = run.out / CONFIG_FILE
    played = {_key(row) for row in read_episodes(run.out / EPISODES_FILE)}
    if not config_path.exists() or (not run.config_current and any(ep.key not in played for ep in run.plan)):
        record = {**run.run_config, "maps": dict(run.maps_record)}  # the maps' hashes join when episodes are played
        write_text(config_path, json.dumps(record, indent=2) + "\n")
    if run.policies:
        path = run.out / POLICIES_FILE
        recorded = json.loads(path.read_text()) if path.exists() else {}
        # a name already recorded with the same weights keeps its entry (the path it was first given),
        # so re-running a command, from another folder or with another path to the file, rewrites nothing
        new = {name: entry for name, entry in run.policies if name not in recorded}
        if new or not path.exists():
            write_text(path, json.dumps({**recorded, **new}, indent=2, sort_keys=True) + "\n")
    drop_duplicate_rows(run.out / EPISODES_FILE)
    done = {_key(row) for row in read_episodes(run.out / EPISODES_FILE)}
    todo = [ep for ep in run.plan if ep.key not in done]
    if not todo:  # nothing to play: nothing is appended (a finished folder on read-only media is summarised)
        return write_summary(run)
    rows_log = AppendLog(run.out / EPISODES_FILE, header=",".join(CSV_FIELDS) + "\n")
    drop_orphan_curves(run.out / CURVES_FILE, {_key(row) for row in read_episodes(run.out / EPISODES_FILE)})
    curves_log = AppendLog(run.out / CURVES_FILE)
    bar = Progress(
        "eval", len(run.plan), "episodes", progress if todo else None, done=len(run.plan) - len(todo), rate_unit="ep/s"
    )
    try:
        with contextlib.closing(_results(todo, run.workers, run.backend, run.address)) as results:
            for row, curve in results:
                curves_log.append(json.dumps(curve, separators=(",", ":")) + "\n")
                rows_log.append(csv_line(row))
                bar.advance()
    finally:
        bar.close()
        rows_log.close()
        curves_log.close()
    return write_summary(run)


def episode_id(row: Mapping[str, Any]) -> tuple[str, str, int, int]:
    """The (method, map, robots, episode) of an episode's row: one row per key in a run."""
    return (str(row["method"]), str(row["map"]), int(row["robots"]), int(row["episode"]))


def unique_rows(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """``rows`` without a second row of one (method, map, robots, episode) key (:func:`episode_id`;
    the first is kept)."""
    seen: set[tuple[str, str, int, int]] = set()
    out = []
    for row in rows:
        key = episode_id(row)
        if key not in seen:
            seen.add(key)
            out.append(row)
    return out


def drop_duplicate_rows(path: Path) -> None:
    """Keep in ``episodes.csv`` the first row of each (method, map, robots, episode) key (rows written
    twice by an older version's concurrent runs). Rewritten atomically, only when a row is dropped."""
    lines, _ = _complete_lines(path)
    rows = read_episodes(path)
    if len(rows) != len(lines) - 1:  # a quoted field across lines: leave the file to the summary's dedup
        return
    kept = unique_rows(rows)
    if len(kept) == len(rows):
        return
    keep = {id(row) for row in kept}
    text = [lines[0]] + [line for line, row in zip(lines[1:], rows, strict=True) if id(row) in keep]
    write_text(path, "".join(line + "\n" for line in text))


def drop_orphan_curves(path: Path, finished: set[tuple[str, str, int, int, int]]) -> None:
    """Keep in the curve log only one line per episode that has its row (``finished``): a run killed
    between the curve and the row of an episode left a curve that the re-run writes again. The file
    is rewritten atomically, and only when something is dropped."""
    lines, _ = _complete_lines(path)
    kept: list[str] = []
    seen: set[tuple[str, str, int, int, int]] = set()
    for line in lines:
        key = _key(json.loads(line))
        if key in finished and key not in seen:
            seen.add(key)
            kept.append(line)
    if len(kept) != len(lines):
        write_text(path, "".join(line + "\n" for line in kept))


def _results(
    todo: Sequence[Episode], workers: int, backend: str = "local", address: str | None = None
) -> Generator[tuple[dict[str, Any], dict[str, Any]], None, None]:
    """Results of ``todo`` in its order, played here (one worker), by a process pool, or as Ray tasks."""
    if backend == "ray" and todo:
        yield from _ray_results(todo, workers, address)
        return
    if workers == 1 or len(todo) <= 1:
        for ep in todo:
            yield run_episode(ep)
        return
    pool = worker_pool(min(workers, len(todo)))
    futures: list[Future[tuple[dict[str, Any], dict[str, Any]]]] = []
    try:
        futures = [pool.submit(run_episode, ep) for ep in todo]
        for future in futures:
            yield future.result()
    finally:
        for future in futures:
            future.cancel()
        pool.shutdown(wait=True, cancel_futures=True)


def check_ray_address(address: str, timeout_s: float = 5.0) -> None:
    """AreaSearchError unless a TCP connection to the ``host:port`` of a Ray address (``host:port`` or
    ``ray://host:port``; ``auto`` is left to Ray) opens within ``timeout_s``: Ray itself keeps retrying
    an unreachable address for minutes."""
    if address == "auto":
        return
    host, sep, port = address.removeprefix("ray://").rpartition(":")
    if not sep or not host or not port.isdigit():
        raise ConfigError(f"--address must be host:port or ray://host:port (or auto), got {address!r}")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s).close()
    except OSError as exc:
        raise AreaSearchError(f"--address {address}: no Ray cluster reachable there ({exc})") from None


def _ray_results(
    todo: Sequence[Episode], workers: int, address: str | None
) -> Generator[tuple[dict[str, Any], dict[str, Any]], None, None]:
    """Results of ``todo`` in its order, each episode a Ray task (one CPU) on a local Ray instance of
    ``workers`` CPUs, or on the cluster at ``address``; a Ray instance already running in this
    process is used as it is. A Ray started here is shut down at the end."""
    import ray

    started = not ray.is_initialized()
    if started:
        try:
            if address is not None:
                ray.init(address=address, log_to_driver=False, logging_level=logging.ERROR)
            else:
                ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR)
        except (ConnectionError, RuntimeError, ValueError, TimeoutError) as exc:
            where = f"the Ray cluster at {address}" if address else "a local Ray instance"
            raise AreaSearchError(f"cannot start or reach {where}: {' '.join(str(exc).split())}") from None
    remote = ray.remote(num_cpus=1)(run_episode)
    refs: list[Any] = []
    fetched = 0
    try:
        refs = [remote.remote(ep) for ep in todo]
        for ref in refs:
            yield ray.get(ref)
            fetched += 1
    finally:
        for ref in refs[fetched:]:
            ray.cancel(ref)
        if started:
            ray.shutdown()


SUMMARY_DECIMALS = DECIMALS + 2
"""Decimals of the numbers in ``summary.json``: two more than the tables print, so a table printed from
the JSON rounds as the summary's own tables do."""


def write_summary(run: RunPlan) -> Summary:
    """summary.md / .json / .tex and curves.png over the planned episodes found in the run folder."""
    planned = {ep.key for ep in run.plan}
    rows = unique_rows([row for row in read_episodes(run.out / EPISODES_FILE) if _key(row) in planned])
    curves = [c for key, c in read_curves(run.out / CURVES_FILE).items() if key in planned]
    settings: dict[str, Any] = {
        "seed": run.seed,
        "max_steps": run.max_steps,
        "episodes_per_map_and_team": run.episodes,
        "maps": len(run.maps),
        "episodes": len(rows),
    }
    if run.settings:
        settings["settings"] = " ".join(f"{k}={json.dumps(v)}" for k, v in run.settings)
    summary = summarize(rows, run.methods, settings)
    reference = PAIRED_REFERENCE if PAIRED_REFERENCE in run.methods and len(run.methods) > 1 else None
    paired = paired_differences(rows, reference, run.methods) if reference else ()
    markdown = to_markdown(summary) + ("\n" + paired_markdown(paired) if paired else "")
    doc = summary.to_dict() | ({"paired": [row.to_dict() for row in paired]} if paired else {})
    write_text(run.out / "summary.md", markdown)
    write_text(run.out / "summary.json", json.dumps(json_ready(doc, SUMMARY_DECIMALS), indent=2) + "\n")
    write_text(run.out / "summary.tex", to_latex(summary))
    if curves:
        maps = f"{len(run.maps)} map{'s' if len(run.maps) != 1 else ''}"
        title = f"{len(curves)} episodes, {maps}, robots {' '.join(map(str, run.robots))}"
        draw_curves(curves, run.methods, run.max_steps, run.out / "curves.png", title=title)
    return summary


def evaluate(
    methods: Sequence[str],
    robots: Sequence[int],
    maps: Sequence[str],
    episodes: int,
    seed: int,
    max_steps: int,
    out: str | Path,
    *,
    workers: int = 1,
    sizes: Sequence[str] | None = None,
    maps_per_size: int | None = None,
    progress: TextIO | None = sys.stderr,
    backend: str = "local",
    address: str | None = None,
    settings: Mapping[str, Any] | None = None,
    policies: Mapping[str, str] | None = None,
) -> Summary:
    """Run (or resume) an evaluation; see the module docstring. Validates everything before writing.
    ``progress`` takes the progress report (:class:`areasearch.progress.Progress`: a bar on a terminal,
    plain lines otherwise); ``settings`` are world settings of every episode (``--set``). The output
    folder is held by this process from the first look at it to the last file written
    (:func:`areasearch.folderlock.hold_folder`): a second process is refused, naming this one's pid."""
    with hold_folder(out, "output path"):
        return _evaluate(
            methods,
            robots,
            maps,
            episodes,
            seed,
            max_steps,
            out,
            workers=workers,
            sizes=sizes,
            maps_per_size=maps_per_size,
            progress=progress,
            backend=backend,
            address=address,
            settings=settings,
            policies=policies,
        )


def _evaluate(
    methods: Sequence[str],
    robots: Sequence[int],
    maps: Sequence[str],
    episodes: int,
    seed: int,
    max_steps: int,
    out: str | Path,
    *,
    workers: int,
    sizes: Sequence[str] | None,
    maps_per_size: int | None,
    progress: TextIO | None,
    backend: str,
    address: str | None,
    settings: Mapping[str, Any] | None,
    policies: Mapping[str, str] | None = None,
) -> Summary:
    run = prepare(
        methods,
        robots,
        maps,
        episodes,
        seed,
        max_steps,
        out,
        workers=workers,
        sizes=sizes,
        maps_per_size=maps_per_size,
        backend=backend,
        address=address,
        settings=settings,
        policies=policies,
    )
    return execute(run, progress)
