"""Writing matplotlib figures: one resolution and one layout step for every PNG the project writes; display helpers."""

from __future__ import annotations

from pathlib import Path

import numpy as np

FIGURE_DPI = 120  # [dots per inch] of the PNG figures


def save_figure(fig, directory: Path, name: str) -> Path:
    """Lay out a matplotlib figure, write it to ``directory / name`` (folders created), close it; the path."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    directory.mkdir(parents=True, exist_ok=True)
    path = directory / name
    fig.savefig(path, dpi=FIGURE_DPI)
    plt.close(fig)
    return path


def moving_mean(values: np.ndarray, n: int) -> np.ndarray:
    """Means of every n consecutive samples (len(values) - n + 1 of them): a display-only smoothing."""
    c = np.cumsum(np.concatenate([[0.0], np.asarray(values, dtype=float)]))
    return (c[n:] - c[:-n]) / n

