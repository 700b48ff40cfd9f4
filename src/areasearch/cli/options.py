"""The parser of the ``areasearch`` command line and what its subcommands share: options given
once (:class:`Parser`), argument types that name the option in their refusal, the shared options
(``--robots``, ``--max-steps``, ``--set``, ``--protocol``, ``--realism``), the world options of a command
(:func:`world_options`: ``--set``, ``--protocol`` and ``--realism`` as one typed configuration), JSON output and the
one ``areasearch: error: ...`` line of bad input."""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn, cast

from ..config import (
    CAMERA_LIMITS,
    FPS_RANGE,
    MAX_ROBOTS,
    NO_REALISM,
    PROTOCOLS,
    REALISM_NAMES,
    ROBOT_LIMITS,
    ProtocolName,
    SearchConfig,
    WorldConfig,
    override,
    parse_settings,
    realism_preset,
    realism_settings,
    search_config,
    search_key,
    search_settings,
)
from ..errors import ConfigError
from ..folderlock import check_file_path
from ..inputs import clip_words, int_digits_message, is_int_digits_error, short
from ..sim.mapfiles import MAX_CELL_M, MAX_ORIGIN_M, MIN_CELL_M

Subparsers = Any  # argparse's _SubParsersAction, private in typeshed's view

# ---------------------------------------------------------------------------------- the parser


class _Once(argparse.Action):
    """An option given a second time is refused, naming it (rather than the last one silently winning)."""

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: Any,
        option_string: str | None = None,
    ) -> None:
        given = vars(namespace).setdefault("_given_options", set())
        if self.dest in given:
            parser.error(f"argument {'/'.join(self.option_strings)}: given twice; give it once")
        given.add(self.dest)
        super().__call__(parser, namespace, values, option_string)


class _StoreOnce(_Once, argparse._StoreAction):
    """``store``, once."""


class _StoreTrueOnce(_Once, argparse._StoreTrueAction):
    """``store_true``, once."""


class Parser(argparse.ArgumentParser):
    """The parser of the command and its subcommands: every option but the repeatable ``--set`` may
    be given once (``--methods a --methods b`` is refused, naming ``--methods``)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.commands: dict[str, argparse.ArgumentParser] = {}
        """The subcommands' parsers by name (set by :func:`build_parser`)."""
        self.register("action", None, _StoreOnce)
        self.register("action", "store", _StoreOnce)
        self.register("action", "store_true", _StoreTrueOnce)

    def parse_args(  # type: ignore[override]
        self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None
    ) -> argparse.Namespace:
        """argparse's, but arguments that no option takes are refused by the subcommand they follow, so
        the usage printed is that subcommand's."""
        parsed, extra = self.parse_known_args(args, namespace)
        if extra:
            self.commands.get(getattr(parsed, "command", None) or "", self).error(
                f"unrecognized arguments: {' '.join(extra)}"
            )
        return parsed

    def error(self, message: str) -> NoReturn:
        """A malformed command line: the usage of the (sub)command, which names it, then one
        ``areasearch: error: ...`` line, the last line of every other bad input too; exit status 2."""
        self.print_usage(sys.stderr)
        self.exit(2, f"{error_line(message)}\n")


# ---------------------------------------------------------------------------------- argument types


def integer_type(minimum: int, what: str) -> Callable[[str], int]:
    """An argparse type: an integer >= ``minimum``, refused as "expected <what>, got ..."."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError as exc:
            if is_int_digits_error(exc):
                raise argparse.ArgumentTypeError(f"expected {what}, got {int_digits_message()}") from None
            raise argparse.ArgumentTypeError(f"expected {what}, got {short(text)}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"expected {what}, got {value}")
        return value

    return parse


def real_type(low: float, high: float, what: str, *, low_open: bool = False) -> Callable[[str], float]:
    """An argparse type: a finite number in [``low``, ``high``] (``(low, high]`` with ``low_open``),
    refused, naming the option, as "expected a number in [low, high] (<what>), got ..." (``inf``, ``nan``,
    ``1e308`` and ``1e-9`` frames per second never reach the code that would divide by them or turn
    them into array sizes)."""
    bounds = f"{'(' if low_open else '['}{low:g}, {high:g}]"

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number in {bounds} ({what}), got {short(text)}") from None
        if not math.isfinite(value) or value < low or (low_open and value == low) or value > high:
            raise argparse.ArgumentTypeError(f"expected a number in {bounds} ({what}), got {short(text)}")
        return value

    return parse


positive_int = integer_type(1, "a positive integer")
"""An integer >= 1 (counts, horizons, frame spacing)."""
non_negative_int = integer_type(0, "a non-negative integer")
"""An integer >= 0 (``train --workers``: 0 plays in this process)."""
seed_type = integer_type(0, "a non-negative integer seed")
"""A seed, an integer >= 0."""


fps_type = real_type(*FPS_RANGE, "frames per second")
"""``render --fps``: a GIF stores a frame's duration in hundredths of a second (at most 655 s)."""
resolution_type = real_type(MIN_CELL_M, MAX_CELL_M, "metres per cell")
"""``assign --resolution``: the cell sizes a map may have (:func:`areasearch.sim.mapfiles.check_resolution`)."""
origin_type = real_type(-MAX_ORIGIN_M, MAX_ORIGIN_M, "metres")
"""``assign --origin``: a map's corner within :data:`areasearch.sim.mapfiles.MAX_ORIGIN_M` of the frame's zero."""
radius_type = real_type(0.0, ROBOT_LIMITS["radius_m"], "metres", low_open=True)
"""``assign --radius-m``: the footprint radii :class:`areasearch.config.RobotConfig` takes."""
sensor_range_type = real_type(0.0, CAMERA_LIMITS["max_range_m"], "metres", low_open=True)
"""``assign --sensor-range-m``: the ranges :class:`areasearch.config.CameraConfig` takes."""


def robots_type(text: str) -> int:
    """A team size, 1 to :data:`~areasearch.config.MAX_ROBOTS`."""
    value = positive_int(text)
    if value > MAX_ROBOTS:
        raise argparse.ArgumentTypeError(f"at most {MAX_ROBOTS} robots, got {value}")
    return value


# ---------------------------------------------------------------------------------- shared options

MAP_HELP = "bundled map id, PNG in a map folder, map folder, ROS .yaml, or procedural:<class>"
METHOD_HELP = "goal planner (default greedy; 'areasearch methods' lists them, plug-ins included)"
WEIGHTS_HELP = (
    "your own weights, PREFIX.safetensors + PREFIX.json (e.g. runs/dahgnn/policy): played by the learned "
    "--method, or without --method by the network they describe"
)
EPISODE_OPTIONS = {"world.num_robots": "--robots", "world.max_steps": "--max-steps"}
"""World settings that the commands playing episodes take as options of their own, not by ``--set``."""


def add_robots(parser: argparse.ArgumentParser, *, several: bool = False) -> None:
    if several:
        parser.add_argument(
            "--robots", nargs="+", type=robots_type, default=[3], metavar="R", help="team sizes, 1-8 (default 3)"
        )
    else:
        parser.add_argument("--robots", type=robots_type, default=3, help="team size, 1-8 (default 3)")


def add_max_steps(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--max-steps", type=positive_int, default=3600, metavar="N", help="horizon in primitive steps (default 3600)"
    )


def add_set(parser: argparse.ArgumentParser, example: str, what: str = "a world setting") -> None:
    parser.add_argument(
        "--set",
        action="append",
        metavar="KEY=VALUE",
        help=f"override {what}, e.g. --set {example} (repeatable; values read as JSON numbers, true/false, lists)",
    )


def add_protocol(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--protocol",
        choices=tuple(PROTOCOLS),
        default=None,
        help="coverage protocol: paper (default; a robot centre passes over the target's cell) or passby "
        "(within 0.3 m at the end of a step: a looser rule, for results measured under it)",
    )


def add_realism(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--realism",
        choices=REALISM_NAMES,
        default=None,
        help="a preset of the world's imperfections: motion and depth noise, target detection, communication "
        "(default none: the perfect world; docs/environments.md#realism-presets); a --set setting given with "
        "it wins over the preset's value",
    )


@dataclass(frozen=True)
class WorldOptions:
    """The world options of a command that builds a world: its ``--set`` settings, its ``--protocol`` and
    its ``--realism``."""

    settings: Mapping[str, Any]
    """The ``--set`` settings by their full keys (:func:`areasearch.config.search_settings`), sorted."""
    protocol: ProtocolName | None = None
    """``--protocol``, when given."""
    realism: str = NO_REALISM
    """``--realism``, the name of a preset of :data:`areasearch.config.REALISM_PRESETS` (``none``: no settings)."""

    @property
    def given(self) -> dict[str, Any]:
        """The settings as given, a ``--protocol`` among them as ``world.protocol``: what a command's
        output echoes and a results folder's ``config.json`` records."""
        given = dict(self.settings)
        if self.protocol is not None:
            given["world.protocol"] = self.protocol
        return given

    @property
    def applied(self) -> dict[str, Any]:
        """The settings the world is built with: the ``--realism`` preset's, with the settings :attr:`given`
        over them (a setting given wins over the preset's value)."""
        return realism_settings(self.realism, self.given)

    def config(self, *, checked: bool = True) -> SearchConfig:
        """The typed configuration: the protocol a field of the world, the settings applied, validated
        (ConfigError naming the first bad value). ``checked=False``: not validated here, for a command
        that checks its other arguments first (``eval``: :func:`areasearch.harness.plan.run_config`
        validates it)."""
        base = SearchConfig()
        if self.protocol is not None:
            base = dataclasses.replace(base, world=WorldConfig(protocol=self.protocol))
        settings = realism_settings(self.realism, self.settings)
        if not checked:
            return cast(SearchConfig, override(base, **settings))
        return search_config(settings, base)


def world_options(
    pairs: Sequence[str] | None,
    own: Mapping[str, str],
    protocol: ProtocolName | None = None,
    realism: str | None = None,
) -> WorldOptions:
    """The ``--set`` pairs of a command that builds a world, by their full keys, its ``--protocol`` and
    its ``--realism`` (None: ``none``); a key that the command sets by an option of its own (``own``:
    full key -> option) is refused, naming the option, and so is a protocol given both ways."""
    name = realism or NO_REALISM
    realism_preset(name)  # ConfigError for an unknown one (a caller other than the parser)
    settings = parse_settings(pairs or ())
    for key in settings:
        option = own.get(search_key(key))
        if option is not None:
            raise ConfigError(f"--set {key}=... is not allowed here; use {option}")
    resolved = search_settings(settings)
    if protocol is None:
        return WorldOptions(resolved, realism=name)
    if "world.protocol" in resolved:
        raise ConfigError("give the protocol once: --protocol or --set protocol=..., not both")
    return WorldOptions(resolved, protocol, name)


def output_file(path: Path, what: str) -> None:
    check_file_path(path, what)


def print_json(doc: Mapping[str, Any]) -> None:
    """Print a command's result as indented JSON, its numbers rounded to what they mean
    (:func:`areasearch.harness.report.json_ready`); the ``settings`` given are echoed as given."""
    from ..harness.report import json_ready

    rounded = json_ready(dict(doc))
    print(json.dumps({k: doc[k] if k == "settings" else rounded[k] for k in doc}, indent=2))


def error_line(message: object) -> str:
    """The one ``areasearch: error: ...`` line of a message: on one line, a word longer than 300
    characters (a path or value the user gave, perhaps a megabyte long) cut in its middle, the whole at
    most about 1,500 characters (:func:`areasearch.inputs.clip_words`)."""
    return f"areasearch: error: {clip_words(str(message))}"
