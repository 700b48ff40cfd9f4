"""Tests of the result tables and curves (:mod:`areasearch.harness.report`): hand-computed statistics."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from areasearch.harness.report import (
    METRICS,
    Summary,
    draw_curves,
    latex_escape,
    mean_ci,
    mean_curves,
    summarize,
    to_latex,
    to_markdown,
)

T_975_4 = 2.7764451051977987
"""Student t quantile t_{0.975} with 4 degrees of freedom (statistical tables)."""
T_975_2 = 4.302652729911275
"""t_{0.975} with 2 degrees of freedom."""


def test_mean_ci_is_the_t_based_half_width() -> None:
    stat = mean_ci([1.0, 2.0, 3.0, 4.0, 5.0])
    # s = sqrt(2.5), sem = s / sqrt(5) = sqrt(0.5)
    assert stat.mean == pytest.approx(3.0)
    assert stat.half_width == pytest.approx(T_975_4 * math.sqrt(0.5), rel=1e-9)
    assert stat.n == 5
    stat = mean_ci([10.0, 10.0, 16.0])  # mean 12, s = sqrt(12), sem = 2
    assert stat.mean == pytest.approx(12.0)
    assert stat.half_width == pytest.approx(T_975_2 * 2.0, rel=1e-9)


def test_mean_ci_of_one_value_has_no_interval() -> None:
    stat = mean_ci([7.5])
    assert (stat.mean, stat.half_width, stat.n) == (7.5, None, 1)
    with pytest.raises(ValueError):
        mean_ci([])


def _record(method: str, robots: int, size: str, e: float, te: int, c: float, tc: int, map_id: str = "m1") -> dict:
    return {
        "method": method,
        "map": map_id,
        "size_class": size,
        "robots": robots,
        "explored_pct": e,
        "time_e": te,
        "covered_pct": c,
        "time_c": tc,
        "covered_of_discovered_pct": min(100.0, c * 1.25),
    }


RECORDS = [
    # 3 robots, small: alpha explores more, beta is faster on Time_E, Time_C ties
    _record("alpha", 3, "small", 99.0, 500, 40.0, 3600),
    _record("alpha", 3, "small", 97.0, 700, 50.0, 3600, "m2"),
    _record("beta", 3, "small", 90.0, 300, 60.0, 3600),
    _record("beta", 3, "small", 92.0, 500, 70.0, 3600, "m2"),
    # 4 robots, large: one episode each
    _record("beta", 4, "large", 80.0, 1000, 30.0, 2000),
    _record("alpha", 4, "large", 85.0, 1200, 20.0, 2500),
    # 3 robots, medium
    _record("alpha", 3, "medium", 95.0, 900, 55.0, 3000),
]


def test_summary_groups_by_team_and_size_and_marks_the_best() -> None:
    summary = summarize(RECORDS, methods=["alpha", "beta"])
    assert [(t.robots, t.size_class) for t in summary.tables] == [(3, "small"), (3, "medium"), (4, "large")]
    small = summary.tables[0]
    assert small.maps == ("m1", "m2")
    alpha, beta = small.rows
    assert (alpha.method, beta.method) == ("alpha", "beta")
    assert [s.mean for s in alpha.stats] == pytest.approx([98.0, 600.0, 45.0, 3600.0, 56.25])
    assert [s.mean for s in beta.stats] == pytest.approx([91.0, 400.0, 65.0, 3600.0, 81.25])
    # Explo: max -> alpha; Time_E: min -> beta; Cover: max -> beta; Time_C: tie -> both
    assert alpha.best == (True, False, False, True, False)
    assert beta.best == (False, True, True, True, True)
    large = summary.tables[2]
    assert [r.method for r in large.rows] == ["alpha", "beta"]  # the given order, not the order seen
    assert large.rows[0].best == (True, False, False, False, False)
    assert large.rows[1].best == (False, True, True, True, True)
    assert all(s.half_width is None for s in large.rows[0].stats)
    assert [r.method for r in summary.tables[1].rows] == ["alpha"]


def test_markdown_and_latex_hold_every_method_and_bold_only_the_best() -> None:
    records = [dict(r, method="my_planner") if r["method"] == "beta" else r for r in RECORDS]
    summary = summarize(records, methods=["alpha", "my_planner"], settings={"seed": 0})
    md = to_markdown(summary)
    tex = to_latex(summary)
    for method in ("alpha", "my_planner"):
        assert f"| {method} |" in md
    assert "my\\_planner &" in tex and "alpha &" in tex
    alpha_small = next(line for line in md.splitlines() if line.startswith("| alpha |"))
    cells = alpha_small.split("|")[2:6]
    assert [c.strip().startswith("**") for c in cells] == [True, False, False, True]
    # 99 and 97: s = sqrt(2), sem = 1, t_{0.975, 1 dof} = 12.7062
    assert "**98.00 ± 12.71**" in alpha_small
    assert tex.count(r"\begin{table}") == 2  # one per team size
    assert tex.count(r"\begin{tabular}") == 3  # one per (team size, size class)
    assert r"\textbf{98.00 $\pm$ 12.71}" in tex
    assert r"\textbf{91.00" not in tex
    for metric in METRICS:
        assert metric.label in md and metric.latex in tex


def test_latex_escape() -> None:
    assert latex_escape("a_b%c&d") == r"a\_b\%c\&d"


def test_summary_json_round_trip() -> None:
    summary = summarize(RECORDS, methods=["alpha", "beta"], settings={"seed": 3, "max_steps": 3600})
    data = json.loads(json.dumps(summary.to_dict()))
    assert Summary.from_dict(data) == summary
    small_alpha = data["tables"][0]["rows"][0]
    assert small_alpha["method"] == "alpha"
    assert small_alpha["explored_pct"]["mean"] == pytest.approx(98.0)
    assert small_alpha["explored_pct"]["best"] is True
    assert data["tables"][2]["rows"][0]["time_e"]["ci95"] is None


def test_paper_tables_script_picks_rows_and_bolds_their_best(tmp_path: Path, root: Path) -> None:
    import subprocess
    import sys

    summary = summarize(RECORDS, methods=["alpha", "beta"], settings={"seed": 3})
    path = tmp_path / "summary.json"
    path.write_text(json.dumps(summary.to_dict()))
    script = root / "scripts" / "paper_tables.py"
    run = subprocess.run([sys.executable, str(script), str(path), "beta"], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert "| alpha |" not in run.stdout and run.stdout.count("| beta |") == 2  # small and large
    assert "| beta | **91.00 ± 12.71** |" in run.stdout  # the best of the rows shown, not of all
    assert "| beta | **80.00** |" in run.stdout  # one episode: no interval
    bad = subprocess.run([sys.executable, str(script), str(path), "gamma"], capture_output=True, text=True)
    assert bad.returncode == 2 and "gamma" in bad.stderr and "Traceback" not in bad.stderr


def test_paper_tables_script_summarises_every_episode_of_an_eval_folder(tmp_path: Path, root: Path) -> None:
    """A folder filled by two eval commands (one method each) gives one table with both methods."""
    import subprocess
    import sys

    from areasearch.harness.evaluate import CSV_FIELDS, csv_line

    rows = []
    for k, (method, cover) in enumerate([("a", 90.0), ("a", 94.0), ("b", 80.0), ("b", 80.0), ("a", 11.0)]):
        row = dict.fromkeys(CSV_FIELDS, 0) | {"reached_e": True, "reached_c": True}
        episode = k % 2 if k < 4 else 0  # the last row repeats a's episode 0: the first one counts
        row |= {"method": method, "map": "m1", "size_class": "medium", "robots": 3, "episode": episode,
                "covered_pct": cover, "covered_of_discovered_pct": cover}  # fmt: skip
        rows.append(row)
    (tmp_path / "episodes.csv").write_text(",".join(CSV_FIELDS) + "\n" + "".join(csv_line(r) for r in rows))
    script = root / "scripts" / "paper_tables.py"
    run = subprocess.run([sys.executable, str(script), str(tmp_path), "b", "a"], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    lines = [line for line in run.stdout.splitlines() if line.startswith("| a |") or line.startswith("| b |")]
    assert [line[:5] for line in lines] == ["| b |", "| a |"]  # the order asked for
    # a: 90 and 94 (the repeated episode is dropped): mean 92, s = sqrt(8), sem = 2, t_{0.975, 1 dof} = 12.7062
    assert "**92.00 ± 25.41**" in lines[1] and "| 2 |" in lines[1]
    other = subprocess.run(
        [sys.executable, str(script), str(tmp_path), "--robots", "4"], capture_output=True, text=True
    )
    assert other.returncode == 0 and "| a |" not in other.stdout  # no 4-robot episode
    empty = subprocess.run([sys.executable, str(script), str(tmp_path / "none")], capture_output=True, text=True)
    assert empty.returncode == 2 and "Traceback" not in empty.stderr


def test_mean_curves_interpolate_and_hold_the_last_value() -> None:
    curves = [
        {"method": "a", "steps": [0, 40], "explored_pct": [0.0, 40.0], "covered_pct": [0.0, 4.0]},
        {"method": "a", "steps": [0, 40, 80], "explored_pct": [0.0, 20.0, 80.0], "covered_pct": [0.0, 2.0, 8.0]},
        {"method": "b", "steps": [0, 80], "explored_pct": [10.0, 90.0], "covered_pct": [1.0, 9.0]},
    ]
    grid, means = mean_curves(curves, ["a", "b"], max_steps=80, points=5)
    assert grid.tolist() == [0, 20, 40, 60, 80]
    explored_a, covered_a, n_a = means["a"]
    assert n_a == 2
    # step 20: (20 + 10) / 2; step 60: (40 held + 50) / 2; step 80: (40 + 80) / 2
    assert explored_a.tolist() == pytest.approx([0.0, 15.0, 30.0, 45.0, 60.0])
    assert covered_a.tolist() == pytest.approx([0.0, 1.5, 3.0, 4.5, 6.0])
    assert means["b"][0].tolist() == pytest.approx([10.0, 30.0, 50.0, 70.0, 90.0])


def test_draw_curves_writes_a_png(tmp_path: Path) -> None:
    curves = [{"method": "a", "steps": [0, 40], "explored_pct": [0.0, 40.0], "covered_pct": [0.0, 4.0]}]
    path = draw_curves(curves, ["a"], 80, tmp_path / "curves.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert [p.name for p in tmp_path.iterdir()] == ["curves.png"]


def _paired_records() -> list[dict[str, object]]:
    recs: list[dict[str, object]] = []
    for seed, (ref_cover, delta) in enumerate([(80.0, 5.0), (60.0, 6.0), (90.0, 4.0), (70.0, 5.5)]):
        base = {"map": f"m{seed % 2}", "size_class": "large", "robots": 3, "seed": seed}
        recs.append({**base, "method": "greedy", "explored_pct": 90.0, "time_e": 100.0,
                     "covered_pct": ref_cover, "time_c": 1000.0 + seed,
                     "covered_of_discovered_pct": ref_cover})  # fmt: skip
        recs.append({**base, "method": "mine", "explored_pct": 90.0 + (seed % 2), "time_e": 100.0,
                     "covered_pct": ref_cover + delta, "time_c": 1200.0 + seed,
                     "covered_of_discovered_pct": ref_cover + delta})  # fmt: skip
    recs.append({"map": "m9", "size_class": "large", "robots": 3, "seed": 99, "method": "mine",
                 "explored_pct": 0.0, "time_e": 0.0, "covered_pct": 0.0, "time_c": 0.0,
                 "covered_of_discovered_pct": 0.0})  # fmt: skip  # unpaired
    return recs


def test_paired_differences_match_by_episode_and_give_verdicts() -> None:
    from areasearch.harness.report import paired_differences, paired_markdown

    rows = paired_differences(_paired_records(), "greedy")
    assert [(r.method, r.robots, r.size_class) for r in rows] == [("mine", 3, "large")]
    row = rows[0]
    explo, _time_e, cover, time_c, cover_of_discovered = row.stats
    assert cover_of_discovered.mean == pytest.approx(5.125)
    assert cover.n == 4  # the unpaired episode is left out
    assert cover.mean == pytest.approx(5.125)
    assert time_c.mean == pytest.approx(200.0) and time_c.half_width == pytest.approx(0.0)
    assert row.verdict(2) == "better"  # every cover difference is positive: the interval excludes 0
    assert row.verdict(3) == "worse"  # later by 200 steps in every episode
    assert row.verdict(1) == "same"  # identical times: zero width, zero mean
    assert explo.mean == pytest.approx(0.5) and row.verdict(0) == "same"  # half 0, half +1: interval spans 0
    md = paired_markdown(rows)
    assert "**+5.12 ±" in md and "*+200.00 ± 0.00*" in md
    assert row.to_dict()["covered_pct"]["verdict"] == "better"
    assert paired_differences(_paired_records(), "absent") == ()


def test_compare_episodes_script_pairs_episodes_and_counts_failures(tmp_path: Path, root: Path) -> None:
    import subprocess
    import sys

    header = "method,map,robots,episode,seed,explored_pct,covered_pct,collisions\n"
    (tmp_path / "old.csv").write_text(
        header + "greedy,m,3,0,11,100.0,97.0,2500\ngreedy,m,3,1,12,100.0,100.0,100\ncoscan,m,3,0,11,90.0,80.0,10\n"
        "coscan,m,3,1,13,100.0,100.0,5\n"
    )
    (tmp_path / "new.csv").write_text(
        header + "greedy,m,3,0,11,100.0,100.0,300\ngreedy,m,3,1,12,100.0,99.0,50\ncoscan,m,3,0,11,95.0,85.0,20\n"
        "coscan,m,3,1,13,100.0,100.0,5\n"
    )
    script = root / "scripts" / "compare_episodes.py"
    run = subprocess.run(
        [sys.executable, str(script), str(tmp_path / "old.csv"), str(tmp_path / "new.csv")],
        capture_output=True,
        text=True,
    )
    assert run.returncode == 0, run.stderr
    assert "| greedy | 2 | 1300 -> 175 | 98.50 -> 99.50 | 1 -> 0 | 1 -> 1 | 0 |" in run.stdout
    assert "| coscan | 2 | 8 -> 12 | 90.00 -> 92.50 | 0 -> 0 | 0 -> 0 | 1 |" in run.stdout  # one episode unchanged
    assert "| all | 4 |" in run.stdout
    (tmp_path / "other.csv").write_text(header + "greedy,m,3,0,99,100.0,100.0,1\n")
    bad = subprocess.run(
        [sys.executable, str(script), str(tmp_path / "old.csv"), str(tmp_path / "other.csv")],
        capture_output=True,
        text=True,
    )
    assert bad.returncode == 1 and "seed" in bad.stderr and "Traceback" not in bad.stderr


def test_run_report_ends_quietly_when_the_reader_closes_the_pipe() -> None:
    # a report far larger than a pipe's buffer, read one line at a time and closed after the first:
    # the writer must stop with status 1 and nothing on stderr (no BrokenPipeError traceback)
    code = (
        "from areasearch.harness.report import run_report\n"
        "def main():\n"
        "    for i in range(200_000):\n"
        "        print(f'| row {i} | ' + 'x' * 80 + ' |')\n"
        "    return 0\n"
        "run_report(main)\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert proc.stdout is not None and proc.stderr is not None
    assert proc.stdout.readline().startswith(b"| row 0 |")
    proc.stdout.close()
    stderr = proc.stderr.read().decode()
    assert proc.wait(timeout=60) == 1
    assert stderr == ""
    done = subprocess.run([sys.executable, "-c", code.replace("200_000", "3")], capture_output=True, timeout=60)
    assert done.returncode == 0 and done.stdout.decode().count("| row") == 3


def _timed(method: str, map_id: str, tc: int, reached: bool, horizon: int = 400) -> dict:
    return {
        **_record(method, 3, "small", 90.0, 100, 80.0 if reached else 50.0, tc if reached else horizon, map_id),
        "reached_e": True,
        "reached_c": reached,
    }


# (time_c, reached) of two episodes per method -> the Time_C cells printed, and which are bold
CENSORED_CASES = [
    pytest.param(
        {"a": [(300, True), (0, False)], "b": [(0, False), (0, False)]},
        {"a": "> 350.00", "b": "> 400.00"},
        set(),
        id="no-method-reached-80%-in-every-episode:no-best",
    ),
    pytest.param(
        {"a": [(300, True), (320, True)], "b": [(0, False), (0, False)]},
        {"a": "310.00 ± 127.06", "b": "> 400.00"},
        {"a"},
        id="a-known-time-below-every-lower-bound-is-best",
    ),
    pytest.param(
        {"a": [(390, True), (398, True)], "b": [(100, True), (0, False)]},
        {"a": "394.00 ± 50.82", "b": "> 250.00"},
        set(),
        id="a-censored-method-may-be-faster:no-best",
    ),
    pytest.param(
        {"a": [(300, True), (320, True)], "b": [(200, True), (210, True)]},
        {"a": "310.00 ± 127.06", "b": "205.00 ± 63.53"},
        {"b"},
        id="nothing-censored",
    ),
]


@pytest.mark.parametrize(("times", "cells", "bold"), CENSORED_CASES)
def test_a_time_not_reached_is_censored_and_never_best(
    times: dict[str, list[tuple[int, bool]]], cells: dict[str, str], bold: set[str]
) -> None:
    records = [_timed(m, f"m{k}", tc, ok) for m, eps in times.items() for k, (tc, ok) in enumerate(eps)]
    summary = summarize(records, methods=list(times))
    j = [m.key for m in METRICS].index("time_c")
    rows = {row.method: row for row in summary.tables[0].rows}
    assert {m for m, row in rows.items() if row.best[j]} == bold
    md = to_markdown(summary)
    for method, cell in cells.items():
        line = next(line for line in md.splitlines() if line.startswith(f"| {method} |"))
        shown = line.split("|")[5].strip()
        assert shown == (f"**{cell}**" if method in bold else cell), line
        assert rows[method].stats[j].censored == sum(not ok for _, ok in times[method])
    assert ("lower bound" in md) == any(not ok for eps in times.values() for _, ok in eps)
    tex = to_latex(summary)
    assert all(rf"$>$ {c[2:]}" in tex for c in cells.values() if c.startswith(">"))
    data = json.loads(json.dumps(summary.to_dict()))
    assert Summary.from_dict(data) == summary
    assert "censored" in data["tables"][0]["rows"][0]["time_c"]
    assert "censored" not in data["tables"][0]["rows"][0]["covered_pct"]


@pytest.mark.parametrize(
    ("doc", "decimals", "expected"),
    [
        ({"explored_pct": 47.71813080399265, "covered_pct": 13.0}, None, {"explored_pct": 47.72, "covered_pct": 13.0}),
        ({"explored_m2": 24.022500000000004, "path_length_m": [1.75, 16.740000000000002]}, None,
         {"explored_m2": 24.02, "path_length_m": [1.75, 16.74]}),
        ({"goal_xy": [0.27500000001, -4.97499999], "wall_s": 1.23456}, None,
         {"goal_xy": [0.275, -4.975], "wall_s": 1.235}),
        ({"mean": 1054.2000000000003, "steps": 400, "ok": True, "name": "x", "none": None}, None,
         {"mean": 1054.2, "steps": 400, "ok": True, "name": "x", "none": None}),
        ({"tables": [{"mean": 99.97194435555555, "ci95": None, "n": 5}]}, 4,
         {"tables": [{"mean": 99.9719, "ci95": None, "n": 5}]}),
        ({"yaw": -1e-20, "x_pct": -0.001}, None, {"yaw": -1e-20, "x_pct": 0.0}),
    ],
)  # fmt: skip
def test_json_numbers_are_rounded_to_what_they_mean(doc: dict, decimals: int | None, expected: dict) -> None:
    from areasearch.harness.report import json_ready

    rounded = json_ready(doc, decimals)
    assert rounded == expected
    assert json.dumps(rounded) == json.dumps(expected)  # no -0.0, no binary noise in the text
    assert type(json_ready(3)) is int and json_ready(float("nan")) != json_ready(float("nan"))
