"""Benchmarks that print numbers (``dt-highway bench ...``), never timed tests."""

from __future__ import annotations

import contextlib
import cProfile
import gc
import math
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import gymnasium as gym
import highway_env  # noqa: F401  (registers highway-v0)
import numpy as np
import pygame

from dt_highway.agent_config import TrainConfig
from dt_highway.camera.pinhole import Intrinsics, Mount, PinholeCamera, Pose
from dt_highway.camera.render import CameraImage
from dt_highway.camera.scene import RoadScene, VehicleSet
from dt_highway.config import ConfigError, DTConfig, merge
from dt_highway.env import DTHighwayEnv, make_camera
from dt_highway.hmi.drive import DriveOptions, run_drive
from dt_highway.hmi.keys import KeyScript
from dt_highway.perception import METHODS, Detections, Fusion, FusionSettings
from dt_highway.rl.preroll import ahead_ok
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
DRIVE_TARGET_PICTURE_SHARE = 0.95
"""Share of the simulation's steps the driving window must show (pictures per second over the
simulation frequency; a picture is drawn only when a step changed it) [-]"""


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
    :param seed: traffic seed
    :param scenario: scenario file (``None``: the defaults)
    :param overrides: further ``--set`` strings (after those of ``vehicles``, ``width_px`` and ``height_px``)
    :return: frame-time median, p90, p99 and max [ms] of the frames that drew a picture, frames,
        ``fps``: pictures shown per second of the trial's wall time (at most the simulation
        frequency: a picture is drawn when a step changed it), simulated over wall time (1.0: the
        simulation kept real time), targets (p99 <= 33 ms, ``fps`` >= 0.95 x the simulation
        frequency) and whether they are met, the SDL video driver used (``video_driver``: ``x11``,
        ``wayland``, ``offscreen``...) and the display it was given (``display``: ``DISPLAY`` or ``WAYLAND_DISPLAY``, ``None``)
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
    fps_target = DRIVE_TARGET_PICTURE_SHARE * float(result["simulation_frequency_hz"])
    return {
        "condition": condition, "vehicles": vehicles, "size_px": [width_px, height_px], "duration_s": duration_s,
        "end_reason": result["end_reason"], "sim_s": round(result["trial_sim_s"], 2),
        "wall_s": round(result["trial_wall_s"], 2),
        "realtime_factor": round(result["trial_sim_s"] / max(result["trial_wall_s"], 1e-9), 3),
        "frames": int(len(ms)), "fps": round(fps, 1), "fps_target": round(fps_target, 1),
        "fps_target_met": fps >= fps_target,
        "frame_ms": {"median": round(float(np.median(ms)), 2), "p90": round(float(np.percentile(ms, 90)), 2),
                     "p99": round(p99, 2), "max": round(float(ms.max()), 2)},
        "target_p99_ms": DRIVE_TARGET_P99_MS, "target_met": p99 <= DRIVE_TARGET_P99_MS and fps >= fps_target,
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


def deviation_steps(deviation_s: float) -> int:
    """The decisions (env steps) of :func:`bench_sim`'s deviation run of ``deviation_s`` [s].

    :param deviation_s: length of the deviation run [s]
    :return: the number of env steps (``deviation_s`` x the policy frequency, rounded half up)
    :raises ValueError: when that is none (one line naming the least ``deviation_s``)
    """
    f = SIM_SCENARIO["policy_frequency"]
    n = math.floor(deviation_s * f + 0.5)  # half up: round() takes 0.5 to 0
    if n < 1:
        raise ValueError(f"--deviation-s must be at least {0.5 / f:g} s: the deviation run compares whole decisions, "
                         f"{f:g} a second (got {deviation_s:g})")
    return n


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
    :param deviation_s: simulated time of the deviation run [s], in whole decisions (one a second)
    :param repeats: measurements per env (the best is kept) [-]
    :param profile: write a cProfile of one run of our default env to this file
    :return: steps/s per env, ratios to stock, the deviation [m] over ``deviation_sim_s`` (``deviation_s``
        rounded to whole decisions), the ADAS pipeline's step time
    :raises ValueError: on a ``deviation_s`` shorter than half a decision (no step to compare)
    """
    n = deviation_steps(deviation_s)
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
        "deviation_sim_s": n / SIM_SCENARIO["policy_frequency"],
        "same_vehicles": same_count,
        "scenario": {**SIM_SCENARIO, "steps": steps, "seed": seed, "ego_action": "IDLE"},
        "target_ratio": 5.0,
        "target_met": bool(rates["ours_driver_types"] >= 5 * stock_rate and rates["ours_plain_idm"] >= 5 * stock_rate
                           and rates["ours_adas_pipeline"] >= stock_rate),
    }


TRAIN_TARGET_STEPS_PER_S = 300.0
"""PPO steps/s the fast training path should reach on 2 cores with the kinematic settings [1/s]"""


def _load_1min() -> float:
    """The machine's 1-minute load average (``uptime``) [-] (NaN where there is none)."""
    try:
        return round(os.getloadavg()[0], 2)
    except OSError:
        return float("nan")


def _cpu_s(pids: list[int]) -> float:
    """CPU time (user + system) the processes ``pids`` have used so far [s] (Linux ``/proc``; NaN elsewhere)."""
    try:
        total = 0
        for pid in pids:
            with open(f"/proc/{pid}/stat") as fh:
                fields = fh.read().rsplit(")", 1)[1].split()
            total += int(fields[11]) + int(fields[12])  # utime, stime [clock ticks]
        return total / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return float("nan")


def _env_only(make: Callable[[], gym.Env], steps: int, seed: int) -> dict[str, Any]:
    """``steps`` env steps, one process, random actions drawn from ``seed`` (the same for every env).

    :return: reset time [s] (the first, with its pre-roll), steps/s after it (later resets included),
        the observations and rewards
    """
    env = make()
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    obs, _ = env.reset()
    reset_s = time.perf_counter() - t0
    n_actions = int(env.action_space.n)  # type: ignore[attr-defined]  # the discrete menus of the kinematic settings
    seen, rewards, load = [np.asarray(obs)], [], _load_1min()
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(steps):
        obs, reward, terminated, truncated, _ = env.step(int(rng.integers(n_actions)))
        seen.append(np.asarray(obs))
        rewards.append(float(reward))
        if terminated or truncated:
            seen.append(np.asarray(env.reset()[0]))
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    env.close()
    return {"reset_s": round(reset_s, 3), "steps_per_s": round(steps / wall, 1),
            "steps_per_cpu_s": round(steps / cpu, 1) if cpu > 0 else None, "load_1min": load,
            "obs": np.stack(seen), "rewards": np.asarray(rewards)}


def _children(pids: list[int]) -> list[int]:
    """The processes whose parent is one of ``pids`` (Linux ``/proc``; none elsewhere)."""
    found = []
    try:
        names = os.listdir("/proc")
    except OSError:
        return []
    for name in names:
        if not name.isdigit():
            continue
        try:
            with open(f"/proc/{name}/stat") as fh:
                ppid = int(fh.read().rsplit(")", 1)[1].split()[1])
        except (OSError, ValueError, IndexError):
            continue
        if ppid in pids:
            found.append(int(name))
    return found


def _ppo_run(cfg: TrainConfig, env_dict: dict[str, Any], n_envs: int, timesteps: int,
             progress: Callable[[int], None] | None, ahead: bool = False) -> dict[str, Any]:
    """Train PPO (or the file's algorithm) for ``timesteps`` as ``dt-highway train`` does (same env
    factories, reward, seeds, model), without evaluations or checkpoints, and time it.

    :return: steps, wall time of ``learn`` [s] (workers' start-up apart, and with ``ahead`` their
        helpers' up to their first start made ahead: ``setup_s``), steps/s, and the
        split: the learner's updates (``update_s``, its ``train()`` calls) and the rest, collecting
        rollouts (``collect_s``: env steps with their resets, the policy's forward passes) [s]; the CPU
        time of the learner and the workers over ``learn`` (``cpu_s`` [s], a figure that the other
        programs on a shared machine change less than the wall time) and steps per CPU second
    """
    from stable_baselines3.common.callbacks import BaseCallback  # lazy: torch (~1.3 s), only this benchmark
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv  # lazy: torch, only this benchmark

    from dt_highway.rl.train import _close, _make_env, build_model  # lazy: torch

    class Progress(BaseCallback):
        def _on_step(self) -> bool:
            if progress is not None:
                progress(self.training_env.num_envs)
            return True

    t0 = time.perf_counter()
    factories = [_make_env(env_dict, cfg.seed * 1_000_000 + i, n_envs, cfg.reward, ahead) for i in range(n_envs)]
    venv = SubprocVecEnv(factories, start_method="spawn") if n_envs > 1 else DummyVecEnv(factories)
    if ahead:  # the helpers' start-up apart too: their first start is made before the clock starts
        venv.reset()
        venv.env_method("wait_ready")
    setup_s = time.perf_counter() - t0
    load = _load_1min()
    try:
        model = build_model(cfg.model_copy(update={"n_envs": n_envs}), venv)
        learner_s = [0.0]
        algo: Any = model  # an on-policy algorithm: its train() is one update after each rollout
        update = algo.train

        def timed_update() -> None:  # the learner's share: stable-baselines3's train() after each rollout
            t = time.perf_counter()
            update()
            learner_s[0] += time.perf_counter() - t

        algo.train = timed_update
        workers = [p.pid for p in getattr(venv, "processes", []) if p.pid is not None]
        workers += _children(workers)  # the workers' pre-roll helpers
        t0, c0, w0 = time.perf_counter(), time.process_time(), _cpu_s(workers)
        model.learn(timesteps, callback=Progress())
        wall = time.perf_counter() - t0
        cpu = time.process_time() - c0 + (_cpu_s(workers) - w0 if workers else 0.0)
    finally:
        _close(venv)
    steps = int(model.num_timesteps)
    return {"n_envs": n_envs, "vec_env": type(venv).__name__, "preroll_ahead": ahead, "steps": steps,
            "setup_s": round(setup_s, 2),
            "wall_s": round(wall, 2), "steps_per_s": round(steps / wall, 1),
            "collect_s": round(wall - learner_s[0], 2), "update_s": round(learner_s[0], 2),
            "collect_steps_per_s": round(steps / (wall - learner_s[0]), 1),
            "cpu_s": round(cpu, 2), "steps_per_cpu_s": round(steps / cpu, 1) if cpu > 0 else None,
            "load_1min_before": load, "load_1min_after": _load_1min()}


def bench_train(cfg: TrainConfig, timesteps: int = 8192, n_envs: int = 4, env_steps: int = 600, seed: int = 0,
                progress: Callable[[int], None] | None = None) -> dict[str, Any]:
    """Training throughput of a training file: today's path beside the fast one, in one run.

    * **today**: what ``dt-highway train`` did before the fast path, the training file's env
      (twin, camera, fusion... all on) in ``cfg.n_envs`` envs (``DummyVecEnv`` for one);
    * **fast**: the env of :func:`~dt_highway.rl.train.lean_env_config` (what the observation
      and the reward do not read, off) in ``n_envs`` ``SubprocVecEnv`` workers of one torch and one
      OpenCV thread each, the learner on one torch thread; each episode's start computed ahead by a
      helper process per worker when the configuration allows it
      (:class:`~dt_highway.rl.preroll.PrerollAhead`; ``preroll_ahead`` says whether it ran).

    Measured: env-only steps/s of each env in this process (the same seeded episode, the same
    random actions), whether their observations and rewards are identical (the fast path's
    promise; ``marked_entries`` counts the ``marked`` cells that were 1, so that an ``adas``
    comparison is not an empty one), and PPO steps/s of each path over ``timesteps`` (its
    ``learn`` call; workers' start-up apart), split into collecting rollouts and the learner's updates.
    The machine's load (``uptime``) is given beside each number, and the CPU time each path used
    (steps per CPU second: on ``k`` free cores a path cannot beat ``k`` times it).

    :param cfg: the training configuration (:class:`~dt_highway.agent_config.TrainConfig`)
    :param timesteps: PPO steps per path (rounded up to whole rollouts by stable-baselines3) [-]
    :param n_envs: worker processes of the fast path [-] (two per core: a worker's reset, its 60 s pre-roll,
        then stalls one of them, not a core; 4 on 2 cores gave 301 PPO steps/s where 2 gave 262, load ~2)
    :param env_steps: env steps of the env-only measurement [-]
    :param seed: seed of the env-only episode and its random actions
    :param progress: called with the number of steps done (env-only, then PPO)
    :return: ``env_only``, ``ppo`` (``today`` and ``fast`` each), ``speedup``, the target and whether it is met
    """
    import torch  # lazy: ~1.3 s, only this benchmark

    from dt_highway.rl.train import _make_env, lean_env_config  # lazy: torch

    env_cfg = cfg.env_config()
    lean_cfg, switched_off = lean_env_config(env_cfg)
    full_dict, lean_dict = env_cfg.to_dict(), lean_cfg.to_dict()
    if cfg.observation != "vision":
        torch.set_num_threads(1)  # as dt-highway train: a small MLP, one thread
    env_only: dict[str, Any] = {}
    for name, d in (("today", full_dict), ("fast", lean_dict)):
        env_only[name] = _env_only(_make_env(d, seed, 1, cfg.reward), env_steps, seed)
        if progress is not None:
            progress(env_steps)
    a, b = env_only["today"], env_only["fast"]
    same_obs = a["obs"].shape == b["obs"].shape and bool(np.array_equal(a["obs"], b["obs"]))
    same_rewards = bool(np.array_equal(a["rewards"], b["rewards"]))
    column = {"adas": -1, "adas-threat": -3}.get(cfg.observation)  # the ``marked`` column
    marked = int(np.sum(a["obs"][..., column] == 1.0)) if column is not None else None
    for r in env_only.values():
        del r["obs"], r["rewards"]
    ppo = {"today": _ppo_run(cfg, full_dict, cfg.n_envs, timesteps, progress),
           "fast": _ppo_run(cfg, lean_dict, n_envs, timesteps, progress, ahead=n_envs > 1 and ahead_ok(lean_cfg))}
    fast = ppo["fast"]["steps_per_s"]
    kinematic = cfg.observation in ("kinematics", "adas")
    return {
        "config": {"observation": cfg.observation, "action": cfg.action, "scenario": cfg.scenario,
                   "algorithm": cfg.algorithm},
        "cpus": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
        "switched_off": switched_off,
        "env_only": {**env_only, "steps": env_steps, "seed": seed, "same_observations": same_obs,
                     "same_rewards": same_rewards, "marked_entries": marked},
        "ppo": ppo,
        "speedup": round(fast / ppo["today"]["steps_per_s"], 2),
        "target_steps_per_s": TRAIN_TARGET_STEPS_PER_S if kinematic else None,
        "target_met": bool(fast >= TRAIN_TARGET_STEPS_PER_S) if kinematic else None,
    }


@dataclass(frozen=True)
class StartupCase:
    """One command ``bench startup`` times.

    :param args: the arguments of ``python`` (``-c CODE`` or ``-m MODULE ...``)
    :param exit_code: the status it exits with (2: a mistake on the command line)
    """

    args: tuple[str, ...]
    exit_code: int = 0


STARTUP_CASES: dict[str, StartupCase] = {
    "python (nothing imported)": StartupCase(("-c", "pass")),
    "dt-highway --help": StartupCase(("-m", "dt_highway.cli", "--help")),
    "dt-highway study --help": StartupCase(("-m", "dt_highway.cli", "study", "--help")),
    "dt-highway study --bogus (a mistake)": StartupCase(("-m", "dt_highway.cli", "study", "--bogus"), exit_code=2),
    "dt-highway run --set nosuch=1 (a bad setting)": StartupCase(("-m", "dt_highway.cli", "run", "--set", "nosuch=1"),
                                                                 exit_code=2),
    "import dt_highway": StartupCase(("-c", "import dt_highway")),
    "import dt_highway + gym.make": StartupCase(
        ("-c", "import gymnasium as gym, dt_highway\ngym.make('dt-highway-v0').close()")),
}
"""What ``bench startup`` times, each in a new Python process: the command line's answers that import no
simulation (help, a mistyped option, a bad setting: the configuration is checked first), and the package's import
with and without building the env"""

STARTUP_QUICK = ("dt-highway --help", "dt-highway study --help", "dt-highway study --bogus (a mistake)")
"""The answers that should feel immediate: help and a mistyped option"""

STARTUP_TARGET_S = 0.5
"""Each of :data:`STARTUP_QUICK` answers within this much wall time (median) [s]"""


def _run_case(name: str, case: StartupCase, env: dict[str, str]) -> float:
    """Run one case in a new process.

    :return: its wall time from start to exit [s]
    :raises RuntimeError: it exited with another status than the case's (its last line of stderr)
    """
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, *case.args], capture_output=True, text=True, env=env, check=False)
    elapsed = time.perf_counter() - t0
    if proc.returncode != case.exit_code:
        last = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        raise RuntimeError(f"{name} exited with {proc.returncode}: {last}")
    return elapsed


def bench_startup(repeats: int = 5, progress: Callable[[], None] | None = None) -> dict[str, Any]:
    """Wall time from starting Python to its exit for each of :data:`STARTUP_CASES`, in new processes.

    Each case runs once untimed (so that no timed run reads the files from disk for the first time), then
    ``repeats`` times in turn. The children run headless (``SDL_VIDEODRIVER=offscreen`` unless set).

    :param repeats: timed runs of each case [-]
    :param progress: called after each timed run (a progress bar)
    :return: median, least and most wall time per case [s], the quick answers' target and whether each met it
    :raises RuntimeError: a case failed (its last line of stderr)
    """
    env = {**os.environ, "SDL_VIDEODRIVER": os.environ.get("SDL_VIDEODRIVER", "offscreen")}
    for name, case in STARTUP_CASES.items():
        _run_case(name, case, env)
    times: dict[str, list[float]] = {name: [] for name in STARTUP_CASES}
    for _ in range(repeats):
        for name, case in STARTUP_CASES.items():
            times[name].append(_run_case(name, case, env))
            if progress is not None:
                progress()
    cases = {name: {"median_s": round(float(np.median(t)), 3), "min_s": round(min(t), 3), "max_s": round(max(t), 3)}
             for name, t in times.items()}
    return {"repeats": repeats, "python": sys.executable, "cases": cases, "target_s": STARTUP_TARGET_S,
            "target_met": {name: cases[name]["median_s"] <= STARTUP_TARGET_S for name in STARTUP_QUICK}}
