"""Exception types raised by areasearch library calls.

Every problem with user input (a map file, a config field, an action) raises a subclass of
:class:`AreaSearchError` with one message that names the file or field at fault. The command
line turns these into one line on stderr and a non-zero exit, never a traceback.
"""

from __future__ import annotations


class AreaSearchError(Exception):
    """Base class of every error areasearch raises on bad input."""


class MapError(AreaSearchError):
    """A map cannot be loaded or used (missing file, not an image, bad YAML, no free cell...)."""


class ConfigError(AreaSearchError, ValueError):
    """A configuration field has a value that cannot work (negative radius, too many robots...)."""


class TrainingDiverged(AreaSearchError):
    """A training run's losses or parameters became NaN or infinite; nothing of that iteration is saved."""
