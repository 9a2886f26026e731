"""The study's conditions and what each changes in the env's configuration.

* ``baseline``: camera and fusion off, nothing is shown to the driver;
* ``adas``: they run and the driver sees the overlay, in ``overlay.mode`` as configured (scenario
  file or ``--set overlay.mode=...``; default ``type``);
* ``adas-type``, ``adas-threat``: the same with ``overlay.mode`` set to ``type`` (every car the twin
  tags aggressive) or ``threat`` (cars the twin predicts will cut into the ego's lane);
* ``sham``: the placebo (``overlay.sham = true``): the overlay of ``overlay.mode`` as configured is
  computed and hidden, and as many marks, alike, are shown on cars drawn at random
  (:class:`~dt_highway.overlay.ShamOverlay`); ``sham-type`` and ``sham-threat`` mirror the mode
  named, so that one study can hold ``adas-type``, ``adas-threat`` and the sham of either.

Every condition drives the ego through the ``Driver`` action. A condition's settings sit above the
scenario file and below ``--set`` (:func:`~dt_highway.config.load_config`); a ``--set overlay.mode=...``
beside a condition that names its mode is refused (:func:`check_mode_override`).

What a participant is told (:func:`display_name`): ``baseline`` or ``adas``; a sham condition is
shown as ``adas`` (the placebo is blind), as are the named modes.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from highway_env.road.lane import StraightLane

from dt_highway.choices import CONDITIONS
from dt_highway.config import ConfigError, DTConfig, check_overrides, deep_merge, load_config, override_value
from dt_highway.twin.cloud import check_models
from dt_highway.twin.tagger import HighwayMap

_MODE = {"adas-type": "type", "adas-threat": "threat", "sham-type": "type", "sham-threat": "threat"}


def check_condition(condition: str) -> str:
    """Check a condition's name.

    :param condition: the name to check
    :return: ``condition`` when it is one of :data:`CONDITIONS`
    :raises ConfigError: one line naming the allowed ones
    """
    if condition not in CONDITIONS:
        raise ConfigError(f"unknown condition {condition!r} (allowed: {', '.join(CONDITIONS)})")
    return condition


def shows_overlay(condition: str) -> bool:
    """Whether the driver sees an overlay (every condition but ``baseline``).

    :param condition: one of :data:`CONDITIONS`
    :return: ``False`` for ``baseline``, else ``True``
    :raises ConfigError: on an unknown condition
    """
    return check_condition(condition) != "baseline"


def is_sham(condition: str) -> bool:
    """Whether a condition is the placebo.

    :param condition: one of :data:`CONDITIONS`
    :return: whether it is ``sham``, ``sham-type`` or ``sham-threat``
    :raises ConfigError: on an unknown condition
    """
    return check_condition(condition).startswith("sham")


def display_name(condition: str) -> str:
    """What a participant is told the condition is: ``baseline`` or ``adas`` (module docstring).

    :param condition: one of :data:`CONDITIONS`
    :return: ``baseline`` or ``adas``
    :raises ConfigError: on an unknown condition
    """
    return "adas" if shows_overlay(condition) else "baseline"


def condition_config(condition: str) -> dict[str, Any]:
    """What a condition changes in the configuration.

    :param condition: one of :data:`CONDITIONS`
    :return: a partial configuration tree
    :raises ConfigError: on an unknown condition
    """
    on = shows_overlay(condition)
    out: dict[str, Any] = {"highway": {"action": {"type": "Driver"}}, "camera": {"enabled": on}, "fusion": {"enabled": on}}
    overlay: dict[str, Any] = {}
    if condition in _MODE:
        overlay["mode"] = _MODE[condition]
    if is_sham(condition):
        overlay["sham"] = True
    if overlay:
        out["overlay"] = overlay
    return out


def driver_config(scenario: str | None, overrides: Sequence[str], condition: str,
                  driver_overrides: Mapping[str, Any]) -> DTConfig:
    """The configuration a driver's trial or episode runs with: the scenario file, then the condition's
    settings, then the driver's own (``Driver.config_overrides()``), then ``overrides``; checked that the
    ego takes the drivers' action (:func:`check_driver_action`).

    :param scenario: scenario file (``None``: the defaults)
    :param overrides: ``dotted.key=value`` strings (``--set``)
    :param condition: one of :data:`CONDITIONS`
    :param driver_overrides: what the driver adds to the configuration
    :return: the checked configuration
    :raises ConfigError: one line, on a bad scenario, condition or override, or a twin model file that cannot be
        read (:func:`~dt_highway.twin.cloud.check_models`)
    """
    cfg = load_config(scenario, check_overrides(overrides), deep_merge(condition_config(condition), dict(driver_overrides)))
    check_driver_action(cfg)
    check_models(cfg.twin, HighwayMap(StraightLane.DEFAULT_WIDTH, cfg.highway.lanes_count))
    return cfg


def check_mode_override(conditions: Sequence[str], overrides: Sequence[str]) -> None:
    """Refuse a ``--set overlay.mode=...`` beside a condition that names its mode (``adas-type``,
    ``sham-threat``...): the ``--set`` would win, and the condition's trials would be labelled with a
    mode they did not show.

    :param conditions: the study's or session's conditions
    :param overrides: its ``dotted.key=value`` strings
    :raises ConfigError: one line naming the condition
    """
    named = [c for c in conditions if c in _MODE]
    if named and any(override_value(str(o), "overlay.mode") is not None for o in overrides):
        raise ConfigError(f"--set overlay.mode would override the mode {named[0]} names: drop it (adas and sham "
                          "take overlay.mode; the named conditions set their own)")


def check_driver_action(config: DTConfig) -> None:
    """Refuse, in one line, a configuration whose ego does not take the ``Driver`` action: every driver
    (scripted, a trained policy through its menu, the keyboard) answers with ``[acceleration, lane
    request]``, and each condition sets that action, so only a ``--set highway.action.type=...`` can
    change it.

    :param config: the configuration of a driver's trial or episode
    :raises ConfigError: naming the action type found
    """
    kind = config.highway.action.get("type")
    if kind != "Driver":
        raise ConfigError(f"highway.action.type = {kind}: drivers act through the Driver action ([acceleration, "
                          "lane request]), which every condition sets; leave highway.action.type out of --set")
