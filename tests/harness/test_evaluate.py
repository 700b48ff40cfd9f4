"""Tests of the evaluation harness (:mod:`areasearch.harness.evaluate`) and ``areasearch eval``: resumable,
paired seeds, worker-count independent, atomic rows, bad input refused before anything is written."""

from __future__ import annotations

import csv
import json
import re
import shutil
import subprocess
from collections.abc import Callable
from pathlib import Path

import pytest

from areasearch.errors import AreaSearchError, ConfigError, MapError
from areasearch.harness.evaluate import (
    CSV_FIELDS,
    EvalPlan,
    episode_seed,
    evaluate,
    pick_evenly,
    read_curves,
    read_episodes,
    resolve_maps,
)
from areasearch.sim.scene import bundled_index, bundled_maps_dir

CliRunner = Callable[..., subprocess.CompletedProcess[str]]

MAP = "bormann_lab_c_rooms1"
RUN = {
    "methods": ["greedy", "random"],
    "robots": [2],
    "maps": [MAP],
    "episodes": 2,
    "seed": 7,
    "max_steps": 200,
}


def _run(out: Path, settings: dict[str, object] | None = None, **changes: object) -> None:
    plan = EvalPlan(**{**RUN, **changes}, out=out)  # type: ignore[arg-type]
    evaluate(plan.with_settings(settings), progress=None)


def _lines(out: Path) -> list[str]:
    return (out / "episodes.csv").read_text().splitlines()


def _without_wall(row: dict) -> dict:
    return {k: v for k, v in row.items() if k != "wall_s"}


@pytest.fixture(scope="module")
def first_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("eval") / "run"
    _run(out)
    return out


def test_a_tiny_run_writes_one_row_per_episode_and_the_summaries(first_run: Path) -> None:
    rows = read_episodes(first_run / "episodes.csv")
    assert len(rows) == 4
    assert _lines(first_run)[0] == ",".join(CSV_FIELDS)
    assert {(r["method"], r["episode"]) for r in rows} == {(m, k) for m in ("greedy", "random") for k in (0, 1)}
    for r in rows:
        assert r["map"] == MAP and r["size_class"] == "small" and r["robots"] == 2
        assert 0.0 < r["explored_pct"] <= 100.0 and 0.0 <= r["covered_pct"] <= 100.0
        assert r["decisions"] == 5  # 200 steps / 40 per decision (no episode finishes this early)
        assert r["time_e"] == 200 or r["reached_e"]
    curves = read_curves(first_run / "curves.jsonl")
    assert len(curves) == 4
    for c in curves.values():
        assert c["steps"] == [0, 40, 80, 120, 160, 200]
        assert len(c["explored_pct"]) == len(c["covered_pct"]) == 6
    summary = json.loads((first_run / "summary.json").read_text())
    assert [row["method"] for row in summary["tables"][0]["rows"]] == ["greedy", "random"]
    assert all(row["episodes"] == 2 for row in summary["tables"][0]["rows"])
    for name in ("summary.md", "summary.tex", "curves.png", "config.json"):
        assert (first_run / name).stat().st_size > 0
    assert not list(first_run.glob(".*tmp"))


def test_paired_seeds_depend_on_map_team_and_index_not_method(first_run: Path) -> None:
    rows = read_episodes(first_run / "episodes.csv")
    for k in (0, 1):
        seeds = {r["seed"] for r in rows if r["episode"] == k}
        assert seeds == {episode_seed(7, MAP, 2, k)}
    assert episode_seed(7, MAP, 2, 0) != episode_seed(7, MAP, 2, 1)
    assert episode_seed(7, MAP, 2, 0) != episode_seed(7, MAP, 3, 0)
    assert episode_seed(7, MAP, 2, 0) != episode_seed(8, MAP, 2, 0)
    assert episode_seed(7, MAP, 2, 0) != episode_seed(7, "robotathome_sarmis", 2, 0)
    # the same episode sees the same world: identical explored % at step 0 for both methods
    curves = read_curves(first_run / "curves.jsonl")
    for k in (0, 1):
        starts = {c["explored_pct"][0] for c in curves.values() if c["episode"] == k}
        assert len(starts) == 1


def test_rerunning_resumes_and_recomputes_only_a_missing_row(first_run: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    shutil.copytree(first_run, out)
    before = (out / "episodes.csv").read_bytes()
    _run(out)
    assert (out / "episodes.csv").read_bytes() == before  # nothing re-run: wall_s unchanged too
    lines = _lines(out)
    removed = lines.pop(2)
    (out / "episodes.csv").write_text("\n".join(lines) + "\n")
    _run(out)
    after = _lines(out)
    assert len(after) == 5
    assert after[:4] == lines  # the others untouched
    original = next(csv.DictReader([lines[0], removed]))
    redone = next(csv.DictReader([lines[0], after[4]]))
    assert _without_wall(redone) == _without_wall(original)


def test_a_truncated_last_line_is_repaired(first_run: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    shutil.copytree(first_run, out)
    lines = _lines(out)
    partial = lines[-1][: len(lines[-1]) // 2]
    (out / "episodes.csv").write_text("\n".join(lines[:-1]) + "\n" + partial)  # a write cut short
    with open(out / "curves.jsonl", "a") as f:
        f.write('{"method":"gre')
    _run(out)
    text = (out / "episodes.csv").read_text()
    assert text.endswith("\n")
    assert partial + "\n" not in text
    rows = read_episodes(out / "episodes.csv")
    assert len(rows) == 4
    assert [_without_wall(r) for r in rows] == [_without_wall(r) for r in read_episodes(first_run / "episodes.csv")]
    assert len(read_curves(out / "curves.jsonl")) == 4


@pytest.mark.slow
def test_two_workers_give_the_same_rows_as_one(first_run: Path, tmp_path: Path) -> None:
    out = tmp_path / "run2"
    _run(out, workers=2)
    one = [_without_wall(r) for r in read_episodes(first_run / "episodes.csv")]
    two = [_without_wall(r) for r in read_episodes(out / "episodes.csv")]
    assert two == one  # same numbers and the same (plan) order
    assert read_curves(out / "curves.jsonl") == read_curves(first_run / "curves.jsonl")


@pytest.mark.slow
def test_the_ray_backend_writes_the_same_files_as_the_local_one(first_run: Path, tmp_path: Path) -> None:
    """Episodes as Ray tasks on a local 2-CPU Ray instance (started and shut down by the harness)."""
    import ray

    out = tmp_path / "run-ray"
    _run(out, backend="ray", workers=2)
    assert not ray.is_initialized()
    local = [_without_wall(r) for r in read_episodes(first_run / "episodes.csv")]
    assert [_without_wall(r) for r in read_episodes(out / "episodes.csv")] == local
    assert (out / "curves.jsonl").read_bytes() == (first_run / "curves.jsonl").read_bytes()
    assert (out / "summary.json").read_bytes() == (first_run / "summary.json").read_bytes()


def test_resuming_with_other_settings_is_refused(first_run: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    shutil.copytree(first_run, out)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    with pytest.raises(AreaSearchError, match="max_steps"):
        _run(out, max_steps=240)
    with pytest.raises(AreaSearchError, match="seed"):
        _run(out, seed=8)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_resuming_with_other_world_settings_is_refused(first_run: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    shutil.copytree(first_run, out)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    with pytest.raises(AreaSearchError, match=r"other settings \(settings, config differ\)"):
        _run(out, settings={"targets.count": 50})
    with pytest.raises(AreaSearchError, match=r"other settings \(settings differ\)"):
        _run(out, settings={"world.targets.count": 100})  # the default, but given: not the same command
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


def test_world_settings_are_checked_before_anything_is_written(tmp_path: Path) -> None:
    out = tmp_path / "run"
    for settings, message in (
        ({"robot.wheels": 4}, "unknown setting 'robot.wheels'"),
        ({"targets.count": -1}, "targets.count must be an integer >= 0"),
        ({"num_robots": 2}, "world.num_robots is set by the robots argument"),
        ({"world.max_steps": 2}, "world.max_steps is set by the max_steps argument"),
    ):
        with pytest.raises(ConfigError, match=re.escape(message)):
            _run(out, settings=settings)
    for changes, message in (({"robots": [0]}, "robots must be from 1 to 8"), ({"episodes": 0}, "episodes must be")):
        with pytest.raises(ConfigError, match=message):
            _run(out, **changes)
    assert not out.exists()


@pytest.mark.slow
def test_world_settings_reach_every_episode_in_worker_processes_and_ray_tasks(tmp_path: Path) -> None:
    """The settings travel with each episode: a decision every 20 steps in 40 gives 2 decisions."""
    settings = {"decisions.period_steps": 20, "targets.count": 10}
    rows = {}
    for backend in ("local", "ray"):
        out = tmp_path / backend
        _run(out, methods=["greedy"], max_steps=40, workers=2, backend=backend, settings=settings)
        rows[backend] = [_without_wall(r) for r in read_episodes(out / "episodes.csv")]
        assert [r["decisions"] for r in rows[backend]] == [2, 2]
        config = json.loads((out / "config.json").read_text())
        assert config["settings"] == {"decisions.period_steps": 20, "world.targets.count": 10}
        assert config["config"]["decisions"]["period_steps"] == 20
        assert config["config"]["world"]["targets"]["count"] == 10
    assert rows["ray"] == rows["local"]


def test_pick_evenly_takes_slice_centres() -> None:
    assert pick_evenly(list(range(10)), 3) == [1, 5, 8]
    assert pick_evenly(list(range(10)), 1) == [5]
    assert pick_evenly([1, 2], 5) == [1, 2]


def test_resolve_maps_filters_and_picks_per_size_class() -> None:
    chosen = resolve_maps(["bundled"], sizes=["small", "large"], per_size=2)
    assert [e.size_class for e in chosen] == ["small", "small", "large", "large"]
    small = sorted(e["id"] for e in bundled_index() if e["size_class"] == "small")
    assert [e.id for e in chosen[:2]] == pick_evenly(small, 2)
    assert resolve_maps(["bundled"], sizes=["small", "large"], per_size=2) == chosen


def test_resolve_maps_reads_a_map_folder(tmp_path: Path) -> None:
    entry = next(e for e in bundled_index() if e["id"] == MAP)
    shutil.copy(bundled_maps_dir() / entry["file"], tmp_path / entry["file"])
    (tmp_path / "index.json").write_text(json.dumps({"maps": [entry]}))
    (found,) = resolve_maps([str(tmp_path)])
    assert (found.id, found.size_class) == (MAP, "small")
    assert found.spec == str(tmp_path / entry["file"])
    (tmp_path / "index.json").write_text(json.dumps({"maps": []}))
    with pytest.raises(MapError):
        resolve_maps([str(tmp_path)])


# ---------------------------------------------------------------------------------- CLI bad input


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--methods", "greedy", "teleport"], "unknown method(s) teleport"),
        (["--methods", "greedy", "--robots", "0"], "argument --robots: expected a positive integer, got 0"),
        (["--methods", "greedy", "--robots", "3", "9"], "argument --robots: at most 8 robots, got 9"),
        (["--methods", "greedy", "--episodes", "0"], "argument --episodes: expected a positive integer, got 0"),
        (["--methods", "greedy", "--maps", "EMPTY"], "lists no map file"),
        (["--methods", "greedy", "--maps", "NOINDEX"], "no index.json"),
        (["--methods", "greedy", "--set", "targets.count"], "--set 'targets.count': expected KEY=VALUE"),
    ],
)
def test_eval_bad_input_is_one_error_line_and_the_out_folder_is_untouched(
    tmp_path: Path, args: list[str], message: str, run_cli: CliRunner
) -> None:
    """One error line (after argparse's usage line for a malformed option), the folder untouched."""
    out = tmp_path / "results"
    out.mkdir()
    (out / "notes.txt").write_text("keep me\n")
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "index.json").write_text('{"maps": []}')
    (tmp_path / "noindex").mkdir()
    args = [{"EMPTY": str(tmp_path / "empty"), "NOINDEX": str(tmp_path / "noindex")}.get(a, a) for a in args]
    if "--maps" not in args:
        args += ["--maps", MAP]
    result = run_cli("eval", *args, "--max-steps", "200", "--out", str(out))
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    lines = result.stderr.splitlines()
    if message.startswith("argument "):
        assert lines[0].startswith("usage: areasearch eval") and lines[-1].startswith("areasearch: error: ")
    else:
        assert len(lines) == 1 and lines[0].startswith("areasearch: error: "), result.stderr
    assert message in lines[-1]
    assert _snapshot(out) == {"notes.txt": b"keep me\n"}


def test_eval_refuses_an_existing_file_as_out(tmp_path: Path, run_cli: CliRunner) -> None:
    out = tmp_path / "results.csv"
    out.write_text("precious\n")
    result = run_cli("eval", "--methods", "greedy", "--maps", MAP, "--out", str(out))
    assert result.returncode == 2
    assert result.stderr.splitlines() == [f"areasearch: error: {out}: output path is an existing file; give a folder"]
    assert out.read_text() == "precious\n"


def test_a_policy_of_ones_own_is_evaluated_by_name_and_its_weights_are_pinned(tmp_path: Path) -> None:
    """``--policy NAME=PREFIX``: a trained run's policy plays as method NAME, paired with the others;
    a resume with other weights under that name, a name that shadows a planner, or a name missing
    from --methods is refused before anything is written."""
    import torch

    from areasearch.models.network import DAHGNN
    from areasearch.models.network_config import NetworkConfig
    from areasearch.models.weights import save_policy
    from areasearch.planners.learned import LearnedPlanner

    config = NetworkConfig.ncm(rounds=1)
    for seed, name in ((0, "a"), (1, "b")):
        torch.manual_seed(seed)
        save_policy(tmp_path / name, DAHGNN(config))
    out = tmp_path / "run"
    mine = {"methods": ["greedy", "mine"], "episodes": 1, "policies": {"mine": str(tmp_path / "a")}}
    _run(out, **mine)
    rows = read_episodes(out / "episodes.csv")
    assert sorted(r["method"] for r in rows) == ["greedy", "mine"]
    assert json.loads((out / "policies.json").read_text())["mine"]["weights"] == str(tmp_path / "a")
    # the same numbers as the learned planner built by hand from those weights
    from areasearch.harness.evaluate import make_env, play_episode

    row = next(r for r in rows if r["method"] == "mine")
    env = make_env(MAP, 2, int(row["seed"]), RUN["max_steps"])  # type: ignore[arg-type]
    trace = play_episode(env, LearnedPlanner(weights=str(tmp_path / "a"), name="mine"), int(row["seed"]))
    assert float(row["covered_pct"]) == pytest.approx(trace.info["covered_pct"], abs=1e-6)
    with pytest.raises(AreaSearchError, match="other weights"):
        _run(out, **{**mine, "policies": {"mine": str(tmp_path / "b")}})
    with pytest.raises(ConfigError, match="registered planner"):
        _run(tmp_path / "x", methods=["greedy"], policies={"greedy": str(tmp_path / "a")})
    with pytest.raises(ConfigError, match="add other to --methods"):
        _run(tmp_path / "y", methods=["greedy"], policies={"other": str(tmp_path / "a")})
    with pytest.raises(ConfigError, match="cannot read the policy config"):
        _run(tmp_path / "z", methods=["greedy", "gone"], policies={"gone": str(tmp_path / "missing")})
    assert not (tmp_path / "x").exists() and not (tmp_path / "y").exists() and not (tmp_path / "z").exists()


def test_a_method_whose_weights_changed_is_refused_or_played_again_and_its_old_episodes_set_aside(
    tmp_path: Path,
) -> None:
    """A method with weights whose episodes were played with other weights (or weights the folder has no
    record of) is refused on resume; ``replace`` moves its rows, curves and weights entry to
    ``replaced/N/`` and plays it again, the other methods' episodes untouched; a second run of the same
    plan plays nothing (the record now holds the new weights)."""
    import torch

    from areasearch.models.network import DAHGNN
    from areasearch.models.network_config import NetworkConfig
    from areasearch.models.weights import save_policy

    config = NetworkConfig.ncm(rounds=1)
    for seed, name in ((0, "a"), (1, "b")):
        torch.manual_seed(seed)
        save_policy(tmp_path / name, DAHGNN(config))
    out, fresh = tmp_path / "run", tmp_path / "fresh"
    mine = {"methods": ["greedy", "mine"], "episodes": 1}
    _run(out, **mine, policies={"mine": str(tmp_path / "a")})
    before = {name: (out / name).read_text() for name in ("episodes.csv", "curves.jsonl", "policies.json")}
    with pytest.raises(AreaSearchError, match="--replace mine"):
        _run(out, **mine, policies={"mine": str(tmp_path / "b")})
    (out / "episodes" / "mine").mkdir(parents=True)  # as --record-mcap leaves an episode recorded
    (out / "episodes" / "mine" / "old.mcap").write_bytes(b"old episode")
    _run(out, **mine, policies={"mine": str(tmp_path / "b")}, replace=["mine"])
    assert (out / "replaced" / "1" / "episodes" / "mine" / "old.mcap").read_bytes() == b"old episode"
    assert not (out / "episodes" / "mine").exists()
    _run(fresh, **mine, policies={"mine": str(tmp_path / "b")})
    assert sorted(map(_without_wall, read_episodes(out / "episodes.csv")), key=str) == sorted(
        map(_without_wall, read_episodes(fresh / "episodes.csv")), key=str
    )  # greedy's episode kept, mine's played again with b: the rows of a fresh run with b
    assert read_curves(out / "curves.jsonl") == read_curves(fresh / "curves.jsonl")
    assert json.loads((out / "policies.json").read_text())["mine"]["weights"] == str(tmp_path / "b")
    aside = out / "replaced" / "1"
    old = tmp_path / "old"
    old.mkdir()
    for name, text in before.items():
        (old / name).write_text(text)
    assert read_episodes(aside / "episodes.csv") == [
        r for r in read_episodes(old / "episodes.csv") if r["method"] == "mine"
    ]
    assert read_curves(aside / "curves.jsonl") == {
        k: c for k, c in read_curves(old / "curves.jsonl").items() if k[0] == "mine"
    }
    assert json.loads((aside / "policies.json").read_text()) == {"mine": json.loads(before["policies.json"])["mine"]}
    now = [_without_wall(r) for r in read_episodes(out / "episodes.csv")]
    _run(out, **mine, policies={"mine": str(tmp_path / "b")}, replace=["mine"])  # the same command again
    assert [_without_wall(r) for r in read_episodes(out / "episodes.csv")] == now
    assert not (out / "replaced" / "2").exists()
    # no record of the weights that played a method's episodes (a folder written before they were kept)
    (out / "policies.json").unlink()
    with pytest.raises(AreaSearchError, match="no record of the weights"):
        _run(out, **mine, policies={"mine": str(tmp_path / "b")})
    _run(out, **mine, policies={"mine": str(tmp_path / "b")}, replace=["mine"])
    assert [_without_wall(r) for r in read_episodes(out / "episodes.csv")] == now  # the same weights: the same episode
    assert json.loads((out / "replaced" / "2" / "policies.json").read_text()) == {}


def test_a_shipped_policys_weights_are_recorded_so_that_a_policy_shipped_again_does_not_resume_the_old(
    tmp_path: Path,
) -> None:
    from areasearch.planners import shipped_policy
    from areasearch.planners.learned import weights_sha256

    out = tmp_path / "run"
    shipped = {"methods": ["greedy", "dahgnn"], "max_steps": 80}
    _run(out, **shipped, episodes=1)
    record = json.loads((out / "policies.json").read_text())
    assert record == {
        "dahgnn": {"weights": "areasearch/policies/dahgnn", "sha256": weights_sha256(shipped_policy("dahgnn"))}
    }
    _run(out, **shipped, episodes=2)  # the same weights: resumed
    record["dahgnn"]["sha256"] = "0" * 64  # as if played by the policy shipped before
    (out / "policies.json").write_text(json.dumps(record))
    with pytest.raises(AreaSearchError, match=r"dahgnn was evaluated with other weights .*--replace dahgnn"):
        _run(out, **shipped, episodes=2)
    _run(out, **shipped, episodes=2, replace=["dahgnn"])
    assert len(read_episodes(out / "replaced" / "1" / "episodes.csv")) == 2  # both of its episodes played again
    assert sorted(r["method"] for r in read_episodes(out / "episodes.csv")) == ["dahgnn", "dahgnn", "greedy", "greedy"]
    with pytest.raises(ConfigError, match="only a method with weights"):
        _run(out, **shipped, replace=["greedy"], episodes=2)


def test_a_plan_records_its_settings_as_given_and_refuses_a_config_that_is_not_them(tmp_path: Path) -> None:
    from areasearch.config import search_config
    from areasearch.harness.evaluate import run_config

    plan = EvalPlan(**RUN, out=tmp_path / "run").with_settings({"protocol": "passby", "targets.count": 50})  # type: ignore[arg-type]
    assert plan.settings == (("world.protocol", "passby"), ("world.targets.count", 50))
    assert plan.config == search_config({"world.protocol": "passby", "world.targets.count": 50})
    assert run_config(plan)["settings"] == {"world.protocol": "passby", "world.targets.count": 50}
    with pytest.raises(ConfigError, match=re.escape("world.num_robots is set by the robots argument")):
        plan.with_settings({"num_robots": 2})
    with pytest.raises(ConfigError, match="not its settings applied"):
        run_config(EvalPlan(**RUN, out=tmp_path / "run", config=plan.config))  # type: ignore[arg-type]


def test_a_record_holds_the_noise_detection_and_comm_groups_only_when_they_are_set(tmp_path: Path) -> None:
    from areasearch.harness.evaluate import run_config

    world = run_config(EvalPlan(**RUN, out=tmp_path / "run"))["config"]["world"]  # type: ignore[arg-type]
    assert "noise" not in world and "detection" not in world and "comm" not in world
    noisy = EvalPlan(**RUN, out=tmp_path / "run").with_settings({"noise.dropout": 0.1})  # type: ignore[arg-type]
    world = run_config(noisy)["config"]["world"]
    assert world["noise"]["dropout"] == 0.1 and "detection" not in world and "comm" not in world
    linked = EvalPlan(**RUN, out=tmp_path / "run").with_settings({"comm.model": "disc", "comm.range_m": 5})  # type: ignore[arg-type]
    world = run_config(linked)["config"]["world"]
    assert world["comm"]["model"] == "disc" and world["comm"]["range_m"] == 5.0 and "noise" not in world


def test_a_record_holds_the_distance_cell_only_when_it_is_set(tmp_path: Path) -> None:
    from areasearch.harness.evaluate import run_config

    candidates = run_config(EvalPlan(**RUN, out=tmp_path / "run"))["config"]["candidates"]  # type: ignore[arg-type]
    assert "distance_cell_m" not in candidates and candidates["max_candidates"] == 256
    coarse = EvalPlan(**RUN, out=tmp_path / "run").with_settings({"candidates.distance_cell_m": 0.1})  # type: ignore[arg-type]
    assert run_config(coarse)["config"]["candidates"]["distance_cell_m"] == 0.1
