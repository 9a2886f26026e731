"""Strict JSON for the files and printouts of the commands (NaN and infinities become ``null``), and
the check of a number read back from a user's or a log's JSON or TOML."""

from __future__ import annotations

import json
import math
import numbers
import os
from pathlib import Path
from typing import Any


def replace_text(path: Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` through a temporary file beside it and :func:`os.replace`, so a
    crash leaves the earlier file or the new one, never half of one.

    :param path: the file to write
    :param text: its new content
    """
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


def json_safe(obj: Any) -> Any:
    """NaN and infinities become ``null`` so the output is strict JSON.

    :param obj: a value made of dicts, lists, tuples and scalars
    :return: a copy with non-finite floats as ``None``, tuples as lists and dict keys as strings
    """
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    return obj


def finite_number(value: Any) -> float | None:
    """A value read from JSON or TOML as a float when it is a finite number (``true``/``false``,
    text, NaN and infinities are not), else ``None``.

    :param value: the value read
    :return: it as a float, or ``None``
    """
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        return None
    return float(value)


def whole_number(value: Any) -> int | None:
    """A value as an int when it is an integer (numpy's too; ``true``/``false`` are not), else ``None``.

    :param value: the value read
    :return: it as an int, or ``None``
    """
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        return None
    return int(value)


def positive_number(value: Any) -> float | None:
    """A value read as a positive finite number, or ``None``.

    :func:`finite_number`, when it is also > 0 (a duration, a frequency), else ``None``.

    :param value: the value read
    :return: it as a float, or ``None``
    """
    number = finite_number(value)
    return number if number is not None and number > 0 else None


def dump_json(obj: Any) -> str:
    """Strict, indented JSON (:func:`json_safe`).

    :param obj: a value made of dicts, lists, tuples and scalars
    :return: ``obj`` as strict, indented JSON
    """
    return json.dumps(json_safe(obj), indent=2, sort_keys=False, allow_nan=False)
