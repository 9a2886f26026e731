"""Wheel and pedals through pygame's joystick API: calibration, commands, the calibration screen,
driven by an SDL virtual joystick (hmi/joystick.py)."""

import json

import pygame
import pytest

from dt_highway.config import ConfigError
from dt_highway.hmi.joystick import (
    AxisCalibration,
    Calibration,
    CalibrationError,
    CalibrationRecorder,
    JoystickInput,
    VirtualJoystick,
    calibration_frame,
    calibration_screen,
    open_joystick,
    pedal_accel,
)
from dt_highway.hmi.keys import PedalSettings

# a wheel resting a bit right of 0; a throttle resting at -1 (pressed: +1); a brake resting at +1 (pressed: -1)
CAL = Calibration(
    device="test wheel",
    steer=AxisCalibration(axis=0, min=-0.9, centre=0.1, max=0.8, deadzone=0.0),
    throttle=AxisCalibration(axis=1, min=-1.0, centre=-1.0, max=1.0, deadzone=0.0),
    brake=AxisCalibration(axis=2, min=-1.0, centre=1.0, max=1.0, deadzone=0.0),
)


class FakeDevice:
    """The input layer's view of a device, set by hand (for the pure mapping tests)."""

    def __init__(self, values: list[float]) -> None:
        self.values = values

    def get_name(self) -> str:
        return "fake"

    def get_numaxes(self) -> int:
        return len(self.values)

    def get_axis(self, axis_number: int) -> float:
        return self.values[axis_number]


@pytest.mark.parametrize(("value", "want"), [
    (0.1, 0.0),  # the rest position is the centre, though not 0
    (0.45, 0.5),  # (0.45 - 0.1) / (0.8 - 0.1)
    (0.8, 1.0), (1.0, 1.0),  # the end seen, and beyond it
    (-0.4, -0.5),  # (-0.4 - 0.1) / (0.1 - -0.9)
    (-0.9, -1.0),
])
def test_wheel_command_is_linear_on_each_side_of_its_centre(value, want):
    assert CAL.steer.steer(value) == pytest.approx(want)


def test_deadzone_and_inverted_wheel():
    ax = AxisCalibration(axis=0, min=-1.0, centre=0.0, max=1.0, deadzone=0.1)
    assert ax.steer(0.05) == 0.0
    assert ax.steer(0.5) == pytest.approx((0.5 - 0.1) / 0.9)
    inv = AxisCalibration(axis=0, min=-0.5, centre=0.0, max=1.0, deadzone=0.0, inverted=True)
    assert inv.steer(-0.5) == pytest.approx(1.0)  # right lowers it: its low end is full right
    assert inv.steer(0.5) == pytest.approx(-0.5)  # (-0.5 - 0) / (0 - -1)


@pytest.mark.parametrize(("throttle_raw", "brake_raw", "t", "b", "accel"), [
    (-1.0, 1.0, 0.0, 0.0, -0.3),  # both released: coasting
    (0.0, 1.0, 0.5, 0.0, -0.3 + 0.5 * (2.5 + 0.3)),  # half throttle: 1.1
    (1.0, 1.0, 1.0, 0.0, 2.5),
    (-1.0, 0.5, 0.0, 0.25, -0.3 - 0.25 * (7.0 - 0.3)),  # a quarter of the brake: -1.975
    (1.0, -1.0, 1.0, 1.0, -7.0),  # both fully: the brake wins
])
def test_pedals_to_acceleration(throttle_raw, brake_raw, t, b, accel):
    cmd = JoystickInput(FakeDevice([0.1, throttle_raw, brake_raw]), CAL).read()
    assert (cmd.throttle, cmd.brake) == pytest.approx((t, b))
    assert cmd.accel_mps2 == pytest.approx(accel)
    assert pedal_accel(t, b, PedalSettings()) == pytest.approx(accel)


def test_lane_request_once_per_turn_with_hysteresis():
    dev = FakeDevice([0.1, -1.0, 1.0])
    cal = CAL.model_copy(update={"steer": AxisCalibration(axis=0, min=-1.0, centre=0.0, max=1.0, deadzone=0.0)})
    joy = JoystickInput(dev, cal)  # requests past 0.5, armed again under 0.25
    taps = []
    for v in (0.2, 0.6, 0.8, 0.3, 0.2, 0.55, 0.0, -0.7, -0.9):
        dev.values[0] = v
        taps.append(joy.read().lane_tap)
    assert taps == [0, 1, 0, 0, 0, 1, 0, -1, 0]


def test_calibration_round_trip_and_one_line_errors(tmp_path):
    p = CAL.save(tmp_path / "cal" / "wheel.json")
    assert Calibration.load(p) == CAL
    data = json.loads(p.read_text())
    data["steer"]["min"] = 0.5  # above its centre
    p.write_text(json.dumps(data))
    with pytest.raises(ConfigError) as err:
        Calibration.load(p)
    msg = str(err.value)
    assert "\n" not in msg and "steer" in msg and "min <= centre <= max" in msg
    data["steer"]["min"] = -3
    p.write_text(json.dumps(data))
    with pytest.raises(ConfigError, match=r"steer\.min = -3 is out of range: must be >= -1"):
        Calibration.load(p)
    with pytest.raises(ConfigError, match="calibration file not found"):
        Calibration.load(tmp_path / "none.json")
    same = {**CAL.model_dump(), "brake": {**CAL.brake.model_dump(), "axis": 0}}
    with pytest.raises(ValueError, match="three different axes"):
        Calibration.model_validate(same)
    with pytest.raises(CalibrationError, match="uses axis 2, the device 'fake' has 2 axes"):
        JoystickInput(FakeDevice([0.0, 0.0]), CAL)


def test_a_bad_calibration_file_fails_in_one_line_word_for_word(tmp_path):
    missing, folder, bad = tmp_path / "none.json", tmp_path / "dir.json", tmp_path / "bad.json"
    folder.mkdir()
    bad.write_text('{"steer": ,}')
    for path, expected in [
        (missing, f"calibration file not found: {missing} (make one with the calibration screen)"),
        (folder, f"cannot read the calibration file {folder}: [Errno 21] Is a directory: '{folder}'"),
        (bad, f"calibration file {bad} is not valid JSON (Expecting value, line 1)"),
    ]:
        with pytest.raises(ConfigError) as err:
            Calibration.load(path)
        assert str(err.value) == expected


def test_recorder_finds_the_axes_the_ends_and_an_inverted_wheel():
    rec = CalibrationRecorder(4)
    for _ in range(5):
        rec.add("rest", [0.0, 1.0, -1.0, 0.02])
    for v in (0.0, 0.5, 1.0, 0.2, -0.8, 0.0):  # "left" first raises it: inverted
        rec.add("steer", [v, 1.0, -1.0, 0.0])
    for v in (0.0, -1.0, 0.9):  # the brake's stroke: axis 2
        rec.add("brake", [0.0, 1.0, v, 0.0])
    for v in (1.0, -1.0, 1.0):
        rec.add("throttle", [0.0, v, -1.0, 0.1])
    cal = rec.result("x")
    assert (cal.steer.axis, cal.throttle.axis, cal.brake.axis) == (0, 1, 2)
    assert cal.steer.inverted and (cal.steer.min, cal.steer.centre, cal.steer.max) == (-0.8, 0.0, 1.0)
    assert (cal.throttle.min, cal.throttle.centre, cal.throttle.max) == (-1.0, 1.0, 1.0)
    # the brake rests at -1, its end seen is 0.9: -0.05 is half way, less the 3 % deadzone
    assert cal.throttle.pedal(-1.0) == 1.0 and cal.brake.pedal(-0.05) == pytest.approx((0.5 - 0.03) / 0.97)
    lazy = CalibrationRecorder(3)
    lazy.add("rest", [0, 0, 0])
    lazy.add("steer", [0.1, 0, 0])
    lazy.add("throttle", [0, 1, 0])
    lazy.add("brake", [0, 0, 1])
    with pytest.raises(CalibrationError, match="no axis moved in step 'steer'"):
        lazy.result()


@pytest.fixture
def wheel():
    pygame.display.init()
    pygame.joystick.init()
    dev = VirtualJoystick(n_axes=3)
    yield dev
    dev.close()
    pygame.quit()


def test_calibration_screen_with_a_virtual_wheel_then_driving(wheel, tmp_path):
    # the device as pygame sees it
    joy = open_joystick(wheel.index)
    assert joy.get_numaxes() == 3 and joy.get_name()
    with pytest.raises(CalibrationError, match=r"joystick 5 not found: 1 connected \(0\.\.0\)"):
        open_joystick(5)
    moves = {  # per step, the axes at each sample; the step ends after the last
        "rest": [(0.1, -1.0, 1.0)] * 3,
        "steer": [(0.1, -1.0, 1.0), (-0.9, -1.0, 1.0), (0.8, -1.0, 1.0), (0.1, -1.0, 1.0)],
        "throttle": [(0.1, 0.0, 1.0), (0.1, 1.0, 1.0), (0.1, -1.0, 1.0)],
        "brake": [(0.1, -1.0, 0.0), (0.1, -1.0, -1.0), (0.1, -1.0, 1.0)],
    }
    frames = []

    def script(step: str, tick: int) -> bool:
        for a, v in enumerate(moves[step][tick]):
            wheel.set_axis(a, v)
        frames.append(step)
        return tick == len(moves[step]) - 1

    cal = calibration_screen(joy, (320, 180), save_to=tmp_path / "wheel.json", script=script)
    assert cal is not None and frames.count("steer") == 4
    assert (cal.steer.axis, cal.throttle.axis, cal.brake.axis) == (0, 1, 2)
    # SDL keeps 16 bits: values within 1e-4
    assert (cal.steer.min, cal.steer.centre, cal.steer.max) == pytest.approx((-0.9, 0.1, 0.8), abs=1e-4)
    assert not cal.steer.inverted
    assert (cal.brake.min, cal.brake.centre, cal.brake.max) == pytest.approx((-1.0, 1.0, 1.0), abs=1e-4)
    assert Calibration.load(tmp_path / "wheel.json") == cal
    # then driving: half throttle, the wheel halfway right
    inp = JoystickInput(joy, cal)
    wheel.set_axis(0, 0.45)
    wheel.set_axis(1, 0.0)
    pygame.event.pump()
    cmd = inp.read()
    # (0.45 - 0.1) / (0.8 - 0.1) = 0.5, less the default 3 % deadzone: (0.5 - 0.03) / 0.97
    assert cmd.steer == pytest.approx((0.5 - 0.03) / 0.97, abs=1e-3)
    assert cmd.throttle == pytest.approx((0.5 - 0.03) / 0.97, abs=1e-3) and cmd.brake == 0.0
    assert cmd.accel_mps2 == pytest.approx(-0.3 + cmd.throttle * 2.8)


def test_calibration_frame_draws_the_request():
    img = calibration_frame((320, 180), 1, [0.5, -1.0, 1.0])
    assert img.shape == (180, 320, 3) and (img != 28).any()
