"""Replay of a logged keyboard trial from its seed, config and logged actions (hmi/replay.py, dt-highway replay)."""

import json
import shutil

import numpy as np
import pytest
from PIL import Image

from dt_highway.cli import main
from dt_highway.hmi.drive import hud_band_height
from dt_highway.hmi.replay import ReplayError, read_logged_trial, replay_trial
from dt_highway.metrics.trial_log import load_trial

FAST = ["--set", "highway.vehicles_count=16", "--set", "twin.preroll_s=20", "--set", "camera.width_px=480",
        "--set", "camera.height_px=270"]
SCRIPT = "0.2 down UP\n1.0 up UP\n1.2 down LEFT\n1.3 up LEFT\n1.6 down DOWN\n2.0 up DOWN\n"


@pytest.fixture(scope="module")
def trial_dir(tmp_path_factory):
    """One short scripted keyboard trial (adas: the overlay's marks are in the pictures)."""
    tmp = tmp_path_factory.mktemp("replay")
    keys = tmp / "keys.txt"
    keys.write_text(SCRIPT)
    assert main(["drive", "--participant", "P01", "--condition", "adas", "--duration", "2.4", "--out", str(tmp / "s"),
                 "--keys-from", str(keys), "--screenshot-every", "1", "--seed", "3", *FAST]) == 0
    return tmp / "s" / "trials" / "P01-adas"


def test_a_replay_drives_the_same_path_and_shows_what_the_participant_saw(trial_dir, tmp_path):
    logged = load_trial(trial_dir)
    assert logged.meta["status"] == "completed"
    lane_changes = [e for e in logged.events if e["kind"] == "lane_change"]
    assert lane_changes  # the script's LEFT tap changed lanes: the path is not just straight on
    seen: list[float] = []
    result = replay_trial(trial_dir, frames_out=tmp_path / "frames", every_s=1.0, on_frame=lambda t, img: seen.append(t))
    assert result.followed_log and result.diverged_at_s is None and result.max_deviation_m == 0.0
    assert result.steps == len(logged.steps)
    # the ego's positions after every step, equal to the log's to the last bit
    assert np.array_equal(result.positions_m, logged.steps[["x_m", "y_m"]].to_numpy())
    names = sorted(p.name for p in (tmp_path / "frames").iterdir())
    assert names == ["t0000.00s.png", "t0001.00s.png", "t0002.00s.png"] and result.frames == 3
    assert len(seen) == result.steps + 1  # every step's picture to the callback, and t = 0
    # the replayed picture is the trial's screenshot at the same time, but for the replay's banner (bottom left,
    # above the HUD's band: the mirrors at the top stay clear)
    band_min = hud_band_height((480, 270))
    for name in ("t0001.00s.png", "t0002.00s.png"):
        shot = np.asarray(Image.open(trial_dir / "screenshots" / name).convert("RGB"))
        frame = np.asarray(Image.open(tmp_path / "frames" / name).convert("RGB"))
        assert shot.shape == frame.shape == (270, 480, 3)
        diff = (shot != frame).any(axis=-1)
        rows, cols = np.nonzero(diff)
        assert len(rows) > 100  # the banner is there
        assert rows.min() > 270 / 2 and rows.max() < 270 - band_min and cols.max() < 480 * 0.6, \
            (name, rows.min(), rows.max(), cols.max())


def test_the_cli_replays_to_frames_and_says_the_path_was_the_logged_one(trial_dir, tmp_path, capsys):
    n = len(load_trial(trial_dir).steps)  # 2.4 s at the trials' simulation frequency
    assert main(["replay", str(trial_dir), "--frames-out", str(tmp_path / "f"), "--every-s", "2"]) == 0
    out = capsys.readouterr().out
    assert f"replayed {n} steps" in out and "2 frames" in out and "followed the log" in out
    assert sorted(p.name for p in (tmp_path / "f").iterdir()) == ["t0000.00s.png", "t0002.00s.png"]
    # a second replay into the same folder is refused before it runs: the frames there stay
    (tmp_path / "f" / "notes.txt").write_text("mine")
    before = {p.name: p.stat().st_mtime_ns for p in (tmp_path / "f").iterdir()}
    err = _one_line_error(capsys, ["replay", str(trial_dir), "--frames-out", str(tmp_path / "f"), "--every-s", "1"])
    assert "holds 2 frames of an earlier replay: pass --force" in err
    assert {p.name: p.stat().st_mtime_ns for p in (tmp_path / "f").iterdir()} == before
    # --force: the earlier frames go (t0002.00s.png is written anew), other files stay
    assert main(["replay", str(trial_dir), "--frames-out", str(tmp_path / "f"), "--every-s", "1.5", "--force"]) == 0
    assert sorted(p.name for p in (tmp_path / "f").iterdir()) == ["notes.txt", "t0000.00s.png", "t0001.50s.png"]
    assert (tmp_path / "f" / "notes.txt").read_text() == "mine"
    capsys.readouterr()
    assert "--force is for --frames-out" in _one_line_error(capsys, ["replay", str(trial_dir), "--force"])
    # a trial that cannot be read deletes nothing, even with --force
    err = _one_line_error(capsys, ["replay", str(tmp_path / "nowhere"), "--frames-out", str(tmp_path / "f"), "--force"])
    assert "not a trial directory" in err and len(list((tmp_path / "f").glob("t*.png"))) == 2


def test_a_log_the_replay_does_not_follow_is_reported(trial_dir, tmp_path, capsys):
    bad = tmp_path / "P01-adas"
    bad.mkdir()
    for name in ("meta.json", "events.jsonl"):
        (bad / name).write_bytes((trial_dir / name).read_bytes())
    lines = (trial_dir / "steps.csv").read_text().splitlines(keepends=True)
    cols = lines[0].strip().split(",")
    t_s = load_trial(trial_dir).steps["t_s"].to_numpy()
    row = lines[21].split(",")  # the 21st step's action (line 1 is the header)
    row[cols.index("action_accel_mps2")] = "-7.0"  # a hard brake the participant never made
    lines[21] = ",".join(row)
    (bad / "steps.csv").write_text("".join(lines))
    result = replay_trial(bad)
    # the brake changes the speed in that step, the position from the next one (22nd)
    assert not result.followed_log and result.diverged_at_s == pytest.approx(t_s[21])
    assert result.max_deviation_m > 0.01
    assert main(["replay", str(bad), "--frames-out", str(tmp_path / "f")]) == 1
    assert f"left the logged path at t = {t_s[21]:.2f} s" in capsys.readouterr().out


def test_a_log_cut_short_says_so_and_replays_what_it_holds(trial_dir, tmp_path, capsys):
    """A steps.csv that lost its last rows (a disk full, a copy cut off) replayed silently as the whole trial."""
    cut = tmp_path / "P01-adas"
    shutil.copytree(trial_dir, cut)
    text = (trial_dir / "steps.csv").read_bytes()
    (cut / "steps.csv").write_bytes(text[: len(text) - 40])  # the last row cut off mid-line
    written = len(load_trial(trial_dir).steps)
    assert replay_trial(trial_dir).incomplete is None
    result = replay_trial(cut)
    assert result.steps == written - 1 and result.followed_log
    assert result.incomplete == (f"steps.csv holds {written - 1} of the {written} rows meta.json counts written: "
                                 "the rest is lost")
    assert main(["replay", str(cut), "--frames-out", str(tmp_path / "f"), "--every-s", "5"]) == 0
    assert f"{cut}: {result.incomplete}; replayed what it holds" in capsys.readouterr().out


def _one_line_error(capsys, args: list[str]) -> str:
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("dt-highway replay: error:"), err
    return err


def test_bad_trial_dirs_are_one_line_errors(trial_dir, tmp_path, capsys):
    assert "not a trial directory" in _one_line_error(capsys, ["replay", str(tmp_path / "nowhere")])
    (tmp_path / "empty").mkdir()
    assert "no meta.json" in _one_line_error(capsys, ["replay", str(tmp_path / "empty")])
    d = tmp_path / "scripted"
    d.mkdir()
    meta = json.loads((trial_dir / "meta.json").read_text())
    (d / "meta.json").write_text(json.dumps({**meta, "driver": "idm"}))
    assert "replay plays keyboard trials (this one's driver is 'idm')" in _one_line_error(capsys, ["replay", str(d)])
    (d / "meta.json").write_text(json.dumps(meta))
    assert "steps.csv: missing" in _one_line_error(capsys, ["replay", str(d)])
    (d / "steps.csv").write_text("t_s,x_m,y_m\n0.1,1,2\n")
    assert "lacks column(s) action_accel_mps2, action_lane, keys" in _one_line_error(capsys, ["replay", str(d)])
    (d / "meta.json").write_text("{not json")
    assert "is not valid JSON" in _one_line_error(capsys, ["replay", str(d)])
    assert "--every-s S needs --frames-out DIR" in _one_line_error(capsys, ["replay", str(trial_dir), "--every-s", "1"])
    with pytest.raises(ReplayError, match="no meta.json"):
        read_logged_trial(tmp_path / "empty")
    # a damaged frequency or key time: one line naming the file, not a ValueError from float()
    bad = tmp_path / "bad"
    shutil.copytree(trial_dir, bad)
    (bad / "meta.json").write_text(json.dumps({**meta, "simulation_frequency_hz": "x"}))
    assert "meta.json: simulation_frequency_hz must be a positive number of Hz (got 'x')" in _one_line_error(
        capsys, ["replay", str(bad)])
    (bad / "meta.json").write_text(json.dumps(meta))
    with (bad / "events.jsonl").open("a") as f:
        f.write('{"kind": "key_down", "t_s": "x", "key": "UP"}\n')
    assert "events.jsonl: a key_down event has no time (t_s: 'x')" in _one_line_error(capsys, ["replay", str(bad)])


def test_the_window_replay_runs_and_esc_stops_it(trial_dir):
    import pygame

    def esc_after_1s(t_s: float, img: np.ndarray) -> None:
        if t_s >= 1.0:
            pygame.event.post(pygame.event.Event(pygame.KEYDOWN, key=pygame.K_ESCAPE))

    n = len(load_trial(trial_dir).steps)
    whole = replay_trial(trial_dir, window=True, speed=20.0)
    assert whole.followed_log and whole.steps == n and not whole.stopped
    part = replay_trial(trial_dir, window=True, speed=20.0, on_frame=esc_after_1s)
    hz = load_trial(trial_dir).meta["simulation_frequency_hz"]
    # stopped at the first picture at or after 1 s: that step is the last replayed; no divergence for that
    assert part.stopped and part.followed_log and part.steps == round(1.0 * hz)


def test_a_trial_that_goes_on_after_crashes_replays_through_the_ego_resets(tmp_path):
    from dt_highway.hmi.drive import DriveOptions, run_drive
    from dt_highway.hmi.keys import KeyScript

    # throttle held, lane changes left and right every 1.3 s in the near-miss world: the ego rams a car
    taps = [f"{0.5 + 1.3 * k:.2f} {a} {'LEFT' if k % 2 == 0 else 'RIGHT'}" for k in range(7) for a in ("down", "up")]
    script = KeyScript.parse("0.0 down UP\n" + "\n".join(sorted(taps, key=lambda x: float(x.split()[0]))) + "\n")
    opts = DriveOptions(participant="P09", condition="baseline", out=tmp_path, duration_s=9.0, seed=3,
                        scenario="envs/highway-trial.toml", keys_from=script, on_crash="continue", minimap=False,
                        overrides=["twin.preroll_s=20", "camera.width_px=320", "camera.height_px=180"])
    run_drive(opts)
    trial = load_trial(tmp_path / "trials" / "P09-baseline")
    resets = [e for e in trial.events if e["kind"] == "ego_reset"]
    assert resets, "the scripted drive no longer crashes: pick another seed"  # the case under test
    result = replay_trial(trial.path)
    assert result.followed_log and result.steps == len(trial.steps)
    assert np.array_equal(result.positions_m, trial.steps[["x_m", "y_m"]].to_numpy())


def test_the_replay_banner_sits_bottom_left_above_the_hud_clear_of_the_mirrors():
    from dt_highway.hmi.drive import MIRROR_FRACTION
    from dt_highway.hmi.replay import _banner

    h, w = 720, 1280
    minimap = np.zeros((150, 600, 3), np.uint8)
    band = hud_band_height((w, h), minimap)
    assert band == max(110, int(150 * 460 / 600) + 32)  # the mini-map 0.36 * 1280 = 460 px wide, 16 px above and below
    img = np.zeros((h, w, 3), np.uint8)
    _banner(img, 12.5, "UP;LEFT", band)
    ys, xs = np.nonzero(img.any(axis=2))
    # above the HUD's band, in the left half, below the mirrors (top MIRROR_FRACTION[1] of the frame and their frame)
    assert ys.max() < h - band and xs.max() < w // 2 and xs.min() > 0
    assert ys.min() > 2 * MIRROR_FRACTION[1] * h
