"""The learned detector: data, targets, a tiny training run, the shipped weights, bad files, the plug-in."""

from __future__ import annotations

import json
from fractions import Fraction

import numpy as np
import pytest
import torch

from dt_highway.cli import main
from dt_highway.config import ConfigError, load_config
from dt_highway.evaluation.detector import evaluate
from dt_highway.perception.detect import iou
from dt_highway.perception.learned import SHIPPED, Architecture, LearnedDetector, PointDetector, load_weights, save_weights
from dt_highway.perception.learned.data import TRAIN_SEED0, SceneSettings, make_frame, scored
from dt_highway.perception.learned.model import cell_centres, make_targets, peaks
from dt_highway.perception.learned.train import TrainSettings, randomise_colours, train

TINY = Architecture(width_px=128, height_px=72, channels=(8, 8, 16, 16, 16), features=8)


def test_frames_are_pure_functions_of_their_seed_and_label_the_visible_boxes() -> None:
    a, b = make_frame(13), make_frame(13)
    make_frame(999)
    c = make_frame(13)
    assert np.array_equal(a.rgb, c.rgb) and np.array_equal(a.boxes, c.boxes) and np.array_equal(b.boxes, c.boxes)
    assert a.rgb.shape == (180, 320, 3)
    # the labels are the renderer's visible boxes; scored = KITTI moderate (>= 12 px tall of 180, visibility >= 0.5)
    boxes, keep = scored(a.truth)
    assert np.array_equal(boxes, a.boxes)
    tall = (a.boxes[:, 3] - a.boxes[:, 1]) >= 180 * 25 / 375
    assert not (keep & ~tall).any()
    n_scored = sum(make_frame(s).scored.sum() for s in range(40))
    assert n_scored > 60  # the generator shows vehicles worth scoring


def test_targets_put_one_peak_per_box_and_the_box_on_its_cells() -> None:
    f = make_frame(21)
    heat, box, weight = make_targets(f.boxes, (48, 80))
    xs, ys = cell_centres(48, 80)
    peaks_at = np.argwhere(heat[0] == 1.0)
    centre_cells = {(int(np.floor(((b[1] + b[3]) / 2 + 0.5) / 4)), int(np.floor(((b[0] + b[2]) / 2 + 0.5) / 4)))
                    for b in f.boxes}
    assert {tuple(p) for p in peaks_at} == centre_cells
    # every weighted cell holds one of the boxes, and lies inside it
    cells = np.argwhere(weight[0] > 0)
    assert len(cells) >= len(centre_cells)
    for j, i in cells:
        t = box[:, j, i]
        assert any(np.allclose(t, b) for b in f.boxes.astype(np.float32))
        assert t[0] - 1e-3 <= xs[i] <= t[2] + 1e-3 or (j, i) in centre_cells


def test_colour_randomisation_changes_colours_not_geometry_and_is_seeded() -> None:
    rgb = make_frame(5).rgb
    a = randomise_colours(rgb, np.random.default_rng(1))
    b = randomise_colours(rgb, np.random.default_rng(1))
    c = randomise_colours(rgb, np.random.default_rng(2))
    assert a.shape == rgb.shape and a.dtype == np.uint8
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert np.abs(a.astype(int) - rgb).mean() > 5


def test_decoding_reads_boxes_back_from_perfect_outputs() -> None:
    boxes = np.array([[40.5, 60.5, 90.5, 100.5], [200.5, 70.5, 215.5, 82.5]])
    heat, box, weight = make_targets(boxes, (48, 80))
    logits = torch.from_numpy(np.where(heat == 1.0, 8.0, -8.0))[None]
    xs, ys = cell_centres(48, 80)
    t = torch.from_numpy(box)
    dist = torch.stack([xs[None, :] - t[0], ys[:, None] - t[1], t[2] - xs[None, :], t[3] - ys[:, None]])[None].float()
    found, scores = peaks(logits.float(), dist, min_score=0.5)[0]
    assert len(found) == 2 and (scores > 0.99).all()
    assert np.allclose(np.sort(found, axis=0), np.sort(boxes, axis=0), atol=1e-4)


def test_a_tiny_training_run_lowers_the_loss_and_resumes(tmp_path) -> None:
    losses: list[float] = []
    out = tmp_path / "tiny.pt"
    settings = TrainSettings(minutes=5.0, batch=8, lr=3e-3, warmup_steps=5, replay=64, max_steps=40,
                             checkpoint_every_s=3600)
    r = train(out, TINY, settings, progress=lambda s, e, logs: losses.append(logs["loss"]))
    assert r["steps"] == 40 and not r["resumed"] and out.is_file()
    # seeded: 8.32 -> 5.99 here; the margin allows for other CPUs' floating-point sums
    first, last = np.mean(losses[:5]), np.mean(losses[-8:])
    assert last < 0.85 * first, (first, last)
    model, meta = load_weights(out)
    assert meta["steps"] == 40 and model.arch == TINY
    # the same command again resumes from the checkpoint and goes on to the new step limit
    r2 = train(out, TINY, TrainSettings(**{**settings.__dict__, "max_steps": 45}))
    assert r2["resumed"] and r2["steps"] == 45
    # a checkpoint of another network is not silently resumed
    with pytest.raises(ValueError, match="holds another network"):
        train(out, Architecture(**{**TINY.__dict__, "depth": True}), settings)


def test_bad_weights_files_give_clear_errors(tmp_path) -> None:
    model = PointDetector(TINY)
    good = save_weights(model, tmp_path / "good.pt", {"steps": 0})
    data = good.read_bytes()
    (tmp_path / "truncated.pt").write_bytes(data[: len(data) // 2])
    (tmp_path / "text.pt").write_text("not weights")
    torch.save({"format": "dt-highway-detector", "format_version": 1, "arch": TINY.to_dict(), "state_dict": {}},
               tmp_path / "empty.pt")
    torch.save({"some": "dict"}, tmp_path / "foreign.pt")
    # any Python object beyond plain containers and tensors (here a Fraction) is refused
    torch.save({"format": "dt-highway-detector", "x": Fraction(1, 3)}, tmp_path / "objects.pt")
    assert load_weights(good)[0].arch == TINY
    cases = {
        "truncated.pt": "truncated", "text.pt": "not a torch zip archive", "empty.pt": "tensors missing",
        "foreign.pt": "not a dt-highway detector weights file", "objects.pt": "refused",
    }
    for name, words in cases.items():
        with pytest.raises(ValueError, match=words):
            load_weights(tmp_path / name)
    with pytest.raises(FileNotFoundError):
        load_weights(tmp_path / "missing.pt")


def test_bad_weights_on_the_command_line_are_one_line(tmp_path, capsys) -> None:
    (tmp_path / "bad.pt").write_text("x")
    assert main(["detector", "eval", "--weights", str(tmp_path / "bad.pt"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "not a detector weights file" in err
    assert main(["detector", "eval", "--weights", str(tmp_path / "none.pt"), "--quiet"]) == 2
    assert "weights file not found: " + str(tmp_path / "none.pt") + " (a .pt file from dt-highway detector train" \
        in capsys.readouterr().err
    assert main(["matching", "--out", str(tmp_path / "m"), "--detectors", "yolo", "--quiet"]) == 2
    assert "--detectors takes simulated and/or learned" in capsys.readouterr().err


def test_held_out_seeds_never_meet_the_training_seeds() -> None:
    det = LearnedDetector()
    with pytest.raises(ValueError, match="held-out seeds"):
        evaluate(det, frames=10, seed=TRAIN_SEED0 - 5)


def test_the_shipped_weights_reach_the_ap_targets_on_a_small_seeded_set() -> None:
    assert SHIPPED.is_file() and SHIPPED.stat().st_size < 5e6
    r = evaluate(LearnedDetector(), frames=100, seed=0)
    assert r["scored_vehicles"] > 150
    assert r["AP50"] >= 0.95, r
    assert r["AP75"] >= 0.85, r


def test_the_learned_detector_scales_boxes_to_larger_frames() -> None:
    det = LearnedDetector()
    f = make_frame(7, SceneSettings(640, 360, vary_camera=False))
    found = det.detect(f.image)
    gt = f.boxes[f.scored]
    assert len(gt) >= 1
    best = iou(gt, found.boxes).max(axis=1)
    assert np.median(best) >= 0.7, best


def test_the_env_runs_the_learned_detector_by_config() -> None:
    from dt_highway.env import DTHighwayEnv

    env = DTHighwayEnv(config={"camera": {"enabled": True, "width_px": 320, "height_px": 180},
                               "fusion": {"enabled": True}, "detector": {"kind": "learned"},
                               "highway": {"vehicles_count": 20, "duration": 5.0}, "twin": {"preroll_s": 4.0}})
    env.reset(seed=0)
    type_name = type(env.detector).__name__
    for _ in range(3):
        _, _, term, trunc, info = env.step(1)
    env.close()
    assert type_name == "LearnedDetector"
    assert "adas" in info


def test_detector_commands_train_resume_evaluate_and_bench(tmp_path, capsys) -> None:
    out = tmp_path / "d.pt"
    small = ["--width", "128", "--height", "72", "--batch", "4", "--quiet"]
    assert main(["detector", "train", "--out", str(out), "--max-steps", "3", *small]) == 0
    printed = capsys.readouterr().out
    assert "trained 3 steps" in printed and str(out) in printed
    assert main(["detector", "train", "--out", str(out), "--max-steps", "5", *small]) == 0
    again = capsys.readouterr()
    assert "trained 5 steps" in again.out and "resumed" in again.out and "resuming from" in again.err
    assert main(["detector", "eval", "--weights", str(out), "--frames", "4", "--json", "--quiet"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["frames"] == 4 and r["image_px"] == [128, 72] and 0.0 <= r["AP50"] <= 1.0
    assert main(["bench", "detector", "--weights", str(out), "--seconds", "0.2", "--batch", "2", "--json"]) == 0
    b = json.loads(capsys.readouterr().out)
    assert b["frames_per_s_batched"] > 0 and b["single_frame_ms"]["median"] > 0


def test_matching_reports_both_detectors(tmp_path, capsys) -> None:
    out = tmp_path / "m"
    tiny = ["--set", "highway.vehicles_count=10", "--set", "highway.duration=40", "--set", "twin.preroll_s=4",
            "--set", "highway.lanes_count=3", "--set", "traffic.population_size=40",
            "--set", "camera.width_px=320", "--set", "camera.height_px=180"]
    assert main(["matching", "--out", str(out), "--frames", "3", "--quiet", "--detectors", "simulated,learned", *tiny]) == 0
    both = json.loads((out / "detectors.json").read_text())["accuracy"]
    assert set(both) == {"simulated", "learned"} and set(both["learned"]) == {"baseline", "fusion", "joint", "tracked"}
    for kind in both:
        assert json.loads((out / kind / "summary.json").read_text())["settings"]["detector"]["kind"] == kind


class _Oracle:
    """A 'detector' that returns given boxes: checks the evaluation itself."""

    def __init__(self, with_ignored_fp: bool = False) -> None:
        self.arch = Architecture()
        self.min_score = 0.3
        self.with_ignored_fp = with_ignored_fp

    def detect_batch(self, rgbs, depths=None, min_score=None):
        from dt_highway.perception.detect import Detections

        out = []
        for rgb in rgbs:
            seed = next(s for s in range(1000) if np.array_equal(make_frame(s, SceneSettings(vary_camera=False)).rgb, rgb))
            f = make_frame(seed, SceneSettings(vary_camera=False))
            boxes = f.boxes if self.with_ignored_fp else f.boxes[f.scored]
            out.append(Detections(boxes, np.full(len(boxes), 0.9), np.zeros(len(boxes), dtype=np.int64)))
        return out


def test_the_evaluation_scores_perfect_boxes_as_perfect_and_ignores_ignored_vehicles() -> None:
    perfect = evaluate(_Oracle(), frames=6, seed=0, batch=3)
    assert perfect["AP"] == 1.0 and perfect["AP75"] == 1.0 and perfect["recall_iou07"] == 1.0
    assert perfect["recall_iou07_at_operating_score"] == 1.0 and perfect["precision_iou07_at_operating_score"] == 1.0
    # boxes on the ignored (small, hidden) vehicles too: neither hits nor false alarms
    both = evaluate(_Oracle(with_ignored_fp=True), frames=6, seed=0, batch=3)
    assert both["ignored_vehicles"] > 0
    assert both["AP"] == 1.0 and both["precision_iou07_at_operating_score"] == 1.0


def test_training_and_config_mistakes_are_one_line(tmp_path, capsys) -> None:
    (tmp_path / "bad.pt").write_text("x")
    cases = [
        (["matching", "--out", str(tmp_path / "m"), "--frames", "1", "--quiet", "--set", "detector.kind=learned",
          "--set", f"detector.weights={tmp_path / 'bad.pt'}"], "not a detector weights file"),
        (["detector", "train", "--out", str(tmp_path / "t.pt"), "--batch", "1", "--quiet"], "must be even"),
        (["detector", "train", "--out", str(tmp_path / "t.pt"), "--width", "8", "--quiet"], "32 to 4096"),
        (["detector", "train", "--out", str(tmp_path / "bad.pt"), "--quiet"], "pass --fresh"),
        (["detector", "train", "--out", str(tmp_path / "torn.pt"), "--quiet"],
         "torn.pt.ckpt: not a checkpoint of this trainer"),
    ]
    (tmp_path / "torn.pt.ckpt").write_bytes(b"PK\x03\x04 torn")  # a checkpoint cut short
    for argv, words in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and words in err and "weights_only" not in err, (argv, err)
    assert (tmp_path / "bad.pt").read_text() == "x"  # not replaced without --fresh
    with pytest.raises(SystemExit):  # argparse's own one-line error
        main(["detector", "eval", "--min-score", "0", "--quiet"])
    assert "--min-score must be in (0, 1]" in capsys.readouterr().err


def test_a_weights_file_that_is_no_torch_archive_is_refused_with_the_configuration(tmp_path) -> None:
    """Before any trial: a study ran its baseline trials and failed each ADAS trial on it."""
    bad = tmp_path / "bad.pt"
    bad.write_text("garbage")
    with pytest.raises(ConfigError, match=r"bad.pt is not a detector weights file: not a torch zip archive") as err:
        load_config(None, ["detector.kind=learned", f"detector.weights={bad}"])
    assert "\n" not in str(err.value)
