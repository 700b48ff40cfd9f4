"""The map error in evaluation results (:func:`areasearch.harness.episodes.map_error_record`): recorded in
``curves.jsonl`` and shown as a "Map err. (%)" summary column for imperfect worlds only; a default folder
and an older imperfect folder (curves without it) are summarised as before."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from areasearch.errors import AreaSearchError
from areasearch.harness.evaluate import EvalPlan, evaluate, read_curves
from areasearch.harness.report import MAP_ERROR, METRICS, Summary

MAP = "bormann_lab_c_rooms1"
NOISE = {"noise.odometry_forward": 0.02, "noise.odometry_turn": 0.02}
CURVE_KEYS = {"method", "map", "robots", "episode", "seed", "steps", "explored_pct", "covered_pct"}


def _run(out: Path, settings: dict[str, object] | None = None) -> None:
    plan = EvalPlan(["greedy", "random"], [2], [MAP], 1, 5, 120, out)
    evaluate(plan.with_settings(settings), progress=None)


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("maperr")
    _run(root / "default")
    _run(root / "noisy", NOISE)
    return {"default": root / "default", "noisy": root / "noisy"}


def test_only_an_imperfect_eval_records_the_map_error(runs: dict[str, Path]) -> None:
    for curve in read_curves(runs["default"] / "curves.jsonl").values():
        assert set(curve) == CURVE_KEYS
    assert "Map err." not in (runs["default"] / "summary.md").read_text()
    assert json.loads((runs["default"] / "summary.json").read_text())["metrics"] == [m.key for m in METRICS]

    curves = read_curves(runs["noisy"] / "curves.jsonl").values()
    assert len(curves) == 2
    for curve in curves:
        assert 0 < curve["map_error_pct"] < 100
        assert sum(curve["map_error_parts_pct"].values()) == pytest.approx(curve["map_error_pct"], abs=1e-3)
        assert set(curve["map_error_parts_pct"]) == {"phantom", "missed", "misplaced", "unmapped"}
        assert curve["map_error_steps"][0] == 0 and curve["map_error_steps"][-1] == curve["steps"][-1]
        assert curve["map_error_curve_pct"][-1] == curve["map_error_pct"]
        assert len(curve["map_error_steps"]) == len(curve["map_error_curve_pct"]) <= 12
    markdown = (runs["noisy"] / "summary.md").read_text()
    assert "| Map err. (%) | episodes |" in markdown
    doc = json.loads((runs["noisy"] / "summary.json").read_text())
    assert doc["metrics"][-1] == "map_error_pct"
    row = doc["tables"][0]["rows"][0]
    assert row["map_error_pct"]["n"] == 1 and row["map_error_pct"]["mean"] > 0
    assert Summary.from_dict(doc).metrics == (*METRICS, MAP_ERROR)
    assert "Map err." in (runs["noisy"] / "summary.tex").read_text()


def test_an_imperfect_folder_without_map_errors_is_summarised_without_the_column(
    runs: dict[str, Path], tmp_path: Path
) -> None:
    out = tmp_path / "old"
    out.mkdir()
    for name in ("episodes.csv", "config.json"):
        (out / name).write_bytes((runs["noisy"] / name).read_bytes())
    lines = (runs["noisy"] / "curves.jsonl").read_text().splitlines()
    old = [{k: v for k, v in json.loads(line).items() if not k.startswith("map_error")} for line in lines]
    (out / "curves.jsonl").write_text("".join(json.dumps(c, separators=(",", ":")) + "\n" for c in old))
    _run(out, NOISE)  # nothing to play: summarised from the files
    assert "Map err." not in (out / "summary.md").read_text()
    assert (runs["noisy"] / "episodes.csv").read_bytes() == (out / "episodes.csv").read_bytes()


def test_a_map_error_that_is_not_a_percentage_is_refused(runs: dict[str, Path], tmp_path: Path) -> None:
    line = (runs["noisy"] / "curves.jsonl").read_text().splitlines()[0]
    for bad in (150, -1, "5", True):
        path = tmp_path / "curves.jsonl"
        path.write_text(json.dumps({**json.loads(line), "map_error_pct": bad}) + "\n")
        with pytest.raises(AreaSearchError, match="map_error_pct must be a percentage from 0 to 100"):
            read_curves(path)
