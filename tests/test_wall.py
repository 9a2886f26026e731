"""The ground-truth wall, in code: drivers and the keyboard window cannot import the truth (by
module, by name or through a re-export), nor name the attributes and keys that reach it; a driver
that goes looking for the truth in what it is given finds nothing but plain data; and a driver
cannot write into the env through what it is given."""

import ast
import dataclasses
import functools
import hashlib
import importlib
import sys
import types
from collections.abc import Iterator
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from highway_env.envs.common.abstract import AbstractEnv
from highway_env.road.road import Road
from highway_env.vehicle.objects import RoadObject

import dt_highway.study as study
from dt_highway.camera.pinhole import Pose
from dt_highway.camera.render import CameraImage, CameraRenderer
from dt_highway.camera.truth import CameraTruth, VehicleTruth
from dt_highway.conditions import condition_config
from dt_highway.config import load_config
from dt_highway.drivers import IDMDriver, IDMParams, Perception, SenseRequest
from dt_highway.drivers.perception import Mark, ObservationSpec, OwnState, Seen, Surroundings
from dt_highway.env.seat import DriverSeat
from dt_highway.labels import LABELS
from dt_highway.study import TrialSpec, run_trial
from dt_highway.world.traffic import DriverPopulation, TrafficManager

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "dt_highway"
TRUTH_MODULES = ("dt_highway.camera.truth", "dt_highway.world", "dt_highway.evaluation",
                 "dt_highway.metrics.trial_log", "dt_highway.perception.learned.data")
"""What neither a driver nor the keyboard window may import, by module or by a name defined there
(the trial log logs the truth; the learned detector's data renders truth labels)"""
DRIVER_MODULES = TRUTH_MODULES + ("dt_highway.env", "highway_env", "gc", "inspect", "ctypes")
"""What a driver may not import either: the env (also as ``dt_highway``'s re-exports of it), the
simulator, and the introspection that finds live objects (the env among them)"""
ALLOWED_IMPORTS = {
    ("dt_highway/hmi/drive.py", "dt_highway.metrics.trial_log", "TrialRecorder"):
        "the keyboard trial is logged as a scripted one (hmi holds the env: its wall is import-only)",
    ("dt_highway/hmi/drive.py", "dt_highway.metrics.trial_log", "TrialWriter"): "the same",
    ("dt_highway/hmi/session.py", "dt_highway.metrics.trial_log", "load_trial"):
        "a session resumes after the trials whose log says completed",
}
"""The only forbidden imports the keyboard window makes, each with why"""
TRUTH_NAMES = frozenset({
    "camera_truth", "_camera_frame", "_frame",  # the env's camera truth (env/core.py)
    "ground_truth", "cut_ins", "_cut_ins", "_events",  # info["ground_truth"], info["safety"]["cut_ins"] (driver types)
    "population", "traffic",  # the env's DriverPopulation and TrafficManager
    "driver_type", "dt_driver_type", "dt_connected",  # a vehicle's true type (world/traffic.py)
    "CameraTruth", "VehicleTruth", "DriverPopulation", "TrafficManager",
})
"""Attribute, key and other names through which the env, its info or a vehicle reach the truth"""
INTROSPECTION_NAMES = frozenset({"_getframe", "currentframe", "f_back", "f_locals", "f_globals", "get_referrers",
                                 "get_objects", "__self__", "__closure__", "__globals__", "__subclasses__"})
"""What a driver may not name either: the ways from what it is given (or its caller's frame) to live objects"""


# ----------------------------------------------------------------------------- (a) imports
def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _package(path: Path) -> str:
    return _module_name(path) if path.name == "__init__.py" else _module_name(path).rpartition(".")[0]


@dataclasses.dataclass(frozen=True)
class Import:
    """One import: ``import module`` (``name`` None) or ``from module import name``."""

    line: int
    module: str
    name: str | None = None


def _imports(source: str, package: str) -> list[Import]:
    """Every import in a module's source, anywhere in it (module level, functions,
    TYPE_CHECKING blocks, ``importlib.import_module("...")``), relative imports resolved against
    ``package`` (the module's package); an ``import_module`` of a computed name is module ``?``."""
    found: list[Import] = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            found += [Import(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join(anchor + ([base] if base else []))
            found += [Import(node.lineno, base, alias.name) for alias in node.names]
        elif isinstance(node, ast.Call) and node.args:
            func = node.func
            name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            if name in ("import_module", "__import__"):
                arg = node.args[0]
                literal = isinstance(arg, ast.Constant) and isinstance(arg.value, str)
                found.append(Import(node.lineno, arg.value if literal else "?"))
    return found


def _origins(obj: object, owner: types.ModuleType, name: str) -> set[str]:
    """Where an object a module exports under ``name`` is defined: a module is itself; a class or
    function its ``__module__``; another object its type's module, and, exported by one of our
    packages, the package's submodule that holds it under the same name (``dt_highway.ENV_ID``)."""
    if isinstance(obj, types.ModuleType):
        return {obj.__name__}
    if isinstance(obj, type) or callable(obj):
        module = getattr(obj, "__module__", None)
        return {module} if isinstance(module, str) else set()
    found = {type(obj).__module__}
    if hasattr(owner, "__path__") and _under(owner.__name__, ("dt_highway",)):
        prefix = owner.__name__ + "."
        found |= {m for m, sub in list(sys.modules.items())
                  if m.startswith(prefix) and sub is not None and getattr(sub, name, None) is obj}
    return found


def _resolve(module: str, name: str | None) -> set[str]:
    """The modules an import reaches: the module imported, and for ``from module import name``
    where what it binds is defined (``*``: every public name)."""
    where = {module}
    if name is None or module == "?":
        return where
    try:
        owner = importlib.import_module(module)
    except ImportError:
        return where
    names = [n for n in vars(owner) if not n.startswith("_")] if name == "*" else [name]
    for n in names:
        obj = getattr(owner, n, None)
        if obj is None:
            try:
                obj = importlib.import_module(f"{module}.{n}")  # a submodule not imported yet
            except ImportError:
                continue
        where |= _origins(obj, owner, n)
    return where


def _root_module(x: ast.expr, bound: dict[str, str]) -> str | None:
    """The module an expression names: a name bound to a module, or ``import_module("m")`` /
    ``__import__("m")`` (the top-level package ``m`` for ``__import__``)."""
    if isinstance(x, ast.Name):
        return bound.get(x.id)
    if isinstance(x, ast.Call) and x.args and isinstance(x.args[0], ast.Constant) and isinstance(x.args[0].value, str):
        func = x.func
        name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
        if name == "import_module":
            return x.args[0].value
        if name == "__import__":
            return x.args[0].value.split(".")[0]
    return None


def _attribute_uses(source: str, package: str) -> list[tuple[int, str, set[str]]]:
    """Every ``module.attr.attr`` a module's code reaches through a module (``import dt_highway``
    and then ``dt_highway.env.DTHighwayEnv``): the line, the dotted name and where what it
    reaches is defined. Names bound to modules: ``import a.b`` binds ``a``, ``import a.b as c``
    binds ``c`` to ``a.b``, ``from a import b`` binds ``b`` to ``a.b`` when that is a module."""
    tree = ast.parse(source)
    bound: dict[str, str] = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                bound[alias.asname or alias.name.split(".")[0]] = alias.name if alias.asname else alias.name.split(".")[0]
    for imp in _imports(source, package):
        if imp.name not in (None, "*") and isinstance(sys.modules.get(f"{imp.module}.{imp.name}"), types.ModuleType):
            bound.setdefault(imp.name, f"{imp.module}.{imp.name}")
    uses = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Attribute):
            continue
        chain: list[str] = []
        x: ast.expr = node
        while isinstance(x, ast.Attribute):
            chain.insert(0, x.attr)
            x = x.value
        root = _root_module(x, bound)
        if root is None:
            continue
        try:
            obj: object = importlib.import_module(root)
        except ImportError:
            continue
        where = {root}
        for attr in chain:
            if not isinstance(obj, types.ModuleType):
                break
            nxt = getattr(obj, attr, None)
            if nxt is None:
                break
            where |= _origins(nxt, obj, attr)
            obj = nxt
        uses.append((node.lineno, ".".join([root, *chain]), where))
    return uses


def _under(module: str, prefixes: tuple[str, ...]) -> bool:
    return any(module == p or module.startswith(p + ".") for p in prefixes)


def _forbidden(path: Path) -> tuple[str, ...]:
    return DRIVER_MODULES if "drivers" in path.relative_to(PACKAGE).parts else TRUTH_MODULES


def _wall_files() -> list[Path]:
    return sorted((PACKAGE / "drivers").rglob("*.py")) + sorted((PACKAGE / "hmi").rglob("*.py"))


def import_offences(rel: str, source: str, package: str, forbidden: tuple[str, ...],
                    allowed: set[tuple[str, str, str]] | frozenset = frozenset()) -> tuple[list[str], set]:
    """The forbidden imports (and module attributes) of one module's source, less the allowed ones.

    :return: the offences, and the allowances used
    """
    offences, used = [], set()
    for imp in _imports(source, package):
        bad = sorted(m for m in _resolve(imp.module, imp.name) if _under(m, forbidden) or m == "?")
        if not bad:
            continue
        key = (rel, imp.module, imp.name)
        if key in allowed:
            used.add(key)
            continue
        what = imp.module if imp.name is None else f"{imp.name} from {imp.module}"
        offences.append(f"{rel}:{imp.line} imports {what} (defined in {', '.join(bad)})")
    for line, dotted, where in _attribute_uses(source, package):
        bad = sorted(m for m in where if _under(m, forbidden))
        if bad:
            offences.append(f"{rel}:{line} reaches {dotted} (defined in {', '.join(bad)})")
    return offences, used


def test_drivers_and_the_keyboard_window_import_no_truth_and_drivers_no_env():
    files = _wall_files()
    names = {_module_name(f) for f in files}
    assert {"dt_highway.drivers.perception", "dt_highway.drivers.scripted", "dt_highway.drivers.policy",
            "dt_highway.hmi.drive", "dt_highway.hmi.session"} <= names
    offences, used = [], set()
    for f in files:
        rel = str(f.relative_to(ROOT))
        found, u = import_offences(rel, f.read_text(encoding="utf-8"), _package(f), _forbidden(f), set(ALLOWED_IMPORTS))
        offences += found
        used |= u
    assert not offences, "\n".join(offences)
    assert used == set(ALLOWED_IMPORTS), f"allowances no longer needed: {set(ALLOWED_IMPORTS) - used}"


def test_the_import_check_sees_every_kind_of_import():
    code = ("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import dt_highway.env.core\n"
            "def f():\n    from dt_highway.world.traffic import driver_type\n    from ..camera import truth\n"
            "    from .. import evaluation\n    import importlib\n    importlib.import_module('dt_highway.world')\n")
    found = [m for imp in _imports(code, "dt_highway.drivers") for m in _resolve(imp.module, imp.name)]
    for module in ("dt_highway.env.core", "dt_highway.world.traffic", "dt_highway.camera.truth",
                   "dt_highway.evaluation", "dt_highway.world"):
        assert module in found, (module, found)
        assert _under(module, DRIVER_MODULES)


@pytest.mark.parametrize(("code", "in_hmi"), [
    ("from dt_highway import DTHighwayEnv", False),  # the top-level re-export of the env
    ("from dt_highway import ENV_ID", False),  # the env's id (a plain value the env package re-exports)
    ("from dt_highway.camera.render import CameraTruth", True),  # a re-export of the truth
    ("from dt_highway.perception.detect import CameraTruth", True),
    ("from dt_highway import load_trial", True),  # the trial log (it logs the truth)
    ("from dt_highway.metrics.trial_log import TrialRecorder", True),
    ("from dt_highway.perception.learned import data", True),  # it renders truth labels
    ("from dt_highway.perception.learned.data import make_frame", True),
    ("from dt_highway.env.seat import DriverSeat", False),
    ("from dt_highway.world.traffic import *", True),
    ("import dt_highway\nx = dt_highway.env.core.DTHighwayEnv", False),  # a module's attribute, not an import
    ("import dt_highway.drivers as d\nx = d.base.Perception\ny = __import__('dt_highway').world", True),
    ("import importlib\nm = importlib.import_module('dt_highway.' + 'env')", True),  # a computed name
    ("import gc", False),
])
def test_the_import_check_sees_where_a_name_is_defined(code, in_hmi):
    offences, _ = import_offences("dt_highway/drivers/x.py", code, "dt_highway.drivers", DRIVER_MODULES)
    assert offences, code
    hmi, _ = import_offences("dt_highway/hmi/x.py", code, "dt_highway.hmi", TRUTH_MODULES)
    assert bool(hmi) == in_hmi, (code, hmi)


def test_the_drivers_own_imports_are_clean():
    ok = ("from dt_highway.drivers.perception import Perception\nfrom dt_highway.agent_config import IDMParams\n"
          "import numpy as np\nx = np.pi\nfrom dt_highway.labels import AGGRESSIVE\nfrom dt_highway import ConfigError\n"
          "import dt_highway.drivers as d\ny = d.base.Perception")
    assert import_offences("dt_highway/drivers/x.py", ok, "dt_highway.drivers", DRIVER_MODULES) == ([], set())


TWIN_TRUTH_MODULES = TRUTH_MODULES + ("dt_highway.env", "dt_highway.metrics", "highway_env")
"""What the cloud twin may not import: the truth, the env and the simulator (it knows the world only
through the fixes its uplink receives)"""


def test_the_twin_imports_nothing_that_holds_the_truth():
    """Every module of the twin (tagger, intention, chase, store, cloud, uplink, weights...), by
    every kind of import the driver wall checks (relative, ``from dt_highway import world``,
    ``import_module``, module attributes)."""
    files = sorted((PACKAGE / "twin").rglob("*.py"))
    assert {"dt_highway.twin.tagger", "dt_highway.twin.intention", "dt_highway.twin.chase", "dt_highway.twin.store",
            "dt_highway.twin.cloud", "dt_highway.twin.uplink"} <= {_module_name(f) for f in files}
    offences = []
    for f in files:
        found, _ = import_offences(str(f.relative_to(ROOT)), f.read_text(encoding="utf-8"), _package(f),
                                   TWIN_TRUTH_MODULES)
        offences += found
    truth_names = frozenset({"driver_type", "dt_driver_type", "ground_truth", "DriverPopulation", "TrafficManager"})
    offences += [o for f in files for o in name_offences(str(f.relative_to(ROOT)), f.read_text(encoding="utf-8"),
                                                          truth_names)]
    assert not offences, "\n".join(offences)


@pytest.mark.parametrize("code", ["from dt_highway import world", "from ..world.traffic import driver_type",
                                  "import importlib\nm = importlib.import_module('dt_highway.env')",
                                  "from dt_highway.metrics import safety", "import highway_env.road.road"])
def test_the_twin_check_sees_each_way_in(code):
    offences, _ = import_offences("dt_highway/twin/x.py", code, "dt_highway.twin", TWIN_TRUTH_MODULES)
    assert offences, code


# ----------------------------------------------------------------------------- (a') names that reach the truth
def names_used(source: str) -> list[tuple[int, str]]:
    """Every identifier a module's code uses, with its line: attribute names, names, string
    constants (keys, ``getattr`` names), keyword arguments, parameters and imported names."""
    found: list[tuple[int, str]] = []
    for node in ast.walk(ast.parse(source)):
        line = getattr(node, "lineno", 0)
        if isinstance(node, ast.Attribute):
            found.append((line, node.attr))
        elif isinstance(node, ast.Name):
            found.append((line, node.id))
        elif isinstance(node, ast.Constant) and isinstance(node.value, str):
            found.append((line, node.value))
        elif isinstance(node, ast.keyword) and node.arg:
            found.append((line, node.arg))
        elif isinstance(node, ast.arg):
            found.append((line, node.arg))
        elif isinstance(node, ast.alias):
            found += [(line, part) for part in (node.name.split(".") + ([node.asname] if node.asname else []))]
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            found.append((line, node.name))
    return found


def name_offences(rel: str, source: str, forbidden: frozenset[str]) -> list[str]:
    return [f"{rel}:{line} names {name!r}" for line, name in names_used(source) if name in forbidden]


def test_drivers_and_the_keyboard_window_name_nothing_that_reaches_the_truth():
    offences = []
    for f in _wall_files():
        drivers = "drivers" in f.relative_to(PACKAGE).parts
        offences += name_offences(str(f.relative_to(ROOT)), f.read_text(encoding="utf-8"),
                                  TRUTH_NAMES | INTROSPECTION_NAMES if drivers else TRUTH_NAMES)
    assert not offences, "\n".join(offences)


def test_the_name_check_sees_every_way_to_name_the_truth():
    import dt_highway.env.core as core
    import dt_highway.world.traffic as traffic

    env_source = Path(core.__file__).read_text(encoding="utf-8") + Path(traffic.__file__).read_text(encoding="utf-8")
    for name in ("camera_truth", "ground_truth", "population", "driver_type", "dt_driver_type", "dt_connected",
                 "cut_ins", "traffic", "_frame", "_camera_frame"):
        assert name in env_source, name  # the names are the env's own (renamed there, renamed here)
    for code in ("u.camera_truth()", "info['ground_truth']", "info.get('ground_truth')", "env.unwrapped.population",
                 "getattr(v, 'dt_driver_type')", "x = driver_type", "f(driver_type=1)", "def f(population): pass",
                 "env.traffic.population", "v.dt_connected", "u._frame[1]", "info['safety']['cut_ins']"):
        assert name_offences("x.py", code, TRUTH_NAMES), code
    for code in ("sys._getframe(1).f_locals", "gc.get_objects()", "m.__self__", "f.__closure__[0]"):
        assert name_offences("x.py", code, INTROSPECTION_NAMES), code
    assert not name_offences("x.py", '"""the ground truth, the population of drivers"""\nx = 1', TRUTH_NAMES)


# ----------------------------------------------------------------------------- (b) a driver looking for truth
FORBIDDEN_TYPES = (AbstractEnv, Road, RoadObject, CameraTruth, VehicleTruth, DriverPopulation, TrafficManager)
"""What must never be in a perception (named for better messages; the allow-list below rejects it anyway)"""
TRUTH_PREFIXES = ("dt_highway.world", "dt_highway.camera.truth", "dt_highway.evaluation", "dt_highway.env")
PLAIN = (type(None), bool, int, float, str)
SEQUENCES = (tuple, list, set, frozenset)
RECORDS = (Perception, OwnState, Surroundings, Seen, Mark, CameraImage, Pose)
"""The records a perception is made of: all it may hold besides plain data, containers and numeric arrays"""
OBSERVATION_KEYS = frozenset({"rgb", "depth"})
"""The only string keys in a perception (a vision policy's observation); other dicts are keyed by id or lane"""
NUMERIC = "biuf"
"""numpy dtype kinds of a perception's arrays and scalars: bool, int, unsigned, float"""


def _describe(x: object) -> str:
    """What a non-data object is, and for a function what it reaches."""
    t = type(x)
    if isinstance(x, (types.MethodType, types.BuiltinMethodType)) and getattr(x, "__self__", None) is not None:
        return f"method {x.__qualname__} bound to a {type(x.__self__).__name__}"
    if isinstance(x, functools.partial):
        return f"functools.partial of {_describe(x.func)}, args {[type(a).__name__ for a in x.args]}"
    if isinstance(x, types.FunctionType):
        cells = [type(c.cell_contents).__name__ for c in x.__closure__ or () if c.cell_contents is not None]
        return f"function {x.__qualname__}" + (f" closing over {', '.join(cells)}" if cells else "")
    if isinstance(x, types.ModuleType):
        return f"module {x.__name__}"
    return f"{t.__module__}.{t.__qualname__}"


def _record_children(x: object, path: str) -> tuple[list[tuple[object, str]], list[str]]:
    """A record's fields, and any attribute it carries beside them (a finding)."""
    fields = [f.name for f in dataclasses.fields(x)]
    extra = sorted(set(vars(x)) - set(fields)) if hasattr(x, "__dict__") else []
    children = [(getattr(x, n), f"{path}.{n}") for n in fields] + [(vars(x)[n], f"{path}.{n}") for n in extra]
    return children, [f"{path}.{n}: an attribute beside {type(x).__name__}'s fields" for n in extra]


def _array_finding(x: np.ndarray, path: str, truth_arrays: tuple[np.ndarray, ...]) -> str | None:
    if x.dtype.kind not in NUMERIC:
        return f"{path}: array of dtype {x.dtype} (not numeric data)"
    for a in truth_arrays:
        if np.may_share_memory(x, a) or (x.shape == a.shape and x.dtype == a.dtype and np.array_equal(x, a)):
            return f"{path}: the camera's instance map (truth)"
    return None


def find_truth(obj: object, truth_arrays: tuple[np.ndarray, ...] = ()) -> list[str]:
    """Everything reachable from ``obj`` that is not plain perception data: the paths to them.

    An allow-list: every object reached must be ``None``, a bool, int, float or str, a numeric
    numpy scalar or array, a tuple, list, set, frozenset or dict of those, or one of
    :data:`RECORDS` (exact types: no subclass, and no attribute beside a record's fields).
    Anything else (the env, a bound method, a function or closure, a ``functools.partial``, a
    module, a vehicle, a truth object, any other instance) is a finding, as are a string key
    other than an observation's, a driver type's name as a value and an array that is (or
    shares memory with) one of ``truth_arrays`` (the camera's instance map)."""
    found: list[str] = []
    seen: set[int] = set()
    stack: list[tuple[object, str]] = [(obj, "perception")]
    while stack:
        x, path = stack.pop()
        t = type(x)
        if t in PLAIN:
            if t is str and x in LABELS:
                found.append(f"{path}: {x!r}, a driver type")
            continue
        if id(x) in seen:
            continue
        seen.add(id(x))
        if isinstance(x, FORBIDDEN_TYPES) or (t.__module__ or "").startswith(TRUTH_PREFIXES):
            found.append(f"{path}: {t.__module__}.{t.__qualname__}")
        elif isinstance(x, (np.bool_, np.number)):
            if x.dtype.kind not in NUMERIC:
                found.append(f"{path}: numpy scalar {x.dtype}")
        elif t is np.ndarray:
            finding = _array_finding(x, path, truth_arrays)
            found += [finding] if finding else []
        elif t is dict:
            for k, v in x.items():
                if k == "ground_truth":
                    found.append(f"{path}['ground_truth']")
                elif type(k) is str and k not in OBSERVATION_KEYS:
                    found.append(f"{path}: key {k!r} (not a perception's)")
                stack += [(k, f"{path}.key({k!r})"), (v, f"{path}[{k!r}]")]
        elif t in SEQUENCES:
            stack += [(v, f"{path}[{i}]") for i, v in enumerate(x)]
        elif t in RECORDS:
            children, extra = _record_children(x, path)
            stack += children
            found += extra
        else:
            found.append(f"{path}: {_describe(x)} (not perception data)")
    return found


def _camera_spec(width: int, height: int) -> ObservationSpec:
    """A vision policy's observation at the camera's size, with depth (its rgb is the env's frame's)."""
    space = spaces.Dict({"rgb": spaces.Box(0, 255, (3, height, width), np.uint8),
                         "depth": spaces.Box(0, 255, (1, height, width), np.uint8)})
    return ObservationSpec("wall", "Camera", {"depth": True}, {"width_px": width, "height_px": height}, {}, space)


class Snoop(IDMDriver):
    """Drives like plain IDM, asks for every sense, and searches all it is given for the truth
    (the test hands it the camera's latest instance maps, which it never sees otherwise)."""

    senses = SenseRequest(surroundings=True, entering=True, marks=True, image=True)

    def __init__(self, truths: list[CameraTruth] | None = None) -> None:
        super().__init__("snoop", IDMParams())
        self.found: list[str] = []
        self.truths = truths if truths is not None else []
        self.decisions = self.images = self.marks = 0

    def act(self, perception: Perception) -> np.ndarray:
        assert isinstance(perception, Perception)
        self.decisions += 1
        self.images += perception.image is not None
        self.marks += len(perception.marks)
        self.found += find_truth(perception, tuple(t.instance for t in self.truths[-2:]))
        return super().act(perception)


def test_the_walker_finds_the_truth_when_it_is_there():
    env = gym.make("dt-highway-v0", config={"highway": {"vehicles_count": 5, "duration": 2.0},
                                            "twin": {"preroll_s": 0.0}, "camera": {"enabled": True}})
    _, info = env.reset(seed=0)
    u = env.unwrapped
    own = Perception(0.0, OwnState(1.0, 0.0, 1, 3, False))
    truth = u.camera_truth()
    vt = next(iter(truth.vehicles.values()))
    leaks = ((u, "DTHighwayEnv"), (u.road, "Road"), (u.vehicle, "Vehicle"), (u.population, "DriverPopulation"),
             (u.traffic, "TrafficManager"), (vt, "VehicleTruth"), (truth, "CameraTruth"),
             ({"info": info}, "ground_truth"), ([{3: (1, u.road.vehicles[0])}], "Vehicle"),
             (u.camera_truth, "bound to a DTHighwayEnv"), (env.unwrapped.step, "bound to a DTHighwayEnv"),
             (lambda: u.vehicle, "closing over DTHighwayEnv"), (functools.partial(u.step, None), "partial"),
             (functools.partial(print), "partial"), (np, "module numpy"), (object(), "builtins.object"),
             (info["ground_truth"]["vehicles"], "'driver_type'"), ({7: "aggressive"}, "a driver type"),
             (truth.instance, "instance map"), ({"rgb": truth.instance.copy()}, "instance map"),
             (np.array([u], dtype=object), "dtype object"), (type("D", (dict,), {})(), "D"),
             ((Seen(), types.SimpleNamespace(env=u)), "SimpleNamespace"))
    for leak, what in leaks:
        found = find_truth(dataclasses.replace(own, observation=leak), (truth.instance,))
        assert found and any(what in f for f in found), (what, found)
    hidden = Perception(0.0, OwnState(1.0, 0.0, 1, 3, False))
    object.__setattr__(hidden.own, "env", u)  # an attribute beside a record's fields
    assert any("beside OwnState" in f for f in find_truth(hidden))
    image = u.camera_image().read_only_copy()
    clean = dataclasses.replace(own, image=image, marks=(Mark((0.0, 1.0, 2.0, 3.0), "aggressive driver", 0.9, None),),
                                cars_under_marks=frozenset({3}), entering=Seen(3, 10.0, 20.0),
                                observation={"rgb": image.rgb, "depth": image.depth_m[..., None]})
    assert not find_truth(clean, (truth.instance,))
    env.close()


def test_a_driver_looking_for_the_truth_in_a_study_trial_finds_nothing(tmp_path, monkeypatch):
    truths: list[CameraTruth] = []
    render = CameraRenderer.render

    def recording_render(self, *args, **kwargs):
        image, truth = render(self, *args, **kwargs)
        truths.append(truth)
        return image, truth

    monkeypatch.setattr(CameraRenderer, "render", recording_render)
    snoop = Snoop(truths)
    monkeypatch.setattr(study, "load_driver", lambda path: snoop)
    # seed 3: a trial with aggressive-tagged cars in view in its first seconds (seeds 0-2 have none)
    spec = TrialSpec(str(tmp_path / "adas-000"), "agents/idm.toml", "adas", 0, 3, str(ROOT / "envs/highway-trial.toml"),
                     ("highway.duration=4", "highway.vehicles_count=16"))
    result = run_trial(spec)
    assert result["status"] == "completed", result
    assert snoop.decisions >= 15 and snoop.images == snoop.decisions  # it was given the camera image every time
    assert snoop.marks > 0  # and the overlay's marks
    assert truths
    assert not snoop.found, "\n".join(snoop.found[:20])


def test_a_driver_looking_for_the_truth_in_the_intention_recordings_finds_nothing():
    """``twin-eval --intent --driver`` / ``train-intent --driver``: the recording env carries the truth
    recorder; the driver at the wheel gets its seat's perceptions only."""
    from dt_highway.evaluation.intent import record_episodes

    snoop = Snoop()
    cfg = load_config(str(ROOT / "envs/highway-trial.toml"), ["highway.duration=3", "highway.vehicles_count=12",
                                                               "twin.preroll_s=4"])
    episodes = record_episodes(cfg, [3, None], driver=snoop)
    assert len(episodes) == 2 and len(episodes[0].truth) > 0  # the recorder had the truth beside the driver
    assert snoop.decisions >= 2 * 3 * cfg.highway.policy_frequency
    assert not snoop.found, "\n".join(snoop.found[:20])


# ----------------------------------------------------------------------------- (c) a driver writing into the env
def _arrays(obj: object, path: str = "perception") -> Iterator[tuple[str, np.ndarray]]:
    """Every array reachable in a perception (its records, dicts and sequences)."""
    if type(obj) is np.ndarray:
        yield path, obj
    elif type(obj) in RECORDS:
        for f in dataclasses.fields(obj):
            yield from _arrays(getattr(obj, f.name), f"{path}.{f.name}")
    elif isinstance(obj, dict):
        for k, v in obj.items():
            yield from _arrays(v, f"{path}[{k!r}]")
    elif isinstance(obj, (tuple, list)):
        for i, v in enumerate(obj):
            yield from _arrays(v, f"{path}[{i}]")


class Vandal(IDMDriver):
    """Drives like plain IDM, asks for every sense and a vision policy's observation, and tries to
    write into every array it is given: plainly (it must be refused), then by making the array
    writeable again (which may work, but only on its own copy)."""

    def __init__(self, spec: ObservationSpec, attack: bool = True) -> None:
        super().__init__("vandal", IDMParams())
        self.senses = SenseRequest(surroundings=True, entering=True, marks=True, image=True, observation=spec)
        self.attack = attack
        self.refused: list[str] = []
        self.wrote: list[str] = []
        self.arrays: set[str] = set()
        self.found: list[str] = []

    def act(self, perception: Perception) -> np.ndarray:
        if self.attack:
            self.found += find_truth(perception)
            for path, a in _arrays(perception):
                self.arrays.add(path)
                try:
                    a[...] = 0
                except ValueError as err:
                    assert "read-only" in str(err), err
                    self.refused.append(path)
                else:
                    self.wrote.append(path)
                try:
                    a.flags.writeable = True
                    a[...] = 0
                except ValueError:
                    pass
            with pytest.raises(dataclasses.FrozenInstanceError):
                perception.image.rgb = np.zeros(1)
        return super().act(perception)


def _digest(*arrays: np.ndarray) -> str:
    h = hashlib.sha1()
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


def _vandal_config() -> dict:
    cfg = load_config(str(ROOT / "envs/highway-trial.toml"),
                      ["highway.duration=3", "highway.vehicles_count=12", "twin.preroll_s=10"], condition_config("adas"))
    return cfg.to_dict()


def _frames(driver: Vandal, steps: int) -> list[tuple[str, str, str]]:
    """A short trial of ``driver``: per decision, digests of the env's frame (rgb, depth, range)
    before the driver acts, after it acts and at the next step, checked on the way."""
    env = gym.make("dt-highway-v0", config=_vandal_config())
    env.reset(seed=1)
    seat = DriverSeat(env, driver.senses)
    u = seat.env
    driver.reset(1)
    digests = []
    for _ in range(steps):
        frame = u.camera_image()
        assert not frame._ray_norm.flags.writeable  # the renderer's, shared by every frame
        with pytest.raises(ValueError, match="read-only"):
            frame._ray_norm[0, 0] = 0.0
        before = _digest(frame.rgb, frame.depth_m, frame.range_m())
        action = driver.act(seat.perceive())
        assert u.camera_image() is frame
        after = _digest(frame.rgb, frame.depth_m, frame.range_m())
        _, _, terminated, truncated, _ = env.step(action)
        nxt = u.camera_image()
        assert float(nxt.range_m().max()) > 0.0
        digests.append((before, after, _digest(nxt.rgb, nxt.depth_m, nxt.range_m())))
        if terminated or truncated:
            break
    env.close()
    return digests


def test_a_driver_cannot_write_into_the_env_through_its_perception():
    cam = _vandal_config()["camera"]
    spec = _camera_spec(cam["width_px"], cam["height_px"])  # the observation's rgb is the frame's own array
    vandal, reference = Vandal(spec), Vandal(spec, attack=False)
    frames = _frames(vandal, 8)
    assert len(frames) == 8
    assert not vandal.wrote, f"a driver wrote into {sorted(set(vandal.wrote))}"
    assert {"perception.image.rgb", "perception.image.depth_m", "perception.image._ray_norm",
            "perception.observation['rgb']", "perception.observation['depth']"} <= vandal.arrays
    assert len(vandal.refused) == 8 * len(vandal.arrays)  # every array, every decision
    assert not vandal.found, "\n".join(vandal.found[:20])
    assert all(before == after for before, after, _ in frames)  # this step's frame is as it was
    assert frames == _frames(reference, 8)  # and every next frame is the one a harmless driver gets
