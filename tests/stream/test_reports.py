"""The CLI's file outputs (``stream.reports``): PNG plots and CSV tables, drawn without pyplot
so that importing or using them never switches the process's matplotlib backend."""

import subprocess
import sys

import numpy as np
import pandas as pd

from stream.reports.plots import plot_sizes, save_histogram, write_learning_curve

PNG = b"\x89PNG\r\n\x1a\n"


def test_histogram_png(tmp_path):
    path = save_histogram(np.random.default_rng(0).gamma(3, 0.3, 500), tmp_path / "h" / "e.png")
    assert path.read_bytes()[:8] == PNG and path.stat().st_size > 5000


def test_learning_curve_csv_and_png(tmp_path):
    curve = [{"n_seen": n, "batch_mean_mm": 1.0 / n, "mean_mm": 0.5 / n} for n in (100, 200, 300)]
    csv_path, png_path = tmp_path / "c" / "m.curve.csv", tmp_path / "c" / "m.curve.png"
    write_learning_curve(curve, (csv_path, png_path), "max_error: N_m=500, n_B=100")
    assert pd.read_csv(csv_path).to_dict("records") == curve
    assert png_path.read_bytes()[:8] == PNG


def test_size_plot_only_with_a_size_section(tmp_path):
    rows = [
        {"section": "size", "n_train": n, "mean_mm": 1.0 / n + r}
        for n in (50, 100)
        for r in (0, 0.1)
    ]
    plot_sizes(rows, tmp_path / "size.png")
    assert (tmp_path / "size.png").read_bytes()[:8] == PNG
    plot_sizes([{"section": "features", "n_train": 10, "mean_mm": 1.0}], tmp_path / "none.png")
    assert not (tmp_path / "none.png").exists()


def test_reports_leave_the_matplotlib_backend_alone(tmp_path):
    code = f"""
import sys, matplotlib
before = matplotlib.rcParams._get_backend_or_none()
import stream.reports.gap, stream.reports.learner
from stream.reports.plots import save_histogram
save_histogram([1.0, 2.0, 3.0], {str(tmp_path / "h.png")!r})
assert "matplotlib.pyplot" not in sys.modules, "pyplot was imported"
assert matplotlib.rcParams._get_backend_or_none() == before, "the backend was switched"
print("ok")
"""
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=False
    )
    assert done.stdout.strip() == "ok", done.stderr[-2000:]
