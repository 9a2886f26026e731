"""The detector's weights file: plain tensors and values, read with ``weights_only=True``.

Layout (a dict saved by :func:`torch.save`): ``format`` (``"dt-highway-detector"``),
``format_version``, ``arch`` (:meth:`Architecture.to_dict`), ``state_dict``, ``meta``
(training steps, frames, minutes, package version). Nothing in it is a pickled object, so
loading a file cannot run code.
"""

from __future__ import annotations

import os
import pickle
import zipfile
from pathlib import Path

import torch

from dt_highway._version import __version__
from dt_highway.perception.learned.model import Architecture, PointDetector

FORMAT = "dt-highway-detector"
FORMAT_VERSION = 1
SHIPPED = Path(__file__).with_name("weights") / "vehicles-320x180.pt"
"""The weights shipped with the package (RGB, 320 x 180)"""


def save_weights(model: PointDetector, path: str | Path, meta: dict | None = None) -> Path:
    """Write a trained model's weights (atomically).

    :param model: the network
    :param path: the file to write
    :param meta: training facts to keep beside the weights (plain values only)
    :return: the path written
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    obj = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "arch": model.arch.to_dict(),
        "state_dict": {k: v.detach().clone() for k, v in model.state_dict().items()},
        "meta": {**(meta or {}), "package_version": __version__},
    }
    tmp = path.with_name(path.name + ".tmp")
    torch.save(obj, tmp)
    os.replace(tmp, path)
    return path


def load_weights(path: str | Path | None = None) -> tuple[PointDetector, dict]:
    """Read a weights file into a network in eval mode.

    :param path: the file (``None``: the shipped weights)
    :return: ``(model, meta)``
    :raises FileNotFoundError: if the file does not exist
    :raises ValueError: if the file is not a complete dt-highway detector weights file
    """
    path = SHIPPED if path is None else Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"detector weights not found: {path}")
    if not zipfile.is_zipfile(path):
        raise ValueError(
            f"{path} is not a detector weights file: not a torch zip archive (truncated, or another format)"
        )
    try:
        obj = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError:
        raise ValueError(
            f"{path} holds Python objects, not plain weights: refused (loading it could run code)"
        ) from None
    except Exception as exc:  # noqa: BLE001 - a damaged archive fails in many ways: one message for all
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ValueError(f"{path} is not a readable detector weights file ({first[:160]})") from None
    if not isinstance(obj, dict) or obj.get("format") != FORMAT:
        raise ValueError(f"{path} is not a dt-highway detector weights file (no format '{FORMAT}')")
    if obj.get("format_version") != FORMAT_VERSION:
        raise ValueError(f"{path} has weights format {obj.get('format_version')}, this version reads {FORMAT_VERSION}")
    try:
        model = PointDetector(Architecture.from_dict(obj["arch"]))
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{path}: its architecture record is unusable ({exc})") from None
    expected, given = model.state_dict(), obj.get("state_dict", {})
    if not isinstance(given, dict) or not all(isinstance(v, torch.Tensor) for v in given.values()):
        raise ValueError(f"{path}: its state_dict is not a dict of tensors")
    missing = [k for k in expected if k not in given]
    wrong = [k for k in expected if k in given and tuple(given[k].shape) != tuple(expected[k].shape)]
    if missing or wrong:
        what = f"{len(missing)} tensors missing" if missing else f"{len(wrong)} tensors of the wrong shape"
        raise ValueError(f"{path}: weights do not fit their architecture ({what}, e.g. {(missing or wrong)[0]})")
    model.load_state_dict(given, strict=False)
    model.eval()
    model = model.to(memory_format=torch.channels_last)  # type: ignore[call-overload]  # torch's stubs omit it
    return model, dict(obj.get("meta", {}))
