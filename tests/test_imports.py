"""Import rules of the package, checked on the source (AST) of every module under ``dt_highway/``.

1. **No import cycles** among dt_highway modules: the module graph, with an edge for every
   import statement (module level and function level alike), has no strongly connected
   component of more than one module. ``import a.b.c`` and ``from a.b import c`` are edges to
   the longest prefix of ``a.b.c`` that is a module of the package (``c`` may be a submodule or
   a name defined in ``a.b``); relative imports are resolved first. Imports under
   ``if TYPE_CHECKING:`` are not edges: they never run. Python also runs the parent packages'
   ``__init__`` on ``import a.b.c``; those implicit edges are **not** added (every package
   that re-exports its submodules' names would otherwise be in a cycle with them), so a cycle
   that closes only through a package's ``__init__`` is not reported.
2. **Function-level imports are lazy on purpose**: every import inside a function carries a
   trailing comment ``# lazy: <reason>``, and imports something worth deferring: an optional
   extra (:data:`OPTIONAL`), a heavy dependency (:data:`HEAVY`), or a dt_highway module whose
   module-level imports load one of those beyond what ``import dt_highway`` already loads (the
   CLI's per-command imports, so that ``dt-highway --help`` stays fast). Standard-library and
   light imports belong at the top of the module; a function-level import never dodges a cycle
   (rule 1 counts it).
"""

from __future__ import annotations

import ast
import io
import re
import tokenize
from dataclasses import dataclass, field
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "dt_highway"

OPTIONAL = ("ray", "pyarrow", "tensorboard")
"""Optional extras (``pip install dt-highway[ray|parquet|tensorboard]``)"""
HEAVY = ("torch", "stable_baselines3", "matplotlib", "jinja2", "pycocotools", "cv2", "scipy.stats", "scipy.optimize",
         "highway_env", "numba", "pandas", "pydantic")
"""Dependencies whose import takes long enough to defer (after numpy and gymnasium, which ``import dt_highway``
loads): torch, stable-baselines3 ~1.3 s; highway-env 0.7-1.3 s (matplotlib with it); scipy.stats 0.35-1.1 s,
scipy.optimize ~0.5 s; pandas ~0.4 s; numba ~0.2 s; pydantic with the config models ~0.25 s"""
LAZY_COMMENT = re.compile(r"#\s*lazy:\s*\S")


@dataclass
class Import:
    """One import statement of a module.

    :param names: the dotted names it imports (``from a import b, c`` gives ``a.b`` and ``a.c``)
    :param line: first line
    :param end_line: last line
    :param in_function: inside a function body
    """

    names: list[str]
    line: int
    end_line: int
    in_function: bool


@dataclass
class Module:
    name: str
    path: str
    imports: list[Import] = field(default_factory=list)
    comments: dict[int, str] = field(default_factory=dict)


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"
    )


def _imports(tree: ast.Module, module: str, is_package: bool) -> list[Import]:
    """Every import statement that can run (``if TYPE_CHECKING:`` bodies left out), with its names resolved."""
    package = module if is_package else module.rpartition(".")[0]
    found: list[Import] = []

    def visit(node: ast.AST, in_function: bool) -> None:
        if isinstance(node, ast.If) and _is_type_checking(node.test):
            for child in node.orelse:
                visit(child, in_function)
            return
        if isinstance(node, ast.Import):
            found.append(Import([a.name for a in node.names], node.lineno, node.end_lineno or node.lineno, in_function))
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                parts = parts[: len(parts) - node.level + 1]
                base = ".".join(parts + ([base] if base else []))
            names = [f"{base}.{a.name}" for a in node.names if a.name != "*"] or [base]
            found.append(Import(names, node.lineno, node.end_lineno or node.lineno, in_function))
        inner = in_function or isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
        for child in ast.iter_child_nodes(node):
            visit(child, inner)

    visit(tree, False)
    return found


def _comments(source: str) -> dict[int, str]:
    """The comment on each line that has one."""
    out: dict[int, str] = {}
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            out[tok.start[0]] = tok.string
    return out


def load_package(root: Path, package: str = PACKAGE) -> dict[str, Module]:
    """Every module of the package under ``root / package``, with its imports and comments."""
    modules: dict[str, Module] = {}
    for path in sorted((root / package).rglob("*.py")):
        parts = list(path.relative_to(root).with_suffix("").parts)
        is_package = parts[-1] == "__init__"
        if is_package:
            parts = parts[:-1]
        name = ".".join(parts)
        source = path.read_text(encoding="utf-8")
        imports = _imports(ast.parse(source, str(path)), name, is_package)
        modules[name] = Module(name, str(path.relative_to(root)), imports, _comments(source))
    return modules


def _target(name: str, modules: dict[str, Module]) -> str | None:
    """The longest prefix of a dotted name that is a module of the package."""
    while name and name not in modules:
        name = name.rpartition(".")[0]
    return name or None


def graph(modules: dict[str, Module]) -> dict[str, set[str]]:
    """The import graph among the package's modules (self-imports left out)."""
    edges: dict[str, set[str]] = {m: set() for m in modules}
    for m, mod in modules.items():
        for imp in mod.imports:
            for name in imp.names:
                t = _target(name, modules)
                if t is not None and t != m:
                    edges[m].add(t)
    return edges


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    for start in sorted(edges):
        if start in index:
            continue
        work = [(start, iter(sorted(edges[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            v, children = work[-1]
            for w in children:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(edges[w]))))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    component = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        component.append(w)
                        if w == v:
                            break
                    if len(component) > 1:
                        found.append(sorted(component))
    return found


def _deferrable(names: set[str] | list[str]) -> set[str]:
    """The optional and heavy dependencies among dotted names."""
    return {h for n in names for h in OPTIONAL + HEAVY if n == h or n.startswith(h + ".")}


def _loads(module: str, modules: dict[str, Module]) -> set[str]:
    """Every name that importing ``module`` imports at module level, through the package's modules
    (their parent packages' ``__init__`` included, as Python runs them)."""
    seen: set[str] = set()
    names: set[str] = set()
    todo = [module]
    while todo:
        m = todo.pop()
        if m in seen:
            continue
        seen.add(m)
        parent = m.rpartition(".")[0]
        if parent in modules:
            todo.append(parent)
        for imp in modules[m].imports:
            if imp.in_function:
                continue
            for name in imp.names:
                names.add(name)
                t = _target(name, modules)
                if t is not None:
                    todo.append(t)
    return names


def lazy_import_problems(modules: dict[str, Module], package: str = PACKAGE) -> list[str]:
    """Function-level imports without a ``# lazy:`` reason, or of something light."""
    already = _deferrable(_loads(package, modules))
    problems = []
    for mod in sorted(modules.values(), key=lambda mod: mod.path):
        for imp in mod.imports:
            if not imp.in_function:
                continue
            where = f"{mod.path}:{imp.line}"
            lines = range(imp.line, imp.end_line + 1)
            if not any(LAZY_COMMENT.match(mod.comments.get(k, "")) for k in lines):
                problems.append(f"{where}: import of {imp.names[-1]} in a function without a "
                                "'# lazy: <reason>' comment")
            target = next((t for t in (_target(n, modules) for n in imp.names) if t is not None), None)
            adds = _deferrable(_loads(target, modules) if target is not None else imp.names)
            if not adds - already:
                problems.append(f"{where}: {imp.names[-1]} is light (stdlib, or loaded by 'import {package}' "
                                f"already): import it at the top of the module")
    return problems


# ----------------------------------------------------------------------------- the rules
@pytest.fixture(scope="module")
def package() -> dict[str, Module]:
    return load_package(ROOT)


def test_no_import_cycles(package: dict[str, Module]) -> None:
    found = cycles(graph(package))
    assert not found, "import cycles among dt_highway modules (module and function level):\n" + "\n".join(
        " <-> ".join(c) for c in found)


def test_function_level_imports_are_lazy_and_say_why(package: dict[str, Module]) -> None:
    problems = lazy_import_problems(package)
    assert not problems, "function-level imports:\n" + "\n".join(problems)


# ----------------------------------------------------------------------------- the checks themselves
def _write(root: Path, files: dict[str, str]) -> dict[str, Module]:
    for rel, text in files.items():
        path = root / "pkg" / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return load_package(root, "pkg")


def test_a_cycle_is_found_also_through_a_function_and_not_through_type_checking(tmp_path: Path) -> None:
    mods = _write(tmp_path, {
        "__init__.py": "",
        "a.py": "from pkg.b import f\n",
        "b.py": "def f():\n    from pkg import a  # lazy: torch\n",
        "c.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from pkg.a import x\n",
        "d.py": "from . import c\n",
    })
    assert cycles(graph(mods)) == [["pkg.a", "pkg.b"]]
    assert graph(mods)["pkg.c"] == set() and graph(mods)["pkg.d"] == {"pkg.c"}


def test_lazy_imports_need_a_reason_and_a_heavy_target(tmp_path: Path) -> None:
    mods = _write(tmp_path, {
        "__init__.py": "import cv2\n",
        "heavy.py": "import torch\n",
        "light.py": "import json\n",
        "user.py": (
            "def ok():\n    import ray  # lazy: optional extra\n"
            "def ok_module():\n    from pkg.heavy import x  # lazy: torch\n"
            "def no_reason():\n    import torch  # torch\n"
            "def stdlib():\n    import json  # lazy: why not\n"
            "def light_module():\n    from pkg import light  # lazy: ?\n"
            "def loaded():\n    import cv2  # lazy: already loaded by the package\n"
        ),
    })
    problems = lazy_import_problems(mods, "pkg")
    assert [p.split(":")[1] for p in problems] == ["6", "8", "10", "12"], problems
