"""Time to social learning: when each seed left the one-tile plateau (outcomes are bimodal, so a mean return
hides them). The time-to-event statistics over seeds (Kaplan-Meier, log-rank) are `stats`'s.

One definition everywhere (recipes, designs, the sweep): a seed's learning curve is cut into windows of
`window_iterations` consecutive iterations, about `WINDOW_STEPS` env-steps each, from its first iteration on
(the last window may be shorter). Its *takeoff* is the end of the first window whose episode-weighted mean
learner return exceeds the "learned" threshold (`metrics.LEARNED_RETURN`, 2); a seed that never takes off
is right-censored at the end of its run. The window width depends only on the env-steps per iteration, not
on the run's length, so seeds of different budgets share their windows.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from jaxsocial.run import metrics

WINDOW_STEPS = 200_000
"""Env-steps per window of the learning curve in which a takeoff is looked for."""


def window_iterations(steps_per_iteration: int) -> int:
    """Iterations per window: `WINDOW_STEPS` env-steps rounded to whole iterations (at least 1); 24 at the
    laptop and cpu scales' 8,192 env-steps per iteration (196,608 env-steps)."""
    return max(1, round(WINDOW_STEPS / steps_per_iteration))


def window_curve(
    rows: Sequence[Mapping[str, Any]], steps_per_iteration: int, slot: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """(float64[W] the last iteration of each window, float64[W] its episode-weighted mean return of `slot`;
    nan where no episode ended in it)."""
    returns, episodes = metrics.slot_returns(list(rows), slot)
    width = window_iterations(steps_per_iteration)
    starts = np.arange(0, len(rows), width)
    ends = np.array([rows[min(s + width, len(rows)) - 1][metrics.ITERATION] for s in starts], np.float64)
    summed, counted = np.add.reduceat(returns, starts), np.add.reduceat(episodes, starts)
    with np.errstate(invalid="ignore", divide="ignore"):
        return ends, np.where(counted > 0, summed / counted, np.nan)


def takeoff(iterations: np.ndarray, returns: np.ndarray, threshold: float) -> int | None:
    """The first of float64[B] block-end `iterations` whose block mean return exceeds `threshold` (None if
    none does)."""
    above = np.flatnonzero(np.asarray(returns) > threshold)
    return int(iterations[above[0]]) if len(above) else None


def seed_takeoff(
    rows: Sequence[Mapping[str, Any]], steps_per_iteration: int, threshold: float = metrics.LEARNED_RETURN
) -> int | None:
    """The iteration at which a seed took off (the end of its first window above `threshold`; None if it
    never did)."""
    return takeoff(*window_curve(rows, steps_per_iteration), threshold)
