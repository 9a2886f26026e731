"""The ground-truth wall, in code: drivers and the keyboard window cannot import the truth, and a
driver that goes looking for the truth in what it is given finds nothing."""

import ast
import dataclasses
from pathlib import Path

import numpy as np
from highway_env.envs.common.abstract import AbstractEnv
from highway_env.road.road import Road
from highway_env.vehicle.objects import RoadObject

import dt_highway.study as study
from dt_highway.camera.truth import CameraTruth, VehicleTruth
from dt_highway.drivers import IDMDriver, IDMParams, Perception, SenseRequest
from dt_highway.study import TrialSpec, run_trial
from dt_highway.world.traffic import DriverPopulation, TrafficManager

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "dt_highway"
TRUTH_MODULES = ("dt_highway.camera.truth", "dt_highway.world", "dt_highway.evaluation")
"""What neither a driver nor the keyboard window may import"""


# ----------------------------------------------------------------------------- (a) imports
def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(source: str, package: str) -> list[tuple[int, str]]:
    """Every module a module's source imports, anywhere in it (module level, functions,
    TYPE_CHECKING blocks, ``importlib.import_module("...")``), with the line; relative imports
    resolved against ``package`` (the module's package)."""
    tree = ast.parse(source)
    found: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join(anchor + ([base] if base else []))
            found.append((node.lineno, base))
            found += [(node.lineno, f"{base}.{alias.name}") for alias in node.names]  # `from pkg import module`
        elif isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant) \
                and isinstance(node.args[0].value, str):
            func = node.func
            name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            if name in ("import_module", "__import__"):
                found.append((node.lineno, node.args[0].value))
    return found


def _under(module: str, prefixes: tuple[str, ...]) -> bool:
    return any(module == p or module.startswith(p + ".") for p in prefixes)


def test_drivers_and_the_keyboard_window_import_no_truth_and_drivers_no_env():
    files = sorted((PACKAGE / "drivers").rglob("*.py")) + sorted((PACKAGE / "hmi").rglob("*.py"))
    names = {_module_name(f) for f in files}
    assert {"dt_highway.drivers.perception", "dt_highway.drivers.scripted", "dt_highway.drivers.policy",
            "dt_highway.hmi.drive"} <= names
    offences = []
    for f in files:
        forbidden = TRUTH_MODULES + (("dt_highway.env",) if "drivers" in f.relative_to(PACKAGE).parts else ())
        package = _module_name(f) if f.name == "__init__.py" else _module_name(f).rpartition(".")[0]
        offences += [f"{f.relative_to(ROOT)}:{line} imports {m}"
                     for line, m in _imports(f.read_text(encoding="utf-8"), package) if _under(m, forbidden)]
    assert not offences, "\n".join(offences)


def test_the_import_check_sees_every_kind_of_import():
    code = ("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import dt_highway.env.core\n"
            "def f():\n    from dt_highway.world.traffic import driver_type\n    from ..camera import truth\n"
            "    from .. import evaluation\n    import importlib\n    importlib.import_module('dt_highway.world')\n")
    found = [m for _, m in _imports(code, "dt_highway.drivers")]
    for module in ("dt_highway.env.core", "dt_highway.world.traffic", "dt_highway.camera.truth",
                   "dt_highway.evaluation", "dt_highway.world"):
        assert module in found, (module, found)
        assert _under(module, TRUTH_MODULES + ("dt_highway.env",))


# ----------------------------------------------------------------------------- (b) a driver looking for truth
FORBIDDEN_TYPES = (AbstractEnv, Road, RoadObject, CameraTruth, VehicleTruth, DriverPopulation, TrafficManager)


def find_truth(obj: object) -> list[str]:
    """Everything reachable from ``obj`` (dataclass fields, dicts, tuples, lists, sets, objects'
    ``__dict__`` and slots) that is the env, the road, a vehicle, a truth object, the driver
    population, or a dict key ``"ground_truth"``: the paths to them."""
    found: list[str] = []
    seen: set[int] = set()
    stack: list[tuple[object, str]] = [(obj, "perception")]
    while stack:
        x, path = stack.pop()
        if id(x) in seen or x is None or isinstance(x, (str, bytes, int, float, bool, np.generic)):
            continue
        seen.add(id(x))
        if isinstance(x, FORBIDDEN_TYPES):
            found.append(f"{path}: {type(x).__module__}.{type(x).__name__}")
            continue
        module = type(x).__module__ or ""
        if module.startswith(("dt_highway.world", "dt_highway.camera.truth", "dt_highway.evaluation")):
            found.append(f"{path}: {module}.{type(x).__name__}")
            continue
        if isinstance(x, np.ndarray):
            if x.dtype == object:
                stack += [(v, f"{path}[{i}]") for i, v in enumerate(x.ravel().tolist())]
            continue
        if isinstance(x, dict):
            for k, v in x.items():
                if k == "ground_truth":
                    found.append(f"{path}['ground_truth']")
                stack += [(k, f"{path}.key({k!r})"), (v, f"{path}[{k!r}]")]
            continue
        if isinstance(x, (tuple, list, set, frozenset)):
            stack += [(v, f"{path}[{i}]") for i, v in enumerate(x)]
            continue
        if dataclasses.is_dataclass(x) and not isinstance(x, type):
            stack += [(getattr(x, f.name), f"{path}.{f.name}") for f in dataclasses.fields(x)]
        if hasattr(x, "__dict__") and not isinstance(x, type):
            stack += [(v, f"{path}.{k}") for k, v in vars(x).items()]
        for k in getattr(type(x), "__slots__", ()):
            if hasattr(x, k):
                stack.append((getattr(x, k), f"{path}.{k}"))
    return found


class Snoop(IDMDriver):
    """Drives like plain IDM, asks for every sense, and searches all it is given for the truth."""

    senses = SenseRequest(surroundings=True, entering=True, marks=True, image=True)

    def __init__(self) -> None:
        super().__init__("snoop", IDMParams())
        self.found: list[str] = []
        self.decisions = self.images = self.marks = 0

    def act(self, perception: Perception) -> np.ndarray:
        assert isinstance(perception, Perception)
        self.decisions += 1
        self.images += perception.image is not None
        self.marks += len(perception.marks)
        self.found += find_truth(perception)
        return super().act(perception)


def test_the_walker_finds_the_truth_when_it_is_there():
    import gymnasium as gym

    env = gym.make("dt-highway-v0", config={"highway": {"vehicles_count": 5, "duration": 2.0},
                                            "twin": {"preroll_s": 0.0}})
    _, info = env.reset(seed=0)
    u = env.unwrapped
    own = Perception(0.0, None)  # type: ignore[arg-type]
    leaks = ((u, "DTHighwayEnv"), (u.road, "Road"), (u.vehicle, "Vehicle"), (u.population, "DriverPopulation"),
             ({"info": info}, "ground_truth"), ([{"x": (1, u.road.vehicles[0])}], "Vehicle"))
    for leak, what in leaks:
        found = find_truth(dataclasses.replace(own, observation=leak))
        assert found and any(what in f for f in found), (what, found)
    env.close()


def test_a_driver_looking_for_the_truth_in_a_study_trial_finds_nothing(tmp_path, monkeypatch):
    snoop = Snoop()
    monkeypatch.setattr(study, "load_driver", lambda path: snoop)
    spec = TrialSpec(str(tmp_path / "adas-000"), "agents/idm.toml", "adas", 0, 0, str(ROOT / "envs/highway-trial.toml"),
                     ("highway.duration=4", "highway.vehicles_count=16"))
    result = run_trial(spec)
    assert result["status"] == "completed", result
    assert snoop.decisions >= 15 and snoop.images == snoop.decisions  # it was given the camera image every time
    assert snoop.marks > 0  # and the overlay's marks
    assert not snoop.found, "\n".join(snoop.found[:20])
