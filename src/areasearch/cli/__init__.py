"""The ``areasearch`` command line.

Subcommands:

* ``run``: one search episode on a map with a goal planner; writes a PNG, prints the metrics.
* ``maps``: the bundled maps (size class, free area, license).
* ``eval``: goal planners over maps, team sizes and seeded episodes, resumable: the paper's tables
  (:mod:`areasearch.harness.evaluate`).
* ``render``: one goal-planner episode, or several planners on the same episode side by side, as a
  GIF / MP4 (:mod:`areasearch.harness.animate`).
* ``assign``: goals for your own robots on your own map, JSON in and out (:mod:`areasearch.service.assign`).
* ``train``: PPO training of a DA-HGNN / NCM goal planner, resumable (:mod:`areasearch.training.train`).
* ``serve``: ``assign`` as a warm HTTP JSON service for robot stacks (:mod:`areasearch.service.serve`).
* ``ros2``: ``assign`` as a ROS 2 node for a robot team: ``/map`` and poses in, Nav2 goals out
  (:mod:`areasearch.ros2.node`; the ``ros2`` extra).
* ``methods``: every goal planner with its origin: built in, shipped policy, plug-in
  (:func:`areasearch.planners.describe_planners`).

``run``, ``render``, ``assign``, ``serve`` and ``ros2`` take ``--weights PREFIX``: a learned method
(``--method``) plays your own weights, or without ``--method`` the network the weights describe
(:func:`areasearch.planners.choose_planner`); the output names the weights' SHA-256.

The commands share their option names and checks: ``--robots`` (team size, 1-8), ``--max-steps``
(horizon in primitive steps), ``--seed``, ``--workers``, and ``--set KEY=VALUE`` (repeatable) on
every command that builds a world (:func:`areasearch.config.parse_settings`; world keys such as
``robot.radius_m`` or ``targets.count``, training-config keys for ``train``), and ``--protocol`` (the
coverage rule, :data:`areasearch.config.PROTOCOLS`) on ``run``, ``render`` and ``eval``. Progress of ``run``,
``render``, ``eval`` and ``train`` goes to stderr: a bar on a terminal, a plain line every 10 s otherwise
(:mod:`areasearch.progress`). Results printed as JSON have their numbers rounded to what they mean
(:func:`areasearch.harness.report.json_ready`). Bad input ends with one ``areasearch: error: ...`` line on stderr
and exit status 2 (after the usage of the command for a malformed command line), never a traceback;
outputs are written atomically, so nothing already there is lost.

The parts: :mod:`.options` (the parser, argument types, shared options, the world options),
:mod:`.episodes` (``run``, ``eval``, ``render``), :mod:`.tools` (``maps``, ``assign``, ``serve``,
``ros2``, ``train``, ``methods``). ``python -m areasearch.cli`` runs :func:`main` (:mod:`.__main__`).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence

from .._version import __version__
from ..errors import AreaSearchError
from ..inputs import WRITE_ERRORS, int_digits_message, is_int_digits_error
from .episodes import add_eval_parser, add_render_parser, add_run_parser
from .options import Parser, error_line
from .tools import (
    add_assign_parser,
    add_maps_parser,
    add_methods_parser,
    add_ros2_parser,
    add_serve_parser,
    add_train_parser,
)

__all__ = ["Parser", "build_parser", "main"]

# ---------------------------------------------------------------------------------- main


def build_parser() -> Parser:
    parser = Parser(
        prog="areasearch", description="Multi-robot collaborative area search (explore and cover), after DA-HGNN."
    )
    parser.add_argument("--version", action="version", version=f"areasearch {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add_parser in (add_run_parser, add_maps_parser, add_eval_parser, add_render_parser, add_assign_parser):
        add_parser(sub)
    add_train_parser(sub)
    add_serve_parser(sub)
    add_ros2_parser(sub)
    add_methods_parser(sub)
    parser.commands = dict(sub.choices)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """The command line: one subcommand with its arguments; its exit status. Bad input ends in one
    ``areasearch: error: ...`` line and status 2: an AreaSearchError, an integer beyond Python's
    conversion limit wherever it was met, a file that cannot be written (file too large, disk full,
    read-only file system: an OSError with a file name); never a traceback."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except AreaSearchError as exc:
        print(error_line(exc), file=sys.stderr)
        return 2
    except ValueError as exc:
        if not is_int_digits_error(exc):
            raise
        print(error_line(f"a value given is {int_digits_message()}"), file=sys.stderr)
        return 2
    except BrokenPipeError:  # e.g. `areasearch maps | head` (before OSError: it is one)
        sys.stdout = open(os.devnull, "w")
        return 1
    except OSError as exc:
        if exc.filename is None or exc.errno not in WRITE_ERRORS:
            raise
        print(error_line(f"{exc.filename}: {WRITE_ERRORS[exc.errno]}"), file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("areasearch: interrupted", file=sys.stderr)
        return 130
