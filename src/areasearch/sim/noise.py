"""The world's noisy path: noisy motion commands, odometry drift, depth noise and dropout, and target
detection with a probability per frame (the settings of :class:`~areasearch.config.NoiseConfig` and
:class:`~areasearch.config.DetectionConfig`).

Why a path of its own: with every imperfection off, :class:`~areasearch.sim.world.World` runs one fused
kernel (:mod:`areasearch.sim.sensing`) that renders, maps and discovers in one pass at the one pose
each robot has. With noise, the robot's *believed* pose (its odometry) differs from its *true* pose, and
the pieces see different ones: the depth image is rendered at the true pose, the mapper fuses it at the
believed pose (so the map blurs and misaligns as a real robot's does), the planners read the believed
pose, while collisions, coverage and the metrics go by the truth. :class:`Imperfections` holds what this
path needs (its own random generator, the believed poses' drift, a scratch map for one frame's view) and
does its steps; the world calls them in order (:meth:`World.step
<areasearch.sim.world.World.step>`).

Units: metres and radians, map frame; cells (iy, ix), flat indices ``iy * W + ix``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..config import WorldConfig
from .knowledge import TeamKnowledge, coverers
from .mapper import Mapper
from .scene import Scene
from .sensing import targets_kernel

_NO_CELLS = np.zeros(0, dtype=np.int64)


class Imperfections:
    """The noisy path's state for one episode of a world configured by ``config`` in ``scene``, drawing
    from ``rng`` (the world seeds it from the episode's generator, after the targets)."""

    def __init__(self, config: WorldConfig, scene: Scene, rng: np.random.Generator) -> None:
        self.noise, self.detection, self.camera = config.noise, config.detection, config.camera
        self.rng = rng
        n = config.num_robots
        self.clean = np.zeros((n, config.camera.height_px, config.camera.width_px), dtype=np.float32)
        """(R, H, W) the depth images as rendered at the true poses, before noise."""
        self.view = Mapper(scene.shape, scene.cell_m, scene.origin_xy, obstacle_top_m=config.robot.height_m)
        """Scratch map of one frame: the cells a frame shows by the true geometry (kept empty between frames)."""
        self.seen = np.zeros(scene.shape, dtype=bool)
        """(H, W) cells some frame showed by the true geometry: the explored area the metrics count."""
        self.seen_occupied = np.zeros(scene.shape, dtype=bool)
        """(H, W) cells some frame showed as obstacles by the true geometry: with :attr:`seen`, the map a
        perfect mapper at the true poses makes (:mod:`areasearch.sim.mapquality` scores maps against it)."""
        self.cell_m, self.origin = scene.cell_m, np.array(scene.origin_xy, dtype=np.float64)
        self.extent = self.origin + np.array([scene.shape[1], scene.shape[0]]) * scene.cell_m
        self.map_cells = np.zeros((0, 2), dtype=np.int64)
        """(K, 2) where each target is marked on the map: the cell a robot believed it saw it in (its true
        cell until detected)."""
        self.map_xy = np.zeros((0, 2))
        """(K, 2) the point a robot believed it saw each target at, metres (its true one until detected)."""

    # ------------------------------------------------------------------ motion
    def commands(self, count: int, forward_m: float, turn_rad: float) -> tuple[np.ndarray, np.ndarray]:
        """(R,) distances of a FORWARD and (R,) angles of a turn for this step, action noise applied."""
        forward = np.full(count, forward_m)
        turn = np.full(count, turn_rad)
        if self.noise.forward:
            forward *= 1.0 + self.rng.uniform(-self.noise.forward, self.noise.forward, count)
        if self.noise.turn:
            turn *= 1.0 + self.rng.uniform(-self.noise.turn, self.noise.turn, count)
        return forward, turn

    def odometry(self, before: np.ndarray, after: np.ndarray, believed: np.ndarray) -> None:
        """Move the ``believed`` poses (R, 3), in place, by what odometry measures of each robot's true
        move from ``before`` to ``after``: the distance and the angle turned, each times ``1 + e`` (normal
        errors of the configured deviations); the believed pose drives along its believed heading. It
        stays on the map's grid (the frame's extent is known)."""
        sigma_f, sigma_t = self.noise.odometry_forward, self.noise.odometry_turn
        if not (sigma_f or sigma_t):
            believed[:] = after
            return
        n = len(after)
        distance = np.hypot(after[:, 0] - before[:, 0], after[:, 1] - before[:, 1])
        turned = (after[:, 2] - before[:, 2] + math.pi) % (2 * math.pi) - math.pi
        if sigma_f:
            distance *= 1.0 + sigma_f * self.rng.standard_normal(n)
        if sigma_t:
            turned *= 1.0 + sigma_t * self.rng.standard_normal(n)
        believed[:, 2] = (believed[:, 2] + turned + math.pi) % (2 * math.pi) - math.pi
        believed[:, 0] += distance * np.cos(believed[:, 2])
        believed[:, 1] += distance * np.sin(believed[:, 2])
        margin = 0.5 * self.cell_m
        np.clip(believed[:, :2], self.origin + margin, self.extent - margin, out=believed[:, :2])

    # ------------------------------------------------------------------ sensing
    def perturb(self, out: np.ndarray) -> None:
        """Write the images of :attr:`clean` into ``out`` with range noise and pixel dropout."""
        out[:] = self.clean
        if self.noise.depth:
            out *= 1.0 + self.noise.depth * self.rng.standard_normal(out.shape, dtype=np.float32)
            np.maximum(out, 0.0, out=out)
        if self.noise.dropout:
            out[self.rng.random(out.shape) < self.noise.dropout] = 0.0

    def frame_cells(self, poses: np.ndarray, r: int) -> np.ndarray:
        """Flat indices of the cells robot ``r``'s clean frame shows from its true pose (``poses`` (R, 3)),
        by the mapper's rule: seen on the floor, seen through, or an obstacle face."""
        cells = self.view.integrate(self.clean[r : r + 1], self.camera, poses[r : r + 1])
        occupied = self.view.occupied.reshape(-1)  # flat views (the arrays are C-contiguous): faster than .flat
        seen_occupied = self.seen_occupied.reshape(-1)
        seen_occupied[cells] |= occupied[cells]
        self.view.explored.reshape(-1)[cells] = False
        occupied[cells] = False
        return cells

    def place(self, ks: np.ndarray, xy: np.ndarray, pose: np.ndarray, believed: np.ndarray) -> None:
        """Set the :attr:`map_xy` and :attr:`map_cells` of targets ``ks`` (int64 indices) to where a robot at
        true ``pose`` that believes it is at ``believed`` places the points it sees at their true positions
        ``xy[ks]``: the same offsets from the camera, in the believed frame (kept on the grid). One target's
        arithmetic is the same whether it is placed alone or with others (element by element, in order)."""
        turn = believed[2] - pose[2]
        cos, sin = math.cos(turn), math.sin(turn)
        dx, dy = xy[ks, 0] - pose[0], xy[ks, 1] - pose[1]
        points = np.empty((len(ks), 2))
        points[:, 0] = believed[0] + dx * cos - dy * sin
        points[:, 1] = believed[1] + dx * sin + dy * cos
        margin = 0.5 * self.cell_m
        self.map_xy[ks] = np.clip(points, self.origin + margin, self.extent - margin)
        self.map_cells[ks] = np.floor((self.map_xy[ks][:, ::-1] - self.origin[::-1]) / self.cell_m).astype(np.int64)

    def detect(self, ks: np.ndarray, pose: np.ndarray, targets_xy: np.ndarray) -> np.ndarray:
        """Which of the targets ``ks`` in view of a frame taken from ``pose`` it detects: all when
        detection is certain, else each with the configured probability at its distance."""
        if not self.detection.active or len(ks) == 0:
            return ks
        distance = np.hypot(targets_xy[ks, 0] - pose[0], targets_xy[ks, 1] - pose[1])
        p = np.array([self.detection.probability(float(d), self.camera.max_range_m) for d in distance])
        return ks[self.rng.random(len(ks)) < p]


def sense(
    nz: Imperfections,
    poses: np.ndarray,
    believed: np.ndarray,
    mapper: Mapper,
    targets: TargetState,
    step: int,
    known: TeamKnowledge | None = None,
) -> None:
    """One sensing step of the noisy path, after :attr:`Imperfections.clean` was rendered at the true
    ``poses``: every robot's frame counts the truly seen cells and detects the targets in view (each
    marked on ``mapper`` where its robot believed it was); a frame that shows a target its robot knows of
    and that is not covered yet moves the target's mark to where that robot places it now (a robot tracks
    what it sees: near a target, its mark is off by the little drift since the robot last saw it, not by the
    drift of the whole way since it was found); then robots cover targets by their true
    positions (:func:`~areasearch.sim.sensing.targets_kernel`); covering an undetected target detects it.

    With ``known`` (limited communication), a robot detects the targets in view that it does not know of
    yet (a target discovered by a team-mate out of touch is news to it) and learns of the targets it
    covers; a target's mark goes where the last robot that saw it placed it."""
    t = targets
    moved: list[np.ndarray] = []  # (n, 2) arrays of the cells marks were moved off
    for r in range(len(poses)):
        cells = nz.frame_cells(poses, r)
        seen = nz.seen.reshape(-1)
        new = cells[~seen[cells]]
        seen[new] = True
        t.counts[0] += int(np.count_nonzero(t.free_flat[new]))
        ks = t.target_id_flat[cells]
        ks = ks[ks >= 0]
        known_r = t.discovered if known is None else known.found[r]
        tracked = ks[known_r[ks] & ~t.covered[ks]]  # tracked while in view: the mark follows the robot's frame
        if len(tracked):
            moved.append(nz.map_cells[tracked])  # (n, 2): a copy (fancy indexing)
            nz.place(tracked, t.xy, poses[r], believed[r])
        for k in nz.detect(ks[~(t.discovered if known is None else known.found[r])[ks]], poses[r], t.xy):
            if known is not None:
                known.found[r, k] = True
                if t.discovered[k]:
                    continue
            t.discovered[k], t.discovered_at[k] = True, step
            t.counts[1] += 1
            nz.place(np.array([k], dtype=np.int64), t.xy, poses[r], believed[r])
            mapper.targets[nz.map_cells[k, 0], nz.map_cells[k, 1]] = True
    k_all = len(t.covered)
    was_covered = t.covered.copy() if known is not None else t.covered
    counts = np.array([0, k_all, t.counts[2]], dtype=np.int64)  # every target may be covered
    targets_kernel(
        _NO_CELLS, t.free_flat, t.target_id_flat, nz.map_cells, t.xy, poses, t.previous_xy, t.cover_r2, t.swept,
        step, np.ones(k_all, dtype=bool), np.zeros(k_all, dtype=np.int64), t.covered, t.covered_at,
        mapper.targets, counts,
    )  # fmt: skip
    t.counts[2] = counts[2]
    late = t.covered & ~t.discovered
    t.discovered[late], t.discovered_at[late] = True, step
    t.counts[1] += int(np.count_nonzero(late))
    if known is not None:
        for k in np.flatnonzero(t.covered & ~was_covered):
            known.cover(coverers(t.xy[k], poses, t.previous_xy, t.cover_r2, t.swept), int(k))
    for cells in moved:
        mapper.targets[cells[:, 0], cells[:, 1]] = False
    pending = t.discovered & ~t.covered  # a cleared cell may also hold another target's mark
    mapper.targets[nz.map_cells[pending, 0], nz.map_cells[pending, 1]] = True


@dataclass
class TargetState:
    """The world's target arrays the noisy path reads and updates (the world's own arrays, not copies)."""

    xy: np.ndarray
    """(K, 2) true target positions, metres."""
    target_id_flat: np.ndarray
    """(H * W,) the target on each cell, -1 for none."""
    free_flat: np.ndarray
    """(H * W,) bool: the reachable floor the explored metric counts."""
    discovered: np.ndarray
    discovered_at: np.ndarray
    covered: np.ndarray
    covered_at: np.ndarray
    counts: np.ndarray
    """(3,) [truly explored reachable floor cells, discovered, covered]."""
    previous_xy: np.ndarray
    """(R, 2) true robot centres before the step."""
    cover_r2: float
    swept: bool
