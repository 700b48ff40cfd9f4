"""Write the bad-input corpus of ``tests/test_bad_inputs.py`` into this folder (the files are
committed; re-run this after changing it: ``python tests/bad_inputs/make_corpus.py``).

Maps are 0.05 m per cell. ``ros/good.yaml`` is a valid partial map (a 2.9 x 2.9 m room, its eastern
third unknown) that the robots files are placed on; every other file is broken in one way, named by
its file name, except the ones read correctly (``good16.yaml``: a 16-bit PGM of the same room;
``exponent.yaml``: ``resolution: 5e-2``; ``robots/huge_yaw.json``) and ``ros/thick.yaml`` (a room
with a 1 m thick wall, unknown space behind it, a closed pocket in it) with targets no robot can
reach (``robots/targets_dropped.json``). Checkpoints are not here: they depend on the network's
layout and are written by the test's fixture (a JSON that does not match its weights, a truncated
safetensors file).

Inputs that would be large on disk, and those git cannot hold (a named pipe, a symbolic link loop),
are written at test time by :func:`write_generated`: decompression bombs (images small on disk whose
headers declare 20000 x 20000 or 6000 x 6000 pixels, a PGM header that lies), a 10 MB YAML, 10,000
robots.
"""

from __future__ import annotations

import json
import os
import struct
import zlib
from pathlib import Path

import numpy as np
import yaml
from PIL import Image

HERE = Path(__file__).resolve().parent
ROS_KEYS = {"resolution": 0.05, "origin": [0.0, 0.0, 0.0], "negate": 0, "occupied_thresh": 0.65, "free_thresh": 0.196}


def _room() -> np.ndarray:
    """(60, 60) uint8 image (top row north): walls 0, free 254, the eastern 20 columns unknown 205."""
    pixels = np.full((60, 60), 254, dtype=np.uint8)
    pixels[:, 40:] = 205
    pixels[[0, -1], :40] = 0
    pixels[:, 0] = 0
    return pixels


def _thick() -> np.ndarray:
    """(60, 80) uint8 image: a room (x < 2 m), a wall 1 m thick (2-3 m) with a closed 0.25 m pocket
    of floor inside it, unknown space behind it (x >= 3 m); walls around."""
    pixels = np.full((60, 80), 254, dtype=np.uint8)
    pixels[:, 40:60] = 0
    pixels[28:33, 48:53] = 254  # the pocket, around (2.5, 1.5)
    pixels[:, 60:] = 205
    pixels[[0, -1], :60] = 0
    pixels[:, 0] = 0
    return pixels


def png_header_only(width: int, height: int) -> bytes:
    """A PNG whose header declares ``width`` x ``height`` 8-bit grey pixels, with a few bytes of data."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    header = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b"")
    )


def write_generated(folder: Path) -> None:
    """The inputs written at test time into ``folder``: bombs small on disk (large only in their
    headers), a 10 MB YAML, 10,000 robots, a named pipe and a symbolic link loop as map YAMLs."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "bomb.png").write_bytes(png_header_only(20000, 20000))  # PIL's own limit refuses it
    (folder / "bomb6k.png").write_bytes(png_header_only(6000, 6000))  # under PIL's limit, over areasearch's
    (folder / "lying.pgm").write_bytes(b"P5\n30000 30000\n255\n" + b"\xfe" * 64)
    for name in ("bomb.png", "bomb6k.png", "lying.pgm"):
        doc = {"image": name, **ROS_KEYS}
        (folder / f"{name.split('.')[0]}.yaml").write_text(yaml.safe_dump(doc, sort_keys=False))
    line = "# " + "x" * 98 + "\n"
    (folder / "big.yaml").write_text(yaml.safe_dump({"image": "bomb.png", **ROS_KEYS}) + line * 100_000)  # 10 MB
    many = [{"id": f"r{i}", "x": 1.0 + (i % 30) * 0.05, "y": 1.0} for i in range(10_000)]
    (folder / "many_robots.json").write_text(json.dumps({"robots": many}))
    if not (folder / "fifo.yaml").exists():
        os.mkfifo(folder / "fifo.yaml")
    for name, target in (("loop.yaml", "loop2.yaml"), ("loop2.yaml", "loop.yaml")):
        if not os.path.lexists(folder / name):
            os.symlink(target, folder / name)


def main() -> None:
    maps, ros, robots = HERE / "maps", HERE / "ros", HERE / "robots"
    for folder in (maps, ros, robots):
        folder.mkdir(exist_ok=True)

    # --- PNG maps in the bundled folder format (index.json gives the resolution)
    Image.fromarray(_room()).save(ros / "good.png")
    buffer = (ros / "good.png").read_bytes()
    (maps / "truncated.png").write_bytes(buffer[: len(buffer) // 2])
    Image.fromarray(_room().astype(np.uint16) * 257).save(maps / "wrong_mode.png")  # 16-bit grey
    Image.fromarray(np.zeros((20, 20), dtype=np.uint8)).save(maps / "no_free.png")
    tiny = np.zeros((20, 20), dtype=np.uint8)
    tiny[9:12, 9:12] = 255  # 15 cm of floor: no robot of radius 0.18 m fits
    Image.fromarray(tiny).save(maps / "tiny_free.png")
    entries = [{"file": name, "resolution_m_per_px": 0.05} for name in
               ("truncated.png", "wrong_mode.png", "no_free.png", "tiny_free.png")]  # fmt: skip
    (maps / "index.json").write_text(json.dumps({"maps": entries}, indent=2) + "\n")

    # --- ROS map_server YAML maps
    def write(name: str, doc: dict) -> None:
        (ros / name).write_text(yaml.safe_dump(doc, sort_keys=False))

    write("good.yaml", {"image": "good.png", **ROS_KEYS})
    write("missing_key.yaml", {"image": "good.png", **{k: v for k, v in ROS_KEYS.items() if k != "free_thresh"}})
    write("wrong_type.yaml", {"image": "good.png", **ROS_KEYS, "resolution": "fine"})
    write("wrong_origin.yaml", {"image": "good.png", **ROS_KEYS, "origin": "here"})
    write("missing_image.yaml", {"image": "no_such_image.pgm", **ROS_KEYS})
    write("truncated_image.yaml", {"image": "../maps/truncated.png", **ROS_KEYS})
    write("no_free.yaml", {"image": "../maps/no_free.png", **ROS_KEYS})
    write("tiny_free.yaml", {"image": "../maps/tiny_free.png", **ROS_KEYS})
    (ros / "not_yaml.yaml").write_text("image: [good.png\nresolution: 0.05\n")

    # --- hardening, round two (issue 21)
    room16 = _room().astype(">u2") * 257  # the same room as a 16-bit PGM (maxval 65535)
    (ros / "good16.pgm").write_bytes(b"P5\n60 60\n65535\n" + room16.tobytes())
    write("good16.yaml", {"image": "good16.pgm", **ROS_KEYS})
    Image.fromarray(_room()).save(ros / "jpeg_named.png", format="JPEG", quality=90)  # a JPEG under a .png name
    write("jpeg.yaml", {"image": "jpeg_named.png", **ROS_KEYS})
    (ros / "exponent.yaml").write_text(yaml.safe_dump({"image": "good.png", **ROS_KEYS}).replace("0.05", "5e-2"))
    laughs = "a: &a [lol, lol, lol, lol, lol, lol, lol, lol, lol]\n"
    laughs += "".join(f"{b}: &{b} [{', '.join(['*' + a] * 9)}]\n" for a, b in zip("abcdefgh", "bcdefghi", strict=True))
    (ros / "aliases.yaml").write_text(laughs + yaml.safe_dump({"image": "good.png", **ROS_KEYS}))
    write("non_scalar.yaml", {"image": "good.png", **ROS_KEYS, "resolution": {"x": [0.05] * 200}})
    write("far_origin.yaml", {"image": "good.png", **ROS_KEYS, "origin": [1e300, 0.0, 0.0]})
    write("fine_resolution.yaml", {"image": "good.png", **ROS_KEYS, "resolution": 1e-300})
    Image.fromarray(_thick()).save(ros / "thick.png")
    write("thick.yaml", {"image": "thick.png", **ROS_KEYS})

    # --- robots and targets on ros/good.yaml (x, y in metres; the room spans x, y in [0, 3))
    def robots_file(name: str, text: str) -> None:
        (robots / name).write_text(text)

    robots_file(
        "good.json", '{"robots": [{"id": "a", "x": 1.0, "y": 1.0, "yaw": 0.0}, {"id": "b", "x": 1.6, "y": 2.0}]}\n'
    )
    robots_file("in_wall.json", '{"robots": [{"id": "a", "x": 1.0, "y": 1.0}, {"id": "b", "x": 0.02, "y": 1.5}]}\n')
    robots_file("outside.json", '{"robots": [{"id": "a", "x": 1.0, "y": 1.0}, {"id": "b", "x": 7.5, "y": 1.5}]}\n')
    robots_file("below_origin.json", '{"robots": [{"id": "a", "x": 1.0, "y": -0.4}]}\n')
    robots_file("nan.json", '{"robots": [{"id": "a", "x": NaN, "y": 1.0}]}\n')
    robots_file("infinite.json", '{"robots": [{"id": "a", "x": 1.0, "y": 1e999}]}\n')
    robots_file("nan_yaw.json", '{"robots": [{"id": "a", "x": 1.0, "y": 1.0, "yaw": NaN}]}\n')
    robots_file("string_pose.json", '{"robots": [{"id": "a", "x": "1.0", "y": 1.0}]}\n')
    robots_file("overlap.json", '{"robots": [{"id": "a", "x": 1.0, "y": 1.0}, {"id": "b", "x": 1.05, "y": 1.0}]}\n')
    robots_file("in_tiny.json", '{"robots": [{"id": "a", "x": 0.5, "y": 0.5}]}\n')  # on maps/tiny_free.png
    robots_file("empty.json", '{"robots": []}\n')
    robots_file("not_json.json", '{"robots": [{"id": "a", "x": 1.0,\n')
    robots_file("targets_outside.json", '{"targets": [{"id": "p", "x": 1.0, "y": 9.0}]}\n')
    robots_file("targets_nan.json", '{"targets": [{"id": "p", "x": NaN, "y": 1.0}]}\n')
    robots_file(
        "huge_yaw.json",
        '{"robots": [{"id": "a", "x": 1.0, "y": 1.0, "yaw": 1e308}, {"id": "b", "x": 1.6, "y": 2.0}]}\n',
    )
    robots_file("far.json", '{"robots": [{"id": "a", "x": 1e20, "y": 1.0}]}\n')
    robots_file(
        "footprints_overlap.json", '{"robots": [{"id": "a", "x": 1.0, "y": 1.0}, {"id": "b", "x": 1.2, "y": 1.0}]}\n'
    )
    robots_file("unknown_top_key.json", '{"robots": [{"id": "a", "x": 1.0, "y": 1.0}], "robts": []}\n')
    robots_file("targets_far.json", '{"targets": [{"id": "p", "x": 1.0, "y": 1e20}]}\n')
    robots_file("targets_unknown_top_key.json", '{"targets": [], "target": []}\n')
    # on ros/thick.yaml: a target in the room, one 0.5 m deep in the wall, one in its pocket, one behind it
    robots_file(
        "targets_dropped.json",
        '{"targets": [{"id": "room", "x": 1.0, "y": 2.0}, {"id": "wall", "x": 2.5, "y": 0.6}, '
        '{"id": "pocket", "x": 2.5, "y": 1.5}, {"id": "behind", "x": 3.5, "y": 1.5}]}\n',
    )


if __name__ == "__main__":
    main()
