"""Trial logs: what the recorder writes (the new safety columns, cut-in and collision events), and
the length of a real trial (one sample per simulation step, none at reset)."""

import math
import signal

import pytest
from conftest import numba_interrupt

from dt_highway.interrupts import interrupted_by_user
from dt_highway.metrics import trial_log
from dt_highway.metrics.safety import SafetySample
from dt_highway.metrics.trial_log import STEP_COLUMNS, TrialRecorder, TrialWriter, load_trial
from dt_highway.study import TrialSpec, run_trial


def _sample(t, crashed=False, collision=None, **kw):
    base = SafetySample(t_s=t, x_m=25.0 * t, y_m=4.0, lane=1, speed_mps=25.0, accel_mps2=0.0, leader_id=3, gap_m=10.0,
                        closing_mps=5.0, ttc_s=2.0, drac_mps2=1.25, headway_s=0.4, crashed=crashed).to_dict()
    return {**base, **kw, "collision": collision}


def test_the_recorder_logs_the_2d_columns_and_the_collision_with_its_partner(tmp_path):
    collision = {"partner_id": 3, "kind": "cut_in", "lane_changer": "partner", "striker": "ego",
                 "partner_type": "aggressive"}
    infos = [
        {"time_s": 0.1, "safety": {"samples": [_sample(0.1, ttc2d_s=1.25, ttc2d_id=3)], "cut_ins": [
            {"t_s": 0.1, "vehicle_id": 3, "gap_m": 10.0, "t_lane_s": 0.0, "driver_type": "aggressive"}]}},
        {"time_s": 0.2, "safety": {"samples": [_sample(0.2, crashed=True, collision=collision, ttc_s=math.nan,
                                                       ttc_contact=True, ttc2d_s=math.nan, ttc2d_id=3,
                                                       ttc2d_contact=True)], "cut_ins": []}},
    ]
    with TrialWriter(tmp_path / "t", {"driver": "x", "simulation_frequency_hz": 10,
                                      "config": {"highway": {"duration": 120.0}}}) as log:
        rec = TrialRecorder(log)
        for info in infos:
            rec.record(info, [0.0, 0.0])
    trial = load_trial(tmp_path / "t")
    assert list(trial.steps.columns) == list(STEP_COLUMNS) and "collision" not in trial.steps
    s = trial.steps
    assert s["ttc2d_s"].tolist()[0] == 1.25 and math.isnan(s["ttc2d_s"].tolist()[1]) and math.isnan(s["ttc_s"][1])
    assert s["ttc_contact"].tolist() == [False, True] and s["ttc2d_contact"].tolist() == [False, True]
    cut, col = trial.cut_ins[0], trial.collisions[0]
    assert (cut["t_s"], cut["t_lane_s"], cut["gap_m"], cut["driver_type"]) == (0.1, 0.0, 10.0, "aggressive")
    assert {k: col[k] for k in ("t_s", "partner_id", "partner_type", "collision_kind", "lane_changer", "striker")} == {
        "t_s": 0.2, "partner_id": 3, "partner_type": "aggressive", "collision_kind": "cut_in", "lane_changer": "partner",
        "striker": "ego"}
    m = trial.metrics()
    assert m["collision_kind"] == "cut_in" and m["collision_partner_id"] == 3 and m["cut_short"]
    assert m["duration_s"] == pytest.approx(0.2) and m["ttc_contact_s"] == pytest.approx(0.1)
    assert m["cut_ins"] == 1 and m["conflicts_2d"] == 1 and m["overlay_on_share"] == 0.0


def test_a_120_s_trial_at_15_hz_has_1800_samples(tmp_path):
    spec = TrialSpec(str(tmp_path / "t"), "agents/idm.toml", "baseline", 0, 5, "envs/highway-trial.toml",
                     ("highway.vehicles_count=8", "twin.preroll_s=2"))
    result = run_trial(spec)
    assert result["status"] == "completed"
    steps = load_trial(tmp_path / "t").steps
    assert len(steps) == 1800 and steps["t_s"].iloc[0] == pytest.approx(1 / 15) and steps["t_s"].iloc[-1] == 120.0
    assert result["metrics"]["n_samples"] == 1800 and result["metrics"]["duration_s"] == 120.0
    assert not result["metrics"]["cut_short"]


def test_ctrl_c_inside_a_numba_function_closes_the_log_as_interrupted_not_as_an_error(tmp_path):
    assert interrupted_by_user(numba_interrupt()) and interrupted_by_user(KeyboardInterrupt())
    assert not interrupted_by_user(SystemError("a real error")) and not interrupted_by_user(None)
    for name, exc, reason in (("ki", numba_interrupt(), "interrupted by the user"),
                              ("err", SystemError("a real error"), "SystemError: a real error")):
        with pytest.raises(SystemError), TrialWriter(tmp_path / name, {"driver": "x"}):
            raise exc
        meta = load_trial(tmp_path / name).meta
        assert (meta["status"], meta["end_reason"]) == ("aborted", reason)


def test_ctrl_c_while_the_log_is_opened_does_not_leave_it_running(tmp_path, monkeypatch):
    # a study's worker that starts its next trial as the Ctrl-C comes: the log was marked "running" first and the
    # KeyboardInterrupt came before the ``with`` was entered, so nothing closed it (seen in a SIGTERM test)
    def interrupted(self):
        raise KeyboardInterrupt

    monkeypatch.setattr("csv.DictWriter.writeheader", interrupted)
    with pytest.raises(KeyboardInterrupt):
        TrialWriter(tmp_path / "t", {"driver": "x"})
    meta = load_trial(tmp_path / "t").meta
    assert (meta["status"], meta["end_reason"], meta["n_steps"]) == ("aborted", "interrupted by the user", 0)


def test_a_second_ctrl_c_while_the_log_is_closed_does_not_leave_it_running(tmp_path, monkeypatch):
    # an impatient user presses Ctrl-C twice (or a study's worker gets the group's SIGINT and the study's too): the
    # second came as the first one's "aborted" was being written, and the log stayed "running"
    real = trial_log._write_json_atomic

    def write(path, meta):
        if meta["status"] != "running":
            signal.raise_signal(signal.SIGINT)  # the second Ctrl-C, as the log's end is written
        real(path, meta)

    monkeypatch.setattr(trial_log, "_write_json_atomic", write)
    # Python's own Ctrl-C handler to start from, whatever an earlier test on this pytest-xdist worker left (once,
    # in the suite on 2 workers, SIGINT was found ignored here); put back as found after
    found = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt), TrialWriter(tmp_path / "t", {"driver": "x"}):
            raise KeyboardInterrupt  # the first
        meta = load_trial(tmp_path / "t").meta
        assert (meta["status"], meta["end_reason"]) == ("aborted", "interrupted by the user")
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # the handler is put back
    finally:
        signal.signal(signal.SIGINT, found)


@pytest.mark.parametrize("interrupt", [True, False])
def test_a_trial_interrupted_inside_a_numba_function_raises_ctrl_c_and_a_real_error_fails_it(tmp_path, monkeypatch,
                                                                                             interrupt):
    """Ray cancels a trial by a simulated Ctrl-C, which may land inside the camera's numba code (CI, stop 28)."""
    from dt_highway import study

    calls = []

    def perceive(self):
        calls.append(1)
        if len(calls) == 5:
            raise numba_interrupt() if interrupt else SystemError("a real error")
        return original(self)

    original = study.DriverSeat.perceive
    monkeypatch.setattr(study.DriverSeat, "perceive", perceive)
    spec = TrialSpec(str(tmp_path / "t"), "agents/idm.toml", "baseline", 0, 5, "envs/highway-trial.toml",
                     ("highway.vehicles_count=8", "twin.preroll_s=2", "highway.duration=5"))
    if interrupt:
        with pytest.raises(KeyboardInterrupt):
            run_trial(spec)
    else:
        result = run_trial(spec)
        assert (result["status"], result["error"]) == ("failed", "SystemError: a real error")
    meta = load_trial(tmp_path / "t").meta
    assert meta["status"] == "aborted"
    assert meta["end_reason"] == ("interrupted by the user" if interrupt else "SystemError: a real error")
