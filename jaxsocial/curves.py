"""Learning curves over seeds on a matplotlib Axes (shared by `jaxsocial.plot` and the experiments'
figures): each seed a faint line, the mean a thick one, a 95% Student-t band over the seeds; a panel zoomed
to the means."""

from __future__ import annotations

import numpy as np

from jaxsocial.stats import mean_ci95


def band(ax, xs: list[np.ndarray], ys: list[np.ndarray], label: str, color) -> None:
    """Per-seed faint lines, the mean and a 95% CI band over seeds (cut to the shortest seed)."""
    n = min(len(x) for x in xs)
    x, y = xs[0][:n], np.stack([v[:n] for v in ys])
    for v in y:
        ax.plot(x, v, color=color, alpha=0.25, lw=0.8)
    stats_ = np.array([mean_ci95(y[:, i]) for i in range(n)])
    ax.plot(x, stats_[:, 0], color=color, lw=2, label=label)
    if len(y) > 1:
        ax.fill_between(x, stats_[:, 1], stats_[:, 2], color=color, alpha=0.2)


def zoom_to_means(ax) -> None:
    """Limit `ax`'s y-axis to the range of the mean curves `band` drew on it (the labelled lines), padded by a
    tenth of it: the seeds' lines and the bands beyond are cut, so the differences between the means show."""
    means = np.concatenate([line.get_ydata() for line in ax.lines if not line.get_label().startswith("_")])
    low, high = float(np.nanmin(means)), float(np.nanmax(means))
    pad = 0.1 * (high - low) or 0.1
    ax.set_ylim(low - pad, high + pad)
