"""Train every learned policy with several seeds, one run after another, resumable across sessions.

    python scripts/train_campaign.py                 # train what is missing (resumes a killed run)
    python scripts/train_campaign.py --dry-run       # list the runs and where each stands
    python scripts/train_campaign.py --publish       # copy each run's logs to results/training/
    python scripts/train_campaign.py --compact       # shrink unfinished runs to move or commit them

The campaign that trains the learned policies under the ``paper`` protocol: ``dahgnn`` and ``ncm``
with seeds 0, 1, 2, the ablations ``dahgnn-no-type`` and ``dahgnn-no-history`` with seeds 0, 1, every
run with its config's decision budget (equal for all four configs). Every policy's first seed trains
first, so that a campaign stopped there has one comparable run of each; then the other seeds of the
policies with the most seeds, interleaved by seed (``dahgnn`` and ``ncm``, whose median seeds the paper's
claim compares and which are shipped), then the ablations' second seeds.
Each run is ``areasearch train --config configs/NAME.toml --set seed=S --out runs/NAME-sS``
(``--resume`` when the folder exists); a run is done when its ``selection.json`` exists (the final
checkpoint selection, docs/training.md), in its run folder or, once that folder is removed and its log
kept, in its published copy (``--results-dir``, below). Stdout and stderr of each run are appended to
``runs/NAME-sS.log``.

``--publish`` copies every finished run's logs (config.json, progress.csv, eval.csv, selection.json,
curve.png) and its chosen policy (policy.safetensors + policy.json, about 1 MB) to
``results/training/NAME-sS/``, so that every seed can be evaluated from a clean checkout
(``areasearch eval --policy dahgnn-s1=results/training/dahgnn-s1/policy``); the checkpoints, snapshots
and TensorBoard logs stay in the run folder, out of the repository. The test-split evaluation of the
policies is a separate ``areasearch eval`` command (docs/results.md).

``--evaluate DIR`` evaluates each finished run on the test split right after it, before the next run
trains: the run is published (as ``--publish``) and ``areasearch eval --methods NAME-sS --policy
NAME-sS=results/training/NAME-sS/policy --robots 3 4 5 --maps bundled:test --episodes 5 --seed 0 --out DIR``
plays its episodes beside every method already there (paired; resumable, so a killed evaluation goes on
where it stopped the next time the campaign runs). A run whose episodes are all in DIR already (same
settings and weights, :func:`evaluated`) is not evaluated again, so a campaign that resumes leaves the
logs of the runs it finished before as they were. ``python scripts/train_campaign.py --paper-budget
--evaluate results/paper-seeds`` is the whole paper-budget campaign, training and evaluation, in one
command that resumes.

``--compact`` makes every unfinished run small enough to move or commit (to resume it on another
machine or in another session): it removes the snapshots the run's final selection can no longer
choose, whatever the rest of the run does (:func:`~areasearch.training.validation.unchoosable_snapshots`:
a handful kept instead of one per validation, ~1 MB each), and refuses a run that is training. The
checkpoint, the logs and the TensorBoard folder stay.

``--table`` prints the finished runs (published to ``--results-dir``) as the rows of docs/training.md's
tables of runs: decisions; wall time (the time the run's processes ran, not the gaps between sessions),
decisions/s over it with its validations, the median iteration's decisions/s, the iterations' share of
the time, and the processes it took (``areasearch train`` commands in its log); the first and best
validation coverage AUC; the final selection's chosen checkpoint and the others' paired differences
with it (:func:`areasearch.training.figures.run_figures`).

``--variants`` does the same for the variants tried to clear the bar of the paper's claim
(:data:`VARIANTS`, ``configs/variants/NAME.toml``): ``python scripts/train_campaign.py --variants
[--publish]``; ``--paper-budget`` for the four policies at the paper's 300,000 decisions
(:data:`PAPER_BUDGET`, ``configs/paper-budget/NAME.toml``).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

from areasearch.errors import AreaSearchError

ROOT = Path(__file__).resolve().parent.parent
CAMPAIGN = {"dahgnn": (0, 1, 2), "ncm": (0, 1, 2), "dahgnn-no-type": (0, 1), "dahgnn-no-history": (0, 1)}
"""Policy (configs/NAME.toml) -> training seeds."""
VARIANTS = {
    "dahgnn-r3": (0, 1),
    "dahgnn-120k": (0, 1, 2),
    "ncm-120k": (0, 1, 2),
    "dahgnn-no-type-120k": (0, 1),
    "dahgnn-no-history-120k": (0, 1),
}
"""``--variants``: the variants tried to clear the bar of the paper's claim, each a config of
``configs/variants/NAME.toml``, NAME = ``<policy>-<change>``, that changes one setting of
``configs/<policy>.toml`` (:func:`base_policy`; docs/results.md, Variants) -> training seeds. ``ncm-120k``
gives NCM the decision budget of ``dahgnn-120k``, so that the two are compared at equal budgets; the
ablations' ``-120k`` variants do the same for Table 6."""


PAPER_BUDGET = {
    "dahgnn-300k": (0, 1, 2),
    "ncm-300k": (0, 1, 2),
    "dahgnn-no-type-300k": (0, 1),
    "dahgnn-no-history-300k": (0, 1),
}
"""``--paper-budget``: the four policies at the paper's budget of 300,000 decisions, each a config of
``configs/paper-budget/NAME.toml`` that changes four settings of ``configs/<policy>.toml``: the budget,
and three that make the run cheaper on two cores, ``ppo.shards = 2``, the candidates' distance
fields on 10 cm cells (``rollout.env.candidates.distance_cell_m = 0.1``) and a validation every 50
iterations (``evaluation.every``: as many validations as a 120,000-decision run's every 20) -> training seeds."""
PAPER_BUDGET_SETTINGS = frozenset(
    {"total_decisions", "ppo.shards", "rollout.env.candidates.distance_cell_m", "evaluation.every"}
)
"""The settings a ``--paper-budget`` config changes in its policy's config."""


def base_policy(variant: str) -> str:
    """The policy of :data:`CAMPAIGN` a variant is one setting away from: the longest one its name
    starts with (``dahgnn-120k`` -> ``dahgnn``, ``ncm-120k`` -> ``ncm``)."""
    bases = [p for p in CAMPAIGN if variant.startswith(p + "-")]
    if not bases:
        raise ValueError(f"variant {variant!r} does not start with a policy of CAMPAIGN ({', '.join(CAMPAIGN)})")
    return max(bases, key=len)


PUBLISHED = (
    "config.json", "progress.csv", "eval.csv", "selection.json", "curve.png", "policy.safetensors", "policy.json"
)  # fmt: skip


def runs(campaign: dict[str, tuple[int, ...]] = CAMPAIGN) -> list[tuple[str, int]]:
    """(policy, seed) in training order: each policy's first seed, by seed, then by policy; then the
    other seeds, the policies with more seeds first, by seed, then by policy."""
    order = list(campaign)

    def key(run: tuple[str, int]) -> tuple[int, int, int, int]:
        name, seed = run
        first = seed == min(campaign[name])
        return (0, 0, seed, order.index(name)) if first else (1, -len(campaign[name]), seed, order.index(name))

    return sorted(((name, seed) for name, have in campaign.items() for seed in have), key=key)


def published_only(folder: Path, results: Path) -> bool:
    """Whether the run of ``folder`` was trained here (its log is beside the folder), finished and
    published to ``results``, and its run folder removed since (no checkpoint there): nothing to train,
    nothing to publish. A published run that was never trained in this runs folder (a fresh clone's
    ``runs/``: no log) is not: it trains, so a campaign reproduces the published runs."""
    return (
        (folder.parent / f"{folder.name}.log").exists()
        and not (folder / "checkpoint.json").exists()
        and (results / folder.name / "selection.json").exists()
    )


def status(folder: Path, results: Path) -> str:
    published = published_only(folder, results)
    if published or (folder / "selection.json").exists():
        chosen = json.loads(((results if published else folder.parent) / folder.name / "selection.json").read_text())
        done = f"done (policy from {chosen.get('chosen_decisions', 0):,} decisions)"
        return f"{done}, published to {results / folder.name}" if published else done
    if (folder / "checkpoint.json").exists():
        state = json.loads((folder / "checkpoint.json").read_text())
        return f"started ({state.get('decisions', 0):,} decisions)"
    return "not started"


def publish(folder: Path, target: Path) -> None:
    """Copy a finished run's PUBLISHED files to target, each written under a temporary name and renamed
    (the weights before their JSON, as the trainer writes them), so an interrupted copy leaves no
    half-written file under a published name."""
    target.mkdir(parents=True, exist_ok=True)
    for file in PUBLISHED:
        if (folder / file).exists():
            tmp = target / f".{file}.tmp"
            shutil.copyfile(folder / file, tmp)
            os.replace(tmp, target / file)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs-dir", type=Path, default=ROOT / "runs")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--only", nargs="+", metavar="NAME-sS", help="only these runs (e.g. dahgnn-s1)")
    parser.add_argument("--dry-run", action="store_true", help="list the runs and their state; train nothing")
    parser.add_argument("--publish", action="store_true", help="copy runs' logs and policies to --results-dir")
    parser.add_argument("--results-dir", type=Path, default=ROOT / "results" / "training")
    parser.add_argument(
        "--compact", action="store_true", help="shrink unfinished runs to move or commit them; train nothing"
    )
    parser.add_argument("--table", action="store_true", help="print the finished runs as docs/training.md's rows")
    parser.add_argument(
        "--evaluate", type=Path, metavar="DIR", help="publish and evaluate each finished run on the test split into DIR"
    )
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--variants", action="store_true", help="the variants (configs/variants/) instead")
    group.add_argument(
        "--paper-budget", action="store_true", help="the policies at 300,000 decisions (configs/paper-budget/)"
    )
    args = parser.parse_args()
    folder_name, campaign = ("variants", VARIANTS) if args.variants else ("", CAMPAIGN)
    if args.paper_budget:
        folder_name, campaign = "paper-budget", PAPER_BUDGET
    configs = ROOT / "configs" / folder_name
    todo = [(n, s) for n, s in runs(campaign) if not args.only or f"{n}-s{s}" in args.only]
    if args.table:
        print(TABLE_HEADER)
        for name, seed in todo:
            if (args.results_dir / f"{name}-s{seed}" / "selection.json").exists():
                print(table_row(args.results_dir / f"{name}-s{seed}", args.runs_dir / f"{name}-s{seed}.log"))
        return 0
    for name, seed in todo:
        folder = args.runs_dir / f"{name}-s{seed}"
        if args.compact:
            if (folder / "checkpoint.json").exists() and not (folder / "selection.json").exists():
                try:
                    print(f"{folder.name:26s} {compact(folder)}")
                except AreaSearchError as error:  # a run that is training, an unreadable config or checkpoint
                    print(f"train_campaign: {error}", file=sys.stderr)
                    return 1
            continue
        if args.dry_run or args.publish:
            print(f"{folder.name:26s} {status(folder, args.results_dir)}")
            if args.publish and (folder / "selection.json").exists():  # finished runs only
                publish(folder, args.results_dir / folder.name)
            continue
        done = published_only(folder, args.results_dir)
        if not done and not (folder / "selection.json").exists():
            command = [sys.executable, "-m", "areasearch.cli", "train", "--config", str(configs / f"{name}.toml")]
            command += ["--set", f"seed={seed}", "--out", str(folder), "--workers", str(args.workers)]
            if (folder / "config.json").exists():
                command.append("--resume")
            args.runs_dir.mkdir(parents=True, exist_ok=True)
            code = logged_call(command, folder)
            if code != 0:
                print(f"train_campaign: {folder.name} exited with {code}; see {folder}.log", file=sys.stderr)
                return code
            print(f"{folder.name}: {status(folder, args.results_dir)}", flush=True)
        code = evaluate(folder, args.results_dir, args.evaluate, args.workers, not done) if args.evaluate else 0
        if code != 0:
            return code
    return 0


TABLE_HEADER = """\
| run | decisions | wall time | validation AUC: first → best | chosen checkpoint (final selection, 50 fresh episodes) |
|---|---:|---:|---|---|"""
"""The head of :func:`table_row`'s table."""


def table_row(published: Path, log: Path) -> str:
    """The row of docs/training.md's table of runs for the finished run published in ``published``,
    with its log ``log`` (the processes that trained it; left out without the log)."""
    from areasearch.training.figures import run_figures

    figures = run_figures(published)
    share = figures.iterations_share
    speed = [f"{figures.decisions / figures.wall_s:.1f} decisions/s with its {len(figures.validations)} validations"]
    if figures.median_rate is not None and share is not None:
        speed += [f"the median iteration {figures.median_rate:.1f}", f"iterations {100 * share:.0f} % of the time"]
    wall = f"{figures.wall_s / 60:.0f} min ({'; '.join(speed)})"
    if log.is_file():
        processes = sum(1 for line in log.read_text().splitlines() if line.startswith("== ") and " train " in line)
        wall += f", in {processes} process{'es' if processes != 1 else ''}"
    first, best = figures.validations[0], figures.best
    validation = f"{first.score:.2f} ({first.decisions:,}) → {best.score:.2f} ({best.decisions:,})"
    chosen = ""
    if figures.selection:
        finalists = figures.selection["finalists"]
        pick = next(f for f in finalists if f["decisions"] == figures.selection["chosen_decisions"])
        others = [
            f"{_signed(f['minus_chosen'])} ± {f['minus_chosen_ci95']:.2f} ({f['decisions']:,})"
            for f in finalists
            if f is not pick
        ]
        chosen = f"{pick['decisions']:,} decisions: {pick['final_score']:.2f}"
        chosen += f"; the others {' and '.join(others)}" if others else ""
    return f"| `{published.name}` | {figures.decisions:,} | {wall} | {validation} | {chosen} |"


def _signed(x: float) -> str:
    """``x`` with its sign and two decimals, a minus sign for a negative one (as the docs print it)."""
    return f"{x:+.2f}".replace("-", "\N{MINUS SIGN}")


def compact(folder: Path) -> str:
    """Remove the snapshots of the unfinished run in ``folder`` that its final selection can no longer
    choose (JSON first: a snapshot without it does not exist for the selection); say what is left.
    Holds the run folder meanwhile, so a run that is training is refused (FolderInUse)."""
    from areasearch.folderlock import hold_folder
    from areasearch.training.config import load_config
    from areasearch.training.runfolder import read_checkpoint
    from areasearch.training.validation import SNAPSHOTS, snapshot_name, unchoosable_snapshots

    with hold_folder(folder, "run folder"):
        config = load_config(folder / "config.json")
        iteration = read_checkpoint(folder, config.rollout.episodes)["iteration"]  # checked, as a resume checks it
        gone = unchoosable_snapshots(folder, config.evaluation.finalists, iteration)
        for decisions in gone:
            for suffix in (".json", ".safetensors"):
                (folder / SNAPSHOTS / f"{snapshot_name(decisions)}{suffix}").unlink(missing_ok=True)
        left = len(list((folder / SNAPSHOTS).glob("dec-*.json")))
        size = sum(f.stat().st_size for f in folder.rglob("*") if f.is_file())
    return f"{len(gone)} snapshots removed, {left} kept; {size / 1e6:.1f} MB"


def logged_call(command: list[str], folder: Path) -> int:
    """Run ``command`` with its output appended to the run's log (``<folder>.log``, after a ``==`` line naming it)."""
    with open(folder.parent / f"{folder.name}.log", "a") as log:
        print(f"== {' '.join(command)}", file=log, flush=True)
        return subprocess.call(command, stdout=log, stderr=subprocess.STDOUT)


EVAL_ROBOTS = (3, 4, 5)
"""Team sizes of ``--evaluate``'s test-split evaluation (the paper's)."""
EVAL_MAPS, EVAL_EPISODES, EVAL_SEED, EVAL_MAX_STEPS = "bundled:test", 5, 0, 3600
"""Its maps, episodes per (map, team size), run seed and horizon (``areasearch eval``'s default)."""


def eval_command(run: str, policy: Path, out: Path, workers: int) -> list[str]:
    """The ``areasearch eval`` of a finished run's published policy on the test split (paired, seed 0)."""
    command = [sys.executable, "-m", "areasearch.cli", "eval", "--methods", run, "--policy", f"{run}={policy}"]
    command += ["--robots", *map(str, EVAL_ROBOTS), "--maps", EVAL_MAPS, "--episodes", str(EVAL_EPISODES)]
    command += ["--seed", str(EVAL_SEED), "--max-steps", str(EVAL_MAX_STEPS)]
    return [*command, "--out", str(out), "--workers", str(workers)]


def evaluated(run: str, policy: Path, out: Path) -> bool:
    """Whether ``out`` holds every episode of :func:`eval_command`'s evaluation of ``run`` already, as
    ``areasearch eval`` would resume it (:func:`areasearch.harness.resume.prepare`, which writes nothing);
    AreaSearchError where the evaluation would be refused (other settings or weights in ``out``)."""
    from areasearch.harness.plan import EvalPlan
    from areasearch.harness.resume import prepare

    request = EvalPlan(
        methods=[run],
        robots=EVAL_ROBOTS,
        maps=[EVAL_MAPS],
        episodes=EVAL_EPISODES,
        seed=EVAL_SEED,
        max_steps=EVAL_MAX_STEPS,
        out=out,
        policies={run: str(policy)},
    )
    plan = prepare(request)
    return len(plan.done) == len(plan.plan)


def evaluate(folder: Path, results: Path, out: Path, workers: int, publishing: bool = True) -> int:
    """Publish the finished run in ``folder`` to ``results`` (unless ``publishing`` is False: published
    already) and evaluate its policy into ``out`` (what is already there is kept: the evaluation
    resumes); its output goes to the run's log."""
    if publishing:
        publish(folder, results / folder.name)
    else:
        try:
            if evaluated(folder.name, results / folder.name / "policy", out):
                print(f"{folder.name}: evaluated into {out} already", flush=True)
                return 0
        except AreaSearchError as error:  # the evaluation would be refused: it says why, in the log
            print(f"train_campaign: {error}", file=sys.stderr)
    code = logged_call(eval_command(folder.name, results / folder.name / "policy", out, workers), folder)
    if code != 0:
        print(f"train_campaign: evaluating {folder.name} exited with {code}; see {folder}.log", file=sys.stderr)
    else:
        print(f"{folder.name}: evaluated into {out}", flush=True)
    return code


if __name__ == "__main__":
    sys.exit(main())
