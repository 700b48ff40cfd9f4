"""The grid walk of a ray (areasearch.sim.raycast) and the mapper's carve built on it, against the plain
reference (the sorted grid-line crossings in closed form) on random rays."""

from __future__ import annotations

import math

import numpy as np
import pytest

from areasearch.sim.mapper import carve_ray
from areasearch.sim.raycast import ray_cells_reference, ray_in_grid, ray_next, ray_start

GH, GW = 30, 40
TIE = 1e-9
"""Cells: two grid-line crossings closer than this may come in either order in floating point."""


def _random_rays(n: int) -> list[tuple[float, float, float, float, float]]:
    """(px, py, dx, dy, t_max): random starts and headings, a quarter of them along an axis."""
    rng = np.random.default_rng(0)
    rays = []
    for k in range(n):
        angle = rng.uniform(-math.pi, math.pi) if k % 4 else rng.integers(4) * math.pi / 2
        dx, dy = math.cos(angle), math.sin(angle)
        if k % 4 == 0:  # exactly along the axis
            dx, dy = float(round(dx)), float(round(dy))
        rays.append((rng.uniform(0, GW), rng.uniform(0, GH), dx, dy, rng.choice([0.0, 0.5, 3.0, 60.0])))
    return rays


def _kernel_cells(px: float, py: float, dx: float, dy: float, t_max: float) -> list[tuple[int, int, float]]:
    ray = ray_start(px, py, dx, dy)
    cells = []
    while ray.t_enter <= t_max and ray_in_grid(ray, GH, GW):
        cells.append((ray.iy, ray.ix, ray.t_enter))
        ray = ray_next(ray)
    return cells


def _decided(cells: list[tuple[int, int, float]]) -> int:
    """How many leading cells of the reference lie before the first near-tie of two crossings."""
    for k in range(1, len(cells) - 1):
        if cells[k + 1][2] - cells[k][2] < TIE:
            return k + 1
    return len(cells)


@pytest.mark.parametrize("ray", _random_rays(400))
def test_the_walk_crosses_the_cells_of_the_reference(ray: tuple[float, float, float, float, float]) -> None:
    ref = ray_cells_reference(*ray, GH, GW)
    got = _kernel_cells(*ray)
    n = _decided(ref)
    assert [c[:2] for c in got[:n]] == [c[:2] for c in ref[:n]]
    np.testing.assert_allclose([c[2] for c in got[:n]], [c[2] for c in ref[:n]], rtol=0, atol=1e-9)
    if n == len(ref):
        assert len(got) == len(ref)
    assert ref[0][:2] == (math.floor(ray[1]), math.floor(ray[0]))  # starts in the camera's cell


def test_the_reference_walk_by_hand() -> None:
    """From (2.3, 4.5) towards (0.6, 0.8): up at t = 0.625, right at 7/6, up at 1.875, right at 17/6."""
    got = ray_cells_reference(2.3, 4.5, 0.6, 0.8, 3.0, 10, 10)
    assert [c[:2] for c in got] == [(4, 2), (5, 2), (5, 3), (6, 3), (6, 4)]
    np.testing.assert_allclose([c[2] for c in got], [0.0, 0.625, 7 / 6, 1.875, 17 / 6])
    assert ray_cells_reference(2.3, 4.5, 0.6, 0.8, 3.0, 6, 10)[-1][:2] == (5, 3)  # stops at the grid's edge


@pytest.mark.parametrize("ray", _random_rays(100))
def test_the_carve_marks_the_reference_cells_in_order(ray: tuple[float, float, float, float, float]) -> None:
    ref = ray_cells_reference(*ray, GH, GW)
    explored = np.zeros((GH, GW), dtype=bool)
    new_cells = np.empty(GH * GW, dtype=np.int64)
    n_new = carve_ray(*ray, explored, new_cells, 0)
    n = _decided(ref)
    assert [int(c) for c in new_cells[:n]] == [iy * GW + ix for iy, ix, _ in ref[:n]]
    assert n_new == len(ref) == explored.sum() or n < len(ref)
    assert carve_ray(*ray, explored, new_cells, n_new) == n_new  # nothing new the second time
