"""PPO training: config files, splits, GAE, checkpoints with exact resume, the command line."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from areasearch.errors import ConfigError, MapError
from areasearch.sim.splits import SPLITS, propose_splits, split_maps, split_table
from areasearch.training.train import (
    EpisodeSpec,
    Trajectory,
    config_to_dict,
    coverage_auc,
    expand_maps,
    gae,
    iteration_episodes,
    load_config,
    train,
)

TINY = """
seed = 3
total_decisions = 12
[network]
rounds = 1
node_dim = 16
history_dim = 16
[rollout]
maps = ["procedural:small"]
robots = [2, 3]
episodes = 2
max_steps = 120
[evaluation]
maps = ["wrs2020_arena"]
robots = [2]
every = 2
max_steps = 80
[ppo]
minibatch_size = 4
epochs = 2
"""

# columns that do not depend on timing
STABLE = ("iteration", "decisions", "episodes", "charts/episodic_return", "charts/covered_pct", "losses/policy_loss",
          "losses/value_loss", "losses/entropy", "losses/aux_loss", "losses/approx_kl", "losses/grad_norm")  # fmt: skip


def _config(tmp_path: Path, text: str = TINY, name: str = "tiny.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def _stable_rows(run: Path) -> list[dict[str, str]]:
    with open(run / "progress.csv", newline="") as f:
        return [{k: row[k] for k in STABLE} for row in csv.DictReader(f)]


def _eval_rows(run: Path) -> list[dict[str, str]]:
    with open(run / "eval.csv", newline="") as f:
        return list(csv.DictReader(f))


# ---------------------------------------------------------------------------------------------- config


def test_shipped_configs_load(root: Path) -> None:
    configs = sorted(root.glob("configs/*.toml"))
    assert configs, "no training configs in configs/"
    for path in configs:
        config = load_config(path)
        assert config.rollout.maps and config.total_decisions > 0
        assert not any(m.startswith("bundled:test") for m in config.rollout.maps + config.evaluation.maps)


def test_config_errors_name_the_setting(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"unknown setting ppo\.learning_rat"):
        load_config(_config(tmp_path, "[ppo]\nlearning_rat = 1e-3\n"))
    with pytest.raises(ConfigError, match=r"ppo\.epochs must be an integer"):
        load_config(_config(tmp_path, "[ppo]\nepochs = 1.5\n"))
    with pytest.raises(ConfigError, match=r"ppo\.gamma must be in \[0, 1\]"):
        load_config(_config(tmp_path, "[ppo]\ngamma = 1.5\n"))
    with pytest.raises(ConfigError, match=r"network\.preset"):
        load_config(_config(tmp_path, '[network]\npreset = "gnn"\n'))
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(_config(tmp_path, "[ppo\n"))
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(tmp_path / "missing.toml")


def test_config_presets_and_overrides(tmp_path: Path) -> None:
    ncm = load_config(_config(tmp_path, '[network]\npreset = "ncm"\n'))
    assert not ncm.network.type_aware and ncm.network.rounds == 3
    cfg = load_config(_config(tmp_path), {"ppo.learning_rate": 1e-3, "rollout.robots": [4]})
    assert cfg.ppo.learning_rate == 1e-3 and cfg.rollout.robots == (4,)
    # the resolved config reads back to the same config
    resolved = tmp_path / "config.json"
    resolved.write_text(json.dumps(config_to_dict(cfg)))
    assert load_config(resolved) == cfg


# ---------------------------------------------------------------------------------------------- splits


def test_splits_file_matches_the_rule_and_keeps_groups_whole() -> None:
    from areasearch.sim.scene import bundled_index
    from areasearch.sim.splits import _groups

    assert _groups() == propose_splits()
    index = bundled_index()
    seen: dict[str, str] = {}
    for split in SPLITS:
        for map_id in split_maps(split):
            group = next(e["group"] for e in index if e["id"] == map_id)
            assert seen.setdefault(group, split) == split, f"group {group} in two splits"
    assert sum(len(split_maps(s)) for s in SPLITS) == len(index)
    for split, sizes in split_table().items():
        assert all(n > 0 for n in sizes.values()), f"{split} lacks a size class: {sizes}"


def test_training_maps_never_include_test_maps() -> None:
    train_maps = set(expand_maps(["bundled:train"]))
    assert train_maps and not train_maps & set(split_maps("test")) and not train_maps & set(split_maps("val"))
    with pytest.raises(MapError, match="name a split"):
        expand_maps(["bundled"])
    with pytest.raises(MapError, match="unknown split"):
        expand_maps(["bundled:holdout"])


def test_iteration_episodes_depend_on_seed_and_iteration_only(tmp_path: Path) -> None:
    cfg = load_config(_config(tmp_path))
    maps = expand_maps(cfg.rollout.maps)
    assert iteration_episodes(cfg, maps, 5) == iteration_episodes(cfg, maps, 5)
    assert iteration_episodes(cfg, maps, 5) != iteration_episodes(cfg, maps, 6)


# ---------------------------------------------------------------------------------------------- GAE, AUC


def test_gae_by_hand(hand_trajectory: Callable[..., Trajectory]) -> None:
    gamma, lam = 0.9, 0.5
    spec, steps, covered = EpisodeSpec("procedural:small", 2, 0, 80), [0, 40, 80], [0.0, 0.0, 0.0]
    # terminated: no bootstrap after the last decision
    adv, ret = gae(hand_trajectory([1.0, 2.0], [0.5, 1.0], True, 7.0, spec, steps, covered), gamma, lam, 1.0)
    d1 = 2.0 - 1.0
    d0 = 1.0 + gamma * 1.0 - 0.5
    assert adv == pytest.approx([d0 + gamma * lam * d1, d1])
    assert ret == pytest.approx([d0 + gamma * lam * d1 + 0.5, d1 + 1.0])
    # truncated at the horizon: the end of the mission, nothing bootstraps; rewards are scaled
    adv, _ = gae(hand_trajectory([1.0], [0.5], False, 2.0, spec, steps, covered), gamma, lam, 0.5)
    assert adv == pytest.approx([0.5 - 0.5])


def test_coverage_auc_by_hand() -> None:
    # 0 % for 40 steps, 50 % for 40 steps, 100 % for the last 20 of a 100-step horizon
    assert coverage_auc([0, 40, 80], [0.0, 50.0, 100.0], 100) == pytest.approx((50 * 40 + 100 * 20) / 100)
    assert coverage_auc([0, 100], [0.0, 100.0], 100) == 0.0


# ---------------------------------------------------------------------------------------------- runs


@pytest.mark.slow
def test_train_resume_equals_uninterrupted_run(tmp_path: Path) -> None:
    from areasearch.planners.learned import LearnedPlanner

    cfg = load_config(_config(tmp_path))
    whole = train(cfg, tmp_path / "whole", workers=0, log=None, progress=None)
    assert whole.decisions >= cfg.total_decisions
    for name in ("config.json", "checkpoint.json", "policy.json", "policy.safetensors", "final.json", "curve.png"):
        assert (tmp_path / "whole" / name).exists(), name
    assert len(list((tmp_path / "whole").glob("checkpoint-*.safetensors"))) == 1
    LearnedPlanner(weights=str(tmp_path / "whole" / "policy"))  # the best policy loads as a planner

    part = train(cfg, tmp_path / "part", workers=0, log=None, progress=None, iterations=1)
    assert part.iterations == 1
    with pytest.raises(ConfigError, match="pass --resume"):
        train(cfg, tmp_path / "part", workers=0, log=None, progress=None)
    other = load_config(_config(tmp_path), {"seed": 4})
    with pytest.raises(ConfigError, match="another config"):
        train(other, tmp_path / "part", resume=True, workers=0, log=None, progress=None)
    # a checkpoint of a trainer whose Adam stepped tensor by tensor (foreach unset) resumes with the same numbers
    meta = tmp_path / "part" / "checkpoint.json"
    doc = json.loads(meta.read_text())
    assert [g["foreach"] for g in doc["param_groups"]] == [True]
    meta.write_text(json.dumps({**doc, "param_groups": [{**g, "foreach": None} for g in doc["param_groups"]]}))
    rest = train(cfg, tmp_path / "part", resume=True, workers=0, log=None, progress=None)
    assert rest.iterations == whole.iterations
    assert _stable_rows(tmp_path / "part") == _stable_rows(tmp_path / "whole")
    drop = ("iteration", "decisions")
    assert [{k: v for k, v in r.items() if k not in drop} for r in _eval_rows(tmp_path / "part")] == [
        {k: v for k, v in r.items() if k not in drop} for r in _eval_rows(tmp_path / "whole")
    ]
    a = (tmp_path / "whole" / "final.safetensors").read_bytes()
    assert a == (tmp_path / "part" / "final.safetensors").read_bytes()
    # the final selection: the same finalists, scores and choice after a resume; policy = the chosen snapshot
    chosen = json.loads((tmp_path / "whole" / "selection.json").read_text())
    assert chosen == json.loads((tmp_path / "part" / "selection.json").read_text())
    assert 1 <= len(chosen["finalists"]) <= 3 and chosen["episodes"] == 5
    snapshot = tmp_path / "whole" / "snapshots" / f"dec-{chosen['chosen_decisions']:09d}.safetensors"
    assert (tmp_path / "whole" / "policy.safetensors").read_bytes() == snapshot.read_bytes()
    best = max(chosen["finalists"], key=lambda f: f["final_score"])
    assert best["decisions"] == chosen["chosen_decisions"] and best["minus_chosen"] == 0.0
    # the network's health is logged every iteration, finite
    with open(tmp_path / "whole" / "progress.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    health = [k for k in rows[0] if k.startswith("health/")]
    assert "health/round0_score_spread" in health and "health/grad_norm_round0" in health
    assert all(np.isfinite(float(row[k])) for row in rows for k in health)


@pytest.mark.slow
def test_ray_backend_trains_like_the_local_learner(tmp_path: Path) -> None:
    """Rollouts and the update's shards (``ppo.shards = 2``, the graphs in Ray's object store) as Ray
    tasks on a local 2-CPU Ray instance (started and shut down by train): the same iterations, losses
    and weights as rollouts and shards in the learner's process."""
    import ray

    cfg = load_config(_config(tmp_path, TINY.replace("epochs = 2\n", "epochs = 2\nshards = 2\n")))
    assert cfg.ppo.shards == 2
    local = train(cfg, tmp_path / "local", workers=0, log=None, progress=None, iterations=2)
    remote = train(cfg, tmp_path / "ray", workers=2, backend="ray", log=None, progress=None, iterations=2)
    assert not ray.is_initialized()
    assert local.iterations == remote.iterations == 2 and local.decisions == remote.decisions
    assert _stable_rows(tmp_path / "ray") == _stable_rows(tmp_path / "local")
    ckpt = "checkpoint-000002.safetensors"
    assert (tmp_path / "ray" / ckpt).read_bytes() == (tmp_path / "local" / ckpt).read_bytes()


def test_corrupt_checkpoint_is_refused(tmp_path: Path) -> None:
    cfg = load_config(_config(tmp_path))
    train(cfg, tmp_path / "run", workers=0, log=None, progress=None, iterations=1)
    weights = next((tmp_path / "run").glob("checkpoint-*.safetensors"))
    weights.write_bytes(weights.read_bytes()[:100])
    with pytest.raises(ConfigError, match="cannot read the checkpoint"):
        train(cfg, tmp_path / "run", resume=True, workers=0, log=None, progress=None)


def _children(pid: int) -> list[int]:
    """Processes whose parent is ``pid`` (Linux /proc)."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            found.append(int(stat.parent.name))
    return found


def _checkpointed(run: Path) -> int:
    """The iteration of the run's checkpoint (-1: none yet, or being replaced)."""
    try:
        return int(json.loads((run / "checkpoint.json").read_text())["iteration"])
    except (OSError, ValueError, KeyError):
        return -1


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "areasearch.cli", *args]


@pytest.mark.slow
def test_cli_kill_and_resume_with_workers(tmp_path: Path) -> None:
    """SIGKILL mid-run, rerun with --resume (two worker processes): same numbers as an uninterrupted
    in-process run, no duplicated or missing row, no corrupt file."""
    config = _config(tmp_path, TINY.replace("total_decisions = 12", "total_decisions = 30"))
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    reference = tmp_path / "reference"
    done = subprocess.run(_cli("train", "--config", str(config), "--out", str(reference), "--workers", "0"),
                          capture_output=True, text=True, env=env, timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr
    killed = tmp_path / "killed"
    args = _cli("train", "--config", str(config), "--out", str(killed), "--workers", "2", "--resume")
    proc = subprocess.Popen(args, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
    deadline = time.time() + 240
    try:
        while time.time() < deadline and _checkpointed(killed) < 1:  # past the iteration-0 checkpoint
            time.sleep(0.05)
        assert _checkpointed(killed) >= 1, "no checkpoint before the deadline"
        children = _children(proc.pid)
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait()
    assert children, "the run had no worker processes"
    deadline = time.time() + 10
    while time.time() < deadline and any(Path(f"/proc/{pid}").exists() for pid in children):
        time.sleep(0.1)
    assert not any(Path(f"/proc/{pid}").exists() for pid in children), "worker processes outlived the killed run"
    first = json.loads((killed / "checkpoint.json").read_text())["iteration"]
    assert first < len(_stable_rows(reference))
    resumed = subprocess.run(args, capture_output=True, text=True, env=env, timeout=300)
    assert resumed.returncode == 0, resumed.stderr
    assert "resumed" in resumed.stdout
    assert _stable_rows(killed) == _stable_rows(reference)
    assert len(list(killed.glob("checkpoint-*.safetensors"))) == 1
    assert not list(killed.glob(".*.tmp"))


@pytest.mark.slow
def test_cli_bad_input_one_line_no_traceback(tmp_path: Path) -> None:
    out = tmp_path / "run"
    out.write_text("keep me")
    cases = [
        ("train", "--config", str(tmp_path / "missing.toml"), "--out", str(tmp_path / "a")),
        ("train", "--config", str(_config(tmp_path, "[ppo]\nepochs = 0\n", "bad.toml")), "--out", str(tmp_path / "b")),
        ("train", "--config", str(_config(tmp_path)), "--out", str(out)),
    ]
    for case in cases:
        res = subprocess.run(_cli(*case), capture_output=True, text=True, timeout=120)
        assert res.returncode == 2, res.stderr
        assert res.stderr.startswith("areasearch: error: ") and "Traceback" not in res.stderr
        assert len(res.stderr.strip().splitlines()) == 1, res.stderr
    assert out.read_text() == "keep me"


@pytest.mark.slow
def test_lockstep_rollouts_and_update_shards_do_not_depend_on_the_workers(tmp_path: Path) -> None:
    """Episodes played two at a time with one batched forward per round (``rollout.lockstep``) and
    minibatches cut into two shards (``ppo.shards``): the same iterations, losses and weights in the
    learner's process as in two worker processes."""
    text = TINY.replace("episodes = 2\n", "episodes = 3\nlockstep = 2\n").replace(
        "epochs = 2\n", "epochs = 2\nshards = 2\n"
    )
    cfg = load_config(_config(tmp_path, text))
    assert cfg.rollout.lockstep == 2 and cfg.ppo.shards == 2
    here = train(cfg, tmp_path / "here", workers=0, log=None, progress=None, iterations=2)
    pool = train(cfg, tmp_path / "pool", workers=2, log=None, progress=None, iterations=2)
    assert here.decisions == pool.decisions
    assert _stable_rows(tmp_path / "pool") == _stable_rows(tmp_path / "here")
    ckpt = "checkpoint-000002.safetensors"
    assert (tmp_path / "pool" / ckpt).read_bytes() == (tmp_path / "here" / ckpt).read_bytes()


def test_a_batch_draws_each_observations_goals_from_its_own_generator() -> None:
    """act() with a generator per observation: an observation's goals are drawn from its own robots
    and candidates with its own generator, so a batch of one draws what the single call draws, and
    in a batch of two each draws what it draws alone (the probabilities agree to float precision)."""
    import torch

    from areasearch.envs.goal import AreaSearchEnv
    from areasearch.models.dahgnn import act
    from areasearch.models.network import DAHGNN
    from areasearch.models.network_config import NetworkConfig

    observations = []
    for robots, seed in ((3, 1), (5, 2)):
        env = AreaSearchEnv(map="wrs2020_arena", num_robots=robots, seed=seed)
        obs, _ = env.reset(seed=seed)
        observations.append(obs)
    torch.manual_seed(0)
    model = DAHGNN(NetworkConfig(rounds=1, node_dim=16, history_dim=16).validate()).eval()

    def gen(seed: int) -> torch.Generator:
        return torch.Generator().manual_seed(seed)

    for k in range(5):
        single = act(model, observations[0], generator=gen(k))
        listed = act(model, [observations[0]], generator=[gen(k)])
        assert torch.equal(single.actions, listed.actions) and torch.equal(single.log_prob, listed.log_prob)
        both = act(model, observations, generator=[gen(k), gen(100 + k)])
        alone = [act(model, [o], generator=[gen(s)]) for o, s in zip(observations, (k, 100 + k), strict=True)]
        for i, one in enumerate(alone):
            r = one.actions.shape[1]
            assert torch.equal(both.actions[i, :r], one.actions[0])
            assert (both.actions[i, r:] == 0).all()
            assert float(both.log_prob[i]) == pytest.approx(float(one.log_prob[0]), abs=1e-4)


def test_smoothed_scores_average_each_validation_with_its_neighbours() -> None:
    from areasearch.training.train import smoothed_scores

    assert smoothed_scores([1.0, 4.0, 1.0, 7.0]) == [2.5, 2.0, 4.0, 4.0]
    assert smoothed_scores([3.0]) == [3.0] and smoothed_scores([]) == []
    # one lucky validation among poor neighbours does not outrank a steady stretch
    noisy = [70.0, 80.0, 70.0, 76.0, 77.0, 76.0, 70.0]
    smooth = smoothed_scores(noisy)
    assert max(range(7), key=lambda i: noisy[i]) == 1 and max(range(7), key=lambda i: smooth[i]) == 4


def test_unchoosable_snapshots_leave_the_final_selections_finalists_as_they_would_be(tmp_path: Path) -> None:
    """A run compacted after every validation (the snapshots the selection can no longer choose removed)
    ends with the same finalists as one that kept them all, and only a handful of snapshots."""
    from areasearch.training.runfolder import EVAL_FILE
    from areasearch.training.train import smoothed_scores
    from areasearch.training.validation import SNAPSHOTS, snapshot_name, unchoosable_snapshots

    def finalists(points: list[int], scores: list[float], have: set[int]) -> list[int]:
        smooth = smoothed_scores(scores)
        return sorted((d for d in points if d in have), key=lambda d: (smooth[points.index(d)], d), reverse=True)[:3]

    rng = np.random.default_rng(7)
    for trial in range(20):
        run = tmp_path / f"run{trial}"
        (run / SNAPSHOTS).mkdir(parents=True)
        n = int(rng.integers(1, 40))
        scores = list(np.round(rng.normal(70, 3, n) + np.linspace(0, rng.uniform(-5, 10), n), 1))
        scores[int(rng.integers(n))] = scores[0]  # ties, broken to the later validation
        points = [100 * (k + 1) for k in range(n)]
        with open(run / EVAL_FILE, "w", newline="") as f:
            rows = csv.writer(f)
            rows.writerow(["iteration", "decisions", "coverage_auc"])
            for k, (d, score) in enumerate(zip(points, scores, strict=True)):
                for episode_score in (score - 1.0, score + 1.0):  # two episodes per validation
                    rows.writerow([k + 1, d, episode_score])
                f.flush()
                for suffix in (".safetensors", ".json"):
                    (run / SNAPSHOTS / f"{snapshot_name(d)}{suffix}").write_text("{}")
                for gone in unchoosable_snapshots(run, 3, checkpoint_iteration=k + 1):
                    for suffix in (".json", ".safetensors"):
                        (run / SNAPSHOTS / f"{snapshot_name(gone)}{suffix}").unlink()
        left = {int(m.stem.removeprefix("dec-")) for m in (run / SNAPSHOTS).glob("dec-*.json")}
        assert finalists(points, scores, left) == finalists(points, scores, set(points)), trial
        assert len(left) <= 4 and len(list((run / SNAPSHOTS).iterdir())) == 2 * len(left)
    # a validation after the checkpoint is played again on resume: it counts for nothing, its snapshot stays
    run = tmp_path / "late"
    (run / SNAPSHOTS).mkdir(parents=True)
    (run / EVAL_FILE).write_text("iteration,decisions,coverage_auc\n" + "".join(
        f"{k},{100 * k},{score}\n" for k, score in enumerate([50, 60, 61, 62, 63, 99], start=1)
    ))  # fmt: skip
    for k in range(1, 7):
        (run / SNAPSHOTS / f"{snapshot_name(100 * k)}.json").write_text("{}")
    assert unchoosable_snapshots(run, 3, checkpoint_iteration=5) == [100]  # 200-400 final and best; 500 is the last
    assert unchoosable_snapshots(run, 3, checkpoint_iteration=6) == [100, 200]  # the 99 lifts 500's smoothed score
    assert unchoosable_snapshots(run, 1, checkpoint_iteration=1) == []


# ---------------------------------------------------------------------------------------------- the user's path


def _main(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    from areasearch.cli import main

    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.slow
def test_iterations_count_the_whole_run_and_resume_takes_the_runs_own_config(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``--iterations N`` stops once the run has N iterations in total: the same command again does
    nothing more, a larger N extends the run, and the pieces equal an uninterrupted run. ``--resume``
    without ``--config`` takes the run's config.json. Before the first validation ``policy.*`` holds
    the last weights, labelled ``last`` in policy.json and in the final line; then the best
    validation; at the end the final selection."""
    from areasearch.planners.learned import LearnedPlanner
    from areasearch.training.train import policy_choice

    config = _config(tmp_path, TINY.replace("total_decisions = 12", "total_decisions = 24"))
    whole = train(load_config(config), tmp_path / "whole", workers=0, log=None, progress=None)
    assert whole.iterations == 4 and whole.finished
    run = tmp_path / "run"
    start = ("train", "--config", str(config), "--out", str(run), "--workers", "0")
    code, out, _ = _main(capsys, *start, "--iterations", "1")
    assert code == 0 and len(_stable_rows(run)) == 1
    last = out.splitlines()[-1]
    assert "no validation yet (the first after iteration 2" in last and "-1.00" not in last, last
    assert f"policy = the last weights (iteration 1, 6 decisions): {run / 'policy'}" in last, last
    assert policy_choice(run) == {"by": "last", "iteration": 1, "decisions": 6}
    LearnedPlanner(weights=str(run / "policy"))  # loads as a planner
    resume = ("train", "--out", str(run), "--resume", "--workers", "0")
    code, out, _ = _main(capsys, *resume, "--iterations", "1")  # the same command again: nothing more to do
    assert code == 0 and len(_stable_rows(run)) == 1 and "1 iteration," in out.splitlines()[-1]
    code, out, _ = _main(capsys, *resume, "--iterations", "3")  # a larger N extends the run
    assert code == 0 and len(_stable_rows(run)) == 3
    assert policy_choice(run)["by"] == "best validation" and policy_choice(run)["iteration"] == 2
    assert "best validation Cover% AUC" in out.splitlines()[-1] and "policy = the best validation" in out
    code, out, _ = _main(capsys, *resume)
    assert code == 0 and "(finished)" in out.splitlines()[-1] and "policy = the final selection" in out
    assert policy_choice(run)["by"] == "final selection"
    assert _stable_rows(run) == _stable_rows(tmp_path / "whole")
    assert (run / "policy.safetensors").read_bytes() == (tmp_path / "whole" / "policy.safetensors").read_bytes()
    assert json.loads((run / "policy.json").read_text()) == json.loads((tmp_path / "whole" / "policy.json").read_text())


def test_a_run_without_validation_leaves_the_last_policy(tmp_path: Path) -> None:
    """``evaluation.episodes = 0``: no validation ever; the run still leaves a policy, the last weights."""
    from areasearch.training.train import policy_choice, summary_line

    cfg = load_config(_config(tmp_path, TINY.replace("[evaluation]\n", "[evaluation]\nepisodes = 0\n")))
    result = train(cfg, tmp_path / "run", workers=0, log=None, progress=None, iterations=1)
    assert result.best_score is None and not result.finished
    assert policy_choice(tmp_path / "run") == {"by": "last", "iteration": 1, "decisions": result.decisions}
    line = summary_line(tmp_path / "run", result, cfg)
    assert "no validation (evaluation.episodes = 0)" in line and "policy = the last weights (iteration 1" in line
    with pytest.raises(ConfigError, match="iterations must be an integer >= 1"):
        train(cfg, tmp_path / "run", resume=True, workers=0, log=None, progress=None, iterations=0)


def test_resume_names_the_settings_that_differ(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A --config or --set that differs from the run's config.json is refused, naming each setting and
    both values; the run's own config (--resume alone, or its config.json as --config) is accepted."""
    from areasearch.training.config import config_differences

    cfg = load_config(_config(tmp_path))
    recorded = config_to_dict(cfg)
    other = config_to_dict(load_config(_config(tmp_path), {"seed": 4, "rollout.env.robot.radius_m": 0.2}))
    assert config_differences(recorded, recorded) == []
    assert config_differences(recorded, other) == [
        "rollout.env.robot.radius_m (run: absent, given: 0.2)",
        "seed (run: 3, given: 4)",
    ]
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(json.dumps(recorded))
    code, _, err = _main(capsys, "train", "--out", str(run), "--resume", "--set", "seed=4", "--set", "ppo.epochs=3")
    assert code == 2 and err.count("\n") == 1
    assert "it differs in ppo.epochs (run: 2, given: 3); seed (run: 3, given: 4). Resume with the run's own" in err
    assert sorted(p.name for p in run.iterdir()) == ["config.json"]


def test_a_refused_run_folder_is_left_as_it_was(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], bad_inputs: Path
) -> None:
    """Damaged run folders (``make_corpus.write_runs``): refused with one line, with or without
    --resume, and not a byte of them changed (a folder without checkpoint.json but with checkpoints
    and progress rows used to start again from zero, cutting them)."""
    import importlib.util

    path = bad_inputs / "make_corpus.py"
    spec = importlib.util.spec_from_file_location("make_corpus", path)
    assert spec is not None and spec.loader is not None
    corpus = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(corpus)
    corpus.write_runs(tmp_path / "runs")
    tiny = str(_config(tmp_path, corpus.TINY_RUN))
    before = {p: p.read_bytes() for p in (tmp_path / "runs").rglob("*") if p.is_file()}
    cases = [
        ("no_checkpoint", ("--resume",), "no checkpoint.json, but the run's checkpoint-000001.safetensors"),
        ("no_checkpoint", ("--config", tiny), "a run is already there; pass --resume"),
        ("no_checkpoint", ("--config", tiny, "--resume"), "no checkpoint.json, but the run's"),
        ("no_config", ("--config", tiny), "but no config.json; nothing was changed"),
        ("no_config", ("--config", tiny, "--resume"), "but no config.json; nothing was changed"),
        ("lying_iteration", ("--resume",), "iteration = 7, but progress.csv has rows up to iteration 1"),
        ("wrong_shape", ("--resume",), "the run's network and optimizer need torch.float32 [4, 116]"),
    ]
    for name, args, expect in cases:
        code, out, err = _main(capsys, "train", "--out", str(tmp_path / "runs" / name), "--workers", "0", *args)
        assert code == 2 and out == "" and err.count("\n") == 1 and expect in err, (name, args, err)
    assert {p: p.read_bytes() for p in (tmp_path / "runs").rglob("*") if p.is_file()} == before
    code, out, err = _main(capsys, "train", "--out", str(tmp_path / "runs" / "valid"), "--workers", "0", "--resume")
    assert code == 0, err  # the undamaged folder resumes and finishes
    assert "resumed" in out and "(finished)" in out.splitlines()[-1]
