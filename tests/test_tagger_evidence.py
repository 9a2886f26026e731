"""The twin's evidence tagger (twin.tagger.model = "evidence"): features, model, traffic samples, fit."""

import math
import re

import numpy as np
import pytest

from dt_highway.config import TaggerConfig, load_config
from dt_highway.evaluation.tagger_train import fit
from dt_highway.twin.store import FixStore
from dt_highway.twin.tagger import EVIDENCE_FEATURES, DriverRecord, EvidenceModel, HighwayMap, Tagger, evidence_features
from dt_highway.twin.uplink import GnssFix

ROAD = HighwayMap(4.0, 3)


def _fixes(vid: int, x0: float, y: float, v: float, t0: float = 0.0, t1: float = 2.0, hz: float = 10.0) -> list[GnssFix]:
    return [GnssFix(vid, t, x0 + v * t, y, v, 0.0, t) for t in np.arange(t0, t1 + 1e-9, 1.0 / hz)]


def test_evidence_features_by_hand():
    rec = DriverRecord(7, 0.0, observed_s=120.0, n_lane_changes=3, n_sudden=1, n_timed=2, max_lateral_speed_mps=2.0,
                       min_gap_s=0.6, n_samples=4, speed_sum=100.0, speed_sq_sum=2504.0, speed_rel_sum=8.0,
                       n_following=2, headway_sum_s=3.0)
    f = dict(zip(EVIDENCE_FEATURES, evidence_features(rec), strict=True))
    assert f["log_max_lateral_speed"] == pytest.approx(math.log(2.0)) and f["has_timed_change"] == 1.0
    assert f["lane_changes_per_min"] == pytest.approx(1.5) and f["sudden_per_min"] == pytest.approx(0.5)
    assert f["min_gap"] == pytest.approx(0.6) and f["speed_rel"] == pytest.approx(2.0) and f["speed"] == pytest.approx(25.0)
    assert f["headway"] == pytest.approx(1.5) and f["following_share"] == pytest.approx(0.5)
    assert f["speed_sd"] == pytest.approx(1.0)  # sqrt(2504/4 - 25^2)
    empty = dict(zip(EVIDENCE_FEATURES, evidence_features(DriverRecord(8, 0.0)), strict=True))
    assert empty["log_max_lateral_speed"] == pytest.approx(math.log(0.5)) and empty["min_gap"] == 3.0
    assert empty["headway"] == 3.0 and empty["has_timed_change"] == 0.0


def test_evidence_model_probability_save_and_load(tmp_path):
    n = len(EVIDENCE_FEATURES)
    w = np.zeros(n)
    w[EVIDENCE_FEATURES.index("headway")] = -2.0
    model = EvidenceModel(np.full(n, 1.0), np.full(n, 0.5), w, 0.5)
    x = np.full(n, 1.0)
    x[EVIDENCE_FEATURES.index("headway")] = 1.5  # (1.5 - 1) / 0.5 = 1 -> 0.5 - 2 = -1.5
    assert model.probability(x) == pytest.approx(1 / (1 + math.exp(1.5)))
    # before 30 s of observation the log-odds are blended with the prior's: at 15 s half of each
    half = 0.5 * -1.5 + 0.5 * math.log(0.2 / 0.8)
    assert model.probability(x, observed_s=15.0, prior=0.2) == pytest.approx(1 / (1 + math.exp(-half)))
    assert model.probability(x, observed_s=0.0, prior=0.2) == pytest.approx(0.2)
    model.save(tmp_path / "w.json", training={"seeds": [0]})
    again = EvidenceModel.load(tmp_path / "w.json")
    assert again.probability(x) == pytest.approx(model.probability(x))
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(ValueError, match="twin.tagger.evidence_weights: cannot read"):
        EvidenceModel.load(tmp_path / "bad.json")
    (tmp_path / "other.json").write_text('{"features": ["a"], "mean": [0], "scale": [1], "weights": [1], "bias": 0}')
    with pytest.raises(ValueError, match="holds other features"):
        EvidenceModel.load(tmp_path / "other.json")


def test_traffic_samples_measure_speed_and_headway_from_the_fixes():
    cfg = TaggerConfig(model="evidence")
    tagger = Tagger(cfg, ROAD)
    store = FixStore(30.0)
    # lane 0: a follower at 20 m/s 25 m behind a leader (bumper gap 20 m: headway 1 s); lane 1: alone at 30 m/s
    store.add(_fixes(1, 0.0, 0.0, 20.0) + _fixes(2, 25.0, 0.0, 20.0) + _fixes(3, 0.0, 4.0, 30.0))
    tagger.observe_traffic(store, 2.0)
    r1, r2, r3 = (tagger.records[i] for i in (1, 2, 3))
    assert (r1.n_samples, r2.n_samples, r3.n_samples) == (1, 1, 1)
    assert r1.n_following == 1 and r1.headway_sum_s == pytest.approx(1.0)
    assert r2.n_following == 0 and r3.n_following == 0
    assert r3.speed_sum == pytest.approx(30.0) and r3.speed_rel_sum == pytest.approx(10.0)  # median 20
    # a vehicle whose last fix is older than a second is not sampled
    tagger.observe_traffic(store, 3.5)
    assert r1.n_samples == 1


def test_the_two_class_default_does_not_track_traffic():
    tagger = Tagger(TaggerConfig(), ROAD)
    assert tagger.evidence_model is None and not tagger.tracks_traffic
    assert "model" not in load_config().to_dict()["twin"]["tagger"]
    shipped = Tagger(TaggerConfig(model="evidence"), ROAD)
    assert shipped.tracks_traffic and shipped.evidence_model is not None


def test_fit_recovers_the_direction_of_the_evidence():
    rng = np.random.default_rng(0)
    n = len(EVIDENCE_FEATURES)
    x = rng.standard_normal((2000, n))
    k = EVIDENCE_FEATURES.index("headway")
    y = rng.random(2000) < 1 / (1 + np.exp(-(-1.5 + -2.0 * x[:, k])))
    model = fit(x, y, l2=0.1)
    assert model.weights[k] == pytest.approx(-2.0, abs=0.3)
    assert np.abs(np.delete(model.weights, k)).max() < 0.3
    with pytest.raises(ValueError, match="both classes"):
        fit(x, np.zeros(2000, dtype=bool))


def test_train_tagger_mistakes_are_one_line_errors_and_keep_existing_weights(tmp_path, capsys):
    from dt_highway.cli import main

    tiny = ["--seeds", "1", "--episodes", "1", "--quiet", "--set", "highway.vehicles_count=8", "--set",
            "highway.duration=5", "--set", "twin.preroll_s=2", "--set", "traffic.population_size=20"]
    out = tmp_path / "w.json"
    out.write_text("{}")
    assert main(["train-tagger", "--out", str(out), *tiny]) == 2
    assert f"{out} exists: pass --force to replace it" in capsys.readouterr().err and out.read_text() == "{}"
    assert main(["train-tagger", "--out", str(out), "--force", "--set", "traffic.aggressive_fraction=0", *tiny]) == 2
    err = capsys.readouterr().err
    assert err.startswith("dt-highway train-tagger: error: train-tagger needs drivers of both classes") and \
        err.count("\n") == 1 and out.read_text() == "{}"


@pytest.mark.parametrize(("content", "message"), [
    ("{}", "has no 'features' (a file of dt-highway train-tagger holds features, mean, scale, weights and bias)"),
    ("[1, 2]", "not an object of features, mean, scale, weights and bias"),
    ("not json", "cannot read"),
])
def test_a_damaged_evidence_weights_file_is_one_line_naming_what_is_missing(tmp_path, content, message):
    from dt_highway.config import ConfigError

    path = tmp_path / "w.json"
    path.write_text(content)
    with pytest.raises(ConfigError, match=r"^twin.tagger.evidence_weights: .*" + re.escape(message)):
        EvidenceModel.load(path)
