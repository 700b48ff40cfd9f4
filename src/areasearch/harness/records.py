"""The files of a results folder (``areasearch eval --out DIR``): ``episodes.csv`` (one row per episode,
:data:`CSV_FIELDS`), ``curves.jsonl`` (one curve per episode), ``config.json`` and ``policies.json``.

Read with the checks of a user's input: a file that is a folder or a named pipe, bytes that are not
UTF-8, a record that is not a JSON object, an integer beyond Python's conversion limit, a row with a
value no episode can have (a percentage outside 0-100, a negative or non-finite time, length or
count) is refused with one message naming the file and the row. Rows and curves are appended by
:class:`AppendLog`, one write per line, fsync'ed; a trailing partial line (an interrupted append)
is never read and is cut off by the next append.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from ..config import MAX_ROBOTS, MAX_STEPS
from ..errors import AreaSearchError
from ..inputs import (
    clip,
    int_digits_message,
    is_int_digits_error,
    parse_json,
    read_bytes,
    regular_file,
    short,
    write_error,
)
from .report import write_text

CSV_FIELDS = (
    "method",
    "map",
    "size_class",
    "robots",
    "episode",
    "seed",
    "explored_pct",
    "covered_pct",
    "covered_of_discovered_pct",
    "time_e",
    "time_c",
    "reached_e",
    "reached_c",
    "collisions",
    "path_length_m",
    "decisions",
    "wall_s",
)
"""Columns of ``episodes.csv``."""

_FIELD_TYPES: dict[str, Callable[[str], Any]] = {
    "method": str,
    "map": str,
    "size_class": str,
    "robots": int,
    "episode": int,
    "seed": int,
    "explored_pct": float,
    "covered_pct": float,
    "covered_of_discovered_pct": float,
    "time_e": int,
    "time_c": int,
    "reached_e": lambda s: {"True": True, "False": False}[s],
    "reached_c": lambda s: {"True": True, "False": False}[s],
    "collisions": int,
    "path_length_m": float,
    "decisions": int,
    "wall_s": float,
}


EPISODES_FILE, CURVES_FILE, CONFIG_FILE = "episodes.csv", "curves.jsonl", "config.json"
POLICIES_FILE = "policies.json"
"""Of an evaluation folder: the weights (path and SHA-256) of each method that has them, a ``--policy``
name or a shipped policy, so that a resume with other weights under the same name is refused."""

REPLACED_FOLDER = "replaced"
"""Of an evaluation folder: the episodes of methods played again (``--replace``), one numbered folder
per replacement (:func:`set_aside`)."""

EpisodeKey = tuple[str, str, int, int, int]
"""(method, map, robots, episode, seed): an episode's identity in the files."""


def episode_key(record: Mapping[str, Any]) -> EpisodeKey:
    """The (method, map, robots, episode, seed) of a row or a curve record."""
    return (
        str(record["method"]),
        str(record["map"]),
        int(record["robots"]),
        int(record["episode"]),
        int(record["seed"]),
    )


def csv_line(row: dict[str, Any]) -> str:
    buf = io.StringIO()
    csv.writer(buf, lineterminator="\n").writerow([row[f] for f in CSV_FIELDS])
    return buf.getvalue()


LOG_NAMES = {EPISODES_FILE: "episodes file", CURVES_FILE: "curve log"}
"""What each line log of a results folder is called in a message."""


def complete_lines(path: Path) -> tuple[list[str], int]:
    """The complete (newline-terminated) lines of a log file and the byte length they span; a
    trailing partial line (an interrupted append) is not among them. AreaSearchError naming the file
    for a folder or named pipe there (never opened) or bytes that are not UTF-8 (naming the line)."""
    if not os.path.lexists(path):
        return [], 0
    what = LOG_NAMES.get(path.name, "log")
    regular_file(path, what, AreaSearchError)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise AreaSearchError(f"{path}: cannot read the {what}: {exc.strerror}") from None
    end = data.rfind(b"\n") + 1
    try:
        text = data[:end].decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise AreaSearchError(f"{path}: line {line}: not UTF-8 text (byte {exc.start})") from None
    return text.splitlines(), end


MAX_EPISODE_SEED = 2**64 - 1
"""Largest episode seed (:func:`episode_seed` gives 63 bits)."""


def _row_problem(row: Mapping[str, Any]) -> str | None:
    """What makes a typed ``episodes.csv`` row impossible for an episode, or None: a percentage outside
    0-100 or not finite, a time outside 0 to the longest horizon, a negative count, length or duration,
    a team size outside 1-8."""
    for key in ("explored_pct", "covered_pct", "covered_of_discovered_pct"):
        if not (math.isfinite(row[key]) and 0.0 <= row[key] <= 100.0):
            return f"{key} = {row[key]:g} is not a percentage from 0 to 100"
    for key in ("time_e", "time_c"):
        if not 0 <= row[key] <= MAX_STEPS:
            return f"{key} = {row[key]} is not a step from 0 to {MAX_STEPS:,}"
    for key in ("path_length_m", "wall_s"):
        if not (math.isfinite(row[key]) and row[key] >= 0.0):
            return f"{key} = {row[key]:g} is not a finite number >= 0"
    for key in ("episode", "collisions", "decisions"):
        if row[key] < 0:
            return f"{key} = {row[key]} is negative"
    if not 0 <= row["seed"] <= MAX_EPISODE_SEED:
        return f"seed = {row['seed']} is not a 64-bit seed"
    if not 1 <= row["robots"] <= MAX_ROBOTS:
        return f"robots = {row['robots']} is not a team size from 1 to {MAX_ROBOTS}"
    return None


def read_episodes(path: Path) -> list[dict[str, Any]]:
    """Rows of an ``episodes.csv`` (ignoring a trailing partial line), typed. AreaSearchError naming the
    file and the row for a malformed row or one no episode can have (:func:`_row_problem`): it is
    refused, never summarised."""
    lines, _ = complete_lines(path)
    if not lines:
        return []
    header = next(csv.reader([lines[0]]))
    if tuple(header) != CSV_FIELDS:
        raise AreaSearchError(f"{path}: not an episodes file of this version (header {short(','.join(header))})")
    rows = []
    for number, values in enumerate(csv.reader(lines[1:]), start=2):
        try:
            if len(values) != len(CSV_FIELDS):
                raise ValueError(f"{len(values)} fields")
            row = {f: _FIELD_TYPES[f](v) for f, v in zip(CSV_FIELDS, values, strict=True)}
        except (ValueError, KeyError) as exc:
            reason = int_digits_message() if is_int_digits_error(exc) else clip(str(exc), 100)
            raise AreaSearchError(f"{path}:{number}: malformed row ({reason})") from None
        problem = _row_problem(row)
        if problem is not None:
            raise AreaSearchError(f"{path}:{number}: impossible row: {problem}; no episode gives it")
        rows.append(row)
    return rows


def _curve_problem(record: Mapping[str, Any]) -> str | None:
    """What makes a ``curves.jsonl`` record unusable for the curve figure, or None."""
    steps, explored, covered = record.get("steps"), record.get("explored_pct"), record.get("covered_pct")
    if not all(isinstance(v, list) for v in (steps, explored, covered)) or not steps:
        return "steps, explored_pct and covered_pct must be non-empty lists"
    assert isinstance(steps, list) and isinstance(explored, list) and isinstance(covered, list)
    if not len(steps) == len(explored) == len(covered):
        return "steps, explored_pct and covered_pct must be as long as each other"
    if not all(isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= MAX_STEPS for v in steps):
        return f"steps must be steps from 0 to {MAX_STEPS:,}"
    for name, values in (("explored_pct", explored), ("covered_pct", covered)):
        if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and 0 <= v <= 100 for v in values):
            return f"{name} must be percentages from 0 to 100"
    error = record.get("map_error_pct", 0)  # imperfect worlds only (areasearch.sim.mapquality)
    if not (isinstance(error, (int, float)) and not isinstance(error, bool) and 0 <= error <= 100):
        return "map_error_pct must be a percentage from 0 to 100"
    return None


def read_curves(path: Path) -> dict[tuple[str, str, int, int, int], dict[str, Any]]:
    """Curve records of a ``curves.jsonl`` by episode key (the last one wins), ignoring a trailing
    partial line; AreaSearchError naming the file and the line for one that is malformed or holds
    values no episode has."""
    lines, _ = complete_lines(path)
    curves = {}
    for number, line in enumerate(lines, start=1):
        try:
            record = json.loads(line)
            key = episode_key(record)
        except (json.JSONDecodeError, KeyError, TypeError, ValueError, AttributeError) as exc:
            reason = int_digits_message() if is_int_digits_error(exc) else clip(str(exc), 100)
            raise AreaSearchError(f"{path}:{number}: malformed curve line ({reason})") from None
        problem = _curve_problem(record)
        if problem is not None:
            raise AreaSearchError(f"{path}:{number}: impossible curve: {problem}")
        curves[key] = record
    return curves


class AppendLog:
    """A line log where each line is appended with one write, then fsync'ed. Opening it truncates a
    trailing partial line left by an interrupted write and writes ``header`` into an empty file. A
    write that fails (file too large, disk full) is cut back to the last whole line and raises one
    AreaSearchError naming the file: the lines already there are kept."""

    def __init__(self, path: Path, header: str | None = None) -> None:
        _, end = complete_lines(path)
        self.path = path
        try:
            self._fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_CLOEXEC, 0o644)
            if os.fstat(self._fd).st_size != end:
                os.ftruncate(self._fd, end)
        except OSError as exc:
            raise AreaSearchError(write_error(path, exc, LOG_NAMES.get(path.name, "log"))) from None
        self._end = end
        if end == 0 and header is not None:
            self.append(header)

    def append(self, line: str) -> None:
        data = line.encode("utf-8")
        try:
            while data:
                data = data[os.write(self._fd, data) :]
            os.fsync(self._fd)
        except OSError as exc:
            with contextlib.suppress(OSError):
                os.ftruncate(self._fd, self._end)  # no partial line is left behind
            raise AreaSearchError(write_error(self.path, exc, LOG_NAMES.get(self.path.name, "log"))) from None
        self._end += len(line.encode("utf-8"))

    def close(self) -> None:
        os.close(self._fd)


MAX_RECORD_BYTES = 16 * 2**20
"""Largest ``config.json`` or ``policies.json`` of a results folder read, bytes (they hold a few KB)."""


def read_record(path: Path, what: str) -> dict[str, Any]:
    """The JSON object in a results folder's ``config.json`` or ``policies.json``; AreaSearchError
    naming the file for a folder or named pipe there (never opened), a file over
    :data:`MAX_RECORD_BYTES`, bytes that are not UTF-8, text that does not parse (an integer beyond
    Python's conversion limit too), or a document that is not an object."""
    data = read_bytes(path, what, MAX_RECORD_BYTES, None, AreaSearchError)
    doc = parse_json(data, str(path), AreaSearchError)
    if not isinstance(doc, dict):
        raise AreaSearchError(f"{path}: the {what} must be a JSON object, got {type(doc).__name__}")
    return doc


def episode_id(row: Mapping[str, Any]) -> tuple[str, str, int, int]:
    """The (method, map, robots, episode) of an episode's row: one row per key in a run."""
    return (str(row["method"]), str(row["map"]), int(row["robots"]), int(row["episode"]))


def unique_rows(rows: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """``rows`` without a second row of one (method, map, robots, episode) key (:func:`episode_id`;
    the first is kept)."""
    seen: set[tuple[str, str, int, int]] = set()
    out = []
    for row in rows:
        key = episode_id(row)
        if key not in seen:
            seen.add(key)
            out.append(row)
    return out


def drop_duplicate_rows(path: Path) -> None:
    """Keep in ``episodes.csv`` the first row of each (method, map, robots, episode) key (rows written
    twice by an older version's concurrent runs). Rewritten atomically, only when a row is dropped."""
    lines, _ = complete_lines(path)
    rows = read_episodes(path)
    if len(rows) != len(lines) - 1:  # a quoted field across lines: leave the file to the summary's dedup
        return
    kept = unique_rows(rows)
    if len(kept) == len(rows):
        return
    keep = {id(row) for row in kept}
    text = [lines[0]] + [line for line, row in zip(lines[1:], rows, strict=True) if id(row) in keep]
    write_text(path, "".join(line + "\n" for line in text))


def drop_orphan_curves(path: Path, finished: set[tuple[str, str, int, int, int]]) -> None:
    """Keep in the curve log only one line per episode that has its row (``finished``): a run killed
    between the curve and the row of an episode left a curve that the re-run writes again. The file
    is rewritten atomically, and only when something is dropped."""
    lines, _ = complete_lines(path)
    kept: list[str] = []
    seen: set[tuple[str, str, int, int, int]] = set()
    for line in lines:
        key = episode_key(json.loads(line))
        if key in finished and key not in seen:
            seen.add(key)
            kept.append(line)
    if len(kept) != len(lines):
        write_text(path, "".join(line + "\n" for line in kept))


def set_aside(out: Path, methods: Sequence[str]) -> Path | None:
    """Move the episodes of ``methods`` out of the results folder ``out``: their rows, curves and
    ``policies.json`` entries go to a new folder ``out/replaced/N/`` (N one more than the last, files of
    the same names), and are taken out of ``out``'s files. The copies are written first, then each file
    of ``out`` is rewritten atomically (curves, rows, weights), so an interruption loses nothing: at
    worst a second copy. Returns the new folder, or None when ``out`` holds nothing of ``methods``."""
    names = set(methods)
    episodes, curves, weights = out / EPISODES_FILE, out / CURVES_FILE, out / POLICIES_FILE
    lines, _ = complete_lines(episodes)
    rows = read_episodes(episodes)
    if len(rows) != len(lines[1:]):
        raise AreaSearchError(f"{episodes}: a row spans several lines; cannot set episodes of it aside")
    row_moves = [row["method"] in names for row in rows]
    moved_rows = [line for line, move in zip(lines[1:], row_moves, strict=True) if move]
    curve_lines, _ = complete_lines(curves)
    curve_moves = [json.loads(line)["method"] in names for line in curve_lines]
    moved_curves = [line for line, move in zip(curve_lines, curve_moves, strict=True) if move]
    recorded = read_record(weights, "policies record") if os.path.lexists(weights) else {}
    moved_weights = {name: entry for name, entry in recorded.items() if name in names}
    if not (moved_rows or moved_curves or moved_weights):
        return None
    root = out / REPLACED_FOLDER
    taken = [int(p.name) for p in root.iterdir() if p.name.isdigit()] if root.is_dir() else []
    folder = root / str(max(taken, default=0) + 1)
    folder.mkdir(parents=True)
    header = lines[0] if lines else ",".join(CSV_FIELDS)
    write_text(folder / EPISODES_FILE, "".join(line + "\n" for line in [header, *moved_rows]))
    write_text(folder / CURVES_FILE, "".join(line + "\n" for line in moved_curves))
    write_text(folder / POLICIES_FILE, json.dumps(moved_weights, indent=2, sort_keys=True) + "\n")
    if moved_curves:
        kept = [line for line, move in zip(curve_lines, curve_moves, strict=True) if not move]
        write_text(curves, "".join(line + "\n" for line in kept))
    if moved_rows:
        kept = [line for line, move in zip(lines[1:], row_moves, strict=True) if not move]
        write_text(episodes, "".join(line + "\n" for line in [header, *kept]))
    if moved_weights:
        rest = {name: entry for name, entry in recorded.items() if name not in names}
        write_text(weights, json.dumps(rest, indent=2, sort_keys=True) + "\n")
    return folder
