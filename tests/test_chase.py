"""The twin's chase detector: its inputs from the cloud's fixes, the shipped weights, training and the command."""

import numpy as np
import pytest

from dt_highway.twin.chase import CHASE_FEATURES, CHASE_LAGS_S, ChaseDetector, ChaseInputs, chase_inputs, save_chase_weights
from dt_highway.twin.store import FixStore
from dt_highway.twin.tagger import DriverRecord, HighwayMap
from dt_highway.twin.uplink import GnssFix

ROAD = HighwayMap(4.0, 3)
NOW = 20.0


def _store(cars):
    """Fixes at 10 Hz from t = 10 s to NOW of the ego (id 0, lane 1, 25 m/s, x = 25 t) and ``cars``:
    ``id -> (lane, x at NOW, speed(t))``, each car's position integrated back from NOW."""
    store = FixStore(30.0)
    ts = np.round(np.arange(100, 201) / 10, 1)
    fixes = [GnssFix(0, t, 25.0 * t, 4.0, 25.0, 0.0, t + 0.1) for t in ts]
    for vid, (lane, x_now, speed) in cars.items():
        v = np.array([speed(t) for t in ts])
        x = x_now - np.concatenate([np.cumsum((v[:-1] * 0.1)[::-1])[::-1], [0.0]])
        fixes += [GnssFix(vid, t, xi, 4.0 * lane, vi, 0.0, t + 0.1) for t, xi, vi in zip(ts, x, v, strict=True)]
    store.add(fixes)
    return store


def _record(vid, p_aggressive):
    aggressive = p_aggressive >= 0.5
    return DriverRecord(vid, 0.0, tag="aggressive" if aggressive else "normal",
                        confidence=p_aggressive if aggressive else 1.0 - p_aggressive)


def test_the_inputs_are_gaps_and_speeds_relative_to_the_ego_over_the_last_seconds():
    # car 5 behind in lane 0, 30 m/s for the last 4 s (25 before); car 6 two lanes away, only 1 s of fixes
    store = _store({5: (0, 25.0 * NOW - 40.0, lambda t: 30.0 if t > NOW - 4 else 25.0)})
    store.add([GnssFix(6, t, 25.0 * t, 12.0, 25.0, 0.0, t + 0.1) for t in np.round(np.arange(190, 201) / 10, 1)])
    inputs = chase_inputs(store, {}, HighwayMap(4.0, 4), NOW)
    assert inputs.vehicle_ids.tolist() == [5, 6] and inputs.x.shape == (2, len(CHASE_FEATURES))
    f = dict(zip(CHASE_FEATURES, inputs.x[0], strict=True))
    assert f["p_aggressive"] == pytest.approx(0.2)  # no record: the prior
    assert (f["ego_same_lane"], f["ego_next_lane"], f["ego_far_lane"]) == (0.0, 1.0, 0.0)
    assert f["speed"] == pytest.approx(1.0) and f["ego_speed"] == pytest.approx(25 / 30)
    assert f["dv_0s"] == pytest.approx(1.0) and f["dv_6s"] == pytest.approx(0.0)  # 5 m/s faster now, as fast 6 s ago
    assert f["dx_0s"] == pytest.approx(-40 / 50, abs=0.02)
    assert f["dx_6s"] == pytest.approx(-60 / 50, abs=0.02)  # it has caught up 20 m in the last 4 s
    assert f["speed_change_2s"] == 0.0 and f["speed_change_2_4s"] == pytest.approx(2.5, abs=0.05)
    g = dict(zip(CHASE_FEATURES, inputs.x[1], strict=True))
    assert g["ego_far_lane"] == 1.0 and g["seen_0s"] == 1.0
    assert [g[f"seen_{lag:g}s"] for lag in CHASE_LAGS_S[2:]] == [0.0] * 4 and g["dx_6s"] == 0.0  # no fixes then
    assert len(chase_inputs(FixStore(30.0), {}, ROAD, NOW)) == 0  # no ego: nothing to chase


def test_the_shipped_detector_tells_a_chase_from_a_car_cruising_beside_the_ego():
    # car 5 (tagged aggressive) has closed in from 60 m behind at the ego's speed + 5 m/s; car 6 (tagged normal)
    # drives beside the ego at its speed all along
    store = _store({5: (0, 25.0 * NOW - 35.0, lambda t: 30.0 if t > NOW - 6 else 25.0), 6: (2, 25.0 * NOW, lambda t: 25.0)})
    records = {5: _record(5, 0.95), 6: _record(6, 0.02)}
    detector = ChaseDetector.load()
    p = detector.predict(chase_inputs(store, records, ROAD, NOW))
    assert p[0] > 0.5 > 0.1 > p[1]
    assert detector.predict(ChaseInputs(np.zeros(0, dtype=np.int64), NOW, np.zeros((0, len(CHASE_FEATURES))))).shape == (0,)


def test_weights_are_checked_when_loaded(tmp_path):
    shipped = ChaseDetector.load()
    assert shipped.meta["seeds"] == "1000-1023"
    good = tmp_path / "good.npz"
    save_chase_weights(good, shipped.mean, shipped.scale, list(shipped.layers), {"seeds": "7-8"})
    assert ChaseDetector.load(good).meta == {"seeds": "7-8"}
    other = tmp_path / "other.npz"
    np.savez(other, mean=shipped.mean, scale=shipped.scale, features=np.asarray(CHASE_FEATURES[:-1]))
    with pytest.raises(ValueError, match="trained for other inputs"):
        ChaseDetector.load(other)
    junk = tmp_path / "junk.npz"
    junk.write_text("not weights")
    with pytest.raises(ValueError, match="cannot read chase weights .*junk.npz: not a .npz archive of arrays$"):
        ChaseDetector.load(junk)  # not numpy's advice to allow pickles
    for name, content in (("zip.npz", b"PK\x03\x04torn"), ("empty.npz", b"")):
        (tmp_path / name).write_bytes(content)
        with pytest.raises(ValueError, match="not a .npz archive of arrays$"):
            ChaseDetector.load(tmp_path / name)
    np.save(tmp_path / "one.npy", np.zeros(3))
    with pytest.raises(ValueError, match="not a .npz archive of arrays$"):
        ChaseDetector.load(tmp_path / "one.npy")


def test_training_is_deterministic_and_learns_the_labels():
    from dt_highway.evaluation.chase_train import fit_chase, score_chase

    rng = np.random.default_rng(0)
    x = rng.normal(size=(3000, len(CHASE_FEATURES)))
    y = x[:, CHASE_FEATURES.index("dv_0s")] + 0.3 * rng.normal(size=3000) > 1.0
    a, b = fit_chase(x, y, epochs=5, batch=64), fit_chase(x, y, epochs=5, batch=64)
    assert all(np.array_equal(wa, wb) and np.array_equal(ba, bb) for (wa, ba), (wb, bb) in zip(a[2], b[2], strict=True))
    detector = ChaseDetector(a[0], a[1], tuple(a[2]))
    scores = score_chase(detector, x, y)
    assert scores["all"]["auc"] > 0.95 and scores["all"]["chasing"] == int(y.sum())


TINY = ["--set", "highway.vehicles_count=10", "--set", "highway.duration=20", "--set", "twin.preroll_s=6",
        "--set", "highway.lanes_count=3", "--set", "traffic.population_size=40", "--quiet"]


def test_train_chase_records_fits_and_scores(tmp_path, capsys):
    from dt_highway.cli import main

    out = tmp_path / "w.npz"
    assert main(["train-chase", "--episodes", "2", "--test-episodes", "1", "--epochs", "2", "--out", str(out), *TINY]) == 0
    text = capsys.readouterr().out
    assert "trained on" in text and "held out, seeds 5000-5000:" in text and "near_ego" in text
    assert ChaseDetector.load(out).meta["seeds"] == "1000-1001"
    before = out.read_bytes()
    assert main(["train-chase", "--episodes", "1", "--epochs", "1", "--out", str(out), *TINY]) == 2
    assert f"{out} exists: pass --force to replace it" in capsys.readouterr().err and out.read_bytes() == before
    assert main(["train-chase", "--episodes", "2", "--seed", "4999", "--out", str(out), "--force", *TINY]) == 2
    assert "overlap the training seeds 4999-5000" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["train-chase", "--test-episodes", "-1", "--out", str(out)])
    assert "--test-episodes must be >= 0" in capsys.readouterr().err
