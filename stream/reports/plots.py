"""The CLI's PNG plots: error histogram, learning curve, accuracy against training-set size.

Figures are drawn on matplotlib's object API with an Agg canvas of their own, so importing or
calling these never switches the process's matplotlib backend (pyplot is not used).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np


def new_figure(size_in: tuple[float, float], dpi: float = 100.0) -> tuple[Any, Any]:
    """A matplotlib ``Figure`` (``size_in`` inches) on its own Agg canvas, and one axes."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size_in, dpi=dpi)
    FigureCanvasAgg(fig)
    return fig, fig.add_subplot()


def save_figure(fig: Any, path: str | Path, dpi: float = 100.0) -> Path:
    """Lay out ``fig`` tightly and write it to ``path`` as PNG at ``dpi``."""
    fig.tight_layout()
    fig.savefig(path, dpi=dpi, format="png")
    return Path(path)


def save_histogram(errors_mm: np.ndarray, path: str | Path, title: str = "") -> Path:
    """A PNG histogram of position errors (mm)."""
    errors_mm = np.asarray(errors_mm, dtype=float)
    fig, ax = new_figure((6.0, 4.0))
    ax.hist(errors_mm, bins=min(60, max(5, errors_mm.size // 20)), color="tab:blue")
    ax.axvline(errors_mm.mean(), color="tab:red", label=f"mean {errors_mm.mean():.3f} mm")
    ax.set_xlabel("position error (mm)")
    ax.set_ylabel("points")
    ax.set_title(title or f"uncalibrated position error, N = {errors_mm.size}")
    ax.legend()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    return save_figure(fig, path)


def write_learning_curve(curve: list[dict], paths: tuple[Path, Path], title: str) -> None:
    """Write the per-update rows to CSV and plot test mean error (mm) against points seen."""
    import pandas as pd

    csv_path, png_path = paths
    csv_path.parent.mkdir(parents=True, exist_ok=True)
    table = pd.DataFrame(curve)
    table.to_csv(csv_path, index=False)
    fig, ax = new_figure((6, 3.5))
    if "mean_mm" in table:
        ax.plot(table["n_seen"], table["mean_mm"], marker=".", label="test mean error")
    ax.plot(table["n_seen"], table["batch_mean_mm"], ls="--", label="new batch, before training")
    ax.set_xlabel("points seen")
    ax.set_ylabel("position error (mm)")
    ax.set_yscale("log")
    ax.set_title(title)
    ax.legend()
    save_figure(fig, png_path, dpi=110)


def plot_sizes(rows: list[dict], path: Path) -> None:
    """Test mean error (mm, mean ± std over repeats) against training points, log x; nothing
    when the rows have no ``size`` section."""
    sizes = sorted({r["n_train"] for r in rows if r["section"] == "size"})
    if not sizes:
        return
    means = [
        [r["mean_mm"] for r in rows if r["section"] == "size" and r["n_train"] == s] for s in sizes
    ]
    fig, ax = new_figure((5, 3.5))
    ax.errorbar(sizes, [np.mean(m) for m in means], yerr=[np.std(m) for m in means], marker="o")
    ax.set_xscale("log")
    ax.set_xlabel("training points")
    ax.set_ylabel("test mean position error (mm)")
    save_figure(fig, path, dpi=110)
