"""The target-identification benchmark of the paper (section IV-B, Fig. 6).

Frames come from simulated traffic seen by the ego camera (ego on its autopilot). In each
frame one connected vehicle is the target: a vehicle the twin reports, that the camera
shows well enough to be worth marking (visibility and height thresholds). A frame is
**tricky** when the target's visible box touches another vehicle's visible box, or its
true anchor point lies inside two or more of them (vehicles close together from the ego's
point of view: the paper's hard case, where the anchor falls inside several detections);
tricky targets are picked preferentially, so that both subsets are well filled.

Every method sees the same frames, the same detections and the same twin messages; the
tracking method also sees every frame in between (it needs the sequence). A method is right
at IoU threshold ``t`` when the box it selects for the target has IoU >= ``t`` with the
target's ground-truth visible box; selecting nothing is a miss.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import matplotlib
import matplotlib.pyplot as plt
import numpy as np

from dt_highway.camera.pinhole import PinholeCamera
from dt_highway.camera.render import CameraImage
from dt_highway.camera.truth import CameraTruth
from dt_highway.choices import OUTPUT_FILES, SWEEP_FILES
from dt_highway.config import DTConfig, merge
from dt_highway.env import DTHighwayEnv
from dt_highway.evaluation.twin import uplink_sweep_runs
from dt_highway.jsonio import dump_json
from dt_highway.perception import (
    METHODS,
    Detections,
    Fusion,
    Placement,
    fusion_settings,
    iou,
    make_detector,
    run_detector,
)
from dt_highway.perception.matching import containing
from dt_highway.twin.cloud import TwinVehicleView

THRESHOLDS = np.round(np.arange(0.05, 1.0, 0.05), 2)
"""IoU thresholds of the accuracy curve"""


@dataclass(frozen=True)
class BenchmarkSettings:
    """How frames and targets are chosen.

    :param min_visibility: least visibility of a target [-]
    :param min_height_px: least visible height of a target [px]
    :param tricky_share: probability of picking a tricky target when a frame has one [-]
    :param every: policy steps between sampled frames (the methods see every step) [-]
    """

    min_visibility: float = 0.3
    min_height_px: float = 10.0
    tricky_share: float = 0.5
    every: int = 1


@dataclass
class MatchingResult:
    """Per-frame outcomes of every method.

    :param rows: one dict per evaluated frame (target, tricky, per method IoU and rule)
    :param methods: the methods run
    :param settings: the conditions (uplink, detector, fusion, seed)
    """

    rows: list[dict[str, Any]] = field(default_factory=list)
    methods: tuple[str, ...] = METHODS
    settings: dict[str, Any] = field(default_factory=dict)

    def accuracy(self, method: str, threshold: float, subset: str = "all") -> float:
        """Share of frames of ``subset`` right at ``threshold``.

        Subsets: ``all``, ``tricky``, ``ordinary`` (not tricky), ``ambiguous`` (the anchor as
        received lies inside two or more detected boxes: where Algorithm 2 uses depth).

        :param method: the method
        :param threshold: the IoU threshold [-]
        :param subset: ``all``, ``tricky``, ``ordinary`` or ``ambiguous``
        :return: the share (NaN: no frame in the subset)
        """
        if subset == "ambiguous":
            rows = [r for r in self.rows if r["ambiguous"]]
        else:
            rows = [r for r in self.rows if subset == "all" or (r["tricky"] == (subset == "tricky"))]
        if not rows:
            return math.nan
        return float(np.mean([r[f"iou_{method}"] >= threshold for r in rows]))

    def curve(self) -> list[dict[str, Any]]:
        """Accuracy against IoU threshold for each method and subset (``curve.csv`` rows).

        :return: one row per method, subset and threshold of :data:`THRESHOLDS`: ``method``, ``subset``,
            ``iou_threshold``, ``accuracy``
        """
        return [
            {"method": m, "subset": sub, "iou_threshold": float(t), "accuracy": self.accuracy(m, float(t), sub)}
            for m in self.methods for sub in ("all", "tricky", "ordinary", "ambiguous") for t in THRESHOLDS
        ]

    def summary(self) -> dict[str, Any]:
        """The ``summary.json`` content.

        :return: per method the accuracies at IoU 0.5 and 0.7 (and by subset at 0.7), ``n_frames``,
            ``n_tricky``, ``n_ambiguous`` and ``settings``
        """
        n_tricky = sum(r["tricky"] for r in self.rows)
        return {
            "methods": {
                m: {
                    "acc_iou50": self.accuracy(m, 0.5),
                    "acc_iou70": self.accuracy(m, 0.7),
                    "acc_iou70_tricky": self.accuracy(m, 0.7, "tricky"),
                    "acc_iou70_ordinary": self.accuracy(m, 0.7, "ordinary"),
                    "acc_iou70_ambiguous": self.accuracy(m, 0.7, "ambiguous"),
                }
                for m in self.methods
            },
            "n_frames": len(self.rows),
            "n_tricky": int(n_tricky),
            "n_ambiguous": int(sum(r["ambiguous"] for r in self.rows)),
            "settings": self.settings,
        }


def run_matching(
    config: DTConfig,
    frames: int,
    seed: int,
    methods: tuple[str, ...] = METHODS,
    settings: BenchmarkSettings = BenchmarkSettings(),
    progress: Callable[[int], None] | None = None,
) -> MatchingResult:
    """Generate ``frames`` evaluation frames and run every method on them.

    :param config: resolved configuration (scenario, uplink, detector, fusion settings)
    :param frames: evaluation frames to collect [-]
    :param seed: seed of the env, the detector, the methods' sampling and the target choice
    :param methods: the methods to run
    :param settings: target choice
    :param progress: called with 1 per evaluation frame
    :return: per-frame outcomes
    :raises ValueError: one line, when the twin is off (no target to identify) or the scenario shows too few
        connected vehicles to find ``frames`` targets
    """
    if not config.twin.enabled:
        raise ValueError("the matching benchmark identifies the twin's vehicles: it needs twin.enabled = true")
    cfg = merge(config, {"camera": {"enabled": True}, "ego": {"autopilot": True}, "fusion": {"enabled": False}})
    env = DTHighwayEnv(config=cfg.to_dict())
    env.reset(seed=seed)
    streams = np.random.SeedSequence([seed, 0xF05E]).spawn(2 + len(methods))
    detector = make_detector(cfg.detector, np.random.default_rng(streams[0]))
    pick = np.random.default_rng(streams[1])
    fusions = {m: Fusion(_camera(env), fusion_settings(cfg.fusion, m), np.random.default_rng(streams[2 + i]))
               for i, m in enumerate(methods)}
    result = MatchingResult(methods=tuple(methods), settings=_settings(cfg, seed, settings))
    episode, step = 0, 0
    max_steps = 200 * frames + 1000
    while len(result.rows) < frames:
        if step >= max_steps:
            raise ValueError(f"no targets in {step} steps: the scenario shows too few connected vehicles "
                               f"({len(result.rows)} frames found, {frames} asked)")
        _, _, terminated, truncated, _ = env.step(0)
        step += 1
        if terminated or truncated:
            env.reset()
            for f in fusions.values():
                f.reset()
            episode += 1
            continue
        frame, camera_truth = env.camera_image(), env.camera_truth()
        view = env.twin_view.vehicles if env.twin_view is not None else ()
        detections = run_detector(detector, frame, camera_truth)
        now = env.twin_now_s
        placed = {m: f.step(frame, detections, view, now) for m, f in fusions.items()}
        if step % settings.every:
            continue
        cands, tricky = _candidates(env, frame, camera_truth, view, settings, cfg.fusion.anchor_height_m)
        if not cands:
            continue
        if tricky and pick.random() < settings.tricky_share:
            target, is_tricky = int(pick.choice(tricky)), True
        else:
            target = int(pick.choice(cands))
            is_tricky = target in tricky
        truth = camera_truth.vehicles
        row: dict[str, Any] = {
            "frame": len(result.rows), "episode": episode, "time_s": round(frame.time_s, 3), "target": target,
            "tricky": is_tricky, "visibility": round(truth[target].visibility, 4),
            "depth_m": round(truth[target].depth_m, 3), "n_detections": len(detections),
        }
        row.update(_outcomes(placed, methods, target, np.array([truth[target].visible_box]), detections))
        result.rows.append(row)
        if progress is not None:
            progress(1)
    env.close()
    return result


def _camera(env: DTHighwayEnv) -> PinholeCamera:
    """The camera model of an env whose camera is on."""
    if env.camera is None:  # run_matching switches camera.enabled on
        raise RuntimeError("the matching benchmark needs the env's camera")
    return env.camera.camera


def _candidates(
    env: DTHighwayEnv, frame: CameraImage, camera_truth: CameraTruth,
    view: Sequence[TwinVehicleView], settings: BenchmarkSettings, anchor_height_m: float,
) -> tuple[list[int], list[int]]:
    """The frame's possible targets: twin vehicles the camera shows well; ground truth is read here only.

    :return: the candidates' ids, and those of the tricky ones among them
    """
    truth = camera_truth.vehicles
    by_id = {int(getattr(v, "dt_id", -1)): v for v in env.road.vehicles}
    visible = {vid: t for vid, t in truth.items() if t.visible_box is not None}
    boxes_gt = np.array([t.visible_box for t in visible.values()]).reshape(-1, 4)
    cands, tricky = [], []
    for tv in view:
        t = truth.get(tv.vehicle_id)
        if t is None or t.visible_box is None or tv.vehicle_id not in by_id:
            continue
        too_low = t.visible_box[3] - t.visible_box[1] < settings.min_height_px
        if t.visibility < settings.min_visibility or too_low:
            continue
        v = by_id[tv.vehicle_id]
        true_anchor = _camera(env).project(np.array([[v.position[0], v.position[1], anchor_height_m]]), frame.pose)
        n_in = len(containing(boxes_gt, true_anchor.uv_px[0])) if true_anchor.in_front[0] else 0
        touching = (
            (iou(np.array([t.visible_box]), boxes_gt)[0] > 0).sum() - 1 > 0 or _touches(t.visible_box, boxes_gt)
        )
        cands.append(tv.vehicle_id)
        if n_in >= 2 or touching:
            tricky.append(tv.vehicle_id)
    return cands, tricky


def _outcomes(placed: dict[str, dict[int, Placement]], methods: tuple[str, ...], target: int, gt_box: np.ndarray,
              detections: Detections) -> dict[str, Any]:
    """A frame's row entries: whether the anchor was ambiguous, and each method's IoU and rule for the target."""
    row: dict[str, Any] = {}
    p_fusion = placed.get("fusion", placed[methods[0]]).get(target)
    anchor = np.array(p_fusion.anchor_uv) if p_fusion is not None else np.array([np.nan, np.nan])
    row["ambiguous"] = bool(np.isfinite(anchor).all() and len(containing(detections.boxes, anchor)) >= 2)
    for m in methods:
        p = placed[m].get(target)
        box = None if p is None else p.box
        row[f"iou_{m}"] = 0.0 if box is None else float(iou(np.array([box]), gt_box)[0, 0])
        row[f"rule_{m}"] = "none" if p is None else p.rule
    return row


def _touches(box: tuple[float, float, float, float], others: np.ndarray, margin_px: float = 1.0) -> bool:
    """Another box (not ``box`` itself) overlaps ``box`` grown by ``margin_px``."""
    b = np.asarray(box, dtype=float)
    grown = b + np.array([-margin_px, -margin_px, margin_px, margin_px])
    hit = ((others[:, 0] <= grown[2]) & (grown[0] <= others[:, 2])
           & (others[:, 1] <= grown[3]) & (grown[1] <= others[:, 3]))
    same = np.all(np.isclose(others, b), axis=1)
    return bool((hit & ~same).any())


def _settings(cfg: DTConfig, seed: int, bench: BenchmarkSettings) -> dict[str, Any]:
    up = cfg.twin.uplink
    return {
        "seed": seed,
        "gnss_noise_sigma_m": up.noise_sigma_m,
        "latency_mean_s": up.latency_mean_s,
        "rate_hz": up.rate_hz,
        "policy_frequency_hz": cfg.highway.policy_frequency,
        "vehicles_count": cfg.highway.vehicles_count,
        "camera": f"{cfg.camera.width_px}x{cfg.camera.height_px}, hfov {cfg.camera.hfov_deg} deg",
        "detector": cfg.detector.model_dump(),
        "fusion": {k: v for k, v in cfg.fusion.model_dump().items() if k not in ("enabled", "method")},
        "targets": bench.__dict__.copy(),
    }


def write_outputs(result: MatchingResult, out: Path) -> list[Path]:
    """Write ``curve.csv``, ``summary.json``, ``frames.csv`` and ``curve.png``.

    :param result: the benchmark's outcomes (:func:`run_matching`)
    :param out: the output directory (created)
    :return: the paths written
    """
    out.mkdir(parents=True, exist_ok=True)
    curve = result.curve()
    paths = [out / name for name in OUTPUT_FILES]
    with paths[0].open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=["method", "subset", "iou_threshold", "accuracy"])
        w.writeheader()
        w.writerows(curve)
    paths[1].write_text(dump_json(result.summary()) + "\n")
    with paths[2].open("w", newline="") as fh:
        if result.rows:
            w = csv.DictWriter(fh, fieldnames=list(result.rows[0]))
            w.writeheader()
            w.writerows(result.rows)
    plot_curve(curve, paths[3], f"{len(result.rows)} frames ({sum(r['tricky'] for r in result.rows)} tricky)")
    return paths


def plot_curve(curve: list[dict[str, Any]], path: Path, title: str = "") -> None:
    """Accuracy against IoU threshold, one line per method (solid: all frames, dashed: tricky), like Fig. 6.

    :param curve: the rows of :meth:`MatchingResult.curve`
    :param path: the image file to write
    :param title: the plot's title
    """
    matplotlib.use("Agg")
    fig, ax = plt.subplots(figsize=(6.4, 4.2), dpi=110)
    methods = list(dict.fromkeys(r["method"] for r in curve))
    for i, m in enumerate(methods):
        for sub, style in (("all", "-"), ("tricky", "--")):
            pts = [(r["iou_threshold"], r["accuracy"]) for r in curve if r["method"] == m and r["subset"] == sub]
            if pts and not all(math.isnan(a) for _, a in pts):
                x, y = zip(*pts, strict=True)
                ax.plot(x, y, style, color=f"C{i}", label=f"{m} ({sub})", marker="o" if sub == "all" else None, ms=3)
    ax.axvline(0.7, color="0.6", lw=0.8)
    ax.set_xlabel("IoU threshold")
    ax.set_ylabel("target identification accuracy")
    ax.set_ylim(0, 1.02)
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


SWEEP = (
    ("gnss_noise_sigma_m", "twin.uplink.noise_sigma_m", (0.5, 1.0, 2.0, 3.0)),
    ("latency_mean_s", "twin.uplink.latency_mean_s", (0.0, 0.1, 0.3, 0.5)),
    ("rate_hz", "twin.uplink.rate_hz", (10.0, 5.0, 1.0)),
)
"""One-at-a-time sweep of the uplink (the other settings at their configured values)"""


def run_sweep(
    config: DTConfig,
    frames: int,
    seed: int,
    methods: tuple[str, ...] = METHODS,
    settings: BenchmarkSettings = BenchmarkSettings(),
    progress: Callable[[int], None] | None = None,
) -> list[dict[str, Any]]:
    """The uplink sweep: GNSS noise, latency and update rate one at a time, plus the
    degraded uplink of the targets (300 ms at 1 Hz).

    :param config: resolved configuration (scenario, uplink, detector, fusion settings)
    :param frames: evaluation frames per setting [-]
    :param seed: seed of each setting's run (as :func:`run_matching`)
    :param methods: the methods to run
    :param settings: target choice
    :param progress: called with 1 per evaluation frame
    :return: one row per (setting, method): ``parameter``, ``value``, ``method``,
        ``acc_iou50``, ``acc_iou70``, ``acc_iou70_tricky``, ``n_frames``, ``n_tricky``
    """
    rows = []
    for name, value, extra in uplink_sweep_runs(SWEEP):
        res = run_matching(merge(config, extra), frames, seed, methods, settings, progress)
        summ = res.summary()
        for m in methods:
            s = summ["methods"][m]
            rows.append({"parameter": name, "value": value, "method": m, "acc_iou50": s["acc_iou50"],
                         "acc_iou70": s["acc_iou70"], "acc_iou70_tricky": s["acc_iou70_tricky"],
                         "n_frames": summ["n_frames"], "n_tricky": summ["n_tricky"]})
    return rows


def write_sweep(rows: list[dict[str, Any]], out: Path) -> list[Path]:
    """Write ``sweep.csv``, ``sweep.json`` and ``sweep.png`` (accuracy at IoU 0.7 per setting).

    :param rows: the rows of :func:`run_sweep`
    :param out: the output directory (created)
    :return: the paths written
    """
    matplotlib.use("Agg")
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / name for name in SWEEP_FILES]
    with paths[0].open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    paths[1].write_text(dump_json(rows) + "\n")
    methods = list(dict.fromkeys(r["method"] for r in rows))
    fig, axes = plt.subplots(1, 3, figsize=(11, 3.6), dpi=110, sharey=True)
    labels = {"gnss_noise_sigma_m": "GNSS noise sigma [m]", "latency_mean_s": "uplink latency [s]",
              "rate_hz": "update rate [Hz]"}
    for ax, (name, _, values) in zip(axes, SWEEP, strict=True):
        for i, m in enumerate(methods):
            y = [next(r["acc_iou70"] for r in rows if r["parameter"] == name and r["value"] == v and r["method"] == m)
                 for v in values]
            ax.plot(values, y, "-o", color=f"C{i}", label=m, ms=3)
        ax.set_xlabel(labels[name])
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("accuracy at IoU 0.7")
    axes[0].set_ylim(0, 1.02)
    axes[-1].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(paths[2])
    plt.close(fig)
    return paths
