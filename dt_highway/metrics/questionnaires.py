"""Where a trial's questionnaire answers are kept, and their reader (the report's, the session's): the
forms that ask them are :mod:`dt_highway.hmi.questionnaire`'s."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

RESULTS_FILE = "questionnaires.json"
"""The file a trial's answers go to, in the trial's directory"""


def read_results(trial_dir: str | Path) -> dict[str, Any] | None:
    """A trial's questionnaire results (:data:`RESULTS_FILE`), or ``None`` when it has none or it
    cannot be read.

    :param trial_dir: the trial's directory
    :return: the results, or ``None``
    """
    p = Path(trial_dir) / RESULTS_FILE
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None
