"""Write the bad-input corpus of ``tests/test_bad_inputs.py`` into this folder (the files are
committed; re-run this after changing it: ``python tests/bad_inputs/make_corpus.py``).

Maps are 0.05 m per cell. ``ros/good.yaml`` is a valid partial map (a 2.9 x 2.9 m room, its eastern
third unknown) that the robots files are placed on; every other file is broken in one way, named by
its file name. Checkpoints are not here: they depend on the network's layout and are written by the
test's fixture (a JSON that does not match its weights, a truncated safetensors file).
"""

from __future__ import annotations

import json
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


if __name__ == "__main__":
    main()
