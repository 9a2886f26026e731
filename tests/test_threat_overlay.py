"""The overlay's modes (type / threat / both), its clutter bound and the label layout, on hand-made
twin views and placements (the pipeline with a stand-in detector and fusion)."""

from types import SimpleNamespace

import numpy as np
import pytest

from dt_highway.config import ConfigError, OverlayConfig, load_config
from dt_highway.env.adas import AdasPipeline
from dt_highway.overlay import (
    MARK_RGB,
    THREAT_RGB,
    OverlayStabilizer,
    bound_marks,
    draw_overlay,
    label_layout,
    select_items,
    threat_label,
)
from dt_highway.perception.fusion import Placement
from dt_highway.twin.cloud import TwinVehicleView
from dt_highway.twin.intention import NO_LANE, LaneChangeIntent
from dt_highway.twin.tagger import HighwayMap

LANES = HighwayMap(4.0, 4)  # lane k's centre at y = 4 k; the ego in lane 1 (y = 4)
EGO_LANE = 1
DT = 1 / 15


class _Detector:
    def detect(self, image):
        return []


class _Fusion:
    """Stands in for the fusion: places the cars it is told to."""

    settings = SimpleNamespace(method="stand-in")

    def __init__(self):
        self.placements = {}

    def step(self, image, detections, view, now_s):
        return self.placements


def view(vid, y_m=0.0, tag="normal", conf=0.9, p=None, target=EGO_LANE, x_m=0.0):
    """A car as the twin sends it; ``p``: its lane-change probability at the 1, 2 and 3 s horizons."""
    intents = () if p is None else tuple(LaneChangeIntent(h, ph, target if ph > 0 else NO_LANE, ph)
                                          for h, ph in zip((1.0, 2.0, 3.0), p, strict=True))
    return TwinVehicleView(vid, 0.0, x_m, y_m, 25.0, 0.0, tag, conf, 0, 60.0, intents)


def place(vid, dist, box=None):
    box = box if box is not None else (100.0 + 40 * vid, 100.0, 130.0 + 40 * vid, 125.0)
    return Placement(vid, box, dist, dist, (0.0, 0.0), "joint")


def pipeline(seed=0, **overlay):
    settings = OverlayConfig(**overlay)
    return AdasPipeline(_Detector(), _Fusion(), OverlayStabilizer(settings.onset_frames, settings.hold_s), settings,
                        LANES, np.random.default_rng(seed))


def step(pipe, views, dists, t_s, boxes=None):
    pipe.fusion.placements = {v.vehicle_id: place(v.vehicle_id, dists[v.vehicle_id], (boxes or {}).get(v.vehicle_id))
                              for v in views if v.vehicle_id in dists}
    return pipe.run(None, None, views, 0.0, t_s, EGO_LANE)


def test_each_mode_marks_its_cars_with_its_cue():
    views = [
        view(1, y_m=0.0, tag="aggressive", conf=0.8),                       # aggressive, no intention
        view(2, y_m=0.3, p=(0.2, 0.5, 0.7)),                                # left lane, into the ego's: threat
        view(3, y_m=8.2, tag="aggressive", conf=0.7, p=(0.3, 0.6, 0.9)),    # right lane, aggressive, threat
        view(4, y_m=12.0, p=(0.5, 0.8, 0.95), target=2),                    # into another lane: no threat
        view(5, y_m=0.0, p=(0.1, 0.2, 0.3)),                                # below the threshold
    ]
    places = {v.vehicle_id: place(v.vehicle_id, 30.0) for v in views}
    by = {v.vehicle_id: v for v in views}

    def chosen(mode, **kw):
        settings = OverlayConfig(mode=mode, **{"horizon_s": 3.0, **kw})
        return {it["vehicle_id"]: it for it in select_items(places, by, settings, EGO_LANE, LANES)}

    typ = chosen("type")
    assert set(typ) == {1, 3} and typ[1]["label"] == "aggressive driver" and typ[1]["confidence"] == 0.8
    thr = chosen("threat")
    assert set(thr) == {2, 3}
    assert thr[2]["label"] == "cutting in from left" and thr[2]["side"] == "left" and thr[2]["confidence"] == 0.7
    assert thr[3]["label"] == "cutting in from right + aggressive driver" and thr[3]["aggressive"]
    both = chosen("both")
    assert set(both) == {1, 2, 3} and both[3]["cue"] == "threat" and both[1]["cue"] == "type"
    # the horizon read is the twin's nearest one: at 1 s only car 3's 0.3 is below 0.5 as well
    assert set(chosen("threat", horizon_s=1.2)) == set()
    assert set(chosen("threat", horizon_s=1.2, threshold=0.2)) == {2, 3}
    # unset, the operating point is the twin's default one (2 s, 0.5): car 2's 0.5 counts, its 0.5 shown
    default = {it["vehicle_id"]: it for it in select_items(places, by, OverlayConfig(mode="threat"), EGO_LANE, LANES)}
    assert set(default) == {2, 3} and default[2]["confidence"] == 0.5
    # the ego's lane unknown: no threat at all
    assert select_items(places, by, OverlayConfig(mode="threat"), -1, LANES) == []


def test_a_threat_mark_appears_before_a_scripted_cut_in():
    """Car 7 drives in the lane left of the ego; the twin's 3 s probability that it changes into the
    ego's lane rises from t = 0 (0.1 + 0.25 t); it starts moving over at t = 3 s at 0.8 m/s, and
    its body (2 m wide) first overlaps the ego's lane (boundary y = 2 m) at y = 1 m: t = 4.25 s.
    The mark must show once p >= 0.5 (t >= 1.6 s) for two frames, before the car moves."""
    pipe, typ = pipeline(mode="threat", horizon_s=3.0), pipeline(mode="type")
    first, first_type = None, None
    for k in range(int(6 / DT)):
        t = k * DT
        p3 = min(1.0, 0.1 + 0.25 * t)
        y = max(0.0, 0.8 * (t - 3.0))
        views = [view(7, y_m=y, p=(p3 / 3, p3 / 2, p3)), view(8, y_m=8.0, tag="aggressive")]
        shown = step(pipe, views, {7: 25.0, 8: 40.0}, t)["overlay"]
        if first is None and shown:
            first = t
            (mark,) = shown
            assert mark["vehicle_id"] == 7 and mark["label"] == "cutting in from left" and not mark["held"]
        if first_type is None and step(typ, views, {7: 25.0, 8: 40.0}, t)["overlay"]:
            first_type = t
    assert first == pytest.approx(1.6 + DT, abs=DT + 1e-9)  # the frame p reaches 0.5, plus one onset frame
    assert first < 3.0 and 4.25 - first >= 1.5  # before the car moves; warned >= 1.5 s before the overlap
    assert first_type == pytest.approx(DT)  # the type overlay marks car 8 (aggressive, no intention) at once


def test_the_clutter_bound_holds_nearest_first_in_range_and_threats_first():
    views = [view(v, y_m=8.0, tag="aggressive") for v in range(1, 7)] + [view(9, y_m=0.0, p=(0.9, 0.9, 0.9))]
    dists = {1: 20.0, 2: 40.0, 3: 60.0, 4: 80.0, 5: 101.0, 6: 150.0, 9: 95.0}
    for mode, want in (("type", [1, 2, 3]), ("both", [9, 1, 2]), ("threat", [9])):
        pipe = pipeline(mode=mode)
        for k in range(5):
            out = step(pipe, views, dists, k * DT)
            assert len(out["overlay"]) <= 3 and all(m["distance_m"] <= 100.0 for m in out["overlay"])
        assert [m["vehicle_id"] for m in out["overlay"]] == want
        assert not any(it["vehicle_id"] in (5, 6) for it in out["fusion_items"])  # beyond range: never a candidate
    pipe = pipeline(mode="type", max_marks=5, max_range_m=200.0)
    for k in range(3):
        out = step(pipe, views, dists, k * DT)
    assert [m["vehicle_id"] for m in out["overlay"]] == [1, 2, 3, 4, 5]
    marks = [{"vehicle_id": 1, "distance_m": 10.0, "cue": "type"}, {"vehicle_id": 2, "distance_m": 90.0, "cue": "threat"}]
    assert [m["vehicle_id"] for m in bound_marks(marks, 1)] == [2]


def test_labels_never_stack_into_towers():
    """Three marks on the same spot (cars at the horizon): the first label sits on its box, the
    second is moved once above it, the third would make a tower and is dropped (its box stays)."""
    box = [300.0, 150.0, 330.0, 170.0]
    items = [{"vehicle_id": v, "box": box, "label": "aggressive driver", "confidence": 0.9, "distance_m": d,
              "cue": "type"} for v, d in ((1, 50.0), (2, 55.0), (3, 58.0))]
    banners = label_layout(items, 640, 360, full_labels=3)
    assert [b.mark for b in banners] == [0, 1, 2]
    first, second, third = banners
    assert first.label is not None and not first.moved and first.label[1] + first.label[3] <= 150
    assert second.label is not None and second.moved and second.label[1] + second.label[3] < first.label[1]
    assert third.label is None and third.box == first.box
    # many marks spread along the horizon: whatever is kept, no two labels overlap
    rng = np.random.default_rng(1)
    many = [{"vehicle_id": v, "box": [x, 150.0, x + 20, 165.0], "label": "aggressive driver", "distance_m": 60 + v,
             "cue": "type"} for v, x in enumerate(rng.uniform(200, 400, 12))]
    rects = [b.label for b in label_layout(many, 640, 360, full_labels=12) if b.label is not None]
    for i, (x, y, w, h) in enumerate(rects):
        for ox, oy, ow, oh in rects[i + 1:]:
            assert not (x < ox + ow and ox < x + w and y < oy + oh and oy < y + h)


def test_a_threat_mark_held_after_its_warning_ends_stays_on_its_car():
    """The pipeline gives the stabiliser the fusion's placements: a car whose threat ends while it is still
    placed keeps its mark for the hold on its own box, at the distance measured now."""
    pipe = pipeline(mode="threat", threshold=0.5, horizon_s=3.0, onset_frames=1)
    t = 0.0
    for k in range(3):
        t = k * DT
        out = step(pipe, [view(2, y_m=0.3, p=(0.3, 0.6, 0.9))], {2: 30.0}, t)
    assert [m["vehicle_id"] for m in out["overlay"]] == [2] and not out["overlay"][0]["held"]
    moved = (300.0, 120.0, 340.0, 150.0)
    (held,) = step(pipe, [view(2, y_m=0.3, p=(0.1, 0.1, 0.1))], {2: 27.0}, t + DT, boxes={2: moved})["overlay"]
    assert held["held"] and held["box"] == list(moved) and held["distance_m"] == 27.0


def test_labels_keep_out_of_what_the_screen_draws_over_the_picture():
    """A car close by whose box reaches the top of the picture: its label goes inside the box, below the areas
    the window draws over it (mirror, trial label), not under them; a small box with no room above or inside
    gets its label below it; with nowhere free the label is dropped, the box kept."""
    def rects_meet(a, b):
        return a[0] < b[0] + b[2] and b[0] < a[0] + a[2] and a[1] < b[1] + b[3] and b[1] < a[1] + a[3]
    mirror, badge = (150, 0, 340, 70), (5, 5, 60, 25)
    near = {"vehicle_id": 1, "box": [0.0, 40.0, 200.0, 300.0], "label": threat_label("left", True), "confidence": 0.8,
            "distance_m": 5.0, "cue": "threat", "side": "left"}
    (banner,) = label_layout([near], 640, 360, keep_out=[mirror, badge])
    assert banner.label is not None and not banner.moved
    assert not rects_meet(banner.label, mirror) and not rects_meet(banner.label, badge)
    assert 40 < banner.label[1] and banner.label[1] + banner.label[3] < 300  # inside its box
    (free,) = label_layout([near], 640, 360)  # nothing drawn over the picture: above the box, as before
    assert free.label is not None and free.label[1] + free.label[3] <= 40
    small = {**near, "box": [250.0, 72.0, 290.0, 100.0]}  # just below the mirror, too small to hold its label
    (below,) = label_layout([small], 640, 360, keep_out=[mirror])
    assert below.label is not None and below.label[1] > 100
    (dropped,) = label_layout([small], 640, 360, keep_out=[mirror, (0, 100, 640, 260)])
    assert dropped.label is None and dropped.box == (250, 72, 290, 100)


def test_a_label_is_not_put_over_another_marked_car():
    """A label over another marked car's box, or right above it, reads as that car's (found in the real window: a
    cut-in label above two far cars). It slides to its box's left or right edge to clear the other car; when no
    side clears, it goes inside its own box if that can hold it; a box too small keeps it above."""
    near = {"vehicle_id": 1, "box": [200.0, 150.0, 440.0, 330.0], "label": threat_label("left", False),
            "confidence": 0.8, "distance_m": 8.0, "cue": "threat", "side": "left"}

    def far(vid: int, x: float) -> dict:
        return {"vehicle_id": vid, "box": [x, 110.0, x + 30.0, 135.0], "label": "aggressive driver",
                "distance_m": 70.0, "cue": "type"}

    def clear_of(label: tuple, boxes: list) -> bool:
        x, _, w, _ = label
        return all(x + w <= b["box"][0] or b["box"][2] <= x for b in boxes)

    alone = label_layout([near], 640, 360)[0]
    assert alone.label is not None and alone.label[1] + alone.label[3] <= 150  # above its box, centred
    assert abs(alone.label[0] + alone.label[2] / 2 - 320) <= 1
    middle = [far(2, 305.0)]  # under the centred label: the label slides to the box's left edge
    slid = label_layout([near, *middle], 640, 360)[0]
    assert slid.mark == 0 and slid.label[0] == 200 and slid.label[1] + slid.label[3] <= 150 and clear_of(slid.label, middle)
    every = [far(2, 205.0), far(3, 305.0), far(4, 405.0)]  # no side clears: inside its own box
    inside = label_layout([near, *every], 640, 360)[0]
    x, y, w, h = inside.label
    assert inside.mark == 0 and 150 < y and y + h < 330
    flat = {**near, "box": [200.0, 150.0, 440.0, 175.0]}  # too low to hold the label: above, centred
    kept = label_layout([flat, *every], 640, 360)[0]
    assert kept.label is not None and kept.label[1] + kept.label[3] <= 150


def test_a_threat_mark_is_drawn_amber_with_its_side():
    rgb = np.full((360, 640, 3), 90, np.uint8)
    threat = {"vehicle_id": 1, "box": [300, 200, 380, 260], "label": threat_label("left", False), "confidence": 0.8,
              "distance_m": 30.0, "cue": "threat", "side": "left"}
    out = draw_overlay(rgb, [threat, {"vehicle_id": 2, "box": [100, 200, 180, 260], "label": "aggressive driver",
                                      "distance_m": 40.0, "cue": "type"}])
    assert tuple(out[230, 300]) == THREAT_RGB and tuple(out[230, 100]) == MARK_RGB
    # the arrows stand on the side the car comes from and point the way it moves (into the ego's lane)
    assert label_layout([threat], 640, 360)[0].head == ">> CUTTING IN"
    assert label_layout([{**threat, "side": "right"}], 640, 360)[0].head == "CUTTING IN <<"
    # a car the twin also tags aggressive: the word after the percentage (the cut-in's) and the distance
    both = label_layout([{**threat, "aggressive": True, "label": threat_label("left", True)}], 640, 360)[0]
    assert (both.head, both.sub) == (">> CUTTING IN", "80 %  30 m  AGGRESSIVE")
    assert threat_label("right", True) == "cutting in from right + aggressive driver"


def test_overlay_settings_are_checked():
    cfg = load_config(None, ["overlay.mode=threat", "overlay.max_marks=2"])
    assert (cfg.overlay.mode, cfg.overlay.max_marks, cfg.overlay.sham, cfg.overlay.horizon_s) == ("threat", 2, False, None)
    assert OverlayConfig().mode == "type"  # the default: the driver-type overlay of earlier versions
    with pytest.raises(ConfigError, match=r"overlay\.mode"):
        load_config(None, ["overlay.mode=everything"])
    with pytest.raises(ConfigError, match=r"overlay\.max_marks"):
        load_config(None, ["overlay.max_marks=0"])
    with pytest.raises(ConfigError, match=r"overlay\.threshold"):
        load_config(None, ["overlay.threshold=1.5"])


@pytest.mark.parametrize("mode", ["threat", "both"])
def test_a_threat_overlay_without_the_twins_intention_is_refused(mode):
    """It ran, marking nothing (0 marks in 600 steps where the intention gave 45), and its sham with it."""
    shown = ["camera.enabled=true", "fusion.enabled=true", f"overlay.mode={mode}"]
    with pytest.raises(ConfigError, match=rf"^invalid configuration: overlay.mode = '{mode}' needs twin.intention.enabled"):
        load_config(None, [*shown, "twin.intention.enabled=false"])
    assert load_config(None, shown).twin.intention.enabled  # with the intention: taken
    assert load_config(None, [*shown, "overlay.mode=type", "twin.intention.enabled=false"]).overlay.mode == "type"
    # nothing shown (the baseline condition): the mode is not read, so not refused
    assert load_config(None, [f"overlay.mode={mode}", "twin.intention.enabled=false"]).overlay.mode == mode
