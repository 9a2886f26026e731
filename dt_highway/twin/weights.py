"""Small perceptrons' weights as ``.npz`` files of plain arrays (no pickles): the twin's intention network and chase
detector both ship and load theirs this way."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

Layers = tuple[tuple[np.ndarray, np.ndarray], ...]
"""``(W, b)`` of each layer, ``W`` as ``(in, out)``"""


def write_weights(path: str | Path, arrays: dict[str, np.ndarray], layers: list[tuple[np.ndarray, np.ndarray]],
                  meta: dict[str, str] | None = None) -> None:
    """Write ``arrays``, then each layer as ``W{i}`` / ``b{i}`` (float64) and each ``meta`` entry as ``meta_{key}``.

    :param path: the ``.npz`` file to write (its folder is created)
    :param arrays: arrays written under their own names
    :param layers: ``(W, b)`` of each layer, ``W`` as ``(in, out)``
    :param meta: how the weights were made (``None``: nothing)
    """
    out = dict(arrays)
    for i, (w, b) in enumerate(layers):
        out[f"W{i}"], out[f"b{i}"] = np.asarray(w, dtype=np.float64), np.asarray(b, dtype=np.float64)
    for k, value in (meta or {}).items():
        out[f"meta_{k}"] = np.asarray(value)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as fh:
        np.savez(fh, **out)  # type: ignore[arg-type]  # numpy's stub types the keyword arrays as allow_pickle


def read_weights(path: Path, what: str) -> tuple[dict[str, np.ndarray], Layers, dict[str, str]]:
    """Read a file of :func:`write_weights` with ``allow_pickle=False``.

    :param path: the ``.npz`` file
    :param what: what the weights are, for the error (e.g. ``"chase"``)
    :return: every array by name, the layers and the meta entries
    :raises ValueError: when the file cannot be read as such a file (one line naming it)
    """
    try:
        z = np.load(path, allow_pickle=False)
        if not isinstance(z, np.lib.npyio.NpzFile):  # a lone .npy array
            raise ValueError("not a .npz archive of arrays")
        with z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        # numpy says a text or pickle file "contains pickled (object) data" and suggests allow_pickle=True (which
        # could run code): name what was expected instead
        foreign = "pickled" in str(exc) or isinstance(exc, (EOFError, zipfile.BadZipFile))
        why = "not a .npz archive of arrays" if foreign else str(exc)
        raise ValueError(f"cannot read {what} weights {path}: {why}") from None
    n_layers = sum(1 for k in arrays if k.startswith("W"))
    try:
        layers = tuple((arrays[f"W{i}"], arrays[f"b{i}"]) for i in range(n_layers))
    except KeyError as exc:
        raise ValueError(f"cannot read {what} weights {path}: no layer array {exc}") from None
    return arrays, layers, {k[5:]: str(arrays[k]) for k in arrays if k.startswith("meta_")}
