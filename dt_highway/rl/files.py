"""A policy's files: the model (``agents/<name>.zip``) and the metadata beside it (``.json``)."""

from __future__ import annotations

import hashlib
import json
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Any

from dt_highway.config import ConfigError

FORMAT = "dt-highway policy 1"


def sidecar_path(model_path: str | Path) -> Path:
    """Where the metadata of a policy lives: ``agents/x.zip`` -> ``agents/x.json``.

    :param model_path: the policy's model file
    :return: the metadata file
    """
    return Path(model_path).with_suffix(".json")


def read_policy_meta(model_path: str | Path) -> dict[str, Any]:
    """The metadata ``dt-highway train`` wrote beside a policy (:func:`sidecar_path`).

    :param model_path: the policy's model file
    :return: the metadata
    :raises ConfigError: one line, when it is missing, unreadable or not a dt-highway policy's
    """
    p = Path(model_path)
    side = sidecar_path(p)
    try:
        meta = json.loads(side.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{p}: no {side.name} beside it (the metadata dt-highway train writes): "
                          f"not a dt-highway policy") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ConfigError(f"cannot read {side}: {err}") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise ConfigError(f"{side} is not the metadata of a dt-highway policy")
    return meta


def sha256(path: str | Path) -> str:
    """SHA-256 of a file, hex.

    :param path: the file
    :return: the digest, 64 hex digits
    """
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def versions() -> dict[str, str]:
    """Versions of the packages a policy file depends on.

    :return: package name -> version (``unknown`` when not installed)
    """
    out = {}
    for pkg in ("dt-highway", "stable-baselines3", "torch", "gymnasium", "highway-env", "numpy"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            out[pkg] = "unknown"
    return out
