"""The human-like driver under a threat cue ("CUTTING IN"), on hand-built perceptions: it reads the
label, reacts sooner (0.6 s instead of 1.0 s, or 0.7 s under a driver-type mark) and opens the gap
to the car that cuts in."""

import math

import numpy as np
import pytest

from dt_highway.drivers import HumanDriver
from dt_highway.drivers.perception import Mark, OwnState, Perception, Seen, Surroundings

DT = 0.05
V = 25.0
LEADER, CUTTER = 3, 7


def _perception(t, leader_speed=V, cutter=(-5.0, -1), cue=None, leader_gap_m=40.0):
    """The driver in the middle of three lanes at 25 m/s; its leader ``leader_gap_m`` ahead; car 7 in the
    lane to its left at ``cutter`` (longitudinal offset [m], lane offset); ``cue``: the label on
    car 7 (``None``: no overlay)."""
    dx, off = cutter
    ahead = {-1: Seen(), 0: Seen(LEADER, leader_gap_m, leader_speed) if math.isfinite(leader_gap_m) else Seen(), 1: Seen()}
    behind = {-1: Seen(), 0: Seen(), 1: Seen()}
    side = ahead if dx > 0 else behind
    side[off] = Seen(CUTTER, abs(dx) - 5.0, V)
    s = Surroundings(t, V, 1, 3, ahead, behind, {LEADER: (leader_gap_m + 5.0, 0), CUTTER: (dx, off)})
    marks = () if cue is None else (Mark((100.0, 100.0, 140.0, 130.0), cue, 0.8, abs(dx)),)
    return Perception(t, OwnState(V, 0.0, 1, 3, False), s, None, marks, frozenset({CUTTER}) if cue else frozenset())


def _accels(cue, brake_at_s=None, n=120, cutter=(-5.0, -1), leader_gap_m=40.0):
    d = HumanDriver("h")
    d.reset(4)
    out = []
    for k in range(n):
        t = k * DT
        lead = 15.0 if brake_at_s is not None and t >= brake_at_s - 1e-9 else V
        out.append(float(d.act(_perception(t, lead, cutter, cue, leader_gap_m))[0]))
    return np.array(out), d


@pytest.mark.parametrize(("cue", "reaction_s"), [(None, 1.0), ("aggressive driver", 0.7), ("cutting in from left", 0.6)])
def test_the_reaction_time_is_shorter_under_a_threat_cue(cue, reaction_s):
    """The leader slows from 25 to 15 m/s at t = 2 s; the driver's pedal first differs from the same
    run without it one reaction time later (same seed: same estimation errors)."""
    calm, d = _accels(cue)
    event, _ = _accels(cue, brake_at_s=2.0)
    first = np.flatnonzero(calm != event)[0] * DT
    assert first - 2.0 == pytest.approx(reaction_s, abs=DT / 2)
    assert d.reaction_s == pytest.approx(reaction_s)
    assert event[-1] < calm[-1]  # and it brakes for it


def test_under_a_threat_cue_the_driver_covers_the_brake_and_opens_the_gap():
    """Car 7 20 m ahead in the next lane at the same speed: as a shadow leader (gap 15 m) IDM asks
    for far more than comfortable braking; a driver-type mark lifts off only (-0.5 m/s^2), a threat
    cue brakes comfortably (b = 1.67 m/s^2); without a mark the driver keeps about its speed (its
    leader 80 m ahead)."""
    ahead = (20.0, -1)
    none, _ = _accels(None, n=10, cutter=ahead, leader_gap_m=80.0)
    typ, _ = _accels("aggressive driver", n=10, cutter=ahead, leader_gap_m=80.0)
    threat, _ = _accels("cutting in from left", n=10, cutter=ahead, leader_gap_m=80.0)
    assert none[-1] > -0.5
    assert typ[-1] == pytest.approx(-0.5)
    assert threat[-1] == pytest.approx(-1.67)
    assert HumanDriver.threat_cars(_perception(0.0, cutter=ahead, cue="cutting in from left"),
                                   _perception(0.0, cutter=ahead).surroundings) == {CUTTER}
    # the label names the other side: the person looks right, sees no marked car there
    assert HumanDriver.threat_cars(_perception(0.0, cutter=ahead, cue="cutting in from right"),
                                   _perception(0.0, cutter=ahead).surroundings) == set()
    # free road, the marked car beside and just behind: warned of its type the driver still speeds up
    # a little (v = 25 < 0.95 v0 = 25.65 m/s); warned of its cut-in, the foot is off the throttle
    typ, _ = _accels("aggressive driver", n=10, leader_gap_m=math.inf)
    threat, _ = _accels("cutting in from left", n=10, leader_gap_m=math.inf)
    assert typ.min() > 0.05 and threat.max() == 0.0


def test_the_mark_reads_its_cue_and_side_from_its_label():
    assert Mark((0, 0, 1, 1), "cutting in from left + aggressive driver").side == -1
    assert Mark((0, 0, 1, 1), "cutting in from right").side == 1
    assert Mark((0, 0, 1, 1), "cutting in").is_cut_in and Mark((0, 0, 1, 1), "cutting in").side == 0
    assert not Mark((0, 0, 1, 1), "aggressive driver").is_cut_in and Mark((0, 0, 1, 1), "aggressive driver").side == 0
