"""The front page tells the truth: its quick-start table is what the command prints, its links resolve."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("check_readme", ROOT / "scripts" / "check_readme.py")
assert _spec is not None and _spec.loader is not None
check_readme = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(check_readme)

PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def test_readme_table_matches_the_committed_command_output() -> None:
    assert check_readme.main(["--committed"]) == 0


@pytest.mark.slow
def test_readme_table_matches_what_the_quick_start_command_prints_now() -> None:
    assert check_readme.main([]) == 0


def test_a_changed_cell_is_named() -> None:
    table = "| method | Cover(%) |\n|---|---:|\n| dahgnn | 100.00 |\n| greedy | 99.00 |"
    assert check_readme.differences(table, table) == []
    changed = check_readme.differences(table, table.replace("99.00", "98.50"))
    assert changed == ["greedy / Cover(%): README 99.00, command 98.50"]
    assert check_readme.differences(table, table.rsplit("\n", 1)[0])  # a row missing


def test_readme_command_is_found() -> None:
    args = check_readme.readme_command((ROOT / "README.md").read_text())
    assert args[0] == "render" and "--methods" in args and "--out" in args


def test_readme_is_a_front_page() -> None:
    assert len((ROOT / "README.md").read_text().splitlines()) <= 260


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_relative_links_resolve(page: Path) -> None:
    text = page.read_text()
    text = re.sub(r"```.*?```", "", text, flags=re.S)  # code blocks hold commands, not links
    missing = []
    for target in re.findall(r"\]\(([^)\s]+)\)", text):
        if re.match(r"[a-z]+:", target) or target.startswith("#"):
            continue
        path = (page.parent / target.split("#", 1)[0]).resolve()
        if not path.exists():
            missing.append(target)
    assert not missing, f"{page.name}: links to missing files {missing}"
