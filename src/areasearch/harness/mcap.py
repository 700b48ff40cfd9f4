"""Episodes as MCAP files for Foxglove: the team's map over time, the robots, their goals and paths, the
targets, the ground truth and the metrics (``areasearch render --out episode.mcap``, ``areasearch eval
--record-mcap``).

:func:`recording` hooks a :class:`Recorder` into an :class:`~areasearch.envs.goal.AreaSearchEnv`'s world
(around each :meth:`World.step <areasearch.sim.world.World.step>`, as the animations of
:mod:`.animate` do) while the caller plays the episode; it reads the world and never changes it, so a
recorded episode plays exactly as an unrecorded one. The file is written with ``foxglove-sdk`` (the
``mcap`` extra, ``pip install 'areasearch[mcap]'``, imported only when a file is written; without it,
one :class:`~areasearch.errors.AreaSearchError`), into a temporary file beside the output, renamed over
it when the episode is over (a failed episode leaves no file and an existing one as it was).

**Time**: the log time of a message is simulated time, step ``k`` at ``k * STEP_S`` seconds
(:data:`STEP_S`, 0.5 s: a forward step of 0.25 m at 0.5 m/s), from 0 (1970-01-01 in Foxglove's clock);
a message at step ``k`` shows the state after ``k`` primitive steps. Nothing depends on the wall clock:
the same episode gives the same file, byte for byte.

**Topics** (every pose in the frame ``map``, metres; grids in the scene's cells, 0.05 m on the bundled
maps, one uint8 field ``state`` per cell; Foxglove's own schemas, protobuf-encoded, JSON for the metrics):

* ``/ground_truth`` (``foxglove.Grid``): the scene, floor 0 and obstacle 2; once, at time 0.
* ``/map`` (``foxglove.Grid``): the team's map, what the team believes (:attr:`World.mapper
  <areasearch.sim.world.World.mapper>`, fused at the believed poses): free 0, unknown 1, occupied 2; at
  step 0, every ``every`` steps and at the last step (a *map frame*).
* ``/map/truth`` (``foxglove.Grid``, imperfect worlds only): the map a perfect mapper at the true poses
  would have made (:func:`~areasearch.sim.mapquality.true_map`); with each map frame.
* ``/map_error`` (JSON ``areasearch.MapError``, imperfect worlds only): the team map's error against that
  truth and its parts, % (:mod:`areasearch.sim.mapquality`); with each map frame.
* ``/robots`` (``foxglove.SceneUpdate``): each robot at its true pose (entity ``robot<i>``: an arrow along
  its heading over a disc of its footprint); every step.
* ``/robots/believed`` (``foxglove.SceneUpdate``, imperfect worlds only): the robots at their believed
  poses (``believed<i>``); every step.
* ``/trajectories`` (``foxglove.SceneUpdate``): each robot's true path so far (``trajectory<i>``, a line
  through the points where it moved); with each map frame.
* ``/goals`` (``foxglove.SceneUpdate``): each robot's long-term goal (``goal<i>``, a square; empty while
  it has none); at step 0 and whenever a goal changes, at the step from which it holds.
* ``/targets`` (``foxglove.SceneUpdate``): the targets where they truly are, entities ``hidden`` (not yet
  discovered), ``discovered`` (not covered) and ``covered``, on an imperfect world also ``marked``
  (where the map marks the discovered ones); at step 0 and whenever one is discovered or covered.
* ``/metrics`` (JSON ``areasearch.Metrics``, :data:`METRICS_FIELDS`): explored %, covered %, covered /
  discovered %, the discovered and covered targets, collisions and path length (team sums); every step.

Colours are those of the animations (:mod:`areasearch.sim.render`). MCAP metadata: ``areasearch.episode``
(what was played and how it was recorded) and ``areasearch.result`` (the world's metrics at the end).

The layout shipped beside this module, ``foxglove_layout.json`` (:data:`LAYOUT`; Foxglove: Layouts,
Import from file), shows the map, the robots, their paths, goals and the targets in a 3D panel seen from
above, explored % and covered % in a Plot panel and the map error in another.

:func:`parse_selector` reads ``eval --record-mcap`` selectors; :func:`record_path` names the file of an
evaluated episode.
"""

from __future__ import annotations

import contextlib
import json
import math
import re
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .._version import __version__
from ..errors import AreaSearchError, ConfigError
from ..folderlock import atomic_path, check_file_path
from ..sim.mapquality import map_quality, true_map
from ..sim.render import ROBOT_COLOURS, TARGET_COVERED, TARGET_FOUND

if TYPE_CHECKING:
    from foxglove.mcap import MCAPWriter
    from foxglove.messages import Color, Grid, Pose, SceneUpdate

    from ..envs.goal import AreaSearchEnv

SUFFIX = ".mcap"
STEP_S = 0.5
"""Simulated seconds per primitive step: the log time of step ``k`` is ``k * STEP_S`` (a forward step of
``robot.forward_m`` = 0.25 m at 0.5 m/s)."""
FRAME = "map"
"""The frame of every pose and grid: the scene's map frame (x east, y north, metres)."""
LAYOUT = Path(__file__).with_name("foxglove_layout.json")
"""The Foxglove layout shipped with the package (the topics above in a 3D panel and two Plot panels)."""
MISSING_EXTRA = "MCAP export needs the mcap extra: pip install 'areasearch[mcap]'"

FREE, UNKNOWN, OCCUPIED = 0, 1, 2
"""The values of a grid's ``state`` field (one uint8 per cell)."""

TOPICS = (
    "/ground_truth",
    "/map",
    "/map/truth",
    "/map_error",
    "/robots",
    "/robots/believed",
    "/trajectories",
    "/goals",
    "/targets",
    "/metrics",
)
"""Every topic a recording may hold (``/map/truth``, ``/map_error`` and ``/robots/believed`` on imperfect
worlds only)."""
IMPERFECT_ONLY = ("/map/truth", "/map_error", "/robots/believed")

METRICS_FIELDS = {
    "step": "integer",
    "explored_pct": "number",
    "covered_pct": "number",
    "covered_of_discovered_pct": "number",
    "discovered": "integer",
    "covered": "integer",
    "collisions": "integer",
    "path_length_m": "number",
}
"""The fields of a ``/metrics`` message and their JSON types."""
MAP_ERROR_FIELDS = {
    "step": "integer",
    "map_error_pct": "number",
    "phantom_pct": "number",
    "missed_pct": "number",
    "misplaced_pct": "number",
    "unmapped_pct": "number",
}
"""The fields of a ``/map_error`` message (:class:`~areasearch.sim.mapquality.MapQuality`)."""

HIDDEN_TARGET = (150, 150, 150)
ARROW_M = 0.45
"""Length of a robot's heading arrow, metres."""
GOAL_M = 0.3
"""Side of a goal's square, metres."""
TARGET_M = 0.16
"""Diameter of a target's sphere, metres."""
LINE_M = 0.04
"""Width of a trajectory line, metres."""


def require_foxglove() -> None:
    """AreaSearchError (:data:`MISSING_EXTRA`) unless ``foxglove-sdk`` can be imported."""
    try:
        import foxglove
        import foxglove.channels
        import foxglove.messages  # noqa: F401
    except ImportError:
        raise AreaSearchError(MISSING_EXTRA) from None


def check_mcap_path(out: Path) -> None:
    """AreaSearchError unless an MCAP file can be written at ``out`` (an ``.mcap`` name, a writable place)
    and ``foxglove-sdk`` is installed."""
    if out.suffix.lower() != SUFFIX:
        raise AreaSearchError(f"{out}: an MCAP file must end in {SUFFIX}")
    check_file_path(out, "MCAP file")
    require_foxglove()


def map_state(explored: np.ndarray, occupied: np.ndarray) -> np.ndarray:
    """(H, W) uint8 grid values of a map: :data:`FREE` where explored and not occupied, :data:`UNKNOWN`
    where not explored, :data:`OCCUPIED` where occupied."""
    state = np.where(explored, np.uint8(FREE), np.uint8(UNKNOWN))
    state[occupied] = OCCUPIED
    return state


# ---------------------------------------------------------------------------------- messages


_COLOURS: dict[tuple[int, int, int, float], Color] = {}


def _color(rgb: Sequence[int], alpha: float = 1.0) -> Color:
    """A ``foxglove.Color`` of 0-255 ``rgb`` and ``alpha`` (made once: a message holds it, never changes it)."""
    from foxglove.messages import Color

    key = (int(rgb[0]), int(rgb[1]), int(rgb[2]), float(alpha))
    colour = _COLOURS.get(key)
    if colour is None:
        colour = _COLOURS[key] = Color(r=key[0] / 255, g=key[1] / 255, b=key[2] / 255, a=key[3])
    return colour


def _pose(x: float, y: float, yaw: float = 0.0, z: float = 0.0) -> Pose:
    from foxglove.messages import Pose, Quaternion, Vector3

    return Pose(
        position=Vector3(x=float(x), y=float(y), z=z),
        orientation=Quaternion(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)),
    )


def _stamp(t_ns: int) -> Any:
    from foxglove.messages import Timestamp

    return Timestamp(t_ns // 1_000_000_000, t_ns % 1_000_000_000)


def grid_message(state: np.ndarray, cell_m: float, origin_xy: Sequence[float], t_ns: int) -> Grid:
    """A ``foxglove.Grid`` of an (H, W) uint8 ``state`` array indexed [iy, ix] (row 0 the south edge, at
    ``origin_xy``): one uint8 field ``state`` per cell, rows of W cells northwards."""
    from foxglove.messages import Grid, PackedElementField, PackedElementFieldNumericType, Vector2

    w = state.shape[1]
    return Grid(
        timestamp=_stamp(t_ns),
        frame_id=FRAME,
        pose=_pose(origin_xy[0], origin_xy[1]),
        column_count=w,
        cell_size=Vector2(x=cell_m, y=cell_m),
        row_stride=w,
        cell_stride=1,
        fields=[PackedElementField(name="state", offset=0, type=PackedElementFieldNumericType.Uint8)],
        data=np.ascontiguousarray(state, dtype=np.uint8).tobytes(),
    )


def _robot_entities(poses: np.ndarray, radius_m: float, t_ns: int, alpha: float, prefix: str) -> SceneUpdate:
    """Each robot as an arrow along its heading over a disc of its footprint (entity ``<prefix><i>``)."""
    from foxglove.messages import ArrowPrimitive, CylinderPrimitive, SceneEntity, SceneUpdate, Vector3

    stamp, disc_size = _stamp(t_ns), Vector3(x=2 * radius_m, y=2 * radius_m, z=0.02)
    entities = []
    for r, (x, y, yaw) in enumerate(poses.tolist()):
        colour = ROBOT_COLOURS[r % len(ROBOT_COLOURS)]
        pose = _pose(x, y, yaw, 0.03)
        arrow = ArrowPrimitive(
            pose=pose,
            shaft_length=ARROW_M * 0.6,
            shaft_diameter=0.06,
            head_length=ARROW_M * 0.4,
            head_diameter=0.16,
            color=_color(colour, alpha),
        )
        disc = CylinderPrimitive(
            pose=pose, size=disc_size, bottom_scale=1.0, top_scale=1.0, color=_color(colour, 0.4 * alpha)
        )
        entities.append(
            SceneEntity(timestamp=stamp, frame_id=FRAME, id=f"{prefix}{r}", arrows=[arrow], cylinders=[disc])
        )
    return SceneUpdate(entities=entities)


def _spheres(xy: np.ndarray, rgb: Sequence[int], alpha: float) -> list[Any]:
    """A sphere of :data:`TARGET_M` at each point of ``xy`` (N, 2), metres."""
    from foxglove.messages import SpherePrimitive, Vector3

    size, colour = Vector3(x=TARGET_M, y=TARGET_M, z=TARGET_M), _color(rgb, alpha)
    return [SpherePrimitive(pose=_pose(x, y, 0.0, TARGET_M / 2), size=size, color=colour) for x, y in xy.tolist()]


# ---------------------------------------------------------------------------------- the recorder


def _json_schema(name: str, fields: Mapping[str, str]) -> Any:
    from foxglove import Schema

    schema = {
        "type": "object",
        "properties": {key: {"type": kind} for key, kind in fields.items()},
        "required": list(fields),
    }
    return Schema(name=name, encoding="jsonschema", data=json.dumps(schema, sort_keys=True).encode())


class Recorder:
    """Writes one episode of ``env`` to an MCAP file while it is played (:func:`recording` makes one).

    ``every``: a map frame (``/map``, ``/trajectories``, on imperfect worlds ``/map/truth`` and
    ``/map_error``) every that many primitive steps, plus step 0 and the last step; ``step_s``: simulated
    seconds per step. :attr:`counts` holds the messages written per topic, :attr:`frame_steps` the steps of
    the map frames, :attr:`seconds` the wall time spent recording."""

    def __init__(self, env: AreaSearchEnv, path: Path, every: int, step_s: float, metadata: Mapping[str, Any]) -> None:
        import foxglove
        from foxglove.channels import GridChannel, SceneUpdateChannel

        self.env, self.world = env, env.world
        self.every, self.step_ns = every, int(round(step_s * 1e9))
        self.counts: dict[str, int] = {}
        self.frame_steps: list[int] = []
        self.seconds = 0.0
        self.imperfect = env.config.world.imperfect
        self._context = foxglove.Context()  # this recording's own channels: nothing else logs to its file
        self._writer: MCAPWriter | None = foxglove.open_mcap(path, allow_overwrite=True, context=self._context)
        episode = {"areasearch": __version__, "step_s": repr(step_s), "every": str(every), "frame_id": FRAME}
        self._writer.write_metadata("areasearch.episode", {**episode, **{k: str(v) for k, v in metadata.items()}})
        topics = [t for t in TOPICS if self.imperfect or t not in IMPERFECT_ONLY]
        self._channels: dict[str, Any] = {}
        for topic in topics:
            if topic in ("/metrics", "/map_error"):
                fields = METRICS_FIELDS if topic == "/metrics" else MAP_ERROR_FIELDS
                name = "areasearch.Metrics" if topic == "/metrics" else "areasearch.MapError"
                schema = _json_schema(name, fields)
                self._channels[topic] = foxglove.Channel(
                    topic, schema=schema, message_encoding="json", context=self._context
                )
            elif topic in ("/ground_truth", "/map", "/map/truth"):
                self._channels[topic] = GridChannel(topic, context=self._context)
            else:
                self._channels[topic] = SceneUpdateChannel(topic, context=self._context)
            self.counts[topic] = 0
        self._started = False
        self._last_step = -1
        self._goals: np.ndarray | None = None
        self._targets: tuple[int, int] = (-1, -1)
        self._trails: list[list[Any]] = []
        self._spheres: dict[str, list[Any]] = {}
        self._trail_step = 0
        self._attached = False
        self._previous: Callable[[np.ndarray], Any] | None = None

    # ------------------------------------------------------------------ hooks
    def attach(self) -> None:
        """Record around each step of the env's world (an attribute of the instance, removed by :meth:`close`)."""
        world_step = self.world.step
        self._previous = vars(self.world).get("step")  # a hook of someone else's, put back by close()
        self._attached = True

        def step_and_record(actions: np.ndarray) -> Any:
            t0 = time.perf_counter()
            if not self._started:
                self._start()
            self._publish_goals()
            self.seconds += time.perf_counter() - t0
            result = world_step(actions)
            t0 = time.perf_counter()
            self._after_step()
            self.seconds += time.perf_counter() - t0
            return result

        self.world.step = step_and_record  # type: ignore[method-assign]

    def finish(self) -> None:
        """The state at the end: a last map frame (when the last step was not one) and the result metadata."""
        t0 = time.perf_counter()
        if not self._started:
            self._start()
        step = int(self.world.metrics.steps)
        if not self.frame_steps or self.frame_steps[-1] != step:
            self._frame(step)
        assert self._writer is not None
        result = self.world.metrics.as_dict()
        self._writer.write_metadata("areasearch.result", {k: json.dumps(v) for k, v in result.items()})
        self.seconds += time.perf_counter() - t0

    def close(self) -> None:
        """Close the file and the channels; the world steps unrecorded again."""
        if self._attached:
            if self._previous is None:
                vars(self.world).pop("step", None)
            else:
                self.world.step = self._previous  # type: ignore[method-assign,assignment]
            self._attached = False
        if self._writer is not None:
            self._writer.close()
            self._writer = None
        for channel in self._channels.values():
            channel.close()

    # ------------------------------------------------------------------ what is written
    def _t(self, step: int) -> int:
        return step * self.step_ns

    def _log(self, topic: str, message: Any, step: int) -> None:
        self._channels[topic].log(message, log_time=self._t(step))
        self.counts[topic] += 1

    def _start(self) -> None:
        """Step 0: the ground truth, the first map frame, the robots, the targets and the metrics."""
        world = self.world
        scene = world.scene
        assert scene is not None
        self._started = True
        truth = np.where(scene.free, np.uint8(FREE), np.uint8(OCCUPIED))
        self._log("/ground_truth", grid_message(truth, scene.cell_m, scene.origin_xy, 0), 0)
        self._trails = [[] for _ in range(world.config.num_robots)]
        self._publish_state(0)
        self._frame(0)

    def _after_step(self) -> None:
        step = int(self.world.metrics.steps)
        self._publish_state(step)
        if step % self.every == 0:
            self._frame(step)

    def _publish_state(self, step: int) -> None:
        """Every step: the robots, the metrics; the targets when one was discovered or covered."""
        world, radius = self.world, self.world.config.robot.radius_m
        self._log("/robots", _robot_entities(world.poses, radius, self._t(step), 1.0, "robot"), step)
        if self.imperfect:
            update = _robot_entities(world.believed_poses, radius, self._t(step), 0.5, "believed")
            self._log("/robots/believed", update, step)
        m = world.metrics
        metrics = {
            "step": step,
            "explored_pct": 100.0 * m.explored_fraction,
            "covered_pct": 100.0 * m.covered_fraction,
            "covered_of_discovered_pct": m.covered_of_discovered_pct,
            "discovered": int(m.discovered),
            "covered": int(m.covered),
            "collisions": int(m.collisions.sum()),
            "path_length_m": float(m.path_length_m.sum()),
        }
        self._log("/metrics", metrics, step)
        self._last_step = step
        counts = (int(m.discovered), int(m.covered))
        if counts != self._targets:
            self._targets = counts
            self._publish_targets(step)

    def _publish_targets(self, step: int) -> None:
        """The targets by state (entities ``hidden``, ``discovered``, ``covered``; ``marked`` on an imperfect
        world), each target's sphere made once per state."""
        from foxglove.messages import SceneEntity, SceneUpdate

        world, stamp = self.world, _stamp(self._t(step))
        if not self._spheres:
            self._spheres = {
                "hidden": _spheres(world.targets_xy, HIDDEN_TARGET, 0.5),
                "discovered": _spheres(world.targets_xy, TARGET_FOUND, 1.0),
                "covered": _spheres(world.targets_xy, TARGET_COVERED, 1.0),
            }
        chosen = {
            "hidden": ~world.discovered,
            "discovered": world.discovered & ~world.covered,
            "covered": world.covered,
        }
        entities = [
            SceneEntity(
                timestamp=stamp,
                frame_id=FRAME,
                id=name,
                spheres=[self._spheres[name][k] for k in np.flatnonzero(mask).tolist()],
            )
            for name, mask in chosen.items()
        ]
        if self.imperfect:  # where the map marks them: moves as the robots re-detect them
            marked = _spheres(world.target_map_xy[world.discovered], TARGET_FOUND, 0.4)
            entities.append(SceneEntity(timestamp=stamp, frame_id=FRAME, id="marked", spheres=marked))
        self._log("/targets", SceneUpdate(entities=entities), step)

    def _publish_goals(self) -> None:
        """The goals when they differ from the last ones written, at the time they take effect."""
        from foxglove.messages import CubePrimitive, SceneEntity, SceneUpdate, Vector3

        goals = self.env.goals
        if self._goals is not None and np.array_equal(goals, self._goals):
            return
        self._goals = goals
        scene = self.world.scene
        assert scene is not None
        step = int(self.world.metrics.steps)
        stamp, size = _stamp(self._t(step)), Vector3(x=GOAL_M, y=GOAL_M, z=0.04)
        entities = []
        for r, cell in enumerate(goals):
            cubes = []
            if cell[0] >= 0:
                (x, y), colour = scene.cell_to_world(cell[None])[0], ROBOT_COLOURS[r % len(ROBOT_COLOURS)]
                cubes.append(CubePrimitive(pose=_pose(x, y, 0.0, 0.02), size=size, color=_color(colour, 0.9)))
            entities.append(SceneEntity(timestamp=stamp, frame_id=FRAME, id=f"goal{r}", cubes=cubes))
        self._log("/goals", SceneUpdate(entities=entities), step)

    def _frame(self, step: int) -> None:
        """A map frame: the team's map, the trajectories; the truth and the map's error on an imperfect world."""
        from foxglove.messages import LinePrimitive, LinePrimitiveLineType, Point3, SceneEntity, SceneUpdate

        world = self.world
        scene, mapper = world.scene, world.mapper
        assert scene is not None and mapper is not None
        t = self._t(step)
        self.frame_steps.append(step)
        self._log(
            "/map", grid_message(map_state(mapper.explored, mapper.occupied), scene.cell_m, scene.origin_xy, t), step
        )
        if self.imperfect:
            explored, occupied = true_map(world)
            self._log("/map/truth", grid_message(map_state(explored, occupied), scene.cell_m, scene.origin_xy, t), step)
            quality = map_quality(world)
            parts = {f"{name}_pct": value for name, value in quality.parts_pct().items()}
            self._log("/map_error", {"step": step, "map_error_pct": quality.error_pct, **parts}, step)
        for s in range(self._trail_step, step + 1):  # the points where each robot moved, since the last frame
            for r, (x, y) in enumerate(world.trajectory[min(s, len(world.trajectory) - 1), :, :2]):
                trail = self._trails[r]
                if not trail or (x, y) != trail[-1][0]:
                    trail.append(((x, y), Point3(x=float(x), y=float(y), z=0.01)))
        self._trail_step = step + 1
        stamp, entities = _stamp(t), []
        for r, trail in enumerate(self._trails):
            line = LinePrimitive(
                type=LinePrimitiveLineType.LineStrip,
                thickness=LINE_M,
                points=[point for _, point in trail],
                color=_color(ROBOT_COLOURS[r % len(ROBOT_COLOURS)], 0.8),
            )
            entities.append(SceneEntity(timestamp=stamp, frame_id=FRAME, id=f"trajectory{r}", lines=[line]))
        self._log("/trajectories", SceneUpdate(entities=entities), step)


@contextlib.contextmanager
def recording(
    env: AreaSearchEnv,
    path: str | Path,
    *,
    every: int | None = None,
    step_s: float = STEP_S,
    metadata: Mapping[str, Any] | None = None,
) -> Iterator[Recorder]:
    """Record the episode played on ``env`` inside the block to the MCAP file ``path`` (the module
    docstring): a map frame every ``every`` steps (default: every decision, ``decisions.period_steps``),
    ``step_s`` simulated seconds per step, ``metadata`` (strings by name) in ``areasearch.episode``. The
    file appears, whole, when the block ends without an error (written beside it, then renamed over
    ``path``); an error leaves no file and an existing one as it was. AreaSearchError when the ``mcap``
    extra is missing or the file cannot be written."""
    path = Path(path)
    check_mcap_path(path)
    frames = env.config.decisions.period_steps if every is None else every
    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 1:
        raise ConfigError(f"every must be an integer >= 1, got {frames!r}")
    if not (isinstance(step_s, (int, float)) and math.isfinite(step_s) and step_s > 0):
        raise ConfigError(f"step_s must be a positive number of seconds, got {step_s!r}")
    with atomic_path(path, "MCAP file") as tmp:
        recorder = Recorder(env, tmp, frames, float(step_s), metadata or {})
        try:
            recorder.attach()
            yield recorder
            recorder.finish()
        finally:
            recorder.close()


# ---------------------------------------------------------------------------------- eval --record-mcap


SELECTOR_KEYS = ("method", "map", "robots", "episode")
ALL = "all"


@dataclass(frozen=True)
class EpisodeSelector:
    """Which episodes of an evaluation to record (``eval --record-mcap``): those whose method, map id, team
    size and episode index equal every field given (None: any)."""

    method: str | None = None
    map: str | None = None
    robots: int | None = None
    episode: int | None = None

    def describe(self) -> str:
        """The selector as ``--record-mcap`` takes it."""
        given = [f"{key}={getattr(self, key)}" for key in SELECTOR_KEYS if getattr(self, key) is not None]
        return ",".join(given) or ALL

    def matches(self, method: str, map_id: str, robots: int, episode: int) -> bool:
        return (
            self.method in (None, method)
            and self.map in (None, map_id)
            and self.robots in (None, robots)
            and self.episode in (None, episode)
        )


def parse_selector(text: str) -> EpisodeSelector:
    """An :class:`EpisodeSelector` from ``all`` or ``KEY=VALUE[,KEY=VALUE...]`` with keys method, map,
    robots, episode (``method=greedy,episode=0``); ConfigError naming what is wrong."""
    if text.strip() == ALL:
        return EpisodeSelector()
    given: dict[str, Any] = {}
    for part in text.split(","):
        key, sep, value = (s.strip() for s in part.partition("="))
        if not sep or not value:
            raise ConfigError(
                f"--record-mcap takes 'all' or KEY=VALUE[,KEY=VALUE...] with keys {', '.join(SELECTOR_KEYS)} "
                f"(e.g. method=greedy,episode=0), got {text[:200]!r}"
            )
        if key not in SELECTOR_KEYS:
            raise ConfigError(f"--record-mcap: unknown key {key[:40]!r}; use {', '.join(SELECTOR_KEYS)}")
        if key in given:
            raise ConfigError(f"--record-mcap: {key} is given twice in {text[:200]!r}")
        if key in ("robots", "episode"):
            if not value.isdigit() or len(value) > 9:
                raise ConfigError(f"--record-mcap: {key} must be a non-negative integer, got {value[:40]!r}")
            given[key] = int(value)
        else:
            given[key] = value
    return EpisodeSelector(**given)


RECORD_FOLDER = "episodes"
"""The folder of an evaluation's recorded episodes, in its results folder."""


def _file_name(text: str) -> str:
    """``text`` with every character other than letters, digits, ``_``, ``.`` and ``-`` replaced by ``_``."""
    name = re.sub(r"[^A-Za-z0-9_.-]", "_", text)
    return "_" if name in ("", ".", "..") else name


def method_records(out: Path, method: str) -> Path:
    """The folder of ``method``'s recorded episodes in the results folder ``out``: ``OUT/episodes/METHOD``."""
    return out / RECORD_FOLDER / _file_name(method)


def record_path(out: Path, method: str, map_id: str, robots: int, episode: int) -> Path:
    """Where ``eval --record-mcap`` writes an episode: ``OUT/episodes/METHOD/MAP-rROBOTS-eEPISODE.mcap``."""
    return method_records(out, method) / f"{_file_name(map_id)}-r{robots}-e{episode}{SUFFIX}"
