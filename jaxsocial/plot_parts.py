"""The parts every plot shares (`jaxsocial.plot`'s curves and the experiments' figures,
`experiments.plot_figures`), on a matplotlib Axes: learning curves over seeds (each seed a faint line, the
mean a thick one, a 95% Student-t band over the seeds), a panel zoomed to the means, and an env-steps x axis
labelled as people read counts (64k, 1.2M)."""

from __future__ import annotations

import numpy as np

from jaxsocial.stats import mean_ci95


def format_steps(value: float, _position=None) -> str:
    """A step count as people read it: 0, 800, 64k, 1.2M, 3.75G (3 significant digits)."""
    for scale, suffix in ((1e9, "G"), (1e6, "M"), (1e3, "k")):
        if abs(value) >= scale:
            return f"{value / scale:.3g}{suffix}"
    return f"{value:.3g}"


def steps_axis(ax) -> None:
    """An env-steps x axis on a matplotlib Axes: at most 5 ticks, labelled by `format_steps`."""
    from matplotlib.ticker import FuncFormatter, MaxNLocator

    ax.xaxis.set_major_locator(MaxNLocator(nbins=5))
    ax.xaxis.set_major_formatter(FuncFormatter(format_steps))
    ax.set_xlabel("env steps", fontsize=8)


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
