"""What an inline OccupancyGrid costs ``areasearch serve`` before planning: its way beside the old way.

A ``POST /assign`` that sends the map in its body (``{"map": <OccupancyGrid>, "robots": [...]}``)
is parsed, checked and hashed by the service's HTTP process on every call. Two maps, as a SLAM
node would send them (bundled maps read as 0 free / 100 occupied, their eastern half -1 unknown;
``json.dumps`` with its default separators, as a Python client writes):

* ``large``: ``bormann_office_g_rooms3``, 1821 x 1826 cells, the largest bundled map (about 14 MB);
* ``medium``: ``bormann_lab_ipa``, 489 x 492 cells (about 0.9 MB).

Ways, each from the body's bytes to the checked cells (:class:`areasearch.service.occupancy_msg.GridCells`,
the library's reader run once) and their hash, alternated ``--repeats`` times in one run so that
both see the same load; medians:

* **old**: pydantic's ``AssignRequest.model_validate_json(body)`` (its JSON parser, then JSON-mode
  validation of the map as ``Any``), then ``np.array(data)`` (NumPy's type inference over the cell
  list), the range check and ``astype(int8)``: what the service did before;
* **new**: :func:`areasearch.service.schema.read_json` (orjson), then Python-mode validation of the
  typed body (what FastAPI runs on it) and :func:`areasearch.service.schema.read_grid`
  (``array.array("b", data)``: one C pass);

and the new way's parts: the JSON parse, the validation, the cells (conversion, checks, the
library's reader), the hash; beside them pydantic-core's ``from_json`` alone (the parser of the old
way, and the service's for the bodies orjson refuses: :func:`areasearch.service.schema.read_json`).

    python benchmarks/bench_serve_parse.py [--repeats 15]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from PIL import Image
from pydantic_core import from_json

from areasearch.service.app import map_key
from areasearch.service.occupancy_msg import GridCells, OccupancyGrid
from areasearch.service.schema import AssignRequest, read_grid, read_json
from areasearch.sim.scene import bundled_index, bundled_maps_dir

MAPS = {"large": "bormann_office_g_rooms3", "medium": "bormann_lab_ipa"}
MAX_CELLS = 25_000_000


def body_of(map_id: str) -> bytes:
    """A ``POST /assign`` body with ``map_id`` inline as a SLAM node's partial map."""
    (entry,) = [m for m in bundled_index() if m["id"] == map_id]
    image = np.asarray(Image.open(bundled_maps_dir() / entry["file"]).convert("L"))
    cells = np.where(image > 200, 0, 100).astype(np.int8)[::-1]  # row 0 at the origin (the image's bottom)
    cells[:, cells.shape[1] // 2 :] = -1
    h, w = cells.shape
    message = {
        "header": {"frame_id": "map"},
        "info": {
            "resolution": 0.05,
            "width": w,
            "height": h,
            "origin": {
                "position": {"x": 0.0, "y": 0.0, "z": 0.0},
                "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
            },
        },
        "data": cells.reshape(-1).tolist(),
    }
    return json.dumps({"map": message, "robots": [{"id": "r0", "x": 1.0, "y": 1.0}], "method": "greedy"}).encode()


def old_way(body: bytes) -> tuple[GridCells, str]:
    """The service's parsing before: pydantic's JSON mode over the whole body, NumPy's type inference."""
    req = AssignRequest.model_validate_json(body)
    msg = OccupancyGrid.model_validate(req.map)
    info = msg.info
    values = np.array(msg.data)
    if values.shape != (info.width * info.height,) or values.dtype.kind not in "iu":
        raise ValueError("not a list of integers")
    if int(values.min()) < -1 or int(values.max()) > 100:
        raise ValueError("a value outside -1..100")
    cells = values.astype(np.int8).reshape(info.height, info.width)
    grid = GridCells(cells, info.resolution, (info.origin.position.x, info.origin.position.y), "map")
    grid.to_map()
    return grid, map_key(grid)


def new_way(body: bytes) -> tuple[GridCells, str]:
    """The service's parsing now (``POST /assign``'s own calls)."""
    req = AssignRequest.model_validate(read_json(body))
    grid = read_grid(req.map, "map", MAX_CELLS)
    return grid, map_key(grid)


def timed(fn: Callable[[], Any]) -> tuple[float, Any]:
    t0 = time.perf_counter()
    out = fn()
    return 1e3 * (time.perf_counter() - t0), out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=15)
    args = parser.parse_args()
    print(f"{'map':7} {'cells':>10} {'body':>8} {'old':>9} {'new':>9} {'old/new':>8} | new: {'parse':>8} "
          f"{'validate':>8} {'cells':>8} {'hash':>6}{'from_json':>11}")  # fmt: skip
    for label, map_id in MAPS.items():
        body = body_of(map_id)
        old_grid, old_key = old_way(body)
        new_grid, new_key = new_way(body)
        assert np.array_equal(old_grid.cells, new_grid.cells) and old_key == new_key
        times: dict[str, list[float]] = {
            k: [] for k in ("old", "new", "parse", "validate", "cells", "hash", "pydantic")
        }
        for _ in range(args.repeats):
            times["old"].append(timed(lambda: old_way(body))[0])  # noqa: B023
            times["new"].append(timed(lambda: new_way(body))[0])  # noqa: B023
            ms, value = timed(lambda: read_json(body))  # noqa: B023
            times["parse"].append(ms)
            ms, req = timed(lambda: AssignRequest.model_validate(value))  # noqa: B023
            times["validate"].append(ms)
            ms, grid = timed(lambda: read_grid(req.map, "map", MAX_CELLS))  # noqa: B023
            times["cells"].append(ms)
            times["hash"].append(timed(lambda: map_key(grid))[0])  # noqa: B023
            times["pydantic"].append(timed(lambda: from_json(body))[0])  # noqa: B023
        med = {k: statistics.median(v) for k, v in times.items()}
        size, mb, ratio = new_grid.cells.size, len(body) / 1e6, med["old"] / med["new"]
        print(
            f"{label:7} {size:>10,} {mb:>6.1f}MB {med['old']:>7.1f}ms {med['new']:>7.1f}ms {ratio:>8.2f} | "
            f"{med['parse']:>6.1f}ms {med['validate']:>6.2f}ms {med['cells']:>6.1f}ms {med['hash']:>4.1f}ms"
            f"{med['pydantic']:>9.1f}ms"
        )


if __name__ == "__main__":
    main()
