"""End-to-end runs of each command on small inputs."""

import ast
import io
import json
import os
import subprocess
import sys
import warnings
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import pytest

from dt_highway.cli import main

TINY = ["--set", "highway.vehicles_count=10", "--set", "highway.duration=4", "--set", "twin.preroll_s=4",
        "--set", "highway.lanes_count=3", "--set", "traffic.population_size=40"]


def test_help_lists_commands(capsys):
    proc = subprocess.run([sys.executable, "-m", "dt_highway.cli", "--help"], capture_output=True, text=True)
    assert proc.returncode == 0
    for cmd in ("run", "twin-eval", "bench"):
        assert cmd in proc.stdout


SIMULATION = ("highway_env", "matplotlib", "scipy", "torch", "numba", "pandas", "stable_baselines3", "dt_highway.env",
              "dt_highway.world")
"""What a mistake in a command's settings has no need of: the configuration is checked before the simulation loads"""

HEAVY = (*SIMULATION, "pygame", "cv2", "pydantic", "dt_highway.config", "dt_highway.study")
"""What ``dt-highway --help`` has no need of (2-4 s to import): the simulation, the config models, the study"""


def _main_in_a_new_process(argv: list[str], watched: tuple[str, ...]) -> tuple[object, str, str, list[str]]:
    """Run ``main(argv)`` in a new Python process.

    :return: what ``main`` returned (``'SystemExit(code)'`` for help or an argparse error), its stdout, its stderr,
        and the modules of ``watched`` it imported
    """
    code = (f"import sys\nfrom dt_highway.cli import main\ntry:\n    status = main({argv!r})\n"
            f"except SystemExit as exc:\n    status = f'SystemExit({{exc.code}})'\n"
            f"print(repr((status, [m for m in sys.modules if m.startswith({watched!r})])), file=sys.stderr)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    *before, last = proc.stderr.splitlines() or [""]
    status, imported = ast.literal_eval(last)
    return status, proc.stdout, "\n".join(before), imported


@pytest.mark.parametrize("argv", [["--help"], ["study", "--help"], ["session", "--help"], ["bench", "sim", "--help"],
                                  ["study", "--bogus"], ["drive", "--condition", "nope"], []])
def test_help_and_a_mistyped_command_line_import_no_simulation(argv):
    _, out, err, imported = _main_in_a_new_process(argv, HEAVY)
    assert imported == [], err
    assert out.strip() or "error" in err  # it answered: help, or the one-line error


@pytest.mark.parametrize(("argv", "message"), [
    (["run", "--set", "nosuch.key=1"], "unknown key 'nosuch'"),
    (["run", "--scenario", "nosuch.toml"], "scenario file 'nosuch.toml' does not exist"),
    (["twin-eval", "--sweep"], "--sweep goes with --intent"),
    (["twin-eval", "--intent", "--oracle-hide", "positions"], "--oracle-hide goes with --oracle N"),
    (["camera", "--out", "OUT", "--set", "camera.enabled=false"], "needs the camera"),
    (["matching", "--out", "OUT", "--detectors", "bogus"], "--detectors takes simulated and/or learned"),
    (["train-intent", "--out", "OUT/w.npz", "--set", "twin.intention.model=physics"], "trains the learned network"),
    (["bench", "memory", "--hours", "0.01"], "--every-min must be at most half of --hours"),
    (["evaluate", "--driver", "agents/idm.toml", "--set", "nosuch=1"], "unknown key 'nosuch'"),
    (["evaluate", "--driver", "agents/idm.toml", "--episodes-json"], "--episodes-json needs --json"),
])
def test_a_mistake_in_the_settings_answers_before_the_simulation_is_imported(argv, message, tmp_path):
    argv = [a.replace("OUT", str(tmp_path)) for a in argv]
    status, _, err, imported = _main_in_a_new_process(argv, SIMULATION)
    error = err.splitlines()[-1]
    assert message in error and error.startswith("dt-highway "), err
    assert (status, imported) == (2, []), err


def test_import_registers_the_env_and_imports_it_when_first_used():
    code = ("import sys\nimport gymnasium as gym\nimport dt_highway\n"
            "assert 'dt-highway-v0' in gym.registry and 'highway_env' not in sys.modules\n"
            "import dt_highway.hmi.screens\n"  # pygame before highway-env: no banner (gymnasium hides it)
            "assert dt_highway.DTConfig.__module__ == 'dt_highway.config' and dt_highway.env.core.DTHighwayEnv\n"
            "assert {'load_trial', 'DTHighwayEnv', 'metrics', 'world', 'study'} <= set(dir(dt_highway))\n"
            "assert not hasattr(dt_highway, 'no.such') and not hasattr(dt_highway, '_version_')\n"
            "assert {n for n in dt_highway.__all__ if getattr(dt_highway, n) is not None} == {*dt_highway._LAZY, "
            "'ConfigError', 'ENV_ID', '__version__'}\n"
            "try:\n    dt_highway.no_such_name\nexcept AttributeError as exc:\n    print(exc, file=sys.stderr)\n"
            "env = gym.make('dt-highway-v0', config={'highway': {'vehicles_count': 5}, 'camera': {'enabled': False}})\n"
            "assert type(env.unwrapped) is dt_highway.DTHighwayEnv\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env={**os.environ, "SDL_VIDEODRIVER": "offscreen"})
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == ""  # pygame's banner is hidden
    assert "module 'dt_highway' has no attribute 'no_such_name'" in proc.stderr


def test_twin_eval_json(capsys):
    assert main(["twin-eval", "--episodes", "1", "--seed", "3", "--json", "--min-observed-s", "1", *TINY]) == 0
    result = json.loads(capsys.readouterr().out)
    for key in ("precision", "recall", "median_time_to_tag_s", "n_aggressive", "n_normal"):
        assert key in result
    assert result["n_aggressive"] + result["n_normal"] > 0
    assert result["settings"]["noise_sigma_m"] == 1.0


def test_run_writes_its_outputs(tmp_path, capsys):
    out = tmp_path / "quick"
    assert main(["run", "--episodes", "1", "--out", str(out), "--quiet", *TINY]) == 0
    printed = capsys.readouterr().out
    assert str(out / "twin_eval.json") in printed
    assert json.loads((out / "config.json").read_text())["highway"]["vehicles_count"] == 10
    assert "precision" in json.loads((out / "twin_eval.json").read_text())


def test_bench_memory_prints_numbers(capsys):
    args = ["bench", "memory", "--hours", "0.02", "--every-min", "0.4", "--json", *TINY]
    assert main(args) == 0
    result = json.loads(capsys.readouterr().out)
    assert len(result["samples"]) >= 2
    assert result["samples"][-1]["rss_mb"] > 0


def test_bench_startup_times_each_case_in_a_new_process(capsys, monkeypatch):
    from dt_highway import bench

    assert main(["bench", "startup", "--repeats", "1", "--quiet"]) == 0
    text = capsys.readouterr().out
    for name in bench.STARTUP_CASES:
        assert f"{name}  " in text, text
    assert "target: help and a mistake answer within 0.5 s (median): met by" in text
    # a case that fails says which, in one line
    monkeypatch.setattr(bench, "STARTUP_CASES", {"broken": bench.StartupCase(("-c", "import sys; sys.exit('no such thing')"))})
    with pytest.raises(RuntimeError, match="broken exited with 1: no such thing"):
        bench.bench_startup(repeats=1)
    monkeypatch.setattr(bench, "STARTUP_CASES", {"a": bench.StartupCase(("-c", "pass")),
                                                 "b": bench.StartupCase(("-c", "import time; time.sleep(1.0)"))})
    monkeypatch.setattr(bench, "STARTUP_QUICK", ("a", "b"))
    monkeypatch.setattr(bench, "STARTUP_TARGET_S", 0.9)
    r = bench.bench_startup(repeats=2)
    assert r["repeats"] == 2 and r["target_met"] == {"a": True, "b": False}
    assert r["cases"]["b"]["min_s"] >= 1.0
    assert r["cases"]["b"]["min_s"] <= r["cases"]["b"]["median_s"] <= r["cases"]["b"]["max_s"]


def test_bad_numbers_on_the_command_line(capsys):
    proc = subprocess.run([sys.executable, "-m", "dt_highway.cli", "twin-eval", "--episodes", "0"],
                          capture_output=True, text=True)
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1
    assert "--episodes must be a finite number > 0" in proc.stderr
    assert "Traceback" not in proc.stderr


@pytest.mark.parametrize(("args", "message"), [
    (["twin-eval", "--intent", "--oracle", "65"], "--oracle must be at most 64 (got 65): each future multiplies"),
    (["study", "--trials", "6000"], "--trials must be at most 1000 (got 6000): a larger count is most likely a typo"),
])
def test_counts_with_an_upper_bound_are_refused_in_one_line(args, message, capsys):
    with pytest.raises(SystemExit) as stop:
        main(args)
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and err.count("\n") == 1


def test_unknown_scenario_file(capsys):
    assert main(["twin-eval", "--scenario", "envs/nope.toml", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "does not exist" in err[0]


def _cli(*args):
    """``dt-highway ARGS`` in this process (a child process per case cost ~1.5 s of imports each):
    its exit status and what it printed, warnings included as a plain interpreter shows them
    (pytest would keep them off stderr). An exception main() lets through fails the test."""
    out, err = io.StringIO(), io.StringIO()
    with warnings.catch_warnings(record=True) as caught, redirect_stdout(out), redirect_stderr(err):
        warnings.resetwarnings()  # python's own filters, not pytest's
        warnings.simplefilter("default")
        for quiet in (DeprecationWarning, PendingDeprecationWarning, ImportWarning, ResourceWarning):
            warnings.simplefilter("ignore", quiet)
        try:
            status = main(list(args))
        except SystemExit as exc:  # argparse's errors
            status = exc.code
    shown = "".join(warnings.formatwarning(w.message, w.category, w.filename, w.lineno) for w in caught)
    return subprocess.CompletedProcess(args, status, out.getvalue(), shown + err.getvalue())


def test_the_in_process_cli_shows_a_warning_as_the_real_one_does():
    from unittest import mock

    def noisy(args):
        warnings.warn("something noisy", UserWarning, stacklevel=1)
        return 0

    with mock.patch("dt_highway.cli.cmd_report", noisy):
        proc = _cli("report", "x")
    assert "UserWarning: something noisy" in proc.stderr


def _one_line_error(proc, must_contain):
    assert proc.returncode == 2, proc.stderr
    lines = [ln for ln in proc.stderr.strip().splitlines() if ln]
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert must_contain in lines[0]


def test_a_json_result_already_there_is_replaced_only_with_force(tmp_path):
    """twin-eval, evaluate and detector eval refuse an --out FILE that exists before any work (the file is
    kept); --force replaces it."""
    earlier = tmp_path / "result.json"
    earlier.write_text('{"earlier": true}\n')
    for cmd in (["twin-eval"], ["evaluate", "--driver", "agents/idm.toml"], ["detector", "eval"]):
        _one_line_error(_cli(*cmd, "--out", str(earlier), "--quiet"),
                        f"--out {earlier} exists: pass --force to replace it, or name another file")
    assert earlier.read_text() == '{"earlier": true}\n'
    assert main(["twin-eval", "--episodes", "1", "--min-observed-s", "1", "--out", str(earlier), "--force", "--quiet",
                 *TINY]) == 0
    assert "precision" in json.loads(earlier.read_text())


def test_run_camera_and_matching_replace_an_earlier_output_only_with_force(tmp_path):
    """Each rewrote its --out without a word (camera left the earlier run's other frames beside the new ones)."""
    cam = tmp_path / "cam"
    assert main(["camera", "--out", str(cam), "--frames", "2", "--quiet", *TINY]) == 0
    before = sorted(p.name for p in cam.iterdir())
    _one_line_error(_cli("camera", "--out", str(cam), "--frames", "1", "--quiet", *TINY),
                    f"--out {cam} holds the outputs of an earlier camera (frames.jsonl): pass --force")
    assert sorted(p.name for p in cam.iterdir()) == before and "rgb_0001.png" in before
    (cam / "notes.txt").write_text("mine")
    assert main(["camera", "--out", str(cam), "--frames", "1", "--force", "--quiet", *TINY]) == 0
    assert sorted(p.name for p in cam.iterdir()) == ["boxes_0000.png", "config.json", "depth_0000.png", "frames.jsonl",
                                                     "instance_0000.png", "notes.txt", "rgb_0000.png"]
    stray = tmp_path / "stray"  # frames of no camera run (no frames.jsonl): kept without --force
    stray.mkdir()
    (stray / "rgb_0007.png").write_bytes(b"mine")
    assert main(["camera", "--out", str(stray), "--frames", "1", "--quiet", *TINY]) == 0
    assert (stray / "rgb_0007.png").read_bytes() == b"mine" and (stray / "rgb_0000.png").is_file()
    run = tmp_path / "run"
    (run / "twin_eval.json").parent.mkdir()
    (run / "twin_eval.json").write_text("{}")
    _one_line_error(_cli("run", "--out", str(run), "--quiet", *TINY),
                    f"--out {run} holds the outputs of an earlier run (twin_eval.json): pass --force")
    (tmp_path / "m" / "learned").mkdir(parents=True)
    (tmp_path / "m" / "learned" / "config.json").write_text("{}")
    _one_line_error(_cli("matching", "--out", str(tmp_path / "m"), "--quiet", *TINY),
                    "holds the outputs of an earlier matching (learned/config.json)")
    # the sweep ran with the scenario's detector whatever --detectors said
    _one_line_error(_cli("matching", "--out", str(tmp_path / "m2"), "--detectors", "simulated,learned", "--sweep"),
                    "--sweep runs with one detector: give --detectors simulated or learned with it")


def test_user_mistakes_are_one_line_errors(tmp_path):
    _one_line_error(_cli("twin-eval", "--set", "twin.enabled=false", "--quiet"), "twin.enabled")
    _one_line_error(_cli("twin-eval", "--set", "traffic.driver_types=false", "--quiet"), "driver_types")
    _one_line_error(_cli("twin-eval", "--seed", "-1"), "argument --seed: a seed must be >= 0 (got -1)")
    _one_line_error(_cli("train-chase", "--set", "twin.intention.enabled=false", "--out", str(tmp_path / "c.npz"),
                         "--quiet"), "twin-eval --intent, train-intent and train-chase need twin.intention.enabled = true")
    _one_line_error(_cli("train-chase", "--test-seed", "-1", "--out", "x.npz"), "argument --test-seed: a seed must be >= 0")
    _one_line_error(_cli("train-intent", "--alternate", "foo", "--out", str(tmp_path / "a.npz"), "--quiet"),
                    "--alternate expects dotted.key=value")
    _one_line_error(_cli("bench", "memory", "--hours", "nan"), "--hours must be a finite number")
    _one_line_error(_cli("bench", "memory", "--hours", "0.01", "--every-min", "100", "--quiet"),
                    "--every-min must be at most half of --hours in minutes (0.3 for --hours 0.01; got 100)")
    _one_line_error(_cli("bench", "fusion", "--boxes", "100000"), "--boxes must be at most 1000")
    # the deviation run compared no step and reported a deviation of 0 m; the error names the bench
    _one_line_error(_cli("bench", "sim", "--deviation-s", "0.01"),
                    "dt-highway bench sim: error: --deviation-s must be at least 0.5 s")
    from dt_highway.bench import deviation_steps

    assert [deviation_steps(s) for s in (0.5, 1.0, 1.4, 1.5, 30.0)] == [1, 1, 1, 2, 30]  # 0.5 s: its own least value
    (tmp_path / "p.prof").write_text("mine")
    _one_line_error(_cli("bench", "sim", "--profile", str(tmp_path / "p.prof")),
                    f"--profile {tmp_path / 'p.prof'} exists: pass --force to replace it")
    _one_line_error(_cli("bench", "sim", "--profile", str(tmp_path)), f"--profile {tmp_path} is a folder: name a file")
    _one_line_error(_cli("detector", "train", "--out", ""), "--out must not be empty (got '')")
    _one_line_error(_cli("run", "--out", "", "--quiet"), "--out must not be empty (got '')")
    _one_line_error(_cli("report", " "), "study must not be empty (got ' ')")
    _one_line_error(_cli("twin-eval", "--out", str(tmp_path), "--quiet"), f"--out {tmp_path} is a folder: name a file")
    blocker = tmp_path / "file"
    blocker.write_text("x")
    _one_line_error(_cli("run", "--out", str(blocker / "sub"), "--quiet", *TINY), f"{blocker} is a file, not a folder")
    _one_line_error(_cli("replay", str(tmp_path), "--frames-out", str(blocker / "frames")),
                    f"{blocker} is a file, not a folder")
    _one_line_error(_cli("matching", "--frames", "2", "--set", "twin.enabled=false", "--out", str(tmp_path / "m")),
                    "drop --set twin.enabled=false")
    assert not (tmp_path / "m").exists()
    bad = tmp_path / "latin1.toml"
    bad.write_bytes("title = 'caf\xe9'".encode("latin-1"))
    _one_line_error(_cli("twin-eval", "--scenario", str(bad), "--quiet"), "not valid TOML")


ACTION = "highway.action.type = DiscreteMetaAction: drivers act through the Driver action"
DMA = ("--set", "highway.action.type=DiscreteMetaAction")


@pytest.mark.parametrize(("args", "message"), [
    (["evaluate", "--driver", "agents/idm.toml", "--episodes-json"], "--episodes-json needs --json"),
    (["study", "--quick", "--ray-address", "auto"], "--ray-address needs --backend ray"),
    (["study", "--quick", "--backend", "ray", "--ray-address", "127.0.0.1:1"], "cannot reach Ray at 127.0.0.1:1"),
    (["study", "--quick", "--backend", "ray", "--ray-address", "nowhere"], "--ray-address must be host:port"),
    (["replay", "runs/none", "--frames-out", "f", "--speed", "2"], "--speed is for the window"),
    (["calibrate", "--knob", "traffic.dangerous.brake_mps2=2,3,2"], "--knob names the value '2' twice"),
    (["calibrate", "--knob", "traffic.dangerous.brake_mps2=2,3,2.0"], "--knob names the value '2.0' twice"),
    (["calibrate", "--knob", "traffic.dangerous.brake_mps2=2", "--drivers", "agents/human.toml,other/human.toml"],
     "--drivers names two files called 'human' (agents/human.toml, other/human.toml)"),
    (["calibrate", "--knob", "traffic.dangerous.brake_mps2=2", "--drivers", "agents/idm.toml,idm.toml"],
     "--drivers names the driver file 'idm.toml' twice"),
    # an action no driver gives: was a traceback (evaluate, rl-compare) or every trial failing (study, calibrate)
    (["evaluate", "--driver", "agents/idm.toml", "--episodes", "1", *DMA], ACTION),
    (["rl-compare", "--rows", "idm.toml@adas", "--episodes", "1", *DMA], ACTION),
    (["study", "--driver", "agents/ppo-adas.zip", "--trials", "1", *DMA], ACTION),
    (["calibrate", "--knob", "traffic.dangerous.brake_mps2=2", "--drivers", "agents/idm.toml", *DMA], ACTION),
    (["calibrate", "--knob", "highway.action.type=Driver,DiscreteMetaAction", "--drivers", "agents/idm.toml"], ACTION),
])
def test_options_that_would_be_ignored_or_run_twice_are_refused(tmp_path, capsys, monkeypatch, args, message):
    monkeypatch.chdir(Path(__file__).resolve().parents[1])  # the shipped agents/
    out = ["--out", str(tmp_path / "o")] if args[0] in ("study", "calibrate", "rl-compare") else []
    assert main([*args, *out]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err, err  # the one line alone: no progress bar before it
    assert not (tmp_path / "o").exists()  # refused before any work


def test_camera_writes_pngs(tmp_path, capsys):
    import cv2

    out = tmp_path / "cam"
    args = ["camera", "--out", str(out), "--frames", "2", "--raw", "--quiet",
            "--set", "camera.width_px=160", "--set", "camera.height_px=90", *TINY]
    assert main(args) == 0
    assert str(out) in capsys.readouterr().out
    for kind in ("rgb", "depth", "instance", "boxes"):
        for i in range(2):
            img = cv2.imread(str(out / f"{kind}_{i:04d}.png"))
            assert img is not None and img.shape == (90, 160, 3)
    raw = __import__("numpy").load(out / "frame_0001.npz")
    assert raw["depth_m"].dtype.name == "float32" and raw["instance"].dtype.name == "int32"
    lines = (out / "frames.jsonl").read_text().splitlines()
    assert len(lines) == 2 and "vehicles" in json.loads(lines[0])
    assert not (out / "overlay_0000.png").exists()  # no fusion, no ADAS view
    adas = tmp_path / "adas"
    assert main(["camera", "--out", str(adas), "--frames", "2", "--quiet", "--set", "fusion.enabled=true",
                 "--set", "camera.width_px=160", "--set", "camera.height_px=90", *TINY]) == 0
    assert cv2.imread(str(adas / "overlay_0001.png")).shape == (90, 160, 3)


def test_camera_bad_input(tmp_path, capsys):
    assert main(["camera", "--out", str(tmp_path), "--set", "camera.hfov_deg=200", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "camera.hfov_deg" in err[0]
    proc = subprocess.run([sys.executable, "-m", "dt_highway.cli", "camera", "--out", str(tmp_path), "--frames", "0"],
                          capture_output=True, text=True)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr


def test_bench_camera_prints_numbers(capsys):
    import os

    affinity = os.sched_getaffinity(0)
    args = ["bench", "camera", "--scenes", "2", "--repeats", "1", "--json", *TINY]
    assert main(args) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["median_ms"]["ours_320x180"] > 0 and result["median_ms"]["highway_env_topdown_640x360"] > 0
    assert result["ratio_ours_640x360_to_highway_env"] > 0
    assert os.sched_getaffinity(0) == affinity  # the benchmark gives the cores back


def test_matching_writes_curve_and_summary(tmp_path, capsys):
    out = tmp_path / "match"
    args = ["matching", "--out", str(out), "--frames", "4", "--quiet", *TINY, "--set", "highway.duration=40",
            "--set", "camera.width_px=320", "--set", "camera.height_px=180"]
    assert main(args) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n_frames"] == 4
    assert set(summary["methods"]) == {"baseline", "fusion", "joint", "tracked"}
    for m in summary["methods"].values():
        assert 0.0 <= m["acc_iou70"] <= 1.0
    header = (out / "curve.csv").read_text().splitlines()[0]
    assert header == "method,subset,iou_threshold,accuracy"
    assert (out / "curve.png").stat().st_size > 1000


def test_bench_fusion_prints_numbers(capsys):
    assert main(["bench", "fusion", "--frames", "5", "--boxes", "5", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert set(result["methods"]) == {"baseline", "fusion", "joint", "tracked"}
    assert all(r["median_ms"] > 0 for r in result["methods"].values())


def test_bench_sim_prints_steps_ratios_and_the_deviation(capsys):
    assert main(["bench", "sim", "--steps", "1", "--deviation-s", "2", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert set(r["steps_per_s"]) == {"stock_highway_v0", "ours_plain_idm", "ours_driver_types", "ours_adas_pipeline"}
    assert all(v > 0 for v in r["steps_per_s"].values())
    assert r["same_vehicles"] and r["max_deviation_m"] <= 1e-6


def test_an_unknown_observation_or_action_type_is_a_one_line_error():
    proc = _cli("run", "--set", "highway.observation.type=Nope", "--quiet")
    _one_line_error(proc, "highway.observation.type = 'Nope'")
    proc = _cli("run", "--set", "highway.action.type=Nope", "--quiet")
    _one_line_error(proc, "highway.action.type = 'Nope'")
    assert "Driver, DiscreteDriver" in proc.stderr and "DiscreteMetaAction" in proc.stderr


def test_evaluate_shows_a_dash_where_there_is_no_ttc():
    # a 3 s episode without a closing leader has no TTC sample: "-", as the study's summary shows it, not "nan"
    run = _cli("evaluate", "--driver", "agents/idm.toml", "--episodes", "1", "--quiet",
               "--set", "highway.duration=3", "--set", "twin.preroll_s=1")
    assert run.returncode == 0 and "mean TTC - s  cut-in min TTC - s (0 cut-ins)" in run.stdout, run
    assert "nan" not in run.stdout
