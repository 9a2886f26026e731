"""Strict JSON for the files and printouts of the commands (NaN and infinities become ``null``)."""

from __future__ import annotations

import json
import math
from typing import Any


def json_safe(obj: Any) -> Any:
    """NaN and infinities become ``null`` so the output is strict JSON."""
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    return obj


def dump_json(obj: Any) -> str:
    """:return: ``obj`` as strict, indented JSON."""
    return json.dumps(json_safe(obj), indent=2, sort_keys=False, allow_nan=False)
