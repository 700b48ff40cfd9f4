"""Pipeline stage "mapper": the reconstruction mapper of DA-HGNN ("Reconstruction mapper" section).

Given depth images, camera intrinsics and global poses, it back-projects every pixel to a 3D point,
flattens the points onto the global grid and keeps the merged map M_t of all robots
(communication is assumed reliable, as in the paper):

* a point higher than ``floor_tolerance_m`` and not higher than the robot (``obstacle_top_m``)
  marks its cell **occupied**;
* a point on the floor marks its cell **explored**;
* the cells along each column's ray, from the camera up to the first obstacle point (or to the
  farthest floor point when the column sees no obstacle), are **explored** — they were seen through.

Explored includes occupied cells; "known free" is ``explored & ~occupied``. Occupancy is sticky
(the scene is static); :attr:`Mapper.occupied_at` tells when each obstacle cell was first marked
(the action planner re-plans for obstacles newer than its path). With ``occupancy`` (a
:class:`~areasearch.config.MappingConfig` of ``log_odds``) the mapper keeps log-odds occupancy
instead, which clears outliers of a noisy depth camera when a cell is seen free again
(:mod:`areasearch.sim.occupancy`). :class:`areasearch.sim.world.World`
runs the renderer and this mapper's work in one kernel pass (same result, tested). The third
channel, uncovered targets, is set by whoever knows the targets (:class:`areasearch.sim.world.World`)
through :meth:`Mapper.set_targets`.

The camera is assumed level (no roll or pitch), as on a ground robot: all pixels of one image
column then share one horizontal ray, which the mapper traverses once per column. The depth may
come from any source (our renderer, a real sensor): z-depth in metres, 0 or non-finite = no return.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ..config import CameraConfig, MappingConfig
from .depth import camera_in_grid, camera_tables, column_ray
from .occupancy import integrate_log_odds
from .raycast import ray_in_grid, ray_next, ray_start


@numba.njit(cache=True, nogil=True, error_model="numpy")
def mark_explored(iy: int, ix: int, explored: np.ndarray, new_cells: np.ndarray, n_new: int) -> int:
    """Mark cell (iy, ix) explored (a cell outside the grid is ignored); a cell not explored before
    is appended to ``new_cells`` (flat indices ``iy * W + ix``, as many as it holds) at ``n_new``.
    Returns the new count of newly explored cells (it may exceed ``len(new_cells)``)."""
    if iy < 0 or ix < 0 or iy >= explored.shape[0] or ix >= explored.shape[1]:
        return n_new
    if not explored[iy, ix]:
        explored[iy, ix] = True
        if n_new < new_cells.shape[0]:
            new_cells[n_new] = iy * explored.shape[1] + ix
        n_new += 1
    return n_new


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def fuse_column(
    depth: np.ndarray,
    r: int,
    u: int,
    slope: np.ndarray,
    cam_h: float,
    floor_tol: float,
    obstacle_top: float,
    px: float,
    py: float,
    dx: float,
    dy: float,
    scale: float,
    explored: np.ndarray,
    occupied: np.ndarray,
    occupied_at: np.ndarray,
    stamp: int,
    new_cells: np.ndarray,
    n_new: int,
    floor_s: np.ndarray,
) -> tuple[int, float]:
    """Mark the points of column ``u`` of depth image ``r`` (R, H, W; 0 or non-finite: no return)
    seen from grid point (px, py) along the column's unit ray (dx, dy), ``scale`` cells of it per metre
    of z: obstacle points occupied and explored, floor points beyond the first obstacle explored
    (``floor_s``: scratch of H). Returns the new count of newly explored cells and the distance
    (cells) the caller carves the ray up to (:func:`carve_ray`), from the camera to the first
    obstacle point or else the farthest floor point."""
    gh = explored.shape[0]
    gw = explored.shape[1]
    # cells: an obstacle point is binned this far behind its face along the ray (half the smallest
    # segment a depth renderer should report, far above the float32 depth error of ~4e-6 cells)
    eps = 5e-5
    s_obstacle = np.inf  # horizontal distance (cells) to the nearest obstacle point
    s_floor = 0.0  # farthest floor point (cells)
    n_floor = 0
    last_z = -1.0
    for v in range(depth.shape[1]):
        z = depth[r, v, u]
        if not (z > 0.0) or not math.isfinite(z):
            continue
        height = cam_h + slope[v] * z
        if height <= floor_tol:
            s = z * scale
            floor_s[n_floor] = s
            n_floor += 1
            if s > s_floor:
                s_floor = s
        elif height <= obstacle_top and z != last_z:
            last_z = z  # rows on one face share z and hence the cell
            s = z * scale
            iy = int(math.floor(py + dy * (s + eps)))
            ix = int(math.floor(px + dx * (s + eps)))
            if 0 <= iy < gh and 0 <= ix < gw:
                if not occupied[iy, ix]:
                    occupied[iy, ix] = True
                    occupied_at[iy, ix] = stamp
                n_new = mark_explored(iy, ix, explored, new_cells, n_new)
            if s < s_obstacle:
                s_obstacle = s
    s_carve = s_obstacle + eps if s_obstacle < np.inf else s_floor
    # floor seen beyond the first obstacle (over a low obstacle): mark those cells alone
    for k in range(n_floor):
        s = floor_s[k]
        if s > s_carve:
            n_new = mark_explored(
                int(math.floor(py + dy * s)), int(math.floor(px + dx * s)), explored, new_cells, n_new
            )
    return n_new, s_carve


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def carve_ray(
    px: float, py: float, dx: float, dy: float, s_carve: float, explored: np.ndarray, new_cells: np.ndarray, n_new: int
) -> int:
    """Mark explored every cell the ray from grid point (px, py) along (dx, dy) crosses up to
    ``s_carve`` cells (:mod:`areasearch.sim.raycast`); returns the new count of newly explored cells."""
    gh = explored.shape[0]
    gw = explored.shape[1]
    ray = ray_start(px, py, dx, dy)
    while ray.t_enter <= s_carve and ray_in_grid(ray, gh, gw):
        if not explored[ray.iy, ray.ix]:
            explored[ray.iy, ray.ix] = True
            new_cells[n_new] = ray.iy * gw + ray.ix
            n_new += 1
        ray = ray_next(ray)
    return n_new


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _integrate_kernel(
    depth: np.ndarray,
    poses: np.ndarray,
    xu_cols: np.ndarray,
    slope: np.ndarray,
    cam_h: float,
    floor_tol: float,
    obstacle_top: float,
    cell_m: float,
    origin_x: float,
    origin_y: float,
    explored: np.ndarray,
    occupied: np.ndarray,
    occupied_at: np.ndarray,
    stamp: int,
    new_cells: np.ndarray,
) -> int:
    n_new = 0
    floor_s = np.empty(depth.shape[1])
    for r in range(depth.shape[0]):
        px, py, cos_y, sin_y = camera_in_grid(poses, r, origin_x, origin_y, cell_m)
        for u in range(depth.shape[2]):
            dx, dy, norm = column_ray(cos_y, sin_y, xu_cols[u])
            n_new, s_carve = fuse_column(
                depth, r, u, slope, cam_h, floor_tol, obstacle_top, px, py, dx, dy, norm / cell_m,
                explored, occupied, occupied_at, stamp, new_cells, n_new, floor_s,
            )  # fmt: skip
            if s_carve > 0.0:
                n_new = carve_ray(px, py, dx, dy, s_carve, explored, new_cells, n_new)
    return n_new


class Mapper:
    """The merged global map M_t: explored / occupied / uncovered-target channels.

    Args:
        shape: (H, W) cells, indexed [iy, ix] with y northwards.
        cell_m: cell size in metres.
        origin_xy: map-frame coordinates of the south-west corner of cell [0, 0], metres.
        obstacle_top_m: points up to this height mark obstacles (the robot height).
        floor_tolerance_m: points up to this height are floor.
        occupancy: the occupancy model (None or ``sticky``: sticky; ``log_odds``: :mod:`areasearch.sim.occupancy`).
        planes: the (H, W) arrays to hold ``explored`` (bool), ``occupied`` (bool) and ``occupied_at``
            (int32) in, zeroed here: views into a caller's (R, H, W) stacks, so that several robots' maps
            are one array each for a kernel that reads them all (:class:`~areasearch.sim.knowledge.TeamKnowledge`).
    """

    EXPLORED, OCCUPIED, TARGETS = 0, 1, 2
    """Channel order of :meth:`channels`."""

    def __init__(
        self,
        shape: tuple[int, int],
        cell_m: float,
        origin_xy: tuple[float, float] = (0.0, 0.0),
        *,
        obstacle_top_m: float = 0.6,
        floor_tolerance_m: float = 0.05,
        occupancy: MappingConfig | None = None,
        planes: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    ) -> None:
        self.shape = (int(shape[0]), int(shape[1]))
        self.cell_m = float(cell_m)
        self.origin_xy = (float(origin_xy[0]), float(origin_xy[1]))
        self.obstacle_top_m = float(obstacle_top_m)
        self.floor_tolerance_m = float(floor_tolerance_m)
        if planes is None:
            planes = (np.zeros(self.shape, bool), np.zeros(self.shape, bool), np.zeros(self.shape, np.int32))
        for plane, dtype in zip(planes, (bool, bool, np.int32), strict=True):
            if plane.shape != self.shape or plane.dtype != dtype:
                raise ValueError(f"a map plane must be {self.shape} {np.dtype(dtype)}, got {plane.shape} {plane.dtype}")
            plane[...] = 0
        self.explored, self.occupied, self.occupied_at = planes
        """(H, W) each: explored and occupied cells; ``occupied_at`` the :attr:`integrations` count of the call
        that marked each occupied cell (0 for cells never marked by :meth:`integrate`), so users can tell which
        obstacles are new."""
        self.targets = np.zeros(self.shape, dtype=bool)
        self.integrations = 0
        """Calls of :meth:`integrate` since the last reset."""
        self.new_cells = np.empty(self.shape[0] * self.shape[1], dtype=np.int64)
        """Scratch: the flat indices of the cells an integration newly explored, written by
        :meth:`integrate` and by the world's fused sensing kernel."""
        self.log_odds: np.ndarray | None = None
        """(H, W) float32: each cell's log-odds of occupancy (``log_odds`` occupancy only, else None)."""
        if occupancy is not None and occupancy.occupancy == "log_odds":
            self._params = np.array(occupancy.log_odds())
            self.log_odds = np.zeros(self.shape, dtype=np.float32)
            self._hits = np.zeros(self.shape, dtype=np.int32)
            self._misses = np.zeros(self.shape, dtype=np.int32)
            self._touched = np.empty(self.shape[0] * self.shape[1], dtype=np.int64)

    def reset(self) -> None:
        self.explored[:] = False
        self.occupied[:] = False
        self.targets[:] = False
        self.occupied_at[:] = 0
        self.integrations = 0
        if self.log_odds is not None:
            self.log_odds[:] = 0.0

    def integrate(self, depth: np.ndarray, camera: CameraConfig, poses: np.ndarray) -> np.ndarray:
        """Fuse depth images (R, H, W) taken at ``poses`` (R, 3) into the map.

        Returns the flat indices (``iy * W + ix``) of the cells that became explored.
        """
        if depth.dtype != np.float32 or depth.ndim != 3:
            depth = np.asarray(depth, dtype=np.float32).reshape((-1, camera.height_px, camera.width_px))
        if poses.dtype != np.float64 or poses.ndim != 2 or not poses.flags.c_contiguous:
            poses = np.ascontiguousarray(np.asarray(poses, dtype=np.float64).reshape(-1, 3))
        if depth.shape[1:] != (camera.height_px, camera.width_px) or depth.shape[0] != poses.shape[0]:
            raise ValueError(
                f"depth shape {depth.shape} does not match {poses.shape[0]} poses and a "
                f"{camera.height_px}x{camera.width_px} camera"
            )
        tables = camera_tables(camera)
        self.integrations += 1
        if self.log_odds is not None:
            n_new = integrate_log_odds(
                depth, poses, tables.xu, tables.slope, camera.mount_height_m, self.floor_tolerance_m,
                self.obstacle_top_m, self.cell_m, self.origin_xy[0], self.origin_xy[1], self._params, self.log_odds,
                self.explored, self.occupied, self.occupied_at, self.integrations, self.new_cells, self._hits,
                self._misses, self._touched,
            )  # fmt: skip
            return self.new_cells[:n_new].copy()
        n_new = _integrate_kernel(
            depth,
            poses,
            tables.xu,
            tables.slope,
            camera.mount_height_m,
            self.floor_tolerance_m,
            self.obstacle_top_m,
            self.cell_m,
            self.origin_xy[0],
            self.origin_xy[1],
            self.explored,
            self.occupied,
            self.occupied_at,
            self.integrations,
            self.new_cells,
        )
        return self.new_cells[:n_new].copy()

    def set_targets(self, cells: np.ndarray, value: bool) -> None:
        """Mark (or clear) uncovered-target cells; ``cells`` is (N, 2) of (iy, ix)."""
        cells = np.asarray(cells, dtype=np.int64).reshape(-1, 2)
        self.targets[cells[:, 0], cells[:, 1]] = value

    @property
    def known_free(self) -> np.ndarray:
        """(H, W) bool: explored and not occupied."""
        return self.explored & ~self.occupied

    def channels(self) -> np.ndarray:
        """M_t as (3, H, W) uint8 in {0, 1}: explored, occupied, uncovered targets."""
        return np.stack([self.explored, self.occupied, self.targets]).astype(np.uint8)
