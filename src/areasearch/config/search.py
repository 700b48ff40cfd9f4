"""The high-level environment's configuration: candidate goals, the action planner, the decision
process, and :class:`SearchConfig`, their root with the world's (:class:`~areasearch.config.world.WorldConfig`)."""

from __future__ import annotations

from dataclasses import dataclass, field

from .checks import integer, positive, within
from .world import MAX_STEPS, WorldConfig


@dataclass(frozen=True)
class CandidateConfig:
    """Candidate goals: frontier nodes and target nodes (DA-HGNN "Topological Planner")."""

    min_frontier_cells: int = 3
    """Frontier fragments smaller than this are dropped, unless they are all that is left."""
    cluster_m: float = 1.0
    """A connected frontier longer than this is split into several nodes, metres."""
    exhausted_m: float = 0.5
    """Frontier nodes this close to an exhausted one (reached and looked at, still there) are dropped."""
    max_candidates: int = 256
    """Candidates offered to the planner per decision; beyond it, targets first, then the frontier
    nodes nearest to the team are kept (observation arrays are padded to this size)."""
    distance_cell_m: float = 0.0
    """The robot-candidate distances (and the fields the robots' first paths are read off) are
    marched on cells of about this size, metres: blocks of the map's cells, the whole number nearest
    it (a block passable where any of its cells is; the paths are then refined on the map's cells);
    0: on the map's own cells. 0.1 on the bundled maps' 5 cm cells is NCM's 10 cm planning cell and
    marches a quarter of the cells."""

    def validate(self) -> None:
        integer("candidates.min_frontier_cells", self.min_frontier_cells, 1, 1_000_000)
        positive("candidates.cluster_m", self.cluster_m, 100.0)
        positive("candidates.exhausted_m", self.exhausted_m, 100.0)
        integer("candidates.max_candidates", self.max_candidates, 1, 4096)
        within("candidates.distance_cell_m", self.distance_cell_m, 0.0, 1.0)


@dataclass(frozen=True)
class PathConfig:
    """The FMM action planner (DA-HGNN "Action Planner and Execution")."""

    goal_tolerance_m: float = 0.25
    """A robot this close to its long-term goal has arrived and stays, metres."""
    lookahead_m: float = 0.5
    """The short-term goal is this far ahead along the path, metres."""
    min_aim_m: float = 0.05
    """A short-term goal nearer than this to the robot's centre is replaced by the first path cell
    beyond it: the heading to a point a few centimetres away is set by where in its cell the robot
    stands, not by the path (a robot backing off in a narrow doorway aimed 3.5 cm west, at a
    team-mate, for ever), metres; the default is one cell of the bundled maps; 0: never. Half a
    FORWARD (0.125 m) was tried and cut corners in the tightest doorways (0.40 m, slanted 60°): the
    bump marks it left closed the doorway to a team of five."""
    check_ahead_m: float = 0.5
    """Each step, this much of the path ahead is checked for newly mapped obstacles, metres."""
    unknown_margin_m: float = 0.5
    """Unknown cells are traversable up to this far beyond a frontier, metres (as for candidates)."""
    local_margin_m: float = 1.0
    """Paths are first sought in the box around the robot and its goal grown by this much, metres
    (then, if none is found there, over the whole map)."""
    bump_memory_steps: int = 200
    """Steps a bumped cell stays impassable for planning."""
    robot_wait_steps: int = 2
    """Steps a robot blocked by a team-mate waits before it re-plans around the other robots."""
    robot_wait_limit: int = 20
    """Blocked tries behind team-mates, without moving, after which a goal counts as unreachable."""
    detour_every_steps: int = 5
    """A robot blocked by a team-mate, once it has waited ``robot_wait_steps``, seeks a detour round the
    team-mates at its next blocked try and then at every this-many-th one (it waits in between); when
    it is still blocked this many steps after its first detour, one of the two robots gives way, steps."""
    give_way_steps: int = 40
    """A robot giving way (driving to a spot off a team-mate's way and waiting there) re-plans to its own
    goal this many steps after it began, steps (the default is twice ``robot_wait_limit``)."""
    look_radius_m: float = 1.0
    """On arrival a robot turns towards the unknown cells within this distance of its goal, metres."""
    max_bumps: int = 8
    """Bumps into obstacles, without moving in between, after which a goal counts as unreachable."""
    primitive_search_m: float = 1.0
    """A robot about to drive into a mapped obstacle (by the world's collision rule) plans its next
    moves with the motion primitives instead (A* over the poses FORWARD and the turns reach), to its
    goal if the goal is this close, else to the point of its path this far ahead, metres; 0: never."""
    primitive_search_expansions: int = 20000
    """Most poses one primitive search expands before it gives up (the heading heuristic then acts)."""
    primitive_search_narrow_expansions: int = 200000
    """In a narrow passage (few cells round the robot where a centre may stand, e.g. a doorway barely
    wider than the robot) a search that found no plan within ``primitive_search_expansions`` is tried
    again with this many: a way through such a passage can take dozens of turns and short moves."""
    primitive_search_pause_steps: int = 40
    """Steps after a primitive search of a robot found no plan, or an obstacle the map did not show
    blocked its plan, before that robot searches again, steps (the default is twice ``robot_wait_limit``)."""
    progress_window_cells: int = 40
    """Each step the path cell nearest the robot (its progress along the path) is sought among this many
    cells of the path from the last one, path cells: progress never goes back, and a path that passes
    near itself further on is not cut short."""
    deadlock_steps: int = 10
    """A robot with a goal that has not moved for this many steps while team-mates block it is in a jam:
    the other robots near it back off the way of the one closest to its goal
    (:mod:`areasearch.planning.paths.jams`), steps."""
    path_buffer_cells: int = 256
    """First length of each robot's path buffer, path cells; a longer path doubles it (memory only: no
    effect on what the robots do)."""
    bump_log_per_robot: int = 64
    """First size of the log of bump marks, bumps per robot (a bump logs up to 6 cells); a fuller log
    doubles (memory only: no effect on what the robots do)."""

    def validate(self) -> None:
        positive("paths.goal_tolerance_m", self.goal_tolerance_m, 100.0)
        positive("paths.lookahead_m", self.lookahead_m, 100.0)
        positive("paths.check_ahead_m", self.check_ahead_m, 100.0)
        positive("paths.look_radius_m", self.look_radius_m, 100.0)
        positive("paths.local_margin_m", self.local_margin_m, 100.0)
        # counts of steps and tries are compared with counters (bounded by the horizon); the expansions of a
        # search, the path buffer and the bump log are loop counts and array sizes
        for name, minimum, maximum in (
            ("max_bumps", 1, 1_000_000),
            ("robot_wait_steps", 0, MAX_STEPS),
            ("robot_wait_limit", 1, 1_000_000),
            ("bump_memory_steps", 1, MAX_STEPS),
            ("primitive_search_expansions", 1, 10_000_000),
            ("primitive_search_narrow_expansions", 1, 10_000_000),
            ("detour_every_steps", 1, MAX_STEPS),
            ("give_way_steps", 1, MAX_STEPS),
            ("primitive_search_pause_steps", 0, MAX_STEPS),
            ("progress_window_cells", 1, 1_000_000),
            ("path_buffer_cells", 1, 1_000_000),
            ("deadlock_steps", 1, MAX_STEPS),
            ("bump_log_per_robot", 1, 100_000),
        ):
            integer(f"paths.{name}", getattr(self, name), minimum, maximum)
        for name in ("primitive_search_m", "min_aim_m", "unknown_margin_m"):
            within(f"paths.{name}", getattr(self, name), 0.0, 100.0)


@dataclass(frozen=True)
class DecisionConfig:
    """The high-level decision process: one long-term goal per robot every ``period_steps``."""

    period_steps: int = 40
    """Primitive steps between two decisions (paper: 40)."""
    history: int = 8
    """Past decisions kept in the observation (historical robot positions and goals)."""
    failed_memory: int = 5
    """Decisions during which a goal that proved unreachable for a robot is not offered to it again."""
    map_cells: int = 128
    """Side of the square observation map, cells after downsampling."""
    map_downsample: int = 4
    """Smallest downsampling factor of the observation map (paper: 4); larger maps use the factor
    that makes them fit ``map_cells``."""

    def validate(self) -> None:
        # map_cells is the side of the (7, S, S) observation map, history a dimension of its arrays
        for name, maximum in (
            ("period_steps", MAX_STEPS),
            ("history", 1_000),
            ("failed_memory", 1_000_000),
            ("map_cells", 2_048),
            ("map_downsample", 1_024),
        ):
            integer(f"decisions.{name}", getattr(self, name), 1, maximum)


@dataclass(frozen=True)
class SearchConfig:
    """Root configuration of the high-level (goal-assignment) environment."""

    world: WorldConfig = field(default_factory=WorldConfig)
    candidates: CandidateConfig = field(default_factory=CandidateConfig)
    paths: PathConfig = field(default_factory=PathConfig)
    decisions: DecisionConfig = field(default_factory=DecisionConfig)

    def validate(self) -> SearchConfig:
        self.world.validate()
        self.candidates.validate()
        self.paths.validate()
        self.decisions.validate()
        return self
