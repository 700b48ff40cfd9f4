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
  per episode; on an imperfect world (noise, uncertain detection or limited communication) also the team
  map's error against the truth (:mod:`areasearch.sim.mapquality`; :func:`.episodes.map_error_record`),
  which the summaries then show as a "Map err. (%)" column.
* ``config.json``: the run seed, the ``--set`` settings (``settings``, when there are any), the
  resolved environment configuration and the SHA-256 of each map's content (``maps``, by map id:
  :attr:`areasearch.sim.scene.Scene.content_sha256`); resuming into a folder made with other settings, or
  on a map whose content has changed since its episodes were played, is refused. A folder whose
  ``config.json`` has no ``maps`` (written before maps were pinned) is resumed, and the hashes are
  added when the run next writes episodes there.
* ``policies.json``: the weights (path and SHA-256) of every method that has them, a ``--policy`` name
  or a shipped policy; a resume with other weights under a name, or with episodes of a method whose
  weights were not recorded, is refused, unless the plan's ``replace`` names that method: its old
  episodes then move to ``replaced/N/`` (:func:`.records.set_aside`) and it plays them again.
* ``summary.md``, ``summary.json``, ``summary.tex``, ``curves.png``: :mod:`areasearch.harness.report` over the
  episodes of this command; when ``greedy`` is among several methods, ``summary.md`` and
  ``summary.json`` also hold every other method's paired differences against it (same episodes).
* ``episodes/METHOD/MAP-rR-eK.mcap`` (``--record-mcap``, ``record``): the episodes asked for as MCAP
  files for Foxglove (:mod:`.mcap`), recorded as they are played; recording changes no number
  (``wall_s`` leaves out its time). An episode already played whose file is missing is played again
  to record it; an existing file is left as it is.

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

Backends (:func:`areasearch.runners.make_runner`): ``local`` plays the episodes in this process
(``workers=1``) or in a pool of ``workers`` processes; ``ray`` plays each episode as a Ray task, on a
local Ray instance of ``workers`` CPUs or on an existing cluster (``address``, whose nodes have
areasearch installed). Results come back in plan order either way, so every backend writes the same
files.

The parts: :mod:`.plan` (:class:`EvalPlan`, what is asked, and its checks), :mod:`.episodes` (seeds,
maps, playing one episode), :mod:`.records` (the folder's files), :mod:`.resume` (:func:`prepare`: a
checked plan against what the folder holds); this module plays and writes. Their public names are
imported from here too.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import sys
from collections.abc import Generator, Mapping, Sequence
from pathlib import Path
from typing import Any, TextIO, cast

from ..errors import ConfigError
from ..folderlock import hold_folder
from ..progress import Progress
from ..runners import make_runner
from .episodes import (
    Episode,
    EpisodeTrace,
    MapEntry,
    check_teams,
    episode_metrics,
    episode_seed,
    make_env,
    make_planner,
    pick_evenly,
    plan_episodes,
    planner_rng,
    play_episode,
    resolve_maps,
    run_episode,
    stable_hash,
)
from .mcap import EpisodeSelector, method_records, record_path, require_foxglove
from .plan import BACKENDS, RESERVED_SETTINGS, RUN_FORMAT, EvalPlan, check_plan, check_ray_address, run_config
from .records import (
    CONFIG_FILE,
    CSV_FIELDS,
    CURVES_FILE,
    EPISODES_FILE,
    LOG_NAMES,
    MAX_EPISODE_SEED,
    MAX_RECORD_BYTES,
    POLICIES_FILE,
    AppendLog,
    EpisodeKey,
    csv_line,
    drop_duplicate_rows,
    drop_orphan_curves,
    episode_id,
    episode_key,
    read_curves,
    read_episodes,
    read_record,
    set_aside,
    unique_rows,
)
from .report import (
    DECIMALS,
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
from .resume import RunPlan, check_policies, prepare

__all__ = [
    "BACKENDS",
    "CONFIG_FILE",
    "CSV_FIELDS",
    "CURVES_FILE",
    "EPISODES_FILE",
    "LOG_NAMES",
    "MAX_EPISODE_SEED",
    "MAX_RECORD_BYTES",
    "PAIRED_REFERENCE",
    "POLICIES_FILE",
    "RESERVED_SETTINGS",
    "RUN_FORMAT",
    "SUMMARY_DECIMALS",
    "AppendLog",
    "Episode",
    "EpisodeTrace",
    "EvalPlan",
    "MapEntry",
    "RunPlan",
    "check_plan",
    "check_policies",
    "check_ray_address",
    "check_teams",
    "csv_line",
    "drop_duplicate_rows",
    "drop_orphan_curves",
    "episode_id",
    "episode_key",
    "episode_metrics",
    "episode_seed",
    "evaluate",
    "execute",
    "make_env",
    "make_planner",
    "pick_evenly",
    "plan_episodes",
    "planner_rng",
    "play_episode",
    "prepare",
    "read_curves",
    "read_episodes",
    "read_record",
    "resolve_maps",
    "run_config",
    "run_episode",
    "stable_hash",
    "unique_rows",
    "write_summary",
]

PAIRED_REFERENCE = "greedy"
"""The method every other one is compared with, episode by episode, in the summary (when present)."""


def evaluate(plan: EvalPlan, progress: TextIO | None = sys.stderr, record: Sequence[EpisodeSelector] = ()) -> Summary:
    """Run (or resume) the evaluation ``plan``; see the module docstring. Validates everything before
    writing. ``progress`` takes the progress report (:class:`areasearch.progress.Progress`: a bar on a
    terminal, plain lines otherwise); ``record``: the episodes to record as MCAP files too
    (:func:`recorded_episodes`). The output folder is held by this process from the first look at
    it to the last file written (:func:`areasearch.folderlock.hold_folder`): a second process is
    refused, naming this one's pid."""
    with hold_folder(plan.out, "output path"):
        return execute(prepare(plan), progress, record)


def execute(run: RunPlan, progress: TextIO | None = sys.stderr, record: Sequence[EpisodeSelector] = ()) -> Summary:
    """Play the missing episodes of ``run`` (on the runner of its backend and workers), append their
    rows and curves, then write the summary tables and the curve figure over all planned episodes.
    The folder is held by this process meanwhile (:func:`areasearch.folderlock.hold_folder`); the
    episodes to play are those not in ``episodes.csv`` when it is taken (a row found twice there is
    dropped, :func:`drop_duplicate_rows`). The episodes ``record`` selects are recorded as they are
    played; those of them already played whose MCAP file is missing are played again to record them,
    their rows and curves not written again (:func:`recorded_episodes`)."""
    with hold_folder(run.out, "output path"):
        return _execute(run, progress, recorded_episodes(run, record))


def recorded_episodes(run: RunPlan, record: Sequence[EpisodeSelector]) -> dict[EpisodeKey, Path]:
    """The MCAP file (:func:`.mcap.record_path`) of each planned episode of ``run`` that a selector of
    ``record`` matches. ConfigError for a selector that matches no episode of the run; AreaSearchError
    when ``foxglove-sdk`` (the ``mcap`` extra) is missing. Nothing is written."""
    if not record:
        return {}
    require_foxglove()
    paths: dict[EpisodeKey, Path] = {}
    for selector in record:
        chosen = [ep for ep in run.plan if selector.matches(ep.method, ep.map.id, ep.robots, ep.index)]
        if not chosen:
            raise ConfigError(f"--record-mcap {selector.describe()} matches no episode of this evaluation")
        for ep in chosen:
            # absolute: a worker process or a Ray task may start elsewhere (on a cluster, the node that plays
            # an episode writes its file, at this path: a shared file system collects them)
            paths[ep.key] = record_path(run.out.absolute(), ep.method, ep.map.id, ep.robots, ep.index)
    return paths


def _execute(run: RunPlan, progress: TextIO | None, recordings: Mapping[EpisodeKey, Path]) -> Summary:
    run.out.mkdir(parents=True, exist_ok=True)
    config_path = run.out / CONFIG_FILE
    played = {episode_key(row) for row in read_episodes(run.out / EPISODES_FILE)}
    if not config_path.exists() or (not run.config_current and any(ep.key not in played for ep in run.plan)):
        record = {**run.run_config, "maps": dict(run.maps_record)}  # the maps' hashes join when episodes are played
        write_text(config_path, json.dumps(record, indent=2) + "\n")
    if run.replaced:  # their old episodes, curves and weights move to replaced/N/; the run plays them again
        _set_aside(run.out, run.replaced)
    if run.policies:
        path = run.out / POLICIES_FILE
        recorded = json.loads(path.read_text()) if path.exists() else {}
        # a name already recorded with the same weights keeps its entry (the path it was first given),
        # so re-running a command, from another folder or with another path to the file, rewrites nothing
        new = {name: entry for name, entry in run.policies if name not in recorded}
        if new or not path.exists():
            write_text(path, json.dumps({**recorded, **new}, indent=2, sort_keys=True) + "\n")
    drop_duplicate_rows(run.out / EPISODES_FILE)
    done = {episode_key(row) for row in read_episodes(run.out / EPISODES_FILE)}
    for file in set(recordings.values()):
        file.parent.mkdir(parents=True, exist_ok=True)
    todo = [_recorded(ep, recordings) for ep in run.plan if ep.key not in done]
    missing = {key for key, file in recordings.items() if key in done and not file.exists()}
    again = [_recorded(ep, recordings) for ep in run.plan if ep.key in missing]
    if todo:  # nothing to play: nothing is appended (a finished folder on read-only media is summarised)
        _play_and_append(run, todo, progress)
    if again:
        _record_again(run.request, again, progress)
    return write_summary(run)


def _set_aside(out: Path, methods: Sequence[str]) -> None:
    """Move the episodes of ``methods`` to ``out/replaced/N/`` (:func:`.records.set_aside`), their
    recorded episodes (MCAP files, :func:`.mcap.method_records`) with them."""
    aside = set_aside(out, methods)
    if aside is None:
        return
    for method in methods:
        recorded = method_records(out, method)
        if recorded.is_dir():
            target = aside / recorded.relative_to(out)
            target.parent.mkdir(parents=True, exist_ok=True)
            os.replace(recorded, target)


def _recorded(ep: Episode, recordings: Mapping[EpisodeKey, Path]) -> Episode:
    """``ep``, recorded to its MCAP file when it is among ``recordings``."""
    file = recordings.get(ep.key)
    return ep if file is None else dataclasses.replace(ep, record=str(file))


def _play_and_append(run: RunPlan, todo: Sequence[Episode], progress: TextIO | None) -> None:
    """Play ``todo``, appending each episode's row and curve (:func:`_play`), under a progress bar."""
    rows_log = AppendLog(run.out / EPISODES_FILE, header=",".join(CSV_FIELDS) + "\n")
    drop_orphan_curves(run.out / CURVES_FILE, {episode_key(row) for row in read_episodes(run.out / EPISODES_FILE)})
    curves_log = AppendLog(run.out / CURVES_FILE)
    bar = Progress(
        "eval", len(run.plan), "episodes", progress if todo else None, done=len(run.plan) - len(todo), rate_unit="ep/s"
    )
    try:
        _play(run.request, todo, rows_log, curves_log, bar)
    finally:
        bar.close()
        rows_log.close()
        curves_log.close()


def _record_again(request: EvalPlan, episodes: Sequence[Episode], progress: TextIO | None) -> None:
    """Play finished ``episodes`` again only to record them (the same seeds, so the same episodes); their
    rows and curves are already in the folder and are not written."""
    runner = make_runner(request.backend, min(request.workers, len(episodes)), request.address)
    bar = Progress("record", len(episodes), "episodes", progress, rate_unit="ep/s")
    try:
        results = cast(Generator[Any, None, None], runner.imap(run_episode, [(ep,) for ep in episodes]))
        with contextlib.closing(results):
            for _ in results:
                bar.advance()
    finally:
        bar.close()
        runner.close()


def _play(
    request: EvalPlan, todo: Sequence[Episode], rows_log: AppendLog, curves_log: AppendLog, bar: Progress
) -> None:
    """Play ``todo`` on the runner of ``request``'s backend (:func:`areasearch.runners.make_runner`, at
    most one worker per episode), appending each episode's curve, then its row, as its result comes
    back (in plan order): a run killed meanwhile keeps every episode finished before."""
    runner = make_runner(request.backend, min(request.workers, len(todo)), request.address)
    try:
        results = cast(Generator[Any, None, None], runner.imap(run_episode, [(ep,) for ep in todo]))
        with contextlib.closing(results):
            for row, curve in results:
                curves_log.append(json.dumps(curve, separators=(",", ":")) + "\n")
                rows_log.append(csv_line(row))
                bar.advance()
    finally:
        runner.close()


SUMMARY_DECIMALS = DECIMALS + 2
"""Decimals of the numbers in ``summary.json``: two more than the tables print, so a table printed from
the JSON rounds as the summary's own tables do."""


def write_summary(run: RunPlan) -> Summary:
    """summary.md / .json / .tex and curves.png over the planned episodes found in the run folder."""
    planned = {ep.key for ep in run.plan}
    rows = unique_rows([row for row in read_episodes(run.out / EPISODES_FILE) if episode_key(row) in planned])
    by_key = {key: c for key, c in read_curves(run.out / CURVES_FILE).items() if key in planned}
    curves = list(by_key.values())
    if rows and all("map_error_pct" in by_key.get(episode_key(row), {}) for row in rows):  # imperfect worlds
        rows = [{**row, "map_error_pct": by_key[episode_key(row)]["map_error_pct"]} for row in rows]
    settings: dict[str, Any] = {
        "seed": run.request.seed,
        "max_steps": run.request.max_steps,
        "episodes_per_map_and_team": run.request.episodes,
        "maps": len(run.maps),
        "episodes": len(rows),
    }
    if "realism" in run.run_config:
        settings["realism"] = run.run_config["realism"]
    if run.request.settings:
        settings["settings"] = " ".join(f"{k}={json.dumps(v)}" for k, v in run.request.settings)
    summary = summarize(rows, run.request.methods, settings)
    reference = PAIRED_REFERENCE if PAIRED_REFERENCE in run.request.methods and len(run.request.methods) > 1 else None
    paired = paired_differences(rows, reference, run.request.methods) if reference else ()
    markdown = to_markdown(summary) + ("\n" + paired_markdown(paired) if paired else "")
    doc = summary.to_dict() | ({"paired": [row.to_dict() for row in paired]} if paired else {})
    write_text(run.out / "summary.md", markdown)
    write_text(run.out / "summary.json", json.dumps(json_ready(doc, SUMMARY_DECIMALS), indent=2) + "\n")
    write_text(run.out / "summary.tex", to_latex(summary))
    if curves:
        maps = f"{len(run.maps)} map{'s' if len(run.maps) != 1 else ''}"
        title = f"{len(curves)} episodes, {maps}, robots {' '.join(map(str, run.request.robots))}"
        draw_curves(curves, run.request.methods, run.request.max_steps, run.out / "curves.png", title=title)
    return summary
