"""Time to social learning: when each seed left the one-tile plateau, the fraction of seeds that had by each
point of training, and the time-to-event statistics over seeds (outcomes are bimodal, so a mean return hides
them).

One definition everywhere (recipes, designs, the sweep): a seed's learning curve is cut into windows of
`window_iterations` consecutive iterations, about `WINDOW_STEPS` env-steps each, from its first iteration on
(the last window may be shorter). Its *takeoff* is the end of the first window whose episode-weighted mean
learner return exceeds the "learned" threshold (`metrics.LEARNED_RETURN`, 2); a seed that never takes off
is right-censored at the end of its run. The window width depends only on the env-steps per iteration, not
on the run's length, so seeds of different budgets share their windows.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from scipy import stats

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


def fraction_learned(takeoffs: list[int | None], at: np.ndarray) -> np.ndarray:
    """float64[T] the fraction of the seeds whose takeoff (iteration or env-step, as `at`) is at or before
    each point of `at`; seeds that never took off count as not yet."""
    times = np.array([t for t in takeoffs if t is not None], np.float64)
    return np.array([(times <= x).sum() / len(takeoffs) for x in np.asarray(at)], np.float64)


def censored(takeoffs: Sequence[float | None], ends: Sequence[float]) -> stats.CensoredData:
    """scipy's right-censored sample: each seed's takeoff, or its run's end where it never took off."""
    observed = [float(t) for t in takeoffs if t is not None]
    right = [float(e) for t, e in zip(takeoffs, ends, strict=True) if t is None]
    return stats.CensoredData(uncensored=observed, right=right)


def logrank(
    a: tuple[Sequence[float | None], Sequence[float]],
    b: tuple[Sequence[float | None], Sequence[float]],
    alternative: str = "greater",
) -> dict[str, float]:
    """The log-rank test of two samples of (takeoffs, run ends) (`scipy.stats.logrank`). 'greater': a's seeds
    take off sooner than b's (a's hazard of taking off is higher), one-sided. Returns the statistic (a's
    observed minus expected takeoffs over its standard error: positive when a takes off sooner) and the
    p-value; both None when no seed of either took off."""
    if all(t is None for t in (*a[0], *b[0])):  # no takeoff at all: nothing to compare
        return {"statistic": None, "p": None}
    result = stats.logrank(censored(*a), censored(*b), alternative=alternative)
    return {"statistic": float(result.statistic), "p": float(result.pvalue)}


def kaplan_meier(
    takeoffs: Sequence[float | None], ends: Sequence[float], confidence: float = 0.95
) -> dict[str, list[float]]:
    """The Kaplan-Meier estimate of the fraction of seeds past the plateau against time, 1 - S(t), with its
    pointwise `confidence` band (scipy's log-log interval of S): 'time' (0 first, then each distinct takeoff),
    'learned', 'low', 'high'. A step function, constant after each time until the next."""
    times, learned, low, high = [0.0], [0.0], [0.0], [0.0]
    if any(t is not None for t in takeoffs):
        fit = stats.ecdf(censored(takeoffs, ends))
        with warnings.catch_warnings():  # undefined where S is 0 or 1: the band is the estimate there
            warnings.simplefilter("ignore", RuntimeWarning)
            band = fit.sf.confidence_interval(confidence, method="log-log")
        at = np.asarray(fit.sf.quantiles, np.float64)
        estimate = 1.0 - fit.sf.evaluate(at)
        lows, highs = 1.0 - band.high.evaluate(at), 1.0 - band.low.evaluate(at)  # 1 - S swaps the bounds
        times += at.tolist()
        learned += estimate.tolist()
        low += np.where(np.isnan(lows), estimate, lows).tolist()
        high += np.where(np.isnan(highs), estimate, highs).tolist()
    return {"time": times, "learned": learned, "low": low, "high": high}


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


def draw_kaplan_meier(ax, curve: dict[str, list[float]], end: float, label: str, color) -> None:
    """A `kaplan_meier` curve on `ax` as a step line with its shaded band, carried on to `end`."""
    x = np.array([*curve["time"], end], np.float64)
    learned, low, high = (np.array([*curve[k], curve[k][-1]], np.float64) for k in ("learned", "low", "high"))
    ax.step(x, learned, where="post", color=color, lw=2, label=label)
    ax.fill_between(x, low, high, step="post", color=color, alpha=0.15)
