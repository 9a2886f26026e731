"""Training the learned detector on the CPU, on frames the camera makes on the fly.

A data worker process renders frames (:func:`~dt_highway.perception.learned.data.make_frame`,
seeds from :data:`~dt_highway.perception.learned.data.TRAIN_SEED0` on), flips half of them
left-right and builds their targets; the trainer takes half of each batch fresh from the
worker and half from a replay pool of recent frames (each frame is seen about twice, under
other colours: the worker randomises colours and lighting, :func:`randomise_colours`) and
steps AdamW with a cosine learning rate over the time budget.

A checkpoint (model, optimiser, counters, generator states) is written atomically every
``checkpoint_every_s`` to ``<out>.ckpt`` and when training is interrupted; running the same
command again resumes from it (the replay pool, 350 MB, is not saved: it refills from the
next frames, so the first steps after a resume train on fresh frames only).
The finished weights (:func:`save_weights`) hold plain tensors and values only, so that
``torch.load(..., weights_only=True)`` reads them.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
from torch.utils.data import DataLoader, IterableDataset

from dt_highway.perception.learned.data import TRAIN_SEED0, SceneSettings, make_frame
from dt_highway.perception.learned.model import (
    STRIDE,
    Architecture,
    PointDetector,
    decode_boxes,
    focal_loss,
    giou_loss,
    inverse_depth,
    make_targets,
    to_input,
)
from dt_highway.perception.learned.weights import save_weights

__all__ = ["TrainSettings", "train", "check_training", "randomise_colours"]


@dataclass(frozen=True)
class TrainSettings:
    """How a detector is trained.

    :param minutes: wall-clock training budget [min] (the learning rate follows it)
    :param batch: images per step (half fresh, half replayed) [-]
    :param lr: peak learning rate [-]
    :param weight_decay: AdamW weight decay [-]
    :param warmup_steps: linear warm-up [steps]
    :param replay: frames kept for replay [-]
    :param threads: torch threads of the trainer (the data worker takes what is left) [-]
    :param checkpoint_every_s: seconds between checkpoints [s]
    :param seed: seed of the initial weights and the replay choices (frames, flips and colours
        follow from the frames' own seeds)
    :param max_steps: stop after this many steps, whatever the time (tests) [-]
    """

    minutes: float = 30.0
    batch: int = 32
    lr: float = 3e-3
    weight_decay: float = 1e-4
    warmup_steps: int = 100
    replay: int = 2048
    threads: int = 2
    checkpoint_every_s: float = 60.0
    seed: int = 0
    max_steps: int | None = None


# ----------------------------------------------------------------------------- data
class _Frames(IterableDataset):
    """Rendered, flipped frames with their targets, seeds ``first_seed, first_seed + 1, ...``.

    Each frame comes in two colourings (:func:`randomise_colours`): one for the batch at hand,
    one for the replay pool.
    """

    def __init__(self, arch: Architecture, first_seed: int) -> None:
        self.arch = arch
        self.first_seed = first_seed

    def __iter__(self) -> Iterator[tuple[torch.Tensor, ...]]:
        arch = self.arch
        settings = SceneSettings(arch.width_px, arch.height_px, vary_camera=True)
        grid = (arch.padded[0] // STRIDE, arch.padded[1] // STRIDE)
        seed = self.first_seed
        while True:
            f = make_frame(seed, settings)
            rgb, boxes = f.rgb, f.boxes
            depth = inverse_depth(f.depth_m) if arch.depth else np.zeros((0, 0), np.float32)
            if np.random.default_rng([seed, 1]).random() < 0.5:
                rgb = rgb[:, ::-1]
                depth = depth[:, ::-1]
                w = arch.width_px
                boxes = np.stack([w - 1 - boxes[:, 2], boxes[:, 1], w - 1 - boxes[:, 0], boxes[:, 3]], axis=1)
            heat, box, weight = make_targets(boxes, grid)
            rng = np.random.default_rng([seed, 2])
            yield (
                torch.from_numpy(randomise_colours(np.ascontiguousarray(rgb), rng)),
                torch.from_numpy(randomise_colours(np.ascontiguousarray(rgb), rng)),
                torch.from_numpy(np.ascontiguousarray(depth)),
                torch.from_numpy(heat),
                torch.from_numpy(box),
                torch.from_numpy(weight),
                torch.tensor(seed),
            )
            seed += 1


_NOISE = np.random.default_rng(12345).standard_normal(1 << 21).astype(np.float32)
"""Sensor-noise bank of :func:`randomise_colours` (8 MB)"""


def randomise_colours(rgb: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Colour and lighting randomisation of one RGB image.

    Hue rotation by any angle (about the grey axis), saturation x0.3 to x1.6, per-channel
    gains 0.75 to 1.25 (white balance, coloured light), brightness x0.5 to x1.4, contrast
    x0.6 to x1.3 (one 3 x 4 colour transform), gamma 0.7 to 1.5, Gaussian sensor noise with
    sigma up to 6 levels, and a 3 x 3 blur for half of the images.

    :param rgb: ``uint8 (H, W, 3)`` image
    :param rng: random generator
    :return: a new ``uint8 (H, W, 3)`` image
    """
    theta = rng.uniform(0.0, 2 * math.pi)
    k = np.full(3, 1 / math.sqrt(3.0))
    kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    hue = math.cos(theta) * np.eye(3) + (1 - math.cos(theta)) * np.outer(k, k) + math.sin(theta) * kx  # Rodrigues
    sat = rng.uniform(0.3, 1.6)
    saturation = sat * np.eye(3) + (1 - sat) / 3.0
    m = np.diag(rng.uniform(0.75, 1.25, 3) * rng.uniform(0.5, 1.4)) @ saturation @ hue
    # contrast about the image's mean after the colour matrix: y = c M x + (1 - c) mean
    contrast = rng.uniform(0.6, 1.3)
    mean = float((m @ np.array(cv2.mean(rgb)[:3])).mean())
    affine = np.hstack([contrast * m, np.full((3, 1), (1 - contrast) * mean)])
    out = cv2.transform(rgb, affine)  # saturates to uint8
    gamma = rng.uniform(0.7, 1.5)
    out = cv2.LUT(out, np.clip(255.0 * (np.arange(256) / 255.0) ** gamma + 0.5, 0, 255).astype(np.uint8))
    sigma = rng.uniform(0.0, 6.0)
    if sigma > 0.5:
        # a window of a fixed bank of normal samples at a random offset (drawing 170 000
        # fresh samples per image cost more than rendering the frame)
        start = int(rng.integers(0, _NOISE.size - out.size))
        noisy = out.astype(np.float32)
        noisy += _NOISE[start : start + out.size].reshape(out.shape) * np.float32(sigma)
        out = np.clip(noisy, 0, 255, out=noisy).astype(np.uint8)
    if rng.random() < 0.5:
        out = cv2.GaussianBlur(out, (3, 3), float(rng.uniform(0.3, 0.9)))
    return out


# ----------------------------------------------------------------------------- training
def _lr(settings: TrainSettings, step: int, elapsed_s: float) -> float:
    warm = min(1.0, (step + 1) / max(settings.warmup_steps, 1))
    frac = min(1.0, elapsed_s / max(settings.minutes * 60.0, 1e-9))
    if settings.max_steps is not None:
        frac = max(frac, step / max(settings.max_steps, 1))
    return settings.lr * warm * (0.02 + 0.98 * 0.5 * (1 + math.cos(math.pi * frac)))


def _atomic_save(obj: object, path: Path) -> None:
    tmp = path.with_name(path.name + ".tmp")
    torch.save(obj, tmp)
    os.replace(tmp, path)


def train(
    out: str | Path,
    arch: Architecture = Architecture(),
    settings: TrainSettings = TrainSettings(),
    resume: bool = True,
    progress: Callable[[int, float, dict[str, float]], None] | None = None,
) -> dict[str, Any]:
    """Train a detector and write its weights to ``out``.

    :param out: the weights file to write; its checkpoint is ``<out>.ckpt``
    :param arch: the network's shape (a checkpoint of another shape is refused)
    :param settings: the training settings (``minutes`` may be raised when resuming)
    :param resume: continue from ``<out>.ckpt`` when it exists
    :param progress: called after every step with ``(step, elapsed_s, losses)``
    :return: a summary (steps, frames rendered, elapsed seconds, last losses, resumed)
    :raises ValueError: as :func:`check_training`, before any training starts
    """
    out = Path(out)
    ckpt_path = out.with_name(out.name + ".ckpt")
    state = check_training(out, arch, settings, resume)
    torch.set_num_threads(settings.threads)
    with torch.random.fork_rng():  # seeded initial weights, without touching the caller's torch RNG
        torch.manual_seed(settings.seed)
        model = PointDetector(arch)
        model = model.to(memory_format=torch.channels_last)  # type: ignore[call-overload]  # torch's stubs omit it
    opt = torch.optim.AdamW(model.parameters(), lr=settings.lr, weight_decay=settings.weight_decay)
    step, elapsed, next_seed, rendered = 0, 0.0, TRAIN_SEED0, 0
    gen = torch.Generator().manual_seed(settings.seed)
    if state is not None:
        _restore(state, model, opt, gen, ckpt_path)
        step, elapsed, next_seed, rendered = state.step, state.elapsed_s, state.next_seed, state.rendered
    half = settings.batch // 2
    loader = DataLoader(_Frames(arch, next_seed), batch_size=half, num_workers=1, persistent_workers=False,
                        prefetch_factor=4)
    pool = _ReplayPool(settings.replay)
    last_ckpt = time.perf_counter()
    losses: dict[str, float] = {}
    budget_s = settings.minutes * 60.0
    model.train()
    t0 = time.perf_counter() - elapsed
    it = iter(loader)
    try:
        while elapsed < budget_s and (settings.max_steps is None or step < settings.max_steps):
            item = next(it)
            next_seed = int(item[6][-1]) + 1
            rendered += len(item[6])
            batch = pool.mix([item[0], *item[2:6]], half, gen)
            pool.add([item[1], *item[2:6]])  # the pool keeps the second colouring
            losses = _train_step(model, opt, batch, arch, _lr(settings, step, elapsed))
            step += 1
            elapsed = time.perf_counter() - t0
            if progress is not None:
                progress(step, elapsed, losses)
            if time.perf_counter() - last_ckpt >= settings.checkpoint_every_s:
                _checkpoint(ckpt_path, model, opt, arch, step, elapsed, next_seed, rendered, gen)
                last_ckpt = time.perf_counter()
    except KeyboardInterrupt:
        # stopped by the user: keep every step done so far, then stop
        _checkpoint(ckpt_path, model, opt, arch, step, elapsed, next_seed, rendered, gen)
        raise
    finally:
        del it, loader
    _checkpoint(ckpt_path, model, opt, arch, step, elapsed, next_seed, rendered, gen)
    meta = {"steps": step, "frames_rendered": rendered, "train_minutes": round(elapsed / 60.0, 2),
            "batch": settings.batch, "last_losses": losses}
    model.eval()
    save_weights(model, out, meta)
    return {**meta, "resumed": state is not None, "checkpoint": str(ckpt_path), "weights": str(out)}


def check_training(out: str | Path, arch: Architecture = Architecture(), settings: TrainSettings = TrainSettings(),
                   resume: bool = True) -> _Resume | None:
    """Check a training before it starts (:func:`train` does): the settings, the output path
    and, when resuming, the checkpoint.

    :param out: the weights file to write; its checkpoint is ``<out>.ckpt``
    :param arch: the network's shape
    :param settings: the training settings
    :param resume: continue from ``<out>.ckpt`` when it exists
    :return: the checkpoint's state to resume from (``None``: training starts anew)
    :raises ValueError: one line, on a batch, network size or budget that cannot train, an
        output path that is a directory, a checkpoint that cannot be read or belongs to another
        network, or one that has already reached ``max_steps`` or the time budget (nothing to train)
    """
    out = Path(out)
    ckpt_path = out.with_name(out.name + ".ckpt")
    _check(arch, settings)
    for path in (out, ckpt_path):
        if path.is_dir():
            raise ValueError(f"{path} is a directory: --out names the weights file to write, e.g. {out / 'detector.pt'}")
    if not resume or not ckpt_path.exists():
        return None
    state = _read_checkpoint(ckpt_path, arch)
    fresh = "pass --fresh to start over"
    if settings.max_steps is not None and state.step >= settings.max_steps:
        raise ValueError(f"nothing to train: {ckpt_path} already holds {state.step} steps, --max-steps "
                         f"{settings.max_steps} is reached (raise it to train on, or {fresh})")
    if state.elapsed_s >= settings.minutes * 60.0:
        raise ValueError(f"nothing to train: {ckpt_path} already trained {state.elapsed_s / 60.0:.2f} min, --minutes "
                         f"{settings.minutes:g} is reached (raise it to train on, or {fresh})")
    return state


def _check(arch: Architecture, settings: TrainSettings) -> None:
    """Check that the architecture and settings can train.

    :raises ValueError: on a batch, network size or time budget that cannot train
    """
    if settings.batch < 2 or settings.batch % 2 or settings.batch // 2 > settings.replay:
        raise ValueError(f"the batch (--batch) must be even, from 2 to {2 * settings.replay} (got {settings.batch})")
    if not (32 <= arch.width_px <= 4096 and 32 <= arch.height_px <= 4096):
        raise ValueError(f"the network's input (--width, --height) must be 32 to 4096 px per side "
                         f"(got {arch.width_px}x{arch.height_px})")
    if settings.minutes <= 0:
        raise ValueError(f"minutes must be > 0 (got {settings.minutes})")


@dataclass(frozen=True)
class _Resume:
    """What a checkpoint holds: the counters, and the states of the model, optimiser and replay generator."""

    step: int
    elapsed_s: float
    next_seed: int
    rendered: int
    model: dict[str, Any]
    optimizer: dict[str, Any]
    generator: torch.Tensor


def _read_checkpoint(path: Path, arch: Architecture) -> _Resume:
    """Read a training checkpoint to resume from.

    :raises ValueError: if the checkpoint cannot be read or holds another network than ``arch``
    """
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
        saved = Architecture.from_dict(state["arch"])
        resume = _Resume(int(state["step"]), float(state["elapsed_s"]), int(state["next_seed"]), int(state["rendered"]),
                         state["model"], state["optimizer"], state["generator"])
    except Exception as exc:  # noqa: BLE001 - a torn or foreign checkpoint: say so, do not guess
        # torch's own message runs over several lines and suggests weights_only=False (which could run code): not shown
        raise ValueError(f"cannot resume from {path}: not a checkpoint of this trainer, or cut short "
                         f"({type(exc).__name__}); delete it or pass --fresh") from None
    if saved != arch:
        raise ValueError(f"{path} holds another network ({_describe(saved)}; asked: {_describe(arch)}): "
                         "give the same options or pass --fresh")
    return resume


def _restore(state: _Resume, model: PointDetector, opt: torch.optim.Optimizer, gen: torch.Generator,
             path: Path) -> None:
    """Load a checkpoint's states into the model, the optimiser and the replay generator.

    :raises ValueError: if they do not fit
    """
    try:
        model.load_state_dict(state.model)
        opt.load_state_dict(state.optimizer)
        gen.set_state(state.generator)
    except Exception as exc:  # noqa: BLE001 - any mismatch: one line naming the checkpoint
        raise ValueError(f"cannot resume from {path}: {str(exc).splitlines()[0]} (pass --fresh)") from None


_FIELDS = ("rgb", "depth", "heat", "box", "weight")
"""The tensors of a batch, in order"""


class _ReplayPool:
    """The newest ``size`` frames (their second colouring), replayed as half of each batch.

    :param size: frames kept [-]
    """

    def __init__(self, size: int) -> None:
        self.size = size
        self.tensors: dict[str, torch.Tensor] = {}
        self.filled = 0
        self.cursor = 0

    def mix(self, batch: list[torch.Tensor], half: int, gen: torch.Generator) -> list[torch.Tensor]:
        """Add replayed frames from the pool to a batch.

        :return: ``batch`` followed by ``half`` frames drawn from the pool (``gen``), once it holds that many
        """
        if self.filled < half:
            return batch
        pick = torch.randint(0, self.filled, (half,), generator=gen)
        return [torch.cat([b, self.tensors[k][pick]]) for b, k in zip(batch, _FIELDS, strict=True)]

    def add(self, fresh: list[torch.Tensor]) -> None:
        """Keep a batch of frames (over the oldest ones when full)."""
        if not self.tensors:
            self.tensors = {k: torch.empty((self.size, *b.shape[1:]), dtype=b.dtype)
                            for k, b in zip(_FIELDS, fresh, strict=True)}
        for i in range(len(fresh[0])):
            for k, b in zip(_FIELDS, fresh, strict=True):
                self.tensors[k][self.cursor] = b[i]
            self.cursor = (self.cursor + 1) % self.size
            self.filled = min(self.filled + 1, self.size)


def _train_step(model: PointDetector, opt: torch.optim.Optimizer, batch: list[torch.Tensor], arch: Architecture,
                lr: float) -> dict[str, float]:
    """One AdamW step at learning rate ``lr`` on a batch; :return: its losses and the learning rate."""
    rgb, depth, heat, box, weight = batch
    inp = to_input(rgb, arch, depth if arch.depth else None)
    for g in opt.param_groups:
        g["lr"] = lr
    heat_logits, dist = model(inp)
    l_heat = focal_loss(heat_logits, heat)
    l_box = giou_loss(decode_boxes(dist), box, weight)
    loss = l_heat + l_box
    opt.zero_grad(set_to_none=True)
    loss.backward()
    torch.nn.utils.clip_grad_norm_(model.parameters(), 10.0)
    opt.step()
    return {"loss": loss.item(), "heat": l_heat.item(), "box": l_box.item(), "lr": lr}


def _describe(arch: Architecture) -> str:
    return f"{arch.width_px}x{arch.height_px}, {'RGB + depth' if arch.depth else 'RGB'}, channels {list(arch.channels)}"


def _checkpoint(path: Path, model: PointDetector, opt: torch.optim.Optimizer, arch: Architecture, step: int,
                elapsed: float, next_seed: int, rendered: int, gen: torch.Generator) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    _atomic_save(
        {"arch": arch.to_dict(), "model": model.state_dict(), "optimizer": opt.state_dict(), "step": step,
         "elapsed_s": elapsed, "next_seed": next_seed, "rendered": rendered, "generator": gen.get_state()},
        path,
    )
