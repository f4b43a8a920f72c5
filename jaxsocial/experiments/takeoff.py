"""Time to social learning: when each seed left the one-tile plateau, and the fraction of seeds that had by
each point of training (a survival-style curve; outcomes are bimodal, so a mean return hides them).

A seed's *takeoff* is the end of the first block of its learning curve (`metrics.curve`: consecutive
iterations averaged, episode-weighted) whose mean return exceeds the "learned" threshold; None if none does.
"""

from __future__ import annotations

import numpy as np


def takeoff(iterations: np.ndarray, returns: np.ndarray, threshold: float) -> int | None:
    """The first of float64[B] block-end `iterations` whose block mean return exceeds `threshold` (None if
    none does)."""
    above = np.flatnonzero(np.asarray(returns) > threshold)
    return int(iterations[above[0]]) if len(above) else None


def fraction_learned(takeoffs: list[int | None], at: np.ndarray) -> np.ndarray:
    """float64[T] the fraction of the seeds whose takeoff (iteration or env-step, as `at`) is at or before
    each point of `at`; seeds that never took off count as not yet."""
    times = np.array([t for t in takeoffs if t is not None], np.float64)
    return np.array([(times <= x).sum() / len(takeoffs) for x in np.asarray(at)], np.float64)


def draw(ax, takeoffs: list[int | None], end: float, label: str, color, ls: str = "-") -> None:
    """The survival-style step curve of one condition on `ax`, from 0 to `end` (same units as takeoffs), in
    `color` and line style `ls`."""
    times = sorted(t for t in takeoffs if t is not None)
    x = np.array([0.0, *times, end], np.float64)
    ax.step(
        x,
        fraction_learned(takeoffs, x),
        where="post",
        color=color,
        ls=ls,
        lw=2,
        label=f"{label} (n={len(takeoffs)})",
    )
