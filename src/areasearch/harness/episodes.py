"""The episodes of an evaluation: their seeds, maps and plan, and how one is played.

Seeds are **paired**: the episode seed comes from (run seed, map id, team size, episode index) only
(:func:`episode_seed`), never from the method, so every method meets the same start poses and
targets; the planner's generator is derived from the same seed (:func:`planner_rng`). An episode's
numbers depend on its :class:`Episode` alone, so it plays the same here, in a worker process or as a
Ray task (:func:`run_episode`).
"""

from __future__ import annotations

import hashlib
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from ..config import SearchConfig
from ..envs.goal import AreaSearchEnv, decide
from ..errors import MapError
from ..planners import GoalPlanner, make_planner
from ..progress import Progress
from ..sim.mapquality import MapQuality, map_quality
from ..sim.placement import draw_targets, sample_start_poses
from ..sim.scene import SIZE_CLASSES, bundled_index, load_scene, scene_source
from .mcap import recording
from .plan import EvalPlan
from .report import size_rank

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
    return sorted(chosen, key=lambda e: (size_rank(e.size_class), e.id))


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
    config: SearchConfig = field(default_factory=SearchConfig)
    """The world of the run (:attr:`areasearch.harness.plan.EvalPlan.config`); team size and horizon
    are this episode's."""
    weights: str | None = None
    """A learned method given by ``--policy NAME=PREFIX``: its weights' path prefix."""
    record: str | None = None
    """An MCAP file to record the episode to (``eval --record-mcap``, :mod:`.mcap`); it changes no number."""

    @property
    def key(self) -> tuple[str, str, int, int, int]:
        return (self.method, self.map.id, self.robots, self.index, self.seed)


def plan_episodes(plan: EvalPlan, maps: Sequence[MapEntry]) -> list[Episode]:
    """Every (map, team size, episode index) x method of ``plan`` on ``maps``, methods innermost so
    that paired episodes finish together."""
    policies = plan.policies
    episodes = []
    for entry in maps:
        for r in plan.robots:
            for k in range(plan.episodes):
                s = episode_seed(plan.seed, entry.id, r, k)
                episodes += [
                    Episode(m, entry, r, k, s, plan.max_steps, plan.config, policies.get(m)) for m in plan.methods
                ]
    return episodes


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
    """What :func:`play_episode` saw: explored / covered after each decision, the last info; on an
    imperfect world, the team map's error (:mod:`areasearch.sim.mapquality`) at a few steps and at the end."""

    steps: list[int]
    explored_pct: list[float]
    covered_pct: list[float]
    info: dict[str, Any]
    map_steps: list[int] = field(default_factory=list)
    """Steps at which the map error was taken (imperfect worlds only; the last is the episode's end)."""
    map_error_pct: list[float] = field(default_factory=list)
    """The map's :attr:`~areasearch.sim.mapquality.MapQuality.error_pct` at each of :attr:`map_steps`."""
    map_quality: MapQuality | None = None
    """The map's quality at the end (None on a perfect world)."""

    @property
    def decisions(self) -> int:
        return len(self.steps) - 1


MAP_ERROR_POINTS = 10
"""On an imperfect world the map error is taken at the first decision after each tenth of the horizon
(and at the start and the end): a few points of its growth, at a cost of a few array passes each."""


def _track_map(env: AreaSearchEnv, trace: EpisodeTrace, end: bool = False) -> None:
    """Append the team map's error to ``trace`` when the episode crossed a checkpoint (or at its ``end``)."""
    step = int(env.world.metrics.steps)
    every = max(1, env.config.world.max_steps // MAP_ERROR_POINTS)
    last = trace.map_steps[-1] if trace.map_steps else -1
    if step == last or (not end and last >= 0 and step // every == last // every):
        return
    trace.map_quality = map_quality(env.world)
    trace.map_steps.append(step)
    trace.map_error_pct.append(trace.map_quality.error_pct)


def play_episode(
    env: AreaSearchEnv, planner: GoalPlanner, seed: int, progress: TextIO | None = None, label: str = "episode"
) -> EpisodeTrace:
    """Reset ``env`` and ``planner`` from ``seed`` and step ``planner.assign(obs)`` (once per group of robots
    that can talk, :func:`~areasearch.envs.goal.decide`) until terminated or truncated. ``progress``: a
    stream for the steps played so far (:class:`areasearch.progress.Progress`, headed ``label``: a bar on a
    terminal, a plain line every 10 s otherwise), None for silence."""
    _, info = env.reset(seed=seed)
    planner.reset(planner_rng(seed))
    trace = EpisodeTrace([int(info["steps"])], [float(info["explored_pct"])], [float(info["covered_pct"])], info)
    imperfect = env.config.world.imperfect
    if imperfect:
        _track_map(env, trace)
    bar = Progress(label, env.config.world.max_steps, "steps", progress, rate_unit="steps/s")
    done = False
    try:
        while not done:
            _, _, terminated, truncated, info = env.step(decide(env, planner.assign))
            trace.steps.append(int(info["steps"]))
            trace.explored_pct.append(float(info["explored_pct"]))
            trace.covered_pct.append(float(info["covered_pct"]))
            bar.update(int(info["steps"]))
            done = terminated or truncated
            if imperfect:
                _track_map(env, trace, end=done)
    except BaseException:
        bar.clear()  # the error's own line follows alone
        raise
    bar.close()
    trace.info = info
    return trace


def make_env(
    map_spec: str, robots: int, seed: int, max_steps: int, config: SearchConfig | None = None
) -> AreaSearchEnv:
    """The environment of one episode: one map, one team size, the harness's horizon, and the world
    ``config`` (default: :class:`~areasearch.config.SearchConfig`) for everything else."""
    return AreaSearchEnv(map=map_spec, num_robots=robots, seed=seed, config=config, max_steps=max_steps)


def run_episode(ep: Episode) -> tuple[dict[str, Any], dict[str, Any]]:
    """Play one episode (in a worker process or here): its CSV row and its curve record; with
    :attr:`Episode.record`, recorded to that MCAP file as it is played (the same numbers; ``wall_s`` leaves
    out the time spent recording)."""
    t0 = time.perf_counter()
    env = make_env(ep.map.spec, ep.robots, ep.seed, ep.max_steps, ep.config)
    if ep.weights is not None:
        from ..planners.learned import LearnedPlanner

        planner: GoalPlanner = LearnedPlanner(weights=ep.weights, name=ep.method)
    else:
        planner = make_planner(ep.method)
    if ep.record is None:
        trace = play_episode(env, planner, ep.seed)
        recording_s = 0.0
    else:
        metadata = {"method": ep.method, "map": ep.map.id, "robots": ep.robots, "episode": ep.index, "seed": ep.seed}
        with recording(env, ep.record, metadata={**metadata, "max_steps": ep.max_steps}) as recorder:
            trace = play_episode(env, planner, ep.seed)
        recording_s = recorder.seconds
    ident = {"method": ep.method, "map": ep.map.id}
    row = {
        **ident,
        "size_class": ep.map.size_class,
        "robots": ep.robots,
        "episode": ep.index,
        "seed": ep.seed,
        **episode_metrics(trace.info),
        "decisions": trace.decisions,
        "wall_s": round(time.perf_counter() - t0 - recording_s, 3),  # the time spent recording left out
    }
    curve = {
        **ident,
        "robots": ep.robots,
        "episode": ep.index,
        "seed": ep.seed,
        "steps": trace.steps,
        "explored_pct": [round(v, 4) for v in trace.explored_pct],
        "covered_pct": [round(v, 4) for v in trace.covered_pct],
        **map_error_record(trace),
    }
    return row, curve


def map_error_record(trace: EpisodeTrace) -> dict[str, Any]:
    """The curve record's map-error keys of an imperfect world's episode (none on a perfect world):
    ``map_error_pct`` at the end, its parts (``map_error_parts_pct``: phantom, missed, misplaced,
    unmapped, adding up to it) and its course (``map_error_steps``, ``map_error_curve_pct``)."""
    q = trace.map_quality
    if q is None:
        return {}
    return {
        "map_error_pct": round(q.error_pct, 4),
        "map_error_parts_pct": {name: round(v, 4) for name, v in q.parts_pct().items()},
        "map_error_steps": trace.map_steps,
        "map_error_curve_pct": [round(v, 4) for v in trace.map_error_pct],
    }
