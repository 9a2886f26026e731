"""The example picture of the warning marks on the overlay's explanation screen."""

from __future__ import annotations

import numpy as np
import pytest

from dt_highway.hmi.briefing import load_protocol, render_screen
from dt_highway.hmi.marks_example import marks_example
from dt_highway.overlay import MARK_RGB, THREAT_RGB


def _pixels_of(img: np.ndarray, rgb: tuple[int, int, int]) -> int:
    return int(np.all(np.abs(img.astype(int) - rgb) <= 3, axis=-1).sum())


@pytest.mark.parametrize("size", [(320, 180), (960, 540), (1280, 720)])
def test_the_example_shows_a_cut_in_mark_and_a_driver_type_mark_as_a_trial_draws_them(size):
    band = marks_example(size)
    assert band.dtype == np.uint8 and band.shape[1] == size[0] and 0.2 * size[1] < band.shape[0] < size[1]
    assert not band.flags.writeable
    # the marks' frames and filled banners, each in its own colour (draw_overlay's)
    area = size[0] * size[1]
    assert _pixels_of(band, THREAT_RGB) > 0.005 * area and _pixels_of(band, MARK_RGB) > 0.005 * area
    # the cut-in mark is on the left car, the driver-type mark on the right one
    threat_cols = np.flatnonzero(np.all(np.abs(band.astype(int) - THREAT_RGB) <= 3, axis=-1).any(axis=0))
    type_cols = np.flatnonzero(np.all(np.abs(band.astype(int) - MARK_RGB) <= 3, axis=-1).any(axis=0))
    assert threat_cols.mean() < size[0] / 2 < type_cols.mean()


def test_the_example_refuses_a_size_it_cannot_draw():
    with pytest.raises(ValueError, match="at least 16 x 16 px"):
        marks_example((8, 200))


@pytest.mark.parametrize("size", [(320, 180), (640, 360), (640, 480), (960, 540), (1920, 1080)])
def test_the_overlay_screen_shows_the_example_below_its_text(size):
    p = load_protocol()
    assert p.overlay.marks_example and not any(s.marks_example for s in p.briefing)
    with_example = render_screen(size, p.overlay.fill(), p.legend, p.continue_hint)
    without = render_screen(size, p.overlay.model_copy(update={"marks_example": False}).fill(), p.legend,
                            p.continue_hint)
    assert with_example.shape == (size[1], size[0], 3)
    assert _pixels_of(with_example, THREAT_RGB) > 0 and _pixels_of(with_example, MARK_RGB) > 0
    assert _pixels_of(without, THREAT_RGB) == 0
    # the picture is below the text and above the hint: the rows that differ form one block
    rows = np.flatnonzero((with_example != without).any(axis=(1, 2)))
    text_rows = np.flatnonzero((without != without[0, 0]).any(axis=(1, 2)))
    hint_top = text_rows[text_rows > 0.8 * size[1]].min()
    assert rows.max() < hint_top
    # at least 60 % of the text column wide
    cols = np.flatnonzero((with_example != without).any(axis=(0, 2)))
    assert cols.max() - cols.min() + 1 >= 0.6 * 0.88 * size[0]
