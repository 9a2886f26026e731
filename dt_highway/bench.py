"""Benchmarks that print numbers (``dt-highway bench ...``), never timed tests."""

from __future__ import annotations

import contextlib
import cProfile
import gc
import math
import os
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import cv2
import gymnasium as gym
import highway_env  # noqa: F401  (registers highway-v0)
import numpy as np
import pygame

from dt_highway.camera.pinhole import Intrinsics, Mount, PinholeCamera, Pose
from dt_highway.camera.render import CameraImage
from dt_highway.camera.scene import RoadScene, VehicleSet
from dt_highway.config import ConfigError, DTConfig, merge
from dt_highway.env import DTHighwayEnv, make_camera
from dt_highway.hmi.drive import DriveOptions, run_drive
from dt_highway.hmi.keys import KeyScript
from dt_highway.perception import METHODS, Detections, Fusion, FusionSettings
from dt_highway.twin.cloud import TwinVehicleView


def _rss_mb() -> float:
    """Resident set size of this process [MB] (Linux ``/proc``; NaN elsewhere)."""
    try:
        with open("/proc/self/statm") as fh:
            pages = int(fh.read().split()[1])
        return pages * os.sysconf("SC_PAGE_SIZE") / 1e6
    except (OSError, ValueError, IndexError):
        return float("nan")


def bench_memory(
    config: DTConfig, hours: float, sample_every_min: float = 10.0, progress: Callable[[int], None] | None = None
) -> dict[str, Any]:
    """Run one env for ``hours`` of simulated time (ego on autopilot) and sample memory.

    The episode lasts the whole run unless the ego crashes; the env is then reset without a
    seed (same drivers, the twin keeps its records), so memory is watched across episodes
    too.

    :param config: resolved configuration (duration is set to cover ``hours``)
    :param hours: simulated time [h]
    :param sample_every_min: sampling period [min of simulated time]
    :param progress: called with the number of policy steps done after each step
    :return: samples of RSS [MB], live Python objects, fixes held, driver records, episodes, and the
        growth between the first sample after warm-up and the last one
    """
    freq = config.highway.policy_frequency
    steps_per_sample = max(1, int(round(sample_every_min * 60 * freq)))
    n_samples = max(2, int(round(hours * 3600.0 * freq / steps_per_sample)))
    seconds = n_samples * steps_per_sample / freq  # what is actually simulated
    cfg = merge(config, {"ego": {"autopilot": True}, "highway": {"duration": seconds + 10.0}})
    env = DTHighwayEnv(config=cfg.to_dict())
    env.reset(seed=0)
    samples = []
    episodes = 1
    t0 = time.perf_counter()
    for k in range(n_samples):
        for _ in range(steps_per_sample):
            _, _, terminated, truncated, _ = env.step(0)
            if terminated or truncated:  # e.g. the ego was hit by a cut-in: the world goes on
                env.reset()
                episodes += 1
            if progress is not None:
                progress(1)
        gc.collect()
        samples.append({
            "sim_time_min": round((k + 1) * steps_per_sample / freq / 60.0, 2),
            "episodes": episodes,
            "rss_mb": round(_rss_mb(), 2),
            "live_objects": len(gc.get_objects()),
            "twin_fixes_held": env.twin.store.n_fixes() if env.twin else 0,
            "twin_records": len(env.twin.tagger.records) if env.twin else 0,
            "vehicles": len(env.road.vehicles),
        })
    wall = time.perf_counter() - t0
    env.close()
    first, last = samples[min(1, len(samples) - 1)], samples[-1]
    return {
        "hours_simulated": round(seconds / 3600.0, 4),
        "wall_time_s": round(wall, 1),
        "sim_seconds_per_wall_second": round(seconds / wall, 1),
        "rss_growth_mb_after_warmup": round(last["rss_mb"] - first["rss_mb"], 2),
        "live_object_growth_after_warmup": last["live_objects"] - first["live_objects"],
        "samples": samples,
    }


@contextlib.contextmanager
def _one_core() -> Iterator[int | None]:
    """Run this process on one CPU, OpenCV on one thread; restore both afterwards.

    :return: (as the context value) the CPU, ``None`` where affinity cannot be set
    """
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    before: set[int] | None
    cpu: int | None
    try:
        before = os.sched_getaffinity(0)
        cpu = min(before)
        os.sched_setaffinity(0, {cpu})
    except (AttributeError, OSError):
        before, cpu = None, None
    try:
        yield cpu
    finally:
        cv2.setNumThreads(threads)
        if before is not None:
            os.sched_setaffinity(0, before)


def bench_camera(
    config: DTConfig, scenes: int = 60, repeats: int = 5, progress: Callable[[int], None] | None = None
) -> dict[str, Any]:
    """Time our camera against highway-env's top-down ``render()`` on the same scenes, on one core.

    The env runs with ``config`` (the ego on autopilot); after each policy step, the same
    scene is rendered ``repeats`` times by each of: our camera at 640x360 and at 320x180
    (RGB + depth + instance + ground-truth boxes, reading the vehicles from the road
    included), and highway-env's ``render()`` (``rgb_array``, 640x360). Calls are
    interleaved so that drifts of the machine hit all three alike.

    :param config: resolved configuration (vehicle count, lanes, camera settings)
    :param scenes: number of scenes (policy steps) [-]
    :param repeats: renderings of each scene per renderer [-]
    :param progress: called with 1 after each scene
    :return: median frame times [ms], frames/s, the ratio ours / highway-env at 640x360,
        vehicles drawn per frame, and whether the targets are met
    """
    with _one_core() as cpu:
        return _bench_camera(config, scenes, repeats, progress, cpu)


def _bench_camera(
    config: DTConfig, scenes: int, repeats: int, progress: Callable[[int], None] | None, cpu: int | None
) -> dict[str, Any]:
    hw = {"screen_width": 640, "screen_height": 360, "offscreen_rendering": True}
    cfg = merge(config, {"ego": {"autopilot": True}, "highway": hw, "camera": {"enabled": False}})
    env = DTHighwayEnv(config=cfg.to_dict(), render_mode="rgb_array")
    env.reset(seed=0)
    scene = RoadScene.from_road(env.road)
    cams = {
        (w, h): make_camera(cfg.camera.model_copy(update={"width_px": w, "height_px": h}), scene)
        for w, h in ((640, 360), (320, 180))
    }
    times: dict[str, list[float]] = {"ours_640x360": [], "ours_320x180": [], "highway_env_topdown_640x360": []}
    drawn, visible, vehicles_on_road = [], [], []
    env.render()  # first call opens the pygame surfaces
    for _ in range(scenes):
        _, _, terminated, truncated, _ = env.step(0)
        if terminated or truncated:
            env.reset()
        ego = env.vehicle
        for _ in range(repeats):
            for (w, h), cam in cams.items():
                t0 = time.perf_counter()
                _, truth = cam.render(Pose(float(ego.position[0]), float(ego.position[1]), float(ego.heading)),
                                      VehicleSet.from_road(env.road, exclude=ego))
                times[f"ours_{w}x{h}"].append(time.perf_counter() - t0)
                if w == 640:
                    drawn.append(len(truth.vehicles))
                    visible.append(sum(v.visible_box is not None for v in truth.vehicles.values()))
            t0 = time.perf_counter()
            env.render()
            times["highway_env_topdown_640x360"].append(time.perf_counter() - t0)
        vehicles_on_road.append(len(env.road.vehicles) - 1)
        if progress is not None:
            progress(1)
    env.close()
    med = {k: float(np.median(v)) * 1e3 for k, v in times.items()}
    ratio = med["ours_640x360"] / med["highway_env_topdown_640x360"]
    fps_small = 1e3 / med["ours_320x180"]
    return {
        "cpu": cpu,
        "opencv_threads": 1,
        "frames_per_renderer": len(times["ours_640x360"]),
        "npc_vehicles_on_road_median": float(np.median(vehicles_on_road)),
        "vehicles_drawn_per_frame_median": float(np.median(drawn)),
        "vehicles_visible_per_frame_median": float(np.median(visible)),
        "median_ms": {k: round(v, 3) for k, v in med.items()},
        "p90_ms": {k: round(float(np.percentile(v, 90)) * 1e3, 3) for k, v in times.items()},
        "ratio_ours_640x360_to_highway_env": round(ratio, 3),
        "fps_ours_320x180": round(fps_small, 1),
        "fps_ours_640x360": round(1e3 / med["ours_640x360"], 1),
        "targets": {"ratio_max": 1.0, "fps_320x180_min": 500.0},
        "targets_met": bool(ratio <= 1.0 and fps_small >= 500.0),
    }


def bench_fusion(frames: int = 300, n_vehicles: int = 20, seed: int = 0) -> dict[str, Any]:
    """Time one frame's fusion (anchor projection, Algorithm 1, matching, tracking) per method.

    A synthetic but consistent scene: ``n_vehicles`` connected cars ahead of the ego in three
    lanes, 10-120 m away, drifting slowly; the twin reports their positions (1 m noise) and
    the detector their true boxes with 3 % jitter, so every frame has ``n_vehicles`` boxes
    and as many twin vehicles. Rendering and detection are not timed.

    :param frames: frames per method [-]
    :param n_vehicles: vehicles (and boxes) per frame [-]
    :param seed: seed of the scene
    :return: median and p90 time per frame [ms] per method, and the target
    """
    with _one_core() as cpu:
        rng = np.random.default_rng(seed)
        camera = PinholeCamera(Intrinsics.from_fov(640, 360, math.radians(90)),
                               Mount(0.5, 0.0, 1.3, math.radians(3), 0.0))
        xs = np.sort(rng.uniform(10, 120, n_vehicles))
        ys = rng.choice([0.0, 4.0, 8.0], n_vehicles)
        depth = np.full((360, 640), 200.0, dtype=np.float32)
        results: dict[str, Any] = {}
        for method in METHODS:
            fusion = Fusion(camera, FusionSettings(method=method), np.random.default_rng(seed))
            times = []
            for f in range(frames):
                pose = Pose(0.0, 4.0, 0.0)
                x = xs + 0.05 * f
                pts = np.stack([np.stack([x - 2.5, x + 2.5], 1).ravel(), np.repeat(ys, 2),
                                np.full(2 * n_vehicles, 0.0)], 1)
                proj = camera.project(pts, pose)
                uv = proj.uv_px.reshape(n_vehicles, 2, 2)
                w_half = 1.0 * camera.intrinsics.fx_px / np.maximum(x - 2.5, 1.0)
                boxes = np.stack([uv[:, 0, 0] - w_half, uv[:, 0, 1] - 1.5 * w_half, uv[:, 0, 0] + w_half,
                                  uv[:, 0, 1]], 1)
                boxes += rng.normal(0, 0.03, boxes.shape) * (2 * w_half)[:, None]
                frame = CameraImage(np.zeros((1, 1, 3), np.uint8), depth, pose)
                twin = [TwinVehicleView(i + 1, 0.0, float(x[i] + rng.normal(0, 1)), float(ys[i] + rng.normal(0, 1)),
                                        25.0, 0.0, "normal", 0.9, 0, 60.0) for i in range(n_vehicles)]
                dets = Detections.of(boxes)
                t0 = time.perf_counter()
                fusion.step(frame, dets, twin, 0.0)
                times.append(time.perf_counter() - t0)
            results[method] = {"median_ms": round(float(np.median(times)) * 1e3, 4),
                               "p90_ms": round(float(np.percentile(times, 90)) * 1e3, 4)}
    return {"cpu": cpu, "boxes_per_frame": n_vehicles, "twin_vehicles_per_frame": n_vehicles, "frames": frames,
            "methods": results, "target_ms": 0.2,
            "target_met_by": [m for m, r in results.items() if r["median_ms"] <= 0.2]}


DRIVE_TARGET_P99_MS = 33.0
"""Frame time the driving window must keep at p99 (30 FPS) [ms]"""
DRIVE_TARGET_FPS = 30.0
"""Frames per second the driving window must reach [1/s]"""


def bench_drive(duration_s: float = 20.0, vehicles: int = 50, width_px: int = 640, height_px: int = 360,
                condition: str = "adas", seed: int = 0, scenario: str | None = None,
                overrides: list[str] | None = None) -> dict[str, Any]:
    """Frame times of the real driving window, driven by a key script that holds the throttle:
    each frame's work (window events, the simulation steps due at that moment, twin, camera,
    detector and fusion, composing and showing the picture), not the wait for the next frame.

    The window opens on the display when there is one (``DISPLAY`` or ``WAYLAND_DISPLAY`` set)
    and ``SDL_VIDEODRIVER`` does not say otherwise; without a display it is drawn offscreen
    (``SDL_VIDEODRIVER=offscreen``). ``video_driver`` says which SDL used.

    :param duration_s: trial length [s] (real time)
    :param vehicles: vehicles on the road [-]
    :param width_px: window and camera width [px]
    :param height_px: window and camera height [px]
    :param condition: ``adas`` (fusion and overlay on) or ``baseline``
    :return: frame-time median, p90, p99 and max [ms], frames, achieved FPS over the trial's wall
        time, simulated over wall time (1.0: the simulation kept real time), targets and whether
        they are met, the SDL video driver used (``video_driver``: ``x11``, ``wayland``, ``offscreen``...)
        and the display it was given (``display``: ``DISPLAY`` or ``WAYLAND_DISPLAY``, ``None``)
    :raises ConfigError: when the window cannot be opened (a display that cannot be reached)
    """
    display = os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    if not os.environ.get("SDL_VIDEODRIVER") and not display:
        os.environ["SDL_VIDEODRIVER"] = "offscreen"  # no display: draw offscreen
    used: list[str] = []

    def note_driver(_: np.ndarray) -> None:
        if not used:
            used.append(pygame.display.get_driver())

    with tempfile.TemporaryDirectory() as tmp:
        opts = DriveOptions(
            participant="bench", condition=condition, out=Path(tmp), scenario=scenario,
            overrides=[f"highway.vehicles_count={vehicles}", f"camera.width_px={width_px}",
                       f"camera.height_px={height_px}", *(overrides or [])],
            duration_s=duration_s, seed=seed, keys_from=KeyScript.parse("0.5 down UP\n1.5 up UP\n"))
        t0 = time.perf_counter()
        try:
            result = run_drive(opts, on_frame=note_driver)
        except pygame.error as err:
            if used:  # the window was open: not a display problem
                raise
            where = f"SDL_VIDEODRIVER={os.environ['SDL_VIDEODRIVER']}" if os.environ.get("SDL_VIDEODRIVER") \
                else f"the display {display}"
            raise ConfigError(f"cannot open the driving window with {where} ({err}): run headless with "
                              "SDL_VIDEODRIVER=offscreen, or fix the display") from None
        wall = time.perf_counter() - t0
        ms = np.asarray(result["frame_ms"][1:], dtype=float)  # the first frame pays for warm-up
    p99 = float(np.percentile(ms, 99))
    fps = len(ms) / max(result["trial_wall_s"], 1e-9)
    return {
        "condition": condition, "vehicles": vehicles, "size_px": [width_px, height_px], "duration_s": duration_s,
        "end_reason": result["end_reason"], "sim_s": round(result["trial_sim_s"], 2),
        "wall_s": round(result["trial_wall_s"], 2),
        "realtime_factor": round(result["trial_sim_s"] / max(result["trial_wall_s"], 1e-9), 3),
        "frames": int(len(ms)), "fps": round(fps, 1), "fps_target_met": fps >= DRIVE_TARGET_FPS,
        "frame_ms": {"median": round(float(np.median(ms)), 2), "p90": round(float(np.percentile(ms, 90)), 2),
                     "p99": round(p99, 2), "max": round(float(ms.max()), 2)},
        "target_p99_ms": DRIVE_TARGET_P99_MS, "target_met": p99 <= DRIVE_TARGET_P99_MS and fps >= DRIVE_TARGET_FPS,
        "wall_s_with_setup": round(wall, 1), "video_driver": used[0] if used else None, "display": display,
    }


def bench_detector(weights: str | None = None, batch: int = 32, seconds: float = 10.0, threads: int = 2,
                   width_px: int = 320, height_px: int = 180) -> dict[str, Any]:
    """Throughput and latency of the learned detector on rendered frames.

    Times the whole :meth:`~dt_highway.perception.learned.detector.LearnedDetector.detect_batch`
    call (uint8 frames in, boxes out: normalisation, the network, peak picking), batched and
    one frame at a time, for ``seconds`` each, after a warm-up.

    :param weights: weights file (``None``: the shipped weights)
    :param batch: frames per batched call [-]
    :param seconds: time spent on each measurement [s]
    :param threads: torch threads [-]
    :param width_px: frame width [px]
    :param height_px: frame height [px]
    :return: frames/s batched, single-frame latency median/p90/p99 [ms], the settings
    """
    import torch  # lazy: torch takes ~1.3 s to import; only this benchmark needs it

    from dt_highway.perception.learned.data import SceneSettings, make_frame  # lazy: loads torch's detector stack
    from dt_highway.perception.learned.detector import LearnedDetector  # lazy: imports torch

    torch.set_num_threads(threads)
    det = LearnedDetector(weights)
    settings = SceneSettings(width_px, height_px, vary_camera=False)
    frames = [make_frame(s, settings) for s in range(batch)]
    rgbs = [f.rgb for f in frames]
    depths = [f.depth_m for f in frames]
    for _ in range(3):
        det.detect_batch(rgbs, depths)
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        det.detect_batch(rgbs, depths)
        n += batch
    batched_fps = n / (time.perf_counter() - t0)
    lat: list[float] = []  # [ms]
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        i = len(lat) % batch
        t = time.perf_counter()
        det.detect_batch(rgbs[i : i + 1], depths[i : i + 1])
        lat.append(1000.0 * (time.perf_counter() - t))
    lat_a = np.array(lat)
    return {
        "frames_per_s_batched": round(batched_fps, 1),
        "batch": batch,
        "single_frame_ms": {"median": round(float(np.median(lat_a)), 2),
                            "p90": round(float(np.percentile(lat_a, 90)), 2),
                            "p99": round(float(np.percentile(lat_a, 99)), 2)},
        "single_frame_fps": round(1000.0 / float(np.median(lat_a)), 1),
        "image_px": [width_px, height_px],
        "network_px": [det.arch.width_px, det.arch.height_px],
        "threads": threads,
        "weights": str(weights or "shipped"),
        "target_frames_per_s": 200,
        "target_met": bool(batched_fps >= 200),
    }


SIM_SCENARIO = {"vehicles_count": 50, "lanes_count": 4, "simulation_frequency": 15, "policy_frequency": 1}
"""highway-v0's scenario: 50 vehicles, 4 lanes, 15 Hz physics, one decision per second"""


def _steps_per_s(env: gym.Env, seed: int, steps: int, action: int = 1) -> float:
    """Time ``steps`` env steps (the ego keeps ``action``; a crash does not stop the clock) [steps/s]."""
    env.reset(seed=seed)
    t0 = time.perf_counter()
    for _ in range(steps):
        env.step(action)
    return steps / (time.perf_counter() - t0)


def bench_sim(steps: int = 30, seed: int = 0, deviation_s: float = 30.0, repeats: int = 1,
              profile: str | None = None) -> dict[str, Any]:
    """Stock ``highway-v0`` against our env on highway-v0's scenario, in one process.

    Measured, each for ``steps`` env steps from ``reset(seed)`` with the ego idling (a crash
    does not stop the run): stock highway-v0; our env with the twin on and the camera off,
    with plain IDM traffic (``traffic.driver_types = false``: the same models as stock) and
    with its driver types (the default); and our full ADAS pipeline (twin, camera, simulated
    detector, fusion). Deviation: stock and ours (plain IDM traffic) run side by side for
    ``deviation_s`` of simulated time; the largest distance between the same vehicle's
    positions is reported.

    :param steps: env steps per measurement [-]
    :param seed: reset seed
    :param deviation_s: simulated time of the deviation run [s]
    :param repeats: measurements per env (the best is kept) [-]
    :param profile: write a cProfile of one run of our default env to this file
    :return: steps/s per env, ratios to stock, the deviation [m], the ADAS pipeline's step time
    """
    hw = {**SIM_SCENARIO, "duration": 10_000}
    ours_hw = {**hw, "road_length": 10_000.0}
    envs: dict[str, Any] = {
        "stock_highway_v0": gym.make("highway-v0", config=hw).unwrapped,
        "ours_plain_idm": DTHighwayEnv(config={"highway": ours_hw, "traffic": {"driver_types": False}}),
        "ours_driver_types": DTHighwayEnv(config={"highway": ours_hw}),
        "ours_adas_pipeline": DTHighwayEnv(config={"highway": ours_hw, "camera": {"enabled": True},
                                                   "fusion": {"enabled": True}}),
    }
    rates: dict[str, float] = {}
    for name, env in envs.items():
        rates[name] = max(_steps_per_s(env, seed, steps) for _ in range(repeats))
    if profile:
        prof = cProfile.Profile()
        prof.enable()
        _steps_per_s(envs["ours_driver_types"], seed, steps)
        prof.disable()
        prof.dump_stats(profile)
    # deviation: lockstep runs of stock and ours (plain IDM traffic)
    stock, ours = envs["stock_highway_v0"], envs["ours_plain_idm"]
    stock.reset(seed=seed)
    ours.reset(seed=seed)
    n = int(round(deviation_s * SIM_SCENARIO["policy_frequency"]))
    worst, same_count = 0.0, True
    for _ in range(n):
        stock.step(1)
        ours.step(1)
        a = np.array([v.position for v in stock.road.vehicles])
        b = np.array([v.position for v in ours.road.vehicles])
        if a.shape != b.shape:
            same_count = False
            break
        worst = max(worst, float(np.hypot(*(a - b).T).max()))  # distance between the same vehicle's positions
    for env in envs.values():
        env.close()
    stock_rate = rates["stock_highway_v0"]
    return {
        "steps_per_s": {k: round(v, 2) for k, v in rates.items()},
        "ratio_to_stock": {k: round(v / stock_rate, 2) for k, v in rates.items() if k != "stock_highway_v0"},
        "adas_step_ms": round(1000.0 / rates["ours_adas_pipeline"], 1),
        "stock_step_ms": round(1000.0 / stock_rate, 1),
        "max_deviation_m": worst if same_count else None,
        "deviation_sim_s": deviation_s,
        "same_vehicles": same_count,
        "scenario": {**SIM_SCENARIO, "steps": steps, "seed": seed, "ego_action": "IDLE"},
        "target_ratio": 5.0,
        "target_met": bool(rates["ours_driver_types"] >= 5 * stock_rate and rates["ours_plain_idm"] >= 5 * stock_rate
                           and rates["ours_adas_pipeline"] >= stock_rate),
    }
