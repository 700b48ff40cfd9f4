"""The footprint's collision rule (areasearch.sim.footprint): kernels against the plain reference, and
the grid rules (traversable cells, joined neighbours, the team's region) against the world."""

from __future__ import annotations

import math

import numpy as np
import pytest

from areasearch.sim import footprint
from areasearch.sim.footprint import (
    footprint_offsets,
    segment_box_d2,
    segment_clearance_reference,
    segment_hits,
    team_region,
    traversable,
)

CELL = 0.05
RADIUS = 0.18


def _random_grid(rng: np.random.Generator, shape: tuple[int, int] = (30, 30), density: float = 0.04) -> np.ndarray:
    return rng.random(shape) < density


def test_segment_hits_agrees_with_the_plain_reference() -> None:
    """Random segments among random obstacle cells: the kernel's answer is the reference's wherever
    the reference's bound decides (the disc does not come within its sampling error of touching)."""
    rng = np.random.default_rng(0)
    decided = 0
    for _ in range(400):
        obstacles = _random_grid(rng)
        a = tuple(rng.uniform(0.0, 1.5, 2))
        length = rng.choice([0.0, 0.05, 0.25, 0.6])
        angle = rng.uniform(-math.pi, math.pi)
        b = (a[0] + length * math.cos(angle), a[1] + length * math.sin(angle))
        samples = 4001
        clearance = segment_clearance_reference(obstacles, CELL, a, b, samples)
        slack = 0.5 * length / (samples - 1) + 1e-7
        hit = segment_hits(obstacles, 0, 0, 0.0, 0.0, CELL, a[0], a[1], b[0], b[1], RADIUS)
        if clearance < RADIUS - slack:
            assert hit, (a, b, clearance)
            decided += 1
        elif clearance - slack > RADIUS:
            assert not hit, (a, b, clearance)
            decided += 1
    assert decided > 380


def test_segment_box_distance_by_hand() -> None:
    box = (1.0, 1.0, 2.0, 2.0)
    assert segment_box_d2(0.0, 1.5, 3.0, 1.5, *box) == 0.0  # through it
    assert segment_box_d2(0.0, 0.0, 0.5, 0.5, *box) == pytest.approx(0.5)  # towards a corner
    assert segment_box_d2(0.0, 3.0, 3.0, 3.0, *box) == pytest.approx(1.0)  # along a side
    assert segment_box_d2(0.0, 1.0, 1.0, 0.0, *box) == pytest.approx(0.5)  # the corner to the segment
    assert segment_box_d2(1.5, 1.5, 1.5, 1.5, *box) == 0.0  # a point inside


def test_a_window_counts_cells_outside_it_as_obstacles_unless_told() -> None:
    empty = np.zeros((10, 10), dtype=bool)
    # a disc of 0.18 m centred 0.1 m from the window's west edge overlaps the cells beyond it
    assert segment_hits(empty, 0, 0, 0.0, 0.0, CELL, 0.1, 0.25, 0.1, 0.25, RADIUS)
    assert not segment_hits(empty, 0, 0, 0.0, 0.0, CELL, 0.1, 0.25, 0.1, 0.25, RADIUS, False)
    assert not segment_hits(empty, 0, 0, 0.0, 0.0, CELL, 0.25, 0.25, 0.25, 0.25, RADIUS)


def test_offsets_are_the_cells_a_disc_on_a_centre_overlaps() -> None:
    offsets = {tuple(o) for o in footprint_offsets(CELL, RADIUS)}
    for dy in range(-6, 7):
        for dx in range(-6, 7):
            grid = np.zeros((13, 13), dtype=bool)
            grid[6 + dy, 6 + dx] = True
            hit = segment_hits(
                grid, 0, 0, 0.0, 0.0, CELL, 6.5 * CELL, 6.5 * CELL, 6.5 * CELL, 6.5 * CELL, RADIUS, False
            )
            assert hit == ((dy, dx) in offsets), (dy, dx)
    assert (0, 4) in offsets and (0, 5) not in offsets  # 3.5 cells < 3.6 <= 4.5
    assert (3, 3) in offsets and (3, 4) not in offsets  # sqrt(2 * 2.5²) = 3.54, sqrt(2.5² + 3.5²) = 4.30


def test_traversable_cells_are_the_centres_the_world_lets_a_robot_stand_on() -> None:
    rng = np.random.default_rng(1)
    obstacles = _random_grid(rng, (24, 24), 0.03)
    grid = traversable(obstacles, CELL, RADIUS)
    for iy in range(24):
        for ix in range(24):
            x, y = (ix + 0.5) * CELL, (iy + 0.5) * CELL
            assert grid[iy, ix] == (not segment_hits(obstacles, 0, 0, 0.0, 0.0, CELL, x, y, x, y, RADIUS)), (iy, ix)


def _moves_from(region: np.ndarray, obstacles: np.ndarray) -> tuple[int, int]:
    """(clear moves between neighbouring region cells, moves from the region to a traversable cell
    outside it that are clear): the second must be 0."""
    free = traversable(obstacles, CELL, RADIUS)
    inside = outside = 0
    h, w = region.shape
    for iy, ix in np.argwhere(region):
        for dy, dx in ((0, 1), (1, -1), (1, 0), (1, 1), (0, -1), (-1, 1), (-1, 0), (-1, -1)):
            ny, nx = iy + dy, ix + dx
            if not (0 <= ny < h and 0 <= nx < w and free[ny, nx]):
                continue
            a = ((ix + 0.5) * CELL, (iy + 0.5) * CELL)
            b = ((nx + 0.5) * CELL, (ny + 0.5) * CELL)
            if not segment_hits(obstacles, 0, 0, 0.0, 0.0, CELL, *a, *b, RADIUS):
                if region[ny, nx]:
                    inside += 1
                else:
                    outside += 1
    return inside, outside


def test_the_team_region_is_closed_under_clear_moves() -> None:
    rng = np.random.default_rng(2)
    for _ in range(5):
        obstacles = _random_grid(rng, (40, 40), 0.01)
        obstacles[:, 20] = True
        obstacles[18:26, 20] = False  # a doorway 0.4 m wide in a one-cell wall
        region = team_region(obstacles, CELL, RADIUS)
        inside, outside = _moves_from(region, obstacles)
        assert region.any() and inside > 0 and outside == 0


def _gap_m(a: np.ndarray, b: np.ndarray) -> float:
    """Least distance between a square of the cells ``a`` and one of ``b`` (K, 2), metres."""
    d = np.abs(a[:, None, :] - b[None, :, :]).astype(float)
    return float(np.sqrt((np.maximum(d - 1.0, 0.0) ** 2).sum(-1)).min()) * CELL


def test_a_doorway_diagonal_to_the_grid_joins_the_rooms_exactly_when_the_disc_fits() -> None:
    """A slot at 45° through a thick wall, rasterised (a staircase of squares on each side): the
    rooms are one region when the squares of its two sides leave more than the footprint's diameter
    between them (the disc passes straight along the slot), and two when they leave less."""
    n = 60
    iy, ix = np.mgrid[0:n, 0:n]
    u = (ix - iy) / math.sqrt(2.0)  # across the slot, cells
    v = (ix + iy) / math.sqrt(2.0) - n / math.sqrt(2.0)  # along the wall's normal, cells
    seen = set()
    for width_m in np.arange(0.36, 0.56, 0.01):
        wall = (np.abs(v) < 3) & (np.abs(u) * CELL > width_m / 2)
        gap = _gap_m(np.argwhere(wall & (u > 0)), np.argwhere(wall & (u < 0)))
        if abs(gap - 2 * RADIUS) < 0.005:
            continue  # the ends of the slot decide, not its sides
        obstacles = wall.copy()
        obstacles[[0, -1], :] = obstacles[:, [0, -1]] = True
        region = team_region(obstacles, CELL, RADIUS)
        joined = bool((region & (v > 3)).any() and (region & (v < -3)).any())
        assert joined == (gap > 2 * RADIUS), (width_m, gap)
        seen.add(joined)
    assert seen == {False, True}


def test_covered_is_the_union_of_the_footprints_on_the_centres() -> None:
    centres = np.zeros((21, 21), dtype=bool)
    centres[10, 10] = True
    cells = footprint.covered(centres, CELL, RADIUS)
    expected = np.zeros_like(centres)
    offsets = footprint_offsets(CELL, RADIUS)
    expected[10 + offsets[:, 0], 10 + offsets[:, 1]] = True
    assert np.array_equal(cells, expected)
