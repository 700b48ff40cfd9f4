"""The checks every configuration field goes through: each raises :class:`~areasearch.errors.ConfigError`
naming the field, with the offending value cut short, so a bad setting ends in one readable message."""

from __future__ import annotations

import math
from typing import Any

from ..errors import ConfigError


def brief(value: Any, limit: int = 60) -> str:
    """``repr(value)``, cut to ``limit`` characters (user input in a message stays bounded)."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def number(name: str, value: Any) -> float:
    """``value`` as a finite float, or ConfigError naming the field."""
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
        raise ConfigError(f"{name} must be a finite number, got {brief(value)}")
    return float(value)


def integer(name: str, value: Any, minimum: int, maximum: int | None = None) -> int:
    """``value`` as an integer >= ``minimum`` (and <= ``maximum``: a bound on what the arrays it
    sizes may cost), or ConfigError naming the field."""
    if not isinstance(value, int) or isinstance(value, bool) or value < minimum:
        raise ConfigError(f"{name} must be an integer >= {minimum}, got {brief(value)}")
    if maximum is not None and value > maximum:
        raise ConfigError(f"{name} must be an integer from {minimum} to {maximum:,}, got {brief(value)}")
    return value


def within(name: str, value: Any, minimum: float, maximum: float) -> float:
    """A finite number in [``minimum``, ``maximum``], or ConfigError naming the field and the bounds."""
    checked = number(name, value)
    if not minimum <= checked <= maximum:
        raise ConfigError(f"{name} must be a number from {minimum:g} to {maximum:g}, got {brief(value)}")
    return checked


def positive(name: str, value: Any, maximum: float | None = None) -> None:
    """A positive finite number (at most ``maximum``: lengths become cell counts and array sizes, so a
    robot of 1e9 m would exhaust the memory before any error), or ConfigError naming the field."""
    if number(name, value) <= 0:
        raise ConfigError(f"{name} must be a positive number, got {brief(value)}")
    if maximum is not None and value > maximum:
        raise ConfigError(f"{name} must be a positive number of at most {maximum:g}, got {brief(value)}")
