"""Communication between the robots (areasearch.config.comm, areasearch.sim.comm): the three link models,
the groups the links make, the cell-exact segment walk against its plain reference, the seeded shadowing,
the refused settings and the last-heard bookkeeping."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest

from areasearch.config.comm import CommConfig
from areasearch.errors import ConfigError
from areasearch.sim.comm import (
    NO_SHADOWING,
    CommState,
    Shadowing,
    draw_shadowing,
    groups,
    links,
    received_power_dbm,
    segment_lengths,
    segment_lengths_reference,
)

CELL_M = 0.05
QUIET = CommConfig(model="signal", shadowing_max_db=0.0)
"""The signal model without shadowing: links are a function of the geometry alone."""


def _open(h: int = 100, w: int = 200) -> np.ndarray:
    return np.zeros((h, w), dtype=bool)


def _as_sets(found: list[np.ndarray]) -> list[list[int]]:
    return [g.tolist() for g in found]


def test_full_connects_everyone() -> None:
    walls = np.ones((10, 10), dtype=bool)
    xy = np.array([[0.1, 0.1], [100.0, 0.0], [-50.0, 3.0]])
    linked = links(CommConfig(), xy, walls, CELL_M)
    assert linked.shape == (3, 3) and linked.all()
    assert _as_sets(groups(linked)) == [[0, 1, 2]]


def test_disc_range_boundary() -> None:
    config = CommConfig(model="disc", range_m=2.0)
    xy = np.array([[0.0, 0.0], [2.0, 0.0], [4.0 + 1e-9, 0.0]])  # 0-1 at exactly the range, 1-2 just beyond
    linked = links(config, xy, _open(), CELL_M)
    assert linked.tolist() == [[True, True, False], [True, True, False], [False, False, True]]
    assert (linked == linked.T).all() and linked.diagonal().all()
    assert _as_sets(groups(linked)) == [[0, 1], [2]]
    assert not links(dataclasses.replace(config, range_m=0.0), xy[:2], _open(), CELL_M)[0, 1]


def test_multi_hop_chain_connects_its_ends() -> None:
    config = CommConfig(model="disc", range_m=1.0)
    xy = np.array([[0.0, 0.0], [5.0, 5.0], [0.9, 0.0], [1.8, 0.0]])  # A=0, B=2, C=3 a chain; 1 far away
    linked = links(config, xy, _open(), CELL_M)
    assert not linked[0, 3]  # A and C out of range of each other
    assert _as_sets(groups(linked)) == [[0, 2, 3], [1]]


def test_a_wall_breaks_a_signal_link_that_open_space_keeps() -> None:
    grid = _open(100, 200)  # 5 m x 10 m of 5 cm cells
    grid[50:100, 100:103] = True  # a 15 cm wall across the upper half, at x = 5.0-5.15 m
    pair_open = np.array([[3.0, 1.0], [7.0, 1.0]])  # 4 m apart below the wall's end
    pair_wall = np.array([[3.0, 4.0], [7.0, 4.0]])  # 4 m apart across the wall
    assert links(QUIET, pair_open, grid, CELL_M)[0, 1]
    assert not links(QUIET, pair_wall, grid, CELL_M)[0, 1]
    # the same in a map whose corner is not at the origin
    origin = (-12.5, 40.0)
    assert not links(QUIET, pair_wall + origin, grid, CELL_M, origin)[0, 1]
    assert links(QUIET, pair_open + origin, grid, CELL_M, origin)[0, 1]


def test_signal_free_space_range_follows_the_formula() -> None:
    # budget 19 dB: 20 log10(d / 1.4) < 19, so d < 1.4 * 10 ** 0.95 = 12.47 m
    reach = QUIET.ref_distance_m * 10 ** (QUIET.budget_db / (10 * QUIET.exponent_free))
    grid = _open(10, 400)  # 20 m long
    near = np.array([[0.5, 0.2], [0.5 + reach - 0.01, 0.2]])
    far = np.array([[0.5, 0.2], [0.5 + reach + 0.01, 0.2]])
    assert links(QUIET, near, grid, CELL_M)[0, 1]
    assert not links(QUIET, far, grid, CELL_M)[0, 1]
    # shadowing on the free stretch shortens the reach: 13 dB leave 6 dB, d < 1.4 * 10 ** 0.3 = 2.79 m
    assert not links(QUIET, near, grid, CELL_M, shadowing=Shadowing(13.0, 0.0))[0, 1]
    assert links(QUIET, np.array([[0.5, 0.2], [3.2, 0.2]]), grid, CELL_M, shadowing=Shadowing(13.0, 0.0))[0, 1]


def test_received_power_terms() -> None:
    config = QUIET
    at = received_power_dbm(config, np.array([0.0, 0.0, 0.5, 0.04, 1e-12]), np.array([0.0, 14.0, 0.0, 0.0, 1.0]))
    assert at[0] == pytest.approx(-51.0)  # tx - ref loss: no term below the reference lengths
    assert at[1] == pytest.approx(-51.0 - 20.0)  # 10x the reference distance, exponent 2
    assert at[2] == pytest.approx(-51.0 - 40.0 * math.log10(0.5 / 0.04))
    assert at[3] == pytest.approx(-51.0)  # one reference length of obstacle: log10(1) = 0
    assert at[4] == pytest.approx(-51.0)  # a rounding sliver is no obstacle
    obstacle, free = np.array([0.04, 0.0]), np.array([0.0, config.ref_distance_m])
    shadowed = received_power_dbm(config, obstacle, free, Shadowing(3.0, 5.0))
    assert shadowed.tolist() == pytest.approx([-56.0, -54.0])  # K with any obstacle, X from the reference on


def test_segment_walk_matches_the_reference_on_random_grids() -> None:
    rng = np.random.default_rng(7)
    for trial in range(40):
        h, w = rng.integers(1, 40, size=2)
        grid = rng.random((h, w)) < rng.uniform(0.0, 0.7)
        for k in range(25):
            if k % 5 == 0:  # on grid lines and along an axis, the walk's edge cases
                a = rng.integers(0, max(h, w), size=2).astype(float)
                shift = rng.integers(-10, 10)
                b = a + np.array([shift, 0] if k % 10 else [0, shift])
            else:  # anywhere, some ends off the grid
                a = rng.uniform(-2, (w + 2, h + 2))
                b = rng.uniform(-2, (w + 2, h + 2))
            got = segment_lengths(grid, a[0], a[1], b[0], b[1])
            want = segment_lengths_reference(grid, a[0], a[1], b[0], b[1])
            assert got == pytest.approx(want, abs=1e-9), (trial, k, a, b)
            assert sum(got) == pytest.approx(math.hypot(*(b - a)), abs=1e-9)
            back = segment_lengths(grid, b[0], b[1], a[0], a[1])
            assert back == pytest.approx(got, abs=1e-9)


def test_links_symmetric_with_true_diagonal_on_random_maps() -> None:
    rng = np.random.default_rng(3)
    grid = rng.random((60, 60)) < 0.2
    for _ in range(20):
        xy = rng.uniform(0, 60 * CELL_M, size=(5, 2))
        for config in (QUIET, CommConfig(model="signal"), CommConfig(model="disc", range_m=1.5)):
            linked = links(config, xy, grid, CELL_M, shadowing=draw_shadowing(config, rng))
            assert linked.dtype == bool and (linked == linked.T).all() and linked.diagonal().all()


def test_shadowing_is_seeded_and_within_its_range() -> None:
    config = CommConfig(model="signal")
    first = draw_shadowing(config, np.random.default_rng(11))
    assert first == draw_shadowing(config, np.random.default_rng(11))
    assert first != draw_shadowing(config, np.random.default_rng(12))
    rng = np.random.default_rng(0)
    draws = np.array([draw_shadowing(config, rng) for _ in range(4000)])
    assert draws.min() >= 0.0 and draws.max() <= 13.0
    assert draws.mean(axis=0) == pytest.approx([6.5, 6.5], abs=0.3)  # uniform: mean 6.5, sd 3.75
    assert np.histogram(draws[:, 0], bins=13, range=(0, 13))[0].min() > 200  # ~308 per 1 dB bin
    assert draw_shadowing(CommConfig(model="signal", shadowing_min_db=4.0, shadowing_max_db=4.0), rng) == (4.0, 4.0)
    assert draw_shadowing(QUIET, rng) == NO_SHADOWING
    # the same seed gives the same links
    grid = np.random.default_rng(5).random((80, 80)) < 0.15
    xy = np.random.default_rng(6).uniform(0, 4, size=(5, 2))
    one = links(config, xy, grid, CELL_M, shadowing=draw_shadowing(config, np.random.default_rng(1)))
    two = links(config, xy, grid, CELL_M, shadowing=draw_shadowing(config, np.random.default_rng(1)))
    assert (one == two).all()


BAD = [
    ("model", "radio", "comm.model"),
    ("model", None, "comm.model"),
    ("range_m", -1.0, "comm.range_m"),
    ("range_m", math.nan, "comm.range_m"),
    ("range_m", "5", "comm.range_m"),
    ("tx_power_dbm", math.inf, "comm.tx_power_dbm"),
    ("threshold_dbm", -400.0, "comm.threshold_dbm"),
    ("threshold_dbm", -51.0, "comm.threshold_dbm"),  # at the power received at the reference distance
    ("ref_loss_db", -1.0, "comm.ref_loss_db"),
    ("ref_distance_m", 0.0, "comm.ref_distance_m"),
    ("obstacle_ref_m", -0.1, "comm.obstacle_ref_m"),
    ("exponent_free", 0.0, "comm.exponent_free"),
    ("exponent_obstacle", -4.0, "comm.exponent_obstacle"),
    ("exponent_obstacle", 100.0, "comm.exponent_obstacle"),
    ("shadowing_min_db", -1.0, "comm.shadowing_min_db"),
    ("shadowing_max_db", True, "comm.shadowing_max_db"),
]


@pytest.mark.parametrize(("name", "value", "field"), BAD)
def test_bad_settings_are_refused_naming_the_field(name: str, value: Any, field: str) -> None:
    with pytest.raises(ConfigError, match=field.replace(".", r"\.")):
        dataclasses.replace(CommConfig(), **{name: value}).validate()


def test_good_settings_pass() -> None:
    assert CommConfig().validate() == CommConfig()
    CommConfig(model="disc", range_m=0.0).validate()
    CommConfig(model="signal", shadowing_min_db=2.0, shadowing_max_db=2.0).validate()
    with pytest.raises(ConfigError, match=r"comm\.shadowing_max_db"):
        CommConfig(shadowing_min_db=5.0, shadowing_max_db=4.0).validate()
    assert not CommConfig().active and CommConfig(model="disc").active
    assert CommConfig().budget_db == pytest.approx(19.0)


def test_last_heard_bookkeeping() -> None:
    config = CommConfig(model="disc", range_m=1.0)
    state = CommState.new(4)
    assert not state.heard(0).any() and (state.age(0, 5) == -1).all()
    # step 0: robots 0-1 together, 2-3 together
    xy = np.array([[0.0, 0.0], [0.5, 0.0], [5.0, 0.0], [5.5, 0.0]])
    found = state.update(0, xy, links(config, xy, _open(), CELL_M))
    assert _as_sets(found) == [[0, 1], [2, 3]]
    assert state.heard(0).tolist() == [True, True, False, False]
    assert state.positions[0, 1].tolist() == [0.5, 0.0] and np.isnan(state.positions[0, 2]).all()
    # step 1: all apart; nobody hears anybody new, old news stays
    xy1 = np.array([[0.0, 2.0], [2.0, 2.0], [4.0, 2.0], [6.0, 2.0]])
    state.update(1, xy1, links(config, xy1, _open(), CELL_M))
    assert state.positions[0, 1].tolist() == [0.5, 0.0] and state.steps[0, 1] == 0
    assert state.positions[0, 0].tolist() == [0.0, 2.0] and state.steps[0, 0] == 1
    assert state.age(0, 3).tolist() == [2, 3, -1, -1]
    # step 2: 1 meets 2; each learns the other now, and what the other last heard of its old partner
    xy2 = np.array([[0.0, 2.0], [3.0, 2.0], [3.5, 2.0], [6.0, 2.0]])
    state.update(2, xy2, links(config, xy2, _open(), CELL_M))
    assert state.positions[1, 2].tolist() == [3.5, 2.0] and state.steps[1, 2] == 2
    assert state.positions[1, 3].tolist() == [5.5, 0.0] and state.steps[1, 3] == 0  # relayed news of 3
    assert state.positions[2, 0].tolist() == [0.0, 0.0] and state.steps[2, 0] == 0  # relayed news of 0
    assert state.steps[0].tolist() == [2, 0, -1, -1]  # robot 0 was alone: only its own position is new
    # fresher own knowledge is not overwritten by a partner's older one
    assert state.positions[1, 0].tolist() == [0.0, 0.0] and state.steps[1, 0] == 0
    assert state.steps[2, 3] == 0  # 2 and 3 parted after step 0: 2's news of 3 is from then
