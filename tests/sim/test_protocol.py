"""The coverage protocols: ``paper`` (a robot centre passes over the target's cell, checked along each
move's swept segment) and ``passby`` (within 0.3 m at the end of a step, the rule of earlier results)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from areasearch.config import PROTOCOLS, PathConfig, SearchConfig, TargetConfig, WorldConfig, override
from areasearch.envs.goal import AreaSearchEnv
from areasearch.errors import ConfigError
from areasearch.planning.paths import ActionPlanner
from areasearch.sim.scene import bundled_index, load_scene, scene_from_grid
from areasearch.sim.world import Action, World, coverable_cells


def test_paper_is_the_default_and_fixes_its_radius() -> None:
    cfg = WorldConfig().validate()
    assert cfg.protocol == "paper" and cfg.rule is PROTOCOLS["paper"] and cfg.cover_radius_m == 0.05
    assert WorldConfig(protocol="passby").validate().cover_radius_m == 0.3
    passby = WorldConfig(protocol="passby", targets=TargetConfig(cover_radius_m=0.2)).validate()
    assert passby.cover_radius_m == 0.2
    assert SearchConfig().validate().world.protocol == "paper"


@pytest.mark.parametrize(
    ("changes", "field"),
    [
        ({"protocol": "papr"}, "protocol"),
        ({"protocol": 3}, "protocol"),
        ({"targets.cover_radius_m": 0.3}, "targets.cover_radius_m"),  # contradicts paper
        ({"protocol": "passby", "targets.cover_radius_m": -1.0}, "targets.cover_radius_m"),
    ],
)
def test_a_bad_protocol_or_a_contradicting_setting_names_the_field(changes: dict, field: str) -> None:
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        override(WorldConfig(), **changes).validate()


def corridor_world(protocol: str, **targets: float) -> World:
    """A 4 m x 1 m corridor, one robot, one target, the whole map known."""
    free = np.zeros((24, 84), dtype=bool)
    free[2:22, 2:82] = True
    world = World(WorldConfig(num_robots=1, protocol=protocol, targets=TargetConfig(count=1, **targets)))
    world.reset(scene_from_grid("corridor", free, 0.05), np.random.default_rng(1))
    return world


def put_robot_before_target(world: World, behind_m: float) -> None:
    """Put the robot ``behind_m`` west of the target, facing it; sense so the target is discovered."""
    tx, ty = world.targets_xy[0]
    world.poses[0] = (tx - behind_m, ty, 0.0)
    world.step(np.array([Action.STAY]))
    assert world.discovered[0] and not world.covered[0]


def test_paper_covers_a_target_a_forward_step_passes_over() -> None:
    world = corridor_world("paper")
    put_robot_before_target(world, 0.125)  # the 0.25 m move ends 0.125 m past the target
    world.step(np.array([Action.FORWARD]))
    assert world.covered[0] and world.metrics.covered == 1


def test_paper_does_not_cover_a_target_beside_the_swept_segment() -> None:
    world = corridor_world("paper")
    tx, ty = world.targets_xy[0]
    world.poses[0] = (tx - 0.125, ty + 0.07, 0.0)  # passes 7 cm beside it
    world.step(np.array([Action.STAY]))
    world.step(np.array([Action.FORWARD]))
    assert world.discovered[0] and not world.covered[0]


def test_an_end_of_step_rule_lets_a_step_jump_over_a_target() -> None:
    world = corridor_world("passby", cover_radius_m=0.1)
    put_robot_before_target(world, 0.125)
    world.step(np.array([Action.FORWARD]))  # ends 0.125 m beyond, outside 0.1 m: passby does not count it
    assert not world.covered[0]


def test_covered_of_discovered_is_reported() -> None:
    world = corridor_world("paper")
    m = world.metrics.as_dict()
    assert m["covered_of_discovered_pct"] == (100.0 if m["discovered"] == 0 else 0.0)
    put_robot_before_target(world, 0.125)
    world.step(np.array([Action.FORWARD]))
    assert world.metrics.as_dict()["covered_of_discovered_pct"] == 100.0


@pytest.mark.parametrize("map_id", ["bormann_office_d_rooms2", "robotathome_sarmis", "bormann_lab_ipa"])
def test_paper_targets_lie_where_a_robot_centre_can_stand(map_id: str) -> None:
    scene = load_scene(map_id)
    world = World(WorldConfig(num_robots=3))
    world.reset(scene, np.random.default_rng(0))
    inner = coverable_cells(scene.reachable(world.config.robot.radius_m))
    assert inner[world.target_cells[:, 0], world.target_cells[:, 1]].all()
    assert len(np.unique(world.target_cells, axis=0)) == 100


def room(free_box: tuple[int, int, int, int] = (2, 62, 2, 82)) -> np.ndarray:
    free = np.zeros((64, 84), dtype=bool)
    y0, y1, x0, x1 = free_box
    free[y0:y1, x0:x1] = True
    return free


def drive_over(world: World, xy: tuple[float, float], limit: int) -> int | None:
    """Send the world's robot 0 to drive its centre over ``xy`` with the action planner; the step at
    which a move of it swept within the cover radius of ``xy``, or None within ``limit`` steps."""
    assert world.scene is not None
    planner = ActionPlanner(PathConfig(), world)
    cell = world.scene.world_to_cell(np.array(xy))
    goals = np.full((len(world.poses), 2), -1, dtype=np.int64)
    goals[0] = cell
    approach = np.full((len(world.poses), 2), np.nan)
    approach[0] = xy
    planner.set_goals(goals, approach_xy=approach)
    blocked = np.zeros(len(world.poses), dtype=np.int8)
    cover = world.config.cover_radius_m
    for step in range(1, limit + 1):
        a, b = world.poses[0, :2].copy(), None
        result = world.step(planner.act(blocked))
        blocked = result.blocked_by
        b = world.poses[0, :2]
        seg = b - a
        t = 0.0 if not seg.any() else float(np.clip(np.dot(np.asarray(xy) - a, seg) / np.dot(seg, seg), 0, 1))
        if math.dist(a + t * seg, xy) <= cover:
            for _ in range(3):  # then it counts as arrived and stays
                world.step(planner.act(blocked))
            assert planner.reached[0] and np.allclose(world.poses[0, :2], b)
            return step
    return None


@pytest.mark.parametrize("yaw", [0.0, 1.0, 2.5, -2.0])
@pytest.mark.parametrize(
    ("where", "xy"),
    [
        ("middle of the room", (2.1, 1.6)),
        # the nearest cells to a wall a target can lie on: the footprint radius + a cell's half
        # diagonal (the world's collision rule) + one cell (coverable_cells) from the wall's cells
        ("beside the south wall", (2.6, 0.1 + 0.18 + 0.1)),
        ("in the south-west corner", (0.1 + 0.18 + 0.1, 0.1 + 0.18 + 0.1)),
    ],
)
def test_a_robot_sent_to_a_point_drives_its_centre_over_it(where: str, xy: tuple[float, float], yaw: float) -> None:
    world = World(WorldConfig(num_robots=1, targets=TargetConfig(count=0)))
    world.reset(scene_from_grid("room", room(), 0.05), np.random.default_rng(0))
    world.poses[0] = (3.4, 2.2, yaw)
    world.step(np.array([Action.STAY]))
    assert coverable_cells(world.scene.reachable(0.18))[tuple(world.scene.world_to_cell(np.array(xy)))], where
    step = drive_over(world, xy, limit=400)
    assert step is not None, f"{where}, start yaw {yaw}: not driven over in 400 steps"


def test_the_goal_env_covers_the_target_it_sends_a_robot_to() -> None:
    env = AreaSearchEnv(map="bormann_office_d_rooms2", num_robots=1, seed=3, max_steps=1200)
    obs, info = env.reset(seed=3)
    covered = 0
    while True:
        targets = np.flatnonzero(obs["action_mask"][0].astype(bool) & (obs["candidates"][:, 2] == 1))
        goal = targets[np.argmin(obs["distances"][0, targets])] if len(targets) else 0
        obs, _, terminated, truncated, info = env.step(np.array([goal]))
        covered = info["covered"]
        if terminated or truncated or covered >= 10:
            break
    assert covered >= 10  # sent to the nearest discovered target every decision, it covers them


@pytest.mark.slow
@pytest.mark.parametrize("map_id", [e["id"] for e in bundled_index()])
def test_on_every_bundled_map_a_robot_sent_to_a_target_covers_it(map_id: str) -> None:
    """A sample of targets per map (the nearest to the robot and two more by distance rank), the map
    known: the action planner drives the robot's centre over each, so the world covers it."""
    scene = load_scene(map_id)
    world = World(WorldConfig(num_robots=1))
    rng = np.random.default_rng(7)
    world.reset(scene, rng)
    assert world.mapper is not None
    world.mapper.explored[:] = True
    world.mapper.occupied[:] = ~scene.free
    order = np.argsort(np.hypot(*(world.targets_xy - world.poses[0, :2]).T))
    for k in order[[0, 5, 15]]:
        xy = (float(world.targets_xy[k, 0]), float(world.targets_xy[k, 1]))
        assert drive_over(world, xy, limit=600) is not None, f"{map_id}: target {k} at {xy} not driven over"
        # the world covers a target once discovered (its cell seen); driven over, a seen one is covered
        assert world.covered[k] or not world.discovered[k], f"{map_id}: target {k} driven over, not covered"


# ---------------------------------------------------------------------------------- entry points


def test_the_constructors_take_the_protocol() -> None:
    import gymnasium

    import areasearch

    par = areasearch.parallel_env(map="bormann_office_d_rooms2", num_robots=2, protocol="passby")
    par.reset(seed=0)
    assert par.unwrapped.world.config.protocol == "passby"  # type: ignore[attr-defined]
    gym_env = gymnasium.make("areasearch/AreaSearch-v0", map="bormann_office_d_rooms2", num_robots=2, protocol="passby")
    assert gym_env.unwrapped.config.world.cover_radius_m == 0.3  # type: ignore[attr-defined]
    with pytest.raises(ConfigError, match="protocol"):
        AreaSearchEnv(map="bormann_office_d_rooms2", num_robots=2, protocol="nope")


def test_cli_protocol_option(tmp_path: Path) -> None:
    from areasearch.cli import main

    base = ["run", "--map", "bormann_office_d_rooms2", "--robots", "2", "--max-steps", "40"]
    assert main([*base, "--protocol", "passby", "--out", str(tmp_path / "a.png")]) == 0
    # both ways of naming the protocol at once: one clear error
    assert main([*base, "--protocol", "passby", "--set", "protocol=paper", "--out", str(tmp_path / "b.png")]) == 2
    assert main([*base, "--set", "protocol=papr", "--out", str(tmp_path / "c.png")]) == 2
    assert not (tmp_path / "b.png").exists() and not (tmp_path / "c.png").exists()
    with pytest.raises(SystemExit):
        main([*base, "--protocol", "papr"])  # argparse: not one of the choices


def test_an_eval_folder_records_its_protocol_and_refuses_another(tmp_path: Path) -> None:
    import json

    from areasearch.errors import AreaSearchError
    from areasearch.harness.evaluate import EvalPlan, evaluate

    out = tmp_path / "run"
    plan = EvalPlan(["greedy"], [2], ["bormann_office_d_rooms2"], 1, 0, 40, out)
    evaluate(plan.with_settings({"world.protocol": "passby"}), progress=None)
    config = json.loads((out / "config.json").read_text())
    assert config["config"]["world"]["protocol"] == "passby"
    with pytest.raises(AreaSearchError, match="other settings"):
        evaluate(plan, progress=None)  # the default protocol, paper


def test_a_training_config_records_the_protocol_for_its_episodes(root: Path) -> None:
    from areasearch.training.train import load_config, validation_episodes

    config = load_config(root / "configs" / "dahgnn.toml")
    assert dict(config.rollout.env)["protocol"] == "paper"
    passby = load_config(root / "configs" / "dahgnn.toml", {"rollout.env.protocol": "passby"})
    assert dict(passby.rollout.env) == {"protocol": "passby"}
    assert all(spec.env.world.protocol == "passby" for spec in validation_episodes(passby, ["bormann_lab_a"]))
