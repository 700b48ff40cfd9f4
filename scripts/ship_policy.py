"""Ship a trained policy in the package: copy a run's best policy to src/areasearch/policies/NAME.*
and write its card (NAME.md: the config, the command, training length, wall time and the share of it in
iterations, the median training speed, validation score).

    python scripts/ship_policy.py runs/dahgnn dahgnn
    python scripts/ship_policy.py runs/dahgnn-s2 dahgnn --why "the median of 3 training seeds on the test split"
    python scripts/ship_policy.py runs/dahgnn-120k-s2 dahgnn --config configs/variants/dahgnn-120k.toml

``--config`` names the config the run was trained with, for the card's command (default
``configs/NAME.toml``). RUN is a run folder or its published copy (``results/training/<run>/``, what
``scripts/train_campaign.py --publish`` keeps of a run: without its checkpoint, the counters of the card
come from the last row of its ``progress.csv``).

NAME must be one of areasearch.planners.SHIPPED_POLICIES; once copied, ``--methods NAME`` works in
``areasearch eval``, ``render`` and ``assign``. The weights are checked (loaded without unpickling)
before anything is written; every file is written atomically.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

from areasearch.errors import ConfigError
from areasearch.models.weights import load_policy
from areasearch.planners import POLICY_DIR, SHIPPED_POLICIES
from areasearch.training.figures import RunFigures, run_figures


def _atomic_write(path: Path, data: bytes) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _time_shares(figures: RunFigures) -> str:
    """`` (iterations N %, the rest M %)``: the share of the run's wall time its iterations (rollouts and
    updates) took; the rest is validations, checkpoints and whatever else held the run (a machine shared
    with other work, a paused process). Empty without ``progress.csv``."""
    share = figures.iterations_share
    if share is None:
        return ""
    return f" (iterations {100 * share:.0f} %; validations, checkpoints and the rest {100 * (1 - share):.0f} %)"


def _speed_row(figures: RunFigures) -> list[str]:
    """The card's row of training speed: the median of its iterations' decisions/s (rollout and update),
    which a pause or a busy moment of the machine moves less than the wall time."""
    if figures.median_rate is None:
        return []
    return [f"| training speed | {figures.median_rate:.1f} decisions/s (median over its iterations) |"]


def ship(run: Path, name: str, into: Path = POLICY_DIR, why: str = "", config_file: str = "") -> list[Path]:
    if name not in SHIPPED_POLICIES:
        raise ConfigError(f"policy name must be one of {', '.join(SHIPPED_POLICIES)}, got {name!r}")
    for file in ("config.json", "eval.csv", "policy.safetensors", "policy.json"):
        if not (run / file).is_file():
            raise ConfigError(f"{run}: no {file}; is this a finished 'areasearch train' run folder?")
    load_policy(run / "policy")  # raises ConfigError naming the file when it is damaged
    figures = run_figures(run)
    config = json.loads((run / "config.json").read_text())
    best, first, selection = figures.best, figures.validations[0], figures.selection
    into.mkdir(parents=True, exist_ok=True)
    written = []
    for suffix in (".safetensors", ".json"):
        target = into / f"{name}{suffix}"
        _atomic_write(target, (run / f"policy{suffix}").read_bytes())
        written.append(target)
    config_file = config_file or f"configs/{name}.toml"
    card = [
        f"# Shipped policy `{name}`",
        "",
        f"Trained by `areasearch train --config {config_file} --set seed={config.get('seed')} --out "
        f"runs/{run.name}` (resolved config: `runs/{run.name}/config.json`), on the training maps of `bundled:train`",
        "and procedural layouts; selected by the mean Cover % over the horizon (coverage AUC) on `bundled:val`.",
        "",
        "| | |",
        "|---|---|",
        f"| iterations | {figures.iteration} |",
        f"| decisions | {figures.decisions:,} |",
        f"| episodes | {figures.episodes:,} |",
        f"| wall time | {figures.wall_s / 60:.1f} min{_time_shares(figures)} |",
        *_speed_row(figures),
        f"| best validation coverage AUC | {best.score:.2f} "
        f"(iteration {best.iteration}, {best.decisions:,} decisions) |",
        f"| first validation coverage AUC | {first.score:.2f} (iteration {first.iteration}) |",
        "",
    ]
    if selection:
        card += [
            f"Shipped: the policy of {selection['chosen_decisions']:,} decisions, chosen by the final selection "
            f"({selection['rule']}; {selection['episodes']} episodes each):",
            "",
            "| decisions | validation | smoothed | final | minus the chosen |",
            "|---:|---:|---:|---:|---:|",
        ]
        for f in selection["finalists"]:
            card.append(
                f"| {f['decisions']:,} | {f['validation_score']:.2f} | {f['smoothed_score']:.2f} | "
                f"{f['final_score']:.2f} ± {f['final_ci95']:.2f} | "
                f"{f['minus_chosen']:+.2f} ± {f['minus_chosen_ci95']:.2f} |"
            )
        card.append("")
    if why:
        card += [f"Why this run: {why}", ""]
    target = into / f"{name}.md"
    _atomic_write(target, ("\n".join(card)).encode())
    written.append(target)
    return written


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path, help="run folder of areasearch train, or its published copy")
    parser.add_argument("name", help=f"policy name: {', '.join(SHIPPED_POLICIES)}")
    parser.add_argument("--into", type=Path, default=POLICY_DIR, help="policy folder (default: the package's)")
    parser.add_argument("--config", default="", help="the config the run was trained with (default configs/NAME.toml)")
    parser.add_argument("--why", default="", help="why this run (of several seeds) is the one shipped, for the card")
    args = parser.parse_args()
    try:
        for path in ship(args.run, args.name, args.into, args.why, args.config):
            print(path)
    except (ConfigError, OSError, ValueError, KeyError) as error:
        print(f"ship_policy: error: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
