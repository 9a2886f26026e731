"""Camera frames written with their ground truth (``dt-highway camera``): the pictures, the
instance ids and the true boxes, for looking at the camera and for training data."""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from dt_highway.camera.export import colourise_depth, colourise_instance, write_png
from dt_highway.camera.render import CameraImage
from dt_highway.camera.truth import CameraTruth
from dt_highway.config import DTConfig
from dt_highway.env import DTHighwayEnv
from dt_highway.overlay import draw_overlay


def draw_boxes(rgb: np.ndarray, truth: CameraTruth) -> np.ndarray:
    """A copy of ``rgb`` with each vehicle's visible box (green, with id and visibility) and
    amodal box (thin yellow) drawn: a look at the ground truth.

    :param rgb: the image to draw on
    :param truth: its ground truth
    :return: the copy, boxes drawn
    """
    out = np.ascontiguousarray(rgb).copy()
    for t in truth.vehicles.values():
        x1, y1, x2, y2 = (int(round(v)) for v in t.amodal_box)
        cv2.rectangle(out, (x1, y1), (x2, y2), (240, 220, 40), 1)
        if t.visible_box is None:
            continue
        x1, y1, x2, y2 = (int(round(v)) for v in t.visible_box)
        cv2.rectangle(out, (x1, y1), (x2, y2), (40, 230, 60), 1)
        if x2 - x1 >= 12:
            cv2.putText(out, f"{t.vehicle_id} {t.visibility:.2f}", (x1, max(9, y1 - 3)),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.32, (40, 230, 60), 1, cv2.LINE_AA)
    return out


FRAME_FILE = re.compile(r"(rgb|depth|instance|boxes|overlay)_\d{4,}\.png|frame_\d{4,}\.npz")
"""The name of a frame's file :func:`record_frames` writes (``rgb_0003.png``, ``frame_0003.npz``...)"""


def frame_files(folder: Path) -> list[Path]:
    """The frames' files of :func:`record_frames` ``folder`` holds (none if it is no folder).

    :param folder: the folder
    :return: the files, sorted by name
    """
    return sorted(p for p in folder.iterdir() if FRAME_FILE.fullmatch(p.name)) if folder.is_dir() else []


def write_frame(image: CameraImage, truth: CameraTruth, out: Path, index: int, max_range_m: float,
                raw: bool = False) -> list[Path]:
    """Write one frame's pictures: ``rgb``, ``depth`` (colour-mapped), ``instance`` and
    ``boxes`` PNGs, and with ``raw`` an ``.npz`` of float depth [m] and int32 instance ids.

    :param image: the camera image
    :param truth: its ground truth
    :param out: the folder written to
    :param index: the frame's number (in the file names, 4 digits or more)
    :param max_range_m: the depth shown darkest blue in the depth picture [m]
    :param raw: also write the ``.npz``
    :return: the paths written
    """
    stem = f"{index:04d}"
    files = {
        out / f"rgb_{stem}.png": image.rgb,
        out / f"depth_{stem}.png": colourise_depth(image.depth_m, max_range_m),
        out / f"instance_{stem}.png": colourise_instance(truth.instance),
        out / f"boxes_{stem}.png": draw_boxes(image.rgb, truth),
    }
    for path, img in files.items():
        write_png(path, img)
    paths = list(files)
    if raw:
        path = out / f"frame_{stem}.npz"
        np.savez_compressed(path, depth_m=image.depth_m, instance=truth.instance)
        paths.append(path)
    return paths


def record_frames(
    config: DTConfig,
    frames: int,
    seed: int,
    out: Path,
    every: int = 1,
    raw: bool = False,
    progress: Callable[[int], None] | None = None,
) -> dict[str, Any]:
    """Drive the env (ego on its autopilot unless configured otherwise) and write camera frames.

    :param config: resolved :class:`~dt_highway.config.DTConfig` with the camera enabled
    :param frames: number of frames to write [-]
    :param seed: env seed
    :param out: output directory (created)
    :param every: policy steps between frames [-]
    :param raw: also write ``.npz`` files with float depth and instance ids; with the fusion on
        (``fusion.enabled``), ``overlay_XXXX.png`` shows the ADAS marks on each frame
    :param progress: called with 1 after each frame
    :return: a summary (files written, frames, vehicles seen)
    """
    out.mkdir(parents=True, exist_ok=True)
    env = DTHighwayEnv(config=config.to_dict())
    env.reset(seed=seed)
    max_range = config.camera.max_range_m
    written: list[Path] = []
    seen: set[int] = set()
    with (out / "frames.jsonl").open("w") as log:
        for i in range(frames):
            if i:
                for _ in range(every):
                    _, _, terminated, truncated, _ = env.step(0)
                    if terminated or truncated:
                        env.reset()
            image, truth = env.camera_image(), env.camera_truth()
            written += write_frame(image, truth, out, i, max_range, raw)
            if env.adas is not None:  # the ADAS view: the marks a driver sees, drawn on the frame
                path = out / f"overlay_{i:04d}.png"
                cv2.imwrite(str(path), draw_overlay(image.rgb, env.adas["overlay"])[..., ::-1])
                written.append(path)
            seen.update(v for v, t in truth.vehicles.items() if t.visible_box is not None)
            log.write(json.dumps({
                "index": i,
                "time_s": round(image.time_s, 6),
                "pose": {"x_m": image.pose.x_m, "y_m": image.pose.y_m, "heading_rad": image.pose.heading_rad},
                "vehicles": [t.to_dict() for t in truth.vehicles.values()],
            }) + "\n")
            log.flush()
            if progress is not None:
                progress(1)
    env.close()
    return {"frames": frames, "files": len(written) + 1, "vehicles_seen": len(seen), "out": str(out)}
