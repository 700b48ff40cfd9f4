"""Train / validation / test split of the bundled maps.

Policies are trained on ``train`` maps (and on procedural layouts), their checkpoints are chosen on
``val`` maps, and results are reported on ``test`` maps only, which no training run ever sees.

A building and every room group cut from it share one ``group`` in the maps' index; a group always
lies entirely in one split, so no building is seen in two splits. Groups are dealt in a fixed order
(SHA-256 of the group name) to the split that is furthest below its target fraction
(:data:`FRACTIONS`), counting maps per size class, so every split has small, medium and large maps.
The result is committed as ``maps/splits.json`` (the source of truth, readable without code);
:func:`propose_splits` recomputes it and a test checks the two agree.

Map specs ``bundled:train``, ``bundled:val`` and ``bundled:test`` name the maps of one split wherever
a list of maps is accepted (``areasearch eval --maps bundled:test``, training configs).
"""

from __future__ import annotations

import hashlib
import json
from collections import Counter
from functools import cache
from typing import Any

from ..errors import MapError
from .scene import SIZE_CLASSES, bundled_index, bundled_maps_dir

SPLITS = ("train", "val", "test")
FRACTIONS = {"train": 0.5, "val": 0.15, "test": 0.35}
"""Target share of the maps of each size class in each split."""
SPLITS_FILE = "splits.json"
SPLITS_FORMAT = "areasearch-splits/1"


def propose_splits(index: list[dict[str, Any]] | None = None) -> dict[str, str]:
    """Group -> split, by the deterministic dealing of the module docstring."""
    index = bundled_index() if index is None else index
    groups: dict[str, Counter[str]] = {}
    for entry in index:
        groups.setdefault(entry["group"], Counter())[entry["size_class"]] += 1
    totals = Counter(entry["size_class"] for entry in index)
    counts = {split: Counter[str]() for split in SPLITS}
    order = sorted(groups, key=lambda g: hashlib.sha256(g.encode()).hexdigest())
    result: dict[str, str] = {}
    for group in order:
        sizes = groups[group]

        def deficit(split: str, sizes: Counter[str] = sizes) -> float:
            return sum(n * (FRACTIONS[split] * totals[s] - counts[split][s]) / totals[s] for s, n in sizes.items())

        best = max(SPLITS, key=deficit)  # ties: the first in SPLITS order
        counts[best].update(sizes)
        result[group] = best
    return dict(sorted(result.items()))


@cache
def _groups() -> dict[str, str]:
    path = bundled_maps_dir() / SPLITS_FILE
    doc = json.loads(path.read_text())
    if doc.get("format") != SPLITS_FORMAT:
        raise MapError(f"{path}: not a splits file (format must be {SPLITS_FORMAT!r})")
    return dict(doc["groups"])


def map_split(map_id: str) -> str:
    """The split (``train``, ``val`` or ``test``) of a bundled map id."""
    for entry in bundled_index():
        if entry["id"] == map_id:
            return _groups()[entry["group"]]
    raise MapError(f"{map_id}: not a bundled map (see 'areasearch maps')")


def split_maps(split: str) -> list[str]:
    """Ids of the bundled maps of ``split``, in index order."""
    if split not in SPLITS:
        raise MapError(f"unknown split {split!r}: use one of {', '.join(SPLITS)}")
    groups = _groups()
    return [e["id"] for e in bundled_index() if groups[e["group"]] == split]


def split_table() -> dict[str, dict[str, int]]:
    """Maps per split and size class (for the README and ``areasearch maps``)."""
    groups = _groups()
    table = {split: dict.fromkeys(SIZE_CLASSES, 0) for split in SPLITS}
    for entry in bundled_index():
        table[groups[entry["group"]]][entry["size_class"]] += 1
    return table


def write_splits_file() -> None:
    """(Re)write ``maps/splits.json`` from :func:`propose_splits` (maintainers, after the index changes)."""
    doc = {
        "format": SPLITS_FORMAT,
        "fractions": FRACTIONS,
        "rule": "groups dealt in SHA-256 order to the split furthest below its fraction, per size class",
        "groups": propose_splits(),
    }
    (bundled_maps_dir() / SPLITS_FILE).write_text(json.dumps(doc, indent=1) + "\n")
    _groups.cache_clear()
