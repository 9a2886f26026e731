"""Static checks in the test run, as CI runs it: ruff (lint) and mypy (types).

Both read their settings from ``pyproject.toml`` (``[tool.ruff]``, ``[tool.mypy]``) and come
with the ``test`` extra (``pip install -e ".[test]"``). A failure shows the tools' own report.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", *args], cwd=ROOT, capture_output=True, text=True, timeout=900)


def test_ruff() -> None:
    result = _run("ruff", "check", "--no-fix", "dt_highway", "tests", "notebooks")
    assert result.returncode == 0, f"ruff check dt_highway tests notebooks:\n{result.stdout}{result.stderr}"


def test_mypy() -> None:
    result = _run("mypy")  # the package and the settings: [tool.mypy] in pyproject.toml
    assert result.returncode == 0, f"mypy:\n{result.stdout}{result.stderr}"
