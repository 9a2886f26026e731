"""Uplink, store, tagger, cloud and downlink, on hand-made inputs."""

import math
import subprocess
import sys

import numpy as np
import pytest

from dt_highway.config import ConfigError, DownlinkConfig, TaggerConfig, TwinConfig, UplinkConfig
from dt_highway.twin import (
    CloudTwin,
    Downlink,
    FixStore,
    GnssFix,
    HighwayMap,
    Tagger,
    Uplink,
    VehicleState,
    cloud,
    posterior_aggressive,
)
from dt_highway.twin.cloud import load_records, save_records
from dt_highway.twin.tagger import fit_ramp


def _state(vid=1, x=0.0, y=4.0, vx=25.0):
    return VehicleState(vid, x, y, vx, 0.0, vx, 0.0)


def _run_uplink(cfg, seconds=20.0, sim_hz=15, n=3):
    up = Uplink(cfg, np.random.default_rng(0))
    fixes = []
    dt = 1.0 / sim_hz
    for k in range(int(seconds * sim_hz)):
        t_prev, t_now = k * dt, (k + 1) * dt
        states = [_state(v, x=25.0 * t_now, y=4.0 * v) for v in range(1, n + 1)]
        fixes += up.sample(t_prev, t_now, states)
    return fixes


def test_uplink_rate_is_exact_even_between_sim_steps():
    fixes = _run_uplink(UplinkConfig(rate_hz=10.0, loss_prob=0.0), seconds=20.0, sim_hz=15)
    for vid in (1, 2, 3):
        t = np.array([f.t_s for f in fixes if f.vehicle_id == vid])
        assert abs(len(t) - 200) <= 1
        assert np.allclose(np.diff(t), 0.1)


def test_uplink_position_is_taken_at_the_fix_time():
    fixes = _run_uplink(UplinkConfig(rate_hz=7.0, noise_sigma_m=0.0, loss_prob=0.0), sim_hz=15)
    assert abs(len(fixes) - 3 * 7 * 20) <= 3  # three cars at 7 Hz for 20 s: the loop below sees them all
    for f in fixes:
        assert f.x_m == pytest.approx(25.0 * f.t_s, abs=1e-9)


def test_uplink_noise_loss_and_latency_statistics():
    cfg = UplinkConfig(rate_hz=10.0, noise_sigma_m=2.0, loss_prob=0.2, latency_mean_s=0.3, latency_jitter_s=0.05)
    fixes = _run_uplink(cfg, seconds=60.0, n=5)
    assert 0.75 * 3000 < len(fixes) < 0.85 * 3000  # 20 % lost
    err = np.array([f.x_m - 25.0 * f.t_s for f in fixes])
    assert np.std(err) == pytest.approx(2.0, rel=0.08)
    lat = np.array([f.arrival_s - f.t_s for f in fixes])
    assert lat.mean() == pytest.approx(0.3, abs=0.01)
    assert lat.min() >= 0.0


def test_store_is_bounded_and_sorted():
    store = FixStore(window_s=5.0)
    rng = np.random.default_rng(1)
    times = rng.permutation(np.arange(0, 30, 0.1))[:200]
    store.add(GnssFix(1, float(t), 0.0, 0.0, 0.0, 0.0, float(t)) for t in times)
    h = store.history(1)
    assert np.all(np.diff(h[:, 0]) >= 0)
    assert h[-1, 0] - h[0, 0] <= 5.0 + 1e-9


def _lane_change_track(lat_speed, noise, rng, rate=10.0, dur=30.0, t_start=12.0, width=4.0):
    t = np.arange(0, dur, 1.0 / rate)
    ramp = np.clip((t - t_start) * lat_speed / width, 0, 1) * width
    return t, 4.0 + ramp + rng.normal(0, noise, len(t))


def _judge(lat_speed, noise, seed):
    rng = np.random.default_rng(seed)
    t, y = _lane_change_track(lat_speed, noise, rng)
    store = FixStore(60.0)
    store.add(GnssFix(7, float(ti), 25.0 * ti, float(yi), 25.0, 0.0, float(ti)) for ti, yi in zip(t, y, strict=True))
    seen = []
    tagger = Tagger(TaggerConfig(), HighwayMap(4.0, 3))
    tagger.on_lane_change = lambda vid, lc: seen.append(lc)
    tagger.update(store, 7, float(t[-1]))
    return seen


def test_fit_ramp_recovers_duration_without_noise():
    t = np.arange(0, 20, 0.1)
    y = np.clip((t - 8.0) / 2.0, 0, 1) * 4.0
    t_mid, dur = fit_ramp(t, y, 9.0, 4.0)
    assert dur == pytest.approx(2.0, rel=0.1)
    assert t_mid == pytest.approx(9.0, abs=0.1)


@pytest.mark.parametrize("noise", [0.0, 1.0])
def test_gentle_and_sudden_lane_changes_are_told_apart(noise):
    gentle = [_judge(1.0, noise, s) for s in range(40)]
    sudden = [_judge(3.0, noise, s) for s in range(40)]
    assert all(len(g) == 1 for g in gentle + sudden)  # exactly one lane change found each time
    false_alarms = sum(g[0].sudden for g in gentle)
    hits = sum(s[0].sudden for s in sudden)
    assert false_alarms <= 1
    assert hits >= 38


def test_no_lane_change_in_a_noisy_straight_track():
    rng = np.random.default_rng(3)
    t = np.arange(0, 30, 0.1)
    store = FixStore(60.0)
    store.add(GnssFix(1, float(ti), 25 * ti, 4.0 + rng.normal(0, 1.0), 25.0, 0.0, float(ti)) for ti in t)
    tagger = Tagger(TaggerConfig(), HighwayMap(4.0, 3))
    rec = tagger.update(store, 1, 30.0)
    assert rec.n_lane_changes == 0 and rec.tag == "normal"


def test_posterior_needs_repeated_sudden_changes():
    cfg = TaggerConfig()
    assert posterior_aggressive(0, 0.0, cfg) == pytest.approx(cfg.prior_aggressive)
    assert posterior_aggressive(1, 1.0, cfg) < cfg.threshold  # one sudden change is not enough
    assert posterior_aggressive(3, 60.0, cfg) > cfg.threshold
    assert posterior_aggressive(3, 60.0, cfg) > posterior_aggressive(3, 600.0, cfg)  # calm time lowers it
    assert posterior_aggressive(4, 60.0, cfg) > posterior_aggressive(3, 60.0, cfg)


def test_cloud_only_sees_fixes_after_they_arrive():
    twin = CloudTwin(TwinConfig(), HighwayMap(4.0, 3))
    twin.receive([GnssFix(1, 0.0, 0.0, 4.0, 25.0, 0.0, arrival_s=0.5)])
    twin.advance(0.4)
    assert 1 not in twin.store
    twin.advance(0.5)
    assert 1 in twin.store


def test_downlink_view_latency_radius_and_no_ego():
    link = DownlinkConfig(rate_hz=10, latency_mean_s=0.2, latency_jitter_s=0.0, loss_prob=0.0, radius_m=100)
    cfg = TwinConfig(downlink=link)
    twin = CloudTwin(cfg, HighwayMap(4.0, 3))
    fixes = [GnssFix(0, 0.0, 0.0, 4.0, 25, 0, 0.0), GnssFix(1, 0.0, 50.0, 0.0, 25, 0, 0.0),
             GnssFix(2, 0.0, 500.0, 0.0, 25, 0, 0.0)]
    twin.receive(fixes)
    down = Downlink(cfg.downlink, np.random.default_rng(0))
    twin.advance(0.0)
    assert down.step(twin, 0, 0.0) is None  # sent at 0.0, arrives at 0.2
    twin.advance(0.2)
    view = down.step(twin, 0, 0.2)
    assert view is not None and view.t_sent_s == 0.0 and view.t_received_s == pytest.approx(0.2)
    assert [v.vehicle_id for v in view.vehicles] == [1]  # not the ego, not the far one
    assert not hasattr(view.vehicles[0], "driver_type")


def test_sqlite_store_round_trip(tmp_path):
    path = tmp_path / "twin.sqlite"
    cfg = TwinConfig(store={"path": str(path)})
    twin = CloudTwin(cfg, HighwayMap(4.0, 3))
    rec = twin.tagger.record(5, 10.0)
    rec.n_sudden, rec.observed_s = 3, 90.0
    twin.now_s = 123.0
    twin.close()  # writes the file and lets another twin open it
    again = CloudTwin(cfg, HighwayMap(4.0, 3))
    assert again.tagger.records[5].n_sudden == 3
    assert again.now_s == 123.0
    again.close()
    save_records(path, again)  # the writer alone, as a tool may use it
    assert CloudTwin(cfg, HighwayMap(4.0, 3)).now_s == 123.0


@pytest.mark.skipif(cloud.fcntl is None, reason="no fcntl (not POSIX): store files are not locked")
def test_a_store_file_serves_one_twin_at_a_time(tmp_path):
    """A second twin on the same file (in this process or another) would replace what the first wrote at its
    close: refused in one line until the first closes; an empty file (a made temporary file) is a new store."""
    path = tmp_path / "twin.sqlite"
    path.write_bytes(b"")
    cfg = TwinConfig(store={"path": str(path)})
    first = CloudTwin(cfg, HighwayMap(4.0, 3))
    assert first.tagger.records == {}
    with pytest.raises(ConfigError, match=r"^twin.store.path '.*' is in use by another env .*env.close\(\).*own file") as err:
        CloudTwin(cfg, HighwayMap(4.0, 3))
    assert "\n" not in str(err.value)
    code = (f"from dt_highway.twin.cloud import lock_store\ntry:\n    lock_store({str(path)!r})\n"
            "except ValueError as e:\n    print(e)")
    other = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert "is in use by another env" in other.stdout
    first.close()
    CloudTwin(cfg, HighwayMap(4.0, 3)).close()


def test_a_foreign_store_file_leaves_no_hold_on_it(tmp_path):
    path = tmp_path / "junk.sqlite"
    path.write_bytes(b"this is not sqlite at all" * 100)
    cfg = TwinConfig(store={"path": str(path)})
    for _ in range(2):  # the same error again, not "in use"
        with pytest.raises(ConfigError, match="not a dt-highway twin store"):
            CloudTwin(cfg, HighwayMap(4.0, 3))


def test_sqlite_store_rejects_a_foreign_file(tmp_path):
    path = tmp_path / "junk.sqlite"
    path.write_bytes(b"this is not sqlite at all" * 100)
    with pytest.raises(ValueError, match="not a dt-highway twin store"):
        load_records(path, CloudTwin(TwinConfig(), HighwayMap(4.0, 3)))


def test_posterior_is_finite_for_extreme_evidence():
    p = posterior_aggressive(10_000, 0.0, TaggerConfig())
    assert math.isfinite(p) and p <= 1.0
