"""Weights of your own through every command: ``--weights PREFIX`` with each learned method (and alone)
in ``assign``, ``run``, ``render`` (``--method`` and ``--methods``), ``serve`` and the library
(``make_planner``, ``assign_goals``, ``choose_planner``). The weights replace the method's shipped ones,
and every answer names the method and the weights' SHA-256 (the hash ``eval --policy`` records).

The weights: the first-release DA-HGNN ablation in ``tests/data`` (a type-blind network: ``--weights``
alone names it ``dahgnn-no-type``) and a fresh NCM network written by ``save_policy``.
"""

from __future__ import annotations

import hashlib
import json
import subprocess
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from areasearch.cli import main
from areasearch.errors import ConfigError
from areasearch.harness.evaluate import check_policies
from areasearch.planners import LEARNED, PLANNERS, SHIPPED_POLICIES, choose_planner, make_planner
from areasearch.planners.learned import LearnedPlanner, weights_sha256
from areasearch.service.assign import OccupancyMap, assign_goals

CliRunner = Callable[..., subprocess.CompletedProcess[str]]

HalfKnown = Callable[..., OccupancyMap]

MINE = Path(__file__).resolve().parents[1] / "data" / "dahgnn-no-type-first-release"
"""A trained policy that is not a shipped one: ``MINE.safetensors`` + ``MINE.json``."""
MINE_SHA = hashlib.sha256(MINE.with_name(MINE.name + ".safetensors").read_bytes()).hexdigest()
MAP = "wrs2020_arena"
POSES = [(1.05, 1.55, 0.0), (0.55, 0.55, 0.5)]


@pytest.fixture(scope="module")
def ncm_weights(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A fresh NCM network saved as a policy (``save_policy``), with seeded weights."""
    import torch

    from areasearch.models.network import DAHGNN
    from areasearch.models.network_config import NetworkConfig
    from areasearch.models.weights import save_policy

    folder = tmp_path_factory.mktemp("ncm")
    torch.manual_seed(5)
    save_policy(folder / "policy", DAHGNN(NetworkConfig.ncm()), NetworkConfig.ncm())
    return folder / "policy"


# ---------------------------------------------------------------------------------- the library


def test_the_weights_hash_is_the_one_eval_records() -> None:
    assert weights_sha256(MINE) == MINE_SHA
    assert check_policies({"mine": str(MINE)}, ["mine"]) == {"mine": {"weights": str(MINE), "sha256": MINE_SHA}}
    with pytest.raises(ConfigError, match=r"absent\.safetensors: cannot read the weights"):
        weights_sha256(MINE.with_name("absent"))


@pytest.mark.parametrize("name", LEARNED)
def test_every_learned_method_plays_weights_of_your_own(name: str, half_known: HalfKnown) -> None:
    reference = LearnedPlanner(weights=str(MINE), name="reference")
    planner = make_planner(name, weights=str(MINE))
    assert isinstance(planner, LearnedPlanner) and planner.name == name and planner.weights_sha256 == MINE_SHA
    grid = half_known()
    mine = assign_goals(grid, POSES, name, planner_settings={"weights": str(MINE)})
    assert mine == assign_goals(grid, POSES, reference)  # the weights replace the method's own
    choice = choose_planner(name, MINE)
    assert (choice.method, choice.weights_sha256) == (name, MINE_SHA)
    assert choice.record() == {"weights": str(MINE), "weights_sha256": MINE_SHA}


def test_weights_alone_name_the_network_they_describe(ncm_weights: Path, root: Path, half_known: HalfKnown) -> None:
    assert choose_planner(weights=str(MINE)).method == "dahgnn-no-type"
    assert choose_planner(weights=ncm_weights).method == "ncm"
    for shipped in SHIPPED_POLICIES:
        if shipped in PLANNERS:
            assert choose_planner(weights=root / "src" / "areasearch" / "policies" / shipped).method == shipped
    grid = half_known()
    alone = assign_goals(grid, POSES, planner_settings={"weights": str(ncm_weights)})
    assert alone == assign_goals(grid, POSES, "ncm", planner_settings={"weights": str(ncm_weights)})
    assert choose_planner().method == "greedy" and choose_planner().record() == {}


def test_weights_for_a_policy_this_installation_does_not_ship(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delitem(PLANNERS, "dahgnn", raising=False)
    with pytest.raises(ConfigError, match="does not ship"):
        make_planner("dahgnn")
    planner = make_planner("dahgnn", weights=str(MINE))
    assert isinstance(planner, LearnedPlanner) and planner.weights_sha256 == MINE_SHA


@pytest.mark.parametrize(
    ("method", "weights", "message"),
    [
        ("greedy", str(MINE), "planner 'greedy' takes no weights: --weights (weights=...) is for a learned planner"),
        ("utility-40", str(MINE), "planner 'utility-40' takes no weights"),
        ("dahgnn", str(MINE.with_name("absent")), "absent.json: cannot read the policy config"),
        (None, str(MINE.with_name("absent")), "absent.json: cannot read the policy config"),
        ("dahgnn", "", "weights must be a path prefix"),
        (None, 3, "weights must be a path prefix"),
        ("teleport", str(MINE), "unknown planner 'teleport'"),
    ],
)
def test_weights_that_cannot_be_played_are_one_clear_error(
    method: str | None, weights: object, message: str, half_known: HalfKnown
) -> None:
    with pytest.raises(ConfigError) as err:
        choose_planner(method, weights)  # type: ignore[arg-type]
    assert message in str(err.value)
    with pytest.raises(ConfigError) as err:
        assign_goals(half_known(), POSES, method, planner_settings={"weights": weights})
    assert message in str(err.value)


# ---------------------------------------------------------------------------------- assign


def _assign(examples: Path, capsys: pytest.CaptureFixture[str], *options: str) -> dict[str, object]:
    args = ["assign", "--map", str(examples / "partial_map.yaml"), "--robots", str(examples / "robots.json")]
    assert main([*args, "--targets", str(examples / "targets.json"), *options]) == 0
    doc: dict[str, object] = json.loads(capsys.readouterr().out)
    return doc


@pytest.mark.parametrize("method", [*LEARNED, None])
def test_assign_plays_your_weights_and_names_them(
    method: str | None, capsys: pytest.CaptureFixture[str], examples: Path
) -> None:
    doc = _assign(examples, capsys, *(["--method", method] if method else []), "--weights", str(MINE))
    assert list(doc)[:4] == ["frame", "method", "weights", "weights_sha256"]
    assert doc["method"] == (method or "dahgnn-no-type")
    assert (doc["weights"], doc["weights_sha256"]) == (str(MINE), MINE_SHA)
    reference = _assign(examples, capsys, "--method", "dahgnn-untrained", "--weights", str(MINE))
    assert doc["robots"] == reference["robots"]


def test_assign_without_weights_names_no_weights(capsys: pytest.CaptureFixture[str], examples: Path) -> None:
    doc = _assign(examples, capsys)
    assert doc["method"] == "greedy" and "weights" not in doc and "weights_sha256" not in doc


# ---------------------------------------------------------------------------------- run, render


@pytest.mark.slow  # whole (short) episodes
def test_run_plays_your_weights(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    common = ["--map", MAP, "--robots", "2", "--max-steps", "80"]
    for options, method in ((["--method", "dahgnn"], "dahgnn"), ([], "dahgnn-no-type")):
        assert main(["run", *common, *options, "--weights", str(MINE), "--out", str(tmp_path / "a.png")]) == 0
        summary = json.loads(capsys.readouterr().out)
        assert (summary["method"], summary["weights"], summary["weights_sha256"]) == (method, str(MINE), MINE_SHA)
        assert (tmp_path / "a.png").stat().st_size > 0
    assert (
        main(["run", *common, "--method", "dahgnn-untrained", "--weights", str(MINE), "--out", str(tmp_path / "b.png")])
        == 0
    )
    same = json.loads(capsys.readouterr().out)
    keep = ("explored_pct", "covered_pct", "path_length_m", "decisions")
    assert {k: same[k] for k in keep} == {k: summary[k] for k in keep}  # the weights decide, not the name


@pytest.mark.slow  # whole (short) episodes, animated
def test_render_plays_your_weights_alone_and_among_methods(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    common = ["--map", MAP, "--robots", "2", "--max-steps", "80", "--every", "40"]
    assert main(["render", *common, "--method", "ncm", "--weights", str(MINE), "--out", str(tmp_path / "a.gif")]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert (summary["method"], summary["weights"], summary["weights_sha256"]) == ("ncm", str(MINE), MINE_SHA)
    assert main(["render", *common, "--weights", str(MINE), "--out", str(tmp_path / "b.gif")]) == 0
    assert json.loads(capsys.readouterr().out)["method"] == "dahgnn-no-type"
    out = tmp_path / "c.gif"
    assert main(["render", *common, "--methods", "greedy", "dahgnn", "--weights", str(MINE), "--out", str(out)]) == 0
    result = json.loads(capsys.readouterr().out.split("\n\n", 1)[1])
    rows = {row["method"]: row for row in result["methods"]}
    assert "weights" not in rows["greedy"]
    assert (rows["dahgnn"]["weights"], rows["dahgnn"]["weights_sha256"]) == (str(MINE), MINE_SHA)
    assert out.is_file() and out.with_suffix(".md").is_file()


# ---------------------------------------------------------------------------------- serve


def _request(examples: Path) -> dict[str, object]:
    from areasearch.service.assign import load_occupancy
    from areasearch.service.occupancy_msg import grid_message

    return {
        "map": grid_message(load_occupancy(examples / "partial_map.yaml")),
        "robots": json.loads((examples / "robots.json").read_text())["robots"],
        "targets": json.loads((examples / "targets.json").read_text())["targets"],
    }


@pytest.mark.slow  # two services, each with a worker process
def test_the_service_plays_your_weights_and_names_them(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], examples: Path, start_service: Callable[..., Any]
) -> None:
    body = _request(examples)
    cli = ["assign", "--map", str(examples / "partial_map.yaml"), "--robots", str(examples / "robots.json")]
    cli += ["--targets", str(examples / "targets.json")]
    for options, method in ((["--method", "dahgnn"], "dahgnn"), ([], "dahgnn-no-type")):
        (tmp_path / method).mkdir()
        service = start_service(tmp_path / method, *options, "--weights", str(MINE))
        try:
            text = service.text(body)  # status 200
            doc = json.loads(text)
            assert (doc["method"], doc["weights"], doc["weights_sha256"]) == (method, str(MINE), MINE_SHA)
            assert main([*cli, *options, "--weights", str(MINE)]) == 0
            assert capsys.readouterr().out == text  # byte for byte what `areasearch assign` prints
            # another method in the same service: its own weights, no weights named
            status, doc = service.request("POST", "/assign", {**body, "method": "greedy"})
            assert status == 200 and "weights" not in doc
            status, listing = service.request("GET", "/methods")
            assert listing["default"] == method
            (row,) = [m for m in listing["methods"] if m["name"] == method]
            assert (row["kind"], row["weights"], row["weights_sha256"]) == ("learned", str(MINE), MINE_SHA)
        finally:
            service.stop()


@pytest.mark.slow  # subprocesses
@pytest.mark.parametrize(
    ("args", "expect"),
    [
        (["--method", "greedy", "--weights", str(MINE)], "planner 'greedy' takes no weights"),
        (["--weights", str(MINE.with_name("absent"))], "absent.json: cannot read the policy config"),
    ],
)
def test_the_service_refuses_weights_it_cannot_play_before_listening(
    args: list[str], expect: str, run_cli: CliRunner
) -> None:
    result = run_cli("serve", "--port", "0", *args, timeout=300)
    assert result.returncode == 2, result.stderr
    assert "listening" not in result.stderr and "Traceback" not in result.stderr
    (line,) = result.stderr.strip().splitlines()
    assert line.startswith("areasearch: error:") and expect in line, result.stderr
