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
* :func:`check_path`: a path a user gave (on the command line or inside a file) that no system call
  can take: a NUL byte, a component longer than the file system's 255 bytes, more than 4,095 bytes.
* :func:`check_output_path`: a path an output is written to is not a device, a named pipe or a socket
  (an atomic write renames a temporary file over it: as root, ``--out /dev/null`` replaced the
  machine's null device with a picture).
* :func:`parse_json`: JSON with one message for an integer longer than Python converts
  (``sys.get_int_max_str_digits()``, 4,300 digits), which it otherwise reports as a bare ValueError.
* :func:`write_error`: the message of an OSError met while writing (file too large, disk full,
  read-only file system).
* :func:`short`, :func:`clip`, :func:`clip_words`: ``repr`` of a user's value, an exception's text, a
  message's long words, cut to a bounded length for messages.

The limits are an :class:`InputLimits`; :func:`limits` reads them, each one overridable by an
environment variable (``AREASEARCH_MAX_MAP_CELLS`` and the others named in the dataclass).
"""

from __future__ import annotations

import dataclasses
import errno
import json
import math
import os
import re
import stat
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
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


def is_real(value: Any) -> bool:
    """Whether ``value`` is one real number as a user may hand it to the library: a Python int or
    float or a NumPy integer or floating scalar (``np.float32`` from a ROS message), not a bool (of
    either kind), a complex number, a string or anything else."""
    if isinstance(value, (bool, np.bool_)):
        return False
    return isinstance(value, (int, float, np.integer, np.floating))


def is_finite_real(value: Any) -> bool:
    """Whether ``value`` is a real number (:func:`is_real`) that is finite as a float (an integer
    beyond the largest float is not)."""
    if not is_real(value):
        return False
    try:
        return math.isfinite(float(value))
    except OverflowError:
        return False


def real_number(name: str, value: Any, error: type[AreaSearchError] = ConfigError) -> float:
    """``value`` (:func:`is_real`) as a finite float, or ``error`` naming ``name``: never the TypeError
    or OverflowError of a conversion deep inside."""
    if not is_real(value):
        raise error(f"{name} must be a number, got {short(value)}")
    try:
        number = float(value)
    except OverflowError:  # an integer beyond the largest float
        number = math.inf
    if not math.isfinite(number):
        raise error(f"{name} must be a finite number, got {short(value)}")
    return number


def clip(text: str, width: int = 200) -> str:
    """``text`` (an exception's message) on one line, cut to about ``width`` characters."""
    text = " ".join(str(text).split())
    return text if len(text) <= width else text[: width - 3] + "..."


def clip_words(text: str, width: int = 300, total: int = 1500) -> str:
    """``text`` on one line with every word (a run of non-blanks: a path, a quoted value) longer than
    ``width`` characters cut in its middle, so that both ends show (a path's folder and file name),
    and the whole cut to ``total`` characters: the last guard of an error line quoting user input."""
    words = []
    for word in str(text).split():
        if len(word) > width:
            keep = (width - 3) // 2
            word = f"{word[:keep]}...{word[-keep:]}"
        words.append(word)
    line = " ".join(words)
    return line if len(line) <= total else line[: total - 3] + "..."


INT_DIGITS_MESSAGE = "an integer longer than {digits:,} digits; no field takes one"
"""What an integer literal beyond Python's conversion limit is called in a message."""


def int_digits_message() -> str:
    """:data:`INT_DIGITS_MESSAGE` with the interpreter's limit (4,300 by default)."""
    return INT_DIGITS_MESSAGE.format(digits=sys.get_int_max_str_digits())


def is_int_digits_error(exc: BaseException) -> bool:
    """Whether ``exc`` is Python's refusal to convert an integer literal of too many digits (a
    ValueError "Exceeds the limit (4300 digits) for integer string conversion")."""
    return isinstance(exc, ValueError) and "integer string conversion" in str(exc)


def parse_json(data: str | bytes, source: str, error: type[AreaSearchError] = ConfigError, what: str = "JSON") -> Any:
    """The JSON document ``data`` (from ``source``, named in the messages): ``error`` naming the source
    for bytes that are not UTF-8, text that does not parse, nesting too deep, or an integer longer than
    Python converts (:func:`int_digits_message`)."""
    try:
        text = data.decode("utf-8") if isinstance(data, bytes) else data
        return json.loads(text)
    except UnicodeDecodeError as exc:
        raise error(f"{source}: not valid {what}: not UTF-8 text (byte {exc.start})") from None
    except json.JSONDecodeError as exc:
        raise error(f"{source}: not valid {what} ({clip(str(exc))})") from None
    except RecursionError:
        raise error(f"{source}: not valid {what} (nested too deeply)") from None
    except ValueError as exc:
        if is_int_digits_error(exc):
            raise error(f"{source}: not valid {what}: {int_digits_message()}") from None
        raise error(f"{source}: not valid {what} ({clip(str(exc))})") from None


# ---------------------------------------------------------------------------------- files

_KINDS = (
    (stat.S_ISDIR, "a folder"),
    (stat.S_ISFIFO, "a named pipe (FIFO)"),
    (stat.S_ISSOCK, "a socket"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
)


MAX_NAME_BYTES = 255
"""Longest path component, bytes (NAME_MAX of Linux's file systems; macOS's and Windows' are 255 too)."""
MAX_PATH_BYTES = 4095
"""Longest path, bytes (PATH_MAX of Linux less its terminating NUL)."""


def check_path(path: str | Path, what: str, error: type[AreaSearchError] = AreaSearchError) -> Path:
    """``path`` as a Path, or ``error`` naming it (cut to a bounded length) when no system call can take
    it: a NUL byte (Python's own error is a bare ValueError), a component longer than
    :data:`MAX_NAME_BYTES` or a whole longer than :data:`MAX_PATH_BYTES` (ENAMETOOLONG, which some
    checks of pathlib do not catch)."""
    text = os.fspath(path)
    if "\x00" in text:
        raise error(f"{what} {short(text)} holds a NUL byte, which no path can")
    encoded = os.fsencode(text)
    if len(encoded) > MAX_PATH_BYTES:
        raise error(f"{what} {short(text)} is {len(encoded):,} bytes long; a path is at most {MAX_PATH_BYTES:,}")
    longest = max(encoded.split(b"/"), key=len)
    if len(longest) > MAX_NAME_BYTES:
        raise error(
            f"{what} {short(text)} has a component of {len(longest):,} bytes; a file or folder name is at most "
            f"{MAX_NAME_BYTES} bytes"
        )
    return Path(path)


def special_kind(info: os.stat_result) -> str | None:
    """What a file that is not a regular file or a folder is ("a named pipe (FIFO)", "a character
    device", ...), or None for a regular file or a folder."""
    return next((kind for test, kind in _KINDS[1:] if test(info.st_mode)), None)


def _stat(path: Path, label: str, error: type[AreaSearchError]) -> os.stat_result:
    """``os.stat(path)``, following symbolic links; ``error`` for a symbolic link loop (``label``
    names the path in the message), any other OSError as it came."""
    try:
        return os.stat(path)
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise error(f"{path}: {label} is a symbolic link loop") from None
        raise


def check_output_path(path: str | Path, what: str, error: type[AreaSearchError] = AreaSearchError) -> Path:
    """``path`` (:func:`check_path`) unless something other than a regular file or a folder stands
    there, following symbolic links: ``error`` for a device (``/dev/null``), a named pipe or a socket,
    which an atomic write's rename would replace (as root even in ``/dev``), a symbolic link loop."""
    path = check_path(path, f"{what} path", error)
    try:
        info = _stat(path, f"{what} path", error)
    except OSError:
        return path  # nothing there (or a broken link): the write makes the file
    kind = special_kind(info)
    if kind is not None:
        raise error(f"{path}: {what} path is {kind}, not a regular file; give a file name")
    return path


WRITE_ERRORS = {
    errno.EFBIG: "file too large (the file-size limit, ulimit -f, or the file system's)",
    errno.ENOSPC: "no space left on the device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EROFS: "read-only file system",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.EIO: "input/output error",
}
"""What the errors a write can meet are called in a message."""


def write_error(path: str | Path, exc: OSError, what: str = "file") -> str:
    """One line for an OSError met while writing ``path``: ``"<path>: cannot write the <what>: no space
    left on the device"``."""
    reason = WRITE_ERRORS.get(exc.errno or 0) or clip(exc.strerror or str(exc), 120)
    return f"{path}: cannot write the {what}: {reason}"


def regular_file(
    path: str | Path, what: str, error: type[AreaSearchError] = AreaSearchError, missing: str = "not found"
) -> os.stat_result:
    """The ``os.stat`` of ``path`` when it is a regular file (a symbolic link to one is fine); else
    ``error`` with one message naming the path and what it is: ``"<path>: <what> <missing>"``, a
    symbolic link loop, a broken link, a folder, a named pipe, a path no system call takes
    (:func:`check_path`)... It never opens the path."""
    path = check_path(path, f"{what} path", error)
    try:
        info = _stat(path, what, error)
    except OSError as exc:
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
    path: str | Path, what: str, max_bytes: int, variable: str | None, error: type[AreaSearchError] = AreaSearchError
) -> bytes:
    """The bytes of the regular file ``path`` (:func:`regular_file`), refused when it holds more than
    ``max_bytes`` (the environment ``variable``, if any, raises the limit) without reading it whole."""
    path = Path(path)
    info = regular_file(path, what, error)
    too_big = f"{path}: {what} is larger than {max_bytes:,} bytes, the limit"
    if variable is not None:
        too_big += f" (environment variable {variable})"
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

    def construct_yaml_int(self, node: Any) -> Any:
        """An integer; one error naming the line for one longer than Python converts (its own
        ValueError would escape the YAML errors)."""
        try:
            return super().construct_yaml_int(node)
        except ValueError as exc:
            if not is_int_digits_error(exc):
                raise
            raise yaml.constructor.ConstructorError(
                None, None, f"{int_digits_message()} (line {node.start_mark.line + 1})", None
            ) from None


NoAliasLoader.add_constructor("tag:yaml.org,2002:int", NoAliasLoader.construct_yaml_int)
NoAliasLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


def load_yaml(text: str) -> Any:
    """``text`` parsed by :class:`NoAliasLoader`; yaml.YAMLError (or RecursionError for absurd
    nesting) on bad input."""
    return yaml.load(text, Loader=NoAliasLoader)  # a SafeLoader subclass
