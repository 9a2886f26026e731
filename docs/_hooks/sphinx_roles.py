"""A griffe extension for the API reference: the docstrings' Sphinx roles as Markdown.

The package's docstrings follow stable-baselines3 (``:param x:``, ``:return:``, parsed by
mkdocstrings' ``sphinx`` style) and name other objects with Sphinx roles
(``:func:`~dt_highway.metrics.ttc2d.contact_axis```, ``:class:`SafetyMonitor```). Markdown has no
roles: each becomes a cross-reference ``[`name`][full.path]`` when the target is an object the API
pages render (public, documented, inside ``dt_highway``), else plain code ``name``. A role is never
left unresolved, so ``mkdocs build --strict`` does not fail on a name it cannot find.
"""

from __future__ import annotations

import re
from typing import Any

import griffe

ROLE = re.compile(r":(?:py:)?(?:func|class|meth|mod|data|attr|exc|obj|const|type):`(~?)([\w.]+?)(\(\))?`")


def _lookup(collection: Any, path: str) -> Any:
    try:
        obj = collection.get_member(path)
    except (KeyError, ValueError, AttributeError, griffe.AliasResolutionError, griffe.CyclicAliasError):
        return None
    return obj


def _rendered(obj: Any) -> bool:
    """Whether the API pages render ``obj``: inside dt_highway, no private part, a docstring on it
    and on every class or module above it (the pages show documented objects only)."""
    if obj.is_alias:
        try:
            obj = obj.final_target
        except (griffe.AliasResolutionError, griffe.CyclicAliasError):
            return False
    if not obj.path.startswith("dt_highway") or obj.path.startswith("dt_highway._"):
        return False
    node = obj
    while node is not None and node.path != "dt_highway":
        if any(part.startswith("_") and not part.startswith("__") for part in node.path.split(".")):
            return False
        if not node.docstring:
            return False
        node = node.parent
    return True


def _resolve(obj: Any, name: str) -> str | None:
    """The full path of ``name`` as written in ``obj``'s docstring, or None."""
    collection = obj.modules_collection
    candidates = [name] if name.startswith("dt_highway") else []
    scope = obj
    while scope is not None:
        candidates.append(f"{scope.path}.{name}")
        scope = scope.parent
    for path in candidates:
        target = _lookup(collection, path)
        if target is None:
            continue
        if target.is_alias:
            try:
                target = target.final_target
            except (griffe.AliasResolutionError, griffe.CyclicAliasError):
                return None
        return target.path if _rendered(target) else None
    return None


def _convert(obj: Any, text: str) -> str:
    def repl(match: re.Match[str]) -> str:
        tilde, name, call = match.group(1), match.group(2), match.group(3) or ""
        shown = (name.rsplit(".", 1)[-1] if tilde else name) + call
        path = _resolve(obj, name)
        return f"[`{shown}`][{path}]" if path else f"`{shown}`"

    return ROLE.sub(repl, text)


def _escape_brackets(text: str) -> str:
    """``[0, 1] [-]`` (a range, then a unit) is a Markdown reference link: escape the second
    bracket, outside code spans."""
    parts = text.split("`")
    for i in range(0, len(parts), 2):
        parts[i] = parts[i].replace("] [", "] \\[")
    return "`".join(parts)


def _nest_lists(text: str) -> str:
    """A sub-list indented by 2 spaces under a list item (reST and CommonMark read it as nested)
    is indented by 4, as Python-Markdown needs."""
    out, in_list = [], False
    for line in text.split("\n"):
        if re.match(r"(?:[-*]|\d+\.) ", line):
            in_list = True
        elif line and not line.startswith(" "):
            in_list = False
        if in_list and re.match(r"  [-*] ", line):
            line = "  " + line
        out.append(line)
    return "\n".join(out)


def _fields_as_attributes(cls: Any) -> None:
    """``:param x:`` on a class for a field that is not a parameter of its constructor (a
    NamedTuple's or a pydantic model's fields, which griffe cannot see in a signature) is
    ``:ivar x:`` (its Attributes section)."""
    try:
        params = {p.name for p in cls.parameters}
    except Exception:  # noqa: BLE001 - griffe cannot build a signature: use none
        params = set()

    def repl(match: re.Match[str]) -> str:
        name = match.group(1)
        if name not in params and name in cls.members:
            return f":ivar {name}:"
        return match.group(0)

    cls.docstring.value = re.sub(r":param (\w+):", repl, cls.docstring.value)


class SphinxRoles(griffe.Extension):
    """Rewrite Sphinx roles in every docstring of a loaded package (module docstring)."""

    def on_package(self, *, pkg: griffe.Module, **kwargs: Any) -> None:
        self._walk(pkg, set())

    def _walk(self, obj: Any, seen: set[str]) -> None:
        if obj.path in seen:
            return
        seen.add(obj.path)
        if obj.docstring is not None:
            obj.docstring.value = _nest_lists(_escape_brackets(_convert(obj, obj.docstring.value)))
            if obj.is_class:
                _fields_as_attributes(obj)
        for member in obj.members.values():
            if not member.is_alias:
                self._walk(member, seen)
