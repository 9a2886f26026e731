"""A policy's files: the model (``agents/<name>.zip``) and the metadata beside it (``.json``)."""

from __future__ import annotations

import hashlib
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

FORMAT = "dt-highway policy 1"


def sidecar_path(model_path: str | Path) -> Path:
    """Where the metadata of a policy lives: ``agents/x.zip`` -> ``agents/x.json``."""
    return Path(model_path).with_suffix(".json")


def sha256(path: str | Path) -> str:
    """SHA-256 of a file, hex."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def versions() -> dict[str, str]:
    """Versions of the packages a policy file depends on."""
    out = {}
    for pkg in ("dt-highway", "stable-baselines3", "torch", "gymnasium", "highway-env", "numpy"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            out[pkg] = "unknown"
    return out
