"""The driving window: a participant drives the ego from the first-person camera view.

One trial: the scenario's highway with the ego under the keyboard (:mod:`dt_highway.hmi.keys`),
the synthetic camera as the main picture, in the ADAS condition the overlay's steady marks
drawn on it (:func:`dt_highway.overlay.draw_overlay`, from the fusion's output only), a HUD
(speed in km/h, lane, time left, condition) and highway-env's top-down view as a mini-map
(M toggles it). The simulation is locked to the wall clock at its configured frequency; the
window redraws at up to ``fps`` frames per second.

Every trial is logged like a scripted one (:mod:`dt_highway.metrics.trial_log`), plus every key press
and release with its time and the keys held at each step. ``--keys-from`` replays a key
script (no prompts or confirmations then), ``--screenshot-every`` saves PNGs of exactly what
the participant saw. Headless: ``SDL_VIDEODRIVER=offscreen``.
"""

from __future__ import annotations

import math
import queue
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import cv2
import gymnasium as gym
import numpy as np
import pygame  # loaded (without its banner) by highway-env already, which sets PYGAME_HIDE_SUPPORT_PROMPT

from dt_highway.conditions import condition_config, display_name
from dt_highway.config import DTConfig, deep_merge, load_config
from dt_highway.env.core import DTHighwayEnv
from dt_highway.hmi.keys import KeyEvent, KeyScript, Pedals, Steering
from dt_highway.metrics.trial_log import TrialRecorder, TrialWriter
from dt_highway.overlay import draw_overlay

LEGEND = (
    ("Up", "throttle (hold)"),
    ("Down", "brake (hold)"),
    ("Left / Right", "change lane"),
    ("M", "mini-map on / off"),
    ("P", "pause"),
    ("Esc", "quit (asks first)"),
)
"""The keys, as shown before a trial"""


def drive_config(condition: str, steering: bool = False) -> dict[str, Any]:
    """What a keyboard trial changes in the configuration: the ``Driver`` action with one
    decision per simulation step (the keys act at once), the camera in every condition (it is
    the participant's view, and the observation), the fusion and its overlay as the condition says
    (:func:`~dt_highway.conditions.condition_config`: ``adas``, ``adas-threat``, ``sham``...).

    :raises ConfigError: on an unknown condition (one line naming the allowed ones)
    """
    cond = condition_config(condition)
    # the window shows the camera frame: as observation it costs nothing more (one rendering
    # per step), where highway-env's Kinematics table would cost ~10 ms a step with 50 vehicles
    action: dict[str, Any] = {"type": "Driver", "steering": True} if steering else {"type": "Driver"}
    return deep_merge(cond, {"highway": {"action": action, "observation": {"type": "Camera"}}, "camera": {"enabled": True}})


@dataclass
class Hud:
    """What the HUD shows.

    :param speed_kmh: ego speed [km/h]
    :param lane: lane number, 1 = leftmost
    :param n_lanes: lanes on the road
    :param time_left_s: trial time left [s]
    :param condition: the condition's name as the participant is told it (``baseline`` or ``adas``: a
        sham condition shows ``adas``; ``practice`` for a practice trial)
    :param paused: the trial is paused
    """

    speed_kmh: float
    lane: int
    n_lanes: int
    time_left_s: float
    condition: str
    paused: bool = False


def _text(img: np.ndarray, text: str, org: tuple[int, int], scale: float, colour: tuple[int, int, int] = (255, 255, 255),
          thick: int = 1, shadow: bool = True) -> None:
    font = cv2.FONT_HERSHEY_DUPLEX
    if shadow:
        cv2.putText(img, text, (org[0] + 1, org[1] + 1), font, scale, (0, 0, 0), thick + 1, cv2.LINE_AA)
    cv2.putText(img, text, org, font, scale, colour, thick, cv2.LINE_AA)


def compose_frame(rgb: np.ndarray, marks: list[dict[str, Any]] | None, hud: Hud,
                  minimap: np.ndarray | None = None) -> np.ndarray:
    """The picture the participant sees: the camera frame, the marks (ADAS), the HUD and the
    mini-map. Used by the window and by the screenshots, so both show the same.

    :param rgb: camera frame ``uint8 (H, W, 3)``
    :param marks: the overlay's marks, or ``None`` (baseline: nothing drawn)
    :param hud: the HUD's values
    :param minimap: highway-env's top-down view, or ``None`` (hidden)
    :return: ``uint8 (H, W, 3)`` RGB
    """
    out = draw_overlay(rgb, marks) if marks else np.ascontiguousarray(rgb).copy()
    h, w = out.shape[:2]
    s = max(h / 720.0, 0.35)
    pad = int(16 * s)
    t1, t2, t4 = max(1, round(1.5 * s)), max(1, round(2 * s)), max(1, round(4 * s))
    small = None
    if minimap is not None:  # bottom right, in the HUD's band: the sky stays free for the marks' labels
        mh, mw = minimap.shape[:2]
        tw = int(w * 0.36)
        small = cv2.resize(minimap, (tw, max(1, int(mh * tw / mw))), interpolation=cv2.INTER_AREA)
    band_h = max(int(110 * s), (small.shape[0] + 2 * pad) if small is not None else 0)
    band = out[h - band_h:, :]
    band[:] = (band * 0.45).astype(np.uint8)
    base = h - band_h // 2
    _text(out, f"{hud.speed_kmh:3.0f}", (pad, base + int(38 * s)), 2.6 * s, thick=t4, shadow=False)
    _text(out, "km/h", (pad + int(175 * s), base + int(38 * s)), 0.9 * s, thick=t2, shadow=False)
    _text(out, f"lane {hud.lane} of {hud.n_lanes}", (pad + int(300 * s), base - int(6 * s)), 1.0 * s, thick=t1, shadow=False)
    mins, secs = divmod(max(int(math.ceil(hud.time_left_s)), 0), 60)
    _text(out, f"time left {mins}:{secs:02d}", (pad + int(300 * s), base + int(34 * s)), 1.0 * s, thick=t1, shadow=False)
    if small is not None:
        th, tw = small.shape[:2]
        x0, y0 = w - tw - pad, h - band_h + (band_h - th) // 2
        out[y0:y0 + th, x0:x0 + tw] = small
        cv2.rectangle(out, (x0 - 1, y0 - 1), (x0 + tw, y0 + th), (200, 200, 200), 1)
    (cw, ch), _ = cv2.getTextSize(hud.condition.upper(), cv2.FONT_HERSHEY_DUPLEX, 0.9 * s, t1)
    cv2.rectangle(out, (pad // 2, pad // 2), (pad + cw + pad // 2, pad + ch + pad // 2), (0, 0, 0), -1)
    _text(out, hud.condition.upper(), (pad, pad + ch), 0.9 * s, (255, 230, 120), thick=t1, shadow=False)
    if hud.paused:
        _text(out, "PAUSED (P to go on)", (w // 2 - int(250 * s), h // 2), 1.4 * s, (255, 230, 120),
              thick=max(1, round(3 * s)))
    return out


def card(size: tuple[int, int], title: str, lines: list[str]) -> np.ndarray:
    """A plain screen with a title and lines of text (start, break and end screens).

    :param size: ``(width, height)`` [px]
    """
    w, h = size
    out = np.full((h, w, 3), 28, np.uint8)
    s = max(h / 720.0, 0.35)
    _text(out, title, (int(40 * s), int(90 * s)), 1.6 * s, (255, 230, 120), thick=max(1, round(3 * s)), shadow=False)
    for i, line in enumerate(lines):
        _text(out, line, (int(40 * s), int((160 + 48 * i) * s)), 0.95 * s, thick=max(1, round(2 * s)), shadow=False)
    return out


@dataclass
class DriveOptions:
    """One keyboard trial.

    :param participant: participant id
    :param condition: one of :data:`~dt_highway.conditions.CONDITIONS` (``baseline``, ``adas``, ``sham``...)
    :param out: the study directory (the trial goes to ``<out>/trials/<participant>-<condition>``)
    :param practice: a practice trial (``<participant>-practice``; left out of the report)
    :param scenario: scenario file
    :param overrides: ``--set`` strings
    :param duration_s: trial length [s] (``None``: the scenario's)
    :param seed: traffic seed
    :param keys_from: a key script to replay instead of the keyboard
    :param screenshot_every_s: save a screenshot this often [s of trial time] (``None``: never)
    :param screenshots: where screenshots go (default ``<trial>/screenshots``)
    :param fps: most window frames per second
    :param minimap: show the mini-map at the start
    :param steering: Left/Right steer (self-centring) instead of changing lanes
    """

    participant: str
    condition: str
    out: Path
    practice: bool = False
    scenario: str | None = None
    overrides: list[str] = field(default_factory=list)
    duration_s: float | None = None
    seed: int = 0
    keys_from: KeyScript | None = None
    screenshot_every_s: float | None = None
    screenshots: Path | None = None
    fps: int = 60
    minimap: bool = True
    steering: bool = False


def _show(screen: pygame.Surface, img: np.ndarray, on_frame: Callable[[np.ndarray], None] | None = None) -> None:
    """Put ``img`` on the window."""
    screen.blit(pygame.image.frombuffer(np.ascontiguousarray(img).tobytes(), screen.get_size(), "RGB"), (0, 0))
    pygame.display.flip()
    if on_frame is not None:
        on_frame(img)


def _wait_key(screen: pygame.Surface, clock: pygame.time.Clock, img: np.ndarray, keys: tuple[int, ...],
              seconds: float | None = None, on_frame: Callable[[np.ndarray], None] | None = None) -> int | None:
    """Show ``img`` until one of ``keys`` (any key when empty) is pressed or ``seconds`` pass.

    :return: the key pressed (Esc when the window is closed), ``None`` after ``seconds``
    """
    _show(screen, img, on_frame)
    t_end = None if seconds is None else time.monotonic() + seconds
    while t_end is None or time.monotonic() < t_end:
        for ev in pygame.event.get():
            if ev.type == pygame.QUIT:
                return pygame.K_ESCAPE
            if ev.type == pygame.KEYDOWN and (not keys or ev.key in keys):
                return ev.key
        clock.tick(30)
    return None


def show_card(size: tuple[int, int], title: str, lines: list[str], timeout_s: float | None = None) -> bool:
    """Show a screen (e.g. a break between trials) until Enter is pressed.

    :param size: window size ``(width, height)`` [px]
    :param timeout_s: give up waiting after this long (``None``: wait for Enter)
    :return: ``False`` when the participant pressed Esc or closed the window
    """
    pygame.display.init()
    try:
        screen = pygame.display.set_mode(size)
        key = _wait_key(screen, pygame.time.Clock(), card(size, title, lines),
                        (pygame.K_RETURN, pygame.K_KP_ENTER, pygame.K_ESCAPE), timeout_s)
        return key != pygame.K_ESCAPE
    finally:
        pygame.quit()


PYGAME_KEYS = {"UP": "K_UP", "DOWN": "K_DOWN", "LEFT": "K_LEFT", "RIGHT": "K_RIGHT", "P": "K_p", "ESC": "K_ESCAPE",
               "M": "K_m"}


def trial_dir(out: Path, participant: str, condition: str, practice: bool) -> Path:
    """Where a keyboard trial is logged."""
    return Path(out) / "trials" / f"{participant}-{'practice' if practice else condition}"


@dataclass
class _Snapshot:
    """What the window shows of one simulation step (made by the simulation thread)."""

    rgb: np.ndarray
    marks: list[dict[str, Any]] | None
    hud: Hud
    minimap: np.ndarray | None
    n_steps: int


class _Trial:
    """The simulation side of a keyboard trial: runs in its own thread, locked to the wall
    clock, and hands the window a snapshot after every simulation step.

    Every write to the trial log happens on this thread; the window only reads snapshots and
    posts key events.
    """

    def __init__(self, env: gym.Env, log: TrialWriter, opts: DriveOptions, label: str, info: dict[str, Any],
                 shots_dir: Path) -> None:
        u = env.unwrapped
        if not isinstance(u, DTHighwayEnv):
            raise TypeError(f"a keyboard trial drives a dt-highway-v0 env (got {type(u).__name__})")
        self.env, self.u, self.log, self.opts, self.label = env, u, log, opts, label
        self.cfg_fusion = self.u.dt_config.fusion.enabled
        self.duration = self.u.dt_config.highway.duration
        self.dt = 1.0 / self.u.dt_config.highway.simulation_frequency
        self.rec = TrialRecorder(log)
        self.pedals, self.wheel = Pedals(), Steering()
        self.held: set[str] = set()
        self.lane_tap = 0
        self.n_steps = 0
        self.info = info
        self.paused = self.confirm_quit = False
        self.show_map = opts.minimap
        self.done = False
        self.end_reason, self.status = "time limit", "completed"
        self.error: BaseException | None = None
        self.keys_in: queue.SimpleQueue[tuple[bool, str]] = queue.SimpleQueue()
        self.lock = threading.Lock()
        self.snapshot: _Snapshot | None = None
        self.shots_dir = shots_dir
        self.next_shot = 0.0 if opts.screenshot_every_s else math.inf
        self.shots = 0
        self._paused_s = 0.0
        self._pause_start = 0.0
        self.rec.record(info, np.array([self.pedals.accel_mps2, 0.0]), "")
        self._publish()

    @property
    def t_sim(self) -> float:
        """Trial time [s]."""
        return self.n_steps * self.dt

    # ---------------------------------------------------------------- keys
    def _toggle_pause(self, on: bool) -> None:
        if on and not self.paused:
            self.paused, self._pause_start = True, time.monotonic()
        elif not on and self.paused:
            self.paused = False
            self._paused_s += time.monotonic() - self._pause_start

    def key_event(self, ev: KeyEvent) -> None:
        """Log a key press or release and act on it."""
        self.log.event("key_down" if ev.down else "key_up", ev.t_s, key=ev.key)
        if not ev.down:
            self.held.discard(ev.key)
            return
        self.held.add(ev.key)
        scripted = self.opts.keys_from is not None
        if ev.key == "ESC":
            if self.confirm_quit or scripted:
                self.stop("quit by the participant")
            else:
                self.confirm_quit = True
                self._toggle_pause(True)
        elif self.confirm_quit:  # any other key: go on
            self.confirm_quit = False
            self._toggle_pause(False)
        elif ev.key in ("LEFT", "RIGHT") and not self.opts.steering:
            self.lane_tap = -1 if ev.key == "LEFT" else 1
        elif ev.key == "P":
            self._toggle_pause(not self.paused)
        elif ev.key == "M":
            self.show_map = not self.show_map

    def stop(self, reason: str, status: str = "aborted") -> None:
        """End the trial."""
        if not self.done:
            self.done, self.end_reason, self.status = True, reason, status

    # ---------------------------------------------------------------- simulation
    def _publish(self) -> None:
        u = self.u
        ego = u.vehicle
        hud = Hud(float(ego.speed) * 3.6, int(ego.lane_index[2]) + 1,
                  len(u.road.network.graph[ego.lane_index[0]][ego.lane_index[1]]), self.duration - self.t_sim,
                  self.label, self.paused)
        marks = (self.info.get("adas") or {}).get("overlay") if self.cfg_fusion else None
        minimap = self.env.render() if self.show_map else None  # rgb_array mode: an image
        assert minimap is None or isinstance(minimap, np.ndarray)
        snap = _Snapshot(u.camera_image().rgb, marks, hud, minimap, self.n_steps)
        with self.lock:
            self.snapshot = snap
        if self.t_sim + 1e-9 >= self.next_shot:  # what the window shows of this step, saved
            self.shots_dir.mkdir(parents=True, exist_ok=True)
            img = compose_frame(snap.rgb, snap.marks, snap.hud, snap.minimap)
            cv2.imwrite(str(self.shots_dir / f"t{self.t_sim:07.2f}s.png"), img[..., ::-1])
            self.shots += 1
            self.next_shot += self.opts.screenshot_every_s or math.inf

    def _step(self) -> None:
        held = self.held
        accel = self.pedals.update("UP" in held, "DOWN" in held, self.dt)
        if self.opts.steering:
            action = np.array([accel, self.wheel.update("LEFT" in held, "RIGHT" in held, self.dt)])
        else:
            action = np.array([accel, float(self.lane_tap)])
        self.lane_tap = 0
        _, _, terminated, truncated, self.info = self.env.step(action)
        self.n_steps += 1
        self.rec.record(self.info, action, ";".join(sorted(held)))
        if terminated or truncated:
            self.stop("collision" if self.u.vehicle.crashed else "time limit", "completed")
        self._publish()

    def run(self) -> None:
        """The simulation loop (thread body): keys, then the steps the wall clock asks for."""
        script = self.opts.keys_from
        wall0 = time.monotonic()
        try:
            while not self.done:
                while True:
                    try:
                        down, key = self.keys_in.get_nowait()
                    except queue.Empty:
                        break
                    self.key_event(KeyEvent(self.t_sim, down, key))
                if script is not None and self.paused:  # a script's pause lasts in wall time
                    for ev in script.due(self.t_sim + time.monotonic() - self._pause_start):
                        self.key_event(ev)
                if self.done:
                    break
                now = time.monotonic() - wall0 - self._paused_s
                if self.paused or self.t_sim + self.dt > now + 1e-9:
                    wait = 0.01 if self.paused else self.t_sim + self.dt - now
                    time.sleep(min(max(wait, 0.0), 0.005))
                    continue
                if script is not None:
                    for ev in script.due(self.t_sim):
                        self.key_event(ev)
                    if self.done or self.paused:
                        continue
                self._step()
        except BaseException as err:  # noqa: BLE001 - handed to the window's thread, which re-raises it
            self.error = err
            self.done = True


@dataclass
class _Window:
    """The trial's pygame window; every frame shown on it also goes to ``on_frame``."""

    screen: pygame.Surface
    clock: pygame.time.Clock
    size: tuple[int, int]
    on_frame: Callable[[np.ndarray], None] | None = None

    @classmethod
    def open(cls, size: tuple[int, int], caption: str,
             on_frame: Callable[[np.ndarray], None] | None = None) -> _Window:
        """Open the window (pygame's display only: text is drawn with OpenCV, no sound)."""
        pygame.display.init()
        screen = pygame.display.set_mode(size)
        pygame.display.set_caption(caption)
        return cls(screen, pygame.time.Clock(), size, on_frame)

    def show(self, img: np.ndarray) -> None:
        _show(self.screen, img, self.on_frame)

    def wait_key(self, img: np.ndarray, keys: tuple[int, ...], seconds: float | None = None) -> int | None:
        return _wait_key(self.screen, self.clock, img, keys, seconds, self.on_frame)


def _trial_config(opts: DriveOptions) -> tuple[DTConfig, list[str], float]:
    """The trial's configuration, with one decision per simulation step.

    :return: the configuration, the ``--set`` strings (``--duration`` among them) and the
        simulation frequency [Hz]
    """
    overrides = list(opts.overrides)
    if opts.duration_s is not None:
        overrides.append(f"highway.duration={opts.duration_s}")
    cfg = load_config(opts.scenario, overrides, drive_config(opts.condition, opts.steering))
    f_sim = cfg.highway.simulation_frequency
    cfg = load_config(opts.scenario, [*overrides, f"highway.policy_frequency={f_sim}"],
                      drive_config(opts.condition, opts.steering))
    return cfg, overrides, f_sim


def _trial_meta(opts: DriveOptions, cfg: DTConfig, overrides: list[str], f_sim: float) -> dict[str, Any]:
    """The trial log's metadata (as a scripted trial's, the driver being the keyboard)."""
    return {"driver": "keyboard", "driver_file": None,
            "driver_params": {"keys_from": opts.keys_from is not None, "steering": opts.steering},
            "participant": opts.participant, "condition": opts.condition, "practice": opts.practice,
            "pair": None, "seed": opts.seed, "scenario": opts.scenario, "overrides": overrides,
            "config": cfg.to_dict(), "simulation_frequency_hz": f_sim}


def _start_screens(win: _Window, label: str) -> bool:
    """The keys, until Enter, then a count-down.

    :return: ``False`` when the participant pressed Esc (or closed the window) instead
    """
    legend = [f"{k:14s} {v}" for k, v in LEGEND]
    if win.wait_key(card(win.size, f"{label.upper()} trial: the keys", [*legend, "", "Press Enter to start"]),
                    (pygame.K_RETURN, pygame.K_KP_ENTER, pygame.K_ESCAPE)) == pygame.K_ESCAPE:
        return False
    for n in (3, 2, 1):
        win.wait_key(card(win.size, str(n), ["get ready"]), (), 1.0)
    return True


def _pass_events(trial: _Trial, names: dict[int, str], scripted: bool) -> None:
    """Hand the window's key presses and releases to the simulation (not when a script drives)."""
    for ev in pygame.event.get():
        if ev.type == pygame.QUIT:
            trial.stop("window closed")
        elif not scripted and ev.type in (pygame.KEYDOWN, pygame.KEYUP) and ev.key in names:
            trial.keys_in.put((ev.type == pygame.KEYDOWN, names[ev.key]))


def _window_frame(trial: _Trial, snap: _Snapshot, size: tuple[int, int]) -> np.ndarray:
    """The picture of a step, with the pause and the question whether to quit."""
    img = compose_frame(snap.rgb, snap.marks, replace(snap.hud, paused=trial.paused), snap.minimap)
    if trial.confirm_quit:
        _text(img, "Quit the trial? Esc: quit, any other key: go on", (20, size[1] // 2 + 40),
              max(size[1] / 720.0, 0.35), (255, 230, 120), thick=2)
    return img


def _window_loop(win: _Window, trial: _Trial, sim: threading.Thread, fps: int, scripted: bool) -> list[float]:
    """Redraw the latest simulation step at up to ``fps`` frames per second until the trial is
    over and its last step shown (or the simulation failed).

    :return: each frame's work [ms]
    """
    names = {getattr(pygame, v): k for k, v in PYGAME_KEYS.items()}
    frame_ms: list[float] = []
    shown_steps = -1
    composed: tuple[tuple[int, bool, bool], np.ndarray] | None = None
    while True:
        t0 = time.perf_counter()
        _pass_events(trial, names, scripted)
        with trial.lock:
            snap = trial.snapshot
        if snap is not None:
            key = (snap.n_steps, trial.paused, trial.confirm_quit)
            if composed is None or key != composed[0]:  # a step's picture is composed once, shown every frame
                composed = key, _window_frame(trial, snap, win.size)
            win.show(composed[1])
            frame_ms.append((time.perf_counter() - t0) * 1e3)
            shown_steps = snap.n_steps
        if trial.done and not sim.is_alive() and (shown_steps == trial.n_steps or trial.error is not None):
            return frame_ms
        win.clock.tick(fps)


def _drive(win: _Window, env: gym.Env, log: TrialWriter, opts: DriveOptions, label: str, info: dict[str, Any],
           shots_dir: Path) -> tuple[_Trial, list[float], float]:
    """The trial itself: the simulation in its own thread, the window in this one.

    :return: the trial, each frame's work [ms] and the trial's wall time [s]
    :raises BaseException: what failed in the simulation (the log is then closed as aborted)
    """
    trial = _Trial(env, log, opts, label, info, shots_dir)
    sim = threading.Thread(target=trial.run, name="dt-highway-sim", daemon=True)
    old_switch = sys.getswitchinterval()
    sys.setswitchinterval(0.0005)  # the window gets the interpreter back quickly from the simulation
    sim.start()
    loop_t0 = time.perf_counter()
    frame_ms = _window_loop(win, trial, sim, opts.fps, opts.keys_from is not None)
    sim.join()
    loop_wall_s = time.perf_counter() - loop_t0
    sys.setswitchinterval(old_switch)
    if trial.error is not None:
        raise trial.error
    log.meta["end_reason"] = trial.end_reason
    if trial.status != "completed":
        log.close(trial.status, trial.end_reason)
    return trial, frame_ms, loop_wall_s


def run_drive(opts: DriveOptions, on_frame: Callable[[np.ndarray], None] | None = None) -> dict[str, Any]:
    """Run one keyboard trial in a pygame window and log it.

    The simulation runs in its own thread, locked to the wall clock; the window (this thread)
    redraws the latest simulation step at up to ``opts.fps`` frames per second and passes key
    presses to the simulation, so that drawing never waits for a simulation step.

    :param opts: the trial
    :param on_frame: called with every composed frame (tests, recording)
    :return: ``directory``, ``status`` (``completed`` or ``aborted``), ``end_reason``,
        ``frames`` drawn, ``screenshots`` saved, ``frame_ms``: each frame's work (window
        events, composing and showing the picture; not the wait for the next frame) [ms],
        ``size_px``, ``trial_wall_s`` and ``trial_sim_s`` (wall and simulated time of the trial [s])
    """
    cfg, overrides, f_sim = _trial_config(opts)
    directory = trial_dir(opts.out, opts.participant, opts.condition, opts.practice)
    shots_dir = opts.screenshots or directory / "screenshots"
    scripted = opts.keys_from is not None
    label = "practice" if opts.practice else display_name(opts.condition)  # a sham is shown as adas: blind
    caption = f"dt-highway: {opts.participant} {label}"

    env = gym.make("dt-highway-v0", config=cfg.to_dict(), render_mode="rgb_array")
    size = (cfg.camera.width_px, cfg.camera.height_px)
    win = _Window.open(size, caption, on_frame)
    meta = _trial_meta(opts, cfg, overrides, f_sim)
    old_switch = sys.getswitchinterval()
    try:
        # the traffic and the twin's listening time are prepared while the participant reads the keys
        if not scripted:
            win.show(card(size, "Preparing the trial...", []))
        _, info = env.reset(seed=opts.seed)
        env.render()  # highway-env's viewer (the mini-map) is made here, on the window's thread
        pygame.display.set_caption(caption)  # it renames the window
        if not scripted and not _start_screens(win, label):
            return {"directory": str(directory), "status": "not started", "end_reason": "quit before the start",
                    "frames": 0, "screenshots": 0, "frame_ms": [], "size_px": list(size)}
        with TrialWriter(directory, meta) as log:
            trial, frame_ms, loop_wall_s = _drive(win, env, log, opts, label, info, shots_dir)
        if not scripted:
            win.wait_key(card(size, "Trial saved", [f"{directory}", "", "Press any key"]), (), 10.0)
    finally:
        sys.setswitchinterval(old_switch)
        env.close()
        pygame.quit()
    return {"directory": str(directory), "status": trial.status, "end_reason": trial.end_reason,
            "frames": len(frame_ms), "screenshots": trial.shots, "frame_ms": frame_ms, "size_px": list(size),
            "trial_wall_s": loop_wall_s, "trial_sim_s": trial.t_sim}
