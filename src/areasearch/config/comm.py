"""Communication between the robots (:class:`CommConfig`, the ``comm`` group of the world's configuration):
which pairs of robots can exchange messages in a step, given where they stand in the true map.

Three models: ``full`` (every robot always hears every other one: the perfect-communication world),
``disc`` (a link when two robots are at most ``range_m`` apart) and ``signal``, the signal-strength model
of IR2 (Tan, Ma, Liang, Cao and Sartoretti, "IR2: Implicit Rendezvous for Robotic Exploration Teams under Sparse
Intermittent Connectivity", IROS 2024, code marmotlab/IR2-Multi-Robot-RL-Exploration,
``ss_realistic_model.py`` and ``parameter.py``), a log-distance path loss in which the stretch of the line
between the two robots that crosses obstacles loses power faster than the stretch in free space.

The received power of a link over a segment of ``free_m`` metres of free space and ``obstacle_m`` metres of
obstacle cells is ``P_R = tx_power_dbm - L`` with the path loss, in dB::

    L = ref_loss_db
        + [obstacle_m > 0]      * (10 * exponent_obstacle * log10(max(obstacle_m, obstacle_ref_m) / obstacle_ref_m) + K)
        + [free_m >= ref_distance_m] * (10 * exponent_free * log10(free_m / ref_distance_m) + X)

and the link exists when ``P_R > threshold_dbm``. ``X`` and ``K`` are the shadowing of the free and the
obstacle stretch, each drawn uniformly from ``[shadowing_min_db, shadowing_max_db]`` once per episode and
shared by every pair, as IR2 draws them once per environment. IR2 counts its distances in map pixels,
taken as 1 m each; its sensor reaches 80 pixels. Our defaults express its lengths in metres at
:data:`IR2_PIXEL_M` (0.04 m) per pixel, so that its sensor range is our camera's 3.2 m and a link reaches
as many sensor ranges here as it does in IR2 (IR2's numbers taken literally as metres would never break a
link on our maps, whose walls are 0.1-0.3 m thick and whose rooms are a few metres across). The ``max``
(``obstacle_ref_m``, one IR2 pixel) is ours: IR2 counts whole pixels, so a crossed obstacle is never
shorter than its reference; we measure the exact length, which can be a sliver where the line grazes a
corner, and a sliver must not gain power.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from ..errors import ConfigError
from .checks import brief, number, within

CommModel = Literal["full", "disc", "signal"]
"""The names of the communication models (``CommConfig.model``)."""

COMM_MODELS = ("full", "disc", "signal")

IR2_PIXEL_M = 0.04
"""Metres per IR2 map pixel in our defaults: IR2's sensor range (80 pixels) over our camera's (3.2 m)."""
MAX_COMM_M = 1e6
"""Largest length of a communication setting, metres."""
MAX_DB = 300.0
"""Largest magnitude of a power or loss setting, dB (dBm)."""
MAX_EXPONENT = 20.0
"""Largest path-loss exponent (free space is 2; dense obstacles 4-6)."""


@dataclass(frozen=True)
class CommConfig:
    """Which robots can talk to which: the communication model and its parameters (``full`` by default)."""

    model: CommModel = "full"
    """``full``: every robot always linked to every other one. ``disc``: a link when the Euclidean distance
    is at most ``range_m``. ``signal``: IR2's signal-strength model (module docstring). A team is split into
    groups by the links, and a chain of links connects its ends (multi-hop)."""
    range_m: float = 3.6
    """Link range of ``disc``, metres. IR2's proximity model draws its range per episode from 30 to 150
    pixels; this is the middle, 90 pixels, at 0.04 m per pixel."""
    tx_power_dbm: float = -20.0
    """Transmit power of ``signal``, dBm (IR2: -20)."""
    threshold_dbm: float = -70.0
    """Received power above which a ``signal`` link exists, dBm (IR2: -70)."""
    ref_loss_db: float = 31.0
    """Path loss at the reference distance, dB (IR2: 31)."""
    ref_distance_m: float = 1.4  # 35 IR2 pixels at IR2_PIXEL_M
    """Reference distance of the free-space term, metres: free stretches shorter than this add no loss
    (IR2: 35 pixels, 1.4 m at 0.04 m per pixel)."""
    exponent_free: float = 2.0
    """Path-loss exponent along the free stretch of the line (IR2: 2, free space)."""
    exponent_obstacle: float = 4.0
    """Path-loss exponent along the stretch through obstacle cells (IR2: 4)."""
    obstacle_ref_m: float = IR2_PIXEL_M
    """Reference length of the obstacle term, metres: the obstacle loss counts ``obstacle_m / obstacle_ref_m``,
    and at least 1 (IR2 counts obstacle pixels of 1 unit: one pixel, 0.04 m; the floor at 1 is ours)."""
    shadowing_min_db: float = 0.0
    """Least shadowing, dB: the free and the obstacle term each add a loss drawn uniformly from
    [``shadowing_min_db``, ``shadowing_max_db``] once per episode (IR2: 0)."""
    shadowing_max_db: float = 13.0
    """Largest shadowing, dB (IR2: 13). Set both to 0 for a deterministic model."""

    def validate(self) -> CommConfig:
        """Raise :class:`ConfigError` naming the first bad field; return self when all is well."""
        if not isinstance(self.model, str) or self.model not in COMM_MODELS:
            names = ", ".join(repr(m) for m in COMM_MODELS)
            raise ConfigError(f"comm.model must be one of {names}, got {brief(self.model)}")
        within("comm.range_m", self.range_m, 0.0, MAX_COMM_M)
        for name in ("tx_power_dbm", "threshold_dbm"):
            within(f"comm.{name}", getattr(self, name), -MAX_DB, MAX_DB)
        within("comm.ref_loss_db", self.ref_loss_db, 0.0, MAX_DB)
        for name in ("ref_distance_m", "obstacle_ref_m"):
            _positive_within(f"comm.{name}", getattr(self, name), MAX_COMM_M)
        for name in ("exponent_free", "exponent_obstacle"):
            _positive_within(f"comm.{name}", getattr(self, name), MAX_EXPONENT)
        within("comm.shadowing_min_db", self.shadowing_min_db, 0.0, MAX_DB)
        within("comm.shadowing_max_db", self.shadowing_max_db, 0.0, MAX_DB)
        if self.shadowing_max_db < self.shadowing_min_db:
            raise ConfigError(
                f"comm.shadowing_max_db must be at least shadowing_min_db ({self.shadowing_min_db:g}), "
                f"got {brief(self.shadowing_max_db)}"
            )
        if self.threshold_dbm >= self.tx_power_dbm - self.ref_loss_db:
            raise ConfigError(
                f"comm.threshold_dbm must be below tx_power_dbm - ref_loss_db "
                f"({self.tx_power_dbm - self.ref_loss_db:g} dBm, the power received at the reference distance: "
                f"no two robots could ever link), got {brief(self.threshold_dbm)}"
            )
        return self

    @property
    def active(self) -> bool:
        """Communication is limited (some pairs of robots may be out of touch)."""
        return self.model != "full"

    @property
    def budget_db(self) -> float:
        """The loss a ``signal`` link may have beyond the reference loss, dB: it exists while the obstacle,
        free-space and shadowing terms add up to less than this."""
        return self.tx_power_dbm - self.ref_loss_db - self.threshold_dbm


def _positive_within(name: str, value: object, maximum: float) -> None:
    """A finite number in (0, ``maximum``], or ConfigError naming the field."""
    checked = number(name, value)
    if not 0.0 < checked <= maximum:
        raise ConfigError(f"{name} must be a number above 0 and at most {maximum:g}, got {brief(value)}")
