"""COCO-style average precision of a detector on a held-out, seeded set of synthetic frames.

The set is frames ``seed .. seed + frames - 1`` of
:func:`~dt_highway.perception.learned.data.make_frame` with the product's camera (training
draws seeds from :data:`~dt_highway.perception.learned.data.TRAIN_SEED0` on, so the two never
meet). Scored vehicles are those of :func:`~dt_highway.perception.learned.data.scored`
(KITTI moderate); the other labelled vehicles are COCO crowd regions: a detection on one is
neither a hit nor a false alarm. AP, AP50 and AP75 come from pycocotools' ``COCOeval``
(101-point interpolation, IoU 0.50:0.05:0.95, up to 100 detections per image); recall at IoU
0.7 is read from the same evaluation. At the detector's operating score, detections are
matched greedily (highest score first) at IoU 0.7: recall = scored vehicles found / scored
vehicles, precision = hits / (hits + false alarms), detections on ignored vehicles left out.
"""

from __future__ import annotations

import contextlib
import io
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from pycocotools.coco import COCO
from pycocotools.cocoeval import COCOeval

from dt_highway.perception.detect import iou
from dt_highway.perception.learned.data import TRAIN_SEED0, SceneSettings, make_frame
from dt_highway.perception.learned.detector import LearnedDetector

EVAL_SEED = 0
"""First seed of the default held-out set"""


def _coco_box(b: np.ndarray) -> list[float]:
    # COCO boxes are [x, y, w, h] with x, y the top-left corner; ours are pixel-centre
    # coordinates of the box's edges, so widths are x2 - x1 either way
    return [float(b[0]), float(b[1]), float(b[2] - b[0]), float(b[3] - b[1])]


def evaluate(
    detector: LearnedDetector,
    frames: int = 500,
    seed: int = EVAL_SEED,
    width_px: int | None = None,
    height_px: int | None = None,
    batch: int = 16,
    progress: Callable[[int], None] | None = None,
) -> dict[str, Any]:
    """AP, AP50, AP75 and recall at IoU 0.7 of a detector on held-out frames.

    :param detector: the detector
    :param frames: number of frames [-]
    :param seed: first frame seed (must stay below the training seeds)
    :param width_px: frame width (default: the detector's input width) [px]
    :param height_px: frame height (default: the detector's input height) [px]
    :param batch: frames per forward pass [-]
    :param progress: called with the number of frames done after each batch
    :return: the numbers, with the set's description
    :raises ValueError: if the set would overlap the training seeds
    """
    if frames < 1:
        raise ValueError(f"frames must be >= 1 (got {frames})")
    if seed < 0 or seed + frames > TRAIN_SEED0:
        raise ValueError(f"held-out seeds must lie in 0..{TRAIN_SEED0 - 1} (got {seed}..{seed + frames - 1})")
    settings = SceneSettings(width_px or detector.arch.width_px, height_px or detector.arch.height_px,
                             vary_camera=False)
    images: list[dict[str, Any]] = []
    annotations: list[dict[str, Any]] = []
    detections: list[dict[str, Any]] = []
    operating = {"hits": 0, "scored": 0, "false": 0, "ignored": 0}
    t_detect = 0.0
    for start in range(seed, seed + frames, batch):
        labelled = [make_frame(s, settings) for s in range(start, min(start + batch, seed + frames))]
        t = time.perf_counter()
        found = detector.detect_batch([f.rgb for f in labelled], [f.depth_m for f in labelled],
                                      min_score=min(0.01, detector.min_score))
        t_detect += time.perf_counter() - t
        for f, s, det in zip(labelled, range(start, start + len(labelled)), found, strict=True):
            images.append({"id": s, "width": settings.width_px, "height": settings.height_px})
            for b, keep in zip(f.boxes, f.scored, strict=True):
                area = float((b[2] - b[0]) * (b[3] - b[1]))
                annotations.append({"id": len(annotations) + 1, "image_id": s, "category_id": 1, "bbox": _coco_box(b),
                                    "area": area, "iscrowd": int(not keep)})
            for b, sc in zip(det.boxes, det.scores, strict=True):
                detections.append({"image_id": s, "category_id": 1, "bbox": _coco_box(b), "score": float(sc)})
            # at the operating score: greedy matching at IoU 0.7, highest score first; a
            # detection on an ignored vehicle is neither a hit nor a false alarm
            op = det.scores >= detector.min_score
            operating["scored"] += int(f.scored.sum())
            if op.any() and len(f.boxes) == 0:
                operating["false"] += int(op.sum())
            elif op.any():
                m = iou(det.boxes[op], f.boxes)
                taken = np.zeros(len(f.boxes), dtype=bool)
                for d in np.argsort(-det.scores[op], kind="stable"):
                    cand = np.where(~taken, m[d], -1.0)
                    j = int(np.argmax(cand))
                    if cand[j] >= 0.7:
                        taken[j] = True
                        operating["hits" if f.scored[j] else "ignored"] += 1
                    elif m[d].max() < 0.3 or f.scored[int(np.argmax(m[d]))]:
                        operating["false"] += 1
                    else:
                        operating["ignored"] += 1
        if progress is not None:
            progress(len(images))
    gt = COCO()
    gt.dataset = {"images": images, "annotations": annotations, "categories": [{"id": 1, "name": "vehicle"}]}
    with contextlib.redirect_stdout(io.StringIO()):
        gt.createIndex()
        dt = gt.loadRes(detections) if detections else None
        if dt is None:
            stats, recall07 = np.zeros(12), 0.0
        else:
            ev = COCOeval(gt, dt, "bbox")
            ev.evaluate()
            ev.accumulate()
            ev.summarize()
            stats = ev.stats
            t07 = int(np.argmin(np.abs(ev.params.iouThrs - 0.7)))
            # recall[T, K, A, M]: category 0, area "all", maxDets 100
            recall07 = float(ev.eval["recall"][t07, 0, 0, -1])
    n_scored = sum(1 for a in annotations if not a["iscrowd"])
    return {
        "AP": round(float(stats[0]), 4),
        "AP50": round(float(stats[1]), 4),
        "AP75": round(float(stats[2]), 4),
        "AP_small": round(float(stats[3]), 4),
        "AP_medium": round(float(stats[4]), 4),
        "AP_large": round(float(stats[5]), 4),
        "recall_iou07": round(max(recall07, 0.0), 4),
        "operating_score": detector.min_score,
        "recall_iou07_at_operating_score": round(operating["hits"] / max(operating["scored"], 1), 4),
        "precision_iou07_at_operating_score": round(
            operating["hits"] / max(operating["hits"] + operating["false"], 1), 4),
        "frames": len(images),
        "seeds": [seed, seed + frames - 1],
        "image_px": [settings.width_px, settings.height_px],
        "scored_vehicles": n_scored,
        "ignored_vehicles": len(annotations) - n_scored,
        "scored_rule": "visible height >= 25/375 of the image height and visibility >= 0.5 (KITTI moderate)",
        "detect_ms_per_frame": round(1000.0 * t_detect / max(len(images), 1), 2),
    }
