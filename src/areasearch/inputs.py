"""Checks shared by every reader of a user's file: what a path is, how large a file or image may be,
how a map YAML is parsed, and how user input is quoted in a message.

* :func:`regular_file`: a path names a regular file, or one message saying what it is instead (not
  found, a folder, a named pipe, a device, a symbolic link loop or a broken link, no permission). A
  named pipe is never opened: reading one would wait for a writer forever.
* :func:`read_bytes`: a regular file's bytes, at most a limit (:class:`InputLimits`): a file over it
  is refused before it is read.
* :func:`check_image_size`: an image's declared width and height against the cell and byte limits,
  read from its header before any pixel is decoded (a decompression bomb, or a header that lies, is
  refused without allocating anything).
* :func:`load_yaml`: YAML with the safe loader, without anchors and aliases (no "billion laughs"
  expansion), with YAML 1.2 numbers (``1e6`` is a number, as ROS's map_server reads it).
* :func:`short`, :func:`clip`: ``repr`` of a user's value, an exception's text, cut to a bounded
  length for messages.

The limits are an :class:`InputLimits`; :func:`limits` reads them, each one overridable by an
environment variable (``AREASEARCH_MAX_MAP_CELLS`` and the others named in the dataclass).
"""

from __future__ import annotations

import dataclasses
import errno
import os
import re
import stat
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from .errors import AreaSearchError, ConfigError


@dataclass(frozen=True)
class InputLimits:
    """Largest inputs areasearch reads; each field can be set by the environment variable named in
    :data:`LIMIT_VARIABLES` (an integer, e.g. ``AREASEARCH_MAX_MAP_CELLS=50000000``)."""

    max_map_cells: int = 25_000_000
    """Cells of a map image (width x height): 5000 x 5000, 250 m x 250 m at 5 cm per cell. The
    largest bundled map has 3.3 million; the planners hold a few float arrays of this many cells."""
    max_image_bytes: int = 256 * 2**20
    """Bytes of a map image, both its file and its decoded pixels (width x height x bytes per pixel)."""
    max_yaml_bytes: int = 64 * 2**10
    """Bytes of a map YAML file (a ROS map_server YAML is a handful of scalar keys)."""
    max_json_bytes: int = 16 * 2**20
    """Bytes of a robots or targets JSON file."""

    def validate(self) -> InputLimits:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ConfigError(f"input limit {f.name} must be a positive integer, got {short(value)}")
        return self


LIMIT_VARIABLES = {f.name: f"AREASEARCH_{f.name.upper()}" for f in dataclasses.fields(InputLimits)}
"""The environment variable of each :class:`InputLimits` field."""


def limits(environ: Mapping[str, str] | None = None) -> InputLimits:
    """The input limits in force: :class:`InputLimits`' defaults, overridden by the environment."""
    environ = os.environ if environ is None else environ
    values: dict[str, int] = {}
    for name, variable in LIMIT_VARIABLES.items():
        text = environ.get(variable)
        if text is None:
            continue
        try:
            values[name] = int(text.replace("_", ""))
        except ValueError:
            raise ConfigError(f"environment variable {variable} must be an integer, got {short(text)}") from None
    return InputLimits(**values).validate()


def short(value: Any, width: int = 60) -> str:
    """``repr(value)``, cut to about ``width`` characters (user input quoted in a message)."""
    if isinstance(value, (str, bytes)) and len(value) > width:
        value = value[:width]
        return repr(value)[:-1] + "..." + repr(value)[-1]
    if isinstance(value, (list, tuple, dict)) and len(value) > 8:
        return f"a {type(value).__name__} of {len(value)} items"
    text = repr(value)
    return text if len(text) <= width else text[: width - 3] + "..."


def clip(text: str, width: int = 200) -> str:
    """``text`` (an exception's message) on one line, cut to about ``width`` characters."""
    text = " ".join(str(text).split())
    return text if len(text) <= width else text[: width - 3] + "..."


# ---------------------------------------------------------------------------------- files

_KINDS = (
    (stat.S_ISDIR, "a folder"),
    (stat.S_ISFIFO, "a named pipe (FIFO)"),
    (stat.S_ISSOCK, "a socket"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
)


def regular_file(
    path: str | Path, what: str, error: type[AreaSearchError] = AreaSearchError, missing: str = "not found"
) -> os.stat_result:
    """The ``os.stat`` of ``path`` when it is a regular file (a symbolic link to one is fine); else
    ``error`` with one message naming the path and what it is: ``"<path>: <what> <missing>"``, a
    symbolic link loop, a broken link, a folder, a named pipe... It never opens the path."""
    path = Path(path)
    try:
        info = os.stat(path)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise error(f"{path}: {what} is a symbolic link loop") from None
        if exc.errno == errno.ENOENT and os.path.lexists(path):
            raise error(f"{path}: {what} is a broken symbolic link (to {os.readlink(path)})") from None
        if exc.errno in (errno.ENOENT, errno.ENOTDIR):
            raise error(f"{path}: {what} {missing}") from None
        raise error(f"{path}: cannot read the {what}: {exc.strerror}") from None
    for test, kind in _KINDS:
        if test(info.st_mode):
            raise error(f"{path}: {what} is {kind}, not a regular file")
    return info


def read_bytes(
    path: str | Path, what: str, max_bytes: int, variable: str, error: type[AreaSearchError] = AreaSearchError
) -> bytes:
    """The bytes of the regular file ``path`` (:func:`regular_file`), refused when it holds more than
    ``max_bytes`` (the environment ``variable`` raises the limit) without reading it whole."""
    path = Path(path)
    info = regular_file(path, what, error)
    too_big = f"{path}: {what} is larger than {max_bytes:,} bytes, the limit (environment variable {variable})"
    if info.st_size > max_bytes:
        raise error(too_big)
    try:
        with open(path, "rb") as f:
            data = f.read(max_bytes + 1)
    except OSError as exc:
        raise error(f"{path}: cannot read the {what}: {exc.strerror}") from None
    if len(data) > max_bytes:
        raise error(too_big)
    return data


BYTES_PER_PIXEL = {"1": 1, "L": 1, "P": 1, "LA": 2, "PA": 2, "I;16": 2, "I;16B": 2, "I;16L": 2, "RGB": 3}
"""Decoded bytes per pixel of an image mode (4 for any other: RGBA, I, F, CMYK...)."""


def check_image_size(path: str | Path, size: tuple[int, int], mode: str, error: type[AreaSearchError]) -> None:
    """``error`` unless an image of ``size`` (width, height) in ``mode``, as its header declares it,
    is within :attr:`InputLimits.max_map_cells` and :attr:`InputLimits.max_image_bytes`."""
    bound = limits()
    width, height = size
    cells = width * height
    if cells > bound.max_map_cells:
        raise error(
            f"{path}: the image declares {width} x {height} pixels, more than the limit of {bound.max_map_cells:,} "
            f"map cells (environment variable {LIMIT_VARIABLES['max_map_cells']})"
        )
    decoded = cells * BYTES_PER_PIXEL.get(mode, 4)
    if decoded > bound.max_image_bytes:
        raise error(
            f"{path}: the image declares {width} x {height} pixels of mode {mode}, {decoded:,} bytes decoded, more "
            f"than the limit of {bound.max_image_bytes:,} (environment variable {LIMIT_VARIABLES['max_image_bytes']})"
        )


# ---------------------------------------------------------------------------------- YAML


class AliasError(yaml.YAMLError):
    """A YAML anchor or alias, refused by :class:`NoAliasLoader`."""

    def __init__(self, line: int) -> None:
        super().__init__(f"anchors and aliases (&name, *name) are not allowed (line {line})")


class NoAliasLoader(yaml.SafeLoader):
    """PyYAML's safe loader without anchors and aliases, with YAML 1.2 floats (``1e6``, ``1.0e6``
    are numbers, as yaml-cpp and so ROS's map_server read them; PyYAML's YAML 1.1 reads them as
    strings)."""

    def compose_node(self, parent: Any, index: Any) -> Any:
        event = self.peek_event()
        if isinstance(event, yaml.AliasEvent) or getattr(event, "anchor", None) is not None:
            raise AliasError(event.start_mark.line + 1)
        return super().compose_node(parent, index)


NoAliasLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


def load_yaml(text: str) -> Any:
    """``text`` parsed by :class:`NoAliasLoader`; yaml.YAMLError (or RecursionError for absurd
    nesting) on bad input."""
    return yaml.load(text, Loader=NoAliasLoader)  # a SafeLoader subclass
