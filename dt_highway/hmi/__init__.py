"""The human-machine interface: keyboard driving, key scripts, the driving window."""

from dt_highway.hmi.keys import (
    KEYS,
    KeyEvent,
    KeyScript,
    KeyScriptError,
    Pedals,
    PedalSettings,
    Steering,
)

__all__ = ["KEYS", "KeyEvent", "KeyScript", "KeyScriptError", "PedalSettings", "Pedals", "Steering"]
