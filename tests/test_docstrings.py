"""The house docstring rule, checked on the source (stable-baselines3 style, DESIGN.md "Conventions"): every public
function and method starts with a summary line, documents each argument with a ``:param name:`` line and what it
returns with ``:return:``.

ruff's pydocstyle rules check that a docstring exists; its argument rule (D417) knows only the Google style, so the
sphinx-style lines are checked here, on the syntax tree (nothing is imported)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "dt_highway"


def _decorator_names(node: ast.FunctionDef | ast.AsyncFunctionDef) -> set[str]:
    names = set()
    for d in node.decorator_list:
        if isinstance(d, ast.Name):
            names.add(d.id)
        elif isinstance(d, ast.Attribute):
            names.add(d.attr)
    return names


def _returns_something(node: ast.FunctionDef | ast.AsyncFunctionDef) -> bool:
    r = node.returns
    return r is not None and not (isinstance(r, ast.Constant) and r.value is None) and node.name != "__init__"


def missing_lines(source: str) -> list[str]:
    """The public functions of one module whose docstring lacks a ``:param:`` line or ``:return:``.

    :param source: the module's source text
    :return: one ``line name: what is missing`` entry per offending function
    """
    out: list[str] = []

    def visit(parent: ast.AST, owner: str, owner_doc: str) -> None:
        for node in ast.iter_child_nodes(parent):
            if isinstance(node, ast.ClassDef) and not node.name.startswith("_"):
                class_doc = ast.get_docstring(node) or ""
                if class_doc.lstrip().startswith(":"):
                    out.append(f"{node.lineno} {owner}{node.name}: a summary line before the fields")
                visit(node, node.name + ".", class_doc)
            if not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                continue
            if node.name.startswith("_") and node.name != "__init__":
                continue
            decorators = _decorator_names(node)
            if decorators & {"overload", "setter", "deleter"}:
                continue
            doc = ast.get_docstring(node) or ""
            if node.name == "__init__":
                doc += owner_doc  # mkdocstrings merges __init__ into the class: its arguments are in either
            a = node.args
            names = [x.arg for x in a.posonlyargs + a.args + a.kwonlyargs] + [x.arg for x in (a.vararg, a.kwarg) if x]
            lacking = [f":param {n}:" for n in names if n not in ("self", "cls") and f":param {n}:" not in doc]
            if _returns_something(node) and not decorators & {"property", "cached_property"} and ":return:" not in doc:
                lacking.append(":return:")
            if doc.lstrip().startswith(":") and node.name != "__init__":
                lacking.insert(0, "a summary line before the fields")
            if lacking:
                out.append(f"{node.lineno} {owner}{node.name}: {' '.join(lacking)}")

    visit(ast.parse(source), "", "")
    return out


def _public_modules() -> list[Path]:
    return sorted(p for p in PACKAGE.rglob("*.py")
                  if not any(part.startswith("_") and part != "__init__.py" for part in p.relative_to(PACKAGE).parts))


def test_the_checker_finds_a_missing_param_and_return() -> None:
    src = '''
def documented(a: int, *, b: float = 1.0) -> int:
    """Fine.

    :param a: one
    :param b: two [m]
    :return: three
    """

def half(a: int, b: int) -> int:
    """Lacks b and the return.

    :param a: one
    """

def fields_only(a: int) -> None:
    """:param a: one"""

class Thing:
    """A class whose __init__ is documented here.

    :param x: the x
    """

    def __init__(self, x: int, y: int) -> None:
        pass

    @property
    def size(self) -> int:
        """A property needs no return line."""
        return 1

    def _private(self, z: int) -> int:
        return z
'''
    assert missing_lines(src) == ["10 half: :param b: :return:", "16 fields_only: a summary line before the fields",
                                  "25 Thing.__init__: :param y:"]


@pytest.mark.parametrize("path", _public_modules(), ids=lambda p: str(p.relative_to(PACKAGE)))
def test_every_public_function_documents_its_arguments_and_return(path: Path) -> None:
    assert missing_lines(path.read_text(encoding="utf-8")) == []
