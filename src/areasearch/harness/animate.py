"""Episode animation: a top-down movie of one search episode (DA-HGNN "Visualization Analysis").

:func:`render_episode` plays one episode of :class:`~areasearch.envs.goal.AreaSearchEnv` with a goal
planner, seeded exactly as :mod:`areasearch.harness.evaluate` seeds it (so ``seed`` from a row of
``episodes.csv`` replays that episode), and records a frame every ``every`` primitive steps (default
40, one per decision) plus the first and the last state. Frames come from
:func:`areasearch.sim.render.draw_world`: robots as triangles with their trajectories, long-term goals as
squares, frontier nodes as blue diamonds, discovered targets red, covered targets green, explored
floor white; a caption gives the method, step, explored % and covered %.

With ``belief`` (``areasearch render --belief team`` or ``--belief N``) each frame has two panels: on
the left the truth (the map a perfect mapper at the true poses would have made, the robots where they
are: ``draw_world(truth=True)``), on the right what the team, or robot N (its own map under limited
communication), believes (:func:`areasearch.sim.render.draw_belief`); the caption adds that map's error
against the truth (:mod:`areasearch.sim.mapquality`).

Output: an animated GIF (Pillow) or, when ``ffmpeg`` is on PATH, an MP4; plus the last frame as a
PNG beside it (same stem). Both are written atomically (temporary file, then ``os.replace``).
:func:`record_episode` writes the episode as an MCAP file for Foxglove instead (:mod:`.mcap`).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from collections.abc import Mapping
from pathlib import Path
from typing import Any, TextIO

import numpy as np
from PIL import Image, ImageDraw

from ..config import search_config, search_settings
from ..errors import AreaSearchError, ConfigError
from ..folderlock import atomic_path, check_file_path
from ..planners import LEARNED, PLANNERS, Choice, GoalPlanner, choose_planner, make_planner, takes_weights
from ..sim.mapquality import map_quality
from ..sim.render import draw_belief, draw_world, save_png
from ..sim.scene import Scene
from .evaluate import EpisodeTrace, episode_metrics, make_env, play_episode
from .mcap import LAYOUT, check_mcap_path, recording
from .report import write_text

FORMATS = (".gif", ".mp4")
CAPTION_PX = 18
"""Height of the caption band above each frame, pixels."""


def check_output(out: Path) -> None:
    """AreaSearchError unless ``out`` can take an animation: .gif, or .mp4 with ffmpeg on PATH."""
    if out.suffix.lower() not in FORMATS:
        raise AreaSearchError(f"{out}: animation must be a .gif or .mp4 file")
    if out.suffix.lower() == ".mp4" and shutil.which("ffmpeg") is None:
        raise AreaSearchError(f"{out}: writing .mp4 needs ffmpeg on PATH; install ffmpeg or write a .gif")
    check_file_path(out, "animation")
    if out.with_suffix(".png").is_dir():
        raise AreaSearchError(f"{out}: animation path is a folder; give a file name")
    check_file_path(out.with_suffix(".png"), "last frame")


BELIEF_TEAM = "team"
"""``belief`` naming the team map (any other value names a robot, 0 to R - 1)."""


def check_belief(belief: str | None, robots: int) -> int | None:
    """The robot whose belief a second panel shows (None: the team's) for ``belief`` ('team' or a robot
    index 0 to ``robots`` - 1); ConfigError naming the option for anything else. Call only with a belief."""
    if belief == BELIEF_TEAM:
        return None
    text = str(belief).strip()
    if not text.isdigit() or not 0 <= int(text) < robots:
        raise ConfigError(f"--belief must be 'team' or a robot from 0 to {robots - 1}, got {str(belief)[:40]!r}")
    return int(text)


def belief_frame(world: Any, method: str, robot: int | None, goals: Any = None, candidates: Any = None) -> np.ndarray:
    """The truth (left) beside the belief of the team or of ``robot`` (right), captioned with the step,
    explored %, covered % and the believed map's error against the truth."""
    truth = draw_world(world, goals=goals, candidates=candidates, truth=True)
    belief = draw_belief(world, robot)
    mapper = world.mapper if robot is None else world.robot_maps[robot]
    m, error = world.metrics, map_quality(world, mapper).error_pct
    whose = "team" if robot is None else f"robot {robot}"
    text = (
        f"{method}  step {m.steps}  explored {100 * m.explored_fraction:.1f}%  covered "
        f"{100 * m.covered_fraction:.1f}%    left: truth    right: belief of {whose}, map error {error:.1f}%"
    )
    return caption(side_by_side([truth, belief]), text)


def caption(frame: np.ndarray, text: str) -> np.ndarray:
    """``frame`` (H, W, 3) with a white band of text on top: (H + CAPTION_PX, W, 3) uint8."""
    band = Image.new("RGB", (frame.shape[1], CAPTION_PX), (255, 255, 255))
    ImageDraw.Draw(band).text((4, 3), text, fill=(0, 0, 0))
    return np.vstack([np.asarray(band), frame])


class GifWriter:
    """Collects frames as palette images (one byte per pixel) and writes an animated GIF."""

    def __init__(self, path: Path, fps: float) -> None:
        self.path, self.fps = path, fps
        self.frames: list[Image.Image] = []

    def add(self, frame: np.ndarray) -> None:
        rgb = Image.fromarray(frame)
        self.frames.append(rgb.quantize(colors=128, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE))

    def close(self) -> None:
        first, *rest = self.frames
        with atomic_path(self.path, "animation") as tmp:  # a failed write: one error, the old file kept
            first.save(tmp, "GIF", save_all=True, append_images=rest, duration=int(round(1000 / self.fps)), loop=0)


class Mp4Writer:
    """Streams RGB frames into ``ffmpeg`` (H.264 when available, yuv420p, even dimensions)."""

    def __init__(self, path: Path, fps: float) -> None:
        self.path, self.fps = path, fps
        self.tmp = path.with_name(f".{path.name}.tmp")
        self.proc: subprocess.Popen[bytes] | None = None
        self.frames = 0

    def add(self, frame: np.ndarray) -> None:
        if self.proc is None:
            h, w = frame.shape[:2]
            command = [
                "ffmpeg", "-hide_banner", "-loglevel", "error", "-y",
                "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{w}x{h}", "-r", f"{self.fps}", "-i", "-",
                "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-pix_fmt", "yuv420p", "-f", "mp4", str(self.tmp),
            ]  # fmt: skip
            self.proc = subprocess.Popen(command, stdin=subprocess.PIPE, stderr=subprocess.PIPE)
        assert self.proc.stdin is not None
        self.proc.stdin.write(np.ascontiguousarray(frame, dtype=np.uint8).tobytes())
        self.frames += 1

    def close(self) -> None:
        assert self.proc is not None
        _, err = self.proc.communicate()
        if self.proc.returncode != 0:
            self.tmp.unlink(missing_ok=True)
            tail = " ".join(err.decode(errors="replace").split())[-300:]
            raise AreaSearchError(f"{self.path}: ffmpeg failed (exit {self.proc.returncode}): {tail}")
        os.replace(self.tmp, self.path)


def _record(
    method: str,
    map: str,
    robots: int,
    seed: int,
    max_steps: int,
    every: int,
    add: Any,
    settings: Mapping[str, Any],
    planner: GoalPlanner,
    progress: TextIO | None = None,
    belief: str | None = None,
) -> tuple[Any, Any, np.ndarray]:
    """Play one episode of ``planner`` (named ``method`` in the captions), passing each captioned
    frame to ``add``, its progress to ``progress`` (headed ``render METHOD``); ``belief``: a second
    panel (:func:`belief_frame`) of the team's belief ('team') or a robot's (its index); returns (trace,
    scene, last frame)."""
    env = make_env(map, robots, seed, max_steps, search_config(settings) if settings else None)
    world = env.world
    final = np.zeros((0, 0, 3), np.uint8)
    final_step = -1

    def capture() -> None:
        nonlocal final, final_step
        m = world.metrics
        final_step = m.steps
        if belief is not None:
            frame = belief_frame(world, method, check_belief(belief, robots), env.goals, env.candidates)
            final = frame[CAPTION_PX:]
            add(frame)
            return
        final = draw_world(world, goals=env.goals, candidates=env.candidates)
        explored, covered = 100 * m.explored_fraction, 100 * m.covered_fraction
        add(caption(final, f"{method}  step {m.steps}  explored {explored:.1f}%  covered {covered:.1f}%"))

    world_step = world.step

    def step_and_record(actions: np.ndarray) -> Any:
        if final_step < 0:
            capture()  # the start, with the first goals
        result = world_step(actions)
        if world.metrics.steps % every == 0:
            capture()
        return result

    # Frames between decisions need the world's own steps: record around each one.
    world.step = step_and_record  # type: ignore[method-assign]
    trace = play_episode(env, planner, seed, progress, f"render {method}")
    if final_step != world.metrics.steps:
        capture()
    return trace, world.scene, final


def _check_settings(
    every: object, fps: float, settings: Mapping[str, Any] | None, belief: str | None = None, robots: int = 1
) -> dict[str, Any]:
    """Check the frame settings, the ``belief`` asked for (:func:`check_belief`) and the world ``settings``;
    return the latter by their full keys."""
    if belief is not None:
        check_belief(belief, robots)
    if isinstance(every, bool) or not isinstance(every, int) or every < 1:
        raise ConfigError(f"every must be an integer >= 1, got {every!r}")
    if not fps > 0:
        raise ConfigError(f"fps must be positive, got {fps!r}")
    given = search_settings(settings or {})
    search_config(given)  # a bad setting fails before anything is played
    return given


def render_episode(
    method: str | None,
    map: str,
    robots: int,
    seed: int,
    out: str | Path,
    *,
    max_steps: int = 3600,
    every: int = 40,
    fps: float = 8.0,
    settings: Mapping[str, Any] | None = None,
    weights: str | None = None,
    progress: TextIO | None = None,
    belief: str | None = None,
) -> dict[str, Any]:
    """Play one episode with planner ``method`` and write its animation to ``out`` (.gif / .mp4) and
    its last frame to ``out`` with suffix .png. ``settings``: world settings (``--set``, keys as
    :func:`areasearch.config.search_settings` takes them); ``weights``: a policy of your own for the
    learned ``method`` (or, with ``method`` None, the network it describes:
    :func:`areasearch.planners.choose_planner`); ``progress``: a stream for the steps played
    (:class:`areasearch.progress.Progress`), None for silence; ``belief``: 'team' or a robot's index, a
    second panel of that belief beside the truth in every frame (:func:`belief_frame`). Returns the
    episode's metrics (and, on an imperfect world, the team map's error at the end) and the paths."""
    out = Path(out).expanduser()
    check_output(out)
    given = _check_settings(every, fps, settings, belief, robots)
    choice = choose_planner(method, weights)  # a bad method or weights fail before anything is played
    writer: GifWriter | Mp4Writer = Mp4Writer(out, fps) if out.suffix.lower() == ".mp4" else GifWriter(out, fps)
    trace, scene, final = _record(
        choice.method, map, robots, seed, max_steps, every, writer.add, given, choice.planner, progress, belief
    )
    writer.close()
    picture = save_png(final, out.with_suffix(".png"))
    assert scene is not None
    return {
        **_episode_summary(choice, scene, robots, seed, max_steps, given, trace),
        **({"belief": belief} if belief is not None else {}),
        "steps": int(trace.info["steps"]),
        "decisions": trace.decisions,
        "frames": len(writer.frames) if isinstance(writer, GifWriter) else writer.frames,
        "animation": str(out),
        "picture": str(picture),
    }


def _episode_summary(
    choice: Choice, scene: Scene, robots: int, seed: int, max_steps: int, given: Mapping[str, Any], trace: EpisodeTrace
) -> dict[str, Any]:
    """What :func:`render_episode` and :func:`record_episode` report first of an episode they played: the
    planner, the map, the team, the settings, the metrics and, on an imperfect world, the map error."""
    return {
        "method": choice.method,
        **choice.record(),
        "map": scene.name,
        "size_class": scene.size_class,
        "robots": robots,
        "seed": seed,
        "max_steps": max_steps,
        **({"settings": given} if given else {}),
        **episode_metrics(trace.info),
        **({"map_error_pct": round(trace.map_quality.error_pct, 4)} if trace.map_quality is not None else {}),
    }


def record_episode(
    method: str | None,
    map: str,
    robots: int,
    seed: int,
    out: str | Path,
    *,
    max_steps: int = 3600,
    every: int = 40,
    settings: Mapping[str, Any] | None = None,
    weights: str | None = None,
    progress: TextIO | None = None,
) -> dict[str, Any]:
    """Play one episode with planner ``method``, seeded as :func:`render_episode` seeds it, and write it to
    ``out`` (.mcap) for Foxglove (:mod:`.mcap`: a map frame every ``every`` steps); ``settings``,
    ``weights`` and ``progress`` as for :func:`render_episode`. AreaSearchError naming the extra when
    ``foxglove-sdk`` is missing, before anything is played. Returns the episode's metrics, the messages
    written per topic and the paths of the file and of the Foxglove layout (:data:`.mcap.LAYOUT`)."""
    out = Path(out).expanduser()
    check_mcap_path(out)
    given = _check_settings(every, 1.0, settings)
    choice = choose_planner(method, weights)  # a bad method or weights fail before anything is played
    env = make_env(map, robots, seed, max_steps, search_config(given) if given else None)
    metadata = {"method": choice.method, "map": map, "robots": robots, "seed": seed, "max_steps": max_steps}
    if given:
        metadata["settings"] = json.dumps(given, sort_keys=True)
    with recording(env, out, every=every, metadata=metadata) as recorder:
        trace = play_episode(env, choice.planner, seed, progress, f"render {choice.method}")
    scene = env.world.scene
    assert scene is not None
    return {
        **_episode_summary(choice, scene, robots, seed, max_steps, given, trace),
        "steps": int(trace.info["steps"]),
        "decisions": trace.decisions,
        "frames": len(recorder.frame_steps),
        "messages": dict(recorder.counts),
        "mcap": str(out),
        "bytes": out.stat().st_size,
        "layout": str(LAYOUT),
    }


def side_by_side(frames: list[np.ndarray], gap: int = 6) -> np.ndarray:
    """Frames (H_i, W_i, 3) next to each other on white, top-aligned, ``gap`` pixels apart."""
    h = max(f.shape[0] for f in frames)
    w = sum(f.shape[1] for f in frames) + gap * (len(frames) - 1)
    canvas = np.full((h, w, 3), 255, np.uint8)
    x = 0
    for f in frames:
        canvas[: f.shape[0], x : x + f.shape[1]] = f
        x += f.shape[1] + gap
    return canvas


COMPARE_COLUMNS = ("explored_pct", "covered_pct", "time_e", "time_c", "collisions", "path_length_m")


CENSORED = {"time_e": "reached_e", "time_c": "reached_c"}
"""Time columns and the field saying whether the episode reached them: a time never reached is the
horizon, a lower bound, shown as ``> horizon``."""


def compare_table(rows: list[dict[str, Any]]) -> str:
    """A small Markdown table of the methods' metrics (Explo%, Cover%, Time_E, Time_C, ...); a time the
    episode never reached shows as ``> horizon``."""
    head = "| method | Explo(%) | Cover(%) | Time_E (step) | Time_C (step) | collisions | path (m) |"
    lines = [head, "|---|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        cells = [f"{r[c]:.2f}" if isinstance(r[c], float) else str(r[c]) for c in COMPARE_COLUMNS]
        cells = [
            f"> {cell}" if c in CENSORED and r.get(CENSORED[c], True) is False else cell
            for c, cell in zip(COMPARE_COLUMNS, cells, strict=True)
        ]
        lines.append(f"| {r['method']} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def compare_episodes(
    methods: list[str],
    map: str,
    robots: int,
    seed: int,
    out: str | Path,
    *,
    max_steps: int = 3600,
    every: int = 40,
    fps: float = 8.0,
    settings: Mapping[str, Any] | None = None,
    weights: str | None = None,
    progress: TextIO | None = None,
    belief: str | None = None,
) -> dict[str, Any]:
    """The same episode (map, team, seed: same start poses and targets) played by each of
    ``methods``, animated side by side in ``out`` (.gif / .mp4), the last frames side by side in
    ``out`` with suffix .png and a comparison table in ``out`` with suffix .md. ``settings``: world
    settings, as for :func:`render_episode`; ``weights``: a policy of your own, played by the one
    learned method among ``methods`` (ConfigError when there is none or more than one); ``progress``:
    as for :func:`render_episode`, one report per method; ``belief``: as for :func:`render_episode` (each
    method's frames then two panels). Returns the metrics per method, the table and the paths."""
    out = Path(out).expanduser()
    check_output(out)
    given = _check_settings(every, fps, settings, belief, robots)
    if not methods:
        raise ConfigError("name at least one method")
    if len(set(methods)) != len(methods):
        raise ConfigError(f"methods repeat: {' '.join(methods)}")
    mine = None
    if weights is not None:
        for method in methods:
            if method not in PLANNERS and method not in LEARNED:
                make_planner(method)  # an unknown name: its own message first
        learned = [m for m in methods if takes_weights(m)]
        if len(learned) != 1:
            which = f"{len(learned)} are ({', '.join(learned)})" if learned else "none is"
            raise ConfigError(
                f"--weights with --methods is played by the one learned method among them, and {which}; "
                "list exactly one learned method (e.g. --methods greedy dahgnn --weights PREFIX)"
            )
        mine = learned[0]
    # every planner built (unknown methods and bad weights fail) before anything is played
    choices = [choose_planner(m, weights if m == mine else None) for m in methods]
    movies: list[list[np.ndarray]] = []
    rows: list[dict[str, Any]] = []
    scene = None
    for choice in choices:
        frames: list[np.ndarray] = []
        trace, scene, _ = _record(
            choice.method, map, robots, seed, max_steps, every, frames.append, given, choice.planner, progress, belief
        )
        movies.append(frames)
        rows.append(
            {"method": choice.method, **choice.record(), **episode_metrics(trace.info), "decisions": trace.decisions}
        )
    writer: GifWriter | Mp4Writer = Mp4Writer(out, fps) if out.suffix.lower() == ".mp4" else GifWriter(out, fps)
    length = max(len(m) for m in movies)
    for i in range(length):
        writer.add(side_by_side([m[min(i, len(m) - 1)] for m in movies]))
    writer.close()
    picture = save_png(side_by_side([m[-1] for m in movies]), out.with_suffix(".png"))
    assert scene is not None
    table = compare_table(rows)
    extra = "".join(f", {k.removeprefix('world.')}={json.dumps(v)}" for k, v in given.items())
    header = f"{scene.name} ({scene.size_class}), {robots} robots, seed {seed}, {max_steps} steps{extra}\n\n"
    table_path = write_text(out.with_suffix(".md"), header + table)
    return {
        "map": scene.name,
        "size_class": scene.size_class,
        "robots": robots,
        "seed": seed,
        "max_steps": max_steps,
        **({"settings": given} if given else {}),
        "methods": rows,
        "table": table,
        "animation": str(out),
        "picture": str(picture),
        "table_file": str(table_path),
    }
