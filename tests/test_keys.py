"""Keyboard pedals and key scripts."""

import pytest

from dt_highway.hmi import KeyEvent, KeyScript, KeyScriptError, Pedals, PedalSettings


def test_pedals_ramp_smoothly_and_the_brake_wins():
    p = Pedals(PedalSettings(throttle_max_mps2=2.0, brake_max_mps2=6.0, coast_mps2=-0.5, throttle_rate_mps3=2.0,
                             brake_rate_mps3=12.0, release_rate_mps3=10.0))
    assert p.accel_mps2 == -0.5  # released: coasting
    assert p.update(True, False, 0.5) == pytest.approx(0.5)  # throttle rises 2 m/s^3
    assert p.update(True, False, 1.0) == pytest.approx(2.0)  # and stops at full throttle
    assert p.update(True, True, 0.25) == pytest.approx(-1.0)  # both held: braking, 12 m/s^3
    assert p.update(False, True, 1.0) == pytest.approx(-6.0)  # full brake
    assert p.update(False, False, 0.2) == pytest.approx(-4.0)  # released: back towards coasting
    assert p.update(True, False, 0.2) == pytest.approx(-2.0)  # off the brake at the release rate
    assert p.update(True, False, 0.2) == pytest.approx(-0.4)  # then throttle: -2 -> coast (-0.5) fast, then 2 m/s^3
    p.reset()
    assert p.accel_mps2 == -0.5


def test_key_script_parses_and_replays_in_time_order():
    script = KeyScript.parse("# demo\n0.5 down UP\n3.0 up up   # released\n\n3.0 down left\n3.1 up LEFT\n")
    assert script.events == [KeyEvent(0.5, True, "UP"), KeyEvent(3.0, False, "UP"), KeyEvent(3.0, True, "LEFT"),
                             KeyEvent(3.1, False, "LEFT")]
    assert script.due(0.4) == [] and script.due(0.5) == [KeyEvent(0.5, True, "UP")]
    assert len(script.due(3.05)) == 2 and not script.finished
    assert script.due(10.0) == [KeyEvent(3.1, False, "LEFT")] and script.finished


@pytest.mark.parametrize("text, message", [
    ("0.5 down", "expected 'TIME down|up KEY'"),
    ("soon down UP", "time must be a number"),
    ("nan down UP", "keys.txt:1: time must be a finite number of seconds (got 'nan')"),
    ("inf up UP", "time must be a finite number of seconds (got 'inf')"),
    ("-3.5 down UP", "keys.txt:1: time must be >= -3 s (before 0: the countdown) (got -3.5)"),
    ("-1 down P", "only UP, DOWN, LEFT, RIGHT can be pressed before 0 s (the countdown; got P at -1 s)"),
    ("2 down UP\n1 up UP", "keys.txt:2: times must not go back"),
    ("1 hold UP", "action must be 'down' or 'up'"),
    ("1 down SPACE", "unknown key 'SPACE' (allowed: UP, DOWN, LEFT, RIGHT, P, ESC)"),
    # P toggles the pause: the headless trial waited for ever
    ("0.5 down P\n0.6 up P", "keys.txt: P is pressed 1 time, the last at 0.5 s: the script ends with the trial paused"),
    ("0.5 down P\n1 down P\n2 down P", "keys.txt: P is pressed 3 times, the last at 2 s"),
])
def test_bad_key_scripts_name_the_line(text, message):
    with pytest.raises(KeyScriptError, match=message.replace("(", r"\(").replace(")", r"\)").replace("|", r"\|")):
        KeyScript.parse(text, "keys.txt")


def test_a_script_that_pauses_then_quits_is_taken():
    script = KeyScript.parse("5 down P\n5.1 up P\n6 down ESC\n", "keys.txt")  # a scripted ESC ends the trial
    assert [e.key for e in script.events] == ["P", "P", "ESC"]


def test_a_missing_key_script_is_one_line(tmp_path):
    with pytest.raises(KeyScriptError, match="cannot read the key script"):
        KeyScript.load(tmp_path / "none.txt")


@pytest.mark.parametrize("encoding", ["utf-8", "utf-8-sig", "utf-16"])
def test_a_key_script_saved_by_any_common_editor_is_read(tmp_path, encoding):
    path = tmp_path / "keys.txt"
    path.write_text("0.5 down UP\n1.0 up UP\n", encoding=encoding)  # utf-16: with its byte-order mark
    assert [(e.t_s, e.down, e.key) for e in KeyScript.load(path).events] == [(0.5, True, "UP"), (1.0, False, "UP")]


@pytest.mark.parametrize("content", [bytes(range(256)), "0.5 down UP\n".encode("utf-16-le"),
                                     "0.5 down UP\n".encode("utf-32")])
def test_a_key_script_that_is_not_text_is_one_line(tmp_path, content):
    path = tmp_path / "keys.bin"
    path.write_bytes(content)  # binary, UTF-16 without its byte-order mark, UTF-32
    with pytest.raises(KeyScriptError, match=r"keys.bin is not text \(UTF-8, or UTF-16 with a byte-order mark\)$"):
        KeyScript.load(path)


def test_steering_ramps_self_centres_and_countersteers_quickly():
    from dt_highway.hmi import Steering

    w = Steering(rate_per_s=1.0, centring_per_s=2.0)
    assert w.update(False, True, 0.5) == pytest.approx(0.5)  # right, 1 /s
    assert w.update(False, True, 1.0) == pytest.approx(1.0)  # full lock
    assert w.update(False, False, 0.25) == pytest.approx(0.5)  # released: centring, 2 /s
    assert w.update(True, False, 0.1) == pytest.approx(0.2)  # countersteer: 3 /s
    assert w.update(True, True, 1.0) == 0.0  # both: centre
