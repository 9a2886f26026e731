"""The text screens of a keyboard trial: the keys' legend before it, the 3-2-1 countdown, the
pause and quit question (:func:`dialog`, drawn over the driving picture), the "Trial saved"
("Practice saved") screen after it, and plain screens between trials (:func:`card`, :func:`show_card`). A
full screen (:func:`card`) is drawn as a session's screens are (:func:`~dt_highway.hmi.briefing.render_screen`:
the same font, colours and layout, any text pygame's font can show), so that a session's screens and its
trials' look alike; what is drawn over the driving picture uses OpenCV's Hershey font. Never a
condition's name or a file path.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Sequence

import cv2
import numpy as np
import pygame  # without its banner: gymnasium, which dt_highway imports first, sets PYGAME_HIDE_SUPPORT_PROMPT

from dt_highway.hmi.briefing import Screen, render_screen
from dt_highway.hmi.keys import KeyEvent
from dt_highway.hmi.window import DRIVING_KEYS, PYGAME_KEYS, _key_names, _Signals, _Window

LEGEND = (
    ("Up", "throttle (hold)"),
    ("Down", "brake (hold)"),
    ("Left / Right", "change lane"),
    ("M", "mini-map on / off"),
    ("P", "pause"),
    ("Esc", "stop the trial (asks first)"),
)
"""The keys, as shown before a trial"""

END_SCREEN_S = 10.0
"""The "Trial saved" screen goes by itself after this long [s] (else only Enter dismisses it)"""

QUIT_LINES = ("Quit the trial?", "Esc: quit", "any other key: go on")
"""The question asked on the first Esc"""

PAUSE_LINES = ("PAUSED", "P: go on")
"""The pause screen's text"""

_ENTER = (pygame.K_RETURN, pygame.K_KP_ENTER)

_AMBER = (255, 230, 120)


def _text(img: np.ndarray, text: str, org: tuple[int, int], scale: float, colour: tuple[int, int, int] = (255, 255, 255),
          thick: int = 1, shadow: bool = True) -> None:
    font = cv2.FONT_HERSHEY_DUPLEX
    if shadow:
        cv2.putText(img, text, (org[0] + 1, org[1] + 1), font, scale, (0, 0, 0), thick + 1, cv2.LINE_AA)
    cv2.putText(img, text, org, font, scale, colour, thick, cv2.LINE_AA)


def _scale(h: int) -> float:
    return max(h / 720.0, 0.35)


def dialog(img: np.ndarray, lines: Iterable[str], colour: tuple[int, int, int] = _AMBER) -> list[tuple[int, int, int, int]]:
    """Draw a box with centred lines of text in the middle of ``img`` (in place): the first line
    large, the others smaller, one below the other.

    :param img: ``uint8 (H, W, 3)`` RGB
    :param lines: the text
    :param colour: the first line's colour (RGB)
    :return: each line's box ``(x0, y0, x1, y1)`` [px] (they never overlap)
    """
    h, w = img.shape[:2]
    s = _scale(h)
    font = cv2.FONT_HERSHEY_DUPLEX
    styles = [(1.4 * s, max(1, round(3 * s))) if i == 0 else (0.95 * s, max(1, round(2 * s))) for i, _ in enumerate(lines)]
    texts = list(lines)
    sizes = [cv2.getTextSize(t, font, sc, th) for t, (sc, th) in zip(texts, styles, strict=True)]
    gap, pad = max(4, int(18 * s)), max(6, int(24 * s))
    heights = [ch + base + th for ((_, ch), base), (_, th) in zip(sizes, styles, strict=True)]
    box_w = max(cw for (cw, _), _ in sizes) + 2 * pad
    box_h = sum(heights) + gap * (len(texts) - 1) + 2 * pad
    x0, y0 = max((w - box_w) // 2, 0), max((h - box_h) // 2, 0)
    region = img[y0:y0 + box_h, x0:x0 + box_w]
    region[:] = (region * 0.2).astype(np.uint8)
    cv2.rectangle(img, (x0, y0), (x0 + box_w - 1, y0 + box_h - 1), colour, 1)
    rects = []
    y = y0 + pad
    for i, (text, ((cw, ch), _base), (sc, th), lh) in enumerate(zip(texts, sizes, styles, heights, strict=True)):
        x = (w - cw) // 2
        _text(img, text, (x, y + ch + th // 2), sc, colour if i == 0 else (255, 255, 255), thick=th, shadow=False)
        rects.append((x, y, x + cw, y + lh))
        y += lh + gap
    return rects


def card(size: tuple[int, int], title: str, lines: list[str], *, legend: Sequence[tuple[str, str]] = (),
         hint: str = "") -> np.ndarray:
    """A plain screen with a title and paragraphs of text (start, break and end screens), drawn as a
    session's screens are (:func:`~dt_highway.hmi.briefing.render_screen`).

    :param size: ``(width, height)`` [px]
    :param title: the title
    :param lines: the text, one paragraph each (a long one is wrapped)
    :param legend: the keys' legend below the text: ``(key, what it does)`` pairs
    :param hint: the bottom line (``Press Enter to start``)
    :return: the picture, ``(height, width, 3)`` RGB
    """
    # model_construct: a trial's own text (its label, fixed words), not a protocol's, which the model checks
    screen = Screen.model_construct(title=title, text="\n\n".join(lines), keys=bool(legend), marks_example=False)
    return render_screen(size, screen, legend, hint)


def show_card(size: tuple[int, int], title: str, lines: list[str], timeout_s: float | None = None,
              fullscreen: bool = False, hint: str = "Press Enter to go on") -> bool:
    """Show a screen (e.g. a break between trials) until Enter is pressed.

    :param size: window size ``(width, height)`` [px]
    :param title: the title
    :param lines: the text, one paragraph each
    :param timeout_s: give up waiting after this long (``None``: wait for Enter)
    :param fullscreen: fill the screen
    :param hint: the bottom line
    :return: ``False`` when the participant pressed Esc, closed the window or a signal came
    """
    with _Signals() as signals:
        try:
            win = _Window(size, fullscreen, signals=signals)
            key = win.wait_key(card(size, title, lines, hint=hint), (*_ENTER, pygame.K_ESCAPE), timeout_s)
            return key != pygame.K_ESCAPE and not win.stopped
        finally:
            pygame.quit()


def _countdown(win: _Window) -> list[KeyEvent] | None:
    """3-2-1, one second each, noting the driving keys pressed and released meanwhile.

    :return: those key events, at negative trial times [s] (t = 0 is the end of the countdown);
        ``None`` when the window was closed or a signal came
    """
    names = _key_names()
    t_end = time.monotonic() + 3.0
    events: list[KeyEvent] = []
    pressed = pygame.key.get_pressed()  # a key already held on the keys screen (a real keyboard)
    events += [KeyEvent(-3.0, True, k) for k, v in PYGAME_KEYS.items() if k in DRIVING_KEYS and pressed[getattr(pygame, v)]]
    for n in (3, 2, 1):
        img = card(win.size, str(n), ["get ready"])
        win.show(img)
        while time.monotonic() < t_end - (n - 1):
            for ev in win.events():
                if ev.type in (pygame.KEYDOWN, pygame.KEYUP) and names.get(ev.key) in DRIVING_KEYS:
                    events.append(KeyEvent(round(time.monotonic() - t_end, 4), ev.type == pygame.KEYDOWN, names[ev.key]))
            if win.stopped:
                return None
            win.show(img)  # drawn again only after a resize or an expose
            win.clock.tick(60)
    return events


def _start_screens(win: _Window, label: str, legend: Sequence[tuple[str, str]] = LEGEND) -> list[KeyEvent] | None:
    """The keys, until Enter, then a count-down.

    :param win: the trial's window
    :param label: the trial's neutral name (``Trial 2 of 4``)
    :param legend: the keys' legend (a session's: its protocol's)
    :return: the key events of the countdown (:func:`_countdown`); ``None`` when the participant
        pressed Esc, closed the window or a signal came instead
    """
    pygame.event.clear((pygame.KEYDOWN, pygame.KEYUP))  # pressed while the trial was prepared: not an answer
    screen = card(win.size, f"{label}: the keys", [], legend=legend, hint="Press Enter to start")
    key = win.wait_key(screen, (*_ENTER, pygame.K_ESCAPE))
    if key is None or key == pygame.K_ESCAPE:
        return None
    return _countdown(win)


def _end_screen(win: _Window, status: str, end_reason: str, practice: bool = False) -> None:
    """"Trial saved" ("Practice saved" after a practice trial), until Enter (no other key) or :data:`END_SCREEN_S`;
    not when the window was closed or a signal came.

    :param status: the trial's status (``ended_by_collision`` says so on the screen)
    :param end_reason: why the trial ended
    :param practice: a practice trial (it does not count: the screen does not call it a trial)
    """
    if win.stopped or end_reason == "window closed":
        return
    what = "practice" if practice else "trial"
    early = [f"The {what} ended early: there was a collision."] if status == "ended_by_collision" else []
    win.wait_key(card(win.size, f"{what.capitalize()} saved", [*early, "Thank you."], hint="Press Enter to go on"),
                 _ENTER, END_SCREEN_S)
