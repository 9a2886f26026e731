"""The study runner, trial logs of real trials, the drivers and the report, on tiny studies."""

import json
import os
import re
import signal
from pathlib import Path

import numpy as np
import pytest

from dt_highway.cli import main
from dt_highway.config import ConfigError
from dt_highway.drivers import HumanDriver, HumanParams, IDMDriver, load_driver, make_driver
from dt_highway.metrics.trial_log import load_trial
from dt_highway.study import freeze_inputs, plan, run_study

SHORT = ["highway.duration=4", "highway.vehicles_count=12", "twin.preroll_s=5"]


def _stops_as_on_ctrl_c(run_the_study) -> None:
    """``run_the_study()`` (which sends itself a SIGTERM) raises KeyboardInterrupt, as on Ctrl-C, and leaves SIGTERM's
    handler as it found it. A SIGTERM the study did not take lands in a recording handler, not in the end of the
    test run."""
    outside: list[int] = []

    def handler(signum, frame):
        outside.append(signum)

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            run_the_study()
        assert signal.getsignal(signal.SIGTERM) is handler and outside == []
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_driver_files_load_and_bad_ones_are_refused(tmp_path):
    human = load_driver("agents/human.toml")
    assert isinstance(human, HumanDriver) and human.p == HumanParams()  # the file holds the defaults
    assert isinstance(load_driver("agents/idm.toml"), IDMDriver)
    with pytest.raises(ConfigError, match="unknown key 'reaction_time'"):
        make_driver({"kind": "human", "reaction_time": 1.0})
    with pytest.raises(ConfigError, match="kind"):
        make_driver({"kind": "robot"})
    with pytest.raises(ConfigError, match="finite number >= 0"):
        make_driver({"kind": "human", "reaction_time_s": -1})
    with pytest.raises(ConfigError, match="not found"):
        load_driver(tmp_path / "nope.toml")


def test_a_paired_study_logs_every_trial_resumes_and_survives_a_failed_one(tmp_path, monkeypatch):
    out = tmp_path / "study"
    specs = plan(out, "agents/human.toml", ["baseline", "adas"], 1, 7, "envs/highway-trial.toml", SHORT)
    bad = plan(out, str(tmp_path / "missing.toml"), ["baseline"], 1, 7)[0]
    bad = type(bad)(**{**bad.__dict__, "directory": str(out / "trials" / "broken-000")})
    result = run_study([*specs, bad], out, workers=1)
    assert sorted(result.completed) == sorted(s.directory for s in specs)
    assert len(result.failed) == 1 and "not found" in result.failed[0]["error"]
    for s in specs:
        trial = load_trial(s.directory)
        assert trial.meta["status"] == "completed" and trial.meta["seed"] == 7 and trial.meta["condition"] == s.condition
        assert abs(trial.steps["t_s"].max() - 4.0) < 0.1 and len(trial.steps) == 60  # t = 1/15..4 s
    again = run_study(specs, out, workers=1)
    assert len(again.skipped) == 2 and not again.completed
    import dt_highway.study as study_module

    def no_worker(*args, **kwargs):
        raise AssertionError("a worker (or Ray) was started for trials already done")

    monkeypatch.setattr(study_module, "_run_pool", no_worker)
    monkeypatch.setattr(study_module, "_run_ray", no_worker)
    import importlib.util

    backends = ["process", *(["ray"] if importlib.util.find_spec("ray") else [])]
    for backend in backends:  # a finished study resumes at once: its trials are read here
        seen = []
        done = run_study(specs, out, workers=2, backend=backend, progress=seen.append)
        assert sorted(done.skipped) == sorted(s.directory for s in specs) and not done.completed
        assert [r["status"] for r in seen] == ["skipped", "skipped"] and all(r["metrics"] for r in seen)
    # SIGTERM (a job scheduler's stop) while the done trials are read: the study stops as on Ctrl-C (the command
    # then prints how to resume and exits 130), and SIGTERM's handler comes back

    real_done = study_module._done_result

    def term_first(spec):
        os.kill(os.getpid(), signal.SIGTERM)
        return real_done(spec)

    monkeypatch.setattr(study_module, "_done_result", term_first)
    _stops_as_on_ctrl_c(lambda: run_study(specs, out, workers=2))
    monkeypatch.setattr(study_module, "_done_result", real_done)
    # a completed log that cannot be scored (a column missing: an older version's) fails that trial, not the study
    steps = Path(specs[0].directory) / "steps.csv"
    steps.write_text("\n".join(",".join(line.split(",")[:2]) for line in steps.read_text().splitlines()) + "\n")
    broken = run_study(specs, out, workers=2)
    assert [f["directory"] for f in broken.failed] == [specs[0].directory] and "KeyError" in broken.failed[0]["error"]
    assert broken.skipped == [specs[1].directory]
    other = plan(out, "agents/human.toml", ["baseline", "adas"], 1, 8, "envs/highway-trial.toml", SHORT)
    with pytest.raises(ConfigError, match=r"started with other settings for baseline-000 \(seed 7, now 8\): use another"):
        run_study(other, out, workers=1)  # another seed into the same trial directories


def test_sigterm_stops_a_one_worker_study_as_ctrl_c_does(tmp_path, monkeypatch):
    """``--workers 1`` runs the trials in the study's process: a SIGTERM (``kill PID``, a job scheduler) killed it
    with the running trial's log left open; now the trial is closed as aborted, "interrupted by the user" (run again
    on resume), and the study raises KeyboardInterrupt (the command prints how to resume and exits 130)."""

    import dt_highway.study as study_module

    real_load = study_module.load_driver

    def load_driver(path):
        driver = real_load(path)
        real_act, calls = driver.act, []

        def act(perceived):
            calls.append(1)
            if len(calls) == 10:  # mid-trial
                os.kill(os.getpid(), signal.SIGTERM)
            return real_act(perceived)

        driver.act = act
        return driver

    monkeypatch.setattr(study_module, "load_driver", load_driver)
    specs = plan(tmp_path / "study", "agents/idm.toml", ["baseline"], 2, 7, "envs/highway-trial.toml", SHORT)
    _stops_as_on_ctrl_c(lambda: run_study(specs, tmp_path / "study", workers=1))
    trial = load_trial(specs[0].directory)
    assert (trial.meta["status"], trial.meta["end_reason"]) == ("aborted", "interrupted by the user")
    assert not Path(specs[1].directory).exists()  # the next trial never started


def test_study_and_report_commands(tmp_path, capsys):
    out = tmp_path / "s"
    args = ["study", "--driver", "agents/idm.toml", "--trials", "2", "--workers", "1", "--out", str(out), "--quiet",
            "--scenario", "envs/highway-trial.toml", *sum((["--set", s] for s in SHORT), [])]
    assert main(args) == 0
    pytest.importorskip("pyarrow", reason="the test extras install pyarrow")
    import pandas as pd
    assert not (out / "trials" / "adas-001" / "steps.parquet").exists()
    assert main([*args, "--parquet"]) == 0  # resumed: every trial skipped, the Parquet copies added
    trial = load_trial(out / "trials" / "adas-001")
    pd.testing.assert_frame_equal(pd.read_parquet(trial.path / "steps.parquet"), trial.steps)
    assert main(["report", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["conditions"]) == {"baseline", "adas"}
    assert summary["conditions"]["adas"]["n"] == 2
    assert summary["paired_tests"]["speed_variance_kmh2"]["n_pairs"] == 2
    metrics = (out / "metrics.csv").read_text().splitlines()
    assert len(metrics) == 5 and "speed_variance_kmh2" in metrics[0]
    html = (out / "report.html").read_text()
    assert "data:image/png;base64," in html and "16.6" in html
    assert main(["report", str(tmp_path / "empty")]) == 2
    assert main(["study", "--driver", "agents/idm.toml", "--out", str(out), "--conditions", "baseline,night"]) == 2
    assert "unknown condition 'night'" in capsys.readouterr().err


def test_participant_strings_are_escaped_in_the_html(tmp_path):
    out = tmp_path / "s"
    specs = plan(out, "agents/idm.toml", ["baseline"], 1, 0, "envs/highway-trial.toml", SHORT)
    run_study(specs, out, workers=1)
    meta_path = out / "trials" / "baseline-000" / "meta.json"
    meta = json.loads(meta_path.read_text())
    meta["driver"] = "<script>alert(1)</script>"
    meta_path.write_text(json.dumps(meta))
    assert main(["report", str(out)]) == 0
    html = (out / "report.html").read_text()
    assert "<script>alert(1)</script>" not in html and "&lt;script&gt;" in html


def test_the_ray_backend_runs_the_same_trials_on_a_local_ray(tmp_path):
    pytest.importorskip("ray", reason="the test extras install ray; without it this backend cannot run")
    out = tmp_path / "study"
    specs = plan(out, "agents/idm.toml", ["baseline", "adas"], 1, 3, "envs/highway-trial.toml", SHORT)
    bad = type(specs[0])(**{**specs[0].__dict__, "driver": str(tmp_path / "missing.toml"),
                            "directory": str(out / "trials" / "broken-000")})
    seen = []
    result = run_study([*specs, bad], out, workers=2, progress=seen.append, backend="ray")
    assert sorted(result.completed) == sorted(s.directory for s in specs) and len(seen) == 3
    assert len(result.failed) == 1 and result.failed[0]["directory"] == bad.directory
    assert "not found" in result.failed[0]["error"]
    local = run_study(plan(tmp_path / "local", "agents/idm.toml", ["adas"], 1, 3, "envs/highway-trial.toml", SHORT),
                      tmp_path / "local", workers=1)
    ray_steps = load_trial(out / "trials" / "adas-000").steps
    assert ray_steps.equals(load_trial(local.completed[0]).steps)  # same seed, same trial, wherever it ran
    with pytest.raises(ConfigError, match="cannot reach Ray at 127.0.0.1:1"):
        run_study(specs, out, backend="ray", ray_address="127.0.0.1:1")  # fails at once, Ray would retry for minutes


@pytest.mark.parametrize(("kw", "message"), [
    ({"seed": 1.5}, "--seed must be a whole number >= 0 (got 1.5)"),
    ({"seed": -1}, "--seed must be a whole number >= 0 (got -1)"),
    ({"trials": "3"}, "--trials must be a whole number >= 1 (got '3')"),
    ({"conditions": "adas"}, "conditions must be a list of names"),
])
def test_plan_refuses_what_the_cli_would(tmp_path, kw, message):
    args = {"out": tmp_path, "driver": "agents/idm.toml", "conditions": ["adas"], "trials": 1, "seed": 0, **kw}
    with pytest.raises(ConfigError, match=re.escape(message)):
        plan(**args)
    with pytest.raises(ConfigError, match=re.escape("--workers must be a whole number >= 1 (got 0)")):
        run_study([], tmp_path / "s", workers=0)
    assert not (tmp_path / "s").exists()
    assert plan(tmp_path, "agents/idm.toml", ["adas"], np.int64(2), np.int64(5))[1].seed == 6  # numpy integers are fine


def test_a_study_runs_on_copies_of_its_inputs_and_refuses_changed_ones(tmp_path):
    driver = tmp_path / "mine.toml"
    driver.write_text('kind = "idm"\n')
    out = tmp_path / "study"
    d, sc = freeze_inputs(out, str(driver), "envs/highway-trial.toml")
    assert d == str(out / "inputs" / "mine.toml") and sc == str(out / "inputs" / "highway-trial.toml")
    driver.write_text('kind = "idm"\n[idm]\ndesired_speed_mps = 20.0\n')  # edited while the study runs
    assert load_driver(d).idm.desired_speed_mps == 30.0  # the trials still read the copy
    with pytest.raises(ConfigError, match="differs from the copy"):
        freeze_inputs(out, str(driver), "envs/highway-trial.toml")
    assert freeze_inputs(out, d, sc) == (d, sc)  # the copies themselves are accepted
    with pytest.raises(ConfigError, match="file not found"):
        freeze_inputs(out, str(tmp_path / "nope.toml"), None)


def test_a_trial_whose_action_no_driver_gives_fails_in_one_line(tmp_path):
    """A ``--set highway.action.type`` reaches a trial run from Python too: it fails with the reason, unrun."""
    from dt_highway.study import TrialSpec, run_trial

    spec = TrialSpec(str(tmp_path / "t"), "agents/idm.toml", "adas", 0, 0, None, ("highway.action.type=DiscreteMetaAction",))
    result = run_trial(spec)
    assert result["status"] == "failed" and not (tmp_path / "t" / "steps.csv").exists()
    assert result["error"].startswith("highway.action.type = DiscreteMetaAction: drivers act through the Driver action")


def test_a_study_json_that_cannot_be_read_is_refused_not_written_anew(tmp_path):
    """Resumed, a damaged study.json was replaced by one without the trials of earlier runs; a record of a
    trial without its settings was a KeyError."""
    from dt_highway.study import check_resume

    specs = plan(tmp_path, "agents/idm.toml", ["baseline"], 1, 0, overrides=SHORT)
    for text in ("[", '{"trials": 3}', '{"trials": [{"directory": "x"}]}'):
        (tmp_path / "study.json").write_text(text)
        with pytest.raises(ConfigError, match=r"study.json cannot be read \(not the record of a study's trials\)"):
            run_study(specs, tmp_path)
        assert (tmp_path / "study.json").read_text() == text
    (tmp_path / "study.json").unlink()
    assert check_resume(tmp_path, specs) == {}  # no record: a new study
