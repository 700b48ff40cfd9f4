"""Plug-in goal planners: planners of other installed distributions, found by their entry points.

A distribution adds planners under the entry-point group :data:`GROUP` (``areasearch.planners``),
each entry point's name the planner's name and its object a factory: called with the planner's
settings as keyword arguments (none by default; ``weights`` when it takes ``--weights``), it returns
a :class:`~areasearch.planners.GoalPlanner`, the contract of the built-in registry's values. In a
``pyproject.toml``::

    [project.entry-points."areasearch.planners"]
    myplanner = "mypkg:make_planner"

The entry points are read once per process, on the first look-up of a name that is not built in
(so ``import areasearch`` pays nothing); a plug-in's module is imported only when its planner is
asked for. What can go wrong is kept per plug-in and said in one :class:`~areasearch.errors.ConfigError`
naming the plug-in and its distribution when (and only when) that planner is asked for: a module
that does not import, a factory that is not callable, raises or returns no planner, a name that two
distributions give, a name that is not a plain word. A plug-in named like a built-in planner is
never used (the built-in wins) and is listed as such by ``areasearch methods``.
"""

from __future__ import annotations

import inspect
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib import metadata
from typing import TYPE_CHECKING, Any

from ..errors import AreaSearchError, ConfigError
from ..inputs import clip, short

if TYPE_CHECKING:
    from . import GoalPlanner

GROUP = "areasearch.planners"
"""The entry-point group plug-in planners are registered under."""

NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")
"""A planner name: letters, digits, ``_ . -``, at most 64 characters (it names CSV rows and files)."""


def _error_text(exc: BaseException) -> str:
    """``Type: message`` of an exception raised by a plug-in, on one bounded line."""
    message = clip(str(exc), 200)
    return f"{type(exc).__name__}: {message}" if message else type(exc).__name__


@dataclass(eq=False)
class PlugIn:
    """One entry point of :data:`GROUP`: where it comes from and, once loaded, its factory."""

    name: str
    value: str
    """The entry point's object reference, ``module:attribute``."""
    distribution: str
    """``<distribution> <version>`` of the distribution that declares it."""
    problem: str | None = None
    """Why it cannot be used, when that is known without importing it (a name two distributions
    give, a name that is not a plain word)."""
    entry_point: metadata.EntryPoint | None = field(default=None, repr=False)
    _factory: Callable[..., Any] | None = field(default=None, init=False, repr=False)

    @property
    def origin(self) -> str:
        return f"plug-in {self.distribution}"

    def _fail(self, what: str) -> ConfigError:
        return ConfigError(f"plug-in planner {self.name!r} ({self.distribution}, {self.value}): {what}")

    def factory(self) -> Callable[..., Any]:
        """The entry point's object, imported on first use; ConfigError naming the plug-in when it
        cannot be imported or is not callable."""
        if self.problem is not None:
            raise self._fail(self.problem)
        if self._factory is None:
            assert self.entry_point is not None
            try:
                loaded = self.entry_point.load()
            except (Exception, SystemExit) as exc:  # a plug-in's import may raise anything
                raise self._fail(f"cannot be imported: {_error_text(exc)}") from None
            if not callable(loaded):
                raise self._fail(f"is not callable (a {type(loaded).__name__}); it must be a factory of a GoalPlanner")
            self._factory = loaded
        return self._factory

    def loaded_doc(self) -> str | None:
        """The factory's docstring if it has been imported already (None otherwise: asking never
        imports a plug-in)."""
        return inspect.getdoc(self._factory) if self._factory is not None else None

    def signature(self) -> inspect.Signature | None:
        """The factory's signature, None where Python cannot tell it (a builtin)."""
        try:
            return inspect.signature(self.factory())
        except (TypeError, ValueError):
            return None

    def takes(self, setting: str) -> bool:
        """Whether the factory takes the keyword argument ``setting`` by name."""
        sig = self.signature()
        if sig is None:
            return False
        param = sig.parameters.get(setting)
        return param is not None and param.kind in (param.POSITIONAL_OR_KEYWORD, param.KEYWORD_ONLY)

    def build(self, **kwargs: Any) -> GoalPlanner:
        """A planner from the factory; ConfigError naming the plug-in when the factory refuses the
        settings, raises, or returns something that is not a GoalPlanner."""
        from . import GoalPlanner

        factory = self.factory()
        sig = self.signature()
        if sig is not None:
            try:
                sig.bind(**kwargs)
            except TypeError as err:
                raise ConfigError(f"planner {self.name!r}: {err}") from None
        try:
            planner = factory(**kwargs)
        except AreaSearchError as exc:  # the plug-in's own words about its settings
            raise self._fail(clip(str(exc), 300)) from None
        except (Exception, SystemExit) as exc:
            raise self._fail(f"its factory raised {_error_text(exc)}") from None
        if not (isinstance(planner, GoalPlanner) and callable(planner.reset) and callable(planner.assign)):
            raise self._fail(
                f"its factory returned {short(planner, 60)}, not a GoalPlanner (an object with name, "
                "reset(rng) and assign(obs))"
            )
        return planner

    def check(self) -> str | None:
        """None when the plug-in imports and its factory, called with no settings, returns a
        GoalPlanner; else the error message."""
        try:
            self.build()
        except ConfigError as exc:
            return str(exc)
        return None


@dataclass
class Discovery:
    """What the entry points of :data:`GROUP` hold in this process."""

    plugins: dict[str, PlugIn] = field(default_factory=dict)
    """The usable names (not built in), each to its plug-in (which may fail when asked for)."""
    shadowed: list[PlugIn] = field(default_factory=list)
    """Plug-ins named like a built-in planner: never used."""
    invalid: list[PlugIn] = field(default_factory=list)
    """Plug-ins whose name is not a planner name: they cannot be asked for."""
    error: str | None = None
    """Why the entry points could not be read at all (the built-in planners still work)."""


def _distribution(ep: metadata.EntryPoint) -> str:
    dist = getattr(ep, "dist", None)
    if dist is None:
        return "an unknown distribution"
    name = dist.metadata["Name"] if dist.metadata is not None else None
    return f"{name or 'an unnamed distribution'} {dist.version or '(no version)'}"


def discover(builtins: Callable[[str], bool]) -> Discovery:
    """The plug-ins declared by the installed distributions (:func:`importlib.metadata.entry_points`);
    ``builtins(name)`` says whether ``name`` is a built-in planner (a plug-in of that name is
    shadowed). Nothing is imported here, and nothing raises: a failure is recorded."""
    found = Discovery()
    try:
        entries = list(metadata.entry_points(group=GROUP))
    except Exception as exc:  # damaged metadata of some distribution: the built-ins are unaffected
        found.error = f"the entry points of {GROUP!r} cannot be read: {_error_text(exc)}"
        return found
    by_name: dict[str, list[PlugIn]] = {}
    for ep in entries:
        plugin = PlugIn(ep.name, ep.value, _distribution(ep), entry_point=ep)
        if not NAME.match(ep.name):
            plugin.problem = f"{short(ep.name, 70)} is not a planner name (letters, digits, _ . -; at most 64)"
            found.invalid.append(plugin)
        elif builtins(ep.name):
            found.shadowed.append(plugin)
        else:
            by_name.setdefault(ep.name, []).append(plugin)
    for name, plugins in sorted(by_name.items()):
        if len(plugins) > 1:
            who = ", ".join(sorted(p.distribution for p in plugins))
            for plugin in plugins:
                plugin.problem = f"the name {name!r} is given by {len(plugins)} distributions ({who}); uninstall one"
        found.plugins[name] = plugins[0]
    return found
