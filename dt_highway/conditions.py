"""The study's conditions and what each changes in the env's configuration.

``baseline``: camera and fusion off, nothing is shown to the driver; ``adas``: they run and the
driver sees the overlay. Every condition drives the ego through the ``Driver`` action.
"""

from __future__ import annotations

from typing import Any

from dt_highway.config import ConfigError

CONDITIONS = ("baseline", "adas")


def condition_config(condition: str) -> dict[str, Any]:
    """What a condition changes in the configuration.

    :param condition: one of :data:`CONDITIONS`
    :return: a partial configuration tree
    :raises ConfigError: on an unknown condition
    """
    if condition not in CONDITIONS:
        raise ConfigError(f"unknown condition {condition!r} (allowed: {', '.join(CONDITIONS)})")
    on = condition == "adas"
    return {"highway": {"action": {"type": "Driver"}}, "camera": {"enabled": on}, "fusion": {"enabled": on}}
