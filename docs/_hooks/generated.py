"""MkDocs hook: pages that are generated from the code, so that they cannot go stale.

A page holds a marker comment and the hook replaces it with text made from the package:

* ``<!-- generated: configuration -->``: every key of the configuration tree
  (:class:`dt_highway.config.DTConfig`), one table per section, with its default, its allowed
  values (the pydantic bounds and choices) and its description;
* ``<!-- generated: step-columns -->``: the columns of a trial's ``steps.csv``
  (:data:`dt_highway.metrics.trial_log.STEP_COLUMNS`);
* ``<!-- generated: commands -->``: the ``--help`` of every ``dt-highway`` command and
  sub-command, as argparse prints it (:func:`dt_highway.cli.build_parser`).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import typing
from typing import Any

CONFIG_MARK = "<!-- generated: configuration -->"
COMMANDS_MARK = "<!-- generated: commands -->"
STEP_COLUMNS_MARK = "<!-- generated: step-columns -->"


def _bounds(info: Any) -> str:
    parts = []
    for m in info.metadata:
        for attr, sign in (("ge", ">="), ("gt", ">"), ("le", "<="), ("lt", "<")):
            value = getattr(m, attr, None)
            if value is not None:
                parts.append(f"{sign} {value}")
    literal = [a for a in typing.get_args(info.annotation) if not isinstance(a, type)]
    if typing.get_origin(info.annotation) is typing.Literal:
        parts.append(" / ".join(f"`{v}`" for v in typing.get_args(info.annotation)))
    elif literal and all(isinstance(a, str) for a in literal):
        parts.append(" / ".join(f"`{v}`" for v in literal))
    return ", ".join(parts)


def _show(value: Any) -> str:
    if hasattr(value, "model_dump"):
        value = value.model_dump(mode="json")
    if isinstance(value, float) and math.isfinite(value) and value == int(value) and abs(value) < 1e15:
        text = str(value)
    else:
        text = json.dumps(value, default=str)
    return f"`{text}`".replace("|", "\\|")


def _section(model: Any, path: str, out: list[str]) -> None:
    from pydantic import BaseModel

    fields = type(model).model_fields
    rows, nested = [], []
    for name, info in fields.items():
        value = getattr(model, name)
        if isinstance(value, BaseModel) and not isinstance(info.annotation, type(None)):
            nested.append((name, value))
            continue
        doc = (info.description or "").replace("|", "\\|").replace("\n", " ")
        rows.append(f"| `{name}` | {_show(value)} | {_bounds(info)} | {doc} |")
    out.append(f"{'#' * (2 + path.count('.') + 1)} `{path}`\n")
    doc = (type(model).__doc__ or "").strip().split("\n\n")[0].replace("\n", " ")
    if doc:
        out.append(doc.replace(":class:", "").replace(":mod:", "").replace(":func:", "") + "\n")
    if rows:
        out += ["| key | default | allowed | what [unit] |", "|---|---|---|---|", *rows, ""]
    for name, value in nested:
        _section(value, f"{path}.{name}", out)


def configuration_reference() -> str:
    """:return: Markdown: one table per section of the default configuration tree."""
    from dt_highway.config import DTConfig

    root = DTConfig()
    out: list[str] = []
    for name in type(root).model_fields:
        _section(getattr(root, name), name, out)
    return "\n".join(out)


def _walk(parser: argparse.ArgumentParser, path: list[str], out: list[str]) -> None:
    out += [f"### `{' '.join(path)}`\n", "```text", parser.format_help().rstrip(), "```", ""]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                _walk(sub, [*path, name], out)


def commands_reference() -> str:
    """:return: Markdown: the ``--help`` of every command and sub-command."""
    from dt_highway.cli import build_parser

    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "100"
    try:
        out: list[str] = []
        _walk(build_parser(), ["dt-highway"], out)
    finally:
        if old is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = old
    return "\n".join(out)


def on_page_markdown(markdown: str, **kwargs: Any) -> str:
    """MkDocs event: fill the markers of a page."""
    if CONFIG_MARK in markdown:
        markdown = markdown.replace(CONFIG_MARK, configuration_reference())
    if STEP_COLUMNS_MARK in markdown:
        from dt_highway.metrics.trial_log import STEP_COLUMNS

        markdown = markdown.replace(STEP_COLUMNS_MARK, ", ".join(f"`{c}`" for c in STEP_COLUMNS) + ".")
    if COMMANDS_MARK in markdown:
        markdown = markdown.replace(COMMANDS_MARK, commands_reference())
    return markdown
