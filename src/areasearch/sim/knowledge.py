"""What each robot knows under limited communication (the world's ``comm`` group other than ``full``): its own
map, the targets it knows of, where it last heard its team-mates were; and the sharing within the groups of
robots that can talk (:mod:`areasearch.sim.comm`).

Why: with full communication the team has one map, fused from every frame, and every robot knows every
discovered target. With limited communication a robot knows only what it saw itself and what it heard, so
:class:`TeamKnowledge` keeps, per robot, a :class:`~areasearch.sim.mapper.Mapper` fused from that robot's own
frames at its believed pose, and which targets it knows are discovered (``found``) and covered (``cleared``).
After every step's sensing the world calls :meth:`TeamKnowledge.share`: links on the true positions over the
true map (the radio goes by where the robots are), the groups the links make (multi-hop), and within each
group the members' knowledge merged, so that every member of a group ends the step with the same map and the
same targets; :attr:`TeamKnowledge.heard` records where each robot last heard of each team-mate (their
believed positions: what the robots tell each other).

Each robot keeps a map of its own (rather than the members of a group sharing one object): a group that
splits needs no bookkeeping, each robot's frames go into its own arrays, and the cost is a few passes over
the grid per robot and step, on the noisy path only. Merging: explored and occupied are the members' OR;
a cell that becomes occupied in a robot's map through a merge carries that map's current integration count
in ``occupied_at`` (the robot learns of the obstacle now, so the action planner re-plans round it, as it does
for an obstacle it saw itself). With log-odds occupancy (``mapping.occupancy``) every member's log-odds become
the members' mean (:func:`~areasearch.sim.occupancy.merge_log_odds`) and occupied is that mean being positive,
so a phantom obstacle one member saw is cleared by the others' free evidence, and a cell can turn free in a
merge; a cell turning occupied in a merge is stamped as above. A target's mark stays where the robot that
last saw it placed it (:attr:`~areasearch.sim.noise.Imperfections.map_cells`).

The metrics do not read any of this: explored and covered count the truth (the noisy path's truly seen
floor and the true coverage), and the world's own :attr:`~areasearch.sim.world.World.mapper` stays the union
of every robot's frames.
"""

from __future__ import annotations

import numpy as np

from ..config import CameraConfig, WorldConfig
from .comm import NO_SHADOWING, CommState, draw_shadowing, links
from .mapper import Mapper
from .occupancy import merge_log_odds
from .scene import Scene


class TeamKnowledge:
    """Per-robot maps and target knowledge of one episode in ``scene`` under ``config``'s communication,
    for ``num_targets`` targets; ``rng`` draws the episode's shadowing (``signal`` only)."""

    def __init__(self, config: WorldConfig, scene: Scene, num_targets: int, rng: np.random.Generator) -> None:
        n = config.num_robots
        self.comm = config.comm
        top, mapping = config.robot.height_m, config.mapping
        shape = (n, *scene.shape)
        self.planes = (np.zeros(shape, bool), np.zeros(shape, bool), np.zeros(shape, np.int32))
        """(R, H, W) stacks of every robot's ``explored``, ``occupied`` and ``occupied_at``: the maps' arrays are
        views into them, so that the action planner's step kernel reads all the maps without a copy."""
        self.maps = [
            Mapper(
                scene.shape, scene.cell_m, scene.origin_xy, obstacle_top_m=top, occupancy=mapping,
                planes=(self.planes[0][r], self.planes[1][r], self.planes[2][r]),
            )
            for r in range(n)
        ]  # fmt: skip
        """Each robot's own map (:class:`~areasearch.sim.mapper.Mapper`), merged with its group's after each step."""
        self.found = np.zeros((n, num_targets), dtype=bool)
        """(R, K) robot ``r`` knows target ``k`` was discovered (it detected it or heard of it)."""
        self.cleared = np.zeros((n, num_targets), dtype=bool)
        """(R, K) robot ``r`` knows target ``k`` was covered (it covered it or heard of it)."""
        self.heard = CommState.new(n)
        """Where each robot last heard of each team-mate (believed positions, metres) and when."""
        self.groups: list[np.ndarray] = [np.arange(n, dtype=np.int64)]
        """The groups of robots linked at the last :meth:`share` (each a sorted array of robot indices)."""
        self.adjacency = np.ones((n, n), dtype=bool)
        """(R, R) the direct links of the last :meth:`share`."""
        self.shadowing = draw_shadowing(config.comm, rng) if config.comm.model == "signal" else NO_SHADOWING
        self._walls = ~scene.free
        self._cell_m, self._origin = scene.cell_m, scene.origin_xy

    def integrate(self, depth: np.ndarray, camera: CameraConfig, believed: np.ndarray) -> None:
        """Fuse each robot's depth image (``depth`` (R, H, W)) into its own map at its ``believed`` pose (R, 3)."""
        for r, mapper in enumerate(self.maps):
            mapper.integrate(depth[r : r + 1], camera, believed[r : r + 1])

    def cover(self, robots: np.ndarray, k: int) -> None:
        """The ``robots`` that covered target ``k`` (or came upon it) know it is discovered and covered."""
        self.found[robots, k] = True
        self.cleared[robots, k] = True

    def share(self, step: int, true_xy: np.ndarray, believed_xy: np.ndarray, map_cells: np.ndarray) -> None:
        """The step's communication: links at the robots' true positions ``true_xy`` (R, 2), the groups, each
        group's knowledge merged and the positions it tells (``believed_xy``) recorded; then each robot's
        target channel redrawn from what it knows, the marks at ``map_cells`` (K, 2)."""
        self.adjacency = links(self.comm, true_xy, self._walls, self._cell_m, self._origin, shadowing=self.shadowing)
        self.groups = self.heard.update(step, believed_xy, self.adjacency)
        for group in self.groups:
            if len(group) > 1:
                self._merge(group)
        for r, mapper in enumerate(self.maps):
            mapper.targets[:] = False
            pending = self.found[r] & ~self.cleared[r]
            mapper.targets[map_cells[pending, 0], map_cells[pending, 1]] = True

    def _merge(self, group: np.ndarray) -> None:
        """Every member of ``group`` ends with the members' merged map and target knowledge."""
        maps = [self.maps[r] for r in group]
        explored = np.logical_or.reduce([m.explored for m in maps])
        log_odds = [m.log_odds for m in maps if m.log_odds is not None]
        mean = merge_log_odds(log_odds) if log_odds else None
        occupied = np.logical_or.reduce([m.occupied for m in maps]) if mean is None else mean > 0
        for m in maps:
            heard_of = occupied & ~m.occupied
            m.occupied_at[heard_of] = m.integrations
            np.copyto(m.occupied, occupied)  # sticky: the OR, which holds the member's own
            if m.log_odds is not None and mean is not None:
                np.copyto(m.log_odds, mean)
            np.copyto(m.explored, explored)
        self.found[group] = self.found[group].any(axis=0)
        self.cleared[group] = self.cleared[group].any(axis=0)

    def group_of(self, robot: int) -> np.ndarray:
        """The group ``robot`` was in at the last :meth:`share`."""
        for group in self.groups:
            if robot in group:
                return group
        raise IndexError(f"no robot {robot}")


def coverers(
    target_xy: np.ndarray, poses: np.ndarray, previous_xy: np.ndarray, cover_r2: float, swept: bool
) -> np.ndarray:
    """The robots that came within ``sqrt(cover_r2)`` of the point ``target_xy`` in a step (the coverage rule of
    :func:`~areasearch.sim.sensing.targets_kernel`: along the segment swept from ``previous_xy`` to ``poses``
    with ``swept``, else at the end of the step), as an int64 array of robot indices."""
    end = poses[:, :2]
    if swept:
        seg = end - previous_xy
        length2 = (seg**2).sum(axis=1)
        rel = target_xy - previous_xy
        t = np.clip(np.divide((rel * seg).sum(axis=1), length2, out=np.zeros(len(seg)), where=length2 > 0), 0, 1)
        gap = rel - t[:, None] * seg
    else:
        gap = target_xy - end
    near = (gap**2).sum(axis=1) <= cover_r2 * (1 + 1e-9) + 1e-15
    if not near.any():  # rounding apart: the nearest robot covered it
        near[int(np.argmin((gap**2).sum(axis=1)))] = True
    return np.flatnonzero(near).astype(np.int64)
