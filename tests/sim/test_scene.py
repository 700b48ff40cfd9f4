"""Tests for scene loading (areasearch.sim.scene): size classes, grids, bundled maps, PNG folders, ROS YAML."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from PIL import Image

from areasearch.errors import MapError
from areasearch.sim.mapfiles import ROS_REQUIRED_KEYS
from areasearch.sim.scene import (
    Scene,
    bundled_index,
    largest_component,
    load_scene,
    scene_from_grid,
    scene_source,
    size_class_of,
)

# ---------------------------------------------------------------------------------- helpers


def _write_png(path: Path, pixels: np.ndarray, mode: str | None = None) -> Path:
    image = Image.fromarray(pixels)
    if mode is not None:
        image = image.convert(mode)
    image.save(path)
    return path


def _write_index(folder: Path, entries: list[dict[str, Any]]) -> Path:
    path = folder / "index.json"
    path.write_text(json.dumps({"maps": entries}))
    return path


def _room(h: int = 12, w: int = 16, margin: int = 2) -> np.ndarray:
    """Shared-format image: 0 (occupied) frame around a free (255) rectangle."""
    pixels = np.zeros((h, w), dtype=np.uint8)
    pixels[margin : h - margin, margin : w - margin] = 255
    return pixels


ROS_BASE: dict[str, Any] = {
    "image": "map.pgm",
    "resolution": 0.1,
    "origin": [0.0, 0.0, 0.0],
    "negate": 0,
    "occupied_thresh": 0.65,
    "free_thresh": 0.196,
}


def _write_ros(folder: Path, pixels: np.ndarray, image_name: str = "map.pgm", **changes: Any) -> Path:
    """Write ``pixels`` as ``folder/image_name`` and a map_server YAML ``folder/map.yaml`` naming it."""
    image_path = folder / image_name
    image_path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(pixels).save(image_path)
    data = {**ROS_BASE, "image": image_name, **changes}
    yaml_path = folder / "map.yaml"
    yaml_path.write_text(yaml.safe_dump(data))
    return yaml_path


# ---------------------------------------------------------------------------------- size classes


@pytest.mark.parametrize(
    ("area", "expected"),
    [
        (0.0, "small"),
        (10.0, "small"),
        (31.0, "small"),
        (33.4, "small"),
        (33.6, "medium"),
        (36.0, "medium"),
        (50.0, "medium"),
        (66.0, "medium"),
        (67.4, "medium"),
        (67.6, "large"),
        (69.0, "large"),
        (1000.0, "large"),
        (5000.0, "large"),
    ],
)
def test_size_class_of_bands_and_gaps(area: float, expected: str) -> None:
    assert size_class_of(area) == expected


@pytest.mark.parametrize("area", [-0.1, -100.0, math.nan, math.inf])
def test_size_class_of_rejects_bad_area(area: float) -> None:
    with pytest.raises(MapError, match="free area"):
        size_class_of(area)


# ---------------------------------------------------------------------------------- components


def test_largest_component_keeps_largest_only() -> None:
    free = np.zeros((7, 9), dtype=bool)
    free[1:4, 1:4] = True  # 9 cells
    free[5, 5:8] = True  # 3 cells
    free[1, 7] = True  # 1 cell
    mask = largest_component(free)
    expected = np.zeros_like(free)
    expected[1:4, 1:4] = True
    assert mask.dtype == bool
    np.testing.assert_array_equal(mask, expected)


def test_largest_component_diagonal_touch_does_not_connect() -> None:
    free = np.zeros((6, 6), dtype=bool)
    free[0:2, 0:2] = True  # 4 cells, block A
    free[2:5, 2:5] = True  # 9 cells, block B touches A only diagonally at (1,1)-(2,2)
    mask = largest_component(free)
    assert mask.sum() == 9
    assert not mask[0:2, 0:2].any()
    assert mask[2:5, 2:5].all()
    # Alone, A and a diagonal neighbour of the same size: still two components.
    checker = np.zeros((4, 4), dtype=bool)
    checker[0, 0] = checker[1, 1] = True
    assert largest_component(checker).sum() == 1


def test_largest_component_empty() -> None:
    mask = largest_component(np.zeros((4, 5), dtype=bool))
    assert mask.shape == (4, 5)
    assert not mask.any()


# ---------------------------------------------------------------------------------- scene_from_grid


def test_scene_from_grid_pocket_becomes_obstacle() -> None:
    free = np.zeros((8, 10), dtype=bool)
    free[1:6, 1:5] = True  # main room, 20 cells
    free[2:4, 7:9] = True  # unreachable pocket, 4 cells (separated by walls)
    scene = scene_from_grid("g", free, 0.1, wall_height_m=2.5)
    assert scene.shape == (8, 10)
    assert scene.origin_xy == (0.0, 0.0)
    assert scene.free.sum() == 20
    assert not scene.free[2:4, 7:9].any()
    np.testing.assert_array_equal(scene.height_m[2:4, 7:9], np.float32(2.5))
    assert scene.free_area_m2 == pytest.approx(20 * 0.01)


def test_scene_from_grid_heights_zero_on_free_cells() -> None:
    free = np.zeros((6, 6), dtype=bool)
    free[1:5, 1:5] = True
    given = np.full((6, 6), 0.7, dtype=np.float32)
    given[0, :] = 0.0  # no given height: falls back to the wall height
    scene = scene_from_grid("g", free, 0.2, wall_height_m=3.0, height_m=given)
    assert scene.height_m.dtype == np.float32
    assert (scene.height_m[scene.free] == 0.0).all()
    assert (scene.height_m[~scene.free] > 0.0).all()
    np.testing.assert_array_equal(scene.height_m[0, :], np.float32(3.0))
    np.testing.assert_array_equal(scene.height_m[5, 1:5], np.float32(0.7))


def test_scene_from_grid_pads_free_border() -> None:
    free = np.zeros((5, 6), dtype=bool)
    free[0:3, 0:4] = True  # touches the south and west borders
    scene = scene_from_grid("g", free, 0.5, origin_xy=(10.0, -4.0))
    assert scene.shape == (7, 8)
    assert scene.origin_xy == pytest.approx((9.5, -4.5))
    # Cell [iy, ix] of the input is cell [iy + 1, ix + 1] of the scene, at the same world place.
    assert scene.free[1:4, 1:5].all()
    assert scene.free.sum() == 12
    assert not scene.free[0].any() and not scene.free[-1].any()
    assert not scene.free[:, 0].any() and not scene.free[:, -1].any()
    np.testing.assert_allclose(scene.cell_to_world(np.array([1, 1])), [10.25, -3.75])
    assert (scene.height_m[scene.free] == 0.0).all()
    assert (scene.height_m[~scene.free] > 0.0).all()


def test_scene_from_grid_no_pad_when_sealed() -> None:
    free = np.zeros((5, 6), dtype=bool)
    free[1:4, 1:5] = True
    scene = scene_from_grid("g", free, 0.5, origin_xy=(1.0, 2.0))
    assert scene.shape == (5, 6)
    assert scene.origin_xy == (1.0, 2.0)


def test_scene_from_grid_no_free_cell() -> None:
    with pytest.raises(MapError, match="no free cell"):
        scene_from_grid("empty_grid", np.zeros((5, 5), dtype=bool), 0.1)


# ---------------------------------------------------------------------------------- bundled maps


def test_bundled_maps_load_and_match_index() -> None:
    index = bundled_index()
    assert len(index) >= 60
    ids = [entry["id"] for entry in index]
    assert len(set(ids)) == len(ids)
    for entry in index:
        assert entry.get("license"), entry["id"]
        assert entry.get("source_repo"), entry["id"]
        scene = load_scene(entry["id"])
        assert isinstance(scene, Scene)
        assert scene.name == entry["id"]
        assert scene.free_area_m2 == pytest.approx(entry["free_area_m2"], rel=0.01), entry["id"]
        assert scene.size_class == entry["size_class"], entry["id"]
        assert scene.meta.get("license") == entry["license"]
        assert scene.meta.get("source_repo") == entry["source_repo"]
    assert {entry["size_class"] for entry in index} == {"small", "medium", "large"}


# ---------------------------------------------------------------------------------- PNG folders


def test_png_in_folder_loads_with_resolution(tmp_path: Path) -> None:
    _write_png(tmp_path / "room.png", _room(12, 16, 2))
    _write_index(tmp_path, [{"file": "room.png", "resolution_m_per_px": 0.1}])
    scene = load_scene(str(tmp_path / "room.png"))
    assert scene.cell_m == pytest.approx(0.1)
    assert scene.shape == (12, 16)
    assert scene.free.sum() == 8 * 12
    assert scene.free_area_m2 == pytest.approx(8 * 12 * 0.01)
    assert scene.name == "room"


def test_png_folder_resolution_from_format(tmp_path: Path) -> None:
    _write_png(tmp_path / "room.png", _room())
    (tmp_path / "index.json").write_text(
        json.dumps({"format": {"resolution_m_per_px": 0.25}, "maps": [{"file": "room.png"}]})
    )
    assert load_scene(str(tmp_path / "room.png")).cell_m == pytest.approx(0.25)


def test_png_unknown_and_image_orientation(tmp_path: Path) -> None:
    pixels = np.zeros((10, 10), dtype=np.uint8)
    pixels[1:4, 2:8] = 255  # free near the top of the image (north)
    pixels[6:9, 2:8] = 127  # unknown near the bottom: a wall
    _write_png(tmp_path / "m.png", pixels)
    _write_index(tmp_path, [{"file": "m.png", "resolution_m_per_px": 0.05}])
    scene = load_scene(tmp_path / "m.png")
    rows = np.flatnonzero(scene.free.any(axis=1))
    np.testing.assert_array_equal(rows, [6, 7, 8])
    assert scene.free.sum() == 18


def test_folder_draws_among_maps(tmp_path: Path) -> None:
    sizes = {"a.png": (8, 8), "b.png": (10, 12), "c.png": (14, 9)}
    for name, (h, w) in sizes.items():
        _write_png(tmp_path / name, _room(h, w, 1))
    _write_index(tmp_path, [{"file": name, "resolution_m_per_px": 0.1} for name in sizes])
    drawn = [load_scene(str(tmp_path), np.random.default_rng(seed)).name for seed in range(24)]
    assert set(drawn) <= {"a", "b", "c"}
    assert len(set(drawn)) >= 2
    again = [load_scene(tmp_path, np.random.default_rng(seed)).name for seed in range(24)]
    assert again == drawn
    source = scene_source(str(tmp_path))
    assert sorted(source.names) == sorted(sizes)
    first = source.sample(np.random.default_rng(5))
    second = source.sample(np.random.default_rng(5))
    assert first.name == second.name
    np.testing.assert_array_equal(first.free, second.free)


def test_png_without_index_json(tmp_path: Path) -> None:
    folder = tmp_path / "noindex_folder"
    folder.mkdir()
    _write_png(folder / "room.png", _room())
    with pytest.raises(MapError, match="noindex_folder") as info:
        load_scene(str(folder / "room.png"))
    assert "index.json" in str(info.value)
    with pytest.raises(MapError, match="noindex_folder"):
        load_scene(str(folder))


def test_png_rgb_mode(tmp_path: Path) -> None:
    _write_png(tmp_path / "rgb.png", _room(), mode="RGB")
    _write_index(tmp_path, [{"file": "rgb.png", "resolution_m_per_px": 0.1}])
    with pytest.raises(MapError, match="RGB") as info:
        load_scene(str(tmp_path / "rgb.png"))
    assert "rgb.png" in str(info.value)
    assert "mode" in str(info.value)


@pytest.mark.parametrize("fraction", [0.05, 0.3, 0.6, 0.9])
def test_png_truncated(tmp_path: Path, fraction: float) -> None:
    rng = np.random.default_rng(0)
    pixels = np.where(rng.random((64, 64)) < 0.8, 255, 0).astype(np.uint8)  # noisy: a long IDAT
    _write_png(tmp_path / "full.png", pixels)
    data = (tmp_path / "full.png").read_bytes()
    (tmp_path / "cut.png").write_bytes(data[: int(len(data) * fraction)])
    _write_index(tmp_path, [{"file": "cut.png", "resolution_m_per_px": 0.1}])
    with pytest.raises(MapError, match=re.escape("cut.png")):
        load_scene(str(tmp_path / "cut.png"))


def test_text_file_renamed_png(tmp_path: Path) -> None:
    (tmp_path / "notes.png").write_text("this is not an image\n" * 10)
    _write_index(tmp_path, [{"file": "notes.png", "resolution_m_per_px": 0.1}])
    with pytest.raises(MapError, match=re.escape("notes.png")):
        load_scene(str(tmp_path / "notes.png"))


def test_png_not_listed_in_index(tmp_path: Path) -> None:
    _write_png(tmp_path / "room.png", _room())
    _write_png(tmp_path / "other.png", _room())
    _write_index(tmp_path, [{"file": "room.png", "resolution_m_per_px": 0.1}])
    with pytest.raises(MapError, match=re.escape("other.png")):
        load_scene(str(tmp_path / "other.png"))


def test_png_all_occupied(tmp_path: Path) -> None:
    _write_png(tmp_path / "blank.png", np.zeros((10, 10), dtype=np.uint8))
    _write_index(tmp_path, [{"file": "blank.png", "resolution_m_per_px": 0.1}])
    with pytest.raises(MapError, match="no free cell"):
        load_scene(str(tmp_path / "blank.png"))


def test_index_format_not_object(tmp_path: Path) -> None:
    _write_png(tmp_path / "room.png", _room())
    (tmp_path / "index.json").write_text(json.dumps({"format": 5, "maps": [{"file": "room.png"}]}))
    with pytest.raises(MapError, match=re.escape("index.json")):
        load_scene(str(tmp_path / "room.png"))


# ---------------------------------------------------------------------------------- ROS map_server YAML

PROBE_VALUES = (0, 100, 205, 254, 255)


def _probe_image(wall: int, free: int) -> np.ndarray:
    """Image whose row 1 is a free corridor; probe pixels hang below it at row 2, columns 2, 4, 6, 8, 10."""
    pixels = np.full((7, 13), wall, dtype=np.uint8)
    pixels[1, 1:12] = free
    for k, value in enumerate(PROBE_VALUES):
        pixels[2, 2 + 2 * k] = value
    return pixels


@pytest.mark.parametrize(
    ("negate", "expected_free"),
    [
        # p = (255 - v) / 255: 0 -> 1.0, 100 -> 0.61, 205 -> 0.196 (not < 0.196), 254 -> 0.004, 255 -> 0
        (0, {0: False, 100: False, 205: False, 254: True, 255: True}),
        # p = v / 255: 0 -> 0, 100 -> 0.39, 205 -> 0.80, 254 / 255 -> ~1
        (1, {0: True, 100: False, 205: False, 254: False, 255: False}),
    ],
)
def test_ros_trinary_thresholds(tmp_path: Path, negate: int, expected_free: dict[int, bool]) -> None:
    wall, free = (0, 255) if negate == 0 else (255, 0)
    yaml_path = _write_ros(tmp_path, _probe_image(wall, free), negate=negate)
    scene = load_scene(str(yaml_path))
    assert scene.shape == (7, 13)  # sealed: no padding
    image_free = np.flipud(scene.free)  # back to image rows
    assert image_free[1, 1:12].all()
    for k, value in enumerate(PROBE_VALUES):
        assert bool(image_free[2, 2 + 2 * k]) is expected_free[value], (negate, value)
    assert scene.free.sum() == 11 + sum(expected_free.values())


def test_ros_png_image_and_origin(tmp_path: Path) -> None:
    pixels = np.zeros((6, 8), dtype=np.uint8)
    pixels[1:5, 1:7] = 254
    yaml_path = _write_ros(tmp_path, pixels, image_name="map.png", origin=[1.5, -2.0, 0.0], resolution=0.5)
    scene = load_scene(str(yaml_path))
    assert scene.origin_xy == pytest.approx((1.5, -2.0))
    assert scene.cell_m == pytest.approx(0.5)
    assert scene.free[1, 1]
    np.testing.assert_allclose(scene.cell_to_world(np.array([1, 1])), [1.5 + 0.75, -2.0 + 0.75])
    np.testing.assert_array_equal(scene.world_to_cell(np.array([2.25, -1.25])), [1, 1])
    assert scene.meta["ros_yaml"] == str(yaml_path)


def test_ros_image_relative_to_yaml(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    folder = tmp_path / "maps"
    pixels = np.zeros((6, 6), dtype=np.uint8)
    pixels[1:5, 1:5] = 255
    yaml_path = _write_ros(folder, pixels, image_name="img/floor.pgm")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)  # the image must be found next to the yaml, not in the cwd
    scene = load_scene(str(yaml_path))
    assert scene.free.sum() == 16
    assert scene.name == "map"


def test_ros_image_y_flip(tmp_path: Path) -> None:
    pixels = np.zeros((8, 6), dtype=np.uint8)
    pixels[0:2, 1:5] = 255  # image rows 0-1: the NORTH edge, touching the border
    yaml_path = _write_ros(tmp_path, pixels, origin=[0.0, 0.0, 0.0])
    scene = load_scene(str(yaml_path))
    assert scene.shape == (10, 8)  # padded because free touches the border
    assert scene.origin_xy == pytest.approx((-0.1, -0.1))
    rows = np.flatnonzero(scene.free.any(axis=1))
    np.testing.assert_array_equal(rows, [7, 8])  # high iy; row 9 is the padding
    # The image's top-left free pixel (row 0, col 1) is at the map's north: y = H * res - res / 2.
    np.testing.assert_allclose(scene.cell_to_world(np.array([8, 2])), [0.15, 0.75])


def test_ros_image_y_flip_sealed(tmp_path: Path) -> None:
    pixels = np.zeros((8, 6), dtype=np.uint8)
    pixels[1, 1:5] = 255
    pixels[2, 2] = 255
    scene = load_scene(str(_write_ros(tmp_path, pixels)))
    assert scene.shape == (8, 6)
    assert scene.free[6, 1:5].all() and scene.free[5, 2]
    assert scene.free.sum() == 5


@pytest.mark.parametrize("key", ROS_REQUIRED_KEYS)
def test_ros_missing_key(tmp_path: Path, key: str) -> None:
    pixels = _room(6, 6, 1)
    yaml_path = _write_ros(tmp_path, pixels)
    data = yaml.safe_load(yaml_path.read_text())
    del data[key]
    yaml_path.write_text(yaml.safe_dump(data))
    with pytest.raises(MapError, match=key):
        load_scene(str(yaml_path))


def test_ros_required_keys_constant() -> None:
    assert set(ROS_REQUIRED_KEYS) == {"image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh"}


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("resolution", "abc"),
        ("resolution", -0.1),
        ("resolution", True),
        ("origin", [0.0, 0.0]),
        ("origin", "0 0 0"),
        ("negate", 2),
        ("occupied_thresh", "high"),
        ("free_thresh", None),
        ("image", 5),
        ("mode", "fancy"),
    ],
)
def test_ros_wrong_type(tmp_path: Path, field: str, value: Any) -> None:
    yaml_path = _write_ros(tmp_path, _room(6, 6, 1), **{field: value})
    with pytest.raises(MapError, match=field):
        load_scene(str(yaml_path))


def test_ros_thresholds_out_of_order(tmp_path: Path) -> None:
    yaml_path = _write_ros(tmp_path, _room(6, 6, 1), free_thresh=0.7, occupied_thresh=0.6)
    with pytest.raises(MapError, match="free_thresh"):
        load_scene(str(yaml_path))


def test_ros_image_missing(tmp_path: Path) -> None:
    yaml_path = _write_ros(tmp_path, _room(6, 6, 1))
    data = yaml.safe_load(yaml_path.read_text())
    data["image"] = "gone/missing_image.pgm"
    yaml_path.write_text(yaml.safe_dump(data))
    with pytest.raises(MapError, match=re.escape("missing_image.pgm")) as info:
        load_scene(str(yaml_path))
    assert str(tmp_path / "gone" / "missing_image.pgm") in str(info.value)


def test_ros_nonzero_yaw(tmp_path: Path) -> None:
    yaml_path = _write_ros(tmp_path, _room(6, 6, 1), origin=[0.0, 0.0, 0.3])
    with pytest.raises(MapError, match="yaw"):
        load_scene(str(yaml_path))


@pytest.mark.parametrize("text", ["- image\n- resolution\n", "just a string\n", "", "42\n", "a: [1, 2\n"])
def test_ros_not_a_mapping(tmp_path: Path, text: str) -> None:
    yaml_path = tmp_path / "bad.yaml"
    yaml_path.write_text(text)
    with pytest.raises(MapError, match=re.escape("bad.yaml")):
        load_scene(str(yaml_path))


def test_ros_yaml_not_text(tmp_path: Path) -> None:
    yaml_path = tmp_path / "binary.yaml"
    yaml_path.write_bytes(b"\xff\xfe\x00\x81garbage")
    with pytest.raises(MapError, match=re.escape("binary.yaml")):
        load_scene(str(yaml_path))


# ---------------------------------------------------------------------------------- procedural


@pytest.mark.parametrize("size_class", ["small", "medium", "large"])
def test_procedural_size_class_and_seed(size_class: str) -> None:
    spec = f"procedural:{size_class}"
    first = load_scene(spec, np.random.default_rng(3))
    assert first.size_class == size_class
    again = load_scene(spec, np.random.default_rng(3))
    np.testing.assert_array_equal(first.free, again.free)
    np.testing.assert_array_equal(first.height_m, again.height_m)
    assert first.origin_xy == again.origin_xy
    assert first.cell_m == again.cell_m
    assert (first.height_m[first.free] == 0.0).all()
    assert (first.height_m[~first.free] > 0.0).all()
    assert largest_component(first.free).sum() == first.free.sum()
    other = load_scene(spec, np.random.default_rng(4))
    assert other.size_class == size_class
    assert other.shape != first.shape or not np.array_equal(other.free, first.free)


@pytest.mark.parametrize("spec", ["procedural:huge", "procedural:", "procedural:Small"])
def test_procedural_unknown_class(spec: str) -> None:
    with pytest.raises(MapError, match="size class"):
        load_scene(spec, np.random.default_rng(0))


# ---------------------------------------------------------------------------------- scene_source


def test_scene_source_unknown_id() -> None:
    with pytest.raises(MapError, match="no_such_map"):
        scene_source("no_such_map")


def test_scene_source_missing_path() -> None:
    with pytest.raises(MapError, match=re.escape("missing_dir/nothing.png")):
        scene_source("missing_dir/nothing.png")


def test_scene_source_wrong_suffix(tmp_path: Path) -> None:
    path = tmp_path / "map.txt"
    path.write_text("hello")
    with pytest.raises(MapError, match=re.escape("map.txt")):
        scene_source(str(path))


def test_single_map_cached_and_deterministic() -> None:
    entry = bundled_index()[0]
    source = scene_source(entry["id"])
    assert source.names == [entry["file"]]
    a = source.sample(np.random.default_rng(0))
    b = source.sample(np.random.default_rng(1))
    assert a is b


def test_every_bundled_map_keeps_its_index_size_class_by_its_reachable_floor() -> None:
    """The size class is the reachable floor's (``Scene.size_class``); for every bundled map it is the
    class its index gives by free area, so the splits and tables group the maps as before."""
    from areasearch.sim.scene import bundled_index, load_scene

    for entry in bundled_index():
        scene = load_scene(entry["id"])
        assert scene.reachable_area_m2() <= scene.free_area_m2
        assert scene.size_class == entry["size_class"], entry["id"]
