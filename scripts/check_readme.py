"""Check that README.md's quick-start table is what the quick-start command prints.

The README shows the first quick-start command (``areasearch render --methods ...``) and, between the
markers ``<!-- quickstart-table:start -->`` and ``<!-- quickstart-table:end -->``, the table that
command prints. This script finds that command in the README, runs it (in a temporary folder, with
the README's own arguments) and compares the table it prints with the README's, cell by cell.

    python scripts/check_readme.py             # run the command; exit 1 naming the cells that differ
    python scripts/check_readme.py --committed # no run: compare with docs/search-dahgnn-greedy.md,
                                               # the committed output of the same command
    python scripts/check_readme.py --write     # run it and write the new table into README.md, and
                                               # its outputs to docs/search-dahgnn-greedy.{md,png}

The test suite runs the first form (a slow test, about a minute) and the second (instant).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import re
import shlex
import shutil
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS_TABLE = ROOT / "docs" / "search-dahgnn-greedy.md"
DOCS_PICTURE = ROOT / "docs" / "search-dahgnn-greedy.png"
START, END = "<!-- quickstart-table:start -->", "<!-- quickstart-table:end -->"


def readme_command(text: str) -> list[str]:
    """The arguments of the README's quick-start ``areasearch render`` command (after ``areasearch``)."""
    for line in text.splitlines():
        if "areasearch render" in line and not line.lstrip().startswith("#"):
            words = shlex.split(line.split("areasearch render", 1)[1])
            return ["render", *words]
    raise SystemExit("README.md: no quick-start `areasearch render` command found")


def readme_table(text: str) -> str:
    """The table between the quick-start markers."""
    if START not in text or END not in text:
        raise SystemExit(f"README.md: markers {START} / {END} not found")
    return text.split(START, 1)[1].split(END, 1)[0].strip()


def table_rows(table: str) -> list[list[str]]:
    """Rows of a Markdown table (the separator row left out), cells stripped."""
    rows = []
    for line in table.strip().splitlines():
        if not line.startswith("|") or re.fullmatch(r"[|\s:-]+", line):
            continue
        rows.append([cell.strip() for cell in line.strip().strip("|").split("|")])
    return rows


def differences(expected: str, actual: str) -> list[str]:
    """One line per cell that differs (README value -> command value)."""
    want, got = table_rows(expected), table_rows(actual)
    if len(want) != len(got):
        return [f"the README's table has {len(want)} rows, the command printed {len(got)}"]
    header = got[0]
    out = []
    for w, g in zip(want, got, strict=True):
        if len(w) != len(g):
            out.append(f"row {g[0]!r}: {len(w)} columns in the README, {len(g)} printed")
            continue
        for name, a, b in zip(header, w, g, strict=True):
            if a != b:
                out.append(f"{g[0]} / {name}: README {a}, command {b}")
    return out


def run_command(args: list[str], folder: Path) -> str:
    """Run ``areasearch ARGS`` in-process with ``--out`` inside ``folder``; its printed table."""
    from areasearch.cli import main

    out = args.index("--out")
    args = [*args[: out + 1], str(folder / Path(args[out + 1]).name), *args[out + 2 :]]
    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        status = main(args)
    if status != 0:
        raise SystemExit(f"areasearch {' '.join(args)} exited with {status}")
    printed = buffer.getvalue()
    return printed.split("\n\n", 1)[0].strip()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--committed", action="store_true", help="compare with docs/search-dahgnn-greedy.md only")
    mode.add_argument("--write", action="store_true", help="regenerate the README table and the docs outputs")
    opts = parser.parse_args(argv)
    text = README.read_text()
    expected = readme_table(text)
    if opts.committed:
        actual = DOCS_TABLE.read_text().split("\n\n", 1)[1].strip()
        source = str(DOCS_TABLE.relative_to(ROOT))
    else:
        args = readme_command(text)
        with tempfile.TemporaryDirectory() as tmp:
            actual = run_command(args, Path(tmp))
            if opts.write:
                stem = Path(args[args.index("--out") + 1]).stem
                shutil.copyfile(Path(tmp) / f"{stem}.md", DOCS_TABLE)
                shutil.copyfile(Path(tmp) / f"{stem}.png", DOCS_PICTURE)
        source = "the quick-start command"
    if opts.write:
        README.write_text(text.replace(expected, actual, 1))
        print(f"README.md: quick-start table rewritten; {DOCS_TABLE.name} and {DOCS_PICTURE.name} updated")
        return 0
    diff = differences(expected, actual)
    if diff:
        print(f"README.md's quick-start table disagrees with {source}:", file=sys.stderr)
        for line in diff:
            print(f"  {line}", file=sys.stderr)
        print("regenerate it: python scripts/check_readme.py --write", file=sys.stderr)
        return 1
    print(f"README.md's quick-start table matches {source}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
