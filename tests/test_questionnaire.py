"""Questionnaires between trials: the shipped definitions, scoring by hand, one-line errors for a
lab's own files, the pygame screen driven by scripted keys and by the mouse, the results file and
the report's questionnaire section on a hand-made study."""

import json
import math

import pandas as pd
import pygame
import pytest

from dt_highway.config import ConfigError
from dt_highway.hmi.questionnaire import (
    QUESTIONNAIRE_DIR,
    RESULTS_FILE,
    Form,
    answer_keys,
    available_questionnaires,
    draw_form,
    load_questionnaire,
    run_questionnaires,
    score,
    scripted_answers,
)
from dt_highway.metrics.trial_log import TrialWriter
from dt_highway.report import write_report

TLX = {"mental": 70, "physical": 10, "temporal": 55, "performance": 25, "effort": 60, "frustration": 0}
TRUST_IDS = ["deceptive", "underhanded", "suspicious", "wary", "harmful", "confident", "security", "integrity",
             "dependable", "reliable", "trust", "familiar"]
TRUST = dict(zip(TRUST_IDS, [2, 1, 3, 4, 1, 5, 6, 5, 6, 5, 6, 7], strict=True))


def trust_answers(t):
    """Answers whose trust score is ``t``: the trust items ``t``, the distrust items ``8 - t``."""
    return {k: (8 - t if i < 5 else t) for i, k in enumerate(TRUST_IDS)}


@pytest.fixture(autouse=True)
def offscreen(monkeypatch):
    monkeypatch.setenv("SDL_VIDEODRIVER", "offscreen")
    yield
    pygame.display.quit()


# ----------------------------------------------------------------------------- definitions and scoring
def test_shipped_definitions():
    assert available_questionnaires() == ["nasa_tlx", "trust_jian2000"]
    tlx = load_questionnaire("nasa_tlx")
    assert [i.id for i in tlx.items] == list(TLX)
    assert tlx.scale.points == list(range(0, 101, 5)) and tlx.scale.n_points == 21
    assert not any(i.reverse for i in tlx.items)
    perf = tlx.items[3]
    assert (perf.title, perf.low, perf.high) == ("Performance", "Perfect", "Failure")
    assert tlx.items[0].text == "How mentally demanding was the task?"
    trust = load_questionnaire("trust_jian2000")
    assert [i.id for i in trust.items] == TRUST_IDS
    assert [i.reverse for i in trust.items] == [True] * 5 + [False] * 7
    assert (trust.scale.min, trust.scale.max, trust.scale.low, trust.scale.high) == (1, 7, "not at all", "extremely")
    assert trust.items[0].text == "The system is deceptive." and trust.items[10].text == "I can trust the system."
    assert "Jian, Bisantz & Drury (2000)" in (QUESTIONNAIRE_DIR / "trust_jian2000.toml").read_text()


def test_raw_tlx_is_the_unweighted_mean():
    result = score(load_questionnaire("nasa_tlx"), TLX)
    assert result["score"] == pytest.approx(220 / 6)  # (70 + 10 + 55 + 25 + 60 + 0) / 6
    assert result["items"] == TLX and result["range"] == [0.0, 100.0]


def test_trust_reverses_the_distrust_items():
    result = score(load_questionnaire("trust_jian2000"), TRUST)
    # distrust items 2, 1, 3, 4, 1 -> 6, 7, 5, 4, 7 (29); trust items 5+6+5+6+5+6+7 = 40; (29 + 40) / 12
    assert result["score"] == pytest.approx(69 / 12) and result["score"] == pytest.approx(5.75)
    assert result["items"]["deceptive"] == 6 and result["items"]["familiar"] == 7
    assert score(load_questionnaire("trust_jian2000"), trust_answers(3))["score"] == pytest.approx(3.0)


@pytest.mark.parametrize(("answers", "message"), [
    ({**TLX, "mental": None}, "nasa_tlx.mental is not answered"),
    ({k: v for k, v in TLX.items() if k != "effort"}, "nasa_tlx.effort is not answered"),
    ({**TLX, "mental": 72}, "nasa_tlx.mental = 72 is not on the scale (allowed: 0 to 100 in steps of 5)"),
    ({**TLX, "boredom": 5}, "unknown item 'boredom'"),
])
def test_score_refuses_incomplete_or_off_scale_answers(answers, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        score(load_questionnaire("nasa_tlx"), answers)


def _lab_file(tmp_path, edit):
    text = edit((QUESTIONNAIRE_DIR / "trust_jian2000.toml").read_text())
    path = tmp_path / "lab_scale.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize(("edit", "message"), [
    (lambda t: t.replace("reverse = true", "reversed = true", 1),
     "items.0.reversed' (allowed here: id, text, title, low, high, reverse)"),
    (lambda t: t.replace("step = 1", "step = 4"), "scale: max - min (6) must be a multiple of step (4)"),
    (lambda t: t.replace('id = "wary"', 'id = "deceptive"'), "item ids must be unique (twice: deceptive)"),
    (lambda t: t.replace('scoring = "mean"', 'scoring = "median"'), "scoring = 'median': Input should be 'mean' or 'sum'"),
    (lambda t: t.replace("max = 7", "max = 1"), "scale: max (1) must be above min (1)"),
    (lambda t: t.split("[[items]]")[0], "items missing (required)"),
    (lambda t: t + "\n[[[", "is not valid TOML"),
])
def test_a_bad_definition_is_one_line_naming_the_key(tmp_path, edit, message):
    path = _lab_file(tmp_path, edit)
    with pytest.raises(ConfigError) as err:
        load_questionnaire(path)
    assert str(err.value).startswith(f"questionnaire file {path}") and message in str(err.value)
    assert "\n" not in str(err.value)


def test_an_unreadable_definition_file_fails_in_one_line_word_for_word(tmp_path):
    missing, folder, bad, latin = (tmp_path / n for n in ("none.toml", "dir.toml", "bad.toml", "latin.toml"))
    folder.mkdir()
    bad.write_text("name = \n")
    latin.write_bytes(b'name = "caf\xe9"\n')
    for path, expected in [
        (missing, f"questionnaire file {missing} does not exist"),
        (folder, f"questionnaire file {folder} cannot be read ([Errno 21] Is a directory: '{folder}')"),
        (latin, (f"questionnaire file {latin} cannot be read ('utf-8' codec can't decode byte 0xe9 in position 11: "
                 "invalid continuation byte)")),
        (bad, f"questionnaire file {bad} is not valid TOML (Invalid value (at line 1, column 8))"),
    ]:
        with pytest.raises(ConfigError) as err:
            load_questionnaire(path)
        assert str(err.value) == expected


def test_a_lab_file_loads_by_path_and_a_wrong_name_lists_the_known_ones(tmp_path):
    path = _lab_file(tmp_path, lambda t: t.replace('name = "trust_jian2000"', 'name = "lab_trust"')
                     .replace('scoring = "mean"', 'scoring = "sum"'))
    q = load_questionnaire(str(path))
    assert q.name == "lab_trust" and q.score_range == (12.0, 84.0)
    assert score(q, TRUST)["score"] == 69.0
    with pytest.raises(ConfigError, match=r"unknown questionnaire 'nasa' \(allowed: nasa_tlx, trust_jian2000, or the path"):
        load_questionnaire("nasa")
    with pytest.raises(ConfigError, match="does not exist"):
        load_questionnaire(tmp_path / "none.toml")


# ----------------------------------------------------------------------------- the screen
def test_keys_up_down_left_right_enter_and_no_finish_with_an_unanswered_item():
    form = Form(load_questionnaire("trust_jian2000"))
    form.key(pygame.K_RIGHT)  # first press: the middle point
    assert form.values[0] == 4
    form.key(pygame.K_LEFT)
    form.key(pygame.K_LEFT)
    assert form.values[0] == 2
    form.key(pygame.K_RETURN)
    assert form.index == 1
    form.key(pygame.K_RETURN)  # unanswered: stays
    assert form.index == 1 and "choose a point" in form.message
    form.key(pygame.K_DOWN)  # item 2 left unanswered
    for _ in range(9):
        form.key(pygame.K_7)  # digits pick a point on a 7-point scale
        form.key(pygame.K_RETURN)
    form.key(pygame.K_7)
    assert form.index == 11 and form.values[11] == 7
    form.key(pygame.K_RETURN)  # finish refused: item 2 (index 1) is open
    assert not form.done and form.index == 1 and form.message == "Item 2 is not answered yet."
    form.key(pygame.K_ESCAPE)  # Esc does not skip
    assert not form.done
    form.key(pygame.K_1)
    form.key(pygame.K_UP)
    assert form.index == 0
    form.go(11)
    form.key(pygame.K_RETURN)
    assert form.done and form.values[:3] == [2, 1, 7]
    assert form.changes[0] == 3 and form.first_answer_s[0] is not None


def test_mouse_clicks_on_the_scale_the_dots_and_the_buttons():
    pygame.display.init()
    pygame.font.init()
    surface = pygame.Surface((1280, 720))
    form = Form(load_questionnaire("nasa_tlx"))
    layout = draw_form(surface, form)
    x = layout.x0 + (layout.x1 - layout.x0) * 0.32
    click = pygame.event.Event(pygame.MOUSEBUTTONDOWN, button=1, pos=(x, layout.y + 5))
    form.handle(click, layout)
    assert form.values[0] == 30  # 0.32 of 20 steps -> 6.4 -> point 6 = 30
    form.handle(pygame.event.Event(pygame.MOUSEBUTTONDOWN, button=1, pos=(layout.x1 + 10, layout.y)), layout)
    assert form.values[0] == 100  # just beyond the right end: the end
    form.handle(pygame.event.Event(pygame.MOUSEBUTTONDOWN, button=1, pos=layout.next.center), layout)
    assert form.index == 1
    layout = draw_form(surface, form)
    form.handle(pygame.event.Event(pygame.MOUSEBUTTONDOWN, button=1, pos=layout.dots[4].center), layout)
    assert form.index == 4
    form.handle(pygame.event.Event(pygame.MOUSEBUTTONDOWN, button=1, pos=layout.back.center), layout)
    assert form.index == 3
    form.handle(pygame.event.Event(pygame.MOUSEBUTTONDOWN, button=3, pos=(layout.x0, layout.y)), layout)
    assert form.values[3] is None  # a right click does nothing


def test_answer_keys_reach_every_value():
    tlx = load_questionnaire("nasa_tlx")
    keys = answer_keys(tlx, TLX)
    form = Form(tlx)
    for k in keys:
        form.key(k)
    assert form.done and dict(zip(TLX, form.values, strict=True)) == TLX
    # mental 70 from the middle 50: Right (places 50), Right x4, Enter
    assert keys[:6] == [pygame.K_RIGHT] * 5 + [pygame.K_RETURN]


def test_scripted_answers_are_checked():
    tlx = load_questionnaire("nasa_tlx")
    with pytest.raises(ConfigError, match=r"^a.json: nasa_tlx.effort missing"):
        scripted_answers({"nasa_tlx": {k: v for k, v in TLX.items() if k != "effort"}}, tlx, where="a.json")
    with pytest.raises(ConfigError, match=r"nasa_tlx.mental = 7 is not on the scale"):
        scripted_answers({"nasa_tlx": {**TLX, "mental": 7}}, tlx, where="a.json")
    for odd in (math.inf, math.nan):  # TOML's inf and nan: on no scale (an OverflowError before)
        with pytest.raises(ConfigError, match=rf"nasa_tlx.mental = {odd} is not on the scale"):
            scripted_answers({"nasa_tlx": {**TLX, "mental": odd}}, tlx, where="a.json")
    with pytest.raises(ConfigError, match=r"no table 'nasa_tlx'"):
        scripted_answers({"trust_jian2000": TRUST}, tlx, where="a.json")
    per_trial = {"P01-adas": {"nasa_tlx": {**TLX, "mental": 0}}, "nasa_tlx": TLX}
    assert scripted_answers(per_trial, tlx, "P01-adas")["mental"] == 0
    assert scripted_answers(per_trial, tlx, "P02-adas")["mental"] == 70
    # a session's later attempt takes its trial's table, unless it has its own
    assert scripted_answers(per_trial, tlx, "P01-adas-retry2")["mental"] == 0
    own = {**per_trial, "P01-adas-retry2": {"nasa_tlx": {**TLX, "mental": 5}}}
    assert scripted_answers(own, tlx, "P01-adas-retry2")["mental"] == 5


def test_a_scripted_run_through_the_screens_writes_the_answers(tmp_path):
    answers = tmp_path / "answers.json"
    answers.write_text(json.dumps({"nasa_tlx": TLX, "trust_jian2000": TRUST}))
    trial = tmp_path / "trials" / "P01-adas"
    out = run_questionnaires((640, 360), ["nasa_tlx", "trust_jian2000"], trial, answers_from=answers)
    stored = json.loads((trial / RESULTS_FILE).read_text())
    assert stored == json.loads(json.dumps(out))
    assert stored["completed"] and stored["scripted"] and stored["trial"] == "P01-adas"
    assert stored["scores"] == {"nasa_tlx": pytest.approx(220 / 6), "trust_jian2000": pytest.approx(5.75)}
    tlx = stored["questionnaires"]["nasa_tlx"]
    assert tlx["answers"] == TLX and tlx["completed"]
    assert tlx["duration_s"] >= 0 and tlx["started_at"] <= tlx["ended_at"]
    assert [i["id"] for i in tlx["items"]] == list(TLX)
    # each item's changes: the first press places 50, then one per step (frustration 0: 1 + 10)
    assert [i["changes"] for i in tlx["items"]] == [5, 9, 2, 6, 3, 11]
    assert all(i["first_answer_s"] is not None and i["on_screen_s"] >= 0 for i in tlx["items"])
    assert stored["questionnaires"]["trust_jian2000"]["answers"] == TRUST
    assert not pygame.display.get_init()  # the window it opened is closed


def test_closing_the_window_stops_and_keeps_an_open_window(tmp_path):
    answers = tmp_path / "answers.toml"
    answers.write_text("[nasa_tlx]\n" + "".join(f"{k} = {v}\n" for k, v in TLX.items()))
    pygame.display.init()
    pygame.display.set_mode((320, 180))  # the session's window
    pygame.event.post(pygame.event.Event(pygame.QUIT))
    out = run_questionnaires((640, 360), ["nasa_tlx"], tmp_path / "t", answers_from=answers)
    assert not out["completed"] and not out["questionnaires"]["nasa_tlx"]["completed"]
    assert out["questionnaires"]["nasa_tlx"]["score"] is None and out["scores"] == {}
    assert pygame.display.get_surface() is not None  # not ours: left open
    assert json.loads((tmp_path / "t" / RESULTS_FILE).read_text())["completed"] is False


def test_the_live_loop_takes_keys_from_the_window_and_drops_stale_ones(tmp_path, monkeypatch):
    tlx = load_questionnaire("nasa_tlx")
    pygame.display.init()
    pygame.display.set_mode((640, 360))
    for key in [pygame.K_RETURN, pygame.K_RIGHT]:  # pressed before the questionnaire opened: dropped
        pygame.event.post(pygame.event.Event(pygame.KEYDOWN, key=key))
    pygame.event.post(pygame.event.Event(pygame.QUIT))
    out = run_questionnaires((640, 360), ["nasa_tlx"], tmp_path / "a")
    assert out["questionnaires"]["nasa_tlx"]["answers"] == dict.fromkeys(TLX)
    clear = pygame.event.clear
    monkeypatch.setattr(pygame.event, "clear", lambda *a, **k: None)  # keep the presses posted below
    for key in answer_keys(tlx, TLX):
        pygame.event.post(pygame.event.Event(pygame.KEYDOWN, key=key))
    out = run_questionnaires((640, 360), ["nasa_tlx"], tmp_path / "b")
    clear()
    assert out["completed"] and not out["scripted"] and out["questionnaires"]["nasa_tlx"]["answers"] == TLX


def test_bad_names_and_answers_fail_before_any_window(tmp_path):
    with pytest.raises(ConfigError, match="unknown questionnaire 'tlx'"):
        run_questionnaires((640, 360), ["tlx"], tmp_path / "t")
    bad = tmp_path / "a.json"
    bad.write_text(json.dumps({"nasa_tlx": {**TLX, "effort": 101}}))
    with pytest.raises(ConfigError, match="nasa_tlx.effort = 101 is not on the scale"):
        run_questionnaires((640, 360), ["nasa_tlx"], tmp_path / "t", answers_from=bad)
    assert not (tmp_path / "t").exists() and not pygame.display.get_init()


# ----------------------------------------------------------------------------- the report
HZ = 2


def write_trial(root, participant, cond, n=20):
    meta = {"driver": "keyboard", "condition": cond, "pair": None, "seed": 7, "participant": participant,
            "simulation_frequency_hz": HZ, "config": {"highway": {"duration": n / HZ}}}
    with TrialWriter(root / "trials" / f"{participant}-{cond}", meta) as log:
        for k in range(n):
            log.step({"t_s": (k + 1) / HZ, "x_m": 20.0 * (k + 1) / HZ, "y_m": 4.0, "lane": 1, "speed_mps": 20.0,
                      "accel_mps2": 0.0, "leader_id": -1, "gap_m": math.inf, "closing_mps": 0.0, "ttc_s": math.inf,
                      "drac_mps2": 0.0, "headway_s": math.inf, "crashed": False, "ttc_contact": False,
                      "ttc2d_s": math.inf, "ttc2d_id": -1, "ttc2d_contact": False, "action_accel_mps2": 0.0,
                      "action_lane": 0.0, "keys": "", "overlay_ids": "", "overlay_labels": ""})


RAW_TLX = {"baseline": [40, 50, 60], "adas": [30, 45, 45], "sham": [35, 50, 50]}
TRUST_SCORE = {"adas": [6, 5, 4], "sham": [4, 4, 3]}


def test_the_report_summarises_questionnaires_per_condition(tmp_path):
    root = tmp_path / "study"
    table = {}
    for p, participant in enumerate(("P01", "P02", "P03")):
        for cond in RAW_TLX:
            write_trial(root, participant, cond)
            table[f"{participant}-{cond}"] = {"nasa_tlx": dict.fromkeys(TLX, RAW_TLX[cond][p])}
            if cond in TRUST_SCORE:
                table[f"{participant}-{cond}"]["trust_jian2000"] = trust_answers(TRUST_SCORE[cond][p])
    answers = tmp_path / "session_answers.json"  # one file for the whole session, a table per trial
    answers.write_text(json.dumps(table))
    for name, entry in table.items():
        run_questionnaires((320, 180), list(entry), root / "trials" / name, answers_from=answers)
    write_report(root)
    summary = json.loads((root / "summary.json").read_text())
    q = summary["questionnaires"]
    assert list(q["questionnaires"]) == ["q_nasa_tlx", "q_trust_jian2000"]
    assert q["condition_order"] == ["baseline", "adas", "sham"]
    tlx = {c: q["conditions"][c]["q_nasa_tlx"] for c in RAW_TLX}
    assert [tlx[c]["mean"] for c in RAW_TLX] == pytest.approx([50.0, 40.0, 45.0])
    assert tlx["baseline"]["sd"] == pytest.approx(10.0) and tlx["adas"]["sd"] == pytest.approx(math.sqrt(75))
    assert q["conditions"]["adas"]["q_trust_jian2000"]["mean"] == pytest.approx(5.0)
    assert q["conditions"]["sham"]["q_trust_jian2000"]["mean"] == pytest.approx(11 / 3)
    assert q["conditions"]["baseline"]["q_trust_jian2000"]["n"] == 0
    comps = {(c["a"], c["b"]): c["tests"] for c in q["comparisons"]}
    assert set(comps) == {("baseline", "adas"), ("baseline", "sham"), ("sham", "adas")}
    assert comps[("baseline", "adas")]["q_nasa_tlx"]["mean_diff"] == pytest.approx(-10.0)
    assert "q_trust_jian2000" not in comps[("baseline", "adas")]  # no trust after baseline trials
    trust = comps[("sham", "adas")]["q_trust_jian2000"]
    # differences 2, 1, 1: mean 4/3, SD 1/sqrt(3), t = 4 with 2 df: p = 1 - 4 / sqrt(18)
    assert trust["n_pairs"] == 3 and trust["mean_diff"] == pytest.approx(4 / 3)
    assert trust["ttest_p"] == pytest.approx(1 - 4 / math.sqrt(18))
    assert trust["effect_size_dz"] == pytest.approx(4 / 3 * math.sqrt(3))
    html = (root / "report.html").read_text()
    assert "<h2>Questionnaires</h2>" in html and "Raw TLX (mean of the six subscales, 0-100)" in html
    assert "50.00 &plusmn; 10.00" in html and "Questionnaires: adas &minus; sham" in html
    assert "NASA Task Load Index: Raw TLX" in html and "not asked" in html  # trust after baseline trials
    metrics = pd.read_csv(root / "metrics.csv").set_index("trial")
    assert metrics.loc["P02-adas", "q_nasa_tlx"] == 45 and math.isnan(metrics.loc["P02-baseline", "q_trust_jian2000"])


@pytest.mark.parametrize(("score", "kept"), [
    ({"score": 40.0, "label": "Raw TLX", "range": [0, "x"]}, True),  # a damaged range: unbounded, the score kept
    ({"score": 40.0, "label": "Raw TLX", "range": 7}, True),
    ({"score": 40.0, "label": "Raw TLX", "range": [100, 0]}, True),
    ({"score": "x", "label": "Raw TLX", "range": [0, 100]}, False),  # not a score: left out
    ({"score": True, "label": "Raw TLX", "range": [0, 100]}, False),
])
def test_a_damaged_questionnaires_file_does_not_sink_the_report(tmp_path, score, kept):
    root = tmp_path / "study"
    for cond in ("baseline", "adas"):
        write_trial(root, "P01", cond)
        (root / "trials" / f"P01-{cond}" / "questionnaires.json").write_text(
            json.dumps({"questionnaires": {"nasa_tlx": {"title": "NASA-TLX", "score": score}}}))
    write_report(root)
    summary = json.loads((root / "summary.json").read_text())
    assert ("questionnaires" in summary) == kept
    if kept:
        assert summary["questionnaires"]["conditions"]["adas"]["q_nasa_tlx"]["mean"] == 40.0


def test_no_questionnaire_files_no_section(tmp_path):
    root = tmp_path / "study"
    for cond in ("baseline", "adas"):
        write_trial(root, "P01", cond)
    write_report(root)
    assert "questionnaires" not in json.loads((root / "summary.json").read_text())
    assert "Questionnaires" not in (root / "report.html").read_text()


def test_the_questionnaire_is_drawn_with_the_screens_unkerned_font(monkeypatch):
    # pygame.font (SDL_ttf) kerned "Questionn aire", "t rial", "follow ing" apart (seen in a real window)
    def no_font(*_a, **_k):
        raise AssertionError("the questionnaire uses TextFont (no kerning), not pygame.font.Font")

    from dt_highway.hmi import questionnaire as q

    pygame.display.init()
    monkeypatch.setattr(q, "_FONTS", {})
    monkeypatch.setattr(pygame.font, "Font", no_font)
    surface = pygame.Surface((960, 540))
    for name in ("nasa_tlx", "trust_jian2000"):
        draw_form(surface, Form(load_questionnaire(name)), "Questionnaire 1 of 2")
        pixels = pygame.surfarray.array3d(surface).reshape(-1, 3)
        assert len({tuple(p) for p in pixels[::7]}) > 2  # text and scale drawn on the background
