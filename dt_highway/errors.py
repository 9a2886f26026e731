"""The error a user's mistake raises, in a module that imports nothing, so that the command line can report one
before it imports the simulation (:mod:`dt_highway.config` re-exports it, and most code imports it from there)."""

from __future__ import annotations


class ConfigError(ValueError):
    """A configuration mistake, described in one line (dotted key and what is allowed)."""
