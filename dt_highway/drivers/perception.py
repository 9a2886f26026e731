"""What a driver at the wheel perceives: the :class:`Perception` every driver acts on, and the
:class:`SenseRequest` with which a driver says what it looks at.

This is the drivers' side of the ground-truth wall. A driver is never handed the env, its
``info``, the road's vehicles or any truth object (driver types, true boxes, the population):
the env side (:mod:`dt_highway.env.senses`, the one sanctioned read of the simulator's
geometry, and :class:`~dt_highway.env.seat.DriverSeat`) fills a :class:`Perception` with what
a person in the driver's seat could see, and only the parts the driver's request asks for.
A perception holds nothing but plain data and the records below; its arrays (the camera image,
a policy's observation) are read-only copies, so a driver cannot write into the env through them.
Nothing in this package imports the env, the world, the camera's truth, the trial log or the
evaluation, by module or by a name re-exported elsewhere, nor names the attributes and keys that
reach the truth (``tests/test_wall.py`` checks all of it, and walks real perceptions).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from gymnasium import spaces

    from dt_highway.camera.render import CameraImage


@dataclass(frozen=True)
class Seen:
    """A neighbour as the driver sees it: ``gap_m`` bumper to bumper (inf: nobody), its speed.

    :param vehicle_id: which car it is (to recognise it from one moment to the next; -1: nobody)
    :param gap_m: bumper-to-bumper gap [m]
    :param speed_mps: its speed [m/s]
    """

    vehicle_id: int = -1
    gap_m: float = math.inf
    speed_mps: float = 0.0


@dataclass(frozen=True)
class Surroundings:
    """What the driver sees around it at one moment.

    :param t_s: time [s]
    :param speed_mps: own speed [m/s]
    :param lane: own lane index
    :param n_lanes: lanes on the road
    :param ahead: nearest vehicle ahead per lane offset (-1 left, 0 own, +1 right)
    :param behind: nearest vehicle behind per lane offset
    :param x_of: longitudinal offset of every vehicle nearby [m] and its lane offset, by id
    """

    t_s: float
    speed_mps: float
    lane: int
    n_lanes: int
    ahead: dict[int, Seen]
    behind: dict[int, Seen]
    x_of: dict[int, tuple[float, int]]


@dataclass(frozen=True)
class OwnState:
    """The driver's own car, as the dashboard and the road show it.

    :param speed_mps: speed [m/s]
    :param heading_rad: heading [rad]
    :param lane: lane index (0: leftmost; -1: off the lanes)
    :param n_lanes: lanes on the road
    :param crashed: the car has crashed
    """

    speed_mps: float
    heading_rad: float
    lane: int
    n_lanes: int
    crashed: bool


@dataclass(frozen=True)
class Mark:
    """One overlay mark as it is drawn on the screen (:func:`~dt_highway.overlay.draw_overlay`).

    :param box: ``(x1, y1, x2, y2)`` [px] in the camera image
    :param label: its label (``"aggressive driver"``, ``"cutting in from left"``,
        ``"cutting in from right + aggressive driver"``)
    :param confidence: the twin's confidence shown beside it [-], ``None`` when not shown
    :param distance_m: the distance shown beside it [m], ``None`` when not shown

    :attr:`is_cut_in` and :attr:`side` are what a person reads in the label.
    """

    box: tuple[float, float, float, float]
    label: str
    confidence: float | None = None
    distance_m: float | None = None

    @property
    def is_cut_in(self) -> bool:
        """The label warns of a car cutting into the driver's lane ("CUTTING IN")."""
        return self.label.lower().startswith("cutting in")

    @property
    def side(self) -> int:
        """The side the label says a cutting-in car comes from, as a lane offset: ``-1`` left,
        ``+1`` right, ``0`` not said (or not a cut-in warning)."""
        text = self.label.lower()
        if not self.is_cut_in:
            return 0
        return -1 if "from left" in text else 1 if "from right" in text else 0


@dataclass(frozen=True)
class ObservationSpec:
    """What a trained policy was trained on, as its files say (``agents/<name>.json``): the env
    side makes the same observation of the env the policy drives in, or refuses in one line.

    :param policy: the policy's name (for messages)
    :param kind: ``"Kinematics"``, ``"OverlayKinematics"`` or ``"Camera"``
    :param options: the rest of its ``highway.observation`` table
    :param camera: its ``camera`` table (the image size a vision policy takes)
    :param trained: the ``highway`` settings it must drive with (``lanes_count``,
        ``policy_frequency``, ``simulation_frequency``), those its metadata names
    :param space: the observation space of its network
    """

    policy: str
    kind: str | None
    options: Mapping[str, Any] = field(default_factory=dict)
    camera: Mapping[str, Any] = field(default_factory=dict)
    trained: Mapping[str, Any] = field(default_factory=dict)
    space: spaces.Space | None = None


@dataclass(frozen=True)
class SenseRequest:
    """What a driver looks at; the env side computes only these.

    :param surroundings: the cars around (:class:`Surroundings`)
    :param entering: the nearest car ahead whose body reaches into the own lane
    :param marks: the overlay's marks as drawn, and the cars a person sees them on
    :param image: the camera image (RGB, depth, pose)
    :param observation: a trained policy's observation
    """

    surroundings: bool = False
    entering: bool = False
    marks: bool = False
    image: bool = False
    observation: ObservationSpec | None = None


@dataclass(frozen=True)
class Perception:
    """What a driver at the wheel perceives at one decision, and nothing else.

    :param time_s: time [s] (the episode clock)
    :param own: the own car's state
    :param surroundings: the cars around (``None`` unless asked for)
    :param entering: the nearest car ahead within reach whose body reaches into the own lane
        (the leader, or a car drifting in), ``None`` when there is none or it was not asked for
    :param marks: the overlay's marks as drawn (empty in the baseline condition)
    :param cars_under_marks: ids of the cars a person sees a mark on (the car whose outline
        fits the mark's box, right or wrong)
    :param image: the camera image (``None`` unless asked for and the camera is on; its arrays
        are read-only copies)
    :param observation: a trained policy's observation (``None`` for other drivers; read-only copies)
    """

    time_s: float
    own: OwnState
    surroundings: Surroundings | None = None
    entering: Seen | None = None
    marks: tuple[Mark, ...] = ()
    cars_under_marks: frozenset[int] = frozenset()
    image: CameraImage | None = None
    observation: np.ndarray | dict[str, np.ndarray] | None = None
