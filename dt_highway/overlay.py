"""The AR overlay: which cars are marked, how the marks are kept steady, bounded and drawn.

Which cars (:func:`select_items`, ``overlay.mode``): ``type`` marks every car the twin tags
aggressive ("AGGRESSIVE DRIVER"); ``threat`` marks every car whose lane-change intention at
``overlay.horizon_s`` (:meth:`~dt_highway.twin.cloud.TwinVehicleView.intent`; the configuration takes
one of the twin's horizons only) has ``p_change >= overlay.threshold`` (by default the twin's operating point,
``twin.intention.operating_horizon_s`` and ``twin.intention.threshold``) and targets the ego's lane ("CUTTING IN" with the side
it comes from, left or right of the ego's lane centre by its last fix; "+ aggressive driver" when the
twin also tags it; the percentage shown is ``p_change``); ``both`` marks either (a car that is both
gets the threat cue). Only cars the fusion placed in the image within ``overlay.max_range_m``.

The fusion places the cars on camera boxes frame by frame; a far or partly hidden car is placed in
some frames and not in others. Shown as it is, its mark blinks, and a blinking mark is both hard to
read and a different warning from a steady one. :class:`OverlayStabilizer` turns the per-frame items
into the marks a driver sees:

* a vehicle's mark appears once the fusion has placed it in ``onset_frames`` consecutive
  frames (one stray frame does not flash a mark);
* it stays on its car while the fusion keeps placing it (the fusion's tracking keeps the
  vehicle on its track, so the box follows the car);
* when it stops qualifying (its tag or intention no longer marks it, or the fusion stops placing
  it), the mark is held for ``hold_s``: on the car's box while the fusion still places it, else at
  the box predicted from its last movement (the box's velocity in the image), then removed. A
  prediction is trusted only while its size stays within half and twice the last box's
  (:data:`PREDICTION_SIZE_RANGE`): a car pulling away or going out of the view shrinks or grows
  faster than linearly, and a box moved on at its last velocity would invert or float into the
  sky; the mark then ends early.

Clutter (:func:`bound_marks`): at most ``overlay.max_marks`` of the steady marks are shown, threats
first, then nearest first (by the distance the fusion measured); in ``type`` and ``threat`` all marks
are of one kind, so it is nearest first. Labels never stack into towers (:func:`label_layout`).

The placebo (:class:`ShamOverlay`, ``overlay.sham``): the real overlay is computed and hidden, and as
many marks, with the same labels, are shown on cars drawn at random among the placed ones.

Nothing here reads ground truth: input is the fusion's placements and the twin's view only.

:func:`draw_overlay` draws the marks on an RGB frame (a box and a label a driver reads at a
glance: "AGGRESSIVE DRIVER" or ">> CUTTING IN", the twin's confidence and the distance); the driving
window and the frame export both use it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, NamedTuple

import cv2
import numpy as np

from dt_highway.config import OverlayConfig, validate_section
from dt_highway.labels import AGGRESSIVE

if TYPE_CHECKING:
    from dt_highway.perception.fusion import Placement
    from dt_highway.twin.cloud import TwinVehicleView
    from dt_highway.twin.tagger import HighwayMap

MARK_RGB = (235, 40, 40)
"""Colour of an aggressive-driver mark (RGB)"""
THREAT_RGB = (255, 150, 0)
"""Colour of a cut-in (threat) mark (RGB): amber, a caution that something is about to happen"""
TYPE_LABEL = "aggressive driver"
"""The label of a ``type`` mark"""
THREAT_CUE, TYPE_CUE = "threat", "type"
"""``cue`` of an overlay item: a predicted cut-in, or a driver type"""
_DEFAULTS = OverlayConfig()


PREDICTION_SIZE_RANGE = (0.5, 2.0)
"""A held mark's predicted box is trusted while its width and height stay within these factors of the last
box's [-]"""


def predicted_box(box: np.ndarray, velocity_px_s: np.ndarray, age_s: float) -> np.ndarray | None:
    """A held mark's box ``age_s`` after its car's last box, moved on at that box's image velocity, or ``None``
    when the prediction is no longer trusted (its width or height outside :data:`PREDICTION_SIZE_RANGE` of
    the last box's, an inverted box included).

    :param box: the car's last box ``(x1, y1, x2, y2)`` [px] (``None`` is returned for one that is not a box:
        not finite, or no width or height)
    :param velocity_px_s: the velocity of each of its edges [px/s]
    :param age_s: time since that box [s]
    :return: the predicted box ``(x1, y1, x2, y2)`` [px] (``box`` itself when ``age_s`` <= 0), or ``None``
    """
    size0 = box[2:] - box[:2]
    if not (np.all(np.isfinite(box)) and np.all(size0 > 0)):
        return None
    if age_s <= 0:
        return box
    out = box + velocity_px_s * age_s
    lo, hi = PREDICTION_SIZE_RANGE
    size = out[2:] - out[:2]
    return out if bool(np.all((size >= lo * size0) & (size <= hi * size0))) else None


@dataclass
class _BoxTrack:
    """A car's last box in the image and its edges' velocity, to hold a mark on it while the fusion does not
    place the car (the real overlay's held marks and the placebo's alike).

    :param box: the car's last box ``(x1, y1, x2, y2)`` [px]
    :param t_s: the time of that box [s]
    :param velocity_px_s: the velocity of each of its edges, from the box before [px/s]
    """

    box: np.ndarray
    t_s: float
    velocity_px_s: np.ndarray = field(default_factory=lambda: np.zeros(4))

    def follow(self, box: np.ndarray, t_s: float) -> None:
        """The car's box at ``t_s`` [px] (its image velocity from the box before)."""
        gap = t_s - self.t_s
        if gap > 0:
            self.velocity_px_s = (box - self.box) / gap
        self.box, self.t_s = box, t_s

    def predicted(self, t_s: float) -> np.ndarray | None:
        """The box at ``t_s`` [s]: :func:`predicted_box` (``None`` when no longer trusted)."""
        return predicted_box(self.box, self.velocity_px_s, t_s - self.t_s)


@dataclass
class _Mark:
    item: dict[str, Any]
    track: _BoxTrack
    streak: int = 1
    shown: bool = False
    last_seen_s: float = 0.0


class OverlayStabilizer:
    """Steady marks from the fusion's per-frame overlay items (module docstring).

    :param onset_frames: consecutive frames a vehicle must be placed in before its mark shows [-]
    :param hold_s: how long a shown mark stays after its vehicle stops qualifying (no longer among the items:
        no longer marked, or not placed) [s]

    Defaults and ranges are the ``overlay`` section's (:class:`~dt_highway.config.OverlayConfig`).

    :raises ConfigError: on a value out of range
    """

    def __init__(self, onset_frames: int = _DEFAULTS.onset_frames, hold_s: float = _DEFAULTS.hold_s) -> None:
        settings = validate_section(OverlayConfig, "overlay", onset_frames=onset_frames, hold_s=hold_s)
        self.onset_frames = settings.onset_frames
        self.hold_s = settings.hold_s
        self._marks: dict[int, _Mark] = {}
        self._t_s: float | None = None

    def reset(self) -> None:
        """Forget every mark (a new episode)."""
        self._marks.clear()
        self._t_s = None

    def update(self, items: Sequence[dict[str, Any]], t_s: float,
               placed: Mapping[int, Mapping[str, Any]] | None = None) -> list[dict[str, Any]]:
        """One frame.

        :param items: the fusion's overlay items this frame (``vehicle_id``, ``box`` [px], ...)
        :param t_s: the frame's time [s]
        :param placed: every car the fusion placed this frame, by id: its ``box`` [px] and ``distance_m`` [m]
            (and ``rule``); a held mark stays on its car's box and shows its distance now; ``None``: not known,
            a held mark's box is always predicted
        :return: the marks to show: the items, each with ``held`` (``True`` when its vehicle no longer
            qualifies or was not placed this frame: the box is its car's, or predicted)
        """
        dt = 0.0 if self._t_s is None else max(t_s - self._t_s, 0.0)
        self._t_s = t_s
        now = {int(it["vehicle_id"]): it for it in items}
        placed = placed if placed is not None else {}
        for vid, it in now.items():
            box = np.asarray(it["box"], dtype=float)
            mark = self._marks.get(vid)
            if mark is None:
                self._marks[vid] = _Mark(dict(it), _BoxTrack(box, t_s), last_seen_s=t_s)
                continue
            gap = t_s - mark.last_seen_s
            fresh = gap > 0 and gap <= dt + 1e-9  # placed in the previous frame too
            mark.streak = mark.streak + 1 if fresh else 1
            mark.track.follow(box, t_s)
            mark.item, mark.last_seen_s = dict(it), t_s
        out = []
        for vid in list(self._marks):
            mark = self._marks[vid]
            if vid in now:
                mark.shown = mark.shown or mark.streak >= self.onset_frames
                if mark.shown:
                    out.append({**mark.item, "held": False})
                continue
            held: np.ndarray | None = None
            if mark.shown and t_s - mark.last_seen_s <= self.hold_s:
                car = placed.get(vid)
                if car is not None:
                    mark.track.follow(np.asarray(car["box"], dtype=float), t_s)
                    mark.item.update({k: car[k] for k in ("distance_m", "rule") if k in car})
                held = mark.track.predicted(t_s)
            if held is None:
                del self._marks[vid]
                continue
            out.append({**mark.item, "box": [float(b) for b in held], "held": True})
        return out


# ----------------------------------------------------------------------------- which cars
def threat_label(side: str | None, aggressive: bool) -> str:
    """The label of a threat mark: ``"cutting in from left"`` (``+ aggressive driver`` when the twin
    also tags the car).

    :param side: ``"left"`` or ``"right"`` of the ego's lane, ``None`` when not known
    :param aggressive: the twin tags the car aggressive
    :return: the label
    """
    head = "cutting in" if side is None else f"cutting in from {side}"
    return f"{head} + {TYPE_LABEL}" if aggressive else head


def side_of(y_m: float, ego_lane: int, road_map: HighwayMap) -> str:
    """Which side of the ego's lane a car is on, by its lateral position (left: smaller ``y``, the
    lower lane ids; a car on the lane's centre line counts as right).

    :param y_m: the car's lateral position (its last fix) [m]
    :param ego_lane: the ego's lane id
    :param road_map: the lanes
    :return: ``"left"`` or ``"right"``
    """
    centre = road_map.lane_centre_y_m(ego_lane)
    return "left" if y_m < centre else "right"


def in_lane(y_m: float, ego_lane: int, road_map: HighwayMap) -> bool:
    """Whether a car is in the ego's lane, by its lateral position (within half a lane width of the lane's centre).

    :param y_m: the car's lateral position (its last fix) [m]
    :param ego_lane: the ego's lane id
    :param road_map: the lanes
    :return: whether it is less than half a lane width from the lane's centre
    """
    centre = road_map.lane_centre_y_m(ego_lane)
    return abs(y_m - centre) < road_map.lane_width_m / 2.0


def is_threat(view: TwinVehicleView, ego_lane: int, horizon_s: float, threshold: float) -> bool:
    """Whether the twin predicts that a car moves into the ego's lane within the horizon.

    :param view: what the twin sent of the car
    :param ego_lane: the ego's lane id (negative: unknown, never a threat)
    :param horizon_s: the horizon read (the twin's nearest one) [s]
    :param threshold: least ``p_change`` [-]
    :return: whether the intent at ``horizon_s`` targets the ego's lane with ``p_change`` >= ``threshold``
    """
    intent = view.intent(horizon_s)
    return (ego_lane >= 0 and intent is not None and intent.p_change >= threshold
            and intent.target_lane == ego_lane)


DEFAULT_HORIZON_S, DEFAULT_THRESHOLD = 2.0, 0.5
"""The threat's operating point when neither ``overlay`` nor the caller gives one, for callers outside the
env (the env's pipeline fills in ``twin.intention.operating_horizon_s`` and ``twin.intention.threshold``) [s], [-]"""


def select_items(placements: Mapping[int, Placement], views: Mapping[int, TwinVehicleView], settings: OverlayConfig,
                 ego_lane: int, road_map: HighwayMap) -> list[dict[str, Any]]:
    """This frame's overlay items before stabilising: the placed cars ``overlay.mode`` marks
    (module docstring), within ``overlay.max_range_m``.

    :param placements: the fusion's placements, by vehicle id
    :param views: the twin's view of each placed vehicle, by id
    :param settings: the ``overlay`` section (``horizon_s``/``threshold`` ``None``: :data:`DEFAULT_HORIZON_S`,
        :data:`DEFAULT_THRESHOLD`; the env's pipeline fills them in from ``twin.intention``)
    :param ego_lane: the ego's lane id (the ego knows its own lane)
    :param road_map: the lanes (for the side a threat comes from)
    :return: items ``vehicle_id``, ``box`` [px], ``label``, ``confidence`` [-], ``distance_m``, ``rule``,
        ``cue`` (``"type"`` or ``"threat"``), and for a threat ``side`` and ``aggressive``
    """
    horizon_s = settings.horizon_s if settings.horizon_s is not None else DEFAULT_HORIZON_S
    threshold = settings.threshold if settings.threshold is not None else DEFAULT_THRESHOLD
    items = []
    for vid, p in placements.items():
        if p.box is None or not p.distance_m <= settings.max_range_m:  # NaN fails too
            continue
        tv = views[vid]
        aggressive = tv.tag == AGGRESSIVE
        base = {"vehicle_id": vid, "box": list(p.box), "distance_m": p.distance_m, "rule": p.rule}
        intent = tv.intent(horizon_s)
        if settings.mode != "type" and intent is not None and is_threat(tv, ego_lane, horizon_s, threshold):
            side = side_of(tv.y_m, ego_lane, road_map)
            items.append({**base, "label": threat_label(side, aggressive), "confidence": float(intent.p_change),
                          "cue": THREAT_CUE, "side": side, "aggressive": aggressive})
        elif settings.mode != "threat" and aggressive:
            items.append({**base, "label": TYPE_LABEL, "confidence": float(tv.confidence), "cue": TYPE_CUE})
    return items


def _priority(item: Mapping[str, Any]) -> tuple[bool, float, int]:
    dist = item.get("distance_m")
    d = float(dist) if dist is not None and math.isfinite(float(dist)) else math.inf
    return item.get("cue") != THREAT_CUE, d, int(item.get("vehicle_id", 0))


def bound_marks(marks: Sequence[dict[str, Any]], max_marks: int) -> list[dict[str, Any]]:
    """The clutter bound: the ``max_marks`` marks shown, threats first, then nearest first.

    :param marks: the steady marks (:meth:`OverlayStabilizer.update`)
    :param max_marks: most marks [-]
    :return: the marks kept, in that order
    """
    return sorted(marks, key=_priority)[:max_marks]


# ----------------------------------------------------------------------------- the placebo
@dataclass
class _Slot:
    car: int
    track: _BoxTrack
    distance_m: float
    rule: str
    side: str | None
    box_now: np.ndarray
    """The box shown this frame: the car's, or (held) its trusted prediction [px]"""


class ShamOverlay:
    """The placebo overlay: the real overlay's marks, as many and alike, on cars drawn at random.

    Each frame the real overlay (after stabilising and the clutter bound) is given, hidden from
    the driver. For each real mark the sham shows one mark on a *slot car*:

    * when a real mark first appears, its slot car is drawn uniformly (with this overlay's own
      seeded generator) among the cars the fusion placed this frame within ``overlay.max_range_m``
      that no other sham mark holds, and, for a threat cue, that are not in the ego's lane (a real
      threat is a car in another lane moving into it; "CUTTING IN" on a car already ahead in the
      ego's lane, its side flipping as it wanders about the lane's centre, gave the placebo away);
      nothing about the cars but their ids and, for a threat cue, their lane enters the draw
      (never the twin's tag or intention, and not the real mark's car either: it can be drawn too);
    * the slot car keeps the mark for as long as the real mark is shown; when the fusion stops
      placing the slot car, the sham mark is held at its predicted box like a real one
      (``hold_s``, ending early when the prediction is no longer trusted: :func:`predicted_box`),
      and after that a new car is drawn (the car left the view);
    * the sham mark carries the real mark's label and cue (type or threat, the "aggressive driver"
      part, the percentage shown), with the box, distance and, for a threat cue, the side
      (left or right of the ego's lane) of its own car.

    So the number of marks is the real overlay's at every frame (held real marks included), and
    each sham mark lasts as long as the real mark it mirrors, except when fewer cars are placed
    than there are real marks (then fewer are shown) and when a slot car leaves the view (the mark
    moves to another car). The draws do not depend on which cars the real overlay marks: given the
    times real marks start and end, the sham marks are the same whichever cars the twin tags (a run
    with the tags shuffled among the cars shows the same sham marks), with one exception: real
    marks that start in the same frame are paired with that frame's draws in the real overlay's
    order (threats first, nearest first), so which of those sham marks ends first follows them.

    :param rng: the overlay's random generator (seeded by the env)
    :param hold_s: how long a sham mark stays on a car the fusion lost [s]
    :raises ConfigError: one line, on a bad ``hold_s`` (as ``overlay.hold_s``)
    :raises TypeError: when ``rng`` is no ``numpy.random.Generator``
    """

    def __init__(self, rng: np.random.Generator, hold_s: float = _DEFAULTS.hold_s) -> None:
        if not isinstance(rng, np.random.Generator):
            raise TypeError(f"the sham overlay draws from a numpy.random.Generator (got {type(rng).__name__}): "
                            "numpy.random.default_rng(seed)")
        self.rng = rng
        self.hold_s = validate_section(OverlayConfig, "overlay", hold_s=hold_s).hold_s
        self._slots: dict[int, _Slot] = {}
        self._t_s: float | None = None

    def reset(self) -> None:
        """Forget every slot (a new episode)."""
        self._slots.clear()
        self._t_s = None

    @property
    def pairs(self) -> dict[int, int]:
        """Each real mark's vehicle id and the car its sham mark is on (evaluation)."""
        return {rid: s.car for rid, s in self._slots.items()}

    def _follow(self, cars: Mapping[int, Mapping[str, Any]], t_s: float) -> None:
        """Move the slots with their cars; drop those whose car has been gone longer than the hold, or whose
        predicted box is no longer trusted."""
        for rid in list(self._slots):
            s = self._slots[rid]
            car = cars.get(s.car)
            if car is None:
                held = s.track.predicted(t_s) if t_s - s.track.t_s <= self.hold_s else None
                if held is None:
                    del self._slots[rid]
                else:
                    s.box_now = held
                continue
            s.track.follow(np.asarray(car["box"], dtype=float), t_s)
            s.box_now = s.track.box
            s.distance_m, s.rule, s.side = float(car["distance_m"]), str(car.get("rule", "")), car.get("side")

    def update(self, real: Sequence[Mapping[str, Any]], cars: Mapping[int, Mapping[str, Any]],
               t_s: float) -> list[dict[str, Any]]:
        """One frame.

        :param real: the real overlay's marks this frame (hidden from the driver)
        :param cars: the cars the fusion placed this frame within range, by id: ``box`` [px],
            ``distance_m``, ``rule``, ``side`` (of the ego's lane), ``in_ego_lane`` (``True``: never under a
            threat cue's sham mark)
        :param t_s: the frame's time [s]
        :return: the sham marks (``held`` when the slot car is not placed this frame)
        """
        self._t_s = t_s
        shown = {int(m["vehicle_id"]) for m in real}
        for rid in [r for r in self._slots if r not in shown]:  # the real mark is gone: so is its sham
            del self._slots[rid]
        self._follow(cars, t_s)
        taken = {s.car for s in self._slots.values()}
        out = []
        for m in real:
            rid = int(m["vehicle_id"])
            s = self._slots.get(rid)
            if s is None:
                threat = m.get("cue") == THREAT_CUE
                free = sorted(v for v in set(cars) - taken if not (threat and cars[v].get("in_ego_lane", False)))
                if not free:
                    continue
                vid = free[int(self.rng.integers(len(free)))]
                car = cars[vid]
                box = np.asarray(car["box"], dtype=float)
                s = self._slots[rid] = _Slot(vid, _BoxTrack(box, t_s), float(car["distance_m"]),
                                             str(car.get("rule", "")), car.get("side"), box)
                taken.add(vid)
            out.append(self._item(m, s, t_s))
        return out

    @staticmethod
    def _item(real: Mapping[str, Any], s: _Slot, t_s: float) -> dict[str, Any]:
        item = {**real, "vehicle_id": s.car, "box": [float(b) for b in s.box_now], "distance_m": s.distance_m,
                "rule": s.rule, "held": t_s > s.track.t_s}
        if real.get("cue") == THREAT_CUE:
            side = s.side if s.side is not None else real.get("side")
            item["side"] = side
            item["label"] = threat_label(side, bool(real.get("aggressive", False)))
        return item


# ----------------------------------------------------------------------------- drawing
def _label_lines(item: Mapping[str, Any]) -> tuple[str, str]:
    """A full label's two lines: the head, then the confidence, the distance and, on a cut-in mark of a car the twin
    also tags, "AGGRESSIVE" last (first, "AGGRESSIVE 73 %" read as the driver's aggressiveness; the percentage is
    the cut-in's)."""
    parts = []
    threat = item.get("cue") == THREAT_CUE
    if threat:
        side = item.get("side")
        # the arrows stand on the side the car comes from and point the way it moves: into the ego's lane
        head = ">> CUTTING IN" if side == "left" else "CUTTING IN <<" if side == "right" else "CUTTING IN"
    else:
        head = str(item.get("label", TYPE_LABEL)).upper()
    conf = item.get("confidence")
    if conf is not None and math.isfinite(float(conf)):
        parts.append(f"{100 * float(conf):.0f} %")
    dist = item.get("distance_m")
    if dist is not None and math.isfinite(float(dist)):
        parts.append(f"{float(dist):.0f} m")
    if threat and item.get("aggressive"):
        parts.append("AGGRESSIVE")
    return head, "  ".join(parts)


class Banner(NamedTuple):
    """Where one mark's box and label go on the image (:func:`label_layout`).

    :param mark: the mark's index in the items given
    :param box: the box clipped to the image ``(x1, y1, x2, y2)`` [px]
    :param label: the label's rectangle ``(x, y, w, h)`` [px], ``None`` when dropped
    :param head: the label's first line
    :param sub: its second line (confidence, distance, and "AGGRESSIVE" on a cut-in mark of a car the twin tags so;
        may be empty)
    :param moved: the label was moved up past another one (a leader line joins it to the box)
    """

    mark: int
    box: tuple[int, int, int, int]
    label: tuple[int, int, int, int] | None
    head: str
    sub: str
    moved: bool


Rect = tuple[int, int, int, int]
"""A rectangle ``(x, y, w, h)`` on the image [px]"""


def _overlaps(r: Rect, placed: Sequence[Rect]) -> list[int]:
    x, y, w, h = r
    return [i for i, (ox, oy, ow, oh) in enumerate(placed) if x < ox + ow and ox < x + w and y < oy + oh and oy < y + h]


def _text_size(head: str, sub: str, scale: float) -> tuple[int, int, int, int, int, int]:
    """``(w, h, pad, th1, th2, thick)`` of a label at ``scale``."""
    thick = max(1, round(3 * scale))
    font = cv2.FONT_HERSHEY_DUPLEX
    (tw1, th1), _ = cv2.getTextSize(head, font, 0.9 * scale, thick)
    (tw2, th2), _ = cv2.getTextSize(sub, font, 0.75 * scale, max(1, thick - 1)) if sub else ((0, 0), 0)
    pad = max(2, round(6 * scale))
    return max(tw1, tw2) + 2 * pad, th1 + (th2 + pad if sub else 0) + 2 * pad, pad, th1, th2, thick


def label_layout(items: Sequence[Mapping[str, Any]], width: int, height: int, full_labels: int = 2,
                 label_range_m: float = 60.0, keep_out: Sequence[Rect] = (),
                 bottom_px: int | None = None) -> list[Banner]:
    """Where the marks' boxes and labels go: no two labels overlap, none is stacked more than one
    label high, and none goes under what the screen draws over the picture (``keep_out``).

    Labels are placed in priority order (threats first, then nearest first). A label sits just
    above its box; when there is no room above (the image's top edge, or a ``keep_out`` area such
    as the driving window's mirror or trial label), at the top inside the box when the box is tall
    enough (a car close by), else just below the box. A label over another marked car's box, or right
    above it, reads as that car's: a label is centred on its box unless another mark's box lies in its
    column (between the label and its box's bottom), then aligned with its box's left or right edge,
    whichever clears the others (:func:`_label_x`); if neither does and the label above would cover
    another mark's box, it goes inside its own box when that can hold it. The ``full_labels`` first ones within
    ``label_range_m`` get the full label ("AGGRESSIVE DRIVER" or ">> CUTTING IN", confidence,
    distance), the others a small "!" tag. A label above or below its box that would overlap one
    already placed is moved up once, just above the one in the way, and joined to its box by a leader
    line; if it still overlaps a label or a ``keep_out`` area, or leaves the image, it is **dropped**
    (as is one with no free place inside or below its box): its box is drawn without a
    label (a farther or lower-priority car keeps its box; the warning of the car before it is
    the one that is read). So labels never build towers.

    :param items: the marks (``box`` [px], ``label``, ``cue``, ``distance_m``, ...)
    :param width: image width [px]
    :param height: image height [px]
    :param full_labels: most marks with the full label [-]
    :param label_range_m: farthest distance of a full label [m]
    :param keep_out: rectangles ``(x, y, w, h)`` [px] no label may cover (drawn over the picture later)
    :param bottom_px: the row [px] boxes stop at (the top of a band drawn over the picture's bottom later, such as
        the driving window's HUD: a box does not run under it); ``None``: the image's bottom
    :return: one banner per mark whose box is on the image above ``bottom_px``, in priority order
    """
    scale = max(height / 720.0, 0.3)  # text and lines grow with the picture
    thick = max(1, round(3 * scale))
    floor = height if bottom_px is None else int(np.clip(bottom_px, 1, height))
    placed: list[tuple[int, int, int, int]] = []
    out = []
    n_full = 0
    shown = {i: box for i in range(len(items)) if (box := _clipped_box(items[i]["box"], width, floor)) is not None}
    for i in sorted(shown, key=lambda k: _priority(items[k])):
        item = items[i]
        p1, p2 = shown[i][:2], shown[i][2:]
        others = [(a, b, c - a, d - b) for j, (a, b, c, d) in shown.items() if j != i]
        dist = item.get("distance_m")
        d = float(dist) if dist is not None else math.nan
        if n_full < full_labels and (not math.isfinite(d) or d <= label_range_m):
            head, sub = _label_lines(item)
            n_full += 1
        else:
            head, sub = "!", ""
        bw, bh, pad, _, _, _ = _text_size(head, sub, scale)
        bx = _label_x((p1[0], p1[1], p2[0], p2[1]), bw, bh + thick, width, others)
        rect, moved = _place_label(bx, bw, bh, (p1[1], p2[1]), (thick, pad), height, placed, keep_out, others)
        if rect is not None:
            placed.append(rect)
        out.append(Banner(i, (p1[0], p1[1], p2[0], p2[1]), rect, head, sub, moved))
    return out


def _label_x(box: tuple[int, int, int, int], bw: int, reach: int, width: int, others: Sequence[Rect]) -> int:
    """A label's left edge [px]: centred on its box, unless another mark's box lies in the label's column between
    the label (above the box) and the box's bottom, where a reader would take the label for that car's; then
    aligned with its box's left or right edge, whichever clears the others (else centred).

    :param box: the label's own box ``(x1, y1, x2, y2)`` [px]
    :param bw: the label's width [px]
    :param reach: how far above the box the label reaches [px]
    :param width: image width [px]
    :param others: the other marks' boxes ``(x, y, w, h)`` [px]
    :return: the left edge
    """
    x1, y1, x2, y2 = box
    centred = int(np.clip((x1 + x2) / 2 - bw / 2, 0, max(width - bw, 0)))
    for bx in (centred, int(np.clip(x1, 0, max(width - bw, 0))), int(np.clip(x2 - bw, 0, max(width - bw, 0)))):
        if not _overlaps((bx, y1 - reach, bw, y2 - y1 + reach), others):
            return bx
    return centred


def _clipped_box(box: Sequence[float], width: int, floor: int) -> tuple[int, int, int, int] | None:
    """A mark's box ``(x1, y1, x2, y2)`` [px] clipped to the image above row ``floor``, ``None`` when none of it is."""
    x1, y1, x2, y2 = (float(v) for v in box)
    if not all(map(math.isfinite, (x1, y1, x2, y2))) or x2 <= 0 or y2 <= 0 or x1 >= width or y1 >= floor:
        return None
    return (int(round(max(x1, 0))), int(round(max(y1, 0))), int(round(min(x2, width - 1))), int(round(min(y2, floor - 1))))


def _place_label(bx: int, bw: int, bh: int, box_y: tuple[int, int], gaps: tuple[int, int], height: int,
                 placed: Sequence[Rect], keep_out: Sequence[Rect],
                 other_boxes: Sequence[Rect] = ()) -> tuple[Rect | None, bool]:
    """A label's rectangle (:func:`label_layout`), ``None`` when dropped, and whether it was moved up past
    another label.

    :param bx: the label's left edge [px]
    :param bw: its width [px]
    :param bh: its height [px]
    :param box_y: the top and bottom of its box, clipped to the image [px]
    :param gaps: the line thickness (label to box) and the label's padding (label to label) [px]
    :param height: image height [px]
    :param placed: the labels placed so far
    :param keep_out: the areas no label may cover
    :param other_boxes: the other marks' boxes ``(x, y, w, h)`` [px]: a label above its box that would cover one
        goes inside its own box when that is tall enough (a label on another car's box reads as that car's)
    """
    (top, bottom), (thick, pad) = box_y, gaps

    def free(by: int) -> bool:
        r = (bx, by, bw, bh)
        return 0 <= by <= height - bh and not _overlaps(r, placed) and not _overlaps(r, keep_out)

    def past(in_way: Sequence[int]) -> tuple[Rect | None, bool]:
        """Once up, just above the labels in the way; else dropped."""
        up = min(placed[j][1] for j in in_way) - bh - pad
        return ((bx, up, bw, bh), True) if free(up) else (None, False)

    above = top - bh - thick
    if 0 <= above and not _overlaps((bx, above, bw, bh), keep_out):
        if _overlaps((bx, above, bw, bh), other_boxes):
            room = [y for y in range(top + thick, bottom - thick - bh + 1, max(1, pad))
                    if free(y) and not _overlaps((bx, y, bw, bh), other_boxes)]
            if room:
                return (bx, room[0], bw, bh), False
        in_way = _overlaps((bx, above, bw, bh), placed)
        return past(in_way) if in_way else ((bx, above, bw, bh), False)
    # no room above the box: inside it, as high as is free (its top, or just below an area or label in the
    # way), when the box is tall enough; else below it
    below_others = [y + h + thick for x, y, w, h in (*keep_out, *placed) if x < bx + bw and bx < x + w]
    inside = sorted(y for y in {top + thick, *below_others} if top + thick <= y <= bottom - thick - bh)
    below = min(bottom + thick, height - bh)
    chosen = next((by for by in (*inside, below) if free(by)), None)
    if chosen is not None:
        return (bx, chosen, bw, bh), False
    in_way = _overlaps((bx, below, bw, bh), placed)  # below, in the way of labels: once up past them, as above
    return past(in_way) if in_way else (None, False)


def draw_overlay(rgb: np.ndarray, items: Sequence[Mapping[str, Any]], colour: tuple[int, int, int] = MARK_RGB,
                 full_labels: int = 2, label_range_m: float = 60.0, keep_out: Sequence[Rect] = (),
                 bottom_px: int | None = None) -> np.ndarray:
    """A copy of ``rgb`` with each mark drawn: a box on the vehicle and a label by it (above, inside or below) on a
    filled banner, sized to the image (:func:`label_layout`: no towers of labels). Threat marks
    (">> CUTTING IN": the arrows stand on the side the car comes from and point the way it moves) are amber
    (:data:`THREAT_RGB`), the others ``colour``.

    :param rgb: ``uint8 (H, W, 3)`` RGB frame
    :param items: marks (:meth:`OverlayStabilizer.update` or ``info["adas"]["overlay"]``)
    :param colour: the colour of the driver-type marks (RGB)
    :param full_labels: most marks with the full label [-]
    :param label_range_m: farthest distance of a full label [m]
    :param keep_out: rectangles ``(x, y, w, h)`` [px] no label may cover (what the screen draws over the
        picture afterwards: the driving window's mirror, trial label and HUD band)
    :param bottom_px: the row [px] boxes stop at (the top of the driving window's HUD band); ``None``: the bottom
    :return: the annotated frame (same shape)
    :raises ValueError: on a frame that is not ``uint8 (H, W, 3)``, or a mark without its ``box``
    """
    if not isinstance(rgb, np.ndarray) or rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
        shape = f"{rgb.dtype} {rgb.shape}" if isinstance(rgb, np.ndarray) else type(rgb).__name__
        raise ValueError(f"draw_overlay draws on a uint8 (H, W, 3) RGB frame (got {shape})")
    missing = next((i for i, item in enumerate(items) if "box" not in item), None)
    if missing is not None:
        raise ValueError(f"overlay mark {missing} has no 'box' [px] (marks as info['adas']['overlay'] gives them)")
    out = np.ascontiguousarray(rgb).copy()
    h, w = out.shape[:2]
    scale = max(h / 720.0, 0.3)
    font = cv2.FONT_HERSHEY_DUPLEX
    banners = label_layout(items, w, h, full_labels, label_range_m, keep_out, bottom_px)
    for b in banners:
        c = THREAT_RGB if items[b.mark].get("cue") == THREAT_CUE else colour
        cv2.rectangle(out, b.box[:2], b.box[2:], c, max(1, round(3 * scale)), cv2.LINE_AA)
    for b in reversed(banners):  # the first (nearest, threats) drawn last, on top
        if b.label is None:
            continue
        c = THREAT_RGB if items[b.mark].get("cue") == THREAT_CUE else colour
        bx, by, bw, bh = b.label
        _, _, pad, th1, th2, thick = _text_size(b.head, b.sub, scale)
        x1, y1, x2, _ = b.box
        if b.moved or by + bh < y1 - thick:  # away from its box: a leader line
            cx = (x1 + x2) // 2
            cv2.line(out, (int(np.clip(cx, bx, bx + bw)), by + bh), (cx, y1), c, max(1, thick - 1), cv2.LINE_AA)
        cv2.rectangle(out, (bx, by), (bx + bw, by + bh), c, -1)
        cv2.putText(out, b.head, (bx + pad, by + pad + th1), font, 0.9 * scale, (255, 255, 255), thick, cv2.LINE_AA)
        if b.sub:
            cv2.putText(out, b.sub, (bx + pad, by + 2 * pad + th1 + th2), font, 0.75 * scale, (255, 255, 255),
                        max(1, thick - 1), cv2.LINE_AA)
    return out
