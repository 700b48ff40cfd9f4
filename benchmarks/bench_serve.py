"""Latency of ``areasearch serve``'s ``POST /assign`` beside the in-process call and the CLI, one run.

The inputs are :mod:`bench_assign`'s: what 5 robots of a Greedy team have mapped of the largest
bundled map (``bormann_office_g_rooms3``, 1821 x 1826 cells of 5 cm) after ``--decisions`` decisions,
with their poses and the targets seen so far. For each snapshot and method (a classical and a
learned planner), measured in this order in one run, so that the ratios share the machine's load:

* **CLI**: ``areasearch assign --map snapshot.yaml --robots ... --targets ...`` as a fresh process,
  median of ``--cli-repeats`` runs (wall time, process start to exit); its output is also the
  answer the service must give, byte for byte;
* **service**: ``areasearch serve --workers W`` started once in a subprocess; this process is the
  client, on loopback, one keep-alive HTTP connection per client thread. The map is stored once
  (``PUT /maps/NAME``) and each call sends the poses and targets (``stored``). With 1 client,
  ``--requests`` calls alternate with as many **in-process** calls, ``assign_goals(grid, poses,
  planner, targets)`` with the map in memory and the planner built once (one thread, as the
  service's workers), so that both see the same load of a shared machine; then 4 client threads
  send ``--requests`` calls each; then 1 client sends the whole OccupancyGrid in every body
  (``inline``, about 10 MB of JSON on the largest map), a third as many times. p50 and p95 of the
  clients' time from sending a request to reading the whole answer; beside them the medians of the
  service's own time (request parsed to answer ready) and the worker's (Server-Timing). A case stops
  after ``--max-seconds``.

    python benchmarks/bench_serve.py [--decisions 5 25] [--methods greedy dahgnn] [--workers 2]
        [--requests 30] [--cli-repeats 3] [--max-seconds 60] [--set KEY=VALUE ...]

``--set`` gives the service (``areasearch serve --set``), the command (``areasearch assign --set``) and the
in-process call (``assign_goals(config=...)``) the same decision settings, e.g.
``--set candidates.distance_cell_m=0.1``.
"""

from __future__ import annotations

import argparse
import http.client
import json
import os
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

os.environ.setdefault("NUMBA_NUM_THREADS", "1")

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from areasearch.config import parse_settings, search_config
from areasearch.planners import make_planner
from areasearch.service.assign import assign_goals, save_occupancy_yaml
from areasearch.service.occupancy_msg import grid_message
from bench_assign import snapshots

ONE_THREAD = {"NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}


def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(values), q))


class Client:
    """One keep-alive HTTP connection."""

    def __init__(self, host: str, port: int) -> None:
        self.conn = http.client.HTTPConnection(host, port, timeout=300)
        self.timing: dict[str, str] = {}
        """The last answer's Server-Timing: ``plan`` (the worker's own time), ``service`` (the HTTP
        process's, request parsed to answer ready), ms."""

    def call(self, method: str, path: str, body: bytes | None = None) -> tuple[int, bytes]:
        headers = {"Content-Type": "application/json"} if body is not None else {}
        self.conn.request(method, path, body=body, headers=headers)
        response = self.conn.getresponse()
        self.timing = dict(re.findall(r"(\w+);dur=([0-9.]+)", response.getheader("server-timing") or ""))
        return response.status, response.read()

    def close(self) -> None:
        self.conn.close()


def start_service(
    workers: int, log_path: Path, settings: list[str] | None = None
) -> tuple[subprocess.Popen[bytes], str, int, float]:
    """``areasearch serve --port 0 --workers W [--set ...]``; (process, host, port, seconds until /health is ready)."""
    t0 = time.perf_counter()
    with open(log_path, "wb") as log:
        proc = subprocess.Popen(
            [sys.executable, "-m", "areasearch.cli", "serve", "--port", "0", "--workers", str(workers)]
            + (["--set", *settings] if settings else []),
            stdout=log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            env={**os.environ, **ONE_THREAD},
        )
    while not (found := re.search(r"listening on http://([0-9.]+):(\d+)", log_path.read_text())):
        if proc.poll() is not None:
            raise SystemExit(f"the service did not start:\n{log_path.read_text()}")
        time.sleep(0.05)
    host, port = found.group(1), int(found.group(2))
    client = Client(host, port)
    while True:
        try:
            if client.call("GET", "/health")[0] == 200:
                break
        except OSError:
            client.close()
            client = Client(host, port)
        if proc.poll() is not None:
            raise SystemExit(f"the service stopped:\n{log_path.read_text()}")
        time.sleep(0.05)
    client.close()
    return proc, host, port, time.perf_counter() - t0


def load(
    host: str, port: int, body: bytes, clients: int, requests: int, max_seconds: float
) -> tuple[list[float], list[float], list[float]]:
    """Seconds per request of ``clients`` threads each sending ``body`` up to ``requests`` times, as
    the clients saw them, and the service's and the worker's own seconds (Server-Timing)."""
    times: list[list[float]] = [[] for _ in range(clients)]
    service: list[float] = []
    worker: list[float] = []
    errors: list[str] = []
    end = time.perf_counter() + max_seconds

    def run(k: int) -> None:
        client = Client(host, port)
        try:
            for _ in range(requests):
                if time.perf_counter() > end:
                    break
                t0 = time.perf_counter()
                status, answer = client.call("POST", "/assign", body)
                times[k].append(time.perf_counter() - t0)
                service.append(float(client.timing.get("service", "nan")) / 1e3)
                worker.append(float(client.timing.get("plan", "nan")) / 1e3)
                if status != 200:
                    errors.append(f"{status}: {answer[:200]!r}")
                    break
        finally:
            client.close()

    threads = [threading.Thread(target=run, args=(k,)) for k in range(clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    if errors:
        raise SystemExit(f"the service refused a benchmark request: {errors[0]}")
    return [t for per in times for t in per], service, worker


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--map", default="bormann_office_g_rooms3")
    parser.add_argument("--robots", type=int, default=5)
    parser.add_argument("--decisions", type=int, nargs="+", default=[5, 25])
    parser.add_argument("--methods", nargs="+", default=["greedy", "dahgnn"])
    parser.add_argument("--workers", type=int, default=2, help="service worker processes (default 2)")
    parser.add_argument("--requests", type=int, default=30, help="requests per client and case")
    parser.add_argument("--cli-repeats", type=int, default=3, help="areasearch assign runs per case")
    parser.add_argument("--max-seconds", type=float, default=60.0, help="most seconds per load case")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--set", nargs="+", default=[], metavar="KEY=VALUE", help="decision settings of every call")
    args = parser.parse_args()
    config = search_config(parse_settings(args.set)) if args.set else None
    set_args = ["--set", *args.set] if args.set else []
    torch.set_num_threads(1)
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        tmp = Path(folder)
        shots = snapshots(args.map, args.robots, args.decisions, args.seed)
        proc, host, port, ready_s = start_service(args.workers, tmp / "serve.log", args.set)
        print(f"service ready in {ready_s:.1f} s ({args.workers} workers)", flush=True)
        try:
            for k, grid, poses, targets in shots:
                known = grid.explored.sum() * grid.cell_m**2
                name = f"snap{k}"
                yaml_path = save_occupancy_yaml(grid, tmp / f"{name}.yaml")
                robots = [
                    {"id": f"r{i}", "x": float(x), "y": float(y), "yaw": float(t)} for i, (x, y, t) in enumerate(poses)
                ]
                target_list = [{"id": f"t{i}", "x": float(x), "y": float(y)} for i, (x, y) in enumerate(targets)]
                (tmp / "robots.json").write_text(json.dumps({"robots": robots}))
                (tmp / "targets.json").write_text(json.dumps({"targets": target_list}))
                message = grid_message(grid)
                client = Client(host, port)
                status, answer = client.call("PUT", f"/maps/{name}", json.dumps(message).encode())
                client.close()
                assert status == 201, answer
                for method in args.methods:
                    planner = make_planner(method)  # in-process: the planner built once
                    assign_goals(grid, poses, planner, targets, config=config)
                    # the CLI, a fresh process per call
                    cli = []
                    for _ in range(args.cli_repeats):
                        t0 = time.perf_counter()
                        subprocess.run(
                            [sys.executable, "-m", "areasearch.cli", "assign", "--map", str(yaml_path), "--robots",
                             str(tmp / "robots.json"), "--targets", str(tmp / "targets.json"), "--method", method,
                             "--out", str(tmp / "goals.json"), *set_args],
                            check=True, env={**os.environ, **ONE_THREAD}, capture_output=True,
                        )  # fmt: skip
                        cli.append(time.perf_counter() - t0)
                    cli_s = statistics.median(cli)
                    # the service answers what the CLI printed
                    stored = json.dumps({"map": name, "robots": robots, "targets": target_list, "method": method})
                    client = Client(host, port)
                    status, answer = client.call("POST", "/assign", stored.encode())
                    assert status == 200 and answer.decode() == (tmp / "goals.json").read_text(), answer[:300]
                    # 1 client, interleaved with the in-process call: both measured under the same load
                    spent, times, service, worker = [], [], [], []
                    for _ in range(args.requests):
                        t0 = time.perf_counter()
                        assign_goals(grid, poses, planner, targets, config=config)
                        t1 = time.perf_counter()
                        status, answer = client.call("POST", "/assign", stored.encode())
                        t2 = time.perf_counter()
                        assert status == 200, answer[:300]
                        spent.append(t1 - t0)
                        times.append(t2 - t1)
                        service.append(float(client.timing["service"]) / 1e3)
                        worker.append(float(client.timing["plan"]) / 1e3)
                    client.close()
                    in_process = statistics.median(spent)
                    inline = json.dumps({"map": message, "robots": robots, "targets": target_list, "method": method})
                    cases = [("stored", 1, (times, service, worker))]
                    cases.append(("stored", 4, load(host, port, stored.encode(), 4, args.requests, args.max_seconds)))
                    inline_requests = max(3, args.requests // 3)
                    cases.append(("inline", 1, load(host, port, inline.encode(), 1, inline_requests, args.max_seconds)))
                    for mode, clients, (times, service, worker) in cases:
                        p50, p95 = percentile(times, 50), percentile(times, 95)
                        row = {
                            "steps": k * 40, "known_m2": round(float(known)), "method": method, "mode": mode,
                            "clients": clients, "requests": len(times), "p50_ms": 1e3 * p50, "p95_ms": 1e3 * p95,
                            "in_process_ms": 1e3 * in_process, "cli_ms": 1e3 * cli_s,
                            "p50_over_in_process": p50 / in_process, "cli_over_p50": cli_s / p50,
                            "service_ms": 1e3 * percentile(service, 50), "worker_ms": 1e3 * percentile(worker, 50),
                        }  # fmt: skip
                        rows.append(row)
                        print(
                            f"{k * 40:5d} steps {known:5.0f} m² {method:8} {mode:6} x{clients}: {len(times):3d} "
                            f"requests p50 {1e3 * p50:7.1f} ms p95 {1e3 * p95:7.1f} ms (service "
                            f"{row['service_ms']:6.1f} worker {row['worker_ms']:6.1f}) | "
                            f"in-process {1e3 * in_process:6.1f} ms "
                            f"CLI {cli_s:5.2f} s | p50/in-process {p50 / in_process:4.2f} CLI/p50 {cli_s / p50:5.1f}",
                            flush=True,
                        )
        finally:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(30)
            except subprocess.TimeoutExpired:
                proc.kill()
    print()
    print(
        "| steps | known | method | map in body | clients | requests | p50 | p95 | service p50 | worker p50 "
        "| in-process | CLI | p50 / in-process | CLI / p50 |"
    )
    print("|---:|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        print(
            f"| {r['steps']} | {r['known_m2']} m² | {r['method']} | {r['mode']} | {r['clients']} | {r['requests']} | "
            f"{r['p50_ms']:.0f} ms | {r['p95_ms']:.0f} ms | {r['service_ms']:.0f} ms | {r['worker_ms']:.0f} ms | "
            f"{r['in_process_ms']:.0f} ms | {r['cli_ms'] / 1e3:.2f} s | "
            f"{r['p50_over_in_process']:.2f} | {r['cli_over_p50']:.1f} |"
        )


if __name__ == "__main__":
    main()
