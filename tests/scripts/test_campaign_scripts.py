"""scripts/train_campaign.py, scripts/seed_summary.py and scripts/coverage_auc.py: the campaign's order and
state, the median seed and paired differences, the validation score of an evaluation folder."""

from __future__ import annotations

import csv
import importlib.util
import json
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import pytest

from areasearch.errors import AreaSearchError
from areasearch.training.config import config_to_dict, load_config


@pytest.fixture
def load_script(root: Path) -> Callable[[str], ModuleType]:
    """A function that loads ``scripts/NAME.py`` as a module."""

    def load(name: str) -> ModuleType:
        spec = importlib.util.spec_from_file_location(name, root / "scripts" / f"{name}.py")
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module

    return load


def test_campaign_order_puts_first_seeds_then_the_claims_policies_and_reads_each_runs_state(
    tmp_path: Path, root: Path, load_script: Callable[[str], ModuleType]
) -> None:
    campaign = load_script("train_campaign")
    order = campaign.runs({"a": (0, 1, 2), "b": (0, 1), "c": (1,)})
    assert order == [("a", 0), ("b", 0), ("c", 1), ("a", 1), ("a", 2), ("b", 1)]
    assert campaign.runs() == [
        ("dahgnn", 0), ("ncm", 0), ("dahgnn-no-type", 0), ("dahgnn-no-history", 0),
        ("dahgnn", 1), ("ncm", 1), ("dahgnn", 2), ("ncm", 2), ("dahgnn-no-type", 1), ("dahgnn-no-history", 1),
    ]  # fmt: skip
    run, results = tmp_path / "dahgnn-s0", tmp_path / "published"
    assert campaign.status(run, results) == "not started"
    run.mkdir()
    (run / "checkpoint.json").write_text(json.dumps({"decisions": 1234}))
    assert campaign.status(run, results) == "started (1,234 decisions)"
    (run / "selection.json").write_text(json.dumps({"chosen_decisions": 999}))
    assert campaign.status(run, results) == "done (policy from 999 decisions)"
    out = subprocess.run(
        [sys.executable, str(root / "scripts" / "train_campaign.py"), "--runs-dir", str(tmp_path), "--dry-run"],
        capture_output=True, text=True, check=True,
    )  # fmt: skip
    assert "dahgnn-s0                  done" in out.stdout and "ncm-s2                     not started" in out.stdout
    script = str(root / "scripts" / "train_campaign.py")
    variants = subprocess.run(
        [sys.executable, script, "--runs-dir", str(tmp_path), "--dry-run", "--variants"],
        capture_output=True,
        text=True,
        check=True,
    )
    names = [line.split()[0] for line in variants.stdout.splitlines()]
    assert names == [f"{n}-s{s}" for n, s in campaign.runs(campaign.VARIANTS)] and "dahgnn-s0" not in names
    assert campaign.base_policy("dahgnn-no-type-x") == "dahgnn-no-type" and campaign.base_policy("ncm-120k") == "ncm"
    with pytest.raises(ValueError, match="does not start with a policy"):
        campaign.base_policy("ppo-120k")
    for name in campaign.VARIANTS:  # each variant changes one setting of its policy's config, no more
        base = _leaves(config_to_dict(load_config(root / "configs" / f"{campaign.base_policy(name)}.toml")))
        variant = _leaves(config_to_dict(load_config(root / "configs" / "variants" / f"{name}.toml")))
        assert len({k for k in base.keys() | variant.keys() if base.get(k) != variant.get(k)}) == 1, name
    for name in campaign.PAPER_BUDGET:  # the budget and the three speed settings, no more
        base = _leaves(config_to_dict(load_config(root / "configs" / f"{campaign.base_policy(name)}.toml")))
        paper = _leaves(config_to_dict(load_config(root / "configs" / "paper-budget" / f"{name}.toml")))
        changed = {k for k in base.keys() | paper.keys() if base.get(k) != paper.get(k)}
        assert changed == campaign.PAPER_BUDGET_SETTINGS and paper["total_decisions"] == 300_000, name
    budget = subprocess.run(
        [sys.executable, script, "--runs-dir", str(tmp_path), "--dry-run", "--paper-budget"],
        capture_output=True,
        text=True,
        check=True,
    )
    assert [line.split()[0] for line in budget.stdout.splitlines()][:2] == ["dahgnn-300k-s0", "ncm-300k-s0"]


def _leaves(tree: dict, prefix: str = "") -> dict[str, object]:
    out: dict[str, object] = {}
    for key, value in tree.items():
        out.update(_leaves(value, f"{prefix}{key}.") if isinstance(value, dict) else {f"{prefix}{key}": value})
    return out


def test_campaign_publish_copies_the_logs_and_the_chosen_policy_of_finished_runs_only(
    tmp_path: Path, root: Path
) -> None:
    runs, results = tmp_path / "runs", tmp_path / "results"
    done, started = runs / "ncm-s1", runs / "dahgnn-s0"
    for run in (done, started):
        run.mkdir(parents=True)
        (run / "checkpoint.json").write_text(json.dumps({"decisions": 10}))
        (run / "policy.safetensors").write_bytes(b"weights of " + run.name.encode())
        (run / "policy.json").write_text("{}")
        (run / "checkpoint.pt").write_bytes(b"not published")
    (done / "selection.json").write_text(json.dumps({"chosen_decisions": 10}))
    command = [sys.executable, str(root / "scripts" / "train_campaign.py"), "--runs-dir", str(runs)]
    subprocess.run([*command, "--publish", "--results-dir", str(results)], capture_output=True, check=True)
    assert sorted(p.name for p in results.iterdir()) == ["ncm-s1"]  # the unfinished run is not published
    published = sorted(p.name for p in (results / "ncm-s1").iterdir())
    assert published == ["policy.json", "policy.safetensors", "selection.json"]  # no checkpoint, no temporaries
    assert (results / "ncm-s1" / "policy.safetensors").read_bytes() == b"weights of ncm-s1"


def test_campaign_table_prints_a_finished_runs_row_from_its_published_files_and_log(tmp_path: Path, root: Path) -> None:
    runs, results = tmp_path / "runs", tmp_path / "results"
    run = results / "ncm-s1"
    run.mkdir(parents=True)
    head = "iteration,decisions,episodes,wall_s,perf/decisions_per_s,perf/rollout_s,perf/update_s\n"
    (run / "progress.csv").write_text(head + "1,1000,4,40,30,20,10\n2,2000,8,100,40,15,10\n3,3000,12,120,20,5,5\n")
    header = "iteration,decisions,map,robots,seed,explored_pct,covered_pct,time_e,time_c,coverage_auc\n"
    rows = "1,1000,a,3,1,100,100,5,9,70.0\n1,1000,b,3,2,100,100,5,9,72.0\n3,3000,a,3,1,100,100,5,9,75.5\n"
    (run / "eval.csv").write_text(header + rows)
    finalists = [
        {"decisions": 1000, "final_score": 70.25, "minus_chosen": -1.5, "minus_chosen_ci95": 0.5},
        {"decisions": 3000, "final_score": 71.75, "minus_chosen": 0.0, "minus_chosen_ci95": 0.0},
    ]
    (run / "selection.json").write_text(json.dumps({"chosen_decisions": 3000, "finalists": finalists}))
    runs.mkdir()
    train = "== python -m areasearch.cli train --config c.toml --out runs/ncm-s1 --workers 2"
    (runs / "ncm-s1.log").write_text(f"{train}\niter 1\n{train} --resume\n== python -m areasearch.cli eval x\n")
    command = [sys.executable, str(root / "scripts" / "train_campaign.py"), "--runs-dir", str(runs), "--table"]
    out = subprocess.run([*command, "--results-dir", str(results)], capture_output=True, text=True, check=True).stdout
    lines = out.splitlines()
    assert lines[0].startswith("| run | decisions | wall time |") and len(lines) == 3  # head and one finished run
    assert lines[2] == (
        "| `ncm-s1` | 3,000 | 2 min (25.0 decisions/s with its 2 validations; the median iteration 30.0; "
        "iterations 54 % of the time), in 2 processes | 71.00 (1,000) → 75.50 (3,000) | "
        "3,000 decisions: 71.75; the others \N{MINUS SIGN}1.50 ± 0.50 (1,000) |"
    )


def test_campaign_evaluate_publishes_and_evaluates_each_finished_run_and_stops_on_a_failure(
    tmp_path: Path, load_script: Callable[[str], ModuleType], monkeypatch: pytest.MonkeyPatch
) -> None:
    campaign = load_script("train_campaign")
    runs, results, out = tmp_path / "runs", tmp_path / "results", tmp_path / "eval"
    for name in ("dahgnn-s0", "ncm-s0"):  # both finished
        (runs / name).mkdir(parents=True)
        (runs / name / "selection.json").write_text(json.dumps({"chosen_decisions": 10}))
        (runs / name / "policy.safetensors").write_bytes(b"weights of " + name.encode())
    calls: list[list[str]] = []
    codes = iter([0, 3])

    def call(command: list[str], **_: object) -> int:
        calls.append(command)
        return next(codes)

    monkeypatch.setattr(campaign.subprocess, "call", call)
    argv = ["train_campaign.py", "--runs-dir", str(runs), "--results-dir", str(results), "--evaluate", str(out)]
    monkeypatch.setattr(sys, "argv", [*argv, "--only", "dahgnn-s0", "ncm-s0", "dahgnn-s1"])
    assert campaign.main() == 3  # the second evaluation failed: the campaign stops there, dahgnn-s1 is not trained
    assert calls == [campaign.eval_command(n, results / n / "policy", out, 2) for n in ("dahgnn-s0", "ncm-s0")]
    assert calls[0][3:] == ["eval", "--methods", "dahgnn-s0", "--policy", f"dahgnn-s0={results}/dahgnn-s0/policy",
                            "--robots", "3", "4", "5", "--maps", "bundled:test", "--episodes", "5", "--seed", "0",
                            "--max-steps", "3600", "--out", str(out), "--workers", "2"]  # fmt: skip
    assert (results / "ncm-s0" / "policy.safetensors").read_bytes() == b"weights of ncm-s0"  # published first
    assert "== " in (runs / "ncm-s0.log").read_text()
    # a finished run published and its run folder removed (its log kept): not trained again, not published
    # again, its evaluation resumed; a published run whose folder holds a checkpoint (a rerun) trains on
    shutil.rmtree(runs / "dahgnn-s0")
    (results / "dahgnn-s0" / "policy.safetensors").write_bytes(b"published weights")
    (runs / "ncm-s0" / "checkpoint.json").write_text(json.dumps({"decisions": 5}))
    (runs / "ncm-s0" / "selection.json").unlink()
    calls.clear()
    codes = iter([0, 0, 0])
    asked: list[tuple[str, Path, Path]] = []

    def evaluated(run: str, policy: Path, eval_out: Path) -> bool:  # the published run's evaluation is unfinished
        asked.append((run, policy, eval_out))
        return False

    monkeypatch.setattr(campaign, "evaluated", evaluated)
    monkeypatch.setattr(sys, "argv", [*argv, "--only", "dahgnn-s0", "ncm-s0"])
    assert campaign.main() == 0
    assert asked == [("dahgnn-s0", results / "dahgnn-s0" / "policy", out)]
    assert calls[0] == campaign.eval_command("dahgnn-s0", results / "dahgnn-s0" / "policy", out, 2)
    assert calls[1][3:5] == ["train", "--config"]  # ncm-s0 trains on
    # its evaluation finished: not run again, its log left as it was
    calls.clear()
    log = (runs / "dahgnn-s0.log").read_text()
    monkeypatch.setattr(campaign, "evaluated", lambda *_: True)
    monkeypatch.setattr(sys, "argv", [*argv, "--only", "dahgnn-s0"])
    assert campaign.main() == 0
    assert calls == []
    assert (runs / "dahgnn-s0.log").read_text() == log
    assert not (runs / "dahgnn-s0").exists()
    assert (results / "dahgnn-s0" / "policy.safetensors").read_bytes() == b"published weights"
    assert campaign.status(runs / "dahgnn-s0", results).startswith("done (policy from 10 decisions), published to")
    (runs / "dahgnn-s0.log").unlink()  # never trained in this runs folder (a fresh clone): it trains
    assert campaign.status(runs / "dahgnn-s0", results) == "not started"


def test_campaign_evaluated_reads_whether_an_eval_folder_holds_every_episode_of_a_runs_evaluation(
    tmp_path: Path, load_script: Callable[[str], ModuleType], root: Path
) -> None:
    campaign = load_script("train_campaign")
    run, training, seeds = "ncm-300k-s1", root / "results" / "training", root / "results" / "paper-seeds"
    assert campaign.evaluated(run, training / run / "policy", seeds)  # published and evaluated there
    assert not campaign.evaluated(run, training / run / "policy", tmp_path / "eval")  # nothing there yet
    with pytest.raises(AreaSearchError, match="weights"):  # other weights under the same name: refused
        campaign.evaluated(run, training / "ncm-300k-s0" / "policy", seeds)


def test_campaign_compact_removes_the_snapshots_an_unfinished_run_can_no_longer_choose(
    tmp_path: Path, root: Path
) -> None:
    from areasearch.folderlock import hold_folder

    runs = tmp_path / "runs"
    run, done = runs / "dahgnn-300k-s0", runs / "ncm-300k-s0"
    from areasearch.training.config import TRAIN_FORMAT

    config = config_to_dict(load_config(root / "configs" / "paper-budget" / "dahgnn-300k.toml"))
    checkpoint = {"format": TRAIN_FORMAT, "weights": "checkpoint-000006.safetensors", "param_groups": [],
                  "iteration": 6, "decisions": 600, "episodes": 24, "wall_s": 60.0, "best_score": 63.0}  # fmt: skip
    for folder in (run, done):
        (folder / "snapshots").mkdir(parents=True)
        (folder / "config.json").write_text(json.dumps(config))
        (folder / "checkpoint.json").write_text(json.dumps(checkpoint))
        (folder / "eval.csv").write_text("iteration,decisions,coverage_auc\n" + "".join(
            f"{k},{100 * k},{score}\n" for k, score in enumerate([50, 70, 60, 61, 62, 63], start=1)
        ))  # fmt: skip
        for k in range(1, 7):
            for suffix in (".safetensors", ".json"):
                (folder / "snapshots" / f"dec-{100 * k:09d}{suffix}").write_text("{}")
    (done / "selection.json").write_text("{}")
    command = [sys.executable, str(root / "scripts" / "train_campaign.py"), "--paper-budget", "--runs-dir", str(runs)]
    with hold_folder(run):  # training: refused, nothing removed
        busy = subprocess.run([*command, "--compact"], capture_output=True, text=True)
    assert busy.returncode == 1 and "dahgnn-300k-s0" in busy.stderr and "Traceback" not in busy.stderr
    assert len(list((run / "snapshots").iterdir())) == 12
    out = subprocess.run([*command, "--compact"], capture_output=True, text=True, check=True).stdout
    assert out.startswith("dahgnn-300k-s0             2 snapshots removed, 4 kept;") and "ncm" not in out
    # smoothed: 60, 60, 63.67, 61, 62 (final), 62.5 (the last, kept): 100 and 200 can never be finalists
    kept = sorted(p.name for p in (run / "snapshots").iterdir())
    assert kept == [f"dec-{d:09d}{x}" for d in (300, 400, 500, 600) for x in (".json", ".safetensors")]
    assert len(list((done / "snapshots").iterdir())) == 12  # a finished run is left as it is


def _rows(values: dict[str, list[tuple[float, int]]]) -> list[dict[str, object]]:
    rows = []
    for method, eps in values.items():
        for k, (cover, time_c) in enumerate(eps):
            rows.append({"method": method, "map": f"m{k}", "size_class": "medium", "robots": 3, "episode": 0,
                         "covered_pct": cover, "time_c": time_c})  # fmt: skip
    return rows


def test_seed_summary_picks_the_median_seed_and_pairs_it_by_episode(
    tmp_path: Path, root: Path, load_script: Callable[[str], ModuleType]
) -> None:
    summary = load_script("seed_summary")
    rows = _rows(
        {
            "dahgnn-s0": [(90.0, 500), (92.0, 520), (94.0, 480)],
            "dahgnn-s1": [(99.0, 400), (97.0, 420), (98.0, 410)],
            "dahgnn-s2": [(95.0, 450), (96.0, 460), (94.0, 470)],
            "ncm-s0": [(93.0, 500), (95.0, 510), (94.0, 490)],
            "greedy": [(91.0, 600), (93.0, 610), (92.0, 590)],
        }
    )
    text = [{k: str(v) for k, v in r.items()} for r in rows]
    assert summary.median_seed(text, ["dahgnn-s0", "dahgnn-s1", "dahgnn-s2"]) == "dahgnn-s2"
    with open(tmp_path / "episodes.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    out = subprocess.run(
        [sys.executable, str(root / "scripts" / "seed_summary.py"), str(tmp_path), "--policies", "dahgnn", "ncm",
         "--classical", "greedy"],
        capture_output=True, text=True, check=True,
    ).stdout  # fmt: skip
    assert "dahgnn-s2 (median)" in out and "Best classical planner here: by Cover % (ties: Time_C) greedy" in out
    # median seed minus greedy, episode by episode: Cover +4, +3, +2 (mean 3, sd 1), Time_C -150, -150, -120
    ci = 1.96 * 1.0 / 3**0.5
    assert f"| dahgnn-s2 | greedy | +3.00 ± {ci:.2f} beyond, better | -140.00 ± " in out
    assert "over 3 seeds | 95.00 (range 92.00-98.00)" in out  # seed means 92, 98, 95
    # the seeds' mean per episode (94.67, 95.00, 95.33) minus greedy (91, 93, 92): +3.67, +2.00, +3.33
    assert "| dahgnn (3 seeds) | greedy | +3.00 ± 1.00 beyond, better |" in out


def test_seed_summary_holds_the_median_seed_to_the_bar_and_prints_the_compact_table(tmp_path: Path, root: Path) -> None:
    rows = _rows(
        {
            "dahgnn-s0": [(96.0, 400), (97.0, 420), (98.0, 410)],
            "ncm-s0": [(93.0, 500), (95.0, 510), (94.0, 490)],
            "greedy": [(91.0, 300), (93.0, 310), (92.0, 290)],  # the fastest classical planner
            "hungarian": [(95.0, 600), (95.5, 610), (96.0, 590)],  # the best classical planner by Cover %
        }
    )
    for r in rows:
        r |= {"explored_pct": 100.0, "time_e": 100}
    rows += [r | {"robots": 4} for r in rows if r["method"] == "greedy"]  # a team size without the policy
    with open(tmp_path / "episodes.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    command = [sys.executable, str(root / "scripts" / "seed_summary.py"), str(tmp_path), "--policies", "dahgnn"]
    bar = [*command, "ncm", "--classical", "greedy", "hungarian"]
    out = subprocess.run([*bar, "--table", "3"], capture_output=True, text=True, check=True).stdout
    assert "by Cover % (ties: Time_C) hungarian, by Time_C greedy" in out
    # Cover beats NCM (+3, sd 1) and Hungarian (+1.5, sd 0.5) beyond the intervals; Time_C beats NCM but not Greedy
    assert "Bar for dahgnn-s0: not met: Time_C vs greedy +110.00 ± " in out
    assert "Cover % vs" not in out.split("Bar for dahgnn-s0")[1].splitlines()[0]
    assert "Bar for dahgnn-s0: not measured (no episodes of it here)." in out.split("### 4 robots")[1]
    assert "| medium | hungarian | 100.0 | 100 | 95.5 | 600 |" in out
    assert "| medium | dahgnn (seed 0 of 1) | 100.0 | 100 | 97.0 | 410 |" in out
    fast = [r | {"time_c": 250} if r["method"] == "dahgnn-s0" else r for r in rows]
    fast = [r | {"time_c": r["time_c"] + 5 * (r["map"] == "m1")} for r in fast]  # differences that vary
    with open(tmp_path / "episodes.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, list(rows[0]))
        writer.writeheader()
        writer.writerows(fast)
    out = subprocess.run(bar, capture_output=True, text=True).stdout
    assert "Bar for dahgnn-s0: met." in out


def test_seed_summary_median_compares_seeds_on_the_episodes_all_have_played(
    load_script: Callable[[str], ModuleType],
) -> None:
    summary = load_script("seed_summary")
    rows = _rows(
        {
            "ncm-s0": [(90.0, 500), (90.0, 500)],
            "ncm-s1": [(95.0, 500), (95.0, 500), (20.0, 3600), (20.0, 3600)],  # two more, hard episodes
            "ncm-s2": [(93.0, 500), (93.0, 500)],
        }
    )
    text = [{k: str(v) for k, v in r.items()} for r in rows]
    # over all its episodes ncm-s1 would score 57.5 and be the lowest; on the shared two it is the best
    assert summary.median_seed(text, ["ncm-s0", "ncm-s1", "ncm-s2"]) == "ncm-s2"


def test_seed_summary_ranks_seeds_on_one_team_size(tmp_path: Path, root: Path) -> None:
    three = _rows({"ncm-s0": [(90.0, 500)] * 2, "ncm-s1": [(95.0, 500)] * 2, "ncm-s2": [(93.0, 500)] * 2})
    four = _rows({"ncm-s0": [(99.0, 500)] * 2, "ncm-s1": [(10.0, 500)] * 2, "ncm-s2": [(99.0, 500)] * 2})
    rows = three + [r | {"robots": 4} for r in four]
    with open(tmp_path / "episodes.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    command = [sys.executable, str(root / "scripts" / "seed_summary.py"), str(tmp_path), "--policies", "ncm"]
    everything = subprocess.run(command, capture_output=True, text=True, check=True).stdout
    assert "ncm: ncm-s0" in everything.splitlines()[0]  # means 94.5, 52.5, 96.0
    three_only = subprocess.run([*command, "--median-robots", "3"], capture_output=True, text=True, check=True).stdout
    assert "ncm: ncm-s2" in three_only.splitlines()[0]  # 90, 95, 93
    fixed = subprocess.run([*command, "--median", "ncm=ncm-s1"], capture_output=True, text=True, check=True).stdout
    assert "fixed by --median: ncm): ncm: ncm-s1" in fixed.splitlines()[0]  # held, not ranked
    assert "| ncm | ncm-s1 (median) |" in fixed
    bad = subprocess.run([*command, "--median", "ncm=ncm-s7"], capture_output=True, text=True)
    assert bad.returncode == 2 and "Traceback" not in bad.stderr and "ncm=ncm-s7" in bad.stderr


def test_coverage_auc_script_scores_an_eval_folder(tmp_path: Path, root: Path) -> None:
    curves = [
        {"method": "a", "map": "m", "robots": 2, "episode": 0, "seed": 1, "steps": [0, 100, 200],
         "explored_pct": [0.0, 60.0, 90.0], "covered_pct": [0.0, 50.0, 100.0]},
        {"method": "b", "map": "m", "robots": 2, "episode": 0, "seed": 1, "steps": [0, 200],
         "explored_pct": [0.0, 90.0], "covered_pct": [0.0, 100.0]},
    ]  # fmt: skip
    (tmp_path / "curves.jsonl").write_text("".join(json.dumps(c) + "\n" for c in curves))
    out = subprocess.run(
        [sys.executable, str(root / "scripts" / "coverage_auc.py"), str(tmp_path), "--max-steps", "400",
         "--reference", "b"],
        capture_output=True, text=True, check=True,
    ).stdout  # fmt: skip
    # a: 50 % over steps 100-200, 100 % over 200-400 -> (50 * 100 + 100 * 200) / 400 = 62.5; b: 50.0
    assert "| a | 1 | 62.50 |" in out and "| b | 1 | 50.00 |" in out and "+12.50" in out
    (tmp_path / "curves.jsonl").write_text(json.dumps({**curves[0], "covered_pct": [0.0, 250.0, 100.0]}) + "\n")
    bad = subprocess.run(
        [sys.executable, str(root / "scripts" / "coverage_auc.py"), str(tmp_path), "--max-steps", "400"],
        capture_output=True, text=True,
    )  # fmt: skip
    assert bad.returncode == 2 and "Traceback" not in bad.stderr, bad.stderr
    assert bad.stderr.startswith("coverage_auc.py: error: ") and "curves.jsonl:1" in bad.stderr, bad.stderr
    more = [c | {"robots": 3, "covered_pct": [0.0] * len(c["steps"])} for c in curves]
    more += [c | {"map": "giraff_home_ex3"} for c in curves]  # a large bundled map
    (tmp_path / "curves.jsonl").write_text("".join(json.dumps(c) + "\n" for c in curves + more))
    command = [sys.executable, str(root / "scripts" / "coverage_auc.py"), str(tmp_path), "--max-steps", "400"]
    out = subprocess.run([*command, "--robots", "3"], capture_output=True, text=True, check=True).stdout
    assert "| a | 1 | 0.00 |" in out and "| b | 1 | 0.00 |" in out  # the 3-robot episodes only
    out = subprocess.run([*command, "--robots", "2", "--methods", "a"], capture_output=True, text=True).stdout
    assert "| a | 2 | 62.50 |" in out and "| b |" not in out
    out = subprocess.run([*command, "--size", "large"], capture_output=True, text=True).stdout
    assert "| a | 1 | 62.50 |" in out and "| b | 1 | 50.00 |" in out  # giraff_home_ex3's only


def test_coverage_auc_seed_means_pair_two_policies_seed_for_seed(load_script: Callable[[str], ModuleType]) -> None:
    seed_means = load_script("coverage_auc").seed_means
    e0, e1 = ("m", 3, 0), ("m", 3, 1)
    scores = {
        "p-s0": {e0: 10.0, e1: 20.0}, "p-s1": {e0: 30.0, e1: 40.0}, "p-s2": {e0: 99.0, e1: 99.0},
        "q-s0": {e0: 1.0, e1: 2.0}, "q-s1": {e0: 3.0},  # q-s1 did not play e1
        "r-s0": {e0: 5.0}, "greedy": {e0: 7.0, e1: 8.0},  # r has no seed 1, greedy no seeds
    }  # fmt: skip
    means = seed_means(scores, [0, 1])
    assert means == {"p (seeds 0 1)": {e0: 20.0, e1: 30.0}, "q (seeds 0 1)": {e0: 2.0}}
    assert seed_means(scores, [2]) == {"p (seeds 2)": {e0: 99.0, e1: 99.0}}


@pytest.mark.parametrize("script", ["seed_summary.py", "coverage_auc.py"])
def test_scripts_refuse_an_empty_folder(tmp_path: Path, script: str, root: Path) -> None:
    (tmp_path / "episodes.csv").write_text("method,map,size_class,robots,episode,covered_pct,time_c\n")
    (tmp_path / "curves.jsonl").write_text("")
    command = [sys.executable, str(root / "scripts" / script), str(tmp_path)]
    out = subprocess.run(command, capture_output=True, text=True)
    assert out.returncode == 2 and "Traceback" not in out.stderr


def test_coverage_auc_script_reads_a_training_runs_validations_by_size(tmp_path: Path, root: Path) -> None:
    header = "iteration,decisions,map,robots,seed,explored_pct,covered_pct,time_e,time_c,coverage_auc\n"
    rows = [
        "20,3000,wrs2020_arena,3,1,100,100,5,9,80.0",  # small
        "20,3000,bormann_freiburg101,3,2,100,100,5,9,50.0",  # large
        "40,6000,wrs2020_arena,3,1,100,100,5,9,84.0",
        "40,6000,bormann_freiburg101,3,2,100,100,5,9,56.0",
    ]
    (tmp_path / "eval.csv").write_text(header + "\n".join(rows) + "\n")
    out = subprocess.run(
        [sys.executable, str(root / "scripts" / "coverage_auc.py"), str(tmp_path), "--by-size"],
        capture_output=True, text=True, check=True,
    ).stdout  # fmt: skip
    assert "| 3,000 | 2 | 65.00 | 80.00 |  | 50.00 |" in out and "| 6,000 | 2 | 70.00 | 84.00 |  | 56.00 |" in out


def test_run_health_averages_the_ends_and_the_middle_of_a_run(tmp_path: Path, root: Path) -> None:
    header = "iteration,decisions,health/round0_robot_rms,health/grad_norm_round0,losses/approx_kl\n"
    rows = "".join(f"{i},{100 * i},{i},{2 * i},0.01\n" for i in range(1, 10))  # 9 iterations
    (tmp_path / "progress.csv").write_text(header + rows)
    out = subprocess.run(
        [sys.executable, str(root / "scripts" / "run_health.py"), str(tmp_path), "--window", "3"],
        capture_output=True, text=True, check=True,
    ).stdout  # fmt: skip
    # first 1-3 (mean 2), middle 4-6 (5), last 7-9 (8); the largest RMS of the run 9; grad norms have no "largest"
    assert "| round0_robot_rms | 2 | 5 | 8 | 9 |" in out and "| grad_norm_round0 | 4 | 10 | 16 |  |" in out
    assert "| approx_kl | 0.01 | 0.01 | 0.01 |  |" in out
    (tmp_path / "progress.csv").write_text("iteration,decisions,losses/approx_kl\n1,10,0.01\n")
    bad = subprocess.run(
        [sys.executable, str(root / "scripts" / "run_health.py"), str(tmp_path)], capture_output=True, text=True
    )
    assert bad.returncode == 2 and "no health columns" in bad.stderr and "Traceback" not in bad.stderr


def test_seed_summary_holds_a_variant_to_the_rival_it_names(tmp_path: Path, root: Path) -> None:
    rows = _rows(
        {
            "dahgnn-120k-s0": [(97.0, 400), (98.0, 410), (99.0, 420)],
            "ncm-s0": [(99.0, 300), (99.5, 310), (100.0, 320)],  # the 60k rival: faster than the variant
            "ncm-120k-s0": [(93.0, 500), (94.0, 510), (95.0, 520)],  # the equal-budget rival: slower
            "greedy": [(90.0, 600), (91.0, 610), (92.0, 620)],
        }
    )
    with open(tmp_path / "episodes.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    command = [sys.executable, str(root / "scripts" / "seed_summary.py"), str(tmp_path), "--policies"]
    command += ["dahgnn-120k", "ncm", "ncm-120k", "--classical", "greedy", "--bar", "dahgnn-120k"]
    against_ncm = subprocess.run(command, capture_output=True, text=True, check=True).stdout
    assert "Bar for dahgnn-120k-s0: not met: Cover % vs ncm-s0" in against_ncm
    equal = subprocess.run([*command, "--rival", "ncm-120k"], capture_output=True, text=True, check=True).stdout
    assert "Bar for dahgnn-120k-s0: met." in equal
    assert "| dahgnn-120k-s0 | ncm-120k-s0 | +4.00 ± 0.00 beyond, better | -100.00 ± 0.00 beyond, better |" in equal


def test_seed_summary_marks_censored_times_and_never_picks_one_as_fastest(tmp_path: Path, root: Path) -> None:
    horizon = 700  # an episode that never reached 80 % coverage counts the horizon
    rows = _rows(
        {
            "dahgnn-s0": [(99.0, 400), (98.0, 410), (97.0, 420)],
            "dahgnn-s1": [(96.0, 500), (95.0, horizon), (97.0, 520)],  # the median seed (lower middle of two)
            "greedy": [(90.0, 300), (80.0, horizon), (91.0, 310)],  # mean 437, a bound under Hungarian's 600
            "hungarian": [(92.0, 600), (93.0, 610), (94.0, 590)],
        }
    )
    for r in rows:
        r |= {"explored_pct": 100.0, "time_e": 100, "reached_e": True, "reached_c": r["time_c"] < horizon}
    with open(tmp_path / "episodes.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    command = [sys.executable, str(root / "scripts" / "seed_summary.py"), str(tmp_path), "--policies", "dahgnn"]
    out = subprocess.run([*command, "--classical", "greedy", "hungarian", "--table", "3"], **_TEXT).stdout
    # the fastest classical planner is the one whose episodes all reached 80 %, with the bound named
    assert "by Time_C hungarian (greedy: Time_C censored below it, may be faster)." in out
    assert "| dahgnn | dahgnn-s1 (median) | 96.00 ± " in out and "| > 573 |" in out  # a bound: no interval
    assert "| dahgnn | dahgnn-s0 | 98.00 ± 1.13 | 410 ± 11 |" in out
    assert "| dahgnn | over 2 seeds | 97.00 (range 96.00-98.00) | > 492 (range 410 to > 573) |" in out
    # differences over censored episodes are flagged as bounds; the verdict's arithmetic is unchanged
    flag = "(a bound: dahgnn-s1 1 of 3 censored)"
    assert f"| dahgnn-s1 | hungarian | +3.00 ± 1.13 beyond, better | -26.67 ± 115.59 {flag} |" in out
    assert "| dahgnn (2 seeds) | hungarian |" in out and "(a bound: dahgnn (seeds) 1 of 3 censored) |" in out
    bar = out.split("Bar for dahgnn-s1: ")[1].splitlines()[0]
    assert bar.startswith("not met: Time_C vs hungarian -26.67 ± ")
    assert bar.endswith(
        ". Over censored episodes, a bound, not an estimate: Time_C vs hungarian (dahgnn-s1 1 of 3 censored)."
    )
    table = out.split("### Compact table")[1]
    assert "| medium | greedy | 100.0 | 100 | 87.0 | > 437 |" in table
    assert "| medium | hungarian | 100.0 | 100 | 93.0 | 600 |" in table
    assert "| medium | dahgnn (seed 1 of 2) | 100.0 | 100 | 96.0 (96.0-98.0) | > 573 (410 to > 573) |" in table
    reached = [r | {"reached_c": True} for r in rows]  # the same times, all reached: estimates, no marks
    with open(tmp_path / "episodes.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, list(rows[0]))
        writer.writeheader()
        writer.writerows(reached)
    out = subprocess.run([*command, "--classical", "greedy", "hungarian", "--table", "3"], **_TEXT).stdout
    assert "by Time_C greedy." in out and "> " not in out and "a bound" not in out and "censored" not in out


_TEXT: dict = {"capture_output": True, "text": True, "check": True}


def _episode(method: str, size: str, k: int, time_c: float, reached: bool) -> dict[str, object]:
    return {"method": method, "map": f"{size}{k}", "size_class": size, "robots": 3, "seed": k,
            "explored_pct": 100.0, "time_e": 50, "covered_pct": 100.0, "time_c": time_c,
            "covered_of_discovered_pct": 100.0, "reached_e": True, "reached_c": reached}  # fmt: skip


# size class: per method, its episodes' (Time_C, reached 80 %); the Time_C cell each method prints
PAPER_TABLE_CASES = [
    pytest.param(
        "small",
        {"a": [(400, True), (410, True)], "b": [(300, True), (1000, False)], "c": [(500, True), (520, True)]},
        {"a": "**405.00 ± 63.53**", "b": "> 650.00", "c": "510.00 ± 127.06"},
        id="the bound exceeds the best known time: it stays best",
    ),
    pytest.param(
        "large",
        {"a": [(400, True), (410, True)], "b": [(300, True), (400, False)], "c": [(500, True), (520, True)]},
        {"a": "405.00 ± 63.53", "b": "> 350.00", "c": "510.00 ± 127.06"},
        id="a bound under the best known time: no best",
    ),
    pytest.param(
        "medium",
        {"a": [(400, False), (410, True)], "b": [(300, False), (400, False)]},
        {"a": "> 405.00", "b": "> 350.00"},
        id="every time censored: no best",
    ),
]


@pytest.mark.parametrize(("size", "episodes", "cells"), PAPER_TABLE_CASES)
def test_paper_tables_marks_censored_times_and_never_bolds_them(
    size: str,
    episodes: dict[str, list[tuple[float, bool]]],
    cells: dict[str, str],
    load_script: Callable[[str], ModuleType],
) -> None:
    from areasearch.harness.report import CENSORED_NOTE, summarize

    records = [_episode(m, size, k, t, ok) for m, eps in episodes.items() for k, (t, ok) in enumerate(eps)]
    out = load_script("paper_tables").tables(summarize(records).to_dict(), list(episodes))
    assert out.startswith(CENSORED_NOTE + "\n")
    for method, cell in cells.items():
        row = next(line for line in out.splitlines() if line.startswith(f"| {method} |"))
        assert row.split(" | ")[4] == cell, row  # Time_C
        assert row.split(" | ")[2] == "**50.00 ± 0.00**", row  # Time_E: all reached, all best
    reached = [r | {"reached_c": True} for r in records]  # an older summary without the count reads the same
    assert "> " not in load_script("paper_tables").tables(summarize(reached).to_dict(), list(episodes))


def test_seed_summary_curves_overlay_the_budgets_of_each_policy(
    tmp_path: Path, root: Path, load_script: Callable[[str], ModuleType]
) -> None:
    summary = load_script("seed_summary")
    training = tmp_path / "training"
    for run, rows in {
        "dahgnn-120k-s0": [(20, 70.0), (20, 72.0), (40, 74.0)],
        "dahgnn-120k-s1": [(20, 71.0)],
        "dahgnn-300k-s0": [(50, 73.0), (100, 76.0), (100, 78.0)],
        "dahgnn-300k-s1": [],  # unfinished: no eval.csv
        "dahgnn-300k-extra-s0": [(50, 10.0)],  # another policy's run whose name starts alike
    }.items():
        (training / run).mkdir(parents=True)
        if rows:
            lines = ["iteration,decisions,coverage_auc"] + [f"{d // 10},{d},{a}" for d, a in rows]
            (training / run / "eval.csv").write_text("\n".join(lines) + "\n")
    runs = summary.curve_runs(training, "dahgnn", ["120k", "300k", "60k"])
    assert {b: [r.name for r in rs] for b, rs in runs.items()} == {
        "120k": ["dahgnn-120k-s0", "dahgnn-120k-s1"],
        "300k": ["dahgnn-300k-s0"],
    }
    assert summary.validation_scores(training / "dahgnn-300k-s0")[:2] == ([50, 100], [73.0, 77.0])
    assert summary.curve_runs(training, "dahgnn-120k") == {"": runs["120k"]}
    script = [sys.executable, str(root / "scripts" / "seed_summary.py"), "--training", str(training)]
    done = subprocess.run(
        [*script, "--curves", str(tmp_path / "c.png"), "--policies", "dahgnn", "--budgets", "120k", "300k"],
        capture_output=True, text=True,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "c.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    missing = subprocess.run(
        [*script, "--curves", str(tmp_path / "d.png"), "--policies", "ncm", "--budgets", "300k"],
        capture_output=True, text=True,
    )  # fmt: skip
    assert missing.returncode == 2 and "no finished run (ncm-300k-s*)" in missing.stderr, missing.stderr
    assert not (tmp_path / "d.png").exists()
    alone = subprocess.run([*script, "--budgets", "300k"], capture_output=True, text=True)
    assert alone.returncode == 2 and "--budgets draws curves" in alone.stderr
