"""The vocabulary of driver labels, shared by the simulator's truth and the twin's verdict.

The world gives each driver a true type (:func:`dt_highway.world.traffic.driver_type`, for
evaluation only) and the cloud twin tags each driver from its GNSS history
(:mod:`dt_highway.twin.tagger`). Both speak these words, so that evaluation can compare a
tag with the truth; importing them tells nothing about any driver.
"""

from __future__ import annotations

NORMAL = "normal"
"""A driver who changes lanes gently"""
AGGRESSIVE = "aggressive"
"""A driver who makes sudden lane changes and cuts in"""
LABELS = (NORMAL, AGGRESSIVE)
"""Every label, in this order"""
