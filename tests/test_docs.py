"""The documentation: the MkDocs site builds with ``--strict`` (no broken link or anchor, no
docstring the API reference cannot render, every page built), and every ``dt-highway`` command
that README.md and the pages under docs/ show in a code block, or write in the text with an option
(synopses with placeholders aside), still parses."""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from dt_highway.cli import build_parser, main

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs"
FENCE = re.compile(r"^[ \t]*```([^\n`]*)\n(.*?)^[ \t]*```", re.M | re.S)
SHELL_LANGS = {"bash", "sh", "shell", "console"}
ENV_ASSIGNMENT = re.compile(r"[A-Za-z_][A-Za-z0-9_]*=\S*$")


def doc_files() -> list[Path]:
    """README.md and every Markdown page of the site (not the build hooks)."""
    return [REPO / "README.md", *sorted(p for p in DOCS.rglob("*.md") if "_hooks" not in p.parts)]


def commands_in(text: str) -> list[list[str]]:
    """The ``dt-highway`` commands of a Markdown text's code blocks, as argument lists.

    In bash/sh/shell/console blocks every line is a command (backslash continuations joined,
    ``#`` comments dropped, ``&&``/``;``/``|`` separating commands, leading ``VAR=value``
    assignments skipped); in other blocks only lines with a ``$ `` prompt are.

    :return: one list of words per command, starting with ``dt-highway``
    """
    found: list[list[str]] = []
    for lang, body in FENCE.findall(text):
        shell = lang.strip().lower() in SHELL_LANGS
        lines = body.replace("\\\n", " ").splitlines()
        for line in lines:
            line = line.strip()
            if line.startswith("$ "):
                line = line[2:]
            elif not shell:
                continue
            words = shlex.split(line, comments=True)
            command: list[str] = []
            for word in [*words, ";"]:
                if word in ("&&", ";", "|", "||"):
                    if command and command[0] == "dt-highway":
                        found.append(command)
                    command = []
                elif command or not ENV_ASSIGNMENT.match(word):
                    command.append(word)
    return found


def subcommand_path(words: list[str]) -> list[str]:
    """The leading words of ``dt-highway ...`` that name a command and its sub-commands."""
    parser: argparse.ArgumentParser = build_parser()
    path: list[str] = []
    for word in words[1:]:
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs or word not in subs[0].choices:
            break
        parser = subs[0].choices[word]
        path.append(word)
    return path


def all_commands() -> list[tuple[str, list[str]]]:
    return [(f"{p.relative_to(REPO)}: {shlex.join(c)}", c) for p in doc_files() for c in commands_in(p.read_text())]


def test_command_extraction() -> None:
    text = (
        "```bash\n"
        "python -m pip install -e . && SDL_VIDEODRIVER=offscreen dt-highway study --quick\n"
        "SDL_VIDEODRIVER=offscreen dt-highway drive --participant demo \\\n"
        "    --out runs/demo  # a comment\n"
        "printf 'dt-highway is not a command here'\n"
        "```\n"
        "```\n"
        "$ dt-highway twin-eval --set a.b=-1\n"
        "dt-highway twin-eval: error: not a command (output)\n"
        "```\n"
        "```python\n"
        "subprocess.run(['dt-highway', 'run'])\n"
        "```\n"
    )
    assert commands_in(text) == [
        ["dt-highway", "study", "--quick"],
        ["dt-highway", "drive", "--participant", "demo", "--out", "runs/demo"],
        ["dt-highway", "twin-eval", "--set", "a.b=-1"],
    ]
    assert subcommand_path(["dt-highway", "detector", "eval", "--frames", "5"]) == ["detector", "eval"]
    assert subcommand_path(["dt-highway", "report", "runs/x"]) == ["report"]


def test_docs_show_commands() -> None:
    """The extraction finds the commands the pages show (guards against a regex that finds none)."""
    commands = all_commands()
    assert len(commands) >= 20, commands
    shown = {" ".join(subcommand_path(c)) for _, c in commands}
    assert {"study", "report", "drive", "session", "train", "evaluate", "matching", "twin-eval"} <= shown


@pytest.mark.parametrize("where,words", all_commands(), ids=lambda v: v if isinstance(v, str) else "")
def test_documented_command_parses(where: str, words: list[str]) -> None:
    """Its sub-command's ``--help`` exits 0, and the whole command line parses (options and
    choices exist; nothing is run)."""
    path = subcommand_path(words)
    assert path, f"{where}: names no dt-highway command"
    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit) as exit_help:
        main([*path, "--help"])
    assert exit_help.value.code == 0, f"{where}: --help exited {exit_help.value.code}"
    assert "usage: dt-highway " + " ".join(path) in out.getvalue()
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        try:
            build_parser().parse_args(words[1:])
        except SystemExit as exc:
            pytest.fail(f"{where}: does not parse (exit {exc.code}): {err.getvalue().strip()}")


INLINE = re.compile(r"`(dt-highway [^`]+)`")
PLACEHOLDER = re.compile(r"^\[|^(?:[A-Z]+|[A-Z]x[A-Z])$")  # a synopsis: [--every K], N, DIR, WxH


def inline_commands() -> list[tuple[str, list[str]]]:
    """The ``dt-highway ...`` commands written in the pages' text (not code blocks) with an
    option, other than synopses with placeholders (``--frames N``, ``[--sweep]``)."""
    found = []
    for p in doc_files():
        text = FENCE.sub("", p.read_text()).replace("\n", " ")
        for span in INLINE.findall(text):
            words = shlex.split(span)
            if any(w.startswith("--") for w in words) and not any(PLACEHOLDER.match(w) for w in words):
                found.append((f"{p.relative_to(REPO)}: {span}", words))
    return found


def test_inline_commands_are_found() -> None:
    assert len(inline_commands()) >= 30  # guards against a pattern that finds none


@pytest.mark.parametrize("where,words", inline_commands(), ids=lambda v: v if isinstance(v, str) else "")
def test_inline_command_parses(where: str, words: list[str]) -> None:
    """A command written in the text parses as a whole (its required options are there): a reader
    copies these as they are."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            build_parser().parse_args(words[1:])
        except SystemExit as exc:
            if exc.code:  # 0: a --help
                pytest.fail(f"{where}: does not parse (exit {exc.code}): {err.getvalue().strip()}")


def test_console_script_help() -> None:
    proc = subprocess.run(["dt-highway", "--help"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    for command in ("study", "report", "drive", "train"):
        assert f"    {command} " in proc.stdout


def test_site_builds_strictly(tmp_path: Path) -> None:
    site = tmp_path / "site"
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1", "SDL_VIDEODRIVER": "offscreen", "MPLBACKEND": "Agg"}
    proc = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file", str(REPO / "mkdocs.yml"),
         "--site-dir", str(site)],
        cwd=REPO, capture_output=True, text=True, timeout=600, env=env,
    )
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-4000:]
    pages = [p for p in doc_files() if p.parent != REPO]
    for page in pages:
        rel = page.relative_to(DOCS).with_suffix("")
        html = site / (rel.parent if rel.name == "index" else rel) / "index.html"
        assert html.is_file(), f"{page.relative_to(REPO)} was not built"
        assert "<!-- generated:" not in html.read_text(), f"{html}: a generated section was left unfilled"
    api = (site / "api" / "metrics" / "index.html").read_text()
    assert 'id="dt_highway.metrics.safety.trial_metrics"' in api  # the reference holds the functions
    config = (site / "guide" / "configuration" / "index.html").read_text()
    assert "<code>noise_sigma_m</code>" in config  # the generated table of every key
    commands = (site / "guide" / "commands" / "index.html").read_text()
    assert "usage: dt-highway study" in commands  # the generated --help of every command


def test_readme_quick_start_is_what_ci_runs() -> None:
    """README's Quick start holds exactly two commands (fresh-check runs both), and CI runs the
    second as written."""
    text = (REPO / "README.md").read_text()
    section = re.search(r"^##\s+Quick start\s*$(.*?)(?=^##\s|\Z)", text, re.M | re.S)
    assert section, "README.md has no '## Quick start' section"
    blocks = [body for _, body in FENCE.findall(section.group(1))]
    assert len(blocks) == 2, blocks
    assert blocks[1].strip() in (REPO / ".ci" / "run").read_text().splitlines()
    assert "runs/quick-study/report.html" in section.group(1)  # it says which file to open


def test_readme_lists_every_command() -> None:
    """The README's table of commands has a row for each command ``dt-highway --help`` lists."""
    listed = set(re.findall(r"^\| `dt-highway ([a-z-]+)", (REPO / "README.md").read_text(), re.M))
    subs = [a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction)]
    assert listed == set(subs[0].choices)
