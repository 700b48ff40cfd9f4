"""Map quality: how much of a map (a :class:`~areasearch.sim.mapper.Mapper`) is wrong, against the truth.

With noise on (:mod:`areasearch.sim.noise`) the mapper fuses depth at the *believed* poses, so the map the
robots plan on blurs and misaligns; the metrics (explored %, covered %) go by the truth and do not show it.
This module gives the figure that does.

**The truth** is the map a perfect mapper makes: the clean depth images, fused at the true poses, by the
mapper's own rule (:func:`true_map`). On the noisy path the world keeps it as it senses
(:attr:`Imperfections.seen <areasearch.sim.noise.Imperfections.seen>` and
:attr:`~areasearch.sim.noise.Imperfections.seen_occupied`, the union of every frame's view); with every
imperfection off the team map *is* that map. Why not ``scene.free`` itself: a map can only be asked to hold
what was seen, and the truth must say of every cell the same kind of thing the map says (unknown / free /
occupied) by the same discretisation rule, so that a perfect robot scores 0 by construction and every
wrong cell is the imperfections' doing. (Measured on robotathome_sarmis, the perfect map's obstacles are
exactly its seen cells that are not ``scene.free``; :func:`scene_truth` is that comparison, kept for
checks.)

**The figure** (:func:`score`): every cell is in one of three states in the map (unknown: not explored;
free: explored, not occupied; occupied) and in the truth (not seen; free; occupied). The cells judged are
those the map marks explored or the truth saw (the union: cells nobody claims to know are left out, so
the figure does not shrink as the building grows). A judged cell is *wrong* when the two states differ.
``error_pct`` = 100 x wrong / judged. The wrong cells fall into four disjoint parts that add up to them:

* ``phantom``: mapped occupied where the truth saw free floor (an obstacle in the wrong place);
* ``missed``: an obstacle the truth saw that the map holds as free or unknown;
* ``misplaced``: mapped explored (free or occupied) where no frame truly saw (the map spread to cells
  the robots never looked at: drift);
* ``unmapped``: free floor the truth saw that the map leaves unknown (it put it elsewhere).

Each part is reported as a share of the judged cells too, so the parts' percentages add up to
``error_pct``. Units: cells of the scene's grid (H, W); percentages 0-100.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .mapper import Mapper
from .world import World

PARTS = ("phantom", "missed", "misplaced", "unmapped")
"""The parts of the wrong cells, in the order :meth:`MapQuality.parts_pct` gives them."""


@dataclass(frozen=True)
class MapQuality:
    """How a map compares with the truth: cell counts (:func:`score`)."""

    judged: int
    """Cells the map marks explored or the truth saw."""
    phantom: int
    """Mapped occupied, truly free."""
    missed: int
    """Truly occupied, mapped free or unknown."""
    misplaced: int
    """Mapped explored (free or occupied), never truly seen."""
    unmapped: int
    """Truly seen free floor, mapped unknown."""

    @property
    def wrong(self) -> int:
        """Judged cells whose mapped state differs from the true one: the sum of the four parts."""
        return self.phantom + self.missed + self.misplaced + self.unmapped

    @property
    def error_pct(self) -> float:
        """100 x wrong / judged (0 when nothing is judged)."""
        return 100.0 * self.wrong / self.judged if self.judged else 0.0

    def parts_pct(self) -> dict[str, float]:
        """Each part as a percentage of the judged cells (they add up to :attr:`error_pct`)."""
        share = 100.0 / self.judged if self.judged else 0.0
        return {name: getattr(self, name) * share for name in PARTS}


def score(
    explored: np.ndarray, occupied: np.ndarray, true_explored: np.ndarray, true_occupied: np.ndarray
) -> MapQuality:
    """Compare a map (``explored``, ``occupied``: (H, W) bool, occupied cells explored) with the truth
    (``true_explored``: cells truly seen; ``true_occupied``: those of them that are obstacles)."""
    true_free = true_explored & ~true_occupied
    return MapQuality(
        judged=int(np.count_nonzero(explored | true_explored)),
        phantom=int(np.count_nonzero(occupied & true_free)),
        missed=int(np.count_nonzero(true_occupied & ~occupied)),
        misplaced=int(np.count_nonzero(explored & ~true_explored)),
        unmapped=int(np.count_nonzero(true_free & ~explored)),
    )


def true_map(world: World) -> tuple[np.ndarray, np.ndarray]:
    """(explored, occupied), (H, W) bool each: the map a perfect mapper at the true poses would have made of
    ``world``'s episode so far (the world's own arrays: do not write to them)."""
    mapper = world.mapper
    if mapper is None or world.scene is None:
        raise RuntimeError("true_map needs a World that was reset")
    if world.noise is None:  # every imperfection off: the team map is made at the true poses
        return mapper.explored, mapper.occupied
    return world.noise.seen, world.noise.seen_occupied


def scene_truth(world: World) -> tuple[np.ndarray, np.ndarray]:
    """(explored, occupied): the truly seen cells, occupied where the scene has no free floor. The other
    truth one could take (``scene.free`` over what was seen); :func:`true_map` is the one scored."""
    explored, _ = true_map(world)
    assert world.scene is not None
    return explored, explored & ~world.scene.free


def map_quality(world: World, mapper: Mapper | None = None) -> MapQuality:
    """:func:`score` of ``mapper`` (default: the team map, :attr:`World.mapper
    <areasearch.sim.world.World.mapper>`; or one of :attr:`~areasearch.sim.world.World.robot_maps`) against
    :func:`true_map`. With every imperfection off the team map scores 0 by construction."""
    true_explored, true_occupied = true_map(world)
    chosen = mapper if mapper is not None else world.mapper
    assert chosen is not None
    return score(chosen.explored, chosen.occupied, true_explored, true_occupied)
