"""The choices and defaults a user is offered on the command line: study conditions, traffic populations, what
a crash does, the intention oracle's knobs, seeds and the files a command writes.

They live in this module, which imports nothing heavy, so that ``dt-highway --help`` (and every command's
``--help``, and a mistyped option) answers without importing highway-env, scipy or torch (about 2 s). Each is
defined here once; the module that uses it imports it from here and re-exports it (``dt_highway.conditions.CONDITIONS``
is this ``CONDITIONS``).
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

CONDITIONS = ("baseline", "adas", "adas-type", "adas-threat", "sham", "sham-type", "sham-threat")
"""Every condition a study or a keyboard session can run (:mod:`dt_highway.conditions`)"""

POPULATIONS = ("two_class", "continuum")
"""``traffic.population``: two driver classes with fixed parameters, or a continuum of drivers"""

CRASH_POLICIES = ("end", "continue")
"""What a crash does to a keyboard trial: end it, or put the ego back on the road and go on"""

DEFAULT_PROTOCOL = Path(str(resources.files("dt_highway").joinpath("hmi", "protocols", "default.toml")))
"""The protocol a keyboard session follows unless told otherwise"""

INTENT_EPISODES = 10
"""Episodes of ``twin-eval --intent`` by default"""

HIDEABLE = ("positions", "speeds", "timers", "attempts", "unseen_attempts")
"""What the intention oracle starting from the simulator's state can be denied
(:mod:`dt_highway.evaluation.intent_oracle`)"""
PICTURE_HIDEABLE = ("chases",)
"""What the oracle starting from the twin's picture can be denied: the twin's estimate of who is chasing the ego"""
PICTURE_REVEALABLE = ("chases", "lateral", "types", "positions", "attempts")
"""What of the simulator's state the oracle starting from the twin's picture can be given instead of the twin's
estimate (see :mod:`dt_highway.evaluation.intent_oracle`)"""
STARTS = ("state", "picture")
"""What the oracle's copies start from: the simulator's state, or the twin's picture"""

TRAIN_SEED = 1000
"""First training seed of ``train-chase`` by default (as ``train-intent``'s)"""
TEST_SEED = 5000
"""First held-out seed of ``train-chase``'s score by default"""
SCORE_THRESHOLDS = (0.3, 0.5, 0.7)
"""``train-chase`` reports precision and recall at these thresholds [-]"""

COMPARE_SCENARIO = "envs/highway-trial.toml"
"""The scenario ``rl-compare`` runs by default"""
COMPARE_SEED = 10000
"""First held-out seed of ``rl-compare``: apart from training (seed 0.. of the training envs) and the studies' seeds"""

OUTPUT_FILES = ("curve.csv", "summary.json", "frames.csv", "curve.png")
"""What ``dt-highway matching`` writes (:func:`dt_highway.evaluation.matching.write_outputs`), in this order"""
SWEEP_FILES = ("sweep.csv", "sweep.json", "sweep.png")
"""What ``dt-highway matching --sweep`` writes (:func:`dt_highway.evaluation.matching.write_sweep`), in this order"""
