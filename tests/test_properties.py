"""Property-based tests (hypothesis) on generated maps and random action sequences.

* the world: explored area never shrinks; no robot centre lies in an obstacle or within two radii
  of another robot's; covered targets are discovered targets; metrics stay within [0, 100] %;
  the same seed and actions give the same episode;
* the planners: on generated maps, in the goal environment and on partial maps given to
  :func:`areasearch.service.assign.assign_goals`, every planner's goal is a reachable candidate, or an
  explicit "no goal" exactly when nothing is reachable for that robot.

The examples are drawn the same way on every run (``derandomize``), so CI is reproducible; set
``HYPOTHESIS_PROFILE=explore`` for a longer, random search.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from areasearch.config import TargetConfig, WorldConfig
from areasearch.envs.goal import AreaSearchEnv
from areasearch.errors import ConfigError
from areasearch.harness.evaluate import planner_rng
from areasearch.planners import PLANNERS, GoalPlanner, make_planner
from areasearch.service.assign import OccupancyMap, assign_goals, build_decision
from areasearch.sim.footprint import segment_clearance_reference
from areasearch.sim.scene import Scene, scene_from_grid
from areasearch.sim.world import World

settings.register_profile(
    "ci", max_examples=20, deadline=None, derandomize=True, database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much],
)  # fmt: skip
settings.register_profile(
    "explore", max_examples=300, deadline=None, database=None, suppress_health_check=[HealthCheck.too_slow]
)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

CELL = 0.05


@dataclass(frozen=True)
class Layout:
    """A generated room: free (H, W) bool and obstacle heights (walls 2.5 m, furniture lower)."""

    free: np.ndarray
    height_m: np.ndarray

    def __repr__(self) -> str:
        rows = ["".join(".#"[int(not v)] for v in row) for row in self.free[::-1]]
        return "Layout(north up, # obstacle):\n" + "\n".join(rows)

    def scene(self) -> Scene:
        return scene_from_grid("generated", self.free, CELL, height_m=self.height_m)


@st.composite
def layouts(draw: st.DrawFn) -> Layout:
    """A walled room of 1.2-3 m a side with up to five wall pieces or furniture blocks inside."""
    h, w = draw(st.integers(24, 60)), draw(st.integers(24, 60))
    free = np.zeros((h, w), dtype=bool)
    free[1:-1, 1:-1] = True
    height = np.zeros((h, w), dtype=np.float32)
    for _ in range(draw(st.integers(0, 5))):
        y, x = draw(st.integers(1, h - 2)), draw(st.integers(1, w - 2))
        dy, dx = draw(st.integers(1, 10)), draw(st.integers(1, 10))
        free[y : y + dy, x : x + dx] = False
        height[y : y + dy, x : x + dx] = draw(st.sampled_from([0.4, 1.0, 2.5]))
    return Layout(free, height)


def _world(layout: Layout, robots: int, seed: int, steps: int) -> World:
    world = World(WorldConfig(num_robots=robots, max_steps=steps, targets=TargetConfig(count=5)))
    try:
        world.reset(layout.scene(), np.random.default_rng(seed))
    except ConfigError:  # the generated room has no room for the team or the targets
        assume(False)
    return world


# ---------------------------------------------------------------------------------- the world


@given(layout=layouts(), robots=st.integers(1, 3), seed=st.integers(0, 2**32 - 1), data=st.data())
def test_world_invariants_hold_under_random_actions(
    layout: Layout, robots: int, seed: int, data: st.DataObject
) -> None:
    actions = data.draw(
        st.lists(st.lists(st.integers(0, 3), min_size=robots, max_size=robots), min_size=1, max_size=60)
    )
    world = _world(layout, robots, seed, len(actions))
    scene, radius = world.scene, world.config.robot.radius_m
    assert scene is not None and world.mapper is not None
    explored = world.mapper.explored.copy()
    fraction = world.metrics.explored_fraction
    for step in actions:
        world.step(np.asarray(step, dtype=np.int64))
        now = world.mapper.explored
        assert not (explored & ~now).any(), "explored area shrank"
        assert world.metrics.explored_fraction >= fraction
        explored, fraction = now.copy(), world.metrics.explored_fraction
        for xy in world.poses[:, :2]:  # the footprint clear of every wall square, by the plain reference
            assert segment_clearance_reference(~scene.free, scene.cell_m, tuple(xy), tuple(xy), 2) >= radius - 1e-9
        gaps = np.hypot(*(world.poses[:, None, :2] - world.poses[None, :, :2]).transpose(2, 0, 1))
        assert (gaps[~np.eye(robots, dtype=bool)] >= 2 * radius - 1e-9).all(), "two robots overlap"
        assert not (world.covered & ~world.discovered).any(), "a target covered before it was discovered"
        metrics = world.metrics.as_dict()
        for key in ("explored_pct", "covered_pct"):
            assert 0.0 <= float(metrics[key]) <= 100.0  # type: ignore[arg-type]
        assert 0 <= world.metrics.time_e <= len(actions) and 0 <= world.metrics.time_c <= len(actions)


@given(layout=layouts(), robots=st.integers(1, 3), seed=st.integers(0, 2**32 - 1), data=st.data())
def test_the_same_seed_gives_the_same_episode(layout: Layout, robots: int, seed: int, data: st.DataObject) -> None:
    actions = data.draw(
        st.lists(st.lists(st.integers(0, 3), min_size=robots, max_size=robots), min_size=1, max_size=40)
    )
    runs = []
    for _ in range(2):
        world = _world(layout, robots, seed, len(actions))
        assert world.mapper is not None
        rewards = [world.step(np.asarray(a, dtype=np.int64)).reward for a in actions]
        runs.append((world.trajectory.copy(), world.mapper.explored.copy(), world.covered.copy(), rewards))
    (t1, e1, c1, r1), (t2, e2, c2, r2) = runs
    assert np.array_equal(t1, t2) and np.array_equal(e1, e2) and np.array_equal(c1, c2) and r1 == r2


# ---------------------------------------------------------------------------------- the planners


@pytest.fixture(scope="module")
def planners() -> dict[str, GoalPlanner]:
    """One of each registered planner, built once (the learned ones load a network)."""
    return {name: make_planner(name) for name in sorted(PLANNERS)}


def _check_choice(obs: dict[str, np.ndarray], choice: np.ndarray) -> None:
    allowed = obs["action_mask"].astype(bool)
    assert choice.shape == (allowed.shape[0],)
    for r, i in enumerate(choice):
        if allowed[r].any():
            assert allowed[r, i], f"robot {r} got candidate {i}, not one it may take"
            assert np.isfinite(obs["distances"][r, i])


@pytest.mark.parametrize("method", sorted(PLANNERS))
@given(layout=layouts(), robots=st.integers(1, 3), seed=st.integers(0, 2**32 - 1))
@settings(max_examples=5)
def test_planners_in_the_goal_env_give_reachable_goals_or_none(
    planners: dict[str, GoalPlanner], method: str, layout: Layout, robots: int, seed: int
) -> None:
    env = AreaSearchEnv(map=layout.scene(), num_robots=robots, max_steps=160, **{"targets.count": 5})
    try:
        obs, _ = env.reset(seed=seed)
    except ConfigError:
        assume(False)
    planner = planners[method]
    planner.reset(planner_rng(seed))
    done = False
    while not done:
        choice = planner.assign(obs)
        _check_choice(obs, choice)
        had_any = obs["action_mask"].astype(bool).any(axis=1)
        candidates = env.candidates
        assert candidates is not None
        obs, _, terminated, truncated, info = env.step(choice)
        assert info["invalid_goals"] == int((~had_any).sum())  # every choice was allowed (a robot without any counts)
        goals = env.goals
        none = goals[:, 0] < 0
        # a robot with an allowed candidate got one of them (or, proved unreachable on the way, another
        # reachable one); a robot without any has the explicit no-goal (-1, -1)
        assert not (none & had_any).any() or info["unreachable_goals"] > 0
        assert none[~had_any].all()
        done = terminated or truncated
        if terminated and not env.world.done:
            assert info["candidates"] == 0  # terminated early only because nothing is left


@st.composite
def partial_maps(draw: st.DrawFn) -> tuple[OccupancyMap, np.ndarray]:
    """A generated room seen in part: unknown rectangles over it; 1-3 robots on known-free cells with
    clearance, at least two radii apart."""
    layout = draw(layouts())
    free, occupied = layout.free.copy(), ~layout.free
    for _ in range(draw(st.integers(0, 4))):
        y, x = draw(st.integers(0, free.shape[0] - 1)), draw(st.integers(0, free.shape[1] - 1))
        dy, dx = draw(st.integers(2, 30)), draw(st.integers(2, 30))
        free[y : y + dy, x : x + dx] = False
        occupied[y : y + dy, x : x + dx] = False
    grid = OccupancyMap(free, occupied, CELL)
    scene = layout.scene()
    assert scene.shape == free.shape  # the room's own walls seal it: no padding
    spots = np.argwhere(scene.reachable(0.18) & free)
    assume(len(spots) > 0)
    picks = draw(st.lists(st.integers(0, len(spots) - 1), min_size=1, max_size=3, unique=True))
    xy = grid.cell_to_world(spots[picks])
    gaps = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1)) + 10 * np.eye(len(xy))
    assume(gaps.min() >= 0.36)
    yaw = draw(st.floats(-np.pi, np.pi))
    return grid, np.column_stack([xy, np.full(len(xy), yaw)])


@pytest.mark.parametrize("method", sorted(PLANNERS))
@given(
    case=partial_maps(),
    targets=st.lists(st.tuples(st.floats(0.1, 2.9), st.floats(0.1, 2.9)), max_size=3),
    seed=st.integers(0, 1000),
)
@settings(max_examples=8)
def test_assign_gives_reachable_goals_or_none_on_partial_maps(
    planners: dict[str, GoalPlanner], method: str, case: tuple[OccupancyMap, np.ndarray], targets: list, seed: int
) -> None:
    grid, poses = case
    h, w = grid.shape
    targets = [t for t in targets if t[0] < w * CELL and t[1] < h * CELL]
    decision = build_decision(grid, poses, targets or None)
    planner = planners[method]
    planner.reset(np.random.default_rng(seed))
    _check_choice(decision.obs, planner.assign(decision.obs))
    out = assign_goals(grid, poses, planner, targets or None, seed=seed)
    allowed = decision.obs["action_mask"].astype(bool)
    for a in out:
        if not allowed[a.robot].any():
            assert (a.kind, a.goal_xy, a.path_xy) == ("none", None, [])
            continue
        assert a.kind in ("frontier", "target") and a.goal_xy is not None and a.distance_m is not None
        assert np.isfinite(a.distance_m)
        cell = grid.world_to_cell(np.asarray(a.goal_xy))
        assert not grid.occupied[cell[0], cell[1]]
        path = np.asarray(a.path_xy)
        assert np.allclose(path[0], poses[a.robot, :2]) and np.allclose(path[-1], a.goal_xy)
        cells = grid.world_to_cell(path)
        assert not grid.occupied[cells[:, 0], cells[:, 1]].any()
