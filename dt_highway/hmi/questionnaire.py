"""Questionnaires between trials: definitions from files, a pygame screen, scoring.

A questionnaire is a TOML file (:class:`Questionnaire`): a title, the participant's
instructions, one rating scale (integer points ``min..max`` in steps of ``step``, with end
anchors), the items (text, optional own anchors, ``reverse`` for reversed items) and a scoring
rule (``mean`` or ``sum`` of the items after reversal, ``min + max - value``). Two ship with the
package (:data:`QUESTIONNAIRE_DIR`):

* ``nasa_tlx``: NASA-TLX, raw (Hart & Staveland 1988): six 0-100 subscales in steps of 5;
  raw TLX = their unweighted mean.
* ``trust_jian2000``: trust in automation (Jian, Bisantz & Drury 2000): 12 items, 1-7; the
  score is the mean with the distrust items 1-5 reversed.

A lab adds its own by passing a file's path where a name is taken
(:func:`load_questionnaire`). A definition is checked when it is read: a mistake is one line
naming the file, the dotted key and what is allowed.

The screen (:func:`run_questionnaires`) shows one item at a time with the progress
("item 3 of 12"): Up/Down go to the previous/next item, Left/Right place the mark (first press:
the middle of the scale) and move it one step (held: repeated),
digits pick a point on a scale ``1..k`` (k <= 9),
Enter goes to the next item and on the last one finishes; a click on the scale places the mark,
a click on a progress dot opens that item, the Back/Next buttons act as Up/Enter. It cannot be
finished while an item is unanswered (it opens the first one and says so). Esc does nothing
(the participant cannot skip); closing the window stops the questionnaires (``completed``
false). A scripted answers file drives the same screens with the key presses that give those
answers (:func:`answer_keys`), so a session replays in tests.

The answers go to ``<trial dir>/questionnaires.json`` (rewritten after each questionnaire):
per questionnaire the answers per item, the score (:func:`score`), the wall-clock start and
end, the duration, and per item the time to its first answer, the time it was on screen and
how often it was changed.
"""

from __future__ import annotations

import json
import os
import re
import time
import tomllib
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Literal

import pygame
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from dt_highway.config import ConfigError, read_user_file
from dt_highway.hmi.briefing import TextFont
from dt_highway.hmi.window import open_display
from dt_highway.jsonio import dump_json, finite_number
from dt_highway.metrics.questionnaires import RESULTS_FILE, read_results

QUESTIONNAIRE_DIR = Path(__file__).with_name("questionnaires")
"""Where the shipped questionnaire definitions are (``<name>.toml``)"""
FORMAT_VERSION = 1
"""Version of the layout of :data:`RESULTS_FILE`"""


class Scale(BaseModel):
    """A questionnaire's rating scale: integer points from ``min`` to ``max`` in steps of ``step``.

    :param min: the lowest point (the left end)
    :param max: the highest point (the right end)
    :param step: the distance between two points
    :param low: the left end's anchor ("Very Low")
    :param high: the right end's anchor ("Very High")
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    min: int = Field(..., ge=-1000, le=1000, description="the lowest point (left end)")
    max: int = Field(..., ge=-1000, le=1000, description="the highest point (right end)")
    step: int = Field(1, ge=1, description="distance between two points")
    low: str = Field(..., min_length=1, max_length=40, description="anchor of the left end")
    high: str = Field(..., min_length=1, max_length=40, description="anchor of the right end")

    @model_validator(mode="after")
    def _points(self) -> Scale:
        if self.max <= self.min:
            raise ValueError(f"max ({self.max}) must be above min ({self.min})")
        if (self.max - self.min) % self.step:
            raise ValueError(f"max - min ({self.max - self.min}) must be a multiple of step ({self.step})")
        if not 2 <= self.n_points <= 101:
            raise ValueError(f"the scale has {self.n_points} points; allowed 2-101")
        return self

    @property
    def n_points(self) -> int:
        """How many points the scale has."""
        return (self.max - self.min) // self.step + 1

    @property
    def points(self) -> list[int]:
        """The scale's points, left to right."""
        return list(range(self.min, self.max + 1, self.step))

    @property
    def middle(self) -> int:
        """The point where the mark first appears (the middle one; left of the middle for an even count)."""
        return self.min + (self.n_points - 1) // 2 * self.step

    def check(self, value: Any) -> int:
        """A value, checked to be one of the scale's points.

        :param value: the value to check
        :return: the value, as an int
        :raises ValueError: naming the allowed values
        """
        if finite_number(value) is None or value != int(value) or int(value) not in range(self.min, self.max + 1, self.step):
            raise ValueError(f"{value!r} is not on the scale (allowed: {self.min} to {self.max} in steps of {self.step})")
        return int(value)


class Item(BaseModel):
    """One item (a statement or question) of a questionnaire.

    :param id: its key in the answers (``mental``; lower case, digits, ``_``)
    :param text: what the participant reads
    :param title: a heading above the text (NASA-TLX's "Mental Demand"), or empty
    :param low: the left end's anchor, when it differs from the scale's ("Perfect")
    :param high: the right end's anchor, when it differs from the scale's ("Failure")
    :param reverse: a reversed item: scored as ``min + max - value``
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    id: str = Field(..., pattern=r"^[a-z][a-z0-9_]{0,39}$", description="the item's key: lower case, digits, _")
    text: str = Field(..., min_length=1, max_length=300, description="what the participant reads")
    title: str = Field("", max_length=60, description="a heading above the text")
    low: str | None = Field(None, min_length=1, max_length=40, description="the left anchor, when not the scale's")
    high: str | None = Field(None, min_length=1, max_length=40, description="the right anchor, when not the scale's")
    reverse: bool = Field(False, description="scored as min + max - value")


class Questionnaire(BaseModel):
    """A questionnaire definition (one TOML file).

    :param name: its name (as ``--questionnaires`` takes it, and its key in the results)
    :param title: the heading on the screen
    :param citation: where it comes from (not shown to the participant)
    :param instructions: what the participant is asked, shown above every item
    :param scoring: ``mean`` or ``sum`` of the items after reversal
    :param score_label: what the score is called in the report
    :param scale: the rating scale of every item
    :param items: the items, in the order they are asked
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = Field(..., pattern=r"^[a-z][a-z0-9_]{0,39}$", description="lower case, digits, _")
    title: str = Field(..., min_length=1, max_length=60, description="the screen's heading")
    citation: str = Field("", max_length=300, description="the source (not shown)")
    instructions: str = Field("", max_length=400, description="shown above every item")
    scoring: Literal["mean", "sum"] = Field("mean", description="mean or sum of the items after reversal")
    score_label: str = Field("score", min_length=1, max_length=120, description="the score's name in the report")
    scale: Scale
    items: list[Item] = Field(..., min_length=1, max_length=100, description="the items, in order")

    @model_validator(mode="after")
    def _unique(self) -> Questionnaire:
        ids = [i.id for i in self.items]
        twice = sorted({i for i in ids if ids.count(i) > 1})
        if twice:
            raise ValueError(f"item ids must be unique (twice: {', '.join(twice)})")
        return self

    @property
    def score_range(self) -> tuple[float, float]:
        """The smallest and largest score."""
        n = len(self.items) if self.scoring == "sum" else 1
        return float(self.scale.min * n), float(self.scale.max * n)


def available_questionnaires() -> list[str]:
    """The names of the shipped questionnaires (:data:`QUESTIONNAIRE_DIR`).

    :return: the names, sorted
    """
    return sorted(p.stem for p in QUESTIONNAIRE_DIR.glob("*.toml"))


def load_questionnaire(name_or_path: str | Path) -> Questionnaire:
    """A questionnaire by name (a shipped one, :func:`available_questionnaires`) or by the path
    of a TOML file.

    :param name_or_path: ``"nasa_tlx"``, or ``"labs/my_scale.toml"``
    :return: the checked definition
    :raises ConfigError: one line: an unknown name (with the known ones), an unreadable file, or
        the file's dotted key and what is allowed
    """
    text = str(name_or_path)
    is_path = isinstance(name_or_path, Path) or text.endswith(".toml") or os.sep in text or "/" in text
    path = Path(text) if is_path else QUESTIONNAIRE_DIR / f"{text}.toml"
    if not is_path and not path.is_file():
        raise ConfigError(f"unknown questionnaire {text!r} (allowed: {', '.join(available_questionnaires())}, "
                          "or the path of a .toml file)")
    data = read_user_file(path, tomllib.loads, tomllib.TOMLDecodeError,
                          missing="questionnaire file {path} does not exist",
                          unreadable="questionnaire file {path} cannot be read ({err})",
                          malformed="questionnaire file {path} is not valid TOML ({err})")
    try:
        return Questionnaire.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(f"questionnaire file {path}: " + "; ".join(_error_line(e) for e in exc.errors())) from None


def _error_line(err: Any) -> str:
    """One mistake of a definition: its dotted key and what is allowed."""
    loc = tuple(err["loc"])
    dotted = ".".join(str(p) for p in loc) or "<file>"
    if err["type"] == "extra_forbidden":
        models: dict[str, type[BaseModel]] = {"items": Item, "scale": Scale}
        model = models.get(str(loc[0]), Questionnaire) if len(loc) > 1 else Questionnaire
        return f"unknown key '{dotted}' (allowed here: {', '.join(model.model_fields)})"
    if err["type"] == "missing":
        return f"{dotted} missing (required)"
    msg = str(err["msg"]).removeprefix("Value error, ")
    value = err.get("input")
    if isinstance(value, dict):  # a model's own check (scale: max above min; unique ids)
        return f"{dotted}: {msg}" if loc else msg
    return f"{dotted} = {value!r}: {msg}"


def score(definition: Questionnaire, answers: Mapping[str, Any]) -> dict[str, Any]:
    """A questionnaire's score from its answers: the ``mean`` (or ``sum``) of the items, a
    reversed item counted as ``min + max - value``.

    :param definition: the questionnaire
    :param answers: item id -> the point chosen, for every item
    :return: ``score``, ``scoring``, ``label``, ``range`` ``[lo, hi]`` and ``items`` (item id ->
        its value as scored, after reversal)
    :raises ValueError: one line, on a missing or unknown item or a value off the scale
    """
    ids = [i.id for i in definition.items]
    unknown = sorted(set(answers) - set(ids))
    if unknown:
        raise ValueError(f"{definition.name}: unknown item {unknown[0]!r} (items: {', '.join(ids)})")
    scored: dict[str, int] = {}
    sc = definition.scale
    for item in definition.items:
        if answers.get(item.id) is None:
            raise ValueError(f"{definition.name}.{item.id} is not answered")
        try:
            v = sc.check(answers[item.id])
        except ValueError as exc:
            raise ValueError(f"{definition.name}.{item.id} = {exc}") from None
        scored[item.id] = sc.min + sc.max - v if item.reverse else v
    total = float(sum(scored.values()))
    value = total / len(scored) if definition.scoring == "mean" else total
    return {"score": value, "scoring": definition.scoring, "label": definition.score_label,
            "range": list(definition.score_range), "items": scored}


# ----------------------------------------------------------------------------- scripted answers
def load_answers(path: str | Path) -> dict[str, Any]:
    """A scripted answers file (JSON or TOML): ``{questionnaire: {item: value}}``, or such a
    table per trial directory name (``{"P01-adas": {"nasa_tlx": {...}}}``), which a trial takes
    when its name is there.

    :param path: the answers file (``.json``, else read as TOML)
    :return: the file's table
    :raises ConfigError: one line naming the file, when it cannot be read or is not a table
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
        data = json.loads(text) if p.suffix.lower() == ".json" else tomllib.loads(text)
    except FileNotFoundError:
        raise ConfigError(f"answers file {p} does not exist") from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:  # JSON and TOML errors are ValueErrors
        raise ConfigError(f"answers file {p} cannot be read ({type(exc).__name__}: {exc})") from None
    if not isinstance(data, dict):
        raise ConfigError(f"answers file {p} must hold a table {{questionnaire: {{item: value}}}}")
    return data


def scripted_answers(data: Mapping[str, Any], definition: Questionnaire, trial: str = "",
                     where: str = "answers") -> dict[str, int]:
    """One questionnaire's answers from a scripted answers table (:func:`load_answers`), checked.

    :param data: the table
    :param definition: the questionnaire
    :param trial: the trial directory's name (its own table wins; a session's later attempt,
        ``P01-adas-retry1``, takes its trial's, ``P01-adas``, when it has none of its own)
    :param where: the file, for the error message
    :return: item id -> value, for every item
    :raises ConfigError: one line naming the missing or bad key and what is allowed
    """
    first_attempt = re.sub(r"-retry\d+$", "", trial)
    table = data.get(trial, data.get(first_attempt, data)) if trial else data
    answers = table.get(definition.name) if isinstance(table, dict) else None
    if not isinstance(answers, dict):
        raise ConfigError(f"{where}: no table {definition.name!r}" + (f" (for trial {trial})" if trial else ""))
    ids = [i.id for i in definition.items]
    out: dict[str, int] = {}
    for key in answers:
        if key not in ids:
            raise ConfigError(f"{where}: {definition.name}.{key} is not an item (items: {', '.join(ids)})")
    for item_id in ids:
        if item_id not in answers:
            raise ConfigError(f"{where}: {definition.name}.{item_id} missing (every item needs an answer)")
        try:
            out[item_id] = definition.scale.check(answers[item_id])
        except ValueError as exc:
            raise ConfigError(f"{where}: {definition.name}.{item_id} = {exc}") from None
    return out


def answer_keys(definition: Questionnaire, answers: Mapping[str, int]) -> list[int]:
    """The key presses that answer a questionnaire on its screen, item by item from the first:
    Right (the mark appears in the middle), Left or Right until the value, Enter.

    :param definition: the questionnaire
    :param answers: item id -> value, for every item
    :return: pygame key codes
    """
    keys: list[int] = []
    sc = definition.scale
    for item in definition.items:
        steps = (answers[item.id] - sc.middle) // sc.step
        keys.append(pygame.K_RIGHT)
        keys += [pygame.K_RIGHT if steps > 0 else pygame.K_LEFT] * abs(steps)
        keys.append(pygame.K_RETURN)
    return keys


# ----------------------------------------------------------------------------- the form's state
@dataclass
class Form:
    """The state of one questionnaire on screen: the answers so far, the item shown, the times.

    :param definition: the questionnaire
    :param values: the point chosen per item (``None``: not answered)
    :param index: the item shown (0-based)
    :param message: a line for the participant ("Please answer ...") or empty
    :param done: the participant finished (every item answered)
    """

    definition: Questionnaire
    values: list[int | None] = field(default_factory=list)
    index: int = 0
    message: str = ""
    done: bool = False
    t0: float = field(default_factory=time.monotonic)
    first_answer_s: list[float | None] = field(default_factory=list, init=False)  # per item, since t0 [s]
    on_screen_s: list[float] = field(default_factory=list, init=False)  # per item, time shown [s]
    changes: list[int] = field(default_factory=list, init=False)  # per item, how often its value changed
    _last: float = field(default=0.0, init=False, repr=False)

    def __post_init__(self) -> None:
        n = len(self.definition.items)
        self.values = self.values or [None] * n
        self.first_answer_s = [None] * n
        self.on_screen_s = [0.0] * n
        self.changes = [0] * n
        self._last = self.t0

    def tick(self) -> None:
        """Add the time since the last call to the item on screen."""
        now = time.monotonic()
        self.on_screen_s[self.index] += now - self._last
        self._last = now

    def go(self, index: int) -> None:
        """Show item ``index`` (clipped to the items).

        :param index: the item (0-based)
        """
        self.tick()
        self.index = min(max(index, 0), len(self.values) - 1)
        self.message = ""

    def set(self, value: int) -> None:
        """Answer the item shown with ``value`` (clipped to the scale).

        :param value: the point chosen
        """
        sc = self.definition.scale
        value = min(max(value, sc.min), sc.max)
        if self.values[self.index] != value:
            if self.first_answer_s[self.index] is None:
                self.first_answer_s[self.index] = time.monotonic() - self.t0
            self.values[self.index] = value
            self.changes[self.index] += 1
        self.message = ""

    def move(self, direction: int) -> None:
        """Left (``-1``) or Right (``+1``): the mark moves one step; the first press places it in the middle.

        :param direction: ``-1`` or ``+1``
        """
        current = self.values[self.index]
        sc = self.definition.scale
        self.set(sc.middle if current is None else current + direction * sc.step)

    def enter(self) -> None:
        """Enter: the next item; on the last one, finish, or open the first unanswered item."""
        last = len(self.values) - 1
        if self.values[self.index] is None:
            self.message = "Please choose a point on the scale first."
        elif self.index < last:
            self.go(self.index + 1)
        else:
            missing = [i for i, v in enumerate(self.values) if v is None]
            if missing:
                self.go(missing[0])
                self.message = f"Item {missing[0] + 1} is not answered yet."
            else:
                self.tick()
                self.done = True

    def key(self, key: int) -> None:
        """Handle one key press (module docstring).

        :param key: the pygame key code
        """
        n_points = self.definition.scale.n_points
        if key == pygame.K_UP:
            self.go(self.index - 1)
        elif key == pygame.K_DOWN:
            self.go(self.index + 1)
        elif key in (pygame.K_LEFT, pygame.K_RIGHT):
            self.move(-1 if key == pygame.K_LEFT else 1)
        elif key in (pygame.K_RETURN, pygame.K_KP_ENTER):
            self.enter()
        elif pygame.K_1 <= key <= pygame.K_9 and n_points <= 9 and self.definition.scale.points == list(
                range(1, n_points + 1)) and key - pygame.K_1 < n_points:  # a 1..k scale: the digits pick its points
            self.set(self.definition.scale.points[key - pygame.K_1])
        elif key == pygame.K_ESCAPE:
            self.message = "Please answer every item; Enter goes on."

    def click(self, pos: tuple[int, int], layout: Layout) -> None:
        """Handle a left click at ``pos`` [px] on the screen drawn with ``layout``.

        :param pos: where the click was ``(x, y)`` [px]
        :param layout: where the screen's parts were drawn (:func:`draw_form`)
        """
        x, y = pos
        if layout.scale_hit.collidepoint(x, y):
            frac = (x - layout.x0) / max(layout.x1 - layout.x0, 1)
            k = round(min(max(frac, 0.0), 1.0) * (self.definition.scale.n_points - 1))
            self.set(self.definition.scale.points[k])
        elif layout.back.collidepoint(x, y):
            self.go(self.index - 1)
        elif layout.next.collidepoint(x, y):
            self.enter()
        else:
            for i, dot in enumerate(layout.dots):
                if dot.collidepoint(x, y):
                    self.go(i)

    def handle(self, event: pygame.event.Event, layout: Layout) -> None:
        """Handle one pygame event (a key press or a left click).

        :param event: the event (others are ignored)
        :param layout: where the screen's parts were drawn (:func:`draw_form`)
        """
        if event.type == pygame.KEYDOWN:
            self.key(event.key)
        elif event.type == pygame.MOUSEBUTTONDOWN and getattr(event, "button", 1) == 1:
            self.click(event.pos, layout)

    def result(self) -> dict[str, Any]:
        """The answers, times and (when every item is answered) the score, as stored.

        :return: the questionnaire's record: title, answers, score, and per item its value and times
        """
        self.tick()
        d = self.definition
        answers = {item.id: v for item, v in zip(d.items, self.values, strict=True)}
        complete = all(v is not None for v in self.values)
        return {
            "title": d.title, "citation": d.citation, "completed": self.done and complete,
            "duration_s": round(time.monotonic() - self.t0, 3),
            "answers": answers,
            "score": score(d, answers) if complete else None,
            "items": [{"id": item.id, "value": v, "first_answer_s": None if t is None else round(t, 3),
                       "on_screen_s": round(s, 3), "changes": c}
                      for item, v, t, s, c in zip(d.items, self.values, self.first_answer_s, self.on_screen_s,
                                                  self.changes, strict=True)],
        }


# ----------------------------------------------------------------------------- drawing
BG, FG, DIM, ACCENT, MARK, WARN = (28, 30, 36), (240, 240, 240), (160, 165, 175), (90, 170, 255), (255, 200, 60), \
    (255, 150, 90)


@dataclass
class Layout:
    """Where the screen's parts were drawn (for the clicks) [px].

    :param x0: the scale's left end
    :param x1: the scale's right end
    :param y: the scale's line
    :param scale_hit: the area a click on the scale counts in
    :param back: the Back button
    :param next: the Next / Finish button
    :param dots: the progress dots, one per item
    """

    x0: int
    x1: int
    y: int
    scale_hit: pygame.Rect
    back: pygame.Rect
    next: pygame.Rect
    dots: list[pygame.Rect]


_FONTS: dict[int, TextFont] = {}


def _font(px: float) -> TextFont:
    """The font pygame ships (the same on every machine), spaced as the briefing's screens are (no kerning:
    :class:`~dt_highway.hmi.briefing.TextFont`), at ``px`` [px]."""
    size = max(10, int(px))
    if size not in _FONTS:
        _FONTS[size] = TextFont(size)
    return _FONTS[size]


def _fit(text: str, px: float, width: int) -> TextFont:
    """The font of at most ``px`` pixels in which ``text`` is at most ``width`` pixels wide (at least 40 %)."""
    size = px
    while size > 0.4 * px and _font(size).size(text)[0] > width:
        size *= 0.92
    return _font(size)


def _wrap(text: str, font: TextFont, width: int) -> list[str]:
    lines: list[str] = []
    for para in text.split("\n"):
        line = ""
        for word in para.split():
            trial = f"{line} {word}".strip()
            if line and font.size(trial)[0] > width:
                lines.append(line)
                line = word
            else:
                line = trial
        lines.append(line)
    return lines


def _balanced(text: str, font: TextFont, width: int) -> list[str]:
    """``text`` wrapped to ``width`` [px] in as few lines as it takes, the lines made about as long as each
    other (no single word left on the last line)."""
    lines = _wrap(text, font, width)
    narrower = width
    while len(lines) > 1 and narrower > width // 2:
        trial = _wrap(text, font, int(narrower * 0.95))
        if len(trial) > len(lines):
            break
        lines, narrower = trial, int(narrower * 0.95)
    return lines


def _blit(surface: pygame.Surface, text: str, font: TextFont, colour: tuple[int, int, int],
          anchor: str, pos: tuple[int, int]) -> pygame.Rect:
    img = font.render(text, True, colour)
    rect = img.get_rect(**{anchor: pos})
    surface.blit(img, rect)
    return rect


def _button(surface: pygame.Surface, rect: pygame.Rect, text: str, font: TextFont, active: bool) -> None:
    pygame.draw.rect(surface, ACCENT if active else (70, 74, 84), rect, border_radius=max(3, rect.h // 5))
    _blit(surface, text, font, FG if active else DIM, "center", rect.center)


def _draw_scale(surface: pygame.Surface, form: Form, x0: int, x1: int, y: int, s: float) -> None:
    d, item = form.definition, form.definition.items[form.index]
    sc, value = d.scale, form.values[form.index]
    n = sc.n_points
    pygame.draw.line(surface, FG, (x0, y), (x1, y), max(2, int(3 * s)))
    numbers = n <= 11
    f_num = _font(34 * s)
    for k in range(n):
        x = x0 + round(k * (x1 - x0) / (n - 1))
        tall = k in (0, n - 1) or (n % 2 and k == n // 2)
        h = int((26 if tall else 14) * s)
        pygame.draw.line(surface, FG, (x, y - h), (x, y + h), max(1, int(2 * s)))
        if numbers:
            _blit(surface, str(sc.points[k]), f_num, FG if sc.points[k] == value else DIM, "midtop", (x, y + int(34 * s)))
    f_anchor = _font(34 * s)
    below = y + int((80 if numbers else 40) * s)
    _blit(surface, item.low or sc.low, f_anchor, FG, "topleft", (x0 - int(10 * s), below))
    _blit(surface, item.high or sc.high, f_anchor, FG, "topright", (x1 + int(10 * s), below))
    if value is not None:
        x = x0 + round((value - sc.min) / (sc.max - sc.min) * (x1 - x0))
        r = int(15 * s) + 2
        pygame.draw.circle(surface, MARK, (x, y), r)
        pygame.draw.circle(surface, BG, (x, y), r, max(1, int(3 * s)))
    else:
        _blit(surface, "not answered yet: choose a point", _font(30 * s), WARN, "midbottom", ((x0 + x1) // 2, y - int(40 * s)))


def draw_form(surface: pygame.Surface, form: Form, header: str = "") -> Layout:
    """Draw a questionnaire's item screen on ``surface`` (any size; everything scales with it).

    :param surface: the window (or any surface)
    :param form: the questionnaire's state
    :param header: a line above the title ("Questionnaire 1 of 2"), or empty
    :return: where the scale, buttons and dots are (for the clicks)
    """
    w, h = surface.get_size()
    s = max(min(w / 1280, h / 720), 0.4)
    pad = int(40 * s)
    d = form.definition
    item, n = d.items[form.index], len(d.items)
    surface.fill(BG)
    top = pad // 2
    if header:
        top = _blit(surface, header, _font(28 * s), DIM, "topleft", (pad, top)).bottom + int(4 * s)
    progress = _blit(surface, f"item {form.index + 1} of {n}", _font(40 * s), ACCENT, "topright", (w - pad, top))
    title = _blit(surface, d.title, _fit(d.title, 48 * s, progress.left - 2 * pad), FG, "topleft", (pad, top))
    y = max(title.bottom, progress.bottom) + int(10 * s)
    f_instr = _font(30 * s)
    for line in _wrap(d.instructions, f_instr, w - 2 * pad):
        y = _blit(surface, line, f_instr, DIM, "topleft", (pad, y)).bottom
    y += int(30 * s)
    if item.title:
        y = _blit(surface, item.title, _font(52 * s), FG, "midtop", (w // 2, y)).bottom + int(8 * s)
    room = int(h * 0.56) - int(90 * s) - y  # above the scale
    size = 44 * s
    while size > 16 * s and len(_wrap(item.text, _font(size), int(w * 0.8))) * _font(size).get_linesize() > room:
        size *= 0.9  # a long item: smaller letters, so that the scale stays where it is
    f_text = _font(size)
    for line in _balanced(item.text, f_text, int(w * 0.8)):
        y = _blit(surface, line, f_text, FG, "midtop", (w // 2, y)).bottom
    x0, x1 = int(w * 0.14), int(w * 0.86)
    y_scale = max(y + int(90 * s), int(h * 0.56))
    _draw_scale(surface, form, x0, x1, y_scale, s)
    # bottom: message, progress dots, buttons, keys
    f_small = _font(28 * s)
    keys_y = h - pad // 2
    sc = d.scale
    digits = f" or {sc.min}-{sc.max}" if sc.n_points <= 9 and sc.points == list(range(1, sc.n_points + 1)) else ""
    hint = f"Up/Down: item    Left/Right{digits}: choose    Enter: " + ("finish" if form.index == n - 1 else "next") + \
        "    or click on the scale"
    _blit(surface, hint, f_small, DIM, "midbottom", (w // 2, keys_y))
    bh, bw = int(50 * s), int(150 * s)
    by = keys_y - int(30 * s) - bh
    back = pygame.Rect(pad, by, bw, bh)
    nxt = pygame.Rect(w - pad - bw, by, bw, bh)
    f_button = _font(34 * s)
    _button(surface, back, "Back", f_button, form.index > 0)
    _button(surface, nxt, "Finish" if form.index == n - 1 else "Next", f_button, form.values[form.index] is not None)
    gap = min(int(36 * s), (nxt.left - back.right - 2 * pad) // max(n, 1))
    r = max(3, min(int(9 * s), gap // 3))
    cx0 = w // 2 - gap * (n - 1) // 2
    dots = []
    for i, v in enumerate(form.values):
        c = (cx0 + i * gap, by + bh // 2)
        pygame.draw.circle(surface, ACCENT if v is not None else (90, 94, 104), c, r)
        if i == form.index:
            pygame.draw.circle(surface, FG, c, r + max(2, int(4 * s)), max(1, int(2 * s)))
        dots.append(pygame.Rect(c[0] - gap // 2, c[1] - bh // 2, gap, bh))
    if form.message:
        _blit(surface, form.message, _font(34 * s), WARN, "midbottom", (w // 2, by - int(12 * s)))
    hit = pygame.Rect(x0 - int(20 * s), y_scale - int(40 * s), x1 - x0 + int(40 * s), int(80 * s))
    return Layout(x0, x1, y_scale, hit, back, nxt, dots)


# ----------------------------------------------------------------------------- the run
def _now_iso() -> str:
    return datetime.now(UTC).isoformat(timespec="milliseconds")


def _write_atomic(path: Path, data: dict[str, Any]) -> None:
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(dump_json(data) + "\n", encoding="utf-8")
    os.replace(tmp, path)


def _ask(form: Form, header: str, script: Iterator[int] | None, fps: float) -> bool:
    """Run one questionnaire's screen until it is finished.

    :return: ``False`` when the window was closed first
    """
    clock = pygame.time.Clock()
    layout = _show(form, header)
    while not form.done:
        for event in pygame.event.get():
            if event.type == pygame.QUIT:
                return False
            if script is None:
                form.handle(event, layout)
        if script is not None:
            key = next(script, None)
            if key is None:  # cannot happen with answer_keys' presses: they finish the form
                raise RuntimeError(f"the scripted answers ran out before {form.definition.name} was finished")
            form.key(key)
        else:
            clock.tick(fps)
        layout = _show(form, header)
    return True


def _show(form: Form, header: str) -> Layout:
    """Draw the form in the window (whatever its size now) and show it."""
    surface = pygame.display.get_surface()
    if surface is None:
        raise RuntimeError("the questionnaire's window is gone")
    layout = draw_form(surface, form, header)
    pygame.display.flip()
    return layout


def run_questionnaires(window_size: tuple[int, int], names: list[str], trial_dir: Path,
                       answers_from: Path | None = None) -> dict[str, Any]:
    """Ask each named questionnaire in turn in the window and store the answers in
    ``<trial_dir>/questionnaires.json`` (rewritten after each questionnaire).

    An open pygame window (the session's) is used as it is and left open; otherwise one of
    ``window_size`` is opened and closed at the end.

    :param window_size: the window's size ``(width, height)`` [px], when one has to be opened
    :param names: the questionnaires, by name or path (:func:`load_questionnaire`)
    :param trial_dir: the trial's directory (made when missing)
    :param answers_from: a scripted answers file (:func:`load_answers`): the screens are driven
        with the key presses that give those answers
    :return: what was written: ``trial``, ``scripted``, ``completed`` (every questionnaire
        finished), ``questionnaires`` (name -> ``title``, ``citation``, ``completed``,
        ``started_at``/``ended_at`` (UTC, ISO 8601), ``duration_s`` [s], ``answers`` (item ->
        value), ``score`` (:func:`score`), ``items`` (per item: ``value``, ``first_answer_s`` [s],
        ``on_screen_s`` [s], ``changes``)) and ``scores`` (name -> score)
    :raises ConfigError: one line, on an unknown questionnaire, a bad definition or a bad
        answers file (before any window opens)
    """
    trial_dir = Path(trial_dir)
    definitions = [load_questionnaire(n) for n in names]
    scripts: list[list[int] | None] = [None] * len(definitions)
    if answers_from is not None:
        data = load_answers(answers_from)
        scripts = [answer_keys(d, scripted_answers(data, d, trial_dir.name, where=f"answers file {answers_from}"))
                   for d in definitions]
    trial_dir.mkdir(parents=True, exist_ok=True)
    out: dict[str, Any] = {"format_version": FORMAT_VERSION, "trial": trial_dir.name, "scripted": answers_from is not None,
                           "completed": False, "questionnaires": {}, "scores": {}}
    path = trial_dir / RESULTS_FILE
    owns_window = not (pygame.display.get_init() and pygame.display.get_surface() is not None)
    pygame.display.init()
    pygame.font.init()
    _FONTS.clear()  # fonts made before a pygame.quit() (a window closed since, e.g. `dt-highway drive`'s) are invalid
    repeat = pygame.key.get_repeat()
    try:
        if owns_window:
            open_display(window_size)
            pygame.display.set_caption("Questionnaire")
        pygame.key.set_repeat(400, 60)  # Left/Right held move the mark along a long scale [ms]
        # keys and clicks from before (a key still going at the trial's end) must not answer an item
        pygame.event.clear([pygame.KEYDOWN, pygame.KEYUP, pygame.MOUSEBUTTONDOWN, pygame.MOUSEBUTTONUP])
        for k, (d, keys) in enumerate(zip(definitions, scripts, strict=True)):
            header = f"Questionnaire {k + 1} of {len(definitions)}" if len(definitions) > 1 else ""
            started = _now_iso()
            form = Form(d)
            finished = _ask(form, header, iter(keys) if keys is not None else None, fps=30.0)
            entry = {"started_at": started, "ended_at": _now_iso(), **form.result()}
            out["questionnaires"][d.name] = entry
            if entry["score"] is not None:
                out["scores"][d.name] = entry["score"]["score"]
            _write_atomic(path, out)
            if not finished:
                return out
        out["completed"] = True
        _write_atomic(path, out)
        return out
    finally:
        if owns_window:
            pygame.display.quit()
        elif pygame.display.get_init():
            pygame.key.set_repeat(*repeat)


__all__ = ["FORMAT_VERSION", "QUESTIONNAIRE_DIR", "RESULTS_FILE", "Form", "Item", "Layout", "Questionnaire", "Scale",
           "answer_keys", "available_questionnaires", "draw_form", "load_answers", "load_questionnaire", "read_results",
           "run_questionnaires", "score", "scripted_answers"]
