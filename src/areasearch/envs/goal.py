"""The high-level environment: one long-term goal per robot per decision (Gymnasium).

``gymnasium.make("areasearch/AreaSearch-v0", map=..., num_robots=...)`` (registered on ``import
areasearch``) builds an :class:`AreaSearchEnv`. This is the decision process of DA-HGNN's
topological planner: every ``decisions.period_steps`` (40) primitive steps each robot gets a
long-term goal chosen among the candidate goals (frontier nodes and discovered, uncovered targets);
between decisions the FMM action planner (:mod:`areasearch.planning.paths`) drives the robots.

Spec (R robots, C = ``candidates.max_candidates``, H = ``decisions.history``, S = ``decisions.map_cells``):

* **Action**: ``MultiDiscrete([C] * R)``, one candidate index per robot.
  An index that is out of range or masked (``action_mask[r, i]`` False) is replaced by the robot's
  nearest allowed candidate, and counted in ``info["invalid_goals"]``; a robot with no allowed
  candidate gets no goal and stays. A robot whose goal turns out unreachable mid-way gets its
  nearest other allowed candidate (``info["unreachable_goals"]``; when the action planner found it
  walled in, by new obstacles or bump marks, the nearest one it can still reach), and that goal is
  not offered to it for the next ``decisions.failed_memory`` decisions (unless every goal it can reach
  failed: then all are offered again, so that no robot idles while work remains; but never again
  within the decision in which it failed: a robot without a goal stays, or backs off if it is in a
  team-mate's way, until the next decision). Distances (and so the
  action mask) are planned round the action planner's collision map (its bump marks), so an
  offered goal is one the planner can reach.
* **Observation** (``Dict``): built by :func:`areasearch.envs.observation.build_observation`, whose
  module docstring holds the spec: the pooled 7-channel ``map`` (:data:`MAP_CHANNELS`),
  ``map_scale``, ``cell_m``, ``robots``, ``candidates`` with ``candidate_mask``, ``distances``,
  ``action_mask``, ``history_robots`` / ``history_goals`` with ``history_mask``, and ``progress``.
  Historical positions (map channel 1) are every cell a robot stood on since the reset.
* **Reward**: the sum of the paper's per-step team rewards over the primitive steps of the decision.
* **Termination**: everything reachable explored and every target covered, or no candidate left
  (nothing more the team can do). A frontier node that a robot reached and looked at without
  clearing it (its unknown side cannot be seen from the reachable space around it, e.g. a wall
  corner) is *exhausted*: frontier nodes within ``candidates.exhausted_m`` of it are not offered
  again, so the team never waits forever on a frontier it cannot clear.
  **Truncation**: ``world.max_steps`` primitive steps (3600).
* **Info**: the world's metrics (``explored_pct``, ``covered_pct``, ``time_e``, ``time_c``, ...),
  ``explored_ratio`` (the label of the auxiliary head of DA-HGNN), ``steps``, ``invalid_goals``,
  ``unreachable_goals``, ``candidates`` (count before padding).
* **Reset options**: ``reset(options={"poses": [[x, y, yaw], ...]})`` starts the robots at the given
  poses (metres, radians, map frame; each where a robot can stand, footprints apart) instead of
  drawing them; other keys are ignored.
* **Limited communication** (``comm.model`` other than ``full``): the robots that can talk form groups
  (:attr:`~areasearch.sim.world.World.comm_groups`), and each group decides for itself. Every decision
  has one observation per group (:meth:`AreaSearchEnv.decision_groups`), built from the group's merged
  map and the targets it knows, its robots at their believed poses and every other robot where the
  group last heard of it (:meth:`~areasearch.sim.world.World.team_poses`); a robot's action indexes the
  candidates of its own group's observation. :meth:`reset` and :meth:`step` return the observation of
  the group of robot 0; with full communication there is one group, and that is the team's observation.
  :func:`decide` asks a planner once per group and keeps, of each answer, the goals of that group's robots.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from ..config import NO_REALISM, SearchConfig, env_config, realism_keywords
from ..errors import ConfigError
from ..planning.candidates import CandidateKind, Candidates, extract_candidates, search_candidate_params
from ..planning.paths import ActionPlanner
from ..sim.render import draw_world
from ..sim.scene import Scene, SceneSource, scene_source
from ..sim.world import World, start_poses_option
from .observation import MAP_CHANNELS as MAP_CHANNELS  # re-exported: imported from here too
from .observation import build_observation, map_scale


class AreaSearchEnv(gym.Env):  # type: ignore[type-arg]
    """Multi-robot area search as a goal-assignment MDP. See the module docstring for the spec.

    ``config`` (default :class:`~areasearch.config.SearchConfig`) with ``num_robots`` and the keyword
    ``overrides`` (world fields such as ``protocol="passby"`` or ``max_steps=400``, ``candidates.``,
    ``paths.`` and ``decisions.`` fields, nested ones dotted or with a double underscore) applied
    once, by :func:`areasearch.config.env_config`, into the typed :attr:`config`. ``realism``: a preset
    of the world's imperfections (``none``, the default, ``low``, ``medium``, ``high``:
    :data:`areasearch.config.REALISM_PRESETS`) applied over ``config``, the keyword ``overrides``
    winning over its values (``gymnasium.make("areasearch/AreaSearch-v0", realism="medium")``)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 4}  # noqa: RUF012 - as gymnasium.Env declares it

    def __init__(
        self,
        map: str | Scene = "robotathome_sarmis",
        num_robots: int = 3,
        seed: int | None = None,
        config: SearchConfig | None = None,
        render_mode: str | None = None,
        realism: str = NO_REALISM,
        **overrides: Any,
    ) -> None:
        self.config = env_config(config or SearchConfig(), num_robots, realism_keywords(realism, overrides))
        if render_mode not in (None, "rgb_array"):
            raise ConfigError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        self.source: SceneSource = scene_source(map, wall_height_m=self.config.world.wall_height_m)
        self.world = World(self.config.world)
        self._seed = seed
        self._rng: np.random.Generator | None = None
        r = self.config.world.num_robots
        c = self.config.candidates.max_candidates
        h = self.config.decisions.history
        s = self.config.decisions.map_cells
        inf = np.float32(np.inf)
        self.action_space = spaces.MultiDiscrete(np.full(r, c, dtype=np.int64))
        self.observation_space = spaces.Dict(
            {
                "map": spaces.Box(0.0, 1.0, (len(MAP_CHANNELS), s, s), np.float32),
                "map_scale": spaces.Box(1.0, inf, (1,), np.float32),
                "cell_m": spaces.Box(0.0, inf, (1,), np.float32),
                "robots": spaces.Box(-inf, inf, (r, 3), np.float32),
                "candidates": spaces.Box(-inf, inf, (c, 5), np.float32),
                "candidate_mask": spaces.MultiBinary(c),
                "distances": spaces.Box(0.0, inf, (r, c), np.float32),
                "action_mask": spaces.MultiBinary((r, c)),
                "history_robots": spaces.Box(-inf, inf, (h, r, 2), np.float32),
                "history_goals": spaces.Box(-inf, inf, (h, r, 2), np.float32),
                "history_mask": spaces.MultiBinary(h),
                "progress": spaces.Box(0.0, 1.0, (1,), np.float32),
            }
        )
        self.candidates: Candidates | None = None
        """The candidates of the group of robot 0 at the last decision (with full communication, the team's)."""
        self.planner: ActionPlanner | None = None
        self._groups: list[np.ndarray] = []
        self._group_candidates: list[Candidates] = []
        self._group_observations: list[dict[str, np.ndarray]] = []
        self._group_index = np.zeros(self.config.world.num_robots, dtype=np.int64)

    # ------------------------------------------------------------------ Gymnasium API
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[dict, dict]:
        super().reset(seed=seed)
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        elif self._rng is None:
            self._rng = np.random.default_rng(self._seed)
        scene = self.source.sample(self._rng)
        self.world.reset(scene, self._rng, poses=start_poses_option(options))
        self.planner = ActionPlanner(self.config.paths, self.world)
        n = self.config.world.num_robots
        self._visited = np.zeros(scene.shape, dtype=bool)
        self._mark_visited(0)
        self._history: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=self.config.decisions.history)
        self._failed: list[dict[tuple[int, int], int]] = [{} for _ in range(n)]  # goal cell -> decision
        self._decision = 0
        self._exhausted: list[np.ndarray] = []
        self._goals = np.full((n, 2), -1, dtype=np.int64)
        self._goal_kind = np.full(n, -1, dtype=np.int64)
        self._goal_tol = np.full(n, self.config.paths.goal_tolerance_m)
        self._goal_approach = np.full((n, 2), np.nan)  # target to drive over (``paper`` protocol), per robot
        self._goal_target = np.full(n, -1, dtype=np.int64)  # the target a robot's goal is for, -1 for none
        self._blocked_by = np.zeros(n, dtype=np.int8)
        self._refresh_candidates()
        return self._observation(), self._info(invalid=0, unreachable=0)

    def step(self, action: Any) -> tuple[dict, float, bool, bool, dict]:
        if self.planner is None or self.candidates is None:
            raise RuntimeError("step() called before reset()")
        world, planner = self.world, self.planner
        choice = np.asarray(action).reshape(-1)
        if choice.shape != (self.config.world.num_robots,):
            raise ConfigError(
                f"action must hold one candidate index per robot ({self.config.world.num_robots}), got {action!r}"
            )
        self._decision += 1
        self._mark_exhausted()
        goals, invalid = self._goal_cells(choice)
        cells = world.scene.world_to_cell(world.believed_poses[:, :2])  # type: ignore[union-attr]
        self._history.appendleft((cells.astype(np.float32), goals.astype(np.float32)))  # the team's
        self._goals = goals
        routes = self.candidates.routes if len(self._groups) == 1 else None  # a group's routes are on its map
        planner.set_goals(goals, self._goal_tol, routes, self._goal_approach)
        reward = 0.0
        unreachable = 0
        first = world.metrics.steps + 1
        for _ in range(self.config.decisions.period_steps):
            if planner.unreachable.any():
                unreachable += self._replace_unreachable()
            if world.noise is not None:
                self._follow_marks()
            actions = planner.act(self._blocked_by)
            result = world.step(actions)
            self._blocked_by = result.blocked_by
            reward += result.reward
            if world.done or world.metrics.steps >= self.config.world.max_steps:
                break
        self._mark_visited(first)
        self._drop_missed_targets()
        self._refresh_candidates()
        terminated = world.done or all(len(cand) == 0 for cand in self._group_candidates)
        truncated = not terminated and world.metrics.steps >= self.config.world.max_steps
        return self._observation(), float(reward), bool(terminated), bool(truncated), self._info(invalid, unreachable)

    def decision_groups(self) -> list[tuple[np.ndarray, dict[str, np.ndarray]]]:
        """The groups that decide now, each as its robots (sorted indices) and its observation (the module
        docstring); one group of every robot, with the observation :meth:`step` returned, under full
        communication."""
        return list(zip(self._groups, self._group_observations, strict=True))

    @property
    def goals(self) -> np.ndarray:
        """(R, 2) the robots' current long-term goal cells (rows of -1: no goal)."""
        return self._goals.copy()

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            return None
        return draw_world(self.world, goals=self._goals, candidates=self.candidates)

    # ------------------------------------------------------------------ decisions
    def _robot_cells(self, robot: int = 0) -> np.ndarray:
        """(R, 2) the cells where ``robot``'s group places the team (:meth:`World.team_poses`)."""
        assert self.world.scene is not None
        return self.world.scene.world_to_cell(self.world.team_poses(robot)[:, :2])

    def _candidates_of(self, robot: int) -> Candidates:
        """The candidates of ``robot``'s group at the last decision."""
        return self._group_candidates[int(self._group_index[robot])]

    def _allowed(self, cand: Candidates | None = None) -> np.ndarray:
        """(R, C_real) bool: real, reachable candidates (of ``cand``, default :attr:`candidates`) that did not
        fail for that robot within the last ``decisions.failed_memory`` decisions; all its reachable ones
        when every one of them failed (a robot is never left without a goal while there is work it can
        reach: a goal it failed on because team-mates were in the way may be free now)."""
        cand, world = self.candidates if cand is None else cand, self.world
        assert cand is not None and world.scene is not None
        reachable = np.isfinite(cand.distance_m)
        allowed = reachable.copy()
        recent = self._decision - self.config.decisions.failed_memory
        flat = cand.cells[:, 0] * world.scene.shape[1] + cand.cells[:, 1]
        for r, failed in enumerate(self._failed):
            cells = [y * world.scene.shape[1] + x for (y, x), when in failed.items() if when > recent]
            if cells:
                allowed[r] &= ~np.isin(flat, cells)
                if not allowed[r].any():
                    allowed[r] = reachable[r]
        return allowed

    def _goal_cells(self, choice: np.ndarray) -> tuple[np.ndarray, int]:
        """The goal cells of ``choice`` (each robot's index into its group's candidates) and how many were invalid."""
        allowed_of_group = [self._allowed(cand) for cand in self._group_candidates]
        goals = np.full((len(choice), 2), -1, dtype=np.int64)
        invalid = 0
        for r, index in enumerate(choice):
            cand, allowed = self._candidates_of(r), allowed_of_group[int(self._group_index[r])]
            i = int(index)
            if not (0 <= i < len(cand) and allowed[r, i]):
                invalid += 1
                i = self._nearest_allowed(r, allowed, cand)
            if i >= 0:
                goals[r] = cand.cells[i]
            self._describe_goal(r, i, cand)
        return goals, invalid

    def _describe_goal(self, r: int, index: int, cand: Candidates) -> None:
        """Robot ``r``'s goal is candidate ``index`` of ``cand`` (-1: none): its kind, arrival tolerance, the
        point to drive over and the target it is for (-1 for none)."""
        target = index >= 0 and cand.kind[index] == CandidateKind.TARGET
        self._goal_kind[r] = cand.kind[index] if index >= 0 else -1
        self._goal_tol[r] = self._tolerance(index, cand)
        self._goal_approach[r] = self._approach(index, cand)
        self._goal_target[r] = int(cand.target_id[index]) if target else -1

    def _tolerance(self, index: int, cand: Candidates) -> float:
        """Arrival distance for candidate ``index`` of ``cand``: the planner's default for a frontier node; for
        a target node, close enough to cover the target itself (its goal cell may sit ``offset_m`` from it)."""
        if index < 0 or cand.kind[index] != CandidateKind.TARGET:
            return self.config.paths.goal_tolerance_m
        cover = self.config.world.cover_radius_m
        return max(cover - float(cand.offset_m[index]) - 0.01, 0.05)

    def _approach(self, index: int, cand: Candidates) -> tuple[float, float]:
        """The point the robot sent to candidate ``index`` of ``cand`` must drive its centre over: under the
        ``paper`` protocol, the target's own position for a target node (its goal cell may sit
        ``offset_m`` from it); NaN otherwise (arrival by distance, :meth:`_tolerance`)."""
        if index < 0 or cand.kind[index] != CandidateKind.TARGET or not self.config.world.rule.swept:
            return (np.nan, np.nan)
        x, y = self.world.target_map_xy[int(cand.target_id[index])]
        return (float(x), float(y))

    def _nearest_allowed(self, r: int, allowed: np.ndarray, cand: Candidates) -> int:
        if not allowed[r].any():
            return -1
        return int(np.argmin(np.where(allowed[r], cand.distance_m[r], np.inf)))

    def _replace_unreachable(self) -> int:
        planner = self.planner
        assert planner is not None
        count = 0
        for r in np.flatnonzero(planner.unreachable):
            self._failed[r][(int(self._goals[r, 0]), int(self._goals[r, 1]))] = self._decision
            cand = self._candidates_of(int(r))
            allowed = self._allowed(cand)
            region = planner.walled_in[r]
            if region is not None:
                # walled in (bump marks, new obstacles): only the candidates it can still reach
                box, reach = region
                local = cand.cells - box.origin
                inside = ((local >= 0) & (local < box.shape)).all(axis=1)
                inside[inside] = reach[local[inside, 0], local[inside, 1]]
                allowed[r] &= inside
            # a goal that failed for it during this decision is not given back before the next one
            # (when every goal failed, _allowed offers them all again): a robot sent back at once to
            # the one target that team-mates crowd round keeps the crowd there (three to five robots
            # round the last target of a map, stalled until the horizon); without a goal it stays,
            # and backs off if it is in the way (paths.jams), until the next decision
            now = [cell for cell, when in self._failed[r].items() if when == self._decision]
            if now:
                width = self.world.scene.shape[1]  # type: ignore[union-attr]
                flat = cand.cells[:, 0] * width + cand.cells[:, 1]
                allowed[r] &= ~np.isin(flat, [y * width + x for y, x in now])
            i = self._nearest_allowed(int(r), allowed, cand)
            self._goals[r] = cand.cells[i] if i >= 0 else (-1, -1)
            self._describe_goal(int(r), i, cand)
            count += 1
        planner.set_goals(self._goals, self._goal_tol, approach_xy=self._goal_approach)
        return count

    def _follow_marks(self) -> None:
        """With noise, a target's mark moves as robots see it again (:func:`areasearch.sim.noise.sense`): each
        robot sent to drive over a target drives over where its mark is now, once it moved by half a cell (a
        mark that follows the drift step by step would restart the robot's last moves at every step)."""
        planner, scene = self.planner, self.world.scene
        assert planner is not None and scene is not None
        for r in np.flatnonzero((self._goal_target >= 0) & np.isfinite(self._goal_approach[:, 0])):
            xy = self.world.target_map_xy[self._goal_target[r]]
            if np.hypot(*(xy - self._goal_approach[r])) > scene.cell_m / 2:
                self._goal_approach[r] = xy
                planner.move_approach(int(r), xy)

    def _drop_missed_targets(self) -> None:
        """A robot that arrived at a target's mark and did not cover it (with noise its centre is where it
        believes, off the target by its drift) is not sent there again for ``decisions.failed_memory``
        decisions: it searches elsewhere and comes back once it has seen the target again, from nearer."""
        planner = self.planner
        assert planner is not None
        own = (planner.goals == self._goals).all(axis=1)
        for r in np.flatnonzero(planner.reached & own & (self._goal_target >= 0)):
            if self.world.pending_targets(int(r))[self._goal_target[r]]:
                self._failed[r][(int(self._goals[r, 0]), int(self._goals[r, 1]))] = self._decision

    def _mark_exhausted(self) -> None:
        """Frontier goals a robot reached and looked at without clearing them cannot be explored
        further from the reachable space near them: they are not offered again."""
        planner = self.planner
        assert planner is not None
        own = (planner.goals == self._goals).all(axis=1)  # not a spot it was sent to, off another's way
        for r in np.flatnonzero(planner.settled & own & (self._goal_kind == CandidateKind.FRONTIER)):
            self._exhausted.append(planner.goals[r].copy())
            self._goal_kind[r] = -1

    def _refresh_candidates(self) -> None:
        """The decision's groups (:attr:`World.comm_groups`) and each group's candidates."""
        self._groups = [group.copy() for group in self.world.comm_groups]
        for g, group in enumerate(self._groups):
            self._group_index[group] = g
        self._group_candidates = [self._group_candidates_of(int(group[0])) for group in self._groups]
        self.candidates = self._group_candidates[0]

    def _group_candidates_of(self, robot: int) -> Candidates:
        """The candidates of ``robot``'s group: on its map, for the team where it places it, its known targets."""
        world, cfg = self.world, self.config
        mapper, scene = world.robot_maps[robot], world.scene
        assert mapper is not None and scene is not None
        pending = np.flatnonzero(world.pending_targets(robot))
        shared = mapper is world.mapper  # the action planner's inflated obstacles are of the team's map
        cand = extract_candidates(
            mapper.explored,
            mapper.occupied,
            self._robot_cells(robot),
            world.target_map_cells[pending],
            pending,
            search_candidate_params(cfg, scene.cell_m),
            impassable=self.planner.bumps if self.planner is not None else None,
            inflated=self.planner.inflated_obstacles() if self.planner is not None and shared else None,
        )
        if self._exhausted and len(cand):
            done = np.array(self._exhausted)
            near = ((cand.cells[:, None, :] - done[None, :, :]) ** 2).sum(-1).min(axis=1)
            radius = cfg.candidates.exhausted_m / scene.cell_m
            cand = cand.select(np.flatnonzero((cand.kind != CandidateKind.FRONTIER) | (near > radius**2)))
        return cand.limit(cfg.candidates.max_candidates)

    def _mark_visited(self, first: int) -> None:
        """Mark the cells the robots stood on from step ``first`` to now (the trajectory's rows)."""
        world = self.world
        assert world.scene is not None
        last = min(world.metrics.steps, len(world.believed_trajectory) - 1)
        cells = world.scene.world_to_cell(world.believed_trajectory[first : last + 1, :, :2]).reshape(-1, 2)
        self._visited[cells[:, 0], cells[:, 1]] = True

    # ------------------------------------------------------------------ observation
    def map_scale(self) -> int:
        """Full-map cells per observation-map cell for the current scene (:func:`.observation.map_scale`)."""
        assert self.world.scene is not None
        return map_scale(self.world.scene.shape, self.config.decisions)

    def _observation(self) -> dict[str, np.ndarray]:
        """Each group's observation (kept for :meth:`decision_groups`); returns the first group's."""
        world, cfg = self.world, self.config
        assert world.scene is not None
        n = cfg.world.num_robots
        history_robots = np.zeros((len(self._history), n, 2), dtype=np.float32)
        history_goals = np.zeros((len(self._history), n, 2), dtype=np.float32)
        for i, (robots, goals) in enumerate(self._history):
            history_robots[i], history_goals[i] = robots, goals
        self._group_observations = []
        for group, cand in zip(self._groups, self._group_candidates, strict=True):
            robot = int(group[0])
            mapper = world.robot_maps[robot]
            self._group_observations.append(
                build_observation(
                    cand,
                    self._robot_cells(robot),
                    world.team_poses(robot)[:, 2],
                    mapper.explored,
                    mapper.occupied,
                    mapper.targets,
                    history_robots,
                    history_goals,
                    cell_m=world.scene.cell_m,
                    progress=min(1.0, world.metrics.steps / cfg.world.max_steps),
                    config=cfg,
                    allowed=self._allowed(cand),
                    visited=self._visited,
                )
            )
        return self._group_observations[0]

    def _info(self, invalid: int, unreachable: int) -> dict[str, Any]:
        m = self.world.metrics
        return {
            **m.as_dict(),
            "explored_ratio": m.explored_fraction,
            "invalid_goals": invalid,
            "unreachable_goals": unreachable,
            "candidates": len(self.candidates) if self.candidates is not None else 0,
        }


def decide(env: AreaSearchEnv, assign: Callable[[dict[str, np.ndarray]], Any]) -> np.ndarray:
    """The team's action of a decision: ``assign`` (a planner's) asked once per group of
    :meth:`AreaSearchEnv.decision_groups`, each group's robots taking their goals of its answer; with one
    group, its answer as it is."""
    groups = env.decision_groups()
    if len(groups) == 1:
        return assign(groups[0][1])  # type: ignore[no-any-return]
    action = np.zeros(env.config.world.num_robots, dtype=np.int64)
    for robots, obs in groups:
        action[robots] = np.asarray(assign(obs)).reshape(-1)[robots]
    return action


def nearest_candidate(obs: dict[str, np.ndarray]) -> np.ndarray:
    """The trivial goal choice: each robot takes its nearest allowed candidate (index 0 if none)."""
    masked = np.where(obs["action_mask"].astype(bool), obs["distances"], np.inf)
    return np.argmin(masked, axis=1).astype(np.int64)
