"""The ``dt-highway`` command line.

Every command has ``--help``, takes ``--scenario FILE`` and repeated ``--set key=value``,
prints where its outputs went, and exits with status 2 and a one-line message on bad
input (no traceback for a user's mistake).
"""

from __future__ import annotations

import argparse
import json
import math
import re
import shlex
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn, TypedDict

import gymnasium as gym
from tqdm import tqdm

from dt_highway._version import __version__
from dt_highway.choices import (
    COMPARE_SCENARIO,
    COMPARE_SEED,
    CONDITIONS,
    CRASH_POLICIES,
    DEFAULT_PROTOCOL,
    HIDEABLE,
    INTENT_EPISODES,
    OUTPUT_FILES,
    PICTURE_HIDEABLE,
    PICTURE_REVEALABLE,
    POPULATIONS,
    SCORE_THRESHOLDS,
    STARTS,
    SWEEP_FILES,
    TEST_SEED,
    TRAIN_SEED,
)
from dt_highway.errors import ConfigError
from dt_highway.hmi.keys import KeyScript, KeyScriptError
from dt_highway.interrupts import interrupted_by_user
from dt_highway.jsonio import dump_json

if TYPE_CHECKING:
    from dt_highway.config import DTConfig
    from dt_highway.drivers import Driver
    from dt_highway.hmi.drive import DriveOptions

# Every command imports what it runs when it runs, so that ``dt-highway --help``, each command's ``--help`` and a
# mistyped option answer in well under a second: the parser needs only the light modules above (the choices it
# offers, the error it reports). The simulation (highway-env, matplotlib, numba), the report (scipy.stats), the
# learned detector (torch) and RL training (stable-baselines3 and torch) take 2-4 s to import. Where a command checks
# its settings and options (``--set``, ``--scenario``, a clash of options), it does so before it imports the
# simulation, so that a mistake there answers in under a second too.


class _Parser(argparse.ArgumentParser):
    """argparse, but a mistake is reported in one line (with a pointer to ``--help``)."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _whole(text: str, not_a_number: str, negative: str) -> int:
    """``text`` as a whole number >= 0, else argparse's error with the message given for the case."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{not_a_number} (got '{text}')") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"{negative} (got {text})")
    return value


def _seed(text: str) -> int:
    return _whole(text, "a seed must be a whole number", "a seed must be >= 0")  # argparse names the option


def _add_drive_args(p: argparse.ArgumentParser) -> None:
    """Options shared by drive and session."""
    _add_config_args(p, STUDY_SCENARIO)
    p.add_argument("--participant", required=True, help="participant id, e.g. P01")
    p.add_argument("--duration", type=_positive(float, "--duration"), help="trial length [s] (default: the scenario's)")
    p.add_argument("--seed", type=_seed, default=0, help="traffic seed (default 0)")
    p.add_argument("--keys-from", metavar="FILE",
                   help="replay a key script ('0.5 down UP' lines) instead of the keyboard")
    p.add_argument("--screenshot-every", type=_positive(float, "--screenshot-every"), metavar="S",
                   help="save what the participant sees every S seconds of trial time")
    p.add_argument("--screenshots", metavar="DIR", help="where screenshots go (default <trial>/screenshots)")
    p.add_argument("--fps", type=_positive(int, "--fps"), default=60,
                   help="how often the window reads keys and may draw, per second (default 60); "
                        "a picture is drawn only when the simulation changed it")
    p.add_argument("--no-minimap", action="store_true", help="start with the mini-map hidden (M toggles it)")
    p.add_argument("--steering", action="store_true", help="Left/Right steer (self-centring) instead of changing lanes")
    p.add_argument("--size", type=_window_size, metavar="WxH",
                   help="window and camera size in pixels, e.g. 1280x720 (default: the camera's, 640x360)")
    p.add_argument("--fullscreen", action="store_true", help="fill the screen (the picture scaled, its aspect kept)")
    p.add_argument("--on-crash", choices=CRASH_POLICIES, default="end",
                   help="end: a crash ends the trial (status ended_by_collision); continue: the ego is put back in "
                        "its lane with a clear gap and the trial goes on, crashes counted (default end)")
    p.add_argument("--mirrors", action="store_true", help="draw the rear-view mirror and two side mirrors along the top")
    p.add_argument("--no-sound", action="store_true", help="no beep on a crash")
    p.add_argument("--wheel", nargs="?", const=0, type=_wheel_index, metavar="INDEX",
                   help="drive with a wheel and pedals (or a gamepad) through pygame's joystick API: its index among "
                        "those connected (default 0); P, M and Esc stay on the keyboard")
    p.add_argument("--wheel-calibration", metavar="FILE",
                   help="the wheel's calibration (default <out>/wheel-calibration.json); when missing, the calibration "
                        "screen runs first and saves it there")


def _wheel_index(text: str) -> int:
    return _whole(text, "--wheel must be a device index >= 0", "--wheel must be a device index >= 0")


def _window_size(text: str) -> tuple[int, int]:
    from dt_highway.hmi.window import parse_size  # lazy: cv2 and pygame (0.05 s, not the simulation)

    try:
        return parse_size(text)
    except ConfigError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def _add_config_args(p: argparse.ArgumentParser, default_scenario: str | None = None) -> None:
    p.add_argument("--scenario", metavar="FILE",
                   help=f"scenario TOML file (default {default_scenario})" if default_scenario
                   else "scenario TOML file (e.g. envs/highway-trial.toml)")
    p.add_argument(
        "--set", dest="overrides", metavar="KEY=VALUE", action="append", default=[],
        help="override one configuration value, e.g. --set twin.uplink.noise_sigma_m=3 (repeatable)",
    )


def _add_result_out(p: argparse.ArgumentParser, text: str) -> None:
    """``--out FILE`` for a command's JSON result, and the ``--force`` that lets it replace an earlier one."""
    p.add_argument("--out", dest="out_json", metavar="FILE", help=text)
    p.add_argument("--force", action="store_true", help="replace the file --out names if it exists")


def _config(args: argparse.Namespace, extra: dict[str, Any] | None = None) -> DTConfig:
    from dt_highway.config import load_config  # lazy: pydantic

    return load_config(args.scenario, args.overrides, extra)


def _progress(total: int, desc: str, quiet: bool, unit: str = "step", initial: int = 0) -> tqdm:
    return tqdm(total=total, desc=desc, unit=unit, disable=quiet, file=sys.stderr, leave=False, initial=initial)


def _oracle_hide(text: str) -> frozenset[str]:
    names = frozenset(n.strip() for n in text.split(",") if n.strip())
    unknown = sorted(names - set(HIDEABLE) - set(PICTURE_HIDEABLE))
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"--oracle-hide takes a comma-separated list of {', '.join(HIDEABLE)} (with "
                                         f"--oracle-from state) or {', '.join(PICTURE_HIDEABLE)} (with --oracle-from "
                                         f"picture) (got '{text}')")
    return names


def _oracle_reveal(text: str) -> frozenset[str]:
    names = frozenset(n.strip() for n in text.split(",") if n.strip())
    unknown = sorted(names - set(PICTURE_REVEALABLE))
    if unknown or not names:
        raise argparse.ArgumentTypeError(f"--oracle-reveal takes a comma-separated list of "
                                         f"{', '.join(PICTURE_REVEALABLE)} (got '{text}')")
    return names


def _test_episodes(text: str) -> int:
    return _whole(text, "--test-episodes must be a whole number", "--test-episodes must be >= 0")


def _positive(kind: Callable[[str], float], name: str, most: float | None = None,
              why: str = "") -> Callable[[str], float]:
    """An argparse type: a finite number > 0 (and at most ``most``), else a one-line error naming the option.

    :param kind: ``int`` or ``float``
    :param name: the option, for the message
    :param most: the largest value allowed (``None``: no bound)
    :param why: said after the bound in the message
    :return: the parser
    """
    def parse(text: str) -> float:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be a number (got '{text}')") from None
        if not math.isfinite(value) or value <= 0:
            raise argparse.ArgumentTypeError(f"{name} must be a finite number > 0 (got {text})")
        if most is not None and value > most:
            raise argparse.ArgumentTypeError(f"{name} must be at most {most:g} (got {text}){why}")
        return value

    return parse


# ----------------------------------------------------------------------------- twin-eval
ORACLE_MAX_FUTURES = 64
"""``twin-eval --oracle N``'s largest ``N`` (futures per estimate; 8 already makes the run about 9 times longer)"""

STUDY_MAX_TRIALS = 1000
"""``study --trials``' largest value, pairs per condition (60 pairs of 5 conditions, 300 trials, took 34 min here:
1000 pairs of two conditions would take about 4 hours): a mistyped count is refused rather than started"""

MIN_OBSERVED_S = 30.0
"""``twin-eval``'s default ``--min-observed-s``: judge only drivers the twin observed this long [s]"""


def cmd_twin_eval(args: argparse.Namespace) -> int:
    """``dt-highway twin-eval``: the twin's aggressive tags (or ``--intent``, its intention) scored on episodes.

    :param args: the parsed command line of ``dt-highway twin-eval``
    :return: the exit status (0 on success)
    """
    from dt_highway.config import override_value  # lazy: pydantic

    if args.population is not None:
        for text in args.overrides:
            set_to = override_value(text, "traffic.population")
            if set_to is not None and set_to != args.population:
                raise ConfigError(f"--population {args.population} and --set {text.strip()} name two populations: "
                                  "give one")
        args.overrides = [f"traffic.population={args.population}", *args.overrides]
    if args.intent:
        if args.min_observed_s is not None:
            raise ConfigError("--min-observed-s goes with the tags' evaluation (without --intent): the intention is "
                              "scored at every estimate")
        return _twin_eval_intent(args)
    given = [flag for flag, on in (("--sweep", args.sweep), ("--driver", args.driver is not None),
                                   ("--oracle", args.oracle is not None),
                                   ("--oracle-hide", bool(args.oracle_hide)),
                                   ("--oracle-from", args.oracle_from != "state"),
                                   ("--oracle-reveal", bool(args.oracle_reveal))) if on]
    if given:
        raise ConfigError(f"{' and '.join(given)} {'go' if len(given) > 1 else 'goes'} with --intent")
    cfg = _config(args)
    episodes = args.episodes or 3
    from dt_highway.evaluation.twin import episode_steps, evaluate_twin  # lazy: highway-env

    steps = episodes * episode_steps(cfg)
    with _progress(steps, "twin-eval", args.quiet or args.json) as bar:
        result = evaluate_twin(cfg, episodes, args.seed, args.min_observed_s or MIN_OBSERVED_S, progress=bar.update)
    if args.json:
        print(dump_json(result))
    else:
        r = result
        print(
            f"precision {r['precision']:.3f}  recall {r['recall']:.3f}  "
            f"median time to tag {r['median_time_to_tag_s']:.1f} s"
            f"  (aggressive {r['n_aggressive']}, normal {r['n_normal']}, episodes {r['episodes']}, seed {r['seed']})"
        )
        if "auc_label" in r:
            print(
                f"continuum: AUC vs label {r['auc_label']:.3f}, vs latent above median "
                f"{r['auc_latent_above_median']:.3f}, Spearman vs latent {r['spearman_latent']:.3f}; "
                f"precision {r['precision_at_recall_0_80']:.3f} at recall >= 0.80"
            )
            c = r["ceiling"]
            print(f"ceiling (a ranking by every driver's true parameters): AUC vs label {c['auc_label']:.3f}, "
                  f"precision {c['precision_at_recall_0_80']:.3f} at recall >= 0.80")
    if args.out_json:
        _write_result(args.out_json, result)
    return 0


def _weights_out(args: argparse.Namespace, suffix: str) -> None:
    """A training command's ``--out``, checked before any episode runs: a ``suffix`` file, not there yet
    unless ``--force`` (:func:`_check_out` has checked that it is no folder and that its folder takes a file;
    that folder is made when the weights are written).

    :raises ConfigError: one line naming what is wrong
    """
    out = Path(args.out)
    if out.suffix.lower() != suffix:
        raise ConfigError(f"--out must name a {suffix} file (got {args.out!r})")
    if out.exists() and not args.force:
        raise ConfigError(f"{out} exists: pass --force to replace it")


def _write_result(path: str, result: Any) -> None:
    """Write a command's JSON result to ``path`` (``--out FILE``), creating its folder, and say where."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(dump_json(result) + "\n")
    print(f"wrote {out}", file=sys.stderr)


def _intent_driver(args: argparse.Namespace) -> tuple[Driver | None, dict[str, Any] | None]:
    """The ``--driver`` of ``twin-eval --intent`` and ``train-intent``: the driver, and what it adds to the
    configuration (the baseline condition and the driver's overrides, as in a study trial)."""
    if args.driver is None:
        return None, None
    from dt_highway.conditions import condition_config  # lazy: highway-env
    from dt_highway.config import deep_merge  # lazy: pydantic
    from dt_highway.drivers import load_driver  # lazy: highway-env

    driver = load_driver(args.driver)
    return driver, deep_merge(condition_config("baseline"), driver.config_overrides())


def _twin_eval_intent(args: argparse.Namespace) -> int:
    """``twin-eval --intent [--sweep]``: the lane-change intention against the simulator's truth."""
    if args.scenario is None:
        args.scenario = EVAL_SCENARIO
    driver, extra = _intent_driver(args)
    cfg = _config(args, extra)
    episodes = args.episodes or INTENT_EPISODES
    result: dict[str, Any] | list[dict[str, Any]]
    if args.sweep and args.oracle is not None:
        raise ConfigError("--oracle scores one setting: leave out --sweep")
    if args.oracle_hide and args.oracle is None:
        raise ConfigError("--oracle-hide goes with --oracle N")
    if args.oracle_from != "state" and args.oracle is None:
        raise ConfigError("--oracle-from goes with --oracle N")
    wrong = sorted(set(args.oracle_hide) - set(HIDEABLE if args.oracle_from == "state" else PICTURE_HIDEABLE))
    if args.oracle_from == "picture" and wrong:
        raise ConfigError(f"--oracle-hide {','.join(wrong)} goes with --oracle-from state (the twin's picture has none of "
                          f"the state to hide; with --oracle-from picture it can hide: {', '.join(PICTURE_HIDEABLE)})")
    if wrong:
        raise ConfigError(f"--oracle-hide {','.join(wrong)} goes with --oracle-from picture")
    if args.oracle_reveal and args.oracle_from != "picture":
        raise ConfigError("--oracle-reveal goes with --oracle-from picture (the oracle starting from the simulator's "
                          "state already has all of it)")
    both = sorted(set(args.oracle_reveal) & set(args.oracle_hide))
    if both:
        raise ConfigError(f"--oracle-hide and --oracle-reveal both name {','.join(both)}: choose one")
    if "attempts" in args.oracle_reveal and "chases" in args.oracle_hide:
        raise ConfigError("--oracle-reveal attempts gives the chases too: it cannot go with --oracle-hide chases")
    from dt_highway.evaluation.intent import (  # lazy: highway-env
        evaluate_intent,
        format_intent,
        format_sweep,
        run_intent_sweep,
        sweep_steps,
    )
    from dt_highway.evaluation.intent_oracle import OracleSettings  # lazy: highway-env
    from dt_highway.evaluation.twin import episode_steps  # lazy: highway-env

    if args.sweep:
        with _progress(sweep_steps(cfg, episodes), "intent sweep", args.quiet or args.json) as bar:
            result = run_intent_sweep(cfg, episodes, args.seed, progress=bar.update, driver=driver)
        lines = format_sweep(result)
    else:
        with _progress(episodes * episode_steps(cfg), "twin-eval --intent", args.quiet or args.json) as bar:
            uplink = cfg.twin.uplink  # a hidden position is off by one of this uplink's fixes
            oracle = None if args.oracle is None else OracleSettings(
                rollouts=args.oracle, seed=args.seed, hide=args.oracle_hide, start=args.oracle_from,
                reveal=args.oracle_reveal,
                sigma_position_m=uplink.noise_sigma_m, sigma_speed_mps=uplink.speed_noise_sigma_mps)
            result = evaluate_intent(cfg, episodes, args.seed, progress=bar.update, driver=driver, oracle=oracle)
        lines = format_intent(result)
    print(dump_json(result) if args.json else "\n".join(lines))
    if args.out_json:
        _write_result(args.out_json, result)
    return 0


def cmd_train_tagger(args: argparse.Namespace) -> int:
    """Fit the twin's evidence tagger on simulated training seeds (the continuum by default).

    :param args: the parsed command line of ``dt-highway train-tagger``
    :return: the exit status (0 on success)
    """
    args.overrides = [f"traffic.population={args.population}", *args.overrides]
    cfg = _config(args)
    _weights_out(args, ".json")
    seeds = list(range(args.seed, args.seed + args.seeds))
    from dt_highway.evaluation.tagger_train import train_tagger, training_steps  # lazy: highway-env

    with _progress(training_steps(cfg, seeds, args.episodes), "train-tagger", args.quiet) as bar:
        try:
            summary = train_tagger(cfg, seeds, args.episodes, args.out, progress=bar.update)
        except ValueError as exc:  # drivers of one class only
            raise ConfigError(str(exc)) from None
    print(f"{summary['samples']} drivers ({summary['aggressive']} aggressive) from seeds {seeds[0]}-{seeds[-1]}, "
          f"training AUC {summary['train_auc']:.3f}; wrote {args.out}")
    return 0


def cmd_train_intent(args: argparse.Namespace) -> int:
    """Train the twin's lane-change intention network on simulated fixes (training seeds).

    :param args: the parsed command line of ``dt-highway train-intent``
    :return: the exit status (0 on success)
    """
    from dt_highway.config import deep_merge, merge, parse_override  # lazy: pydantic

    if args.scenario is None:
        args.scenario = EVAL_SCENARIO
    driver, extra = _intent_driver(args)
    cfg = _config(args, extra)
    alternate: dict[str, Any] = {}
    for text in args.alternate:
        alternate = deep_merge(alternate, parse_override(text, "--alternate"))
    for where, tree in (("--scenario, --set or the driver", cfg), ("--alternate", merge(cfg, alternate))):  # one line
        if tree.twin.intention.model != "learned":
            raise ConfigError(f"train-intent trains the learned network: twin.intention.model = "
                              f"{tree.twin.intention.model!r} ({where}) has no weights to train; drop it")
    _weights_out(args, ".npz")
    from dt_highway.evaluation.intent_train import train_intention  # lazy: highway-env
    from dt_highway.evaluation.twin import episode_steps  # lazy: highway-env

    record = _progress(args.episodes * episode_steps(cfg), "record", args.quiet)
    fitting = _progress(args.epochs, "fit", args.quiet, unit="epoch")
    with record, fitting:
        try:
            summary = train_intention(cfg, args.episodes, args.seed, args.out, args.epochs, alternate or None,
                                      progress=lambda stage, n: (record if stage == "record" else fitting).update(n),
                                      driver=driver)
        except ValueError as exc:  # nothing to learn from
            raise ConfigError(str(exc)) from None
    print(f"trained on {summary['samples']} estimates of seeds {summary['seeds'][0]}-{summary['seeds'][1]}, "
          f"final loss {summary['final_loss']:.4f}")
    print(f"wrote {summary['out']}")
    return 0


def cmd_train_chase(args: argparse.Namespace) -> int:
    """Train the twin's chase detector on simulated fixes and score it on held-out seeds.

    :param args: the parsed command line of ``dt-highway train-chase``
    :return: the exit status (0 on success)
    """
    if args.scenario is None:
        args.scenario = EVAL_SCENARIO
    cfg = _config(args)
    _weights_out(args, ".npz")
    from dt_highway.evaluation.chase_train import train_chase  # lazy: highway-env
    from dt_highway.evaluation.twin import episode_steps  # lazy: highway-env

    record = _progress((args.episodes + args.test_episodes) * episode_steps(cfg), "record", args.quiet)
    fitting = _progress(args.epochs, "fit", args.quiet, unit="epoch")
    with record, fitting:
        try:
            summary = train_chase(cfg, args.episodes, args.seed, args.out, args.epochs, args.test_episodes,
                                  args.test_seed,
                                  progress=lambda stage, n: (record if stage == "record" else fitting).update(n))
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
    print(f"trained on {summary['samples']} estimates of seeds {summary['seeds'][0]}-{summary['seeds'][1]} "
          f"({summary['chasing_share']:.1%} chasing the ego), final loss {summary['losses'][-1]:.4f}")
    held = summary.get("held_out")
    if held is not None:
        print(f"held out, seeds {held['seeds'][0]}-{held['seeds'][1]}:")
        for name in ("all", "near_ego"):
            s = held[name]
            at = ", ".join(f"{th:g}: {s[f'precision_at_{th:g}']:.2f} / {s[f'recall_at_{th:g}']:.2f}"
                           for th in SCORE_THRESHOLDS)
            print(f"  {name:8s} {s['samples']} estimates, {s['chasing']} chasing; AUC {s['auc']:.3f}; "
                  f"precision / recall at {at}")
    print(f"wrote {summary['out']}")
    return 0


# ----------------------------------------------------------------------------- run
def cmd_run(args: argparse.Namespace) -> int:
    """Headless episodes with the twin: what the ego receives, and how the tags compare.

    :param args: the parsed command line of ``dt-highway run``
    :return: the exit status (0 on success)
    """
    cfg = _config(args)
    from dt_highway.evaluation.twin import episode_steps, evaluate_twin  # lazy: highway-env

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    steps = args.episodes * episode_steps(cfg)
    t0 = time.perf_counter()
    with _progress(steps, "run", args.quiet) as bar:
        result = evaluate_twin(cfg, args.episodes, args.seed, progress=bar.update)
    result["wall_time_s"] = round(time.perf_counter() - t0, 2)
    (out / "config.json").write_text(dump_json(cfg.to_dict()) + "\n")
    (out / "twin_eval.json").write_text(dump_json(result) + "\n")
    print(
        f"twin tags vs ground truth: precision {result['precision']:.3f}, recall {result['recall']:.3f}, "
        f"median time to tag {result['median_time_to_tag_s']:.1f} s "
        f"({result['n_aggressive']} aggressive / {result['n_normal']} normal judgements)"
    )
    print(f"wrote {out / 'twin_eval.json'} and {out / 'config.json'}")
    return 0


# ----------------------------------------------------------------------------- study / report
STUDY_SCENARIO = "envs/highway-trial.toml"
EVAL_SCENARIO = "envs/highway-trial.toml"
"""The study's default scenario: the paper's trial highway (section IV-C)"""


class _QuickStudy(TypedDict):
    driver: str
    trials: int
    duration_s: float


QUICK: _QuickStudy = {"driver": "agents/human.toml", "trials": 3, "duration_s": 60.0}
"""The README's main job: a small paired study with the human-like driver"""


def cmd_calibrate(args: argparse.Namespace) -> int:
    """Baseline figures of a scenario for several values of one knob (the calibration table).

    :param args: the parsed command line of ``dt-highway calibrate``
    :return: the exit status (0 on success)
    """
    from dt_highway.config import find_file  # lazy: pydantic
    from dt_highway.drivers import load_driver  # lazy: highway-env
    from dt_highway.evaluation.calibration import (  # lazy: highway-env
        calibrate,
        calibration_table,
        check_table_kept,
        check_values,
        knob_value,
        markdown,
        split_values,
    )

    key, sep, values = args.knob.partition("=")
    if not sep or not key.strip() or not values.strip():
        raise ConfigError(f"--knob must be KEY=V1,V2,... e.g. traffic.dangerous.brake_mps2=2,3,4 (got {args.knob!r})")
    typed = [d.strip() for d in args.drivers.split(",") if d.strip()]
    if not typed:
        raise ConfigError("--drivers needs at least one driver file, e.g. agents/human.toml,agents/idm.toml")
    drivers = [find_file(d, "agents") for d in typed]
    found = {d: str(Path(f).resolve()) for d, f in zip(typed, drivers, strict=True)}
    _check_once(typed, "--drivers", "driver file", key=found.__getitem__)  # idm.toml is agents/idm.toml
    stems: dict[str, str] = {}
    for d in typed:  # a cell's folder and table row are named after the driver file
        if stems.setdefault(Path(d).stem, d) != d:
            raise ConfigError(f"--drivers names two files called {Path(d).stem!r} ({stems[Path(d).stem]}, {d}): the "
                              "table's rows and cell folders are named after the file, so rename one")
    for d in drivers:
        load_driver(d)
    value_list = split_values(values)
    _check_once(value_list, "--knob", "value", key=lambda v: knob_value(key.strip(), v))  # 2 and 2.0 alike
    scenario = find_file_or_default(args.scenario)
    check_values(key.strip(), value_list, scenario, args.overrides)  # one line, before the bar
    check_table_kept(Path(args.out), key.strip(), [Path(d).stem for d in typed], value_list, args.force)
    total = len(drivers) * len(value_list) * args.trials
    with _progress(total, "calibrate", args.quiet, unit="trial") as bar:
        cells = calibrate(key.strip(), value_list, drivers, args.out, args.trials, args.seed, scenario,
                          args.overrides, args.workers, lambda r: bar.update(1))
    table = calibration_table(cells, key.strip())
    Path(args.out).mkdir(parents=True, exist_ok=True)
    csv_path, md_path = Path(args.out) / "calibration.csv", Path(args.out) / "calibration.md"
    table.to_csv(csv_path, index=False)
    md_path.write_text(markdown(table), encoding="utf-8")
    print(md_path.read_text(encoding="utf-8"), end="")
    print(f"wrote {csv_path}, {md_path}")
    return 0


def _check_once(items: Sequence[str], option: str, what: str, key: Callable[[str], str] = str) -> None:
    """Refuse a comma-separated list that names the same item twice (it would be run twice).

    :param key: what makes two items the same (default: their text)
    :raises ConfigError: one line naming the repeated item
    """
    seen: set[str] = set()
    for item in items:
        if key(item) in seen:
            raise ConfigError(f"{option} names the {what} {item!r} twice: give each once")
        seen.add(key(item))


def cmd_study(args: argparse.Namespace) -> int:
    """A paired study of one driver in several conditions, then (with --quick) its report.

    :param args: the parsed command line of ``dt-highway study``
    :return: the exit status: 0 when every trial ran or was done already, 1 when one failed, 130 on Ctrl-C
    """
    from dt_highway.conditions import driver_config  # lazy: highway-env
    from dt_highway.config import find_file, load_config  # lazy: pydantic
    from dt_highway.drivers import load_driver  # lazy: highway-env
    from dt_highway.env.seat import DriverSeat  # lazy: highway-env
    from dt_highway.report import write_report  # lazy: heavy (scipy.stats, ~0.35 s)
    from dt_highway.study import check_backend, freeze_inputs, is_completed, plan, run_study  # lazy: highway-env

    if args.quick:
        driver = find_file(args.driver or QUICK["driver"], "agents")
        scenario = find_file_or_default(args.scenario)
        trials = args.trials or QUICK["trials"]
        overrides = [f"highway.duration={QUICK['duration_s']}", *args.overrides]
        out = args.out or "runs/quick-study"
    else:
        if not args.driver or not args.out:
            raise ConfigError("dt-highway study needs --driver FILE and --out DIR (or --quick)")
        driver, scenario = find_file(args.driver, "agents"), find_file_or_default(args.scenario)
        trials, overrides, out = args.trials or 10, list(args.overrides), args.out
    check_backend(args.backend, args.ray_address)  # Ray and its address: before the progress bar
    conditions = [c.strip() for c in args.conditions.split(",") if c.strip()]
    _check_study_out(out)
    # bad driver files and configurations fail here, once, rather than in every trial
    drv = load_driver(driver)
    load_config(scenario, overrides)
    for condition in conditions:
        cfg = driver_config(scenario, overrides, condition, drv.config_overrides())  # e.g. an action no driver takes
        if hasattr(drv, "model"):  # a trained policy: check once that it can drive this scenario in each condition
            env = gym.make("dt-highway-v0", config=cfg.to_dict())
            try:
                DriverSeat(env.unwrapped, drv.senses)  # its observation can be made of this env
                drv.reset(0)  # and its action menu is its network's
            finally:
                env.close()
    specs = plan(out, driver, conditions, trials, args.seed, scenario, overrides, parquet=args.parquet)
    if args.parquet:
        try:
            import pyarrow  # lazy: optional extra (pip install dt-highway[parquet]) # noqa: F401
        except ImportError:
            raise ConfigError("--parquet needs pyarrow: pip install 'dt-highway[parquet]'") from None
    frozen_driver, frozen_scenario = freeze_inputs(out, driver, scenario)  # the trials read the study's copies
    specs = [replace(s, driver=frozen_driver, scenario=frozen_scenario) for s in specs]
    t0 = time.perf_counter()
    with _progress(len(specs), "study", args.quiet, unit="trial",
                   initial=sum(is_completed(s.directory) for s in specs)) as bar:  # a resumed study's done trials

        def done(r: dict[str, Any]) -> None:
            if r["status"] != "skipped":  # counted from the start
                bar.update(1)
            if r["status"] == "failed":
                bar.write(f"trial {Path(r['directory']).name} failed: {r.get('error')}", file=sys.stderr)

        try:
            result = run_study(specs, out, args.workers, done, args.backend, args.ray_address)
        except KeyboardInterrupt:
            bar.close()
            _interrupted(specs, out)
            return 130
    print(f"study {out}: {len(result.completed)} trials run, {len(result.skipped)} already done, "
          f"{len(result.failed)} failed ({time.perf_counter() - t0:.0f} s)")
    if args.quick or args.report:
        files = write_report(out)
        _print_summary(files["summary"])
        print(f"wrote {', '.join(str(f) for f in files.values())}")
    return 1 if result.failed else 0


def _check_study_out(out: str) -> None:
    """Refuse a study directory that exists and is not a study's (no ``study.json``) unless it is empty."""
    path = Path(out)
    if not path.exists() or (path / "study.json").exists():
        return
    if not path.is_dir():
        raise ConfigError(f"--out {out} is not a directory")
    if {p.name for p in path.iterdir()} - {"inputs"}:  # inputs/ alone: a study stopped before its first trial
        raise ConfigError(f"--out {out} exists and is not a study (no study.json): use a new or empty directory")


def _interrupted(specs: Sequence[Any], out: str) -> None:
    """After Ctrl-C: what is done, and the command that resumes the study."""
    from dt_highway.study import is_completed  # lazy: highway-env

    n = sum(is_completed(s.directory) for s in specs)
    if sys.argv[1:2] == ["study"]:
        again = shlex.join(["dt-highway", *sys.argv[1:]])
        how = f"resume with: {again}"
    else:  # called as a function (main(argv)): sys.argv is not this command's
        how = f"resume with the same command (same --out {shlex.quote(out)})"
    print(f"dt-highway study: interrupted, {n} of {len(specs)} trials done in {out}; {how}", file=sys.stderr)


def _two_places(x: float | None) -> str:
    """A figure of a summary line: ``-`` where there is none (no closing samples: no TTC)."""
    return "-" if x is None or not math.isfinite(x) else f"{x:.2f}"


def _print_summary(path: Path) -> None:
    s = json.loads(path.read_text())
    width = max((len(cond) for cond in s["conditions"]), default=8)  # the columns line up (adas-threat: 11)
    for cond, c in s["conditions"].items():
        sv, ttc = c["speed_variance_kmh2"], c["ttc_mean_s"]
        f = _two_places
        print(f"  {cond:{width}s} n={c['n']:3d}  speed variance {f(sv['mean'])} (km/h)^2  mean TTC {f(ttc['mean'])} s  "
              f"collisions {c['collisions']}  cut-ins {c['cut_ins']} ({c['cut_ins_marked_in_time']} marked in time)")


def cmd_drive(args: argparse.Namespace) -> int:
    """One keyboard trial in the driving window.

    :param args: the parsed command line of ``dt-highway drive``
    :return: the exit status: 0 when the trial completed or ended by a collision, else 1
    """
    from dt_highway.hmi.drive import run_drive  # lazy: highway-env

    opts = _drive_options(args, args.condition)
    result = run_drive(opts)
    if result["status"] == "not started":  # no folder was written
        print(f"trial not started ({result['end_reason']}): nothing saved")
        return 1
    print(f"trial {result['directory']}: {result['status']} ({result['end_reason']}), {result['frames']} frames"
          + (f", {result['screenshots']} screenshots" if result["screenshots"] else ""))
    return 0 if result["status"] in ("completed", "ended_by_collision") else 1  # a crash under --on-crash end: saved


def _drive_options(args: argparse.Namespace, condition: str) -> DriveOptions:
    """The options of a keyboard trial from the command line (drive and session)."""
    from dt_highway.hmi.drive import DriveOptions  # lazy: highway-env

    try:
        script = KeyScript.load(args.keys_from) if args.keys_from else None
    except KeyScriptError as err:
        raise ConfigError(str(err)) from None
    if args.screenshots and not args.screenshot_every and args.command == "drive":  # a session's: its screens
        raise ConfigError("--screenshots DIR needs --screenshot-every S")
    if args.wheel_calibration and args.wheel is None:
        raise ConfigError("--wheel-calibration FILE needs --wheel")
    return DriveOptions(
        participant=_participant(args.participant), condition=condition, out=Path(args.out),
        practice=getattr(args, "practice", False), scenario=find_file_or_default(args.scenario),
        overrides=list(args.overrides), duration_s=args.duration, seed=args.seed, keys_from=script,
        screenshot_every_s=args.screenshot_every, screenshots=Path(args.screenshots) if args.screenshots else None,
        fps=args.fps, minimap=not args.no_minimap, steering=args.steering, size=args.size, fullscreen=args.fullscreen,
        on_crash=args.on_crash, mirrors=args.mirrors, sound=not args.no_sound, wheel=args.wheel,
        wheel_calibration=Path(args.wheel_calibration) if args.wheel_calibration else None,
        force=getattr(args, "force", False))


def cmd_session(args: argparse.Namespace) -> int:
    """A participant's session: briefing, practice in every condition, the conditions counterbalanced
    with questionnaires after each, an end screen.

    :param args: the parsed command line of ``dt-highway session``
    :return: the exit status: 0 when the session is complete, 1 when it stopped early
    """
    from dt_highway.hmi.briefing import load_protocol  # lazy: highway-env
    from dt_highway.hmi.drive import open_wheel  # lazy: highway-env
    from dt_highway.hmi.session import run_session  # lazy: highway-env

    base = _drive_options(args, "baseline")
    open_wheel(base)  # no such wheel: one line naming --wheel now, not after the briefing
    conditions = [c.strip() for c in args.conditions.split(",") if c.strip()]
    protocol = load_protocol(args.protocol)
    answers = Path(args.answers_from) if args.answers_from else None
    outcome = run_session(base, args.practice_duration, conditions=conditions, protocol=protocol, answers_from=answers)
    done, n = sum(t["status"] in ("completed", "skipped") for t in outcome.trials), len(outcome.trials)
    print(f"{done} of {n} trials done" + (f"; stopped: {outcome.stopped}" if outcome.stopped else "")
          + ("" if outcome.complete else ": run the same command again to go on"))
    return 0 if outcome.complete else 1


def _participant(text: str) -> str:
    """A participant id: letters, digits, '-' and '_' (it names directories)."""
    if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_-]{0,63}", text or ""):
        raise ConfigError(f"--participant must be 1-64 letters, digits, '-' or '_' (got {text!r})")
    return text


def cmd_replay(args: argparse.Namespace) -> int:
    """Play a logged keyboard trial back, in the window or as PNG frames (``--frames-out``).

    :param args: the parsed command line of ``dt-highway replay``
    :return: the exit status: 0 when the ego followed the log, 1 when it left the logged path
    """
    from dt_highway.hmi.replay import replay_trial  # lazy: highway-env

    if args.every_s is not None and not args.frames_out:
        raise ConfigError("--every-s S needs --frames-out DIR")
    if args.speed != 1.0 and args.frames_out:
        raise ConfigError("--speed is for the window: --frames-out writes every frame as fast as it can")
    if args.force and not args.frames_out:
        raise ConfigError("--force is for --frames-out DIR (it replaces the frames DIR holds)")
    result = replay_trial(args.trial, frames_out=args.frames_out, every_s=args.every_s, window=not args.frames_out,
                          speed=args.speed, replace_frames=args.force)
    where = f", {result.frames} frames in {result.frames_dir}" if result.frames_dir is not None else ""
    where += " (stopped in the window)" if result.stopped else ""
    if result.incomplete:
        print(f"{args.trial}: {result.incomplete}; replayed what it holds")
    if result.followed_log:
        print(f"replayed {result.steps} steps of {args.trial}{where}: the ego followed the log "
              f"(largest position difference {result.max_deviation_m:.3g} m)")
        return 0
    print(f"replayed {result.steps} steps of {args.trial}{where}: the ego left the logged path at "
          f"t = {result.diverged_at_s:.2f} s (largest difference {result.max_deviation_m:.3g} m)")
    return 1


def cmd_report(args: argparse.Namespace) -> int:
    """The safety-metrics report of a study directory.

    :param args: the parsed command line of ``dt-highway report``
    :return: the exit status (0 on success)
    """
    from dt_highway.report import write_report  # lazy: heavy (scipy.stats, ~0.35 s)

    try:
        files = write_report(args.study)
    except FileNotFoundError as err:
        raise ConfigError(str(err)) from None
    _print_summary(files["summary"])
    print(f"wrote {', '.join(str(f) for f in files.values())}")
    return 0


# ----------------------------------------------------------------------------- camera
def cmd_camera(args: argparse.Namespace) -> int:
    """Sample frames of the ego camera as PNGs.

    :param args: the parsed command line of ``dt-highway camera``
    :return: the exit status (0 on success)
    """
    cfg = _config(args, {"camera": {"enabled": True}, "ego": {"autopilot": True}})
    if not cfg.camera.enabled:
        raise ConfigError("dt-highway camera needs the camera: drop --set camera.enabled=false")
    out = Path(args.out)
    from dt_highway.evaluation.frames import frame_files, record_frames  # lazy: highway-env

    if args.force:  # the earlier frames go, so the folder matches its config.json
        for frame in frame_files(out):
            frame.unlink()
    with _progress(args.frames, "camera", args.quiet) as bar:
        result = record_frames(cfg, args.frames, args.seed, out, args.every, args.raw, progress=bar.update)
    (out / "config.json").write_text(dump_json(cfg.to_dict()) + "\n")
    print(
        f"wrote {args.frames} frames ({cfg.camera.width_px}x{cfg.camera.height_px}: rgb, depth, instance, boxes"
        f"{', npz' if args.raw else ''}) to {out}; {result['vehicles_seen']} vehicles seen"
    )
    return 0


# ----------------------------------------------------------------------------- matching
def cmd_matching(args: argparse.Namespace) -> int:
    """The target-identification benchmark (paper Fig. 6).

    :param args: the parsed command line of ``dt-highway matching``
    :return: the exit status (0 on success)
    """
    from dt_highway.config import merge  # lazy: pydantic

    cfg = _config(args)
    kinds = [k.strip() for k in (args.detectors or cfg.detector.kind).split(",") if k.strip()]
    bad = [k for k in kinds if k not in ("simulated", "learned")]
    if bad or not kinds or len(set(kinds)) != len(kinds):
        raise ConfigError(f"--detectors takes simulated and/or learned, comma-separated, each once (got '{args.detectors}')")
    if not cfg.twin.enabled:
        raise ConfigError("the matching benchmark identifies the twin's vehicles: drop --set twin.enabled=false")
    if args.sweep and len(kinds) > 1:
        raise ConfigError(f"--sweep runs with one detector: give --detectors {kinds[0]} or {kinds[1]} with it "
                          f"(got '{args.detectors}')")
    from dt_highway.evaluation.matching import run_matching, run_sweep, write_outputs, write_sweep  # lazy: highway-env

    out = Path(args.out)
    if args.force:  # the earlier run's outputs go, so the folder holds this run's alone
        for folder in (out, out / "simulated", out / "learned"):
            for name in MATCHING_FILES:
                (folder / name).unlink(missing_ok=True)
    out.mkdir(parents=True, exist_ok=True)
    table: dict[str, Any] = {}
    for kind in kinds:
        # one detector: its outputs in --out; several: one subdirectory each (same frames and targets)
        where = out if len(kinds) == 1 else out / kind
        kcfg = merge(cfg, {"detector": {"kind": kind}})
        with _progress(args.frames, f"matching ({kind})", args.quiet) as bar:
            try:
                result = run_matching(kcfg, args.frames, args.seed, progress=bar.update)
            except ValueError as exc:  # too few connected vehicles in view
                raise ConfigError(str(exc)) from None
        write_outputs(result, where)
        (where / "config.json").write_text(dump_json(kcfg.to_dict()) + "\n")
        summ = result.summary()
        table[kind] = {m: {"acc_iou70": v["acc_iou70"], "acc_iou70_tricky": v["acc_iou70_tricky"]}
                       for m, v in summ["methods"].items()}
        print(f"{kind} detector: {summ['n_frames']} frames ({summ['n_tricky']} tricky, {summ['n_ambiguous']} with the "
              "anchor in several boxes); accuracy at IoU 0.7 (all / tricky):")
        for m, v in summ["methods"].items():
            print(f"  {m:9s} {v['acc_iou70']:.3f} / {v['acc_iou70_tricky']:.3f}")
    if len(kinds) > 1:
        comparison = {"frames": args.frames, "seed": args.seed, "accuracy": table}
        (out / "detectors.json").write_text(dump_json(comparison) + "\n")
        print(f"wrote {', '.join(kinds)} results to {out}/<detector>/ and the comparison to {out / 'detectors.json'}")
    written = "curve.csv, summary.json, frames.csv, curve.png"
    if args.sweep:
        n_runs = 4 + 4 + 3 + 1
        with _progress(args.frames * n_runs, "sweep", args.quiet) as bar:
            try:
                rows = run_sweep(merge(cfg, {"detector": {"kind": kinds[0]}}), args.frames, args.seed,
                                 progress=bar.update)
            except ValueError as exc:  # a sweep setting that shows too few connected vehicles
                raise ConfigError(str(exc)) from None
        write_sweep(rows, out)
        print(f"wrote sweep.csv, sweep.json, sweep.png ({kinds[0]} detector) to {out}")
    if len(kinds) == 1:
        print(f"wrote {written} to {out}")
    return 0


# ----------------------------------------------------------------------------- bench
def cmd_bench_camera(args: argparse.Namespace) -> int:
    """``dt-highway bench camera``: the camera's frame time on busy scenes.

    :param args: the parsed command line of ``dt-highway bench camera``
    :return: the exit status (0 on success)
    """
    cfg = _config(args, {"highway": {"vehicles_count": 50}, "twin": {"preroll_s": 10.0}})
    from dt_highway.bench import bench_camera  # lazy: highway-env

    with _progress(args.scenes, "bench camera", args.quiet or args.json) as bar:
        result = bench_camera(cfg, args.scenes, args.repeats, progress=bar.update)
    if args.json:
        print(dump_json(result))
    else:
        med = result["median_ms"]
        print(f"median frame time, one core: ours 640x360 {med['ours_640x360']:.2f} ms, ours 320x180 "
              f"{med['ours_320x180']:.2f} ms ({result['fps_ours_320x180']:.0f} frames/s), highway-env top-down "
              f"640x360 {med['highway_env_topdown_640x360']:.2f} ms; "
              f"ratio {result['ratio_ours_640x360_to_highway_env']:.2f}"
              f" ({result['vehicles_drawn_per_frame_median']:.0f} vehicles drawn per frame); "
              f"targets {'met' if result['targets_met'] else 'NOT met'}")
    return 0


MAX_BENCH_BOXES = 1000
"""Most boxes per frame ``bench fusion`` takes (a camera frame holds tens; its cost matrices grow as the square)"""


def cmd_bench_fusion(args: argparse.Namespace) -> int:
    """``dt-highway bench fusion``: the fusion's time per frame for a number of boxes.

    :param args: the parsed command line of ``dt-highway bench fusion``
    :return: the exit status (0 on success)
    """
    from dt_highway.bench import bench_fusion  # lazy: highway-env

    if args.boxes > MAX_BENCH_BOXES:
        raise ConfigError(f"--boxes must be at most {MAX_BENCH_BOXES} (got {args.boxes})")
    result = bench_fusion(args.frames, args.boxes)
    if args.json:
        print(dump_json(result))
    else:
        for m, r in result["methods"].items():
            print(f"{m:9s} median {r['median_ms']:.3f} ms  p90 {r['p90_ms']:.3f} ms per frame ({args.boxes} boxes)")
        print(f"target <= {result['target_ms']} ms: met by {', '.join(result['target_met_by']) or 'none'}")
    return 0


def cmd_bench_drive(args: argparse.Namespace) -> int:
    """``dt-highway bench drive``: the driving window's frame times, headless or on the display.

    :param args: the parsed command line of ``dt-highway bench drive``
    :return: the exit status (0 on success)
    """
    from dt_highway.bench import bench_drive  # lazy: highway-env

    result = bench_drive(args.duration, args.vehicles, args.width, args.height, args.condition, args.seed,
                         find_file_or_default(args.scenario), list(args.overrides))
    if args.json:
        print(dump_json(result))
    else:
        f = result["frame_ms"]
        print(f"driving window {result['size_px'][0]}x{result['size_px'][1]}, {result['vehicles']} vehicles, "
              f"{result['condition']}: {result['frames']} pictures in {result['wall_s']:g} s ({result['fps']} per s), "
              f"{result['sim_s']:g} s simulated (real-time factor {result['realtime_factor']}, "
              f"{result['end_reason']}); "
              f"frame time median {f['median']} ms, p90 {f['p90']} ms, p99 {f['p99']} ms, max {f['max']} ms "
              f"(targets p99 <= {result['target_p99_ms']:g} ms and >= {result['fps_target']:g} pictures/s: "
              f"{'met' if result['target_met'] else 'NOT met'}); video driver {result['video_driver']}"
              + (f" (the display {result['display']} was not used)"
                 if result["display"] and result["video_driver"] not in ("x11", "wayland") else ""))
    return 0


def find_file_or_default(scenario: str | None) -> str:
    """The scenario given, or the study's default one (``envs/highway-trial.toml``).

    :param scenario: the scenario file given (``None``: the default)
    :return: the path to read (:func:`~dt_highway.config.find_file`)
    """
    from dt_highway.config import find_file  # lazy: pydantic

    return find_file(scenario or STUDY_SCENARIO, "envs")


def cmd_bench_startup(args: argparse.Namespace) -> int:
    """``dt-highway bench startup``: how long the command line takes to answer, and ``import dt_highway``.

    :param args: the parsed command line of ``dt-highway bench startup``
    :return: the exit status (0 on success)
    """
    from dt_highway.bench import STARTUP_CASES, bench_startup  # lazy: highway-env

    with _progress(args.repeats * len(STARTUP_CASES), "startup", args.quiet or args.json, unit="run") as bar:
        result = bench_startup(args.repeats, bar.update)
    if args.json:
        print(dump_json(result))
        return 0
    width = max(map(len, result["cases"]))
    for name, r in result["cases"].items():
        print(f"{name:{width}s}  median {r['median_s']:.2f} s  (least {r['min_s']:.2f}, most {r['max_s']:.2f}; "
              f"{result['repeats']} runs)")
    met = [name for name, ok in result["target_met"].items() if ok]
    print(f"target: help and a mistake answer within {result['target_s']} s (median): met by {len(met)} of "
          f"{len(result['target_met'])}")
    return 0


def cmd_bench_memory(args: argparse.Namespace) -> int:
    """``dt-highway bench memory``: the env's memory over hours of simulated driving.

    :param args: the parsed command line of ``dt-highway bench memory``
    :return: the exit status (0 on success)
    """
    if args.every_min > args.hours * 60 / 2:  # two samples at least: a shorter run would be made longer
        default = " (the default)" if args.every_min == 10.0 else ""
        raise ConfigError(f"--every-min must be at most half of --hours in minutes ({args.hours * 30:g} for --hours "
                          f"{args.hours:g}; got {args.every_min:g}{default})")
    cfg = _config(args)
    steps = int(args.hours * 3600 * cfg.highway.policy_frequency)
    from dt_highway.bench import bench_memory  # lazy: highway-env

    with _progress(steps, "bench memory", args.quiet or args.json) as bar:
        result = bench_memory(cfg, args.hours, args.every_min, progress=bar.update)
    if args.json:
        print(dump_json(result))
    else:
        for s in result["samples"]:
            print(f"{s['sim_time_min']:8.1f} min  rss {s['rss_mb']:8.1f} MB  objects {s['live_objects']:8d}  "
                  f"fixes {s['twin_fixes_held']:6d}  records {s['twin_records']:4d}  vehicles {s['vehicles']}  "
                  f"episodes {s['episodes']}")
        print(f"RSS growth after warm-up: {result['rss_growth_mb_after_warmup']} MB over {args.hours} h simulated "
              f"({result['sim_seconds_per_wall_second']} sim s per wall s)")
    return 0



# ----------------------------------------------------------------------------- detector
def _weights_arg(path: str | None) -> str | None:
    if path is not None and not Path(path).is_file():
        raise ConfigError(f"weights file not found: {path} (a .pt file from dt-highway detector train; "
                          "without --weights: the shipped weights)")
    return path


def cmd_detector_train(args: argparse.Namespace) -> int:
    """Train the learned detector (resumes from <out>.ckpt).

    :param args: the parsed command line of ``dt-highway detector train``
    :return: the exit status (0 on success)
    """
    from dt_highway.perception.learned.model import Architecture  # lazy: torch (~1.3 s)
    from dt_highway.perception.learned.train import TrainSettings, check_training, train  # lazy: torch

    out = Path(args.out)
    ckpt = out.with_name(out.name + ".ckpt")
    arch = Architecture(width_px=args.width, height_px=args.height, depth=args.depth)
    settings = TrainSettings(minutes=args.minutes, batch=args.batch, seed=args.seed, max_steps=args.max_steps)
    try:  # a directory for --out, a checkpoint already done...: refused before any training starts
        check_training(out, arch, settings, resume=not args.fresh)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    if out.exists() and not ckpt.exists() and not args.fresh:
        raise ConfigError(f"{out} exists and has no checkpoint to resume: pass --fresh to train anew and replace it")
    if ckpt.exists() and not args.fresh:
        print(f"resuming from {ckpt}", file=sys.stderr)
    total = int(round(args.minutes * 60))
    with tqdm(total=total, desc="train", unit="s", disable=args.quiet, file=sys.stderr, leave=False,
              bar_format="{l_bar}{bar}| {n:.0f}/{total} s [{elapsed}<{remaining}{postfix}]") as bar:

        def progress(step: int, elapsed_s: float, losses: dict[str, float]) -> None:
            if bar.n == 0 and elapsed_s > 5:  # resumed: time left counts from here
                bar.initial = elapsed_s
                bar.start_t = time.time()  # tqdm's clock (not bar._time: a disabled bar, --quiet, has none)
            bar.n = min(elapsed_s, total)
            if step % 10 == 0:
                bar.set_postfix(step=step, loss=f"{losses['loss']:.3f}", refresh=False)
            bar.refresh()

        try:
            result = train(out, arch, settings, resume=not args.fresh, progress=progress)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
    print(f"trained {result['steps']} steps ({result['frames_rendered']} frames rendered, "
          f"{result['train_minutes']} min{', resumed' if result['resumed'] else ''}); "
          f"last loss {result['last_losses'].get('loss', float('nan')):.3f}")
    print(f"wrote {result['weights']} (checkpoint {result['checkpoint']})")
    if args.eval_frames:
        from dt_highway.evaluation.detector import EVAL_SEED  # lazy: torch

        args.weights, args.frames, args.json, args.seed = str(out), args.eval_frames, False, EVAL_SEED
        return cmd_detector_eval(args)
    return 0


def cmd_detector_eval(args: argparse.Namespace) -> int:
    """AP of the learned detector on held-out frames.

    :param args: the parsed command line of ``dt-highway detector eval``
    :return: the exit status (0 on success)
    """
    from dt_highway.evaluation.detector import evaluate  # lazy: torch (~1.3 s)
    from dt_highway.perception.learned.detector import LearnedDetector  # lazy: torch

    try:
        det = LearnedDetector(_weights_arg(args.weights), min_score=args.min_score, scale=args.scale)
    except (FileNotFoundError, ValueError) as exc:
        raise ConfigError(str(exc)) from None
    size = getattr(args, "size", None)
    w, h = size if size else (None, None)
    with _progress(args.frames, "eval", args.quiet, unit="frame") as bar:
        try:
            result = evaluate(det, args.frames, args.seed, w, h, progress=lambda n: bar.update(n - bar.n))
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
    result["weights"] = args.weights or "shipped"
    result["scale"] = args.scale
    if args.out_json:
        _write_result(args.out_json, result)
    if args.json:
        print(dump_json(result))
    else:
        print(f"{result['frames']} held-out frames {result['image_px'][0]}x{result['image_px'][1]} "
              f"(seeds {result['seeds'][0]}..{result['seeds'][1]}), {result['scored_vehicles']} scored vehicles, "
              f"{result['ignored_vehicles']} ignored")
        print(f"AP {result['AP']:.3f}  AP50 {result['AP50']:.3f}  AP75 {result['AP75']:.3f}  "
              f"recall@IoU0.7 {result['recall_iou07']:.3f} (at score >= {result['operating_score']}: "
              f"{result['recall_iou07_at_operating_score']:.3f}, "
              f"precision {result['precision_iou07_at_operating_score']:.3f})")
    return 0


def cmd_train(args: argparse.Namespace) -> int:
    """Train an RL driver with stable-baselines3.

    :param args: the parsed command line of ``dt-highway train``
    :return: the exit status: 0 on success, 130 when training was interrupted
    """
    from dt_highway.rl.config import load_train_config  # lazy: highway-env
    from dt_highway.rl.files import sidecar_path  # lazy: highway-env
    from dt_highway.rl.train import train  # lazy: stable-baselines3 and torch (~1.3 s)

    cfg = load_train_config(args.config)
    out = Path(args.out)
    if out.suffix != ".zip":
        raise ConfigError(f"--out must name a .zip file, e.g. agents/{Path(args.config).stem}.zip (got {out})")
    for path in (out, sidecar_path(out), out.with_suffix(".d")):  # the .d folder: the last run's checkpoints
        if path.exists() and not args.force:
            raise ConfigError(f"{path} exists: pass --force to replace it (the policy {out.name}, its metadata "
                              f"{sidecar_path(out).name} and its checkpoints {out.with_suffix('.d').name}/)")
    meta = train(cfg, out, timesteps=args.timesteps, n_envs=args.n_envs, tensorboard_dir=args.tensorboard,
                 progress=not args.quiet)
    last = meta["evaluations"][-1] if meta["evaluations"] else None
    print(f"trained {cfg.algorithm} ({cfg.observation}, {cfg.action}) for {meta['timesteps_done']} steps in "
          f"{meta['wall_time_s']:.0f} s ({meta['steps_per_s']} steps/s)"
          + (" - interrupted" if meta["interrupted"] else ""))
    if last:
        print(f"last evaluation ({cfg.eval_episodes} held-out episodes at {last['timesteps']} steps): "
              f"mean return {last['mean_return']:.2f}, mean length {last['mean_length']:.0f} decisions, "
              f"collision rate {last['collision_rate']:.2f}")
    print(f"wrote {out}, {sidecar_path(out)} (config, versions, evaluations), {out.with_suffix('.curve.png')} "
          f"(training curve, and .csv), checkpoints and logs in {meta['checkpoints']}")
    return 130 if meta["interrupted"] else 0


def cmd_rl_curve(args: argparse.Namespace) -> int:
    """Re-draw a policy's training curve (CSV + PNG) from its training log and metadata.

    :param args: the parsed command line of ``dt-highway rl-curve``
    :return: the exit status (0 on success)
    """
    from dt_highway.rl.curves import write_curve  # lazy: matplotlib

    if Path(args.model).suffix != ".zip":
        raise ConfigError(f"MODEL must be a policy .zip, e.g. agents/ppo-safe-adas.zip (got {args.model})")
    csv_path, png_path = write_curve(args.model, args.progress)
    print(f"wrote {csv_path} and {png_path}")
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    """Any driver (policy or scripted) on the same seeds: return, collisions, speed, TTC.

    :param args: the parsed command line of ``dt-highway evaluate``
    :return: the exit status (0 on success)
    """
    from dt_highway.config import load_config  # lazy: pydantic

    if args.episodes_json and not args.json:
        raise ConfigError("--episodes-json needs --json (--out FILE writes every episode's metrics without it)")
    scenario = args.scenario or EVAL_SCENARIO
    load_config(scenario, args.overrides)  # mistakes in the scenario or the driver: one line, before the bar
    from dt_highway.drivers import load_driver  # lazy: highway-env
    from dt_highway.evaluation.rl import evaluate as evaluate_driver  # lazy: highway-env

    driver = load_driver(args.driver)
    bars: list[tqdm] = []  # the bar appears once the env accepted the driver (else the error stands alone)

    def progress(n: int) -> None:
        if not bars:
            bars.append(_progress(args.episodes, "evaluate", args.quiet, unit="episode"))
        bars[0].update(n)

    try:
        result = evaluate_driver(args.driver, args.episodes, args.seed, scenario, args.condition, tuple(args.overrides),
                          progress=progress, driver=driver)
    finally:
        for bar in bars:
            bar.close()
    if args.out_json:
        _write_result(args.out_json, result)
    if args.json:
        print(dump_json({k: v for k, v in result.items() if k != "per_episode" or args.episodes_json}))
    else:
        print(f"{args.driver}: {args.episodes} episodes of {scenario} ({args.condition}), seeds "
              f"{result['seeds'][0]}..{result['seeds'][1]}")
        print(f"mean return {result['mean_return']:.2f}  collision rate {result['collision_rate']:.2f}  "
              f"mean speed {result['mean_speed_kmh']:.1f} km/h  mean TTC {_two_places(result['mean_ttc_s'])} s  "
              f"cut-in min TTC {_two_places(result['cut_in_ttc_min_s'])} s ({result['cut_ins']} cut-ins)")
    return 0


def cmd_rl_compare(args: argparse.Namespace) -> int:
    """Rows of driver x condition (x ablation) on the same held-out seeds, with paired tests (issue 22).

    :param args: the parsed command line of ``dt-highway rl-compare``
    :return: the exit status (0 on success)
    """
    from dt_highway.config import load_config  # lazy: pydantic
    from dt_highway.evaluation.rl import (  # lazy: highway-env
        compare_paths,
        markdown_table,
        parse_rows,
        rl_compare,
        write_compare,
    )

    rows = parse_rows(args.rows)  # a bad row: one line, before any env
    held = [p.name for p in compare_paths(args.out) if p.exists()]
    if held and not args.force:  # an earlier comparison (hours of episodes) is not replaced unasked
        raise ConfigError(f"{args.out} holds an earlier comparison ({', '.join(held)}): pass --force to replace it, "
                          "or another --out")
    scenario = args.scenario or COMPARE_SCENARIO
    load_config(scenario, args.overrides)
    bars: list[tqdm] = []  # the bar appears once every row's driver and env were accepted

    def progress(n: int) -> None:
        if not bars:
            bars.append(_progress(args.episodes * len(rows), "rl-compare", args.quiet, unit="episode"))
        bars[0].update(n)

    try:
        result = rl_compare(rows, args.episodes, args.seed, scenario, tuple(args.overrides), args.workers, progress)
    finally:
        for bar in bars:
            bar.close()
    paths = write_compare(result, args.out)
    print(markdown_table(result), end="")
    print(f"wrote {', '.join(str(p) for p in paths)}")
    return 0


def _score(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--min-score must be a number in (0, 1] (got '{text}')") from None
    if not 0.0 < value <= 1.0:
        raise argparse.ArgumentTypeError(f"--min-score must be in (0, 1] (got {text})")
    return value


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--size must look like 640x360 (got '{text}')") from None
    if not (16 <= w <= 4096 and 16 <= h <= 4096):
        raise argparse.ArgumentTypeError(f"--size must be 16..4096 per side (got '{text}')")
    return w, h


def cmd_bench_sim(args: argparse.Namespace) -> int:
    """``dt-highway bench sim``: the fast road's steps per second against highway-env's, and where they part.

    :param args: the parsed command line of ``dt-highway bench sim``
    :return: the exit status (0 on success)
    """
    from dt_highway.bench import bench_sim, deviation_steps  # lazy: highway-env

    try:
        deviation_steps(args.deviation_s)  # before the throughput runs
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    result = bench_sim(args.steps, args.seed, args.deviation_s, args.repeats, args.profile)
    if args.json:
        print(dump_json(result))
    else:
        r, q = result["steps_per_s"], result["ratio_to_stock"]
        print(f"env steps/s (50 vehicles, 15 Hz, 1 decision/s): stock highway-v0 {r['stock_highway_v0']}, "
              "ours plain IDM "
              f"{r['ours_plain_idm']} (x{q['ours_plain_idm']}), ours with driver types {r['ours_driver_types']} "
              f"(x{q['ours_driver_types']}), ours with the ADAS pipeline {r['ours_adas_pipeline']} "
              f"({result['adas_step_ms']} ms per step; stock {result['stock_step_ms']} ms)")
        dev = result["max_deviation_m"]
        print(f"deviation from stock over {result['deviation_sim_s']:g} s simulated (plain IDM traffic): "
              + (f"{dev:.3g} m" if dev is not None else "vehicle counts differ"))
        met = "met" if result["target_met"] else "NOT met"
        print(f"target x{result['target_ratio']:g} and ADAS step <= stock step: {met}")
        if args.profile:
            print(f"wrote {args.profile}")
    return 0


def cmd_bench_train(args: argparse.Namespace) -> int:
    """``dt-highway bench train``: env steps and PPO timesteps per second of a training file.

    :param args: the parsed command line of ``dt-highway bench train``
    :return: the exit status (0 on success)
    """
    from dt_highway.bench import bench_train  # lazy: highway-env
    from dt_highway.rl.config import load_train_config  # lazy: highway-env

    cfg = load_train_config(args.config)
    total = 2 * args.env_steps + 2 * args.timesteps  # PPO rounds up to whole rollouts: about
    with _progress(total, "bench train", args.quiet or args.json) as bar:
        result = bench_train(cfg, args.timesteps, args.n_envs, args.env_steps, args.seed, progress=bar.update)
    if args.json:
        print(dump_json(result))
        return 0
    c, e, p = result["config"], result["env_only"], result["ppo"]
    print(f"bench train {args.config} ({c['observation']}, {c['action']}, {c['algorithm']}), {result['cpus']} CPUs; "
          f"the fast path switches off: {', '.join(result['switched_off']) or 'nothing'}")
    t, f = e["today"], e["fast"]
    marked = f" ({e['marked_entries']} marked cells)" if e["marked_entries"] is not None else ""
    print(f"env only, one process, {e['steps']} steps of seed {e['seed']}: today {t['steps_per_s']} steps/s "
          f"({t['steps_per_cpu_s']} per CPU second, first reset {t['reset_s']} s, load {t['load_1min']}), "
          f"fast {f['steps_per_s']} steps/s ({f['steps_per_cpu_s']} per CPU second, first reset {f['reset_s']} s, "
          f"load {f['load_1min']}); same observations: {'yes' if e['same_observations'] else 'NO'}, "
          f"same rewards: {'yes' if e['same_rewards'] else 'NO'}{marked}")
    for name in ("today", "fast"):
        r = p[name]
        print(f"{c['algorithm']} {name}: {r['steps_per_s']} steps/s ({r['n_envs']} env{'s' if r['n_envs'] > 1 else ''}, "
              f"{r['vec_env']}{', starts computed ahead' if r.get('preroll_ahead') else ''}; "
              f"{r['steps']} steps in {r['wall_s']} s: collecting {r['collect_s']} s = "
              f"{r['collect_steps_per_s']} steps/s, learner {r['update_s']} s; {r['steps_per_cpu_s']} steps per CPU "
              f"second; load {r['load_1min_before']} -> {r['load_1min_after']})")
    target = result["target_steps_per_s"]
    verdict = "" if target is None else \
        f"; target {target:g} steps/s: {'met' if result['target_met'] else 'NOT met'}"
    print(f"speedup x{result['speedup']}{verdict}")
    return 0


def cmd_bench_detector(args: argparse.Namespace) -> int:
    """``dt-highway bench detector``: the learned detector's frames per second on the CPU.

    :param args: the parsed command line of ``dt-highway bench detector``
    :return: the exit status (0 on success)
    """
    from dt_highway.bench import bench_detector  # lazy: highway-env

    try:
        result = bench_detector(_weights_arg(args.weights), args.batch, args.seconds, args.threads, *args.size)
    except (FileNotFoundError, ValueError) as exc:
        raise ConfigError(str(exc)) from None
    if args.json:
        print(dump_json(result))
    else:
        s = result["single_frame_ms"]
        print(f"learned detector {result['image_px'][0]}x{result['image_px'][1]}, {result['threads']} threads: "
              f"{result['frames_per_s_batched']} frames/s batched ({result['batch']} per call); one frame "
              f"median {s['median']} ms, p90 {s['p90']} ms, p99 {s['p99']} ms")
        met = "met" if result["target_met"] else "NOT met"
        print(f"target >= {result['target_frames_per_s']} frames/s batched: {met}")
    return 0

# ----------------------------------------------------------------------------- main
def _show_help(parser: argparse.ArgumentParser) -> Callable[[argparse.Namespace], int]:
    """A command that prints ``parser``'s help and returns status 2 (a command group given no action)."""

    def show(_: argparse.Namespace) -> int:
        parser.print_help()
        return 2

    return show


def build_parser() -> argparse.ArgumentParser:
    """The command-line parser of ``dt-highway``.

    :return: the ``dt-highway`` parser, every command and its options
    """
    parser = _Parser(
        prog="dt-highway",
        description="Highway driving with a cloud digital twin that tags aggressive drivers (highway-env extension).",
    )
    parser.add_argument("--version", action="version", version=f"dt-highway {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser("run", help="headless episodes on the IDM autopilot, scoring the twin (the main job is study --quick)")
    _add_config_args(p)
    p.add_argument("--episodes", type=_positive(int, "--episodes"), default=2, help="episodes (default 2)")
    p.add_argument("--seed", type=_seed, default=0, help="seed (default 0)")
    p.add_argument("--out", default="runs/run", help="output directory (default runs/run)")
    p.add_argument("--force", action="store_true", help="replace the outputs of an earlier run --out holds")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_run)

    p = sub.add_parser("twin-eval", help="precision/recall of the twin's aggressive tags against ground truth "
                       "(--intent: its lane-change intention)")
    _add_config_args(p)
    p.add_argument("--episodes", type=_positive(int, "--episodes"),
                   help=f"episodes (default 3; with --intent {INTENT_EPISODES})")
    p.add_argument("--seed", type=_seed, default=0, help="seed of the first episode (default 0)")
    p.add_argument("--min-observed-s", type=_positive(float, "--min-observed-s"),
                   help=f"judge only drivers the twin observed this long [s] (default {MIN_OBSERVED_S:g}; not with "
                   "--intent)")
    p.add_argument("--population", choices=POPULATIONS,
                   help="driver population, shortcut for --set traffic.population=...; continuum adds the ROC AUCs "
                   "and the precision at recall >= 0.80 (default: the configuration's, two_class)")
    p.add_argument("--intent", action="store_true",
                   help="score the lane-change intention instead: ROC AUC and precision/recall per horizon, cut-in recall "
                   "at precision >= 0.80 and warning lead time (default scenario envs/highway-trial.toml, seed 0: "
                   "held out from train-intent's seeds)")
    p.add_argument("--sweep", action="store_true",
                   help="with --intent: sweep GNSS noise {0.5,1,2,3} m, latency {0,0.1,0.3,0.5} s, rate {10,5,2,1} Hz")
    p.add_argument("--driver", metavar="FILE",
                   help="with --intent: this driver (e.g. agents/human.toml) drives the ego, in the baseline condition, "
                   "as in a study (default: the autopilot, 25 m/s in its lane)")
    p.add_argument("--oracle", type=_positive(int, "--oracle", ORACLE_MAX_FUTURES,
                                              ": each future multiplies the run's length"), metavar="N",
                   help="with --intent: also score an oracle that simulates N futures of the simulator's whole state "
                   "at every estimate (drivers' minds included): about how far ahead lane changes can be foreseen "
                   "at all; N = 8 makes the run about 9 times longer")
    p.add_argument("--oracle-hide", type=_oracle_hide, default=frozenset(), metavar="LIST",
                   help="with --oracle: deny the oracle these parts of the state, comma-separated: "
                   f"{', '.join(HIDEABLE)} (each replaced by what the twin could assume): which of them the foresight "
                   f"comes from; with --oracle-from picture: {', '.join(PICTURE_HIDEABLE)}")
    p.add_argument("--oracle-from", choices=STARTS, default="state",
                   help="with --oracle: what its futures start from: the simulator's state (default) or the twin's "
                   "picture (the cloud's fixes and tags, simulated with the simulator's driver models: a twin with a "
                   "perfect traffic model; also scores its mean with the configured model)")
    p.add_argument("--oracle-reveal", type=_oracle_reveal, default=frozenset(), metavar="LIST",
                   help="with --oracle-from picture: put these parts of the simulator's state into the twin's picture "
                   f"instead of its estimates, comma-separated: {', '.join(PICTURE_REVEALABLE)} (who chases the ego; "
                   "every car's lateral position, speed and the lane it steers to; every driver's type; every car's "
                   "position along the road and speed; every open cut-in attempt, which gives the chases too): what "
                   "a better twin could gain")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    _add_result_out(p, "also write the JSON result to this file")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_twin_eval)

    p = sub.add_parser("train-intent", help="train the twin's lane-change intention network on simulated fixes")
    _add_config_args(p, EVAL_SCENARIO)
    p.add_argument("--out", required=True, help="weights file to write (.npz; the shipped one is "
                   "dt_highway/twin/intention_weights.npz)")
    p.add_argument("--episodes", type=_positive(int, "--episodes"), default=40,
                   help="training episodes, one per seed (default 40)")
    p.add_argument("--seed", type=_seed, default=1000,
                   help="first training seed (default 1000; evaluation uses seed 0 and its world)")
    p.add_argument("--epochs", type=_positive(int, "--epochs"), default=25, help="passes over the data (default 25)")
    p.add_argument("--alternate", metavar="KEY=VALUE", action="append", default=[],
                   help="the odd training seeds also take this override (a mix of two worlds), e.g. "
                   "traffic.dangerous.share=0.5 (repeatable)")
    p.add_argument("--driver", metavar="FILE",
                   help="this driver (e.g. agents/human.toml) drives the ego in the recordings, in the baseline "
                   "condition (default: the autopilot)")
    p.add_argument("--force", action="store_true", help="replace an existing --out")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_train_intent)

    p = sub.add_parser("train-chase", help="train the twin's detector of drivers chasing the ego (the picture oracle's "
                       "open cut-in attempts) on simulated fixes")
    _add_config_args(p, EVAL_SCENARIO)
    p.add_argument("--out", required=True, help="weights file to write (.npz; the shipped one is "
                   "dt_highway/twin/chase_weights.npz)")
    p.add_argument("--episodes", type=_positive(int, "--episodes"), default=24,
                   help="training episodes, one per seed (default 24)")
    p.add_argument("--seed", type=_seed, default=TRAIN_SEED, help=f"first training seed (default {TRAIN_SEED})")
    p.add_argument("--epochs", type=_positive(int, "--epochs"), default=12, help="passes over the data (default 12)")
    p.add_argument("--test-episodes", type=_test_episodes, default=10,
                   help="held-out episodes to score the detector on (default 10; 0: none)")
    p.add_argument("--test-seed", type=_seed, default=TEST_SEED, help=f"their first seed (default {TEST_SEED})")
    p.add_argument("--force", action="store_true", help="replace an existing --out")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_train_chase)

    p = sub.add_parser("train-tagger", help="fit the twin's evidence tagger (twin.tagger.model=evidence) on simulated "
                       "training seeds")
    _add_config_args(p)
    p.add_argument("--out", required=True, help="weights file to write (.json; the shipped one is "
                   "dt_highway/twin/tagger_evidence.json)")
    p.add_argument("--population", choices=("continuum", "two_class"), default="continuum",
                   help="the drivers to learn from (default continuum)")
    p.add_argument("--seeds", type=_positive(int, "--seeds"), default=5, help="training seeds (default 5)")
    p.add_argument("--seed", type=_seed, default=0,
                   help="first training seed (default 0; the docs' held-out evaluation uses seed 100)")
    p.add_argument("--episodes", type=_positive(int, "--episodes"), default=3, help="episodes per seed (default 3)")
    p.add_argument("--force", action="store_true", help="replace an existing --out")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_train_tagger)

    p = sub.add_parser("camera", help="write sample frames of the ego camera (RGB, depth, instance ids, boxes) as PNGs")
    _add_config_args(p)
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--frames", type=_positive(int, "--frames"), default=4, help="frames to write (default 4)")
    p.add_argument("--every", type=_positive(int, "--every"), default=1, help="policy steps between frames (default 1)")
    p.add_argument("--seed", type=_seed, default=0, help="seed (default 0)")
    p.add_argument("--raw", action="store_true", help="also write float depth [m] and instance ids as .npz")
    p.add_argument("--force", action="store_true",
                   help="replace the frames of an earlier camera run --out holds (they are deleted first)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_camera)

    p = sub.add_parser("matching", help="target identification accuracy of the fusion methods (paper Fig. 6)")
    _add_config_args(p)
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--frames", type=_positive(int, "--frames"), default=300, help="evaluation frames (default 300)")
    p.add_argument("--seed", type=_seed, default=0, help="seed (default 0)")
    p.add_argument("--sweep", action="store_true",
                   help="also sweep GNSS noise {0.5,1,2,3} m, latency {0,0.1,0.3,0.5} s, rate {10,5,1} Hz")
    p.add_argument("--detectors", metavar="KINDS",
                   help="detectors to compare, e.g. simulated,learned (default: the config's detector.kind); "
                   "--sweep runs with one")
    p.add_argument("--force", action="store_true",
                   help="replace the outputs of an earlier matching run --out holds (they are deleted first)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_matching)

    p = sub.add_parser("study", help="a paired baseline/ADAS study of a driver (trial logs, then the report)")
    _add_config_args(p, STUDY_SCENARIO)
    p.add_argument("--driver", help="driver file, e.g. agents/human.toml")
    p.add_argument("--conditions", default="baseline,adas",
                   help=f"conditions, paired by seed (default baseline,adas; allowed: {','.join(CONDITIONS)})")
    p.add_argument("--trials", type=_positive(int, "--trials", STUDY_MAX_TRIALS,
                                              ": a larger count is most likely a typo"),
                   help=f"pairs of trials (default 10; --quick: 3; at most {STUDY_MAX_TRIALS})")
    p.add_argument("--seed", type=_seed, default=0, help="seed of the first pair; pair i uses seed + i (default 0)")
    p.add_argument("--workers", type=_positive(int, "--workers"), default=2, help="parallel trials (default 2)")
    p.add_argument("--out", help="study directory, e.g. runs/<name> (--quick: runs/quick-study)")
    p.add_argument("--backend", choices=("process", "ray"), default="process",
                   help="process pool (default) or Ray tasks")
    p.add_argument("--ray-address", help="with --backend ray: address of an existing Ray cluster")
    p.add_argument("--quick", action="store_true", help="a small study with the human-like driver, then its report")
    p.add_argument("--report", action="store_true", help="write the report when the study is done")
    p.add_argument("--parquet", action="store_true",
                   help="also write steps.parquet in each completed trial's directory (needs pyarrow)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_study)

    p = sub.add_parser("drive", help="one keyboard trial in the driving window (first-person camera, AR overlay)")
    _add_drive_args(p)
    p.add_argument("--condition", required=True, choices=CONDITIONS, help="baseline, adas, sham...")
    p.add_argument("--practice", action="store_true", help="a practice trial (not in the report)")
    p.add_argument("--out", required=True, help="study directory, e.g. runs/<study>")
    p.add_argument("--force", action="store_true", help="replace the trial already in its folder "
                   "(<out>/trials/<participant>-<condition>, or <participant>-practice; refused without it)")
    p.set_defaults(func=cmd_drive)

    p = sub.add_parser("session", help="a participant's session: practice, the conditions counterbalanced")
    _add_drive_args(p)
    p.add_argument("--conditions", default="baseline,adas",
                   help="conditions, in a balanced Latin square order by participant (default baseline,adas; e.g. "
                        "baseline,adas-threat,sham)")
    p.add_argument("--out", default="runs/keyboard-study", help="study directory (default runs/keyboard-study)")
    p.add_argument("--practice-duration", type=_positive(float, "--practice-duration"),
                   help="each practice trial's length [s] (one per condition; default: the protocol's, 30)")
    p.add_argument("--protocol", metavar="FILE",
                   help=f"what the participant reads and which questionnaires follow which trials (default: the "
                        f"packaged {DEFAULT_PROTOCOL.name}; copy it to change it)")
    p.add_argument("--answers-from", metavar="FILE",
                   help="scripted questionnaire answers (JSON or TOML), with --keys-from")
    p.set_defaults(func=cmd_session)

    p = sub.add_parser("replay", help="play a logged keyboard trial back (its seed, config and actions), in the window "
                                      "or as PNG frames")
    p.add_argument("trial", metavar="TRIAL_DIR", help="the trial's directory, e.g. runs/keyboard-study/trials/P01-adas")
    p.add_argument("--frames-out", metavar="DIR", help="write PNG frames to DIR, no window (headless)")
    p.add_argument("--force", action="store_true", help="with --frames-out: replace the frames of an earlier replay "
                   "DIR holds (they are deleted once the trial is read)")
    p.add_argument("--every-s", type=_positive(float, "--every-s"), metavar="S",
                   help="with --frames-out: a frame every S seconds of trial time (default every simulation step)")
    p.add_argument("--speed", type=_positive(float, "--speed"), default=1.0,
                   help="in the window: times real time (default 1; Space pauses, Esc stops)")
    p.set_defaults(func=cmd_replay)

    p = sub.add_parser("train", help="train an RL driver (stable-baselines3) from agents/<name>.toml")
    p.add_argument("--config", required=True, help="training config, e.g. agents/ppo-baseline.toml (kind = \"rl\")")
    p.add_argument("--out", required=True, help="model file to write, e.g. agents/ppo-baseline.zip")
    p.add_argument("--timesteps", type=_positive(int, "--timesteps"), help="env steps (default: the config's)")
    p.add_argument("--n-envs", type=_positive(int, "--n-envs"), help="parallel envs (default: the config's)")
    p.add_argument("--tensorboard", metavar="DIR", help="also write TensorBoard logs to DIR (needs tensorboard)")
    p.add_argument("--force", action="store_true", help="replace an existing --out")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_train)

    p = sub.add_parser("rl-curve", help="re-draw a policy's training curve (<model>.curve.csv and .png)")
    p.add_argument("model", metavar="MODEL", help="the policy, e.g. agents/ppo-safe-adas.zip (its .json beside it)")
    p.add_argument("--progress", metavar="CSV",
                   help="the training log (default: progress.csv in the metadata's checkpoints folder, or <model>.d/)")
    p.set_defaults(func=cmd_rl_curve)

    p = sub.add_parser("evaluate", help="any driver (policy .zip or scripted .toml) on the same seeds")
    _add_config_args(p, EVAL_SCENARIO)
    p.add_argument("--driver", required=True, help="agents/<name>.zip or agents/<driver>.toml")
    p.add_argument("--episodes", type=_positive(int, "--episodes"), default=10, help="episodes (default 10)")
    p.add_argument("--seed", type=_seed, default=0,
                   help="seed of the first episode; episode i uses seed + i (default 0)")
    p.add_argument("--condition", choices=CONDITIONS, default="adas",
                   help="with the ADAS overlay or without (default adas)")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("--episodes-json", action="store_true", help="with --json: include every episode's metrics")
    _add_result_out(p, "also write the JSON result (every episode) to FILE")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_evaluate)

    p = sub.add_parser("rl-compare", help="drivers x conditions (x ablations) on the same held-out seeds, paired tests")
    _add_config_args(p, COMPARE_SCENARIO)
    p.add_argument("--rows", required=True, metavar="DRIVER@CONDITION[:ABLATION],...",
                   help="comma-separated rows, e.g. ppo-safe-adas.zip@adas-threat,ppo-safe-adas.zip@sham-threat,"
                        "ppo-safe-adas.zip@adas-threat:zero-marks,ppo-safe-baseline.zip@baseline,idm.toml@baseline "
                        "(bare names are looked for in agents/; ablation: zero-marks)")
    p.add_argument("--episodes", type=_positive(int, "--episodes"), default=50, help="episodes per row (default 50)")
    p.add_argument("--seed", type=_seed, default=COMPARE_SEED,
                   help=f"seed of the first episode; episode i uses seed + i in every row (default {COMPARE_SEED}: held out)")
    p.add_argument("--workers", type=_positive(int, "--workers"), default=1, help="parallel episodes (default 1)")
    p.add_argument("--out", default="runs/rl-compare",
                   help="folder for compare.json, compare.md and episodes.csv (default runs/rl-compare)")
    p.add_argument("--force", action="store_true", help="replace the comparison --out holds")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_rl_compare)

    p = sub.add_parser("calibrate", help="a scenario knob's baseline figures (cut-in TTC, collisions) per value and driver")
    _add_config_args(p, STUDY_SCENARIO)
    p.add_argument("--knob", required=True, metavar="KEY=V1,V2,...",
                   help="the configuration key to vary and its values, e.g. traffic.dangerous.brake_mps2=2,3,4")
    p.add_argument("--drivers", default="agents/human.toml,agents/idm.toml",
                   help="driver files, comma-separated (default agents/human.toml,agents/idm.toml)")
    p.add_argument("--trials", type=_positive(int, "--trials"), default=10, help="baseline trials per cell (default 10)")
    p.add_argument("--seed", type=_seed, default=1000,
                   help="seed of the first trial (default 1000: apart from the studies' seeds 0..)")
    p.add_argument("--workers", type=_positive(int, "--workers"), default=2, help="parallel trials (default 2)")
    p.add_argument("--out", default="runs/calibration", help="where the cells' trials and the table go")
    p.add_argument("--force", action="store_true",
                   help="replace the table --out holds when it has cells this run leaves out (another knob, "
                   "driver or value)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("report", help="the safety-metrics report of a study directory")
    p.add_argument("study", help="study directory (runs/<name>)")
    p.set_defaults(func=cmd_report)

    det = sub.add_parser("detector", help="the learned vehicle detector: train it, evaluate it")
    dsub = det.add_subparsers(dest="detector", metavar="ACTION")
    det.set_defaults(func=_show_help(det))
    p = dsub.add_parser("train", help="train on frames the camera renders on the fly (CPU; resumes from <out>.ckpt)")
    p.add_argument("--out", required=True, help="weights file to write, e.g. runs/detector.pt")
    p.add_argument("--minutes", type=_positive(float, "--minutes"), default=30.0,
                   help="training time [min] (default 30)")
    p.add_argument("--depth", action="store_true", help="inverse depth as a fourth input channel")
    p.add_argument("--width", type=_positive(int, "--width"), default=320,
                   help="network input width [px] (default 320)")
    p.add_argument("--height", type=_positive(int, "--height"), default=180,
                   help="network input height [px] (default 180)")
    p.add_argument("--batch", type=_positive(int, "--batch"), default=32, help="images per step (default 32)")
    p.add_argument("--seed", type=_seed, default=0, help="seed of replay choices (default 0)")
    p.add_argument("--max-steps", type=_positive(int, "--max-steps"), help="stop after this many steps")
    p.add_argument("--fresh", action="store_true",
                   help="start over instead of resuming from <out>.ckpt (replaces it and <out> when training ends)")
    p.add_argument("--eval-frames", type=_positive(int, "--eval-frames"),
                   help="evaluate on this many held-out frames after")
    p.add_argument("--min-score", type=_score, default=0.3, help=argparse.SUPPRESS)
    p.add_argument("--scale", default="resize", help=argparse.SUPPRESS)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_detector_train)
    p = dsub.add_parser("eval", help="COCO AP, AP50, AP75 and recall at IoU 0.7 on held-out seeded frames")
    p.add_argument("--weights", help="weights file (default: the shipped weights)")
    p.add_argument("--frames", type=_positive(int, "--frames"), default=500, help="held-out frames (default 500)")
    p.add_argument("--seed", type=_seed, default=0, help="first frame seed (default 0)")
    p.add_argument("--size", type=_size, help="frame size WxH (default: the network's, 320x180)")
    p.add_argument("--min-score", type=_score, default=0.3,
                   help="operating score for recall/precision, in (0, 1] (default 0.3)")
    p.add_argument("--scale", choices=("resize", "native"), default="resize",
                   help="frames of another size: resized to the network's (default) or read as they are")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    _add_result_out(p, "also write the JSON result to this file")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_detector_eval)

    bench = sub.add_parser("bench", help="benchmarks that print numbers")
    bsub = bench.add_subparsers(dest="bench", metavar="BENCH")
    bench.set_defaults(func=_show_help(bench))
    p = bsub.add_parser("camera", help="our camera vs highway-env's top-down render, 50 vehicles, one core")
    _add_config_args(p)
    p.add_argument("--scenes", type=_positive(int, "--scenes"), default=60, help="scenes (policy steps, default 60)")
    p.add_argument("--repeats", type=_positive(int, "--repeats"), default=5,
                   help="renderings of each scene per renderer (default 5)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_bench_camera)
    p = bsub.add_parser("drive", help="frame times of the driving window, headless (640x360, 50 vehicles, ADAS)")
    _add_config_args(p, STUDY_SCENARIO)
    p.add_argument("--duration", type=_positive(float, "--duration"), default=20.0,
                   help="seconds of driving (default 20)")
    p.add_argument("--vehicles", type=_positive(int, "--vehicles"), default=50, help="vehicles (default 50)")
    p.add_argument("--width", type=_positive(int, "--width"), default=640, help="window width [px] (default 640)")
    p.add_argument("--height", type=_positive(int, "--height"), default=360, help="window height [px] (default 360)")
    p.add_argument("--condition", choices=("adas", "baseline"), default="adas", help="condition (default adas)")
    p.add_argument("--seed", type=_seed, default=0, help="traffic seed (default 0)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_bench_drive)
    p = bsub.add_parser("fusion", help="time of one frame's fusion (Alg. 1 + 2 + tracking) per method, one core")
    p.add_argument("--frames", type=_positive(int, "--frames"), default=300, help="frames per method (default 300)")
    p.add_argument("--boxes", type=_positive(int, "--boxes"), default=20,
                   help=f"boxes and twin vehicles per frame (default 20, at most {MAX_BENCH_BOXES})")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_bench_fusion)
    p = bsub.add_parser("detector", help="frames/s of the learned detector, batched, and one frame's latency")
    p.add_argument("--weights", help="weights file (default: the shipped weights)")
    p.add_argument("--batch", type=_positive(int, "--batch"), default=32, help="frames per call (default 32)")
    p.add_argument("--seconds", type=_positive(float, "--seconds"), default=10.0,
                   help="time per measurement [s] (default 10)")
    p.add_argument("--threads", type=_positive(int, "--threads"), default=2, help="torch threads (default 2)")
    p.add_argument("--size", type=_size, default=(320, 180), help="frame size WxH (default 320x180)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_bench_detector)
    p = bsub.add_parser("sim", help="stock highway-v0 vs our env (steps/s, ratio, trajectory deviation), one process")
    p.add_argument("--steps", type=_positive(int, "--steps"), default=30, help="env steps per measurement (default 30)")
    p.add_argument("--seed", type=_seed, default=0, help="reset seed (default 0)")
    p.add_argument("--deviation-s", type=_positive(float, "--deviation-s"), default=30.0,
                   help="simulated seconds of the stock-vs-ours deviation run (default 30)")
    p.add_argument("--repeats", type=_positive(int, "--repeats"), default=1,
                   help="measurements per env, best kept (default 1)")
    p.add_argument("--profile", metavar="FILE", help="also write a cProfile of our env (driver types) to FILE")
    p.add_argument("--force", action="store_true", help="replace the file --profile names if it exists")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=cmd_bench_sim)
    p = bsub.add_parser("train", help="RL training steps/s: today's path and the fast path (lean env, worker processes)")
    p.add_argument("--config", required=True, help="training config, e.g. agents/ppo-adas.toml (kind = \"rl\")")
    p.add_argument("--timesteps", type=_positive(int, "--timesteps"), default=8192,
                   help="PPO steps per path, rounded up to whole rollouts (default 8192)")
    p.add_argument("--n-envs", type=_positive(int, "--n-envs"), default=4,
                   help="worker processes of the fast path (default 4: two per core of a 2-core machine)")
    p.add_argument("--env-steps", type=_positive(int, "--env-steps"), default=600,
                   help="env steps of the env-only comparison (default 600)")
    p.add_argument("--seed", type=_seed, default=0, help="seed of the env-only episode (default 0)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_bench_train)
    p = bsub.add_parser("startup", help="wall time of --help, a mistyped option and import dt_highway, new processes")
    p.add_argument("--repeats", type=_positive(int, "--repeats"), default=5, help="runs of each case (default 5)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_bench_startup)
    p = bsub.add_parser("memory", help="memory over hours of simulated time (ego on autopilot)")
    _add_config_args(p)
    p.add_argument("--hours", type=_positive(float, "--hours"), default=1.0, help="simulated hours (default 1)")
    p.add_argument("--every-min", type=_positive(float, "--every-min"), default=10.0,
                   help="sample every this many simulated minutes (default 10)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_bench_memory)
    return parser


def _option_names(parser: argparse.ArgumentParser) -> dict[str, str]:
    """Every option's name on the command line (``--scenario``, ``TRIAL_DIR``) by its ``dest``, subcommands too."""
    names: dict[str, str] = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                names = {**_option_names(sub), **names}
        elif action.dest not in names:
            names[action.dest] = action.option_strings[-1] if action.option_strings else str(action.metavar or action.dest)
    return names


def _check_not_empty(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """No option is given as an empty string (an unset shell variable): it would name the current folder.

    :raises ConfigError: one line naming the option
    """
    empty = [dest for dest, value in vars(args).items() if isinstance(value, str) and not value.strip()]
    if empty:
        name = _option_names(parser).get(empty[0], empty[0])
        raise ConfigError(f"{name} must not be empty (got '{getattr(args, empty[0])}')")


OUT_FOLDERS = ("run", "camera", "matching", "study", "drive", "session", "rl-compare", "calibrate")
"""Commands whose ``--out`` is a folder (the others' is a file)"""


def _nearest_existing(path: Path) -> Path:
    """``path`` or its nearest ancestor that exists (the root at worst): a file there means no folder can be
    made below it."""
    return next(p for p in (path, *path.parents) if p.exists() or p == p.parent)


def _check_out(args: argparse.Namespace) -> None:
    """Before any work: the folder every ``--out`` writes into takes a file (found now, not after minutes
    of simulation). Nothing is created: the nearest folder that exists is tried with
    a temporary file.

    :raises ConfigError: one line naming the option, the path and why
    """
    for attr, option in (("out", "--out"), ("out_json", "--out"), ("frames_out", "--frames-out"),
                         ("screenshots", "--screenshots"), ("profile", "--profile")):
        value = getattr(args, attr, None)
        if not isinstance(value, str):
            continue
        names_folder = attr in ("frames_out", "screenshots") or (attr == "out" and args.command in OUT_FOLDERS)
        target = Path(value)
        folder = target if names_folder else target.parent
        existing = _nearest_existing(folder)
        if not existing.is_dir():
            raise ConfigError(f"{option} {value}: {existing} is a file, not a folder")
        if not names_folder and target.is_dir() and getattr(args, "detector", None) != "train":  # it says it better
            raise ConfigError(f"{option} {value} is a folder: name a file")
        _check_not_replaced(args, attr, option, target)
        try:
            with tempfile.TemporaryFile(dir=existing):
                pass
        except OSError as exc:
            raise ConfigError(f"{option} {value}: cannot write in {existing} ({exc.strerror or exc})") from None


EARLIER_OUTPUTS = {
    "run": ("twin_eval.json", "config.json"),
    "camera": ("frames.jsonl", "config.json"),
    "matching": ("summary.json", "detectors.json", "sweep.json", "config.json", "simulated/config.json",
                 "learned/config.json"),
}
"""The files that say a folder holds an earlier run of a command whose ``--out`` is a folder it writes
fixed names into (``study``, ``calibrate``, ``session`` and ``drive`` resume instead; ``rl-compare``
checks its own)"""

MATCHING_FILES = (*OUTPUT_FILES, *SWEEP_FILES, "detectors.json", "config.json")
"""What ``dt-highway matching`` writes in its ``--out`` (and, comparing detectors, in ``simulated/`` and ``learned/``)"""


def _check_not_replaced(args: argparse.Namespace, attr: str, option: str, target: Path) -> None:
    """A JSON result (``--out FILE``), replay frames, or the outputs of an earlier ``run``, ``camera`` or
    ``matching`` already there are replaced only with ``--force``.

    :raises ConfigError: one line naming what is there and how to replace it
    """
    if getattr(args, "force", False):
        return
    held = [name for name in EARLIER_OUTPUTS.get(args.command, ()) if (target / name).is_file()]
    if attr == "out" and held:
        raise ConfigError(f"{option} {target} holds the outputs of an earlier {args.command} ({held[0]}): pass --force "
                          "to replace them, or another --out")
    if attr in ("out_json", "profile") and target.is_file():
        raise ConfigError(f"{option} {target} exists: pass --force to replace it, or name another file")
    if attr == "frames_out":
        from dt_highway.hmi.replay import replay_frames_in  # lazy: highway-env; only replay writes frames

        if frames := replay_frames_in(target):
            raise ConfigError(f"{option} {target} holds {len(frames)} frames of an earlier replay: pass --force to "
                              "replace them, or name another folder")


def _os_error(exc: OSError) -> str:
    """One line on an output path that cannot be written: which path, and why."""
    if exc.filename is None:
        return f"cannot write: {exc.strerror or exc}"
    path = Path(str(exc.filename))
    if isinstance(exc, (FileExistsError, NotADirectoryError)):  # a file where a folder is needed
        blocking = _nearest_existing(path)
        if blocking.is_file():
            return f"'{path}' is a file, not a folder" if blocking == path else \
                f"cannot write '{path}': {blocking} is a file, not a folder"
    return f"cannot write '{path}': {exc.strerror or exc}"


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``dt-highway`` console script.

    :param argv: arguments (default ``sys.argv[1:]``)
    :return: exit status
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    name = " ".join(n for n in (args.command, getattr(args, args.command, None)) if isinstance(n, str))  # bench sim
    try:
        _check_not_empty(parser, args)
        _check_out(args)
        return int(args.func(args) or 0)
    except ConfigError as exc:
        print(f"dt-highway {name}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # an output path that cannot be written, a full disk...
        print(f"dt-highway {name}: error: {_os_error(exc)}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, SystemError) as exc:  # SystemError: Ctrl-C inside numba code (dt_highway.interrupts)
        if not interrupted_by_user(exc):
            raise
        print(f"dt-highway {name}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
