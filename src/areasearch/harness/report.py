"""Reporting: the paper's result tables and curves from evaluation episodes (DA-HGNN "Experiments").

Input is one record per episode (a mapping with ``method``, ``map``, ``size_class``, ``robots``,
``explored_pct``, ``time_e``, ``covered_pct``, ``time_c``: the rows of ``episodes.csv`` written by
:mod:`areasearch.harness.evaluate`) and, for the figure, one curve per episode (``method``, ``steps``,
``explored_pct``, ``covered_pct`` after each decision).

* :func:`summarize` builds a :class:`Summary`: for each team size, one :class:`Table` per size class
  with the paper's columns Explo (%), Time_E (step), Cover (%), Time_C (step) per method (Tables 3-5
  and 7), each a mean over episodes with the half-width of its 95 % confidence interval from the
  t-distribution (:func:`mean_ci`). The best mean of a column is marked: the largest for the
  percentages, the smallest for the step counts, compared at the printed precision (ties all best).
* Time_E and Time_C are censored: an episode that never reached 80 % within the horizon counts the
  horizon (a lower bound on the time it would take). A mean over such episodes is printed ``> mean``,
  without interval (:attr:`Stat.censored`), and is never marked best; nor is a time that such a lower
  bound does not exceed, since the censored method may still be faster.
* :func:`to_markdown`, :func:`to_latex` print it; :meth:`Summary.to_dict` / :meth:`Summary.from_dict`
  are its JSON form; :func:`json_ready` rounds a JSON document's numbers to what they mean.
* :func:`paired_differences` compares each method with a reference method (Greedy by default in
  ``areasearch eval``) episode by episode: every method plays the same (map, team, seed) episodes, so
  the per-episode difference removes the variation between maps and seeds that dominates the
  per-method intervals. Mean difference with its 95 % interval per metric; "better" / "worse" when
  the interval excludes 0 (:func:`paired_markdown`).
* :func:`draw_curves` draws the explored and covered percentage against steps, one mean curve per
  method (the paper's Fig. "test_resulting"), with matplotlib's Agg canvas.

Every file is written atomically (:func:`write_text`, temporary file then ``os.replace``).
Units: percentages 0-100, times in primitive steps.
"""

from __future__ import annotations

import io
import math
import os
import sys
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
from scipy import stats

from ..errors import AreaSearchError
from ..folderlock import write_atomic
from ..sim.scene import SIZE_CLASSES


@dataclass(frozen=True)
class Metric:
    """One column of the paper's tables."""

    key: str
    """Field of the episode record."""
    label: str
    """Column heading (plain text)."""
    latex: str
    """Column heading (LaTeX)."""
    higher_is_better: bool
    reached: str | None = None
    """Field of the episode record saying whether the episode reached the value (``reached_e``): when
    false the value is the horizon, a lower bound (censored); None for a metric never censored."""


METRICS = (
    Metric("explored_pct", "Explo(%)", r"Explo(\%)", True),
    Metric("time_e", "Time_E (step)", r"Time$\_$E (step)", False, "reached_e"),
    Metric("covered_pct", "Cover(%)", r"Cover(\%)", True),
    Metric("time_c", "Time_C (step)", r"Time$\_$C (step)", False, "reached_c"),
    Metric("covered_of_discovered_pct", "Cover/disc.(%)", r"Cover/disc.(\%)", True),
)
"""The paper's four columns, in its order, then covered / discovered targets (what the DA-HGNN
authors' coverage code reports)."""

MAP_ERROR = Metric("map_error_pct", "Map err. (%)", r"Map err. (\%)", False)
"""The team map's error at an episode's end (:mod:`areasearch.sim.mapquality`), which evaluations record
for imperfect worlds only: a column after :data:`METRICS` when every episode summarised has it."""

DECIMALS = 2
"""Printed precision of means and half-widths; best marks compare means at this precision."""


@dataclass(frozen=True)
class Stat:
    """Mean of one metric over n episodes with its 95 % confidence half-width."""

    mean: float
    half_width: float | None
    """t-based half-width of the 95 % confidence interval; None with fewer than two episodes."""
    n: int
    censored: int = 0
    """Episodes whose value is the horizon because they never reached 80 % (Time_E, Time_C): the mean
    is then a lower bound, printed ``> mean`` without interval."""


@dataclass(frozen=True)
class MethodRow:
    """One method's line of a table."""

    method: str
    episodes: int
    stats: tuple[Stat, ...]
    """One per entry of the summary's metrics (:attr:`Summary.metrics`), same order."""
    best: tuple[bool, ...]
    """Whether this method is (one of) the best in each column."""


@dataclass(frozen=True)
class Table:
    """Results of one team size in one size class."""

    robots: int
    size_class: str
    maps: tuple[str, ...]
    rows: tuple[MethodRow, ...]


@dataclass(frozen=True)
class Summary:
    """All tables of an evaluation, with the settings that produced them."""

    tables: tuple[Table, ...]
    settings: tuple[tuple[str, Any], ...] = ()
    """(name, value) pairs of the run settings (seed, max_steps, ...), JSON scalars."""
    metrics: tuple[Metric, ...] = METRICS
    """The columns: :data:`METRICS`, then :data:`MAP_ERROR` when every episode has it."""

    def to_dict(self) -> dict[str, Any]:
        return {
            "metrics": [m.key for m in self.metrics],
            "confidence": 0.95,
            "settings": dict(self.settings),
            "tables": [
                {
                    "robots": t.robots,
                    "size_class": t.size_class,
                    "maps": list(t.maps),
                    "rows": [
                        {
                            "method": row.method,
                            "episodes": row.episodes,
                            **{
                                m.key: {
                                    "mean": s.mean,
                                    "ci95": s.half_width,
                                    "n": s.n,
                                    "best": b,
                                    **({"censored": s.censored} if m.reached else {}),
                                }
                                for m, s, b in zip(self.metrics, row.stats, row.best, strict=True)
                            },
                        }
                        for row in t.rows
                    ],
                }
                for t in self.tables
            ],
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Summary:
        keys = data.get("metrics", [m.key for m in METRICS])
        metrics = METRICS + ((MAP_ERROR,) if MAP_ERROR.key in keys else ())
        tables = []
        for t in data["tables"]:
            rows = []
            for r in t["rows"]:
                cells = [r[m.key] for m in metrics]
                rows.append(
                    MethodRow(
                        method=str(r["method"]),
                        episodes=int(r["episodes"]),
                        stats=tuple(
                            Stat(float(c["mean"]), _opt_float(c["ci95"]), int(c["n"]), int(c.get("censored", 0)))
                            for c in cells
                        ),
                        best=tuple(bool(c["best"]) for c in cells),
                    )
                )
            tables.append(Table(int(t["robots"]), str(t["size_class"]), tuple(t["maps"]), tuple(rows)))
        return cls(tuple(tables), tuple(data.get("settings", {}).items()), metrics)


def _opt_float(value: Any) -> float | None:
    return None if value is None else float(value)


def mean_ci(values: Sequence[float] | np.ndarray, confidence: float = 0.95) -> Stat:
    """Mean and the half-width of its ``confidence`` interval, t-distribution with n - 1 degrees of
    freedom: t_{(1+confidence)/2, n-1} * s / sqrt(n), s the sample standard deviation."""
    x = np.asarray(values, dtype=np.float64)
    n = int(x.size)
    if n == 0:
        raise ValueError("mean_ci needs at least one value")
    mean = float(x.mean())
    if n < 2:
        return Stat(mean, None, n)
    sem = float(x.std(ddof=1)) / math.sqrt(n)
    half = float(stats.t.ppf(0.5 + confidence / 2.0, n - 1)) * sem
    return Stat(mean, half, n)


def summarize(
    records: Iterable[Mapping[str, Any]],
    methods: Sequence[str] | None = None,
    settings: Mapping[str, Any] | None = None,
) -> Summary:
    """The paper's tables from episode records: for each team size (ascending), one table per size
    class (small, medium, large) with one row per method (in ``methods`` order, default first seen); the
    map error (:data:`MAP_ERROR`) is a column when every record has it."""
    records = list(records)
    metrics = METRICS + ((MAP_ERROR,) if records and all(MAP_ERROR.key in rec for rec in records) else ())
    groups: dict[tuple[int, str], dict[str, list[Mapping[str, Any]]]] = {}
    maps: dict[tuple[int, str], set[str]] = {}
    seen: list[str] = []
    for rec in records:
        key = (int(rec["robots"]), str(rec["size_class"]))
        method = str(rec["method"])
        groups.setdefault(key, {}).setdefault(method, []).append(rec)
        maps.setdefault(key, set()).add(str(rec["map"]))
        if method not in seen:
            seen.append(method)
    order = list(methods) if methods is not None else seen
    tables = []
    for robots, size in sorted(groups, key=lambda k: (k[0], size_rank(k[1]))):
        by_method = groups[(robots, size)]
        present = [m for m in order if m in by_method]
        stats_by_method = {m: tuple(metric_stat(metric, by_method[m]) for metric in metrics) for m in present}
        best = {m: [False] * len(metrics) for m in present}
        for j, metric in enumerate(metrics):
            shown = {
                m: (round(stats_by_method[m][j].mean, DECIMALS), bool(stats_by_method[m][j].censored)) for m in present
            }
            value = best_value(list(shown.values()), metric.higher_is_better)
            for m in present:
                best[m][j] = value is not None and shown[m] == (value, False)
        rows = tuple(
            MethodRow(method=m, episodes=len(by_method[m]), stats=stats_by_method[m], best=tuple(best[m]))
            for m in present
        )
        tables.append(Table(robots, size, tuple(sorted(maps[(robots, size)])), rows))
    return Summary(tuple(tables), tuple((settings or {}).items()), metrics)


def best_value(means: Sequence[tuple[float, bool]], higher_is_better: bool) -> float | None:
    """The best of shown means, each with whether it is censored: the largest (``higher_is_better``) or
    smallest uncensored mean; None where none is uncensored, or where a censored mean (a lower bound on
    a time) does not exceed it, since that method may still be faster."""
    known = [mean for mean, censored in means if not censored]
    if not known:
        return None
    value = max(known) if higher_is_better else min(known)
    bounds = [mean for mean, censored in means if censored]
    return None if bounds and value > min(bounds) else value


def metric_stat(metric: Metric, records: Sequence[Mapping[str, Any]]) -> Stat:
    """:func:`mean_ci` of ``metric`` over ``records``, counting the episodes that never reached it
    (``metric.reached`` false: their value is the horizon). A record without that field counts as reached."""
    stat = mean_ci([float(rec[metric.key]) for rec in records])
    if metric.reached is None:
        return stat
    censored = sum(1 for rec in records if rec.get(metric.reached, True) in (False, "False"))
    return Stat(stat.mean, stat.half_width, stat.n, censored)


def size_rank(size: str) -> int:
    """Where a size class sorts: the paper's order (small, medium, large), any other name after them."""
    return SIZE_CLASSES.index(size) if size in SIZE_CLASSES else len(SIZE_CLASSES)


@dataclass(frozen=True)
class PairedRow:
    """One method against the reference, in one (team size, size class): per metric the mean of the
    per-episode differences (method - reference) over the episodes both played."""

    robots: int
    size_class: str
    method: str
    reference: str
    stats: tuple[Stat, ...]
    """One per entry of :data:`METRICS`, same order."""

    def verdict(self, j: int) -> str:
        """'better', 'worse' (the 95 % interval excludes 0, in the metric's good or bad direction) or
        'same' (it does not, or fewer than two pairs)."""
        stat, metric = self.stats[j], METRICS[j]
        if stat.half_width is None or abs(stat.mean) <= stat.half_width:
            return "same"
        return "better" if (stat.mean > 0) == metric.higher_is_better else "worse"

    def to_dict(self) -> dict[str, Any]:
        return {
            "robots": self.robots,
            "size_class": self.size_class,
            "method": self.method,
            "reference": self.reference,
            **{
                m.key: {"mean_diff": s.mean, "ci95": s.half_width, "n": s.n, "verdict": self.verdict(j)}
                for j, (m, s) in enumerate(zip(METRICS, self.stats, strict=True))
            },
        }


def paired_differences(
    records: Iterable[Mapping[str, Any]], reference: str, methods: Sequence[str] | None = None
) -> tuple[PairedRow, ...]:
    """Each method (``methods`` order, default first seen; the reference itself skipped) against
    ``reference`` on the episodes both played, matched by (map, robots, seed), per (team size, size
    class). Groups where the reference played nothing are left out."""
    by_key: dict[str, dict[tuple[str, int, int], Mapping[str, Any]]] = {}
    seen: list[str] = []
    for rec in records:
        method = str(rec["method"])
        by_key.setdefault(method, {})[(str(rec["map"]), int(rec["robots"]), int(rec["seed"]))] = rec
        if method not in seen:
            seen.append(method)
    ref = by_key.get(reference, {})
    rows = []
    for method in list(methods) if methods is not None else seen:
        if method == reference or method not in by_key:
            continue
        groups: dict[tuple[int, str], list[tuple[Mapping[str, Any], Mapping[str, Any]]]] = {}
        for key, rec in by_key[method].items():
            if key in ref:
                groups.setdefault((int(rec["robots"]), str(rec["size_class"])), []).append((rec, ref[key]))
        for robots, size in sorted(groups, key=lambda k: (k[0], size_rank(k[1]))):
            pairs = groups[(robots, size)]
            stats_ = tuple(mean_ci([float(a[m.key]) - float(b[m.key]) for a, b in pairs]) for m in METRICS)
            rows.append(PairedRow(robots, size, method, reference, stats_))
    rows.sort(key=lambda r: (r.robots, size_rank(r.size_class)))
    return tuple(rows)


def _signed_cell(stat: Stat) -> str:
    if stat.half_width is None:
        return f"{stat.mean:+.{DECIMALS}f}"
    return f"{stat.mean:+.{DECIMALS}f} ± {stat.half_width:.{DECIMALS}f}"


def paired_markdown(rows: Sequence[PairedRow]) -> str:
    """One markdown table of :func:`paired_differences`: a cell is in bold where the method is better
    than the reference beyond the 95 % interval, in italics where it is worse."""
    if not rows:
        return ""
    reference = rows[0].reference
    lines = [
        f"## Paired differences against {reference}",
        "",
        f"Per episode, method − {reference} on the same map, team and seed; mean ± half-width of the 95 % "
        "confidence interval. **Bold**: better beyond the interval; *italics*: worse beyond it.",
        "",
        "| Robots | Scenes | Method | " + " | ".join(m.label for m in METRICS) + " | pairs |",
        "|---:|---|---|" + "---:|" * len(METRICS) + "---:|",
    ]
    for row in rows:
        cells = []
        for j, stat in enumerate(row.stats):
            text, verdict = _signed_cell(stat), row.verdict(j)
            cells.append(f"**{text}**" if verdict == "better" else f"*{text}*" if verdict == "worse" else text)
        n = row.stats[0].n
        lines.append(f"| {row.robots} | {row.size_class} | {row.method} | " + " | ".join(cells) + f" | {n} |")
    return "\n".join(lines) + "\n"


def _cell(stat: Stat) -> str:
    if stat.censored:  # a lower bound: no interval
        return f"> {stat.mean:.{DECIMALS}f}"
    if stat.half_width is None:
        return f"{stat.mean:.{DECIMALS}f}"
    return f"{stat.mean:.{DECIMALS}f} ± {stat.half_width:.{DECIMALS}f}"


CENSORED_NOTE = (
    "> m: some episodes never reached 80 % within the horizon and count the horizon, so m is a lower bound "
    "on the mean time (no interval; never marked best)."
)
"""The note under a summary's heading when a time is censored."""


def to_markdown(summary: Summary) -> str:
    """Markdown tables, one per (team size, size class); best cells in bold."""
    settings = dict(summary.settings)
    lines = ["# Evaluation summary", ""]
    if settings:
        lines += [", ".join(f"{k} {v}" for k, v in settings.items()), ""]
    lines += ["Mean ± half-width of the 95 % confidence interval (t-distribution) over episodes; best in bold.", ""]
    if any(s.censored for t in summary.tables for row in t.rows for s in row.stats):
        lines += [CENSORED_NOTE, ""]
    for t in summary.tables:
        lines += [
            f"## {t.robots} robots, {t.size_class} scenes ({len(t.maps)} map{'s' if len(t.maps) != 1 else ''})",
            "",
            "| Method | " + " | ".join(m.label for m in summary.metrics) + " | episodes |",
            "|---|" + "---:|" * len(summary.metrics) + "---:|",
        ]
        for row in t.rows:
            cells = [f"**{_cell(s)}**" if b else _cell(s) for s, b in zip(row.stats, row.best, strict=True)]
            lines.append(f"| {row.method} | " + " | ".join(cells) + f" | {row.episodes} |")
        lines += ["", "Maps: " + ", ".join(t.maps), ""]
    return "\n".join(lines)


_LATEX_SPECIAL = {
    "\\": r"\textbackslash{}",
    "&": r"\&",
    "%": r"\%",
    "$": r"\$",
    "#": r"\#",
    "_": r"\_",
    "{": r"\{",
    "}": r"\}",
    "~": r"\textasciitilde{}",
    "^": r"\textasciicircum{}",
}


def latex_escape(text: str) -> str:
    return "".join(_LATEX_SPECIAL.get(ch, ch) for ch in text)


def _latex_cell(stat: Stat, best: bool) -> str:
    if stat.censored:
        return rf"$>$ {stat.mean:.{DECIMALS}f}"
    text = f"{stat.mean:.{DECIMALS}f}"
    if stat.half_width is not None:
        text += rf" $\pm$ {stat.half_width:.{DECIMALS}f}"
    return rf"\textbf{{{text}}}" if best else text


def to_latex(summary: Summary) -> str:
    """LaTeX tables in the layout of the paper's Tables 3-5: one ``table`` per team size holding one
    ``tabular`` per size class; best cells in ``\\textbf``. Needs the booktabs package."""
    out: list[str] = []
    for robots in sorted({t.robots for t in summary.tables}):
        tables = [t for t in summary.tables if t.robots == robots]
        episodes = sorted({row.episodes for t in tables for row in t.rows})
        n_text = "/".join(str(e) for e in episodes)
        out += [
            r"\begin{table}[]",
            r"    \renewcommand{\arraystretch}{1.2}",
            r"    \centering",
            rf"    \caption{{Quantitative Results of Deploying {robots} Robots in Different Scenes "
            rf"(mean $\pm$ 95\% CI over {n_text} episodes)}}",
            rf"    \label{{table:{robots}robots}}",
        ]
        for i, t in enumerate(tables):
            out += [
                r"    \begin{tabular}{c|" + " ".join("c" for _ in summary.metrics) + "}",
                r"        \toprule" if i == 0 else r"        \hline",
                rf"        & \multicolumn{{{len(summary.metrics)}}}{{c}}"
                rf"{{{latex_escape(t.size_class.capitalize())} Scene}}\\",
                r"        \hline",
                "        Method & " + " & ".join(m.latex for m in summary.metrics) + r" \\",
                r"        \hline",
            ]
            for row in t.rows:
                cells = [_latex_cell(s, b) for s, b in zip(row.stats, row.best, strict=True)]
                out.append(f"        {latex_escape(row.method)} & " + " & ".join(cells) + r" \\")
            if i == len(tables) - 1:
                out.append(r"        \bottomrule")
            out.append(r"    \end{tabular}")
        out += [r"\end{table}", ""]
    return "\n".join(out)


def mean_curves(
    curves: Iterable[Mapping[str, Any]], methods: Sequence[str], max_steps: int, points: int = 361
) -> tuple[np.ndarray, dict[str, tuple[np.ndarray, np.ndarray, int]]]:
    """Mean explored % and covered % per method on a common step grid.

    Each curve holds the values after each decision, interpolated linearly in between; after the
    episode ended its last value holds (an episode that terminated early keeps its final values to
    the horizon). Returns (grid (P,) steps, method -> ((P,) explored %, (P,) covered %, episodes))."""
    grid = np.unique(np.linspace(0, max_steps, points).round().astype(np.int64))  # (P,)
    sums: dict[str, list[Any]] = {}
    for c in curves:
        steps = np.asarray(c["steps"], dtype=np.float64)
        if steps.size == 0:
            continue
        acc = sums.setdefault(str(c["method"]), [np.zeros(grid.size), np.zeros(grid.size), 0])
        acc[0] += np.interp(grid, steps, np.asarray(c["explored_pct"], dtype=np.float64))
        acc[1] += np.interp(grid, steps, np.asarray(c["covered_pct"], dtype=np.float64))
        acc[2] += 1
    result = {m: (sums[m][0] / sums[m][2], sums[m][1] / sums[m][2], sums[m][2]) for m in methods if m in sums}
    return grid, result


def draw_curves(
    curves: Iterable[Mapping[str, Any]], methods: Sequence[str], max_steps: int, path: str | Path, title: str = ""
) -> Path:
    """Explored % and covered % against steps, one mean curve per method, two subplots; PNG, atomic."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    grid, means = mean_curves(curves, methods, max_steps)
    fig = Figure(figsize=(11, 4.2), dpi=110)
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 2, sharex=True)
    for ax, which, label in ((axes[0], 0, "Explo (%)"), (axes[1], 1, "Cover (%)")):
        for method, values in means.items():
            ax.plot(grid, values[which], label=f"{method} (n={values[2]})", linewidth=1.6)
        ax.set_xlabel("step")
        ax.set_ylabel(label)
        ax.set_xlim(0, max_steps)
        ax.set_ylim(0, 100)
        ax.grid(alpha=0.3)
    axes[0].set_title("(a) Exploration percentage")
    axes[1].set_title("(b) Coverage percentage")
    axes[1].legend(loc="best", fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png")
    return write_atomic(path, buffer.getvalue(), "curve figure")


UNIT_DECIMALS = (("_pct", 2), ("_m2", 2), ("_xy", 3), ("_m", 3), ("_s", 3))
"""Decimals of a JSON number by the suffix of its key: percentages to 0.01 (the tables' precision),
areas to 0.01 m², positions and lengths to the millimetre, durations to the millisecond."""


def json_ready(doc: Any, decimals: int | None = None, key: str = "") -> Any:
    """``doc`` (dicts, lists, numbers, ...) with each float rounded to what it means, for JSON output:
    to ``decimals`` when given, else by its key's unit (:data:`UNIT_DECIMALS`; the items of a list take
    the list's key), else to 12 significant digits, which drops binary noise such as
    ``16.740000000000002`` and keeps every digit a measurement here has."""
    if isinstance(doc, dict):
        return {k: json_ready(v, decimals, str(k)) for k, v in doc.items()}
    if isinstance(doc, (list, tuple)):
        return [json_ready(v, decimals, key) for v in doc]
    if isinstance(doc, float) and math.isfinite(doc):
        places = decimals if decimals is not None else next((d for s, d in UNIT_DECIMALS if key.endswith(s)), None)
        value = round(doc, places) if places is not None else float(f"{doc:.12g}")
        return value + 0.0  # no -0.0
    return doc


def write_text(path: str | Path, text: str, what: str = "file") -> Path:
    """Write a UTF-8 text file atomically (temporary file, fsync, rename:
    :func:`areasearch.folderlock.write_atomic`); a file that already holds ``text`` is not written
    again. A failed write (file too large, disk full, read-only file system) leaves the file as it was,
    no temporary file, and raises one AreaSearchError naming the path and the reason."""
    return write_atomic(path, text.encode("utf-8"), what)


def run_report(main: Callable[[], int]) -> NoReturn:
    """Run a report script's ``main`` and exit with its status.

    A reader that stops early (``python scripts/run_health.py RUN | head``) closes the pipe; the
    script then ends quietly with status 1, as the ``areasearch`` command does, not with a
    ``BrokenPipeError`` traceback. Stdout is pointed at the null device so that the interpreter's
    final flush cannot raise again (the Python docs' note on SIGPIPE). A file the library refuses
    (:class:`~areasearch.errors.AreaSearchError`) ends the script with one ``error:`` line and status
    2, as it ends the ``areasearch`` command.
    """
    try:
        code = main()
        sys.stdout.flush()
    except AreaSearchError as exc:
        print(f"{Path(sys.argv[0]).name}: error: {' '.join(str(exc).split())}", file=sys.stderr)
        code = 2
    except BrokenPipeError:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        code = 1
    sys.exit(code)
