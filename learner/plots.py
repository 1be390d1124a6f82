"""Learning-curve and study plots (matplotlib, Agg backend) and their CSV tables."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402


def write_learning_curve(curve: list[dict], paths: tuple[Path, Path], title: str) -> None:
    """Write the per-update rows to CSV and plot test mean error (mm) against points seen."""
    csv_path, png_path = paths
    csv_path.parent.mkdir(parents=True, exist_ok=True)
    table = pd.DataFrame(curve)
    table.to_csv(csv_path, index=False)
    fig, ax = plt.subplots(figsize=(6, 3.5))
    if "mean_mm" in table:
        ax.plot(table["n_seen"], table["mean_mm"], marker=".", label="test mean error")
    ax.plot(table["n_seen"], table["batch_mean_mm"], ls="--", label="new batch, before training")
    ax.set_xlabel("points seen")
    ax.set_ylabel("position error (mm)")
    ax.set_yscale("log")
    ax.set_title(title)
    ax.legend()
    fig.tight_layout()
    fig.savefig(png_path, dpi=110)
    plt.close(fig)
