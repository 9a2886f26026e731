"""Replay of a logged keyboard trial: what the participant saw, step by step, in the window or
as PNG frames.

A keyboard trial's directory holds everything needed to run it again: ``meta.json`` the
resolved configuration and the seed, ``steps.csv`` the action the env received at every step
(the pedals' acceleration command and the lane request or steering command), the keys held,
and the ego's position after it. The replay makes the same env, resets it with the same seed
and steps it with the logged actions, so the world unfolds as it did (the simulation is
deterministic given its seed and actions); after a crash in a trial that went on after crashes
(``on_crash = continue``) the ego is put back on the road as the window did
(:func:`~dt_highway.hmi.drive.place_ego_after_crash`). Each step's picture is composed as the driving
window composed it (:func:`~dt_highway.hmi.drive.compose_frame`: camera, overlay marks, HUD,
mini-map toggled by the logged M presses, the mirrors when the trial had them, the crash
feedback), with a replay banner (trial time, keys held).

The logged actions are replayed rather than the key events: the actions are what the env was
given, whatever the timing of a key within a step, the pause, or a key held through the
count-down; the key events are shown (keys held) but not re-interpreted. After every step the
ego's position is compared with the logged one; :class:`ReplayResult` says whether the replay
followed the log and where it first left it.
"""

from __future__ import annotations

import csv
import io
import json
import math
import re
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import gymnasium as gym
import numpy as np
import pygame

from dt_highway.conditions import display_name
from dt_highway.config import ConfigError
from dt_highway.env.core import DTHighwayEnv
from dt_highway.hmi.drive import MIRROR_FRACTION, Hud, compose_frame, crash_layer, hud_band_height, place_ego_after_crash
from dt_highway.hmi.mirror import render_mirrors
from dt_highway.jsonio import finite_number, positive_number

NEEDED_COLUMNS = ("t_s", "x_m", "y_m", "action_accel_mps2", "action_lane", "keys")
"""The columns of ``steps.csv`` a replay reads"""
POSITION_TOLERANCE_M = 1e-6
"""Largest difference between the replayed and the logged ego position that still counts as the same [m]"""


class ReplayError(ConfigError):
    """A trial directory that cannot be replayed (one line: the file and what is wrong)."""


@dataclass
class LoggedTrial:
    """What a replay reads of a trial directory.

    :param path: the trial's directory
    :param meta: its ``meta.json``
    :param actions: ``(N, 2)`` the action of every env step ``[accel m/s^2, lane or steer]``
    :param positions_m: ``(N, 2)`` the logged ego position ``(x, y)`` after every env step [m]
    :param t_s: ``(N,)`` the trial time after every env step [s]
    :param keys: the keys held at every env step (``;``-separated)
    :param key_events: the key presses and releases, ``(t_s, down, key)``
    :param rows_per_action: simulation steps per env step (1 in keyboard trials)
    :param rows: the rows ``steps.csv`` holds (complete ones: a last line cut off mid-row is not read)
    """

    path: Path
    meta: dict[str, Any]
    actions: np.ndarray
    positions_m: np.ndarray
    t_s: np.ndarray
    keys: list[str]
    key_events: list[tuple[float, bool, str]] = field(default_factory=list)
    rows_per_action: int = 1
    rows: int = 0

    @property
    def incomplete(self) -> str | None:
        """Why ``steps.csv`` holds less than the trial wrote (``meta.json``'s ``n_steps``), ``None`` if it
        holds it all or the count is not there (a trial whose process died)."""
        written = self.meta.get("n_steps")
        if isinstance(written, int) and not isinstance(written, bool) and written > self.rows:
            return f"steps.csv holds {self.rows} of the {written} rows meta.json counts written: the rest is lost"
        return None

    @property
    def config(self) -> dict[str, Any]:
        """The trial's resolved configuration tree."""
        return dict(self.meta["config"])

    @property
    def seed(self) -> int:
        """The trial's seed."""
        return int(self.meta["seed"])


def _complete_text(path: Path) -> str:
    """The file's text up to its last newline (a torn last line, left by a killed process, is dropped)."""
    data = path.read_bytes()
    cut = data.rfind(b"\n")
    return data[: cut + 1].decode("utf-8", errors="replace") if cut >= 0 else ""


def _read_meta(d: Path) -> dict[str, Any]:
    p = d / "meta.json"
    if not d.is_dir():
        raise ReplayError(f"not a trial directory: {d} (give a directory like runs/<study>/trials/P01-adas)")
    if not p.is_file():
        raise ReplayError(f"not a trial directory (no meta.json): {d}")
    try:
        meta = json.loads(p.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise ReplayError(f"{p}: is not valid JSON ({err})") from None
    if not isinstance(meta, dict):
        raise ReplayError(f"{p}: holds a JSON {type(meta).__name__}, not an object")
    if meta.get("driver") != "keyboard":
        raise ReplayError(f"{p}: replay plays keyboard trials (this one's driver is {meta.get('driver')!r})")
    if not isinstance(meta.get("config"), dict) or not isinstance(meta.get("seed"), int):
        raise ReplayError(f"{p}: lacks the trial's config or seed (keys 'config', 'seed')")
    return meta


def _read_steps(p: Path) -> list[dict[str, str]]:
    if not p.is_file():
        raise ReplayError(f"{p}: missing (the trial has no steps to replay)")
    rows = list(csv.DictReader(io.StringIO(_complete_text(p))))
    missing = [c for c in NEEDED_COLUMNS if rows and c not in rows[0]]
    if missing or not rows:
        raise ReplayError(f"{p}: " + (f"lacks column(s) {', '.join(missing)}" if missing else "has no rows"))
    return rows


def _numbers(p: Path, rows: list[dict[str, str]], column: str) -> np.ndarray:
    try:
        out = np.array([float(r[column]) for r in rows])
    except (TypeError, ValueError):
        bad = next(i for i, r in enumerate(rows) if not _is_number(r[column]))
        raise ReplayError(f"{p}: column {column} is not a number at line {bad + 2} ({rows[bad][column]!r})") from None
    if not np.isfinite(out).all():
        bad = int(np.flatnonzero(~np.isfinite(out))[0])
        raise ReplayError(f"{p}: column {column} is not a finite number at line {bad + 2}")
    return out


def _is_number(text: str | None) -> bool:
    try:
        float(text or "")
    except ValueError:
        return False
    return True


def _frequency(path: Path, key: str, value: Any) -> float:
    """A logged frequency [Hz], checked to be a positive finite number.

    :raises ReplayError: naming the file and the key
    """
    hz = positive_number(value)
    if hz is None:
        raise ReplayError(f"{path}: {key} must be a positive number of Hz (got {value!r})")
    return hz


def read_logged_trial(directory: str | Path) -> LoggedTrial:
    """Read what a replay needs from a keyboard trial's directory.

    :param directory: the trial's directory (``<study>/trials/<participant>-<condition>``)
    :return: the trial
    :raises ReplayError: one line naming the file and what is wrong (not a trial directory, not a
        keyboard trial, no config or seed, ``steps.csv`` missing, without rows or columns)
    """
    d = Path(directory)
    meta = _read_meta(d)
    p = d / "steps.csv"
    rows = _read_steps(p)
    hw = meta["config"].get("highway") or {}
    f_sim = _frequency(d / "meta.json", "simulation_frequency_hz",
                       meta.get("simulation_frequency_hz") or hw.get("simulation_frequency") or 15)
    f_pol = _frequency(d / "meta.json", "config.highway.policy_frequency", hw.get("policy_frequency") or f_sim)
    per = max(1, int(round(f_sim / f_pol)))
    accel, lane = _numbers(p, rows, "action_accel_mps2"), _numbers(p, rows, "action_lane")
    actions = np.stack([accel, lane], axis=1)[::per]  # an env step's rows share its action
    ends = slice(per - 1, None, per)  # the rows at the end of each env step
    positions = np.stack([_numbers(p, rows, "x_m"), _numbers(p, rows, "y_m")], axis=1)[ends]
    key_events = []
    events = d / "events.jsonl"
    if events.is_file():
        for line in _complete_text(events).splitlines():
            try:
                e = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(e, dict) and e.get("kind") in ("key_down", "key_up"):
                t = finite_number(e.get("t_s", 0.0))
                if t is None:
                    raise ReplayError(f"{events}: a {e['kind']} event has no time (t_s: {e.get('t_s')!r})")
                key_events.append((t, e["kind"] == "key_down", str(e.get("key", ""))))
    return LoggedTrial(d, meta, actions, positions, _numbers(p, rows, "t_s")[ends],
                       [r["keys"] or "" for r in rows][ends], key_events, per, len(rows))


@dataclass
class ReplayResult:
    """What a replay did.

    :param steps: env steps replayed (one per simulation step in keyboard trials)
    :param positions_m: ``(steps, 2)`` the replayed ego position after each env step [m]
    :param max_deviation_m: largest distance between the replayed and the logged ego position [m]
    :param diverged_at_s: trial time of the first step whose position differs from the log by more
        than :data:`POSITION_TOLERANCE_M` (``None``: the replay followed the log)
    :param frames: PNG frames written
    :param frames_dir: where they went (``None``: none asked for)
    :param wall_s: the replay's wall time [s]
    :param stopped: stopped in the window (Esc or closed) before the end
    :param incomplete: why the log holds less than the trial wrote (:attr:`LoggedTrial.incomplete`): the
        replay followed what is there only
    """

    steps: int
    positions_m: np.ndarray
    max_deviation_m: float
    diverged_at_s: float | None
    frames: int = 0
    frames_dir: Path | None = None
    wall_s: float = 0.0
    stopped: bool = False
    incomplete: str | None = None

    @property
    def followed_log(self) -> bool:
        """The replayed ego was where the log says at every step."""
        return self.diverged_at_s is None


def _banner(img: np.ndarray, t_s: float, keys: str, band_h: int = 0) -> None:
    """The replay's banner, bottom left just above the HUD's band (clear of the mirrors at the top
    and of the HUD): trial time and keys held.

    :param band_h: the HUD band's height (:func:`~dt_highway.hmi.drive.hud_band_height`) [px]
    """
    h, _ = img.shape[:2]
    s = max(h / 720.0, 0.35)
    text = f"REPLAY  t = {t_s:6.2f} s  keys: {keys.replace(';', ' ') or '-'}"
    font = cv2.FONT_HERSHEY_DUPLEX
    (tw, th), _ = cv2.getTextSize(text, font, 0.7 * s, 1)
    x0, y0 = int(24 * s), h - band_h - th - int(20 * s)
    cv2.rectangle(img, (x0 - int(8 * s), y0 - int(6 * s)), (x0 + tw + int(8 * s), y0 + th + int(8 * s)), (0, 0, 0), -1)
    cv2.putText(img, text, (x0, y0 + th), font, 0.7 * s, (120, 220, 255), 1, cv2.LINE_AA)


class _Player:
    """Steps the env with the logged actions and composes each step's picture."""

    def __init__(self, trial: LoggedTrial) -> None:
        self.trial = trial
        cfg = trial.config
        try:
            self.env = gym.make("dt-highway-v0", config=cfg, render_mode="rgb_array")
            _, self.info = self.env.reset(seed=trial.seed)
        except ConfigError as err:
            raise ReplayError(f"{trial.path / 'meta.json'}: its config cannot be used: {err}") from None
        u = self.env.unwrapped
        if not isinstance(u, DTHighwayEnv):
            raise ReplayError(f"a replay needs a dt-highway-v0 env (got {type(u).__name__})")
        self.u = u
        self.duration_s = float(u.dt_config.highway.duration)
        self.dt_s = 1.0 / float(u.dt_config.highway.simulation_frequency)
        meta = trial.meta
        label = meta.get("display_label")  # the neutral label the participant saw (older logs: the condition's)
        self.label = str(label) if label else ("practice" if meta.get("practice")
                                               else display_name(str(meta.get("condition", "baseline"))))
        self.show_map = bool((meta.get("driver_params") or {}).get("minimap", True))
        self.mirrors = bool((meta.get("window") or {}).get("mirrors", False))
        self.continue_after_crash = meta.get("on_crash") == "continue"
        self._m_presses = sorted(t for t, down, k in trial.key_events if down and k == "M")
        self.n_sim = self.n_env = 0
        self.crash_t_s: float | None = None
        self.done = False

    def step(self, action: np.ndarray) -> np.ndarray:
        """One env step, then what the trial did after it (a crash: the ego put back on the road
        when the trial went on after crashes, as the driving window does).

        :return: the ego's position after the step, before any such move [m] (what the log holds)
        """
        _, _, terminated, truncated, self.info = self.env.step(action)
        self.n_sim += self.trial.rows_per_action
        self.n_env += 1
        position = np.asarray(self.u.vehicle.position, dtype=float).copy()
        crashed = bool(self.u.vehicle.crashed)
        if crashed:
            self.crash_t_s = self.n_sim * self.dt_s
            if self.continue_after_crash:
                place_ego_after_crash(self.u)
        self.done = bool(truncated or (terminated and not (crashed and self.continue_after_crash)))
        return position

    def picture(self) -> np.ndarray:
        """What the participant saw after the latest step, with the replay's banner."""
        u = self.u
        t = self.n_sim * self.dt_s
        while self._m_presses and self._m_presses[0] <= t + 1e-9:
            self._m_presses.pop(0)
            self.show_map = not self.show_map
        ego = u.vehicle
        hud = Hud(float(ego.speed) * 3.6, int(ego.lane_index[2]) + 1,
                  len(u.road.network.graph[ego.lane_index[0]][ego.lane_index[1]]), self.duration_s - t, self.label)
        marks = (self.info.get("adas") or {}).get("overlay") if u.dt_config.fusion.enabled else None
        minimap = self.env.render() if self.show_map else None
        rgb = u.camera_image().rgb
        h, w = rgb.shape[:2]
        mirror = render_mirrors(u, (round(w * MIRROR_FRACTION[0]), round(h * MIRROR_FRACTION[1]))) if self.mirrors else None
        shown_map = minimap if isinstance(minimap, np.ndarray) else None
        img = compose_frame(rgb, marks, hud, shown_map, mirror)
        if self.crash_t_s is not None:
            img = crash_layer(img, t - self.crash_t_s)
        keys = self.trial.keys[self.n_env - 1] if self.n_env else ""
        _banner(img, t, keys, hud_band_height((w, h), shown_map))
        return img

    def close(self) -> None:
        self.env.close()


class _Outputs:
    """Where the replay's pictures go: PNG frames, a window paced to the trial's clock, a callback.

    :param out_dir: PNG frames' directory (``None``: none)
    :param every_s: a frame every this many seconds of trial time [s] (``None``: every step)
    :param window: the window's size ``(width, height)`` [px] (``None``: no window)
    :param caption: the window's title
    :param speed: the window's speed, times real time
    :param on_frame: called with the trial time [s] and every picture
    """

    def __init__(self, out_dir: Path | None, every_s: float | None, window: tuple[int, int] | None, caption: str,
                 speed: float, on_frame: Callable[[float, np.ndarray], None] | None) -> None:
        self.out_dir, self.every_s, self.speed, self.on_frame = out_dir, every_s, speed, on_frame
        if out_dir is not None:
            out_dir.mkdir(parents=True, exist_ok=True)
        self.next_frame_s = 0.0
        self.frames = 0
        self.stopped = self.paused = False
        self.screen: pygame.Surface | None = None
        if window is not None:
            pygame.display.init()
            self.screen = pygame.display.set_mode(window)
            pygame.display.set_caption(caption)
        self.t0 = time.perf_counter()

    def wants(self, t_s: float) -> bool:
        """Whether the picture at trial time ``t_s`` is needed."""
        return self.screen is not None or self.on_frame is not None or self._frame_due(t_s)

    def _frame_due(self, t_s: float) -> bool:
        return self.out_dir is not None and t_s + 1e-9 >= self.next_frame_s

    def put(self, t_s: float, img: np.ndarray, step_s: float) -> None:
        """Hand on the picture at trial time ``t_s`` (``step_s``: the simulation step [s])."""
        if self.on_frame is not None:
            self.on_frame(t_s, img)
        if self.out_dir is not None and self._frame_due(t_s):
            cv2.imwrite(str(self.out_dir / f"t{t_s:07.2f}s.png"), img[..., ::-1])
            self.frames += 1
            self.next_frame_s = (self.next_frame_s + self.every_s) if self.every_s else t_s + step_s / 2
        if self.screen is not None:
            self.screen.blit(pygame.image.frombuffer(np.ascontiguousarray(img).tobytes(), self.screen.get_size(), "RGB"),
                             (0, 0))
            pygame.display.flip()
            self._poll_window()
            while self.paused and not self.stopped:
                paused_at = time.perf_counter()
                time.sleep(0.02)
                self._poll_window()
                self.t0 += time.perf_counter() - paused_at  # the replay's clock stands still
            wait = t_s / self.speed - (time.perf_counter() - self.t0)
            if wait > 0:
                time.sleep(wait)

    def _poll_window(self) -> None:
        """Esc or a close: stop; Space: pause or go on."""
        for ev in pygame.event.get():
            if ev.type == pygame.QUIT or (ev.type == pygame.KEYDOWN and ev.key == pygame.K_ESCAPE):
                self.stopped = True
            elif ev.type == pygame.KEYDOWN and ev.key == pygame.K_SPACE:
                self.paused = not self.paused

    def close(self) -> None:
        if self.screen is not None:
            pygame.quit()


FRAME_NAME = re.compile(r"t\d{4,}\.\d{2}s\.png")
"""The name of a frame :func:`replay_trial` writes: its trial time (``t0012.40s.png``)"""


def replay_frames_in(folder: Path) -> list[Path]:
    """The replay frames ``folder`` holds, by name (none if it is no folder).

    :param folder: where to look (not its subfolders)
    :return: the frames' paths, sorted by name (so by trial time)
    """
    return sorted(p for p in folder.iterdir() if FRAME_NAME.fullmatch(p.name)) if folder.is_dir() else []


def replay_trial(directory: str | Path, frames_out: str | Path | None = None, every_s: float | None = None,
                 window: bool = False, speed: float = 1.0,
                 on_frame: Callable[[float, np.ndarray], None] | None = None,
                 replace_frames: bool = False) -> ReplayResult:
    """Replay a keyboard trial (see the module docstring).

    :param directory: the trial's directory
    :param frames_out: write PNG frames there, named by trial time (``t0012.40s.png``), from
        ``t = 0`` (before the first step, as the trial's screenshots) (``None``: none)
    :param every_s: a frame every this many seconds of trial time [s] (``None``: every simulation step)
    :param window: show the replay in a window at ``speed`` times real time (Space pauses, Esc stops)
    :param speed: replay speed in the window, times real time
    :param on_frame: called with the trial time [s] and every picture composed
    :param replace_frames: delete the frames of an earlier replay ``frames_out`` holds (see
        :func:`replay_frames_in`) once the trial is read, so the folder holds this replay's alone (``False``:
        they stay, and the ones at this replay's trial times are overwritten)
    :return: what was replayed, and whether it followed the log
    :raises ReplayError: one line, when the directory cannot be replayed
    """
    trial = read_logged_trial(directory)
    if every_s is not None and not (math.isfinite(every_s) and every_s > 0):
        raise ReplayError(f"--every-s must be a finite number > 0 (got {every_s})")
    if not (math.isfinite(speed) and speed > 0):
        raise ReplayError(f"--speed must be a finite number > 0 (got {speed})")
    player = _Player(trial)
    if frames_out is not None and replace_frames:
        for frame in replay_frames_in(Path(frames_out)):
            frame.unlink()
    replayed: list[np.ndarray] = []
    out = None
    t_start = time.perf_counter()
    try:
        cam = player.u.dt_config.camera
        out = _Outputs(Path(frames_out) if frames_out is not None else None, every_s,
                       (cam.width_px, cam.height_px) if window else None, f"dt-highway replay: {trial.path.name}",
                       speed, on_frame)
        if out.wants(0.0):
            out.put(0.0, player.picture(), player.dt_s)
        for action in trial.actions:
            if player.done or out.stopped:
                break
            replayed.append(player.step(action))
            t = player.n_sim * player.dt_s
            if out.wants(t):
                out.put(t, player.picture(), player.dt_s)
    finally:
        player.close()
        if out is not None:
            out.close()
    frames_dir = Path(frames_out) if frames_out is not None else None
    result = _result(trial, replayed, out.stopped if out is not None else False)
    result.frames, result.frames_dir = (out.frames if out is not None else 0), frames_dir
    result.wall_s = time.perf_counter() - t_start
    return result


def _result(trial: LoggedTrial, replayed: list[np.ndarray], stopped: bool) -> ReplayResult:
    """Compare the replayed ego positions with the logged ones (``stopped``: the replay was stopped
    before the end, so fewer steps than the log's is no divergence)."""
    pos = np.array(replayed, dtype=float).reshape(-1, 2)
    n = min(len(pos), len(trial.positions_m))
    dev = np.hypot(*(pos[:n] - trial.positions_m[:n]).T) if n else np.zeros(0)
    off = np.flatnonzero(dev > POSITION_TOLERANCE_M)
    diverged = float(trial.t_s[off[0]]) if len(off) else None
    if diverged is None and len(pos) != len(trial.positions_m) and not stopped:  # the env ended before the log did
        diverged = float(trial.t_s[n - 1]) if n else 0.0
    return ReplayResult(len(pos), pos, float(dev.max()) if n else 0.0, diverged, stopped=stopped,
                        incomplete=trial.incomplete)
