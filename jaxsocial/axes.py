"""Axes for people: env-step counts as 64k / 1.2M on a matplotlib x axis (learning curves and figures)."""

from __future__ import annotations


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
