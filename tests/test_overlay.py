"""The overlay: steady marks from the fusion's per-frame items, and their drawing."""

import numpy as np
import pytest

from dt_highway.overlay import MARK_RGB, OverlayStabilizer, draw_overlay, predicted_box


def _item(vid, box, dist=30.0):
    return {"vehicle_id": vid, "box": list(box), "label": "aggressive driver", "confidence": 0.87, "distance_m": dist}


def test_a_mark_needs_consecutive_frames_to_appear_and_is_held_then_dropped():
    st = OverlayStabilizer(onset_frames=2, hold_s=1.0)
    assert st.update([_item(7, (100, 100, 140, 130))], 0.0) == []  # one frame: not yet
    assert st.update([], 0.2) == []  # never shown: nothing to hold
    assert st.update([_item(7, (100, 100, 140, 130))], 0.4) == []  # the streak starts again
    (shown,) = st.update([_item(7, (110, 100, 150, 130))], 0.6)
    assert not shown["held"] and shown["box"] == [110, 100, 150, 130]
    # lost by the fusion: held at the box moved on at its image velocity (50 px/s to the right)
    (held,) = st.update([], 0.8)
    assert held["held"] and held["box"] == pytest.approx([120, 100, 160, 130])
    assert held["confidence"] == 0.87
    (back,) = st.update([_item(7, (125, 100, 165, 130))], 1.0)  # back within the hold: shown at once
    assert not back["held"]
    assert st.update([], 1.8) != [] and st.update([], 2.1) == []  # 1.1 s after: gone
    st.reset()
    assert st.update([_item(7, (1, 1, 5, 5))], 3.0) == []


def test_onset_of_one_frame_shows_at_once_and_bad_settings_are_refused():
    st = OverlayStabilizer(onset_frames=1, hold_s=0.0)
    assert len(st.update([_item(1, (0, 0, 4, 4)), _item(2, (5, 5, 9, 9))], 0.0)) == 2
    assert st.update([_item(2, (5, 5, 9, 9))], 0.1)[0]["vehicle_id"] == 2
    with pytest.raises(ValueError, match="onset_frames"):
        OverlayStabilizer(onset_frames=0)
    with pytest.raises(ValueError, match="hold_s"):
        OverlayStabilizer(hold_s=-1)


def test_draw_overlay_marks_the_box_and_a_label_and_leaves_the_input_alone():
    rgb = np.full((360, 640, 3), 90, np.uint8)
    out = draw_overlay(rgb, [_item(3, (300, 200, 380, 260)), _item(4, (-50, -50, -10, -10))])
    assert out.shape == rgb.shape and (rgb == 90).all()
    assert tuple(out[230, 300]) == MARK_RGB  # the box's left edge
    assert (out[225, 320:360] == 90).all()  # inside the box: the car stays visible
    banner = out[150:198, 300:380]
    assert (banner == MARK_RGB).all(axis=-1).mean() > 0.3 and (banner == 255).all(axis=-1).any()  # label above
    assert (out[:50, :50] == 90).all()  # a box off the image draws nothing
    assert np.array_equal(draw_overlay(rgb, []), rgb)


def test_a_held_mark_stays_on_its_car_while_the_fusion_places_it():
    """A car that stops qualifying (no longer a threat) but is still placed keeps its mark on its own box, with
    the distance measured now."""
    st = OverlayStabilizer(onset_frames=1, hold_s=1.0)
    st.update([_item(7, (100, 100, 140, 130))], 0.0)
    st.update([_item(7, (110, 100, 150, 130))], 0.1)  # moving right at 100 px/s
    (held,) = st.update([], 0.2, placed={7: {"box": (100, 90, 150, 140), "distance_m": 25.0}})  # placed
    assert held["held"] and held["box"] == [100, 90, 150, 140] and held["distance_m"] == 25.0
    (held,) = st.update([], 0.3)  # then lost: predicted from the last two boxes (-100 px/s, -100 / +100 px/s)
    assert held["box"] == pytest.approx([90, 80, 150, 150])


def test_the_hold_counts_from_the_last_frame_the_mark_qualified():
    """Still boxes (a prediction always trusted): the mark goes hold_s after it last qualified, however long the
    fusion kept placing its car after that."""
    st = OverlayStabilizer(onset_frames=1, hold_s=1.0)
    box = (100, 100, 140, 130)
    st.update([_item(7, box)], 0.0)
    st.update([_item(7, box)], 0.1)  # qualifies last at 0.1
    for t in (0.2, 0.3, 0.4, 0.5):
        assert st.update([], t, placed={7: {"box": box, "distance_m": 30.0}})[0]["held"]
    assert st.update([], 1.05) != []  # 0.95 s after it last qualified (0.55 s after it was last placed)
    assert st.update([], 1.15) == []  # 1.05 s after


def test_a_held_mark_ends_when_its_predicted_box_is_no_longer_a_car_box():
    """A car pulling away shrinks fast: a box moved on at its last edge velocities would invert; the mark ends
    once its predicted width or height falls below half the last box's (or grows past twice it)."""
    st = OverlayStabilizer(onset_frames=1, hold_s=1.0)
    st.update([_item(7, (100, 100, 200, 180))], 0.0)
    st.update([_item(7, (110, 105, 190, 175))], 0.1)  # width 80 px, shrinking 200 px/s
    (held,) = st.update([], 0.2)
    assert held["box"] == pytest.approx([120, 110, 180, 170])  # width 60: trusted
    (held,) = st.update([], 0.275)
    assert held["box"][2] - held["box"][0] == pytest.approx(45)  # width 45: still over half
    assert st.update([], 0.35) == []  # width 30: no longer trusted, the mark ends (the hold had 0.75 s left)
    assert predicted_box(np.array([0.0, 0, 10, 10]), np.array([0.0, 0, -100, 0]), 0.2) is None  # inverted
    assert predicted_box(np.array([0.0, 0, 10, 10]), np.array([0.0, 0, 100, 0]), 0.05) is not None
    assert predicted_box(np.array([0.0, 0, 10, 10]), np.array([0.0, 0, 100, 0]), 0.2) is None  # 3 times as wide
    assert predicted_box(np.array([0.0, 0, np.nan, 10]), np.zeros(4), 0.0) is None  # not a box, even now
    assert predicted_box(np.array([5.0, 0, 5, 10]), np.zeros(4), 0.0) is None  # no width
