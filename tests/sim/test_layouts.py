"""Tests for the procedural floor-layout generator (areasearch.sim.layouts)."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
from scipy import ndimage

from areasearch.sim.layouts import SIZE_BANDS_M2, Layout, generate_layout

CLASSES = ("small", "medium", "large")
SEEDS = (0, 1, 2, 3, 4, 5, 6, 7)
ROBOT_RADIUS_M = 0.18
WALL_HEIGHT_M = 2.5
# Practical limits the generator applies on top of the paper's bands.
PRACTICAL_BANDS_M2 = {
    "small": (10.0, 31.0),
    "medium": (36.0, 66.0),
    "large": (69.0, 400.0),
}

CASES = [(c, s) for c in CLASSES for s in SEEDS]


@cache
def _layout(size_class: str, seed: int) -> Layout:
    return generate_layout(size_class, np.random.default_rng(seed))


def _cspace(layout: Layout) -> np.ndarray:
    dist_m = ndimage.distance_transform_edt(layout.free) * layout.cell_m
    return np.asarray(dist_m > ROBOT_RADIUS_M + 0.5 * layout.cell_m)


def test_size_bands_constant() -> None:
    assert SIZE_BANDS_M2 == {
        "small": (0.0, 31.0),
        "medium": (36.0, 66.0),
        "large": (69.0, 1000.0),
    }


@pytest.mark.parametrize(("size_class", "seed"), CASES)
def test_area_within_band(size_class: str, seed: int) -> None:
    layout = _layout(size_class, seed)
    lo, hi = PRACTICAL_BANDS_M2[size_class]
    band_lo, band_hi = SIZE_BANDS_M2[size_class]
    assert lo <= layout.free_area_m2 <= hi
    assert band_lo <= layout.free_area_m2 <= band_hi
    expected = np.count_nonzero(layout.free) * layout.cell_m**2
    assert layout.free_area_m2 == pytest.approx(expected)


@pytest.mark.parametrize(("size_class", "seed"), CASES)
def test_types_and_shapes(size_class: str, seed: int) -> None:
    layout = _layout(size_class, seed)
    assert layout.free.dtype == np.bool_
    assert layout.height_m.dtype == np.float32
    assert layout.free.ndim == 2
    assert layout.free.shape == layout.height_m.shape
    assert layout.cell_m == 0.05


@pytest.mark.parametrize(("size_class", "seed"), CASES)
def test_single_four_connected_free_component(size_class: str, seed: int) -> None:
    layout = _layout(size_class, seed)
    four = ndimage.generate_binary_structure(2, 1)
    _, n = ndimage.label(layout.free, structure=four)
    assert n == 1


@pytest.mark.parametrize(("size_class", "seed"), CASES)
def test_border_margin_is_not_free(size_class: str, seed: int) -> None:
    free = _layout(size_class, seed).free
    assert not free[:2, :].any()
    assert not free[-2:, :].any()
    assert not free[:, :2].any()
    assert not free[:, -2:].any()


@pytest.mark.parametrize(("size_class", "seed"), CASES)
def test_heights_consistent_with_free(size_class: str, seed: int) -> None:
    layout = _layout(size_class, seed)
    h = layout.height_m
    assert np.all(h[layout.free] == 0.0)
    blocked = h[~layout.free]
    assert np.all(blocked > 0.0)
    # Every obstacle is either wall (exact wall height) or furniture in range.
    furniture = blocked[blocked != np.float32(WALL_HEIGHT_M)]
    assert np.all(furniture >= np.float32(0.4))
    assert np.all(furniture <= np.float32(1.0))


def test_furniture_present_and_optional() -> None:
    with_furn = [_layout(c, s) for c in ("medium", "large") for s in SEEDS]
    assert all(np.any((lay.height_m > 0) & (lay.height_m < WALL_HEIGHT_M)) for lay in with_furn)
    bare = generate_layout("large", np.random.default_rng(3), furniture=False)
    heights = bare.height_m[~bare.free]
    assert np.all(heights == np.float32(WALL_HEIGHT_M))


def test_furniture_block_sizes() -> None:
    layout = _layout("large", 1)
    furn = (layout.height_m > 0) & (layout.height_m < WALL_HEIGHT_M)
    labels, n = ndimage.label(furn)
    assert n > 0
    for sl in ndimage.find_objects(labels):
        assert sl is not None
        h_cells = sl[0].stop - sl[0].start
        w_cells = sl[1].stop - sl[1].start
        # Blocks may touch each other, so only the lower bound is per block.
        assert min(h_cells, w_cells) * layout.cell_m >= 0.4 - 1e-9


@pytest.mark.parametrize(("size_class", "seed"), CASES)
def test_configuration_space_dominant_component(size_class: str, seed: int) -> None:
    layout = _layout(size_class, seed)
    cspace = _cspace(layout)
    total = int(np.count_nonzero(cspace))
    assert total > 0
    labels, n = ndimage.label(cspace, structure=np.ones((3, 3), dtype=bool))
    assert n >= 1
    sizes = np.bincount(labels.ravel())[1:]
    assert sizes.max() >= 0.9 * total
    # C-space must reach most of the free floor (doors wide enough, rooms usable).
    assert total >= 0.3 * np.count_nonzero(layout.free)


@pytest.mark.parametrize("size_class", CLASSES)
@pytest.mark.parametrize("seed", [0, 11, 12345])
def test_same_seed_same_layout(size_class: str, seed: int) -> None:
    a = generate_layout(size_class, np.random.default_rng(seed))
    b = generate_layout(size_class, np.random.default_rng(seed))
    assert a.cell_m == b.cell_m
    assert np.array_equal(a.free, b.free)
    assert np.array_equal(a.height_m, b.height_m)
    assert a.height_m.tobytes() == b.height_m.tobytes()


@pytest.mark.parametrize("size_class", CLASSES)
def test_different_seeds_different_layouts(size_class: str) -> None:
    layouts = [_layout(size_class, s) for s in SEEDS]
    for i in range(len(layouts)):
        for j in range(i + 1, len(layouts)):
            a, b = layouts[i], layouts[j]
            same = a.free.shape == b.free.shape and np.array_equal(a.free, b.free)
            assert not same


def test_does_not_use_global_random_state() -> None:
    # The legacy global generator is used on purpose: it must stay untouched.
    np.random.seed(1)  # noqa: NPY002
    a = generate_layout("medium", np.random.default_rng(42))
    drawn_after = np.random.random()  # noqa: NPY002
    np.random.seed(1)  # noqa: NPY002
    assert np.random.random() == drawn_after  # noqa: NPY002
    np.random.seed(999)  # noqa: NPY002
    b = generate_layout("medium", np.random.default_rng(42))
    assert np.array_equal(a.free, b.free)
    assert np.array_equal(a.height_m, b.height_m)


def test_unknown_class_raises() -> None:
    with pytest.raises(ValueError, match="huge"):
        generate_layout("huge", np.random.default_rng(0))


def test_layout_is_frozen() -> None:
    layout = _layout("small", 0)
    with pytest.raises(AttributeError):
        layout.cell_m = 0.1  # type: ignore[misc]


@pytest.mark.parametrize("cell_m", [0.025, 0.1])
@pytest.mark.parametrize("size_class", CLASSES)
def test_other_resolutions(size_class: str, cell_m: float) -> None:
    layout = generate_layout(size_class, np.random.default_rng(5), cell_m=cell_m)
    lo, hi = PRACTICAL_BANDS_M2[size_class]
    assert layout.cell_m == cell_m
    assert lo <= layout.free_area_m2 <= hi
    _, n = ndimage.label(layout.free)
    assert n == 1


def test_custom_wall_height() -> None:
    layout = generate_layout("medium", np.random.default_rng(2), wall_height_m=3.0)
    blocked = layout.height_m[~layout.free]
    assert np.any(blocked == np.float32(3.0))
    other = blocked[blocked != np.float32(3.0)]
    assert np.all((other >= np.float32(0.4)) & (other <= np.float32(1.0)))


def test_area_spread_across_bands() -> None:
    for size_class in CLASSES:
        areas = [generate_layout(size_class, np.random.default_rng(100 + s)).free_area_m2 for s in range(12)]
        lo, hi = PRACTICAL_BANDS_M2[size_class]
        # Not all clumped in one end of the band.
        assert max(areas) - min(areas) >= 0.3 * (hi - lo)
