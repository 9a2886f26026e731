"""The sham (placebo) overlay: as many marks as the real one, alike, on cars chosen without the
twin's information."""

import numpy as np
import pytest
from test_threat_overlay import DT, pipeline, step, view

from dt_highway.config import load_config
from dt_highway.overlay import ShamOverlay

N_CARS = 8


def _schedule(n_frames, seed, k_tagged=2, epoch=12):
    """Which cars the twin tags at each frame: one more car every ``epoch`` frames up to ``k_tagged``,
    then every ``epoch`` frames one tag moves to another car (so no two marks start in the same frame)."""
    rng = np.random.default_rng(seed)
    tagged = [int(rng.integers(N_CARS))]
    out = []
    for k in range(n_frames):
        if k and k % epoch == 0:
            new = int(rng.choice([c for c in range(N_CARS) if c not in tagged]))
            if len(tagged) < k_tagged:
                tagged.append(new)
            else:
                tagged[int(rng.integers(k_tagged))] = new
        out.append(frozenset(tagged))
    return out


def _views(tagged, mode, perm=None):
    """The twin view: cars 0..7 on both sides of the ego; the tagged ones aggressive (``type``) or
    predicted to cut in (``threat``); ``perm`` moves every car's tag and intention to another car."""
    out = []
    for c in range(N_CARS):
        src = perm[c] if perm is not None else c
        hot = src in tagged
        y = 0.0 if c % 2 else 8.0
        if mode == "type":
            out.append(view(c, y_m=y, tag="aggressive" if hot else "normal", conf=0.8))
        else:
            out.append(view(c, y_m=y, p=(0.9, 0.9, 0.9) if hot else (0.0, 0.0, 0.0)))
    return out


DISTS = {c: 15.0 + 10.0 * c for c in range(N_CARS)}


def _run(mode, n_frames, seed=3, perm=None, sched_seed=0):
    pipe = pipeline(seed=seed, mode=mode, sham=True, max_marks=8)  # the bound never binds: counts are the tags' only
    sched = _schedule(n_frames, sched_seed)
    frames = []
    for k in range(n_frames):
        tagged = sched[k]
        hot = {c for c in range(N_CARS) if (perm[c] if perm is not None else c) in tagged}
        out = step(pipe, _views(tagged, mode, perm), DISTS, k * DT)
        frames.append((hot, out))
    return frames


@pytest.mark.parametrize("mode", ["type", "threat"])
def test_sham_marks_match_the_real_count_and_land_on_tagged_cars_only_by_chance(mode):
    frames = _run(mode, 4800)
    on_tagged = n_sham = 0
    draws_tagged = n_draws = 0
    prev: set[int] = set()
    for hot, out in frames[12:]:  # from the second tag on
        real, sham = out["real_overlay"], out["overlay"]
        assert len(sham) == len(real)  # as many marks, every frame (8 cars, at most 4 real marks with the held)
        assert all(m["vehicle_id"] in hot for m in real if not m["held"])  # the real overlay follows the twin
        if mode == "type":
            assert sorted(m["label"] for m in sham) == sorted(m["label"] for m in real)
        else:  # the cue is the real one's, the side named is the sham car's own
            assert all(m["label"] == f"cutting in from {'left' if m['vehicle_id'] % 2 else 'right'}" for m in sham)
        assert all(m["cue"] == mode for m in sham)
        ids = {m["vehicle_id"] for m in sham}
        on_tagged += len(ids & hot)
        n_sham += len(ids)
        for vid in ids - prev:  # a new sham car: one draw
            draws_tagged += vid in hot
            n_draws += 1
        prev = ids
    share_cand = 2 / N_CARS  # two of the eight placed cars are tagged at every frame
    # the draws: uniform among free cars, whatever the tags: share within 4 binomial standard errors
    se = (share_cand * (1 - share_cand) / n_draws) ** 0.5
    assert n_draws > 300
    assert abs(draws_tagged / n_draws - share_cand) < 4 * se, (draws_tagged, n_draws)
    # and over the frames (correlated, so a looser bound): nothing like the real overlay's 100 %
    assert abs(on_tagged / n_sham - share_cand) < 0.08


@pytest.mark.parametrize("mode", ["type", "threat"])
def test_a_sham_run_with_the_tags_shuffled_gives_identical_marks(mode):
    perm = [3, 6, 0, 7, 1, 4, 2, 5]  # every car's tag and intention moved to another car
    plain, shuffled = _run(mode, 600), _run(mode, 600, perm=perm)
    differs = 0
    for (_, a), (_, b) in zip(plain, shuffled, strict=True):
        key = lambda marks: sorted((m["vehicle_id"], tuple(m["box"]), m["label"], m["confidence"]) for m in marks)  # noqa: E731
        assert key(a["overlay"]) == key(b["overlay"])
        differs += key(a["real_overlay"]) != key(b["real_overlay"])
    assert differs > 100  # the real marks did move with the tags


def test_a_sham_mark_keeps_its_car_while_the_real_one_lasts_and_moves_when_its_car_leaves():
    sham = ShamOverlay(np.random.default_rng(0), hold_s=0.2)
    cars = {c: {"box": [10.0 * c, 0.0, 10.0 * c + 5, 5.0], "distance_m": 20.0 + c, "rule": "joint", "side": "left"}
            for c in range(5)}
    real = [{"vehicle_id": 99, "box": [0, 0, 1, 1], "label": "cutting in from right", "confidence": 0.7,
             "distance_m": 30.0, "cue": "threat", "side": "right", "aggressive": False, "held": False}]
    (first,) = sham.update(real, cars, 0.0)
    car = first["vehicle_id"]
    assert car in cars and first["label"] == "cutting in from left" and first["confidence"] == 0.7  # its own side
    assert first["box"] == cars[car]["box"] and first["distance_m"] == cars[car]["distance_m"]
    for k in range(1, 20):
        assert sham.update(real, cars, k * 0.1)[0]["vehicle_id"] == car  # as long as the real mark lasts
    gone = {c: v for c, v in cars.items() if c != car}
    (held,) = sham.update(real, gone, 2.0)
    assert held["vehicle_id"] == car and held["held"]  # lost by the fusion: held like a real mark
    (moved,) = sham.update(real, gone, 2.3)  # gone longer than the hold: another car
    assert moved["vehicle_id"] != car and moved["vehicle_id"] in gone and not moved["held"]
    assert sham.update([], cars, 2.4) == [] and sham.pairs == {}  # the real mark ended: so did the sham
    assert sham.update(real, {}, 2.5) == []  # no car in view: nothing to show


def test_the_sham_condition_in_the_env_shows_as_many_marks_as_the_hidden_real_overlay():
    import gymnasium as gym

    from dt_highway.conditions import condition_config

    cfg = load_config("envs/highway-trial.toml", ["highway.duration=8", "twin.intention.operating_horizon_s=3",
                                                  "twin.intention.threshold=0.4"], condition_config("sham"))
    assert cfg.overlay.sham and cfg.overlay.mode == "type"
    env = gym.make("dt-highway-v0", config=cfg.to_dict())
    _, info = env.reset(seed=2)
    settings = env.unwrapped.pipeline.settings  # the threat's operating point: the twin's, the overlay setting none
    assert (settings.horizon_s, settings.threshold) == (3.0, 0.4)
    shown = same = 0
    for _ in range(30):
        _, _, term, trunc, info = env.step(np.array([0.0, 0.0]))
        adas = info["adas"]
        shown += len(adas["overlay"])
        same += len(adas["overlay"]) == len(adas["real_overlay"])
        assert {m["vehicle_id"] for m in adas["overlay"]} <= set(adas["placements"]) | {
            m["vehicle_id"] for m in adas["overlay"] if m["held"]}
        if term or trunc:
            break
    env.close()
    assert shown > 0 and same >= 28


def test_a_sham_mark_whose_predicted_box_is_no_longer_trusted_moves_to_another_car():
    """Like a real held mark, a sham mark on a lost car ends once its predicted box shrinks below half its last
    size (a car pulling away), and the still-shown real mark gets a new car at once."""
    sham = ShamOverlay(np.random.default_rng(0), hold_s=1.0)
    cars = {c: {"box": [100.0 * c, 100.0, 100.0 * c + 80, 160.0], "distance_m": 20.0 + c, "rule": "joint",
                "side": "left"} for c in range(3)}
    real = [{"vehicle_id": 99, "box": [0, 0, 1, 1], "label": "aggressive driver", "distance_m": 30.0, "cue": "type"}]
    car = sham.update(real, cars, 0.0)[0]["vehicle_id"]
    shrinking = {**cars, car: {**cars[car], "box": [100.0 * car + 10, 105.0, 100.0 * car + 70, 155.0]}}
    sham.update(real, shrinking, 0.1)  # width 80 -> 60 px in 0.1 s
    gone = {c: v for c, v in cars.items() if c != car}
    (held,) = sham.update(real, gone, 0.15)  # predicted width 50 of 60: still trusted
    assert held["vehicle_id"] == car and held["held"]
    (moved,) = sham.update(real, gone, 0.3)  # predicted width 20 of 60: another car, well within the hold
    assert moved["vehicle_id"] != car and not moved["held"]


def test_a_threat_sham_mark_never_lands_on_a_car_in_the_egos_lane():
    """A real threat is a car in another lane moving into the ego's: "CUTTING IN" on a car ahead in the ego's own
    lane (its side flipping as it wandered about the lane's centre) gave the placebo away in a real-window check.
    A type mark may sit on any car, as the real one does."""
    cars = {c: {"box": [10.0 * c, 0.0, 10.0 * c + 5, 5.0], "distance_m": 20.0 + c, "rule": "joint",
                "side": "left" if c < 4 else "right", "in_ego_lane": c in (2, 3, 4)} for c in range(6)}
    threat = {"vehicle_id": 99, "box": [0, 0, 1, 1], "label": "cutting in from right", "confidence": 0.7,
              "distance_m": 30.0, "cue": "threat", "side": "right", "aggressive": False, "held": False}
    kind = {**threat, "label": "aggressive driver", "cue": "type"}
    drawn: dict[str, set[int]] = {"threat": set(), "type": set()}
    for seed in range(200):
        for real in (threat, kind):
            (mark,) = ShamOverlay(np.random.default_rng(seed)).update([real], cars, 0.0)
            drawn[real["cue"]].add(mark["vehicle_id"])
    assert drawn["threat"] == {0, 1, 5}  # every car outside the lane, and only those
    assert drawn["type"] == set(cars)
    only_in_lane = {c: v for c, v in cars.items() if v["in_ego_lane"]}
    assert ShamOverlay(np.random.default_rng(0)).update([threat], only_in_lane, 0.0) == []  # then no sham mark
