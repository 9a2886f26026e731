"""The example picture of the warning marks on the overlay's explanation screen."""

from __future__ import annotations

import numpy as np
import pygame
import pytest

from dt_highway.hmi import briefing
from dt_highway.hmi.briefing import EXAMPLE_MIN_SCALE, load_protocol, render_screen
from dt_highway.hmi.marks_example import REFERENCE_SIZE_PX, marks_example
from dt_highway.overlay import MARK_RGB, THREAT_RGB


def _mask(img: np.ndarray, rgb: tuple[int, int, int]) -> np.ndarray:
    return np.all(np.abs(img.astype(int) - rgb) <= 3, axis=-1)


def test_the_example_shows_a_cut_in_mark_and_a_driver_type_mark_as_a_trial_draws_them():
    band = marks_example()
    w, h = REFERENCE_SIZE_PX
    assert band.dtype == np.uint8 and band.shape[1] == w and 0.2 * h < band.shape[0] < h
    assert not band.flags.writeable
    # the marks' frames and filled banners, each in its own colour (draw_overlay's)
    threat, kind = _mask(band, THREAT_RGB), _mask(band, MARK_RGB)
    assert threat.sum() > 0.005 * w * h and kind.sum() > 0.005 * w * h
    # the cut-in mark on the left car, the driver-type mark on the right one
    assert np.flatnonzero(threat.any(axis=0)).mean() < w / 2 < np.flatnonzero(kind.any(axis=0)).mean()


def _ink_rows(img: np.ndarray) -> np.ndarray:
    return np.flatnonzero((img != img[0, 0]).any(axis=(1, 2)))


@pytest.mark.parametrize("size", [(320, 180), (640, 360), (640, 480), (960, 540), (1920, 1080), (400, 720),
                                  (720, 1280), (5120, 1440), (1920, 300), (2560, 400)])
def test_the_overlay_screen_shows_the_example_between_its_text_and_the_hint(size, monkeypatch):
    p = load_protocol()
    assert p.overlay.marks_example and not any(s.marks_example for s in p.briefing)
    shown = render_screen(size, p.overlay.fill(), p.legend, p.continue_hint)
    assert shown.shape == (size[1], size[0], 3)
    assert _mask(shown, THREAT_RGB).any() and _mask(shown, MARK_RGB).any()
    # where the picture goes: a solid band in its place, on the screen drawn with and without it at one font size
    band = np.zeros_like(marks_example())
    band[...] = (255, 0, 255)
    monkeypatch.setattr(briefing, "marks_example", lambda: band)
    body_px = max(int(size[1] * 0.055), 10)
    surf, fits = briefing._layout(size, p.overlay.fill(), p.legend, p.continue_hint, body_px)
    while not fits and body_px > 10:  # the font size render_screen settles on
        body_px = max(int(body_px * 0.9), 10)
        surf, fits = briefing._layout(size, p.overlay.fill(), p.legend, p.continue_hint, body_px)
    img = pygame.surfarray.array3d(surf).swapaxes(0, 1)
    text, _ = briefing._layout(size, p.overlay.model_copy(update={"marks_example": False}).fill(), p.legend,
                               p.continue_hint, body_px)
    text_rows = _ink_rows(pygame.surfarray.array3d(text).swapaxes(0, 1))
    pic = _mask(img, (255, 0, 255))
    rows, cols = np.flatnonzero(pic.any(axis=1)), np.flatnonzero(pic.any(axis=0))
    hint_top = text_rows[np.flatnonzero(np.diff(text_rows) > 1)[-1] + 1]  # the hint: the last block of ink
    assert text_rows[text_rows < hint_top].max() < rows.min() and rows.max() < hint_top, "below the text, above the hint"
    assert pic[rows.min():rows.max() + 1, cols.min():cols.max() + 1].all(), "nothing drawn over the picture"
    # at least EXAMPLE_MIN_SCALE of the text column wide (the text shrinks to make room), unless the text is
    # at its smallest already (then as wide as fits: a window far wider than high)
    margin = max(int(0.06 * size[0]), 8)
    assert (fits and cols.size >= EXAMPLE_MIN_SCALE * (size[0] - 2 * margin)) or (not fits and body_px == 10)


@pytest.mark.parametrize("size", [(160, 90), (640, 12), (12, 640), (1, 1), (4097, 720)])
def test_any_window_size_draws_the_screen(size):
    p = load_protocol()
    shown = render_screen(size, p.overlay.fill(), p.legend, p.continue_hint)
    assert shown.shape == (size[1], size[0], 3)


def test_the_example_shows_every_kind_of_label_and_the_explanation_names_them(monkeypatch):
    """The picture has a cut-in label, a driver-type label and a small "!" tag (a mark past the labelled ones), and
    the explanation says what each means: the arrows, the percentage, the distance, the "!"."""
    from dt_highway import overlay

    heads: list[str] = []
    real = overlay.label_layout

    def spy(*args, **kwargs):
        out = real(*args, **kwargs)
        heads.extend(b.head for b in out if b.label is not None)  # a label drawn, not dropped
        return out

    monkeypatch.setattr(overlay, "label_layout", spy)
    marks_example.__wrapped__()  # not the cached picture: drawn again, through the spy
    assert sorted(set(heads)) == ["!", ">> CUTTING IN", "AGGRESSIVE DRIVER"]
    text = load_protocol().overlay.text
    for said in ('"CUTTING IN"', "the arrows point the way it would move", '"AGGRESSIVE DRIVER"', "percentage",
                 "metres", '"!"'):
        assert said in text
