"""Every command the README and docs/*.md show in a ```bash block at least parses.

Each ``areasearch ...`` command goes through the real parser (``areasearch.cli.build_parser``);
each ``python scripts/X.py ...`` names an existing script and goes through that script's own argparse
(its ``main`` is called with ``parse_args`` stopped right after parsing, so nothing runs);
``bash scripts/X.sh`` names an existing script. Commands are read as the shell reads them: line
continuations joined, ``#`` comments dropped, ``&&`` / ``||`` / ``|`` / ``;`` separating commands,
``VAR=value`` prefixes, redirections, ``.venv/bin/`` prefixes and shell keywords (``for ... do``)
set aside.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import inspect
import io
import re
import shlex
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from areasearch.cli import build_parser

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
SHELL_BLOCK = re.compile(r"^```(?:bash|sh|shell|console)[ \t]*\n(.*?)^```", re.M | re.S)
SEPARATORS = {"&&", "||", "|", ";", "&"}
REDIRECTIONS = {">", ">>", "<", ">&", "&>", "2>", "2>>"}
KEYWORDS = {"do", "then", "else", "time", "!", "{", "exec"}
SKIPPED = {
    "done",
    "fi",
    "}",
    "mkdir",
    "cd",
    "cp",
    "ls",
    "cat",
    "head",
    "tail",
    "export",
    "source",
    "pip",
    "git",
    "curl",
}
"""Commands that are not areasearch's (the shell's own, file and HTTP tools): not checked."""
SCRIPT_FOLDERS = ("scripts/", "benchmarks/")
"""Where the Python scripts the docs run live; each is checked with its own argparse."""


@dataclass(frozen=True)
class Command:
    page: str
    line: int
    words: tuple[str, ...]

    def __str__(self) -> str:
        return f"{self.page}:{self.line}: {shlex.join(self.words)}"


def split_commands(block: str) -> list[tuple[int, list[str]]]:
    """The simple commands of a shell block, with the block line each starts on."""
    out: list[tuple[int, list[str]]] = []
    lines = block.split("\n")
    k = 0
    while k < len(lines):
        start, text = k, lines[k]
        while text.endswith("\\") and k + 1 < len(lines):  # a line continuation
            k += 1
            text = text[:-1] + " " + lines[k]
        k += 1
        text = re.sub(r"^\s*\$ ", "", text)  # a console prompt
        text = re.sub(r"^\s*\w+\(\)\s*\{", "", text)  # a shell function's head: its body is checked
        text = re.sub(r"\$\([^()]*\)", "SUBSTITUTED", text)  # $(command): one word here
        text = re.sub(r"(^|\s)\d(>>?|<)", r"\1\2", text)  # `2> log`: the descriptor is no argument
        lexer = shlex.shlex(text, posix=True, punctuation_chars=True)
        lexer.whitespace_split = True
        words: list[str] = []
        tokens = list(lexer)
        i = 0
        while i < len(tokens):
            token = tokens[i]
            if token in SEPARATORS:
                out.append((start, words))
                words = []
            elif token in REDIRECTIONS:
                i += 1  # and the file
            else:
                words.append(token)
            i += 1
        out.append((start, words))
    return [(line, words) for line, words in out if words]


def strip_prefixes(words: list[str]) -> list[str]:
    """The command without environment assignments and shell keywords before it."""
    while words and (words[0] in KEYWORDS or re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*=.*", words[0])):
        words = words[1:]
    return words


def doc_commands() -> list[Command]:
    found = []
    for page in PAGES:
        text = page.read_text()
        for block in SHELL_BLOCK.finditer(text):
            first = text.count("\n", 0, block.start(1)) + 1
            for line, words in split_commands(block.group(1)):
                words = strip_prefixes(words)
                if words and words[0] not in SKIPPED and not words[0].startswith("for"):
                    found.append(Command(str(page.relative_to(ROOT)), first + line, tuple(words)))
    return found


COMMANDS = doc_commands()


def _program(word: str) -> str:
    """``areasearch`` for ``.venv/bin/areasearch``, ``python`` for ``.venv/bin/python3``."""
    name = word.removeprefix(".venv/bin/")
    return "python" if re.fullmatch(r"python(3(\.\d+)?)?", name) else name


class _Parsed(Exception):
    """Raised by the patched ``parse_args`` once a script's command line has parsed."""


def parse_script(script: Path, args: list[str], monkeypatch: pytest.MonkeyPatch) -> None:
    """Run ``script``'s ``main`` on ``args`` up to its ``parse_args``: a SystemExit (argparse's usage
    error) fails, a successful parse stops it there."""
    spec = importlib.util.spec_from_file_location(f"docscript_{script.stem}", script)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)  # dataclasses look their module up there
    spec.loader.exec_module(module)
    assert "argparse" in script.read_text(), f"{script.name}: no argparse parser to check the command with"
    original = argparse.ArgumentParser.parse_args

    def parse_args(self: argparse.ArgumentParser, *a: Any, **k: Any) -> Any:
        original(self, *a, **k)
        raise _Parsed

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", parse_args)
    monkeypatch.setattr(sys, "argv", [str(script), *args])
    main = module.main
    takes_argv = any(p.default is inspect.Parameter.empty for p in inspect.signature(main).parameters.values())
    with pytest.raises(_Parsed):
        main(args) if takes_argv else main()


def test_the_docs_show_commands() -> None:
    programs = {_program(c.words[0]) for c in COMMANDS}
    assert {"areasearch", "python", "bash"} <= programs, programs
    assert len(COMMANDS) > 40


@pytest.mark.parametrize("command", COMMANDS, ids=str)
def test_every_doc_command_parses(command: Command, monkeypatch: pytest.MonkeyPatch) -> None:
    program, args = _program(command.words[0]), list(command.words[1:])
    if program == "areasearch":
        err = io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            try:
                build_parser().parse_args(args)
            except SystemExit as exc:  # --help / --version exit 0; a usage error exits 2
                assert exc.code == 0, f"{command}\n{err.getvalue()}"
    elif program == "python":
        if args[:2] == ["-m", "areasearch.cli"]:
            build_parser().parse_args(args[2:])
            return
        if args and args[0] == "-m":  # another module (pytest): it must be installed
            assert importlib.util.find_spec(args[1]) is not None, f"{command}: no module {args[1]}"
            return
        if args and args[0] == "-c":  # a one-line program: nothing to parse
            return
        assert args and args[0].startswith(SCRIPT_FOLDERS) and args[0].endswith(".py"), str(command)
        script = ROOT / args[0]
        assert script.is_file(), f"{command}: no such script"
        with contextlib.redirect_stderr(io.StringIO()) as err:
            try:
                parse_script(script, args[1:], monkeypatch)
            except SystemExit as exc:
                pytest.fail(f"{command}: exit {exc.code}\n{err.getvalue()}")
    elif program == "bash":
        assert args and (ROOT / args[0]).is_file(), f"{command}: no such script"
    else:
        pytest.fail(f"{command}: neither areasearch, python scripts/... nor bash scripts/...; add it to SKIPPED")


@pytest.mark.parametrize(
    ("block", "expected"),
    [
        ("areasearch maps --size small   # the small ones\n", [["areasearch", "maps", "--size", "small"]]),
        ("a --x 1 \\\n    --y 2 && b | c; d 2> log\n", [["a", "--x", "1", "--y", "2"], ["b"], ["c"], ["d"]]),
        ("b --n 1500 > out.md\n", [["b", "--n", "1500"]]),
        (
            "f() { a --json | b; }\nc --maps $(f x) --n 1\n",
            [["a", "--json"], ["b"], ["}"], ["c", "--maps", "SUBSTITUTED", "--n", "1"]],
        ),
        ("$ areasearch run --out 'a b.png'\n", [["areasearch", "run", "--out", "a b.png"]]),
    ],
)
def test_blocks_split_as_the_shell_splits_them(block: str, expected: list[list[str]]) -> None:
    assert [words for _, words in split_commands(block)] == expected


def test_a_command_that_does_not_parse_is_caught() -> None:
    with pytest.raises(SystemExit), contextlib.redirect_stderr(io.StringIO()):
        build_parser().parse_args(["eval", "--methods", "greedy", "--robots", "3", "--out"])


def _readme_eval_with_policy() -> list[str]:
    """The README's ``areasearch eval ... --policy ...`` command (the arguments after ``areasearch``)."""
    for command in COMMANDS:
        if command.page == "README.md" and command.words[:2] == ("areasearch", "eval") and "--policy" in command.words:
            return list(command.words[1:])
    raise AssertionError("README.md: no `areasearch eval --policy` command")


KEPT = ("README.md", "config.json", "curves.jsonl", "episodes.csv", "policies.json")
"""The files of results/paper-seeds under version control (its summaries are ignored: .gitignore)."""


@pytest.mark.slow
def test_rerunning_the_readme_eval_command_rewrites_no_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Every episode of the command is in the folder already: it only summarises, and the folder's
    kept files stay byte-identical (the weights' path is recorded once, the rows are not rewritten)."""
    import shutil

    from areasearch.cli import main

    args = _readme_eval_with_policy()
    out = args.index("--out") + 1
    source = ROOT / args[out]
    copy = tmp_path / "results"
    shutil.copytree(source, copy)
    monkeypatch.chdir(ROOT)  # the command's paths are relative to the repository
    policy = args.index("--policy") + 1
    name, _, prefix = args[policy].partition("=")
    # as written, then from the weights' absolute path: the same weights, recorded once
    for given in (prefix, str(ROOT / prefix)):
        rerun = [*args[:policy], f"{name}={given}", *args[policy + 1 :]]
        assert main([*rerun[:out], str(copy), *rerun[out + 1 :]]) == 0
        assert "eval: " not in capsys.readouterr().err  # nothing played
        for kept in KEPT:
            assert (copy / kept).read_bytes() == (source / kept).read_bytes(), (kept, given)
