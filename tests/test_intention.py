"""The twin's lane-change intention: hand-built fix histories, the wall to the truth, determinism,
configuration errors, the evaluation's bookkeeping and its command on tiny inputs."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from dt_highway.cli import main
from dt_highway.config import ConfigError, DTConfig, IntentionConfig, TwinConfig, load_config, validate
from dt_highway.env import DTHighwayEnv
from dt_highway.evaluation.intent import (
    Episode,
    Truth,
    Warning,
    cut_in_leads,
    cut_in_scores,
    runs_at,
    view_samples,
    warning_runs,
    warning_time_s,
)
from dt_highway.evaluation.intent_train import dataset, fit
from dt_highway.labels import NORMAL
from dt_highway.twin import CloudTwin, FixStore, GnssFix, HighwayMap
from dt_highway.twin.intention import (
    NO_LANE,
    OWN_FEATURES,
    SIDE_FEATURES,
    IntentionEstimator,
    IntentionInputs,
    LearnedIntention,
    intention_inputs,
)
from dt_highway.twin.tagger import DriverRecord

ROOT = Path(__file__).resolve().parents[1]
ROAD = HighwayMap(4.0, 3)
TINY = ["--set", "highway.vehicles_count=10", "--set", "highway.duration=4", "--set", "twin.preroll_s=6",
        "--set", "highway.lanes_count=3", "--set", "traffic.population_size=40"]


def _track(vid, y_of_t, x0=0.0, v=25.0, t_end=10.0, seconds=2.5, hz=10.0):
    """Noise-free fixes of one vehicle at ``hz`` up to ``t_end``: x = x0 + v t, y = y_of_t(t), course from dy/dt."""
    out = []
    for k in range(int(seconds * hz) + 1):
        t = t_end - seconds + k / hz
        y = y_of_t(t)
        vy = (y_of_t(t + 1e-3) - y_of_t(t - 1e-3)) / 2e-3
        out.append(GnssFix(vid, t, x0 + v * t, y, math.hypot(v, vy), math.atan2(vy, v), t + 0.1))
    return out


def _drift(t, start=9.2, y0=8.0, vy=-2.0):
    """Lane 2's centre until ``start``, then toward lane 1 at ``vy``."""
    return y0 + vy * max(0.0, t - start)


def _fixes():
    return _track(0, lambda t: 4.0, x0=0.0) + _track(1, _drift, x0=10.0) + _track(2, lambda t: 0.0, x0=30.0)


def _scene():
    """The ego (0) in lane 1; car 1 in lane 2 just ahead of it, drifting toward the ego's lane at 2 m/s for
    the last 0.8 s (still in lane 2), no record (the prior); car 2 steady in lane 0's centre, tagged normal."""
    store = FixStore(30.0)
    store.add(_fixes())
    records = {2: DriverRecord(2, 0.0, observed_s=60.0, tag=NORMAL, confidence=0.98)}
    return store, records


@pytest.mark.parametrize("model", ["learned", "physics"])
def test_a_car_drifting_toward_the_ego_lane_is_predicted_to_cut_in_and_a_steady_one_is_not(model):
    store, records = _scene()
    est = IntentionEstimator(IntentionConfig(model=model), ROAD)
    table = est.estimate(store, records, now_s=10.0, ego_id=0)
    assert 0 not in table  # the ego is context, not judged
    drifting = table.intents(1)
    steady = table.intents(2)
    assert [i.horizon_s for i in drifting] == [1.0, 2.0, 3.0]
    for i in drifting:
        assert i.target_lane == 1  # the ego's lane
        assert i.p_change > 0.7
        assert 0 < i.p_target <= i.p_change + 1e-12
    for i in steady:
        assert i.p_change < 0.1
        assert i.target_lane == 1  # lane 0 has only one neighbour
    assert drifting[0].p_change <= drifting[1].p_change + 1e-9 <= drifting[2].p_change + 2e-9


def test_the_inputs_are_what_the_fixes_say():
    store, records = _scene()
    x = intention_inputs(store, records, ROAD, 10.0, ego_id=0)
    assert list(x.vehicle_ids) == [1, 2]
    assert list(x.lane) == [2, 2 - 2]
    i = 0
    left = x.side[i, 0]
    assert x.side_ok[i].tolist() == [True, False]  # lane 2 of 3: only a left neighbour
    # over the last 0.6 s the car moved 2 m/s toward the left (lane 1), from the course
    assert left[SIDE_FEATURES.index("vlat_06")] == pytest.approx(2.0, abs=0.05)
    t = np.arange(9.1, 10.05, 0.1)  # the fixes of the last second: a least-squares slope over them
    assert left[SIDE_FEATURES.index("vlat_fit")] == pytest.approx(-np.polyfit(t, [_drift(u) for u in t], 1)[0])
    # the ego is in the left lane, 10 m behind: the car's bumper is 5 m ahead of the ego's
    assert left[SIDE_FEATURES.index("ego_in_side")] == 1.0
    assert left[SIDE_FEATURES.index("ego_dx_side")] * 50 == pytest.approx(10.0, abs=1e-6)
    assert left[SIDE_FEATURES.index("ego_gap_side")] * 10 == pytest.approx(5.0, abs=1e-6)
    assert left[SIDE_FEATURES.index("ego_is_side_follower")] == 1.0
    assert x.own[i, OWN_FEATURES.index("p_aggressive")] == pytest.approx(0.2)  # the prior
    assert x.own[1, OWN_FEATURES.index("p_aggressive")] == pytest.approx(0.02)


def test_too_few_or_old_fixes_give_no_intents():
    store = FixStore(30.0)
    store.add(_track(5, lambda t: 4.0, seconds=0.1))  # 2 fixes
    store.add(_track(6, lambda t: 4.0, t_end=5.0))  # newest fix 5 s old
    table = IntentionEstimator(IntentionConfig(), ROAD).estimate(store, {}, now_s=10.0)
    assert table.intents(5) == () and table.intents(6) == ()


def test_at_1_hz_the_window_reaches_back_to_three_fixes():
    store = FixStore(30.0)
    store.add(_track(7, lambda t: 4.0, seconds=2.0, hz=1.0))  # fixes at 8, 9 and 10 s: two within the last 2 s
    table = IntentionEstimator(IntentionConfig(), ROAD).estimate(store, {}, now_s=10.5)
    assert len(table.intents(7)) == 3


def test_a_lane_without_neighbours_has_no_target():
    road = HighwayMap(4.0, 1)
    store = FixStore(30.0)
    store.add(_track(1, lambda t: 0.0))
    table = IntentionEstimator(IntentionConfig(), road).estimate(store, {}, now_s=10.0)
    assert all(i.target_lane == NO_LANE and i.p_change == 0.0 and i.p_target == 0.0 for i in table.intents(1))


def test_the_twin_picture_is_each_car_now_from_its_fixes_and_tags():
    from dt_highway.twin.intention import twin_picture

    store, records = _scene()
    pic = twin_picture(store, records, now_s=10.0, prior_aggressive=0.2)
    assert pic.vehicle_ids.tolist() == [0, 1, 2] and pic.t_s == 10.0 and len(pic) == 3
    # noise-free fixes at 25 m/s: the position now is where the car is at 10 s, whatever the fixes' ages
    assert pic.x_m == pytest.approx([250.0, 260.0, 280.0])
    assert pic.speed_mps[[0, 2]] == pytest.approx([25.0, 25.0])
    assert pic.y_m[0] == pytest.approx(4.0) and pic.y_m[2] == pytest.approx(0.0)
    # car 1 drifts toward lane 1 at 2 m/s from 9.2 s: 7.2 m at 9.6 s, 6.4 m at 10 s, the mean of the last 0.5 s 6.8 m
    assert pic.y_m[1] == pytest.approx(6.8) and pic.lateral_speed_mps[1] == pytest.approx(-2.0)
    assert pic.lateral_speed_mps[[0, 2]] == pytest.approx([0.0, 0.0])
    assert pic.p_aggressive == pytest.approx([0.2, 0.2, 0.02])  # no record: the prior; car 2 tagged normal at 0.98
    assert len(twin_picture(FixStore(30.0), {}, now_s=10.0)) == 0


# ----------------------------------------------------------------------------- the wall
# (the twin's imports: tests/test_wall.py::test_the_twin_imports_nothing_that_holds_the_truth)


def test_the_estimate_depends_only_on_the_store_and_the_records():
    """Same fixes and records, anything else different (a twin fed by a simulator, or by hand): same intents."""
    store, records = _scene()
    twin = CloudTwin(TwinConfig(), ROAD)
    twin.receive(_fixes())
    twin.advance(10.2)  # every fix has arrived (0.1 s latency)
    # the twin's tagger made its own records: a hand-made estimate from its store and records is the same
    again = IntentionEstimator(IntentionConfig(), ROAD).estimate(twin.store, dict(twin.tagger.records), 10.2)
    assert twin.intent_table is not None
    assert twin.intent_table.intents(1) == again.intents(1)
    by_hand = IntentionEstimator(IntentionConfig(), ROAD).estimate(store, records, 10.2)
    assert np.array_equal(by_hand.inputs.side[:, :, :7], again.inputs.side[:, :, :7])  # what the fixes say
    view = {v.vehicle_id: v for v in twin.view_around(0)}
    assert view[1].intents == twin.intent_table.intents(1)


# ----------------------------------------------------------------------------- determinism
def _trace(seed):
    cfg = load_config(None, ["highway.vehicles_count=10", "highway.duration=3", "twin.preroll_s=8",
                             "traffic.population_size=40"])
    env = DTHighwayEnv(config=cfg.to_dict())
    env.reset(seed=seed)
    out = []
    for _ in range(15):
        _, _, term, trunc, info = env.step(1)
        out.append(json.dumps(info["twin"], default=float))
        if term or trunc:
            break
    env.close()
    return out


def test_same_seed_same_intents_in_info():
    a, b = _trace(3), _trace(3)
    assert a == b
    last = json.loads(a[-1])
    assert last and all(len(v["intents"]) == 3 for v in last)
    assert {"horizon_s", "p_change", "target_lane", "p_target"} <= set(last[0]["intents"][0])


def test_training_is_deterministic():
    rng = np.random.default_rng(0)
    n, f = 300, len(OWN_FEATURES) + len(SIDE_FEATURES)
    data = {"x": rng.normal(size=(n, 2, f)).astype(np.float32), "side_ok": np.ones((n, 2), bool),
            "y": rng.integers(-1, 3, size=(n, 8)).astype(np.int8)}
    a = fit(data, epochs=2, batch=64, hidden=8)
    b = fit(data, epochs=2, batch=64, hidden=8)
    for (wa, ba), (wb, bb) in zip(a[2], b[2], strict=True):
        assert np.array_equal(wa, wb) and np.array_equal(ba, bb)
    assert a[3] == b[3]


# ----------------------------------------------------------------------------- configuration
@pytest.mark.parametrize("key, value, message", [
    ("horizons_s", [2.0, 1.0], "twin.intention"),
    ("horizons_s", [], "twin.intention"),
    ("operating_horizon_s", 2.5, "operating_horizon_s must be one of horizons_s"),
    ("model", "magic", "twin.intention.model"),
    ("threshold", 1.5, "twin.intention.threshold"),
    ("update_hz", 0, "twin.intention.update_hz"),
    ("weights", "no/such/file.npz", "weights file not found"),
    ("colour", "red", "twin.intention.colour"),
])
def test_config_errors_name_the_key(key, value, message):
    with pytest.raises(ConfigError) as err:
        validate({"twin": {"intention": {key: value}}})
    assert message in str(err.value) and "\n" not in str(err.value)


def test_horizons_outside_the_learned_range_are_refused_when_the_twin_is_made():
    cfg = validate({"twin": {"intention": {"horizons_s": [1.0, 6.0], "operating_horizon_s": 1.0}}})
    with pytest.raises(ConfigError, match=r"twin.intention: the learned intention model covers horizons 0.5-4 s"):
        CloudTwin(cfg.twin, ROAD)
    CloudTwin(validate({"twin": {"intention": {"horizons_s": [1.0, 6.0], "operating_horizon_s": 1.0,
                                                "model": "physics"}}}).twin, ROAD)


def test_the_section_is_dumped_only_when_changed():
    assert "intention" not in DTConfig().to_dict()["twin"]
    dumped = validate({"twin": {"intention": {"threshold": 0.61}}}).to_dict()
    assert dumped["twin"]["intention"]["threshold"] == 0.61
    assert validate(dumped).twin.intention.threshold == 0.61


def test_the_shipped_weights_load_without_pickles():
    model = LearnedIntention.load(None, (1.0, 2.0, 3.0))
    assert model.trained_horizons_s[0] <= 1.0 and model.trained_horizons_s[-1] >= 3.0
    with np.load(ROOT / "dt_highway" / "twin" / "intention_weights.npz", allow_pickle=False) as z:
        assert all(z[k].dtype != object for k in z.files)


# ----------------------------------------------------------------------------- evaluation bookkeeping
def _truth_rows():
    """Car 5 in lane 2, centre in lane 1 from t = 3.0 on, its body over the ego's lane from 2.5 on; car 6 stays."""
    rows = []
    for k in range(61):
        t = round(k * 0.1, 9)
        rows.append((t, 5, 2 if t < 3.0 - 1e-9 else 1, t >= 2.5 - 1e-9))
        rows.append((t, 6, 0, False))
    return np.array(rows, dtype=float)


def test_round_two_weights_load_by_name_and_the_round_two_world_pins_them():
    """The earlier weights stay reachable by name, so round 2's world and the RL policies trained on it
    see the intents they were trained with; a name that is not shipped is a missing file."""
    old = LearnedIntention.load("round2", (1.0, 2.0, 3.0))
    new = LearnedIntention.load(None, (1.0, 2.0, 3.0))
    with np.load(ROOT / "dt_highway" / "twin" / "intention_weights_round2.npz", allow_pickle=False) as z:
        assert np.array_equal(old.layers[0][0], z["W0"]) and str(z["meta_seeds"]) == "1000-1059"
    assert not np.array_equal(old.layers[0][0], new.layers[0][0])
    r2 = load_config(ROOT / "envs" / "highway-trial-r2.toml")
    assert (r2.twin.intention.weights, r2.twin.intention.threshold) == ("round2", 0.7)
    with pytest.raises(ConfigError, match=r"weights file not found: round3 \(a .npz file, or 'round2'\)"):
        validate({"twin": {"intention": {"weights": "round3"}}})


def test_truth_labels_by_hand():
    truth = Truth(_truth_rows(), 0.1)
    rows = truth.rows_at(np.array([5, 5, 6, 6, 7]), np.array([2.0, 1.0, 2.0, 5.5, 2.0]))
    assert rows[-1] == -1  # never on the road
    known, changed, new = truth.labels(rows[:4], np.array([2.0, 1.0, 2.0, 5.5]), 1.5)
    assert changed.tolist() == [True, False, False, False]  # 3.0 - 2.0 <= 1.5; 3.0 - 1.0 > 1.5
    assert known.tolist() == [True, True, True, False]  # car 6's track ends at 6.0 < 5.5 + 1.5
    assert new[0] == 1
    assert truth.overlaps_between(5, 2.0, 2.6) and not truth.overlaps_between(5, 0.0, 2.4)


def _episode(warned):
    """Views every 0.1 s; car 5 (20 m ahead, target lane 1 = the ego's) and car 6 get the probabilities of ``warned``."""
    inputs = IntentionInputs(np.array([5, 6]), 0.0, np.array([2, 0]), np.zeros((2, len(OWN_FEATURES))),
                             np.zeros((2, 2, len(SIDE_FEATURES))), np.array([[True, True], [False, True]]))
    tables, views, probs = [], [], []
    for k in range(61):
        t = round(k * 0.1, 9)
        tables.append((t, inputs))
        views.append((t, t, np.array([5, 6]), np.array([20.0, 30.0]), 1))
        p5, p6 = warned(t)
        probs.append(np.array([[[1 - p5, p5, 0.0]], [[1 - p6, 0.0, p6]]]))
    cut_ins = [{"t_s": 2.5, "vehicle_id": 5, "gap_m": 15.0, "maneuver": "gentle"}]
    return Episode(0.1, _truth_rows(), tables, views, cut_ins, 6.0), probs


def test_warning_runs_precision_and_lead_time_by_hand():
    # car 5 warned 0.5-1.0 s and 1.5-2.8 s (a gap of 0.5 s: one run); car 6 warned 0.0-0.3, 1.5-1.8 and
    # 4.0-4.5 s (gaps of 1.2 s and more: three runs) and never moves
    def within(t, *spans):
        return any(a - 1e-9 <= t < b - 1e-9 for a, b in spans)

    def warned(t):
        return (0.9 if within(t, (0.5, 1.0), (1.5, 2.8)) else 0.1,
                0.9 if within(t, (0.0, 0.3), (1.5, 1.8), (4.0, 4.5)) else 0.0)

    ep, probs = _episode(warned)
    runs = warning_runs(ep, Truth(ep.truth, 0.1), probs, 0, 0.5, 1.0)
    assert [(w.vehicle_id, w.true, w.entered) for w in runs] == [(5, True, True), (6, False, False), (6, False, False),
                                                                   (6, False, False)]  # car 6's target is lane 1 too
    assert [(w.start_s, w.end_s) for w in runs[1:]] == [pytest.approx((0.0, 0.3)), pytest.approx((1.5, 1.8)),
                                                          pytest.approx((4.0, 4.5))]
    assert runs[0].start_s == pytest.approx(0.5) and runs[0].end_s == pytest.approx(2.8)
    assert cut_in_leads(ep.cut_ins, runs, 1.0) == [pytest.approx(2.0)]  # from 0.5 s to the overlap at 2.5 s
    # a warning is on over 0.0-0.3, 0.5-2.8 (car 6's 1.5-1.8 inside it) and 4.0-4.5: 3.1 s of the 6.0 s
    assert warning_time_s(runs) == pytest.approx(3.1)
    scores = cut_in_scores([ep], [Truth(ep.truth, 0.1)], [view_samples(ep, probs, 0)], 0.5, 1.0)
    assert scores["warning_time_share"] == pytest.approx(3.1 / 6.0)
    assert scores["false_warnings_per_min"] == pytest.approx(3 / 0.1)  # car 6's three runs in 0.1 min
    assert scores["precision"] == scores["precision_lane_entry"] == pytest.approx(0.25)


def test_a_warning_is_true_only_when_its_car_cuts_in_not_when_it_merely_enters_the_lane():
    # car 5's body is over the ego's lane from 2.5 s on (it enters at 2.5 s); warned 0.5-1.5 s
    def warned(t):
        return (0.9 if 0.5 - 1e-9 <= t < 1.5 - 1e-9 else 0.1, 0.0)

    ep, probs = _episode(warned)
    truth = Truth(ep.truth, 0.1)
    smp = view_samples(ep, probs, 0)
    # a cut-in at 2.5 s: true under both rules; the lead is 2.0 s
    (run,) = runs_at(smp, truth, ep.cut_ins, 0.5, 1.0)
    assert (run.true, run.entered) == (True, True) and cut_in_leads(ep.cut_ins, [run], 1.0) == [pytest.approx(2.0)]
    # the same lane entry without a cut-in (say, behind the ego or ahead of its leader): only entered
    (run,) = runs_at(smp, truth, [], 0.5, 1.0)
    assert (run.true, run.entered) == (False, True)
    # the run ends at 1.5 s: a cut-in by this car up to 1.5 + H + 1 s = 3.5 s makes it true, a later one does
    # not, another car's never does, and neither does one at the run's very start (it warns of nothing)
    def true_with(*cuts):
        return runs_at(smp, truth, [{"t_s": t, "vehicle_id": v} for t, v in cuts], 0.5, 1.0)[0].true

    assert true_with((3.5, 5)) and not true_with((3.6, 5)) and not true_with((2.5, 6)) and not true_with((0.5, 5))
    assert true_with((0.6, 5))
    # a warning that starts after the cut-in (the car already over the lane) is false, though the car entered
    ep, probs = _episode(lambda t: (0.9 if t >= 2.6 - 1e-9 else 0.1, 0.0))
    (run,) = runs_at(view_samples(ep, probs, 0), truth, ep.cut_ins, 0.5, 1.0)
    assert (run.true, run.entered) == (False, True)
    ep.cut_ins = [{**ep.cut_ins[0], "gap_m": 60.0}]  # at 60 m or more the cut-in is not counted
    scores = cut_in_scores([ep], [truth], [view_samples(ep, probs, 0)], 0.5, 1.0)
    assert scores["n_cut_ins"] == 0 and scores["precision"] == 0.0 and scores["precision_lane_entry"] == 1.0


def _late(warned, probs_at=None, views_at=None):
    """``late_reasons`` of the one cut-in of :func:`_episode` (car 5 at 2.5 s) at threshold 0.5, horizon 1 s, with
    car 5's probabilities and view entries optionally changed per view time."""
    from dt_highway.evaluation.intent import late_reasons

    ep, probs = _episode(warned)
    for k, (t, _) in enumerate(ep.tables):
        if probs_at is not None:
            probs[k][0, 0] = probs_at(t, probs[k][0, 0])
        if views_at is not None:
            ep.views[k] = views_at(ep.views[k])
    smp = view_samples(ep, probs, 0)
    runs = runs_at(smp, Truth(ep.truth, 0.1), ep.cut_ins, 0.5, 1.0)
    leads = cut_in_leads(ep.cut_ins, runs, 1.0)
    return leads[0], {r: n for r, n in late_reasons(ep.cut_ins, leads, smp, 0.5).items() if n}


def test_why_a_cut_in_was_not_warned_in_time_is_read_from_the_cars_view_then():
    def from_(t0):
        return lambda t: (0.9 if t >= t0 - 1e-9 else 0.1, 0.0)

    assert _late(from_(0.5)) == (pytest.approx(2.0), {})  # warned 2 s ahead: not late
    assert _late(from_(1.5)) == (pytest.approx(1.0), {"below the threshold": 1})  # p 0.1 at 1.0 s
    # above the threshold at 1.0 s, but toward lane 3 (right of its lane 2), not the ego's lane 1; from 1.5 s toward it
    right = _late(from_(0.5), probs_at=lambda t, p: np.array([0.1, 0.0, 0.9]) if t < 1.5 - 1e-9 else p)
    assert right == (pytest.approx(1.0), {"another lane predicted": 1})
    # 80 m ahead until 1.2 s: outside the window of 65 m; not in the ego's views until 1.2 s
    far = _late(from_(0.5), views_at=lambda v: (*v[:3], np.array([80.0, 30.0]), v[4]) if v[0] < 1.2 - 1e-9 else v)
    assert far == (pytest.approx(1.3), {"beyond the window": 1})
    unseen = _late(from_(0.5), views_at=lambda v: (*v[:2], v[2][1:], v[3][1:], v[4]) if v[0] < 1.2 - 1e-9 else v)
    assert unseen == (pytest.approx(1.3), {"not in the view": 1})
    # warned from 0.5 s, gone 1.2-2.2 s (1 s: a new run), back at 2.2 s: the lead counts from 2.2 s
    back = _late(lambda t: (0.9 if 0.5 - 1e-9 <= t < 1.2 - 1e-9 or t >= 2.2 - 1e-9 else 0.1, 0.0))
    assert back == (pytest.approx(0.3), {"warned, then a break": 1})
    # never warned (NaN lead): read like the others
    never = _late(lambda t: (0.1, 0.0))
    assert math.isnan(never[0]) and never[1] == {"below the threshold": 1}
    # what counts is the view on screen at 1.0 s: toward another lane until 0.9 s, below the threshold at 1.0 s
    mixed = _late(from_(1.5), probs_at=lambda t, p: np.array([0.1, 0.0, 0.9]) if t < 1.0 - 1e-9 else p)
    assert mixed == (pytest.approx(1.0), {"below the threshold": 1})


def test_the_late_reason_reads_the_view_on_screen_however_old_and_nothing_before_the_first():
    from dt_highway.evaluation.intent import late_reasons

    ep, probs = _episode(lambda t: (0.9 if t >= 1.5 - 1e-9 else 0.1, 0.0))
    # a slow downlink: the view received at 0.4 s stays on screen until the next, at 2.0 s
    keep = [k for k, v in enumerate(ep.views) if not 0.4 + 1e-9 < v[0] < 2.0 - 1e-9]
    ep.views = [ep.views[k] for k in keep]
    smp = view_samples(ep, probs, 0)
    leads = cut_in_leads(ep.cut_ins, runs_at(smp, Truth(ep.truth, 0.1), ep.cut_ins, 0.5, 1.0), 1.0)
    assert leads == [pytest.approx(0.5)]  # warned from 2.0 s
    assert late_reasons(ep.cut_ins, leads, smp, 0.5)["below the threshold"] == 1  # the 0.4 s view: p 0.1
    # a cut-in 1.0 s into the episode could not have been warned 1.5 s ahead: no view existed then
    early = [{"t_s": 1.0, "vehicle_id": 5}]
    assert late_reasons(early, [math.nan], smp, 0.5)["before the first view"] == 1
    # the counts add up over episodes in the scores
    scores = cut_in_scores([ep, ep], [Truth(ep.truth, 0.1)] * 2, [smp, smp], 0.5, 1.0)
    assert scores["late_reasons"]["below the threshold"] == 2 and sum(scores["late_reasons"].values()) == 2


def test_the_time_a_warning_is_on_counts_each_moment_once():
    assert warning_time_s([]) == 0.0
    runs = [Warning(1, 2.0, 3.0, True, True), Warning(2, 0.0, 1.0, False, False), Warning(3, 0.5, 2.5, True, True),
            Warning(4, 1.0, 1.2, True, True), Warning(5, 5.0, 5.5, False, True)]
    assert warning_time_s(runs) == pytest.approx(3.0 + 0.5)  # 0.0-3.0 joined, then 5.0-5.5
    assert warning_time_s(runs[::-1]) == pytest.approx(3.5)  # in any order
    assert warning_time_s(runs, until_s=2.0) == pytest.approx(2.0) and warning_time_s(runs, until_s=0.0) == 0.0


def test_the_operating_curve_has_every_figure_per_threshold_and_prints_a_line():
    from dt_highway.evaluation.intent import CURVE_KEYS, THRESHOLDS, format_intent, score_probs

    ep, probs = _episode(lambda t: (0.9 if t >= 1.0 - 1e-9 else 0.3, 0.0))
    scores = score_probs([ep], [probs], (1.0,), IntentionConfig(horizons_s=[1.0], operating_horizon_s=1.0))
    curve = scores["cut_ins"][0]["curve"]
    assert len(curve) == len(THRESHOLDS) and all(set(g) == set(CURVE_KEYS) for g in curve)
    by = {round(g["threshold"], 3): g for g in curve}
    # at 0.25 car 5 is warned from the start (lead 2.5 s, on 0.0-6.0 s), at 0.35 from 1.0 s (lead 1.5 s, on 1.0-6.0 s;
    # the last view is shown until 6.1 s, past the episode's end at 6.0 s, which is not counted)
    assert by[0.25]["median_lead_s"] == pytest.approx(2.5) and by[0.25]["warning_time_share"] == pytest.approx(1.0)
    assert by[0.35]["median_lead_s"] == pytest.approx(1.5)
    assert by[0.35]["warning_time_share"] == pytest.approx(5.0 / 6.0)
    assert by[0.95]["warning_time_share"] == 0.0 and by[0.95]["share_warned_1.5s_ahead"] == 0.0
    result = {"configured_model": "learned", "operating": {"horizon_s": 1.0, "threshold": 0.65}, "episodes": 1,
              "seed": 0, "models": {"learned": scores}}
    line = [x for x in format_intent(result) if "operating curve" in x]
    assert len(line) == 1 and "0.25: 1.00, 2.50 s, 1.00, 0.0, 1.00; 0.35: 1.00, 1.50 s, 1.00, 0.0, 0.83;" in line[0]
    late = [x for x in format_intent(result) if "not warned >= 1.5 s ahead" in x]  # warned 1.5 s ahead at 0.65
    assert len(late) == 1 and "(0 of 1)" in late[0] and "below the threshold 0, another lane predicted 0" in late[0]
    # a result of an older version without a curve prints no such line
    del result["models"]["learned"]["cut_ins"][0]["curve"]
    assert not [x for x in format_intent(result) if "operating curve" in x]


def test_when_the_driver_decided_is_the_last_switch_of_its_target_lane_seen():
    from dt_highway.evaluation.intent import _Recorder, cut_in_scores, format_intent, headline, view_samples

    rec = _Recorder(0.0)
    for t, target in [(0.0, 2), (0.1, 2), (0.2, 1), (0.3, 1), (0.4, 2), (0.5, 1), (0.6, 1)]:
        rec._note_target(5, target, t)
    rec._note_target(6, 1, 0.0)  # lane 1 already its target when first seen
    assert rec.decided_s(5, 1) == pytest.approx(0.5)  # the last switch to lane 1, not the first
    assert math.isnan(rec.decided_s(5, 2))  # not its target now
    assert math.isnan(rec.decided_s(6, 1)) and math.isnan(rec.decided_s(7, 1))  # chosen unseen; never seen
    # the scores: car 5 enters at 2.5 s after deciding at 1.9 s; a second cut-in with an unknown decision is left out
    ep, probs = _episode(lambda t: (0.9 if t >= 1.0 - 1e-9 else 0.1, 0.0))
    ep.cut_ins = [{**ep.cut_ins[0], "t_decided_s": 1.9}, {**ep.cut_ins[0], "t_decided_s": math.nan}]
    scores = cut_in_scores([ep], [Truth(ep.truth, 0.1)], [view_samples(ep, probs, 0)], 0.5, 1.0)
    assert scores["median_decided_before_s"] == pytest.approx(0.6)
    assert scores["by_maneuver"]["gentle"]["median_decided_before_s"] == pytest.approx(0.6)
    assert scores["by_maneuver"]["gentle"]["median_lead_s"] == pytest.approx(1.5)  # warned from 1.0 s
    assert scores["share_warned_1.5s_ahead"] == pytest.approx(1.0) and scores["share_warned_2s_ahead"] == 0.0
    # the same share at the operating threshold in the headline and the printed line (the overlay's goal is 0.85)
    late = cut_in_scores([ep], [Truth(ep.truth, 0.1)], [view_samples(ep, probs, 0)], 0.95, 1.0)  # never warned
    assert late["share_warned_1.5s_ahead"] == 0.0
    for sc, shown in ((scores, "1.000"), (late, "0.000")):
        result = {"configured_model": "learned", "operating": {"horizon_s": 1.0, "threshold": 0.5}, "episodes": 1,
                  "seed": 0, "models": {"learned": {"per_horizon": [], "cut_ins": [
                      {"horizon_s": 1.0, "at_threshold": {**sc, "by_maneuver": {}}, "best": None, "longest_lead": None,
                       "recall_at_precision": 0.0}]}}}
        assert headline(result)["op_share_warned_1_5s_ahead"] == float(shown)
        assert f"warned >= 1.5 s ahead {shown}" in "\n".join(format_intent(result))


def test_cut_ins_by_gap_band_and_the_intervals_over_episodes():
    from dt_highway.evaluation.intent import cut_in_scores, format_intent, view_samples

    # car 5 warned from 1.0 s, cutting in at 2.5 s: lead 1.5 s; the same episode five times, at gaps 15 m and 50 m
    eps = []
    for gap in (15.0, 15.0, 15.0, 50.0, 50.0):
        ep, probs = _episode(lambda t: (0.9 if t >= 1.0 - 1e-9 else 0.1, 0.0))
        ep.cut_ins = [{**ep.cut_ins[0], "gap_m": gap}]
        eps.append(ep)
    truths = [Truth(ep.truth, 0.1) for ep in eps]
    samples = [view_samples(ep, probs, 0) for ep in eps]
    sc = cut_in_scores(eps, truths, samples, 0.5, 1.0, intervals=True)
    assert {band: v["n"] for band, v in sc["by_gap_m"].items()} == {"0-10": 0, "10-20": 3, "20-40": 0, "40-60": 2}
    assert sc["by_gap_m"]["10-20"]["median_lead_s"] == pytest.approx(1.5)
    assert math.isnan(sc["by_gap_m"]["0-10"]["median_lead_s"])
    # every episode alike: every resample alike, the intervals are points (car 6 is never warned)
    iv = sc["intervals"]
    assert iv["median_lead_s"] == pytest.approx([1.5, 1.5]) and iv["precision"] == [1.0, 1.0]
    assert iv["recall"] == [1.0, 1.0] and iv["share_warned_1.5s_ahead"] == [1.0, 1.0]
    assert iv["episodes"] == 5 and iv["level"] == 0.95
    # too few episodes for an interval
    assert cut_in_scores(eps[:4], truths[:4], samples[:4], 0.5, 1.0, intervals=True)["intervals"] is None
    result = {"configured_model": "learned", "operating": {"horizon_s": 1.0, "threshold": 0.5}, "episodes": 5, "seed": 0,
              "models": {"learned": {"per_horizon": [], "cut_ins": [
                  {"horizon_s": 1.0, "at_threshold": sc, "best": sc, "longest_lead": sc, "recall_at_precision": 1.0}]}}}
    text = "\n".join(format_intent(result))
    assert "10-20 m 3, 1.50 s, 1.00; 40-60 m 2, 1.50 s, 1.00" in text and "0-10 m" not in text
    assert ("95 % intervals (bootstrap over the 5 episodes): at precision >= 0.80 (threshold 0.500): median lead "
            "1.50-1.50 s, precision 1.00-1.00") in text


def test_the_sweep_prints_each_settings_interval_of_the_median_lead():
    from dt_highway.evaluation.intent import format_sweep

    row = {"parameter": "rate_hz", "value": 5.0, "auc": {"1s": 0.9, "2s": 0.8, "3s": 0.7}, "recall_at_precision_0_80": 1.0,
           "threshold_there": 0.7, "median_lead_s_there": 0.73, "longest_median_lead_s": 0.73}
    with_interval, without = format_sweep([{**row, "median_lead_s_there_interval": [0.6, 1.1666]}, row])[1:]
    assert "0.73             0.60-1.17" in with_interval and "0.73             -" in without


def test_the_resampled_medians_are_numpys_median_of_the_repeated_leads():
    from dt_highway.evaluation.intent import _resampled_medians, episode_intervals

    rng = np.random.default_rng(1)
    per = [(np.where(rng.random(k) < 0.2, np.nan, rng.random(k) * 3), 1, 2) for k in rng.integers(0, 6, size=12)]
    counts = np.stack([np.bincount(r, minlength=12) for r in rng.integers(0, 12, size=(300, 12))]).astype(float)
    got = _resampled_medians(per, counts)
    for c, g in zip(counts, got, strict=True):
        leads = np.concatenate([np.repeat(e[0], int(k)) for e, k in zip(per, c, strict=True)])
        warned = leads[~np.isnan(leads)]
        assert (math.isnan(g) and not len(warned)) or g == np.median(warned)
    assert episode_intervals(per) == episode_intervals(per)  # seeded: the same inputs, the same intervals
    lo, hi = episode_intervals(per)["median_lead_s"]
    assert lo < np.nanmedian(np.concatenate([e[0] for e in per])) < hi


def test_a_warning_after_the_overlap_or_long_before_is_no_lead():
    runs = [Warning(5, 2.6, 3.0, False, True), Warning(5, 0.0, 0.2, False, False)]
    assert math.isnan(cut_in_leads([{"t_s": 2.5, "vehicle_id": 5}], runs, 1.0)[0])


def test_dataset_labels_by_side():
    ep, _ = _episode(lambda t: (0.0, 0.0))
    data = dataset([ep], horizons_s=(1.0,))
    # every second estimate is kept (0.0, 0.2, ...); both cars are labelled up to t = 5.0 (then car 6's track
    # ends within the horizon); car 5 (twin lane 2) changes to lane 1 at 3.0: "left" for the estimates 2.0-2.8
    t = np.array([t for t, _ in ep.tables[::2]])
    t = t[t <= 5.0 + 1e-9]
    y5 = data["y"][: 2 * len(t): 2, 0]
    assert set(y5[(t >= 2.0 - 1e-9) & (t < 3.0 - 1e-9)].tolist()) == {1}
    assert set(y5[t < 1.9].tolist()) == {0}
    assert set(data["y"][1: 2 * len(t): 2, 0].tolist()) == {0}  # car 6 stays


# ----------------------------------------------------------------------------- the commands
def test_twin_eval_intent_on_a_tiny_input(capsys):
    assert main(["twin-eval", "--intent", "--episodes", "1", "--seed", "5", "--json", *TINY]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["configured_model"] == "learned" and set(result["models"]) == {"learned", "physics"}
    scores = result["models"]["learned"]
    assert [r["horizon_s"] for r in scores["per_horizon"]] == [1.0, 2.0, 3.0]
    assert all(r["n_samples"] > 0 for r in scores["per_horizon"])
    assert result["operating"] == {"horizon_s": 3.0, "threshold": 0.65}
    cut_ins = scores["cut_ins"][2]
    assert cut_ins["horizon_s"] == 3.0 and len(cut_ins["curve"]) == 37
    assert 0.0 <= cut_ins["curve"][0]["warning_time_share"] <= 1.0
    assert result["settings"]["noise_sigma_m"] == 1.0


def test_train_intent_then_evaluate_with_the_new_weights(tmp_path, capsys):
    out = tmp_path / "w.npz"
    assert main(["train-intent", "--episodes", "1", "--epochs", "1", "--out", str(out), "--quiet", *TINY]) == 0
    assert str(out) in capsys.readouterr().out
    assert main(["twin-eval", "--intent", "--episodes", "1", "--quiet", "--set", f"twin.intention.weights={out}",
                 *TINY]) == 0
    assert "cut-ins in front of the ego" in capsys.readouterr().out


def test_intent_command_mistakes_are_one_line_errors(capsys):
    assert main(["twin-eval", "--sweep", "--quiet", *TINY]) == 2
    assert "--sweep goes with --intent" in capsys.readouterr().err
    assert main(["twin-eval", "--intent", "--quiet", "--set", "twin.intention.enabled=false", *TINY]) == 2
    assert "twin.intention.enabled" in capsys.readouterr().err
    assert main(["train-intent", "--out", "x.npz", "--alternate", "traffic.nope=1", "--quiet", *TINY]) == 2
    assert "traffic.nope" in capsys.readouterr().err
    for option, where in (("--set", "--scenario, --set or the driver"), ("--alternate", "--alternate")):  # trained anyway
        assert main(["train-intent", "--out", "x.npz", option, "twin.intention.model=physics", "--quiet", *TINY]) == 2
        err = capsys.readouterr().err
        assert f"twin.intention.model = 'physics' ({where}) has no weights to train" in err and err.count("\n") == 1
    assert not Path("x.npz").exists()
    # each was silently ignored or replaced
    assert main(["twin-eval", "--intent", "--min-observed-s", "1", "--quiet", *TINY]) == 2
    assert "--min-observed-s goes with the tags' evaluation (without --intent)" in capsys.readouterr().err
    assert main(["twin-eval", "--population", "continuum", "--set", "traffic.population=two_class", "--quiet", *TINY]) == 2
    assert ("--population continuum and --set traffic.population=two_class name two populations: give one"
            in capsys.readouterr().err)
    assert main(["twin-eval", *TINY, "--population", "continuum", "--set", "traffic=1", "--quiet"]) == 2  # was a traceback
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "traffic" in err and "Traceback" not in err


def test_train_intent_refuses_to_replace_weights_or_learn_from_nothing(tmp_path, capsys):
    out = tmp_path / "w.npz"
    out.write_bytes(b"weights")
    assert main(["train-intent", "--episodes", "1", "--epochs", "1", "--out", str(out), *TINY]) == 2
    assert f"{out} exists: pass --force to replace it" in capsys.readouterr().err and out.read_bytes() == b"weights"
    empty = tmp_path / "sub" / "empty.npz"
    assert main(["train-intent", "--episodes", "1", "--epochs", "1", "--out", str(empty), "--quiet", *TINY,
                 "--set", "highway.vehicles_count=0"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("dt-highway train-intent: error: no lane change in 0 estimates") and err.count("\n") == 1
    assert not empty.parent.exists()  # its folder is made only when weights are written
    assert main(["train-intent", "--out", str(tmp_path), *TINY]) == 2
    assert f"--out {tmp_path} is a folder: name a file" in capsys.readouterr().err


def test_recordings_start_the_ego_in_a_lane_drawn_per_episode():
    """The trial drivers spend more than half their time in the edge lanes; recordings for training and
    evaluation must show the model an ego there too, not only in the scenario's start lane."""
    from dt_highway.evaluation.intent import eval_config, record_episodes

    cfg = load_config(ROOT / "envs" / "highway-trial.toml", [t for t in TINY if t != "--set"])
    assert cfg.highway.initial_lane_id == 1
    rec = eval_config(cfg)
    assert rec.highway.initial_lane_id is None and rec.ego.autopilot
    episodes = record_episodes(cfg, [0, 2, 9])  # seeds whose draws differ (with the start lane: 1, 1, 1)
    lanes = [{v[4] for v in ep.views} for ep in episodes]
    assert all(len(s) == 1 for s in lanes)  # the autopilot keeps its lane
    assert [min(s) for s in lanes] == [1, 2, 0]


def test_a_driver_model_can_drive_the_ego_in_the_recordings_and_bad_driver_options_are_one_line_errors(capsys):
    """``twin-eval --intent --driver`` / ``train-intent --driver``: the twin scored (or trained) in the driving
    of a study, where the ego changes lane and speed, instead of the autopilot's."""
    from dt_highway.drivers import Driver
    from dt_highway.evaluation.intent import eval_config, record_episodes

    class Lefty(Driver):  # asks for the lane to its left at every decision
        def __init__(self) -> None:
            super().__init__("lefty")
            self.seeds: list[int] = []
            self.calls = 0

        def reset(self, seed: int) -> None:
            self.seeds.append(seed)

        def act(self, perception):
            self.calls += 1
            return np.array([0.0, -1.0])

    cfg = load_config(ROOT / "envs" / "highway-trial.toml", [t for t in TINY if t != "--set"])
    assert not eval_config(cfg, driven=True).ego.autopilot and eval_config(cfg).ego.autopilot
    lefty = Lefty()
    driven = record_episodes(cfg, [0, None], driver=lefty)
    auto = record_episodes(cfg, [0])
    record_episodes(cfg, [5, None], driver=lefty)  # the driver's seeds follow the first episode's
    assert lefty.seeds == [0, 1, 5, 6] and lefty.calls >= 4 * 4 * cfg.highway.policy_frequency
    assert {v[4] for v in auto[0].views} == {1}  # seed 0 starts in lane 1; the autopilot keeps it
    driven_lanes = [v[4] for v in driven[0].views]
    assert driven_lanes[0] == 1 and driven_lanes[-1] == 0  # the driver moved the ego to the left lane
    assert main(["twin-eval", "--driver", "agents/human.toml", "--quiet", *TINY]) == 2
    assert "--driver goes with --intent" in capsys.readouterr().err
    assert main(["twin-eval", "--intent", "--driver", "agents/nope.toml", "--quiet", *TINY]) == 2
    err = capsys.readouterr().err
    assert "nope.toml" in err and len(err.strip().splitlines()) == 1
