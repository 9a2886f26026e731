"""What a participant reads in a session: the briefing, the explanation of the overlay, the screen
before each trial, the end of the session, from a protocol file (TOML, validated), and the
window that shows those screens.

The default protocol is ``dt_highway/hmi/protocols/default.toml`` (:data:`DEFAULT_PROTOCOL`); a lab
copies it, changes the texts and passes its copy with ``dt-highway session --protocol FILE``.
A protocol's texts never show a condition's name: there is no placeholder for it, a text that
mentions ``sham`` or ``placebo`` is refused, and the overlay is explained by one screen shared by
every overlay condition (``adas``, ``adas-type``, ``adas-threat``, ``sham``, ``sham-*``), so that
a participant cannot tell the real warnings from the placebo by what they read. Placeholders:
``{label}`` (the trial's neutral name, ``Trial 2 of 4``), ``{number}``, ``{total}`` and
``{duration}`` (``2 minutes``).

Screens are drawn with pygame's font (any text it can show, not only ASCII) at the window's size,
shrunk until they fit. :class:`ScreenWindow` shows them and waits for Enter (Backspace goes back
in the briefing, Esc twice ends the session); a scripted session (``--keys-from``) shows each
screen once without waiting and can save it as a PNG.
"""

from __future__ import annotations

import re
import string
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pygame  # without its banner: gymnasium, which dt_highway imports first, sets PYGAME_HIDE_SUPPORT_PROMPT
import pygame.freetype
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from dt_highway.choices import DEFAULT_PROTOCOL
from dt_highway.config import ConfigError, read_toml
from dt_highway.hmi.marks_example import marks_example
from dt_highway.hmi.window import open_display

PLACEHOLDERS = ("label", "number", "total", "duration")
"""The placeholders a protocol's texts may use"""

HIDDEN_WORDS = ("sham", "placebo")
"""Words a participant must never read (they would tell the placebo condition apart)"""

BACKGROUND = (28, 28, 28)
TITLE_COLOUR = (255, 230, 120)
TEXT_COLOUR = (235, 235, 235)
HINT_COLOUR = (150, 150, 150)


def _check_text(text: str) -> str:
    """A participant's text, checked: known placeholders only, no hidden word."""
    try:
        names = [name for _, name, _, _ in string.Formatter().parse(text) if name is not None]
    except ValueError as err:
        raise ValueError(f"bad braces ({err}; write {{{{ and }}}} for a literal brace)") from None
    for name in names:
        if name not in PLACEHOLDERS:
            raise ValueError(f"unknown placeholder {{{name}}} (allowed: {', '.join('{' + p + '}' for p in PLACEHOLDERS)})")
    m = re.search(r"\b(" + "|".join(HIDDEN_WORDS) + r")\b", text, re.IGNORECASE)
    if m:
        raise ValueError(f"mentions '{m.group(1)}': a participant must not be told which overlay is the placebo")
    return text


class Screen(BaseModel):
    """One screen a participant reads.

    :param title: the heading
    :param text: the body (a blank line starts a paragraph; long lines are wrapped)
    :param keys: show the keys legend below the text
    :param marks_example: show a picture of the warning marks below the text (the ``overlay`` screen:
        :mod:`~dt_highway.hmi.marks_example`)
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    title: str = Field(..., min_length=1, max_length=120, description="the heading")
    text: str = Field("", max_length=4000, description="the body; a blank line starts a paragraph")
    keys: bool = Field(False, description="show the keys legend below the text")
    marks_example: bool = Field(False, description="show a picture of the warning marks below the text")

    @field_validator("title", "text")
    @classmethod
    def _texts(cls, v: str) -> str:
        return _check_text(v)

    def fill(self, **values: Any) -> Screen:
        """The screen with its placeholders filled.

        :param values: ``label``, ``number``, ``total``, ``duration``
        :return: a copy with the title and text filled (a placeholder not given: empty)
        """
        full = {p: values.get(p, "") for p in PLACEHOLDERS}
        return self.model_copy(update={"title": self.title.format(**full), "text": self.text.format(**full)})


class QuestionnairePlan(BaseModel):
    """Which questionnaires follow a trial that counts (never a practice trial), by its kind.

    :param baseline: after a trial without overlay
    :param overlay: after a trial with the overlay (every overlay condition, the sham ones too)
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    baseline: list[str] = Field(default_factory=lambda: ["nasa_tlx"], description="after a trial without overlay")
    overlay: list[str] = Field(default_factory=lambda: ["nasa_tlx", "trust_jian2000"],
                               description="after a trial with the overlay (adas and sham alike)")

    @field_validator("baseline", "overlay")
    @classmethod
    def _names(cls, v: list[str]) -> list[str]:
        if any(not name.strip() for name in v):
            raise ValueError("a questionnaire's name (or .toml path) must not be empty")
        if len(set(v)) != len(v):
            raise ValueError("names a questionnaire twice")
        return v

    def for_condition(self, overlay: bool) -> list[str]:
        """The questionnaires after a trial.

        :param overlay: the trial's condition shows the overlay (:func:`~dt_highway.conditions.shows_overlay`)
        :return: the questionnaires' names (or ``.toml`` paths), in order
        """
        return list(self.overlay if overlay else self.baseline)


class Protocol(BaseModel):
    """A session protocol: the texts a participant reads, the practice length, the questionnaires.

    :param name: the protocol's name (logged with the session)
    :param practice_duration_s: each practice trial's length [s]
    :param trial_label: a trial's neutral name (placeholders ``{number}``, ``{total}``)
    :param practice_label: a practice trial's neutral name
    :param continue_hint: the line at the bottom of every screen
    :param back_hint: added to it in the briefing, from its second screen
    :param legend: the keys legend: ``[key, what it does]`` pairs
    :param briefing: the screens before the first trial
    :param overlay: the overlay's explanation, before the first trial with it (any overlay condition)
    :param practice: before each practice trial
    :param after_practice: after the last practice trial (``None``: none)
    :param trial: before each trial that counts
    :param stopped: after a trial stopped before its end (Enter: drive it again, Esc: end the session)
    :param end: the end of the session
    :param questionnaires: which questionnaires follow which trials
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = Field("default", min_length=1, max_length=64, description="the protocol's name (logged)")
    practice_duration_s: float = Field(30.0, gt=0.0, le=3600.0, description="each practice trial's length [s]")
    trial_label: str = Field("Trial {number} of {total}", min_length=1, description="a trial's neutral name")
    practice_label: str = Field("Practice {number} of {total}", min_length=1, description="a practice trial's name")
    continue_hint: str = Field("Press Enter to continue", description="the bottom line of every screen")
    back_hint: str = Field("Backspace: back", description="added to it in the briefing")
    legend: list[tuple[str, str]] = Field(
        default_factory=lambda: [("Up", "throttle (hold)"), ("Down", "brake (hold)"), ("Left / Right", "change lane"),
                                 ("M", "mini-map on / off"), ("P", "pause"), ("Esc", "stop the trial (asks first)")],
        min_length=1, description="the keys legend: [key, what it does] pairs (at least one)")
    briefing: list[Screen] = Field(default_factory=list, description="the screens before the first trial")
    overlay: Screen = Field(..., description="the overlay's explanation (one text for every overlay condition)")
    practice: Screen = Field(..., description="before each practice trial")
    after_practice: Screen | None = Field(None, description="after the last practice trial")
    trial: Screen = Field(..., description="before each trial that counts")
    stopped: Screen = Field(..., description="after a trial stopped before its end")
    end: Screen = Field(..., description="the end of the session")
    questionnaires: QuestionnairePlan = Field(default_factory=QuestionnairePlan)

    @field_validator("trial_label", "practice_label", "continue_hint", "back_hint")
    @classmethod
    def _texts(cls, v: str) -> str:
        return _check_text(v)

    @field_validator("legend")
    @classmethod
    def _legend(cls, v: list[tuple[str, str]]) -> list[tuple[str, str]]:
        for pair in v:
            _check_text(pair[0] + " " + pair[1])
        return v


def _model_at(loc: Sequence[Any]) -> type[BaseModel] | None:
    """The protocol's model (a screen, the questionnaire plan) at a location, list indices skipped."""
    model: type[BaseModel] = Protocol
    for part in loc:
        if isinstance(part, int):
            continue
        f = model.model_fields.get(str(part))
        ann = f.annotation if f is not None else None
        inner = [a for a in getattr(ann, "__args__", ()) if isinstance(a, type) and issubclass(a, BaseModel)]
        if isinstance(ann, type) and issubclass(ann, BaseModel):
            model = ann
        elif inner:  # list[Screen], Screen | None
            model = inner[0]
        else:
            return None
    return model


def _describe(err: Any) -> str:
    """One mistake in a protocol file: its dotted key and what is allowed (the text itself not repeated)."""
    loc = tuple(err["loc"])
    dotted = ".".join(str(x) for x in loc)
    kind, msg = err["type"], str(err["msg"]).removeprefix("Value error, ")
    if kind == "extra_forbidden":
        parent = _model_at(loc[:-1])
        return f"unknown key '{dotted}' (allowed here: {', '.join(parent.model_fields) if parent else '?'})"
    if kind == "missing":
        parent = _model_at(loc[:-1])
        f = parent.model_fields.get(str(loc[-1])) if parent else None
        return f"{dotted} missing" + (f" ({f.description})" if f is not None and f.description else "")
    if kind == "value_error":
        return f"{dotted}: {msg}"
    shown = repr(err.get("input"))
    return f"{dotted} = {shown if len(shown) <= 40 else shown[:37] + '...'}: {msg}"


def load_protocol(path: str | Path | None = None) -> Protocol:
    """Read and check a protocol file.

    :param path: the TOML file (``None``: :data:`DEFAULT_PROTOCOL`)
    :return: the protocol
    :raises ConfigError: one line naming the file and each bad key with what is allowed
    """
    p = Path(path) if path is not None else DEFAULT_PROTOCOL
    if p.is_dir():
        raise ConfigError(f"protocol file {p} is a directory: give a TOML file, e.g. {DEFAULT_PROTOCOL.name}")
    data = read_toml(p, "protocol file")
    try:
        protocol = Protocol.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(f"protocol file {p}: " + "; ".join(_describe(e) for e in exc.errors())) from None

    def beside(name: str) -> str:  # a questionnaire file named by a relative path: beside the protocol
        q = Path(name)
        return str(p.parent / q) if name.endswith(".toml") and not q.is_absolute() and (p.parent / q).is_file() else name

    q = protocol.questionnaires
    plan = q.model_copy(update={"baseline": [beside(n) for n in q.baseline], "overlay": [beside(n) for n in q.overlay]})
    return protocol.model_copy(update={"questionnaires": plan})


def format_duration(seconds: float) -> str:
    """A trial's length as a participant reads it: ``30 seconds``, ``1 minute``, ``2 minutes 30 seconds``.

    :param seconds: the length [s] (rounded to whole seconds)
    :return: the length in words
    """
    s = max(int(round(seconds)), 0)
    mins, secs = divmod(s, 60)
    parts = ([f"{mins} minute{'s' if mins != 1 else ''}"] if mins else []) + \
            ([f"{secs} second{'s' if secs != 1 else ''}"] if secs or not mins else [])
    return " ".join(parts)


# ----------------------------------------------------------------------------- drawing
DEFAULT_FONT_SCALE = 0.6875
"""pygame's default font at ``pygame.font.Font(None, px)`` is drawn at ``px`` times this [pt at 72 dpi]"""


class TextFont:
    """pygame's default font (freesansbold) without kerning, with the methods of ``pygame.font.Font``
    the screens use.

    ``pygame.font`` (SDL_ttf) applies the font's kerning table, whose pairs in freesansbold are
    off by a pixel or two at every size: "a bout", "sa fe", "contin ue". ``pygame.freetype`` with
    kerning off spaces the letters by their advances only.

    :param px: size as ``pygame.font.Font(None, px)`` takes it [px]
    """

    def __init__(self, px: int) -> None:
        if not pygame.freetype.get_init():
            pygame.freetype.init()
        self._ft = pygame.freetype.Font(None, px * DEFAULT_FONT_SCALE)
        self._ft.kerning = False
        self._ft.pad = True  # every line as high as the font, the baselines aligned

    def size(self, text: str) -> tuple[int, int]:
        """Width and height of ``text`` drawn [px].

        :param text: the text
        :return: ``(width, height)`` [px]
        """
        r = self._ft.get_rect(text)
        return r.width, r.height

    def get_linesize(self) -> int:
        """Distance between lines [px].

        :return: the line height [px]
        """
        return int(self._ft.get_sized_height(0))

    def render(self, text: str, antialias: bool, colour: tuple[int, int, int],
               background: tuple[int, int, int] | None = None) -> pygame.Surface:
        """``text`` drawn in ``colour`` (on ``background``, else transparent); ``antialias`` as pygame's (always on).

        :param text: the text
        :param antialias: ignored (kept for ``pygame.font.Font.render``'s signature)
        :param colour: the letters' RGB colour
        :param background: the RGB background colour (``None``: transparent)
        :return: the drawn text
        """
        surf, _ = self._ft.render(text, colour, background)
        return surf


def _wrap(font: TextFont, text: str, width: int) -> list[str]:
    """Lines of ``text`` no wider than ``width`` [px] (a blank line between paragraphs)."""
    lines: list[str] = []
    for para in re.split(r"\n\s*\n", text.strip()):
        words = para.split()
        line = ""
        for word in words:
            trial = f"{line} {word}" if line else word
            if font.size(trial)[0] <= width or not line:
                line = trial
            else:
                lines.append(line)
                line = word
        lines.append(line)
        lines.append("")
    return lines[:-1] if lines else []


def _layout(size: tuple[int, int], screen: Screen, legend: Sequence[tuple[str, str]], hint: str,
            body_px: int) -> tuple[pygame.Surface, bool]:
    """Draw ``screen`` with a body font of ``body_px``; :return: the picture and whether it fits."""
    w, h = size
    surf = pygame.Surface(size)
    surf.fill(BACKGROUND)
    margin = max(int(0.06 * w), 8)
    title_font = TextFont(max(int(body_px * 1.8), 12))
    body = TextFont(body_px)
    small = TextFont(max(int(body_px * 0.85), 10))
    y = int(0.07 * h)
    for line in _wrap(title_font, screen.title, w - 2 * margin):
        surf.blit(title_font.render(line, True, TITLE_COLOUR), (margin, y))
        y += title_font.get_linesize()
    y += body.get_linesize() // 2
    line_h = body.get_linesize()
    for line in _wrap(body, screen.text, w - 2 * margin):
        if line:
            surf.blit(body.render(line, True, TEXT_COLOUR), (margin, y))
        y += line_h if line else line_h // 2
    if screen.keys and legend:
        y += line_h // 2
        col = max(body.size(k)[0] for k, _ in legend) + 2 * body.size(" ")[0]
        for key, what in legend:
            surf.blit(body.render(key, True, TITLE_COLOUR), (margin + line_h, y))
            surf.blit(body.render(what, True, TEXT_COLOUR), (margin + line_h + col, y))
            y += line_h
    hint_y = h - small.get_linesize() - int(0.04 * h)
    if hint:
        surf.blit(small.render(hint, True, HINT_COLOUR), (margin, hint_y))
    if screen.marks_example:
        return surf, _draw_example(surf, (margin, y + line_h // 2), (w - 2 * margin, hint_y - line_h // 2))
    return surf, y <= hint_y - line_h // 2


EXAMPLE_MIN_SCALE = 0.6
"""The example picture of the marks is drawn at least this fraction of its width on the screen [-]
(else the text is shrunk to make room)"""


def _draw_example(surf: pygame.Surface, at: tuple[int, int], limit: tuple[int, int]) -> bool:
    """Draw the example picture of the marks at ``at`` [px], as wide as the text column ``limit[0]`` and
    ending above ``limit[1]`` [px] (aspect kept); :return: whether it is drawn at least
    :data:`EXAMPLE_MIN_SCALE` of the column's width."""
    band = marks_example()
    bh, bw = band.shape[:2]
    scale = min(limit[0] / bw, (limit[1] - at[1]) / bh)
    size = (int(bw * scale), int(bh * scale))
    if min(size) < 1:
        return False
    interpolation = cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR
    pic = np.ascontiguousarray(cv2.resize(band, size, interpolation=interpolation))
    surf.blit(pygame.image.frombuffer(pic.tobytes(), size, "RGB"), (at[0] + (limit[0] - size[0]) // 2, at[1]))
    return size[0] >= EXAMPLE_MIN_SCALE * limit[0]


def render_screen(size: tuple[int, int], screen: Screen, legend: Sequence[tuple[str, str]] = (), hint: str = "",
                  note: str = "") -> np.ndarray:
    """A screen as the participant sees it, at the window's size, its text shrunk until it fits.

    :param size: ``(width, height)`` [px]
    :param screen: the screen (placeholders filled: :meth:`Screen.fill`)
    :param legend: the keys legend (drawn when ``screen.keys``)
    :param hint: the bottom line (``Press Enter to continue``)
    :param note: a line drawn over the bottom of the screen (the question whether to end the session)
    :return: ``uint8 (H, W, 3)`` RGB
    """
    if not pygame.font.get_init():
        pygame.font.init()
    body_px = max(int(size[1] * 0.055), 10)
    surf, fits = _layout(size, screen, legend, hint, body_px)
    while not fits and body_px > 10:
        body_px = max(int(body_px * 0.9), 10)
        surf, fits = _layout(size, screen, legend, hint, body_px)
    img = np.ascontiguousarray(pygame.surfarray.array3d(surf).swapaxes(0, 1))
    if note:
        font = TextFont(max(int(body_px * 1.1), 12))
        text = font.render(note, True, TITLE_COLOUR, (0, 0, 0))
        band = np.ascontiguousarray(pygame.surfarray.array3d(text).swapaxes(0, 1))
        bh, bw = band.shape[:2]
        y0, x0 = max(size[1] - 3 * bh, 0), max((size[0] - bw) // 2, 0)
        img[y0:y0 + bh, x0:x0 + min(bw, size[0] - x0)] = band[:, :min(bw, size[0] - x0)]
    return img


# ----------------------------------------------------------------------------- the window
ENTER = (pygame.K_RETURN, pygame.K_KP_ENTER)


@dataclass
class ScreenWindow:
    """The window that shows a session's screens and waits for the participant's key.

    :param size: window size ``(width, height)`` [px] (screens are drawn at the window's actual size)
    :param fullscreen: fill the screen
    :param scripted: show each screen once and go on without waiting (a scripted session)
    :param save_dir: save each screen shown here as ``NN-<name>.png`` (``None``: not saved)
    :param on_frame: called with every picture shown (tests)
    :param caption: the window's title (neutral: no condition, no path)
    :param min_show_s: keys pressed sooner after a screen appears are ignored (a key still held
        from the trial, a double press) [s]
    :param stop_requested: asked while waiting; ``True`` ends the wait as if the window were closed
        (a SIGTERM)
    """

    size: tuple[int, int]
    fullscreen: bool = False
    scripted: bool = False
    save_dir: Path | None = None
    on_frame: Callable[[np.ndarray], None] | None = None
    caption: str = "dt-highway"
    min_show_s: float = 0.4
    stop_requested: Callable[[], bool] = lambda: False
    shown: list[str] = field(default_factory=list)

    def open(self) -> None:
        """Open the window now when none is open (a trial's window stays open in a session), e.g. for the
        questionnaires to use it."""
        self._surface()

    def _surface(self) -> pygame.Surface:
        """The window's surface (opened when none is: :func:`~dt_highway.hmi.window.open_display`)."""
        if not pygame.display.get_init() or pygame.display.get_surface() is None:
            open_display(self.size, self.fullscreen)  # the same kind of window a trial opens: it keeps this one
        pygame.display.set_caption(self.caption)
        surface = pygame.display.get_surface()
        assert surface is not None
        return surface

    def _show(self, img: np.ndarray) -> None:
        surface = self._surface()
        pic = pygame.image.frombuffer(img.tobytes(), (img.shape[1], img.shape[0]), "RGB")
        if pic.get_size() != surface.get_size():
            pic = pygame.transform.smoothscale(pic, surface.get_size())
        surface.blit(pic, (0, 0))
        pygame.display.flip()
        if self.on_frame is not None:
            self.on_frame(img)

    def _save(self, name: str, img: np.ndarray) -> None:
        self.shown.append(name)
        if self.save_dir is not None:
            self.save_dir.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(self.save_dir / f"{len(self.shown):02d}-{name}.png"), img[..., ::-1])

    def ask(self, name: str, draw: Callable[[tuple[int, int], str], np.ndarray], choices: Mapping[int, str],
            confirm_quit: str = "") -> str:
        """Show a screen until one of ``choices``' keys is pressed.

        :param name: what the screen is (file name of its screenshot, the session log)
        :param draw: the screen's picture at a size ``(width, height)`` [px], with a note drawn over it (``""``: none)
        :param choices: pygame key -> answer; the first one is a scripted session's answer
        :param confirm_quit: when not empty, Esc asks this question first (a second Esc answers ``quit``)
        :return: the answer, or ``closed`` when the window was closed (or a stop was requested)
        """
        note = ""
        img = draw(self._surface().get_size(), note)
        self._save(name, img)
        self._show(img)
        if self.scripted:
            return next(iter(choices.values()))
        pygame.event.clear()
        shown_at = time.monotonic()
        clock = pygame.time.Clock()
        while True:
            if self.stop_requested():
                return "closed"
            for ev in pygame.event.get():
                if ev.type == pygame.QUIT:
                    return "closed"
                if ev.type in (pygame.VIDEORESIZE, pygame.WINDOWSIZECHANGED):
                    self._show(draw(self._surface().get_size(), note))
                    continue
                if ev.type != pygame.KEYDOWN or time.monotonic() - shown_at < self.min_show_s:
                    continue
                if confirm_quit and ev.key == pygame.K_ESCAPE:
                    if note:
                        return "quit"
                    note = confirm_quit
                elif ev.key in choices:
                    if not note or choices[ev.key] == "quit":
                        return choices[ev.key]
                    note = ""  # the question is answered: go on
                else:
                    continue
                self._show(draw(self._surface().get_size(), note))
            clock.tick(30)

    def close(self) -> None:
        """Close the window."""
        pygame.quit()


__all__ = ["DEFAULT_PROTOCOL", "HIDDEN_WORDS", "PLACEHOLDERS", "Protocol", "QuestionnairePlan", "Screen", "ScreenWindow",
           "format_duration", "load_protocol", "render_screen"]
