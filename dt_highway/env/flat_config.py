"""``env.unwrapped.config``: highway-env's flat configuration dict, kept in step with the typed tree.

highway-env documents configuring an env by editing this dict before a reset
(``env.unwrapped.config["lanes_count"] = 2; env.reset()``). In ``dt-highway-v0`` the
configuration is the validated tree ``env.unwrapped.dt_config`` (:mod:`dt_highway.config`)
and the dict is derived from its ``highway`` section, so an edit of the dict is an edit of the
tree: :class:`FlatConfig` validates it and applies it there (through
:func:`~dt_highway.config.set_highway_keys`, the same validation as ``configure()``), then
shows the tree's new values. An unknown key or a bad value raises one
:class:`~dt_highway.config.ConfigError` line naming ``highway.<key>`` at the assignment.
Edits inside a nested table (``config["observation"]["vehicles_count"] = 5``) bypass the
dict's methods; the env applies them the same way at its next ``reset()``.
"""

from __future__ import annotations

import copy
from collections.abc import Iterable, Mapping
from typing import Any, Protocol

from dt_highway.config import ConfigError

_MISSING = object()


class ConfigOwner(Protocol):
    """The env a :class:`FlatConfig` belongs to."""

    def edit_highway_config(self, values: dict[str, Any]) -> None:
        """Validate highway-env keys, apply them to the tree and refresh the flat dict.

        :param values: highway-env keys and their new values
        :raises ConfigError: naming the key
        """


class FlatConfig(dict[str, Any]):
    """highway-env's flat configuration dict whose writes go through the typed tree (module docstring).

    Reads are a plain dict's. A write that does not change a value is let through (highway-env
    writes derived values such as ``offscreen_rendering``); a copy (``copy.deepcopy``,
    ``dict(...)``, pickling) is a plain dict.

    :param owner: the env
    :param items: the flat configuration
    """

    def __init__(self, owner: ConfigOwner, items: Mapping[str, Any]) -> None:
        super().__init__(items)
        self._owner = owner

    def refresh(self, items: Mapping[str, Any]) -> None:
        """Show new values (the owner's tree changed), keeping this dict's identity.

        :param items: the new flat configuration
        """
        super().clear()
        super().update(items)

    def _edit(self, values: dict[str, Any]) -> None:
        changed = {k: v for k, v in values.items() if self.get(k, _MISSING) is _MISSING or not _same(self[k], v)}
        if changed:
            self._owner.edit_highway_config(changed)

    def __setitem__(self, key: str, value: Any) -> None:
        self._edit({key: value})

    def update(self, *args: Any, **kwargs: Any) -> None:
        """Validate and apply the keys given, as one edit.

        :param args: at most one mapping or iterable of ``(key, value)`` pairs, as ``dict.update`` takes
        :param kwargs: more keys and their new values
        """
        self._edit(dict(*args, **kwargs))

    def __ior__(self, other: Any) -> FlatConfig:  # type: ignore[override,misc]  # dict's |= returns Self
        self._edit(dict(other))
        return self

    def setdefault(self, key: str, default: Any = None) -> Any:
        """Set ``key`` (validated) if it has no value.

        :param key: a highway-env key
        :param default: the value to set when ``key`` has none
        :return: the value of ``key`` afterwards
        """
        if key not in self:
            self[key] = default
        return self[key]

    def _refuse(self, key: object) -> ConfigError:
        return ConfigError(f"env.unwrapped.config[{key!r}] cannot be removed (every key has a value): set it instead")

    def __delitem__(self, key: str) -> None:
        raise self._refuse(key)

    def pop(self, key: str, *default: Any) -> Any:
        """Refused: every key has a value (a key the configuration does not have gives ``default``).

        :param key: a highway-env key
        :param default: at most one value, returned for a key the configuration does not have
        :return: ``default``, for a key the configuration does not have
        :raises ConfigError: for a key it has, or with no ``default``
        """
        if key not in self and default:
            return default[0]
        raise self._refuse(key)

    def popitem(self) -> tuple[str, Any]:
        """Refused: every key has a value.

        :return: nothing: it always raises
        :raises ConfigError: always
        """
        raise self._refuse(next(iter(self), "?"))

    def clear(self) -> None:
        """Refused: every key has a value."""
        raise self._refuse("...")

    def __reduce__(self) -> tuple[Any, ...]:
        return dict, (dict(self),)

    def __deepcopy__(self, memo: dict[int, Any]) -> dict[str, Any]:
        items = copy.deepcopy(dict(self), memo)
        owner = memo.get(id(self._owner))  # the env is being copied (highway-env's planners): stay live
        return FlatConfig(owner, items) if owner is not None else items


def _same(old: Any, new: Any) -> bool:
    """Whether a write leaves a value as it is (a list written over the tree's tuple counts as the same)."""
    try:
        if isinstance(old, tuple) and isinstance(new, Iterable) and not isinstance(new, (str, bytes, dict)):
            return old == tuple(new)
        return bool(old == new) and type(old) is type(new)
    except (TypeError, ValueError):  # an array or an odd object: let validation decide
        return False
