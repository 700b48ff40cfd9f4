"""Tests of episodes as MCAP files (:mod:`areasearch.harness.mcap`, ``areasearch render --out x.mcap``,
``areasearch eval --record-mcap``): a written episode read back with the ``mcap`` reader has the channels,
message counts and log times of the episode, and its frames hold the world's arrays at those steps (the
protobuf messages decoded from the schemas stored in the file); the same episode gives the same bytes;
recording changes no result of an evaluation; a missing extra is one clear error; the shipped Foxglove
layout names the topics and fields a recording has, with settings Foxglove's own layout models know."""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from mcap.reader import make_reader

import areasearch
from areasearch.config import realism_settings, search_config
from areasearch.errors import AreaSearchError, ConfigError
from areasearch.harness.animate import record_episode
from areasearch.harness.evaluate import EvalPlan, evaluate, make_env, play_episode, read_episodes
from areasearch.harness.mcap import (
    IMPERFECT_ONLY,
    LAYOUT,
    MAP_ERROR_FIELDS,
    METRICS_FIELDS,
    MISSING_EXTRA,
    STEP_S,
    TOPICS,
    EpisodeSelector,
    parse_selector,
    record_path,
    recording,
)
from areasearch.planners import make_planner
from areasearch.sim.mapquality import map_quality, true_map

STEP_NS = int(STEP_S * 1e9)
STEPS, EVERY, ROBOTS, SEED = 300, 40, 3, 4
FRAMES = [*range(0, STEPS, EVERY), STEPS]  # step 0, every 40 steps, the last step


# ---------------------------------------------------------------------------------- reading back


@dataclass
class Read:
    """A file read back: the channels' schemas by topic, messages (log time, decoded) by topic, metadata."""

    schemas: dict[str, tuple[str, str, str]] = field(default_factory=dict)
    """topic -> (schema name, schema encoding, message encoding)."""
    messages: dict[str, list[tuple[int, Any]]] = field(default_factory=dict)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)
    """The summary's message count per topic."""


def read_mcap(path: Path) -> Read:
    """Every message of ``path`` in file order: protobuf ones decoded with the file descriptors stored in
    their schema, JSON ones parsed."""
    out = Read()
    classes: dict[int, Any] = {}
    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        for channel in summary.channels.values():
            schema = summary.schemas[channel.schema_id]
            out.schemas[channel.topic] = (schema.name, schema.encoding, channel.message_encoding)
            out.counts[channel.topic] = summary.statistics.channel_message_counts.get(channel.id, 0)
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            assert schema is not None
            if channel.message_encoding == "json":
                decoded = json.loads(message.data)
            else:
                if schema.id not in classes:
                    pool = descriptor_pool.DescriptorPool()
                    for proto in descriptor_pb2.FileDescriptorSet.FromString(schema.data).file:
                        pool.Add(proto)
                    classes[schema.id] = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))
                decoded = classes[schema.id].FromString(message.data)
            assert message.publish_time == message.log_time
            out.messages.setdefault(channel.topic, []).append((message.log_time, decoded))
        for record in reader.iter_metadata():
            out.metadata[record.name] = dict(record.metadata)
    return out


def grid_array(grid: Any) -> np.ndarray:
    """The (H, W) ``state`` values of a decoded ``foxglove.Grid`` (one uint8 field, rows northwards)."""
    assert [(f.name, f.offset, f.type) for f in grid.fields] == [("state", 0, 1)]  # UINT8
    assert grid.cell_stride == 1 and grid.row_stride == grid.column_count
    return np.frombuffer(grid.data, np.uint8).reshape(-1, grid.column_count)


def expected_state(explored: np.ndarray, occupied: np.ndarray) -> np.ndarray:
    """A map as the recording's grids hold it: free 0, unknown 1, occupied 2."""
    return np.where(occupied, 2, np.where(explored, 0, 1)).astype(np.uint8)


# ---------------------------------------------------------------------------------- the episode as played


@dataclass
class Played:
    """What the world held after each step of an episode, taken by a hook of its own around ``World.step``."""

    env: Any = None
    poses: list[np.ndarray] = field(default_factory=list)
    believed: list[np.ndarray] = field(default_factory=list)
    metrics: list[dict[str, Any]] = field(default_factory=list)
    maps: dict[int, np.ndarray] = field(default_factory=dict)
    truths: dict[int, np.ndarray] = field(default_factory=dict)
    errors: dict[int, Any] = field(default_factory=dict)
    goals: list[tuple[int, np.ndarray]] = field(default_factory=list)
    target_changes: list[int] = field(default_factory=list)
    trace: Any = None


def play(map_id: str, steps: int, settings: dict[str, Any] | None = None) -> Played:
    """Play the greedy episode the tests record, unrecorded, taking the world's state at every step."""
    env = make_env(map_id, ROBOTS, SEED, steps, search_config(settings) if settings else None)
    world, played = env.world, Played(env=env)
    world_step = world.step

    def take() -> None:
        m, step = world.metrics, int(world.metrics.steps)
        played.poses.append(world.poses.copy())
        played.believed.append(world.believed_poses.copy())
        played.metrics.append(
            {"explored_pct": 100 * m.explored_fraction, "covered_pct": 100 * m.covered_fraction,
             "discovered": m.discovered, "covered": m.covered, "collisions": int(m.collisions.sum()),
             "path_length_m": float(m.path_length_m.sum())}
        )  # fmt: skip
        if step % EVERY == 0 or step == steps:
            played.maps[step] = expected_state(world.mapper.explored, world.mapper.occupied)
            played.truths[step] = expected_state(*true_map(world))
            played.errors[step] = map_quality(world)
        before = played.metrics[-2] if len(played.metrics) > 1 else None
        if before is None or (before["discovered"], before["covered"]) != (m.discovered, m.covered):
            played.target_changes.append(step)

    def step(actions: np.ndarray) -> Any:
        if not played.poses:
            take()
        goals = env.goals
        if not played.goals or not np.array_equal(played.goals[-1][1], goals):
            played.goals.append((int(world.metrics.steps), goals))
        result = world_step(actions)
        take()
        return result

    world.step = step
    played.trace = play_episode(env, make_planner("greedy"), SEED)
    return played


# ---------------------------------------------------------------------------------- tests


def test_a_recorded_episode_reads_back_as_the_episode(tmp_path: Path, small_map: str) -> None:
    out = tmp_path / "episode.mcap"
    summary = record_episode("greedy", small_map, ROBOTS, SEED, out, max_steps=STEPS, every=EVERY)
    played = play(small_map, STEPS)
    world, scene = played.env.world, played.env.world.scene
    assert summary["steps"] == STEPS == world.metrics.steps and summary["frames"] == len(FRAMES)
    assert summary["explored_pct"] == round(played.trace.info["explored_pct"], 6)
    got = read_mcap(out)

    # channels, schemas, counts, log times
    topics = [t for t in TOPICS if t not in IMPERFECT_ONLY]
    assert sorted(got.schemas) == sorted(topics)
    for topic, (name, schema_encoding, encoding) in got.schemas.items():
        if topic == "/metrics":
            assert (name, schema_encoding, encoding) == ("areasearch.Metrics", "jsonschema", "json")
        else:
            kind = "foxglove.Grid" if topic in ("/map", "/ground_truth") else "foxglove.SceneUpdate"
            assert (name, schema_encoding, encoding) == (kind, "protobuf", "protobuf"), topic
    assert summary["messages"] == got.counts == {t: len(got.messages[t]) for t in topics}
    every_step = [s * STEP_NS for s in range(STEPS + 1)]
    for topic in ("/robots", "/metrics"):
        assert [t for t, _ in got.messages[topic]] == every_step, topic
    for topic in ("/map", "/trajectories"):
        assert [t for t, _ in got.messages[topic]] == [s * STEP_NS for s in FRAMES], topic
    assert [t for t, _ in got.messages["/ground_truth"]] == [0]
    assert [t for t, _ in got.messages["/targets"]] == [s * STEP_NS for s in played.target_changes]
    assert [t for t, _ in got.messages["/goals"]] == [s * STEP_NS for s, _ in played.goals]

    # the map frames are the world's map at those steps; the ground truth is the scene
    for (t, grid), step in zip(got.messages["/map"], FRAMES, strict=True):
        assert (grid.timestamp.seconds * 10**9 + grid.timestamp.nanos) == t
        assert grid.frame_id == "map" and grid.cell_size.x == grid.cell_size.y == scene.cell_m
        assert (grid.pose.position.x, grid.pose.position.y) == scene.origin_xy
        np.testing.assert_array_equal(grid_array(grid), played.maps[step], err_msg=f"map at step {step}")
    assert len({grid_array(g).tobytes() for _, g in got.messages["/map"]}) > 3  # the map grew
    ((_, truth),) = got.messages["/ground_truth"]
    np.testing.assert_array_equal(grid_array(truth), np.where(scene.free, 0, 2))

    # robots, metrics, goals, targets, trajectories
    for (_, update), poses in zip(got.messages["/robots"], played.poses, strict=True):
        assert [e.id for e in update.entities] == [f"robot{r}" for r in range(ROBOTS)]
        xy = [(e.arrows[0].pose.position.x, e.arrows[0].pose.position.y) for e in update.entities]
        assert xy == [tuple(p) for p in poses[:, :2].tolist()]
        yaw = [2 * np.arctan2(e.arrows[0].pose.orientation.z, e.arrows[0].pose.orientation.w) for e in update.entities]
        np.testing.assert_allclose(np.angle(np.exp(1j * (np.array(yaw) - poses[:, 2]))), 0, atol=1e-9)
    for step, ((_, metrics), expected) in enumerate(zip(got.messages["/metrics"], played.metrics, strict=True)):
        assert set(metrics) == set(METRICS_FIELDS) and metrics["step"] == step
        assert {k: metrics[k] for k in expected} == expected, step
    assert got.messages["/metrics"][-1][1]["explored_pct"] == pytest.approx(played.trace.info["explored_pct"])
    for (_, update), (_, goals) in zip(got.messages["/goals"], played.goals, strict=True):
        cells = [(e.id, len(e.cubes)) for e in update.entities]
        assert cells == [(f"goal{r}", int(goals[r, 0] >= 0)) for r in range(ROBOTS)]
        for e, cell in zip(update.entities, goals, strict=True):
            if cell[0] >= 0:
                x, y = scene.cell_to_world(cell[None])[0]
                assert (e.cubes[0].pose.position.x, e.cubes[0].pose.position.y) == (x, y)
    _, last = got.messages["/targets"][-1]
    counts = {e.id: len(e.spheres) for e in last.entities}
    m = world.metrics
    assert counts == {"hidden": len(world.covered) - m.discovered, "discovered": m.discovered - m.covered,
                      "covered": m.covered}  # fmt: skip
    covered = {(s.pose.position.x, s.pose.position.y) for e in last.entities if e.id == "covered" for s in e.spheres}
    assert covered == {tuple(p) for p in world.targets_xy[world.covered].tolist()}
    _, trails = got.messages["/trajectories"][-1]
    for r, entity in enumerate(trails.entities):
        path = np.array([p[r, :2] for p in played.poses])
        moved = np.r_[True, (np.diff(path, axis=0) != 0).any(axis=1)]
        assert [(p.x, p.y) for p in entity.lines[0].points] == [tuple(p) for p in path[moved].tolist()]

    # metadata: what was played
    episode = got.metadata["areasearch.episode"]
    assert {k: episode[k] for k in ("method", "map", "robots", "seed", "every", "step_s")} == {
        "method": "greedy", "map": small_map, "robots": str(ROBOTS), "seed": str(SEED), "every": str(EVERY),
        "step_s": repr(STEP_S),
    }  # fmt: skip
    assert json.loads(got.metadata["areasearch.result"]["covered"]) == m.covered

    # the same episode, the same bytes
    again = tmp_path / "again.mcap"
    record_episode("greedy", small_map, ROBOTS, SEED, again, max_steps=STEPS, every=EVERY)
    assert again.read_bytes() == out.read_bytes()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["again.mcap", "episode.mcap"]  # no temporary file left


def test_an_imperfect_world_records_the_belief_beside_the_truth(tmp_path: Path, small_map: str) -> None:
    settings = realism_settings("medium", {})
    steps = 160
    out = tmp_path / "noisy.mcap"
    record_episode("greedy", small_map, ROBOTS, SEED, out, max_steps=steps, every=EVERY, settings=settings)
    played = play(small_map, steps, settings)
    got = read_mcap(out)
    assert sorted(got.schemas) == sorted(TOPICS)
    assert got.schemas["/map_error"][:2] == ("areasearch.MapError", "jsonschema")
    frames = [*range(0, steps, EVERY), steps]
    differ = 0
    for topic in ("/map", "/map/truth", "/map_error"):
        assert [t for t, _ in got.messages[topic]] == [s * STEP_NS for s in frames], topic
    for (_, belief), (_, truth), (_, error), step in zip(
        got.messages["/map"], got.messages["/map/truth"], got.messages["/map_error"], frames, strict=True
    ):
        np.testing.assert_array_equal(grid_array(belief), played.maps[step])
        np.testing.assert_array_equal(grid_array(truth), played.truths[step])
        differ += int((grid_array(belief) != grid_array(truth)).sum())
        quality = played.errors[step]
        assert set(error) == set(MAP_ERROR_FIELDS) and error["step"] == step
        assert error["map_error_pct"] == quality.error_pct and error["missed_pct"] == quality.parts_pct()["missed"]
    assert differ > 0  # the team's belief is not the truth
    believed = got.messages["/robots/believed"]
    assert len(believed) == steps + 1
    for (_, update), poses in zip(believed, played.believed, strict=True):
        xy = [(e.arrows[0].pose.position.x, e.arrows[0].pose.position.y) for e in update.entities]
        assert xy == [tuple(p) for p in poses[:, :2].tolist()]
    assert any(not np.array_equal(a, b) for a, b in zip(played.poses, played.believed, strict=True))
    assert {e.id for _, u in got.messages["/targets"] for e in u.entities} == {
        "hidden",
        "discovered",
        "covered",
        "marked",
    }


def test_recording_restores_the_world_and_leaves_nothing_on_an_error(tmp_path: Path, small_map: str) -> None:
    env = make_env(small_map, 2, 1, 60)
    out = tmp_path / "x.mcap"
    out.write_bytes(b"an earlier file")
    with pytest.raises(RuntimeError, match="planner failed"), recording(env, out):
        play_episode(env, make_planner("greedy"), 1)
        raise RuntimeError("planner failed")
    assert "step" not in vars(env.world)  # the hook is gone
    assert out.read_bytes() == b"an earlier file" and [p.name for p in tmp_path.iterdir()] == ["x.mcap"]
    with recording(env, out, every=7) as recorder:
        play_episode(env, make_planner("greedy"), 1)
    assert recorder.frame_steps == [*range(0, 60, 7), 60] and out.read_bytes()[:8] == b"\x89MCAP0\r\n"
    with (
        pytest.raises(ConfigError, match="every must be an integer >= 1"),
        recording(env, tmp_path / "y.mcap", every=0),
    ):
        pass
    with pytest.raises(AreaSearchError, match=r"an MCAP file must end in \.mcap"), recording(env, tmp_path / "y.bag"):
        pass


def test_a_missing_extra_is_one_clear_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], small_map: str
) -> None:
    from areasearch.cli import main

    for name in [m for m in sys.modules if m == "foxglove" or m.startswith("foxglove.")]:
        monkeypatch.setitem(sys.modules, name, None)  # as if foxglove-sdk were not installed
    assert MISSING_EXTRA == "MCAP export needs the mcap extra: pip install 'areasearch[mcap]'"
    with pytest.raises(AreaSearchError) as error:
        record_episode("greedy", small_map, 2, 0, tmp_path / "x.mcap", max_steps=40)
    assert str(error.value) == MISSING_EXTRA
    out = tmp_path / "run"
    for args in (
        ["render", "--method", "greedy", "--map", small_map, "--max-steps", "40", "--out", str(tmp_path / "x.mcap")],
        ["eval", "--methods", "greedy", "--robots", "2", "--maps", small_map, "--episodes", "1", "--max-steps", "40",
         "--out", str(out), "--record-mcap", "all"],
    ):  # fmt: skip
        assert main(args) == 2
        captured = capsys.readouterr()
        assert captured.err.splitlines() == [f"areasearch: error: {MISSING_EXTRA}"] and captured.out == ""
    assert list(tmp_path.iterdir()) == []  # nothing played, nothing written


def test_render_writes_mcap_and_refuses_what_it_cannot_hold(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], small_map: str
) -> None:
    from areasearch.cli import main

    out = str(tmp_path / "x.mcap")
    for args, message in (
        (["--methods", "greedy", "random"], "an .mcap file holds one episode: name one --method"),
        (["--method", "greedy", "--belief", "team"], "--belief draws a second panel in an animation"),
        (["--method", "nosuch"], "unknown planner 'nosuch'"),
    ):
        assert main(["render", "--map", small_map, *args, "--max-steps", "40", "--out", out]) == 2
        err = capsys.readouterr().err.splitlines()
        assert len(err) == 1 and err[0].startswith("areasearch: error: ") and message in err[0], err
    assert list(tmp_path.iterdir()) == []
    args = ["render", "--map", small_map, "--method", "greedy", "--max-steps", "40", "--every", "20", "--out", out]
    assert main(args) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["mcap"] == out and summary["frames"] == 3 and summary["bytes"] == Path(out).stat().st_size
    assert summary["messages"] == read_mcap(Path(out)).counts and Path(summary["layout"]) == LAYOUT


def test_selectors() -> None:
    assert parse_selector("all") == EpisodeSelector()
    chosen = parse_selector("method=greedy, episode=0,map=a_map,robots=3")
    assert chosen == EpisodeSelector("greedy", "a_map", 3, 0)
    assert chosen.describe() == "method=greedy,map=a_map,robots=3,episode=0"
    assert chosen.matches("greedy", "a_map", 3, 0) and not chosen.matches("greedy", "a_map", 3, 1)
    assert parse_selector("robots=2").matches("random", "other", 2, 7)
    for text, message in (
        ("greedy", "takes 'all' or KEY=VALUE"),
        ("method=", "takes 'all' or KEY=VALUE"),
        ("team=3", "unknown key 'team'"),
        ("episode=-1", "episode must be a non-negative integer"),
        ("robots=x", "robots must be a non-negative integer"),
        ("episode=1,episode=2", "episode is given twice"),
    ):
        with pytest.raises(ConfigError, match=message):
            parse_selector(text)
    root = Path("out")
    assert (
        record_path(root, "greedy", "bormann_lab_c_rooms1", 3, 0)
        == root / "episodes/greedy/bormann_lab_c_rooms1-r3-e0.mcap"
    )
    assert record_path(root, "my/../policy", "m", 1, 2) == root / "episodes/my_.._policy/m-r1-e2.mcap"


def _rows(path: Path) -> list[str]:
    """The lines of an ``episodes.csv`` without the ``wall_s`` column (the time, which no two runs share)."""
    lines = path.read_text().splitlines()
    column = lines[0].split(",").index("wall_s")
    return [",".join(v for i, v in enumerate(line.split(",")) if i != column) for line in lines]


def test_eval_records_chosen_episodes_without_changing_a_result(tmp_path: Path, small_map: str) -> None:
    def plan(out: Path) -> EvalPlan:
        return EvalPlan(["greedy", "random"], [2], [small_map], 2, 3, 120, out)

    evaluate(plan(tmp_path / "plain"), progress=None)
    with pytest.raises(ConfigError, match="--record-mcap method=gredy matches no episode"):
        evaluate(plan(tmp_path / "typo"), progress=None, record=[parse_selector("method=gredy")])
    assert not (tmp_path / "typo").exists()
    run = tmp_path / "recorded"
    evaluate(plan(run), progress=None, record=[parse_selector("method=greedy,episode=1"), parse_selector("episode=0")])
    assert _rows(run / "episodes.csv") == _rows(tmp_path / "plain" / "episodes.csv")
    for name in ("curves.jsonl", "summary.md", "summary.json", "config.json"):
        assert (run / name).read_bytes() == (tmp_path / "plain" / name).read_bytes(), name
    files = sorted(str(p.relative_to(run)) for p in (run / "episodes").rglob("*") if p.is_file())
    assert files == [
        "episodes/greedy/bormann_lab_c_rooms1-r2-e0.mcap",
        "episodes/greedy/bormann_lab_c_rooms1-r2-e1.mcap",
        "episodes/random/bormann_lab_c_rooms1-r2-e0.mcap",
    ]
    rows = {(r.split(",")[0], r.split(",")[4]): r.split(",") for r in _rows(run / "episodes.csv")[1:]}
    header = _rows(run / "episodes.csv")[0].split(",")
    for file in files:
        got = read_mcap(run / file)
        method, index = file.split("/")[1], file.rsplit("-e", 1)[1].removesuffix(".mcap")
        row = dict(zip(header, rows[(method, index)], strict=True))
        episode = got.metadata["areasearch.episode"]
        assert (episode["method"], episode["episode"], episode["seed"]) == (method, index, row["seed"])
        _, last = got.messages["/metrics"][-1]
        assert round(last["explored_pct"], 6) == float(row["explored_pct"]) and last["step"] == 120

    # a recorded file gone: the re-run plays that episode again to record it, and writes no row
    before = (run / "episodes.csv").read_bytes()
    kept = (run / files[0]).read_bytes()
    (run / files[1]).unlink()
    evaluate(plan(run), progress=None, record=[parse_selector("method=greedy,episode=1"), parse_selector("episode=0")])
    assert (run / "episodes.csv").read_bytes() == before
    assert (run / files[0]).read_bytes() == kept and (run / files[1]).is_file()
    assert read_mcap(run / files[1]).counts["/metrics"] == 121


@pytest.mark.slow
def test_eval_records_a_learned_method_of_ones_own(tmp_path: Path, small_map: str) -> None:
    mine = Path(areasearch.__file__).parent / "policies" / "ncm"  # given by its weights: policies.json is written
    plan = EvalPlan(["mine"], [2], [small_map], 1, 3, 40, tmp_path / "run", policies={"mine": str(mine)})
    evaluate(plan, progress=None, record=[parse_selector("all")])
    (row,) = read_episodes(tmp_path / "run" / "episodes.csv")
    got = read_mcap(tmp_path / "run" / "episodes" / "mine" / f"{small_map}-r2-e0.mcap")
    assert got.metadata["areasearch.episode"]["method"] == "mine" and got.counts["/metrics"] == 41
    assert round(got.messages["/metrics"][-1][1]["explored_pct"], 6) == row["explored_pct"]
    assert json.loads((tmp_path / "run" / "policies.json").read_text())["mine"]["weights"] == str(mine)


def _snake(key: str) -> str:
    return "".join(f"_{c.lower()}" if c.isupper() else c for c in key)


def _model(cls: Any, settings: dict[str, Any]) -> Any:
    """``cls`` (a model of ``foxglove.layouts``) made from a layout's camelCase ``settings``: a TypeError
    for a setting the model does not know."""
    return cls(**{_snake(k): v for k, v in settings.items()})


def test_the_shipped_layout_shows_the_recorded_topics() -> None:
    import foxglove.layouts as fl

    layout = json.loads(LAYOUT.read_text())
    panels = layout["configById"]
    three_d = panels["3D!areasearch"]
    plots = [config for name, config in panels.items() if name.startswith("Plot!")]
    shown = set(three_d["topics"]) | {p["value"].split(".")[0] for plot in plots for p in plot["paths"]}
    assert shown == set(TOPICS)  # every topic shown, no topic a recording lacks
    fields = {"/metrics": METRICS_FIELDS, "/map_error": MAP_ERROR_FIELDS}
    for plot in plots:
        for series in plot["paths"]:
            topic, name = series["value"].split(".")
            assert name in fields[topic], series
            _model(fl.PlotSeries, series)
        _model(fl.PlotConfig, {k: v for k, v in plot.items() if k != "paths"})
    # every setting is one Foxglove's own layout models (foxglove-sdk's foxglove.layouts) know
    _model(fl.ThreeDeeConfig, {k: v for k, v in three_d.items() if k not in ("cameraState", "scene")})
    _model(fl.ThreeDeeCameraState, three_d["cameraState"])
    _model(fl.BaseRendererSceneSettings, {k: v for k, v in three_d["scene"].items() if k != "transforms"})
    _model(fl.BaseRendererTransforms, three_d["scene"]["transforms"])
    for settings in three_d["topics"].values():
        model = (
            fl.BaseRendererGridTopicSettings if "colorField" in settings else fl.BaseRendererSceneUpdateTopicSettings
        )
        _model(model, settings)
    assert {"/map", "/map/truth", "/ground_truth"} == {t for t, s in three_d["topics"].items() if "colorField" in s}

    def leaves(node: Any) -> list[str]:
        return [node] if isinstance(node, str) else leaves(node["first"]) + leaves(node["second"])

    assert sorted(leaves(layout["layout"])) == sorted(panels)
