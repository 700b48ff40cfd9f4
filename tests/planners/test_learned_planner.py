"""The learned goal planner: the DA-HGNN network behind the planner interface and in the harness."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from areasearch.envs.goal import AreaSearchEnv
from areasearch.errors import ConfigError
from areasearch.harness.evaluate import EvalPlan, evaluate, read_episodes
from areasearch.models.network import DAHGNN
from areasearch.models.network_config import NetworkConfig
from areasearch.models.weights import save_policy
from areasearch.planners import make_planner
from areasearch.planners.learned import LearnedPlanner


def test_untrained_dahgnn_plays_an_episode_through_the_harness(tmp_path: Path, small_map: str) -> None:
    evaluate(
        EvalPlan(["dahgnn-untrained", "ncm-untrained"], [2], [small_map], 1, 0, 200, tmp_path / "run"), progress=None
    )
    rows = read_episodes(tmp_path / "run" / "episodes.csv")
    assert sorted(r["method"] for r in rows) == ["dahgnn-untrained", "ncm-untrained"]
    for row in rows:
        assert 0 < row["explored_pct"] <= 100 and row["decisions"] >= 1


def test_goals_are_allowed_and_distinct_while_enough() -> None:
    env = AreaSearchEnv(map="robotathome_sarmis", num_robots=3, seed=1)
    obs, _ = env.reset(seed=1)
    planner = make_planner("dahgnn-untrained")
    planner.reset(np.random.default_rng(0))
    for _ in range(4):
        goals = planner.assign(obs)
        assert goals.shape == (3,) and goals.dtype == np.int64
        assert obs["action_mask"][np.arange(3), goals].all()
        if obs["action_mask"].any(axis=0).sum() >= 3:
            assert len(set(goals.tolist())) == 3
        obs, *_ = env.step(goals)


@pytest.mark.slow
def test_saved_weights_load_into_the_planner_and_give_the_same_goals(tmp_path: Path, small_map: str) -> None:
    torch.manual_seed(3)
    model = DAHGNN(NetworkConfig.ncm())
    save_policy(tmp_path / "policy", model)
    env = AreaSearchEnv(map=small_map, num_robots=3, seed=2)
    obs, _ = env.reset(seed=2)
    loaded = LearnedPlanner(weights=str(tmp_path / "policy"))
    from areasearch.models.dahgnn import decide

    np.testing.assert_array_equal(loaded.assign(obs), decide(model.eval(), obs)[0].numpy())


def test_bad_planner_settings_are_config_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="policy"):
        LearnedPlanner(weights=str(tmp_path / "missing"))
    with pytest.raises(ConfigError, match="preset"):
        LearnedPlanner(preset="bert")
    with pytest.raises(ConfigError, match="wings"):
        make_planner("dahgnn-untrained", wings=2)


def test_a_policy_that_is_not_shipped_names_the_command_that_trains_it(monkeypatch: pytest.MonkeyPatch) -> None:
    import areasearch.planners as planners

    monkeypatch.setattr(planners, "SHIPPED_POLICIES", (*planners.SHIPPED_POLICIES, "my-policy"))
    with pytest.raises(ConfigError, match=r"configs/my-policy\.toml"):
        make_planner("my-policy")


def test_threads_are_restored_after_a_decision(small_map: str) -> None:
    env = AreaSearchEnv(map=small_map, num_robots=2, seed=0)
    obs, _ = env.reset(seed=0)
    before = torch.get_num_threads()
    planner = LearnedPlanner(threads=1)
    planner.assign(obs)
    assert torch.get_num_threads() == before
    with pytest.raises(ConfigError, match="threads"):
        LearnedPlanner(threads=0)


@pytest.mark.slow
def test_ship_policy_copies_a_run_and_refuses_a_broken_one(tmp_path: Path, root: Path) -> None:
    import subprocess
    import sys

    script = root / "scripts" / "ship_policy.py"
    run = tmp_path / "run"
    run.mkdir()
    torch.manual_seed(0)
    save_policy(run / "policy", DAHGNN(NetworkConfig.ncm()))
    (run / "config.json").write_text('{"seed": 4}')
    (run / "checkpoint.json").write_text('{"iteration": 20, "decisions": 3000, "episodes": 80, "wall_s": 600.0}')
    header = "iteration,decisions,map,robots,seed,explored_pct,covered_pct,time_e,time_c,coverage_auc\n"
    rows = "10,1500,a,3,1,100,100,5,9,70.0\n10,1500,b,3,2,100,100,5,9,72.0\n20,3000,a,3,1,100,100,5,9,75.0\n"
    (run / "eval.csv").write_text(header + rows)
    finalist = {"validation_score": 75.0, "smoothed_score": 73.0, "final_score": 74.5, "final_ci95": 0.5}
    selection = {
        "rule": "top 3 by the smoothed score",
        "episodes": 50,
        "chosen_decisions": 3000,
        "finalists": [{"decisions": 3000, **finalist, "minus_chosen": 0.0, "minus_chosen_ci95": 0.0}],
    }
    (run / "selection.json").write_text(json.dumps(selection))
    perf = "iteration,decisions,perf/decisions_per_s,perf/rollout_s,perf/update_s\n"
    (run / "progress.csv").write_text(perf + "1,150,30.0,4.0,1.0\n2,300,40.0,2.0,1.0\n3,450,10.0,9.0,6.0\n")
    into = tmp_path / "policies"
    variant = ["--config", "configs/variants/ncm-120k.toml"]
    done = subprocess.run(
        [sys.executable, str(script), str(run), "ncm", "--into", str(into), "--why", "the median of 3 seeds", *variant],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr
    card = (into / "ncm.md").read_text()
    assert "Why this run: the median of 3 seeds" in card
    assert "75.00 (iteration 20, 3,000 decisions)" in card and "71.00 (iteration 10)" in card
    assert "--config configs/variants/ncm-120k.toml --set seed=4 --out runs/run" in card
    assert "| 3,000 | 75.00 | 73.00 | 74.50 ± 0.50 | +0.00 ± 0.00 |" in card
    assert "| wall time | 10.0 min (iterations 4 %; validations, checkpoints and the rest 96 %) |" in card
    assert "| training speed | 30.0 decisions/s (median over its iterations) |" in card
    loaded = LearnedPlanner(weights=str(into / "ncm"))
    assert loaded.name == "dahgnn"  # a LearnedPlanner's default report name; the registry names it
    # a truncated weights file is refused, with one line and nothing written
    (run / "policy.safetensors").write_bytes((run / "policy.safetensors").read_bytes()[:100])
    before = (into / "ncm.safetensors").read_bytes()
    bad = subprocess.run(
        [sys.executable, str(script), str(run), "ncm", "--into", str(into)], capture_output=True, text=True
    )
    assert bad.returncode == 2 and "Traceback" not in bad.stderr and "ship_policy: error" in bad.stderr
    assert (into / "ncm.safetensors").read_bytes() == before
    unknown = subprocess.run(
        [sys.executable, str(script), str(run), "bert", "--into", str(into)], capture_output=True, text=True
    )
    assert unknown.returncode == 2 and "bert" in unknown.stderr
    # a published copy of a run (no checkpoint): the counters from the last row of its progress.csv
    save_policy(run / "policy", DAHGNN(NetworkConfig.ncm()))
    (run / "checkpoint.json").unlink()
    progress = "iteration,decisions,episodes,wall_s,perf/decisions_per_s,perf/rollout_s,perf/update_s\n"
    (run / "progress.csv").write_text(progress + "1,150,4,5.0,30.0,4.0,1.0\n2,300,8,1200.0,40.0,2.0,1.0\n")
    command = [sys.executable, str(script), str(run), "ncm", "--into", str(into)]
    assert subprocess.run(command, capture_output=True, text=True).returncode == 0
    card = (into / "ncm.md").read_text()
    assert "| iterations | 2 |" in card and "| decisions | 300 |" in card and "| episodes | 8 |" in card
    assert "| wall time | 20.0 min (iterations 1 %; validations, checkpoints and the rest 99 %) |" in card
    (run / "progress.csv").unlink()
    gone = subprocess.run(command, capture_output=True, text=True)
    assert gone.returncode == 2 and "no checkpoint.json and no progress.csv rows" in gone.stderr, gone.stderr


SHIPPED_KINDS = {  # (type_aware, history, rounds) of each policy that ships with the package
    "dahgnn": (True, True, 6),
    "ncm": (False, True, 3),
    "dahgnn-no-type": (False, True, 6),
    "dahgnn-no-history": (True, False, 6),
}


@pytest.mark.parametrize("name", ["dahgnn", "ncm", "dahgnn-no-type", "dahgnn-no-history"])
def test_a_shipped_policy_is_registered_and_plays(name: str, small_map: str) -> None:
    from areasearch.planners import PLANNERS, shipped_policy

    assert name in PLANNERS  # src/areasearch/policies/<name>.* ship with the package
    planner = make_planner(name)
    assert planner.name == name
    cfg = planner._model.config  # type: ignore[attr-defined]
    assert (cfg.type_aware, cfg.history, cfg.rounds) == SHIPPED_KINDS[name]  # the right network, not another
    assert shipped_policy(name).with_suffix(".md").is_file()  # its card
    env = AreaSearchEnv(map=small_map, num_robots=3, seed=5)
    obs, _ = env.reset(seed=5)
    planner.reset(np.random.default_rng(0))
    goals = planner.assign(obs)
    assert obs["action_mask"][np.arange(3), goals].all()
