"""Decision latency of the ROS 2 node (``areasearch ros2``), from the pose message to the goal messages,
beside the in-process ``assign_goals`` call on the same input, one run.

The inputs are :mod:`bench_assign`'s: what a Greedy team of ``--robots`` has mapped of the largest
bundled map (``bormann_office_g_rooms3``, 1821 x 1826 cells of 5 cm) after ``--decisions``
decisions, with the robots' poses and the targets seen so far. For each team size and method, the
node runs as users run it, ``areasearch ros2 --robots r0 ... --method M --period-s 3600`` in a
subprocess (one thread: ``NUMBA_NUM_THREADS=1``, ``OMP_NUM_THREADS=1``); this process plays the
robot stack on loopback (rclpy, its own ROS domain): it publishes the map once as map_server does,
the poses as AMCL does and the targets, and takes the first decision (not timed). Then, ``--repeats``
times, one robot (in turn) arrives at its goal: its pose is published there, which makes the node
decide at once, and the time from publishing that pose to receiving the last robot's new goal is
one sample of the node's latency (beside it, the node's own ``assign_goals`` time within that decision,
read from its debug log: the rest is ROS, message in, markers and status out, DDS). The robot then
goes back to its start pose for the next sample. After each sample, the same input (map, poses, targets, each
robot's past positions and goals, as the node holds them) goes to ``assign_goals`` in this process
(the planner built once, one thread), so that both see the same load of a shared machine; its
goals must be the node's. p50 and p95 of each.

    python benchmarks/bench_ros2.py [--robots 3 5] [--methods greedy dahgnn] [--decisions 25] [--repeats 20]
"""

from __future__ import annotations

import argparse
import math
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from collections import deque
from pathlib import Path
from typing import Any

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from areasearch.config import SearchConfig
from areasearch.planners import make_planner
from areasearch.service.assign import OccupancyMap, assign_goals
from areasearch.sim.scene import bundled_index
from bench_assign import snapshots

ONE_THREAD = {"NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
TOLERANCE_M = 0.25
"""The node's default goal tolerance, metres."""
UNBUFFERED_LOG = {"RCUTILS_LOGGING_BUFFERED_STREAM": "0"}
WAIT_S = 300.0
"""Longest wait for a decision (the first one converts the map and may compile numba's kernels)."""


def largest_map() -> str:
    """The bundled map with the most cells."""
    return max(bundled_index(), key=lambda e: e["width"] * e["height"])["id"]


def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(values), q))


class Stack:
    """This process as the robot stack: the map, poses and targets out; the node's goals in."""

    def __init__(self, names: list[str]) -> None:
        import array

        from geometry_msgs.msg import PoseArray, PoseStamped, PoseWithCovarianceStamped
        from nav_msgs.msg import OccupancyGrid
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node

        from areasearch.ros2.convert import quaternion_xyzw
        from areasearch.ros2.node import LATCHED, RELIABLE

        self.array, self.quaternion_xyzw = array, quaternion_xyzw
        self.types = (OccupancyGrid, PoseWithCovarianceStamped, PoseArray)
        self.names = names
        self.node = Node("bench_ros2_stack")
        self.map_publisher = self.node.create_publisher(OccupancyGrid, "/map", LATCHED)
        self.pose_publishers = [
            self.node.create_publisher(PoseWithCovarianceStamped, f"/{n}/amcl_pose", LATCHED) for n in names
        ]
        self.targets_publisher = self.node.create_publisher(PoseArray, "/areasearch/targets", RELIABLE)
        self.goals: list[list[tuple[float, tuple[float, float]]]] = [[] for _ in names]
        for k, n in enumerate(names):
            self.node.create_subscription(PoseStamped, f"/{n}/goal_pose", lambda m, k=k: self._goal(k, m), RELIABLE)
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)

    def _goal(self, k: int, msg: Any) -> None:
        self.goals[k].append((time.perf_counter(), (msg.pose.position.x, msg.pose.position.y)))

    def publish_map(self, grid: OccupancyMap) -> None:
        cells = np.full(grid.shape, -1, dtype=np.int8)
        cells[grid.free] = 0
        cells[grid.occupied] = 100
        msg = self.types[0]()
        msg.header.frame_id = "map"
        msg.info.height, msg.info.width = grid.shape
        msg.info.resolution = grid.cell_m
        msg.info.origin.position.x, msg.info.origin.position.y = grid.origin_xy
        msg.info.origin.orientation.w = 1.0
        msg.data = self.array.array("b", cells.tobytes())
        self.map_publisher.publish(msg)

    def publish_pose(self, k: int, pose: np.ndarray) -> None:
        msg = self.types[1]()
        msg.header.frame_id = "map"
        msg.pose.pose.position.x, msg.pose.pose.position.y = float(pose[0]), float(pose[1])
        q = msg.pose.pose.orientation
        q.x, q.y, q.z, q.w = self.quaternion_xyzw(float(pose[2]))
        self.pose_publishers[k].publish(msg)

    def publish_targets(self, targets: np.ndarray) -> None:
        msg = self.types[2]()
        msg.header.frame_id = "map"
        for x, y in targets:
            pose = self.types[1]().pose.pose
            pose.position.x, pose.position.y = float(x), float(y)
            pose.orientation.w = 1.0
            msg.poses.append(pose)
        self.targets_publisher.publish(msg)

    def connect(self, proc: subprocess.Popen[bytes], log: Path) -> None:
        """Spin until the node's goal publishers and targets subscription are matched (goals and targets
        are not latched: a message sent before that is lost), and half a second more for the other side."""
        started = time.perf_counter()
        topics = [f"/{n}/goal_pose" for n in self.names]
        while self.node.count_subscribers("/areasearch/targets") == 0 or any(
            self.node.count_publishers(t) == 0 for t in topics
        ):
            if proc.poll() is not None or time.perf_counter() - started > WAIT_S:
                raise SystemExit(f"the node did not start; its log:\n{log.read_text()[-3000:]}")
            self.executor.spin_once(timeout_sec=0.05)
        end = time.perf_counter() + 0.5
        while time.perf_counter() < end:
            self.executor.spin_once(timeout_sec=0.05)

    def wait(self, counts: list[int], proc: subprocess.Popen[bytes], log: Path) -> float:
        """Spin until every robot has more goals than ``counts``; the time the last one came."""
        started = time.perf_counter()
        while any(len(g) <= c for g, c in zip(self.goals, counts, strict=True)):
            if proc.poll() is not None or time.perf_counter() - started > WAIT_S:
                got = [len(g) for g in self.goals]
                raise SystemExit(f"the node sent no decision (goals so far {got}); its log:\n{log.read_text()[-3000:]}")
            self.executor.spin_once(timeout_sec=0.1)  # wakes when a message comes
        return max(g[-1][0] for g in self.goals)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()


def measure(
    grid: OccupancyMap, poses: np.ndarray, targets: np.ndarray, method: str, repeats: int, log: Path
) -> tuple[list[float], list[float], list[float], int]:
    """(node latencies, the node's own goal calls, in-process times, decisions whose goals differ),
    seconds, for one case."""
    names = [f"r{k}" for k in range(len(poses))]
    command = [sys.executable, "-m", "areasearch.cli", "ros2", "--robots", *names, "--method", method]
    command += ["--period-s", "3600", "--ros-args", "--log-level", "areasearch:=debug"]  # each decision's time
    with open(log, "wb") as out:
        proc = subprocess.Popen(
            command, env={**os.environ, **ONE_THREAD, **UNBUFFERED_LOG}, stdout=out, stderr=subprocess.STDOUT
        )
    stack = Stack(names)
    planner = make_planner(method)
    keep = SearchConfig().decisions.history
    past_positions: list[deque[Any]] = [deque(maxlen=keep) for _ in names]
    past_goals: list[deque[Any]] = [deque(maxlen=keep) for _ in names]
    start, poses = poses.copy(), poses.copy()
    node_s, inproc_s, differ = [], [], 0

    def decided() -> None:  # the node's memory of a decision: each robot's position and goal
        for r, (_, goal) in enumerate(g[-1] for g in stack.goals):
            past_positions[r].appendleft((float(poses[r, 0]), float(poses[r, 1])))
            past_goals[r].appendleft(goal)

    try:
        stack.connect(proc, log)
        stack.publish_targets(targets)
        stack.publish_map(grid)
        for k, pose in enumerate(poses):
            stack.publish_pose(k, pose)
        stack.wait([0] * len(names), proc, log)  # the first decision: the map converted, kernels warm
        decided()
        assign_goals(grid, poses, planner, targets)  # this process's warm-up
        for i in range(repeats):
            k = _arriving(i, poses, [g[-1][1] for g in stack.goals])
            poses[k, :2] = stack.goals[k][-1][1]
            past = [list(p) for p in past_positions], [list(g) for g in past_goals]
            counts = [len(g) for g in stack.goals]
            sent = time.perf_counter()
            stack.publish_pose(k, poses[k])
            node_s.append(stack.wait(counts, proc, log) - sent)
            started = time.perf_counter()
            answer = assign_goals(grid, poses, planner, targets, *past)
            inproc_s.append(time.perf_counter() - started)
            differ += [a.goal_xy for a in answer] != [g[-1][1] for g in stack.goals]
            decided()
            poses[k] = start[k]  # back to its start, for the next sample (decides only if its goal is there)
            counts = [len(g) for g in stack.goals]
            stack.publish_pose(k, poses[k])
            end = time.perf_counter() + 0.3
            while time.perf_counter() < end:
                stack.executor.spin_once(timeout_sec=0.01)
            if any(len(g) > c for g, c in zip(stack.goals, counts, strict=True)):
                stack.wait(counts, proc, log)
                decided()
    finally:
        stack.close()
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
    calls = [float(t) for t in re.findall(r"reached its goal\): \d+ robots in ([0-9.]+) s", log.read_text())]
    return node_s, calls, inproc_s, differ


def _arriving(i: int, poses: np.ndarray, goals: list[tuple[float, float]]) -> int:
    """The robot that arrives at its goal in sample ``i``: robot ``i % R``, or the next one whose goal
    is farther than twice the goal tolerance from it (arriving there makes the node decide) and keeps a
    footprint's room from the other robots (two robots closer than that would be refused)."""
    n = len(poses)
    for j in range(n):
        k = (i + j) % n
        gap = [math.hypot(goals[k][0] - poses[r, 0], goals[k][1] - poses[r, 1]) for r in range(n)]
        if gap[k] > 2 * TOLERANCE_M + 0.05 and min(gap[:k] + gap[k + 1 :], default=math.inf) > 0.5:
            return k
    raise SystemExit(
        f"sample {i}: no robot's goal lies farther than {2 * TOLERANCE_M:g} m from it and 0.5 m from the others "
        f"(poses {poses[:, :2].round(2).tolist()}, goals {np.round(goals, 2).tolist()}); try another --decisions"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--map", default=None, help="bundled map id (default: the largest)")
    parser.add_argument("--robots", type=int, nargs="+", default=[3, 5])
    parser.add_argument("--methods", nargs="+", default=["greedy", "dahgnn"])
    parser.add_argument("--decisions", type=int, default=25)
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    import rclpy
    import torch

    torch.set_num_threads(1)
    os.environ["ROS_DOMAIN_ID"] = str(101 - os.getpid() % 50)  # this run's own domain; the node inherits it
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    map_id = args.map or largest_map()
    rclpy.init(args=[])
    columns = ("robots", "known", "targets", "method", "node p50", "node p95", "its call p50", "in-process p50")
    print(" ".join(f"{c:>{w}}" for c, w in zip(columns, (6, 7, 7, 10, 9, 9, 12, 15), strict=True)),
          f"{'in-process p95':>15} {'n':>3} {'goals differ':>12}")  # fmt: skip
    try:
        with tempfile.TemporaryDirectory() as folder:
            for robots in args.robots:
                _, grid, poses, targets = snapshots(map_id, robots, [args.decisions], args.seed)[0]
                known = grid.explored.sum() * grid.cell_m**2
                for method in args.methods:
                    log = Path(folder) / f"node_{robots}_{method}.log"
                    node_s, calls, inproc_s, differ = measure(grid, poses, targets, method, args.repeats, log)
                    node_ms, inproc_ms = 1e3 * np.array(node_s), 1e3 * np.array(inproc_s)
                    print(
                        f"{robots:6d} {known:6.0f}m² {len(targets):7d} {method:10} {percentile(node_ms, 50):7.1f}ms "
                        f"{percentile(node_ms, 95):7.1f}ms {1e3 * np.median(calls):10.1f}ms "
                        f"{percentile(inproc_ms, 50):13.1f}ms "
                        f"{percentile(inproc_ms, 95):13.1f}ms {len(node_s):3d} {differ:12d}",
                        flush=True,
                    )
    finally:
        rclpy.try_shutdown()
    print(
        f"(map {map_id}; node = pose message published -> last robot's goal message received, the node in its own "
        "process; its call = the node's assign_goals call within that (its debug log); in-process = one "
        "assign_goals call here on the same input; one thread each)"
    )


if __name__ == "__main__":
    main()
