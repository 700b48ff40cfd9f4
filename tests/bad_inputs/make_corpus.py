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
robots, and the damaged training run folders of ``train --resume`` (:func:`write_runs`: their
checkpoints follow the network's layout), named pipes where outputs go (:func:`write_outputs`), and
damaged evaluation results folders (:func:`write_results`: a finished run of ``eval``, then one file
or row changed).
"""

from __future__ import annotations

import json
import os
import shutil
import struct
import tomllib
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
    write_runs(folder / "runs")
    write_outputs(folder / "outputs")
    write_results(folder / "results")


HUGE_INT = "9" * 5000
"""An integer literal longer than Python converts to an int (4,300 digits)."""


def write_outputs(folder: Path) -> None:
    """Named pipes where a command's output would go: ``fifo.png`` (``run``), ``fifo.gif`` (``render``),
    ``fifo.json`` (``assign``), ``frame.png`` beside ``frame.gif`` (``render``'s last frame), and
    ``fifo_dir`` (``eval`` / ``train`` folders)."""
    folder.mkdir(parents=True, exist_ok=True)
    for name in ("fifo.png", "fifo.gif", "fifo.json", "frame.png", "fifo_dir"):
        if not os.path.lexists(folder / name):
            os.mkfifo(folder / name)


EVAL_ARGS = ["--methods", "greedy", "--robots", "2", "--episodes", "1", "--max-steps", "5"]
"""The evaluation of the damaged results folders: the good ``eval`` arguments of
``tests/test_bad_inputs.py`` (with ``--maps`` the corpus's ``ros/good.yaml``)."""


def write_results(folder: Path) -> None:
    """Results folders of ``eval --out`` resumed with :data:`EVAL_ARGS`, each damaged in one way (its
    folder's name): a finished run, then one file, row or field changed."""
    from areasearch.cli import main

    if folder.exists():
        shutil.rmtree(folder)
    base = folder / "valid"
    with open(os.devnull, "w") as quiet:
        import contextlib

        with contextlib.redirect_stdout(quiet), contextlib.redirect_stderr(quiet):
            code = main(["eval", *EVAL_ARGS, "--maps", str(HERE / "ros" / "good.yaml"), "--out", str(base)])
    assert code == 0, "the evaluation of the results folders failed"

    def variant(name: str) -> Path:
        shutil.copytree(base, folder / name)
        return folder / name

    def edit_row(run: Path, **changes: str) -> None:
        header, row = (run / "episodes.csv").read_text().splitlines()
        fields = dict(zip(header.split(","), row.split(","), strict=True)) | changes
        (run / "episodes.csv").write_text(header + "\n" + ",".join(fields.values()) + "\n")

    def edit_config(run: Path, **changes: object) -> None:
        doc = json.loads((run / "config.json").read_text())
        (run / "config.json").write_text(json.dumps({**doc, **changes}, indent=2) + "\n")

    (variant("config_list") / "config.json").write_text("[1, 2, 3]\n")
    run = variant("config_folder")
    (run / "config.json").unlink()
    (run / "config.json").mkdir()
    run = variant("config_fifo")
    (run / "config.json").unlink()
    os.mkfifo(run / "config.json")
    (variant("config_not_utf8") / "config.json").write_bytes(b'{"seed": "\xff\xfe"}\n')
    run = variant("config_huge_int")
    (run / "config.json").write_text((run / "config.json").read_text().replace('"seed": 0', '"seed": ' + HUGE_INT))
    edit_config(variant("map_changed"), maps={"good": "0" * 64})
    edit_config(variant("maps_malformed"), maps=["good"])
    run = variant("episodes_folder")
    (run / "episodes.csv").unlink()
    (run / "episodes.csv").mkdir()
    run = variant("episodes_fifo")
    (run / "episodes.csv").unlink()
    os.mkfifo(run / "episodes.csv")
    run = variant("episodes_not_utf8")
    (run / "episodes.csv").write_bytes((run / "episodes.csv").read_bytes().replace(b"greedy,good", b"gr\xffedy,good"))
    edit_row(variant("cover_250"), covered_pct="250.0")
    edit_row(variant("negative_time"), time_e="-5")
    edit_row(variant("nan_cover"), covered_pct="nan")
    edit_row(variant("infinite_length"), path_length_m="inf")
    edit_row(variant("huge_int_row"), collisions=HUGE_INT)
    run = variant("curve_nan")
    curve = json.loads((run / "curves.jsonl").read_text())
    nan_curve = {**curve, "explored_pct": [float("nan")] * len(curve["steps"])}
    (run / "curves.jsonl").write_text(json.dumps(nan_curve) + "\n")
    run = variant("curves_folder")
    (run / "curves.jsonl").unlink()
    (run / "curves.jsonl").mkdir()


TINY_RUN = """
seed = 0
total_decisions = 8
[network]
rounds = 1
node_dim = 4
history_dim = 4
encoder_layers = 1
encoder_hidden = 4
heads = 1
key_dim = 1
value_dim = 2
attention_hidden = 2
edge_dim = 2
update_hidden = 2
critic_channels = 2
critic_hidden = 2
[rollout]
maps = ["procedural:small"]
robots = [2]
episodes = 2
max_steps = 80
[evaluation]
episodes = 0
"""
"""The training run of the damaged run folders: a network of 2,394 parameters."""


def write_runs(folder: Path) -> None:
    """Training run folders for ``train --resume``, each damaged in one way (its folder's name): a
    checkpoint after iteration 1 of :data:`TINY_RUN` (its Adam state from one step), then one file or
    field changed. Written at test time: a checkpoint's tensors follow the network's layout."""
    import torch
    from safetensors.torch import load_file, save_file

    from areasearch.models.network import DAHGNN
    from areasearch.training.config import config_from_dict, config_to_dict
    from areasearch.training.runfolder import progress_fields, save_checkpoint

    config = config_from_dict(tomllib.loads(TINY_RUN))
    torch.manual_seed(0)
    model = DAHGNN(config.network)
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-3, eps=1e-5)
    for p in model.parameters():
        p.grad = torch.full_like(p, 0.01)
    optimizer.step()
    base = folder / "valid"
    if base.exists():
        shutil.rmtree(folder)
    base.mkdir(parents=True)
    (base / "config.json").write_text(json.dumps(config_to_dict(config), indent=1) + "\n")
    state = {"iteration": 1, "decisions": 4, "episodes": 2, "wall_s": 1.5, "best_score": -1.0}
    save_checkpoint(base, model, optimizer, state)
    fields = progress_fields(config.network.rounds)
    row = {k: "0" for k in fields} | {"iteration": "1", "decisions": "4", "episodes": "2"}
    (base / "progress.csv").write_text(",".join(fields) + "\n" + ",".join(row[k] for k in fields) + "\n")

    def variant(name: str) -> Path:
        shutil.copytree(base, folder / name)
        return folder / name

    def edit_checkpoint(run: Path, **changes: object) -> None:
        doc = json.loads((run / "checkpoint.json").read_text())
        (run / "checkpoint.json").write_text(json.dumps({**doc, **changes}, indent=1) + "\n")

    def edit_tensors(run: Path, change: object) -> None:
        path = run / "checkpoint-000001.safetensors"
        tensors = load_file(str(path))
        change(tensors)  # type: ignore[operator]
        save_file(tensors, str(path))

    # the checkpoint.json lost: its weights and the progress rows are still there
    (variant("no_checkpoint") / "checkpoint.json").unlink()
    (variant("no_config") / "config.json").unlink()
    edit_checkpoint(variant("lying_iteration"), iteration=7, episodes=14, weights="checkpoint-000007.safetensors")
    edit_checkpoint(variant("negative_count"), decisions=-4)
    edit_checkpoint(variant("bool_count"), iteration=True)
    run = variant("bad_param_groups")
    groups = json.loads((run / "checkpoint.json").read_text())["param_groups"]
    edit_checkpoint(run, param_groups=[{**groups[0], "eps": 0.5}])
    edit_checkpoint(variant("weights_path"), weights="../valid/checkpoint-000001.safetensors")
    first = next(iter(model.state_dict()))
    edit_tensors(variant("wrong_shape"), lambda t: t.update({f"model/{first}": torch.zeros(3, 3)}))
    edit_tensors(variant("wrong_dtype"), lambda t: t.update({f"model/{first}": t[f"model/{first}"].double()}))
    edit_tensors(variant("optimizer_shape"), lambda t: t.update({"optim/0/exp_avg": torch.zeros(2, 2, 2)}))
    edit_tensors(variant("optimizer_unknown"), lambda t: t.update({"optim/9999/exp_avg": torch.zeros(1)}))
    edit_tensors(variant("nan_weight"), lambda t: t[f"model/{first}"].fill_(float("nan")))
    (variant("config_not_object") / "config.json").write_text("[1, 2, 3]\n")
    run = variant("config_folder")
    (run / "config.json").unlink()
    (run / "config.json").mkdir()
    (run / "config.json" / "notes.txt").write_text("a folder where config.json belongs\n")
    (variant("config_not_utf8") / "config.json").write_bytes(b'{"seed": "\xff\xfe"}\n')
    run = variant("config_huge_int")
    (run / "config.json").write_text((run / "config.json").read_text().replace('"seed": 0', '"seed": ' + "9" * 5000))
    run = variant("checkpoint_fifo")
    (run / "checkpoint.json").unlink()
    os.mkfifo(run / "checkpoint.json")
    (variant("progress_not_utf8") / "progress.csv").write_bytes(b"iteration,decisions\n1,\xff\n")
    run = variant("progress_columns")
    (run / "progress.csv").write_text("iteration,decisions,episodes\n1,4,2\n")


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

    # --- hardening, round two
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
    # integers longer than Python converts (4,300 digits), a NUL byte and a 300-byte name in a map's image path
    robots_file("huge_int.json", '{"robots": [{"id": "a", "x": 1.0, "y": 1.0, "yaw": ' + HUGE_INT + "}]}\n")
    robots_file("targets_huge_int.json", '{"targets": [{"id": "p", "x": ' + HUGE_INT + ', "y": 1.0}]}\n')
    text = yaml.safe_dump({"image": "good.png", **ROS_KEYS})
    (ros / "huge_int.yaml").write_text(text.replace("negate: 0", "negate: " + HUGE_INT))
    (ros / "nul_image.yaml").write_text(yaml.safe_dump({"image": "good\0.png", **ROS_KEYS}))
    write("long_image.yaml", {"image": "m" * 300 + ".png", **ROS_KEYS})
    # on ros/thick.yaml: a target in the room, one 0.5 m deep in the wall, one in its pocket, one behind it
    robots_file(
        "targets_dropped.json",
        '{"targets": [{"id": "room", "x": 1.0, "y": 2.0}, {"id": "wall", "x": 2.5, "y": 0.6}, '
        '{"id": "pocket", "x": 2.5, "y": 1.5}, {"id": "behind", "x": 3.5, "y": 1.5}]}\n',
    )


if __name__ == "__main__":
    main()
