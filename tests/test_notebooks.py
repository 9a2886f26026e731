"""The analysis notebooks run end to end on a small command output."""

from pathlib import Path

import nbformat
from nbclient import NotebookClient

from dt_highway.cli import main

NOTEBOOKS = Path(__file__).resolve().parent.parent / "notebooks"
TINY = ["--set", "highway.vehicles_count=10", "--set", "highway.duration=40", "--set", "twin.preroll_s=4",
        "--set", "highway.lanes_count=3", "--set", "traffic.population_size=40",
        "--set", "camera.width_px=320", "--set", "camera.height_px=180"]


def test_target_identification_notebook(tmp_path, monkeypatch):
    out = tmp_path / "matching"
    assert main(["matching", "--out", str(out), "--frames", "6", "--quiet", *TINY]) == 0
    monkeypatch.setenv("MATCHING_DIR", str(out))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    nb = nbformat.read(NOTEBOOKS / "target_identification.ipynb", as_version=4)
    NotebookClient(nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}).execute()
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])]
    assert not [o for o in outputs if o.get("output_type") == "error"]
    text = "".join(o.get("text", "") for o in outputs)
    assert "6 frames" in text


def test_safety_study_notebook(tmp_path, monkeypatch):
    out = tmp_path / "study"
    assert main(["study", "--driver", "agents/idm.toml", "--trials", "2", "--workers", "1", "--out", str(out), "--quiet",
                 "--set", "highway.duration=4", "--set", "highway.vehicles_count=12", "--set", "twin.preroll_s=5"]) == 0
    monkeypatch.setenv("STUDY_DIR", str(out))
    monkeypatch.delenv("MPLBACKEND")  # the kernel's inline backend, so that the figures are outputs
    nb = nbformat.read(NOTEBOOKS / "safety_study.ipynb", as_version=4)
    NotebookClient(nb, timeout=300, kernel_name="python3", resources={"metadata": {"path": str(tmp_path)}}).execute()
    outputs = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])]
    assert not [o for o in outputs if o.get("output_type") == "error"]
    text = "".join(o.get("text", "") for o in outputs)
    assert "4 trials, 4 completed, conditions ['baseline', 'adas']" in text and "speed_variance_kmh2:" in text
    assert sum(o.get("output_type") == "display_data" and "image/png" in o.get("data", {}) for o in outputs) == 3
