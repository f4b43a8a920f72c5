"""The statistics over seeds, as pure functions of numbers (no files, no figures).

* Exact tests of learned-seed counts, k_a of n_a seeds against k_b of n_b, their power, and Holm's
  correction. The tests are scipy's: Fisher's exact test conditions on the total learned; Boschloo's ranks
  tables by Fisher's p-value and takes the supremum over the common success rate, so it is never less
  powerful than Fisher's. `power` enumerates every table, which scipy does not offer.
* Time to event over seeds: each seed's takeoff, or its run's end where it never took off (right-censored);
  the fraction of seeds past the plateau, its Kaplan-Meier estimate and the log-rank test.
* Per-seed scores: the Mann-Whitney U test of two samples, the paired difference with its Wilcoxon test.
* A summary's conditions: which 95% intervals separate, and the learned-seed tests of every pair.

* Means over seeds: the mean's t interval, the interquartile mean (IQM) and its bootstrap interval, and a
  summary of final returns with both (`summary`).

Numbers in, numbers out (numpy and scipy only): runs, summaries, figures and the tools for people read it.
"""

from __future__ import annotations

import functools
import itertools
import math
import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np

from jaxsocial import lazy

scipy_stats = lazy.module("scipy.stats")
"""scipy's tests and intervals, imported at their first use (a design's checks read only the names here)."""

# ----------------------------------------------------------------------------------------------------------
# Means over seeds
# ----------------------------------------------------------------------------------------------------------


def mean_ci95(values: np.ndarray) -> tuple[float, float, float]:
    """Mean and a 95% t-interval of the mean of independent samples (half-width 0 for one sample)."""
    values = np.asarray(values, np.float64)
    mean = float(values.mean())
    n = len(values)
    if n < 2:
        return mean, mean, mean
    half = float(scipy_stats.t.ppf(0.975, n - 1)) * float(values.std(ddof=1)) / math.sqrt(n)
    return mean, mean - half, mean + half


IQM_RESAMPLES = 10_000
"""Bootstrap resamples of `iqm_ci95`."""


def iqm(values: np.ndarray, axis: int = -1) -> np.ndarray:
    """The interquartile mean: the mean after cutting a quarter of the values from each end (as rliable
    computes it, `scipy.stats.trim_mean(values, 0.25)`)."""
    return scipy_stats.trim_mean(values, 0.25, axis=axis)


def iqm_ci95(values: np.ndarray) -> tuple[float, float, float]:
    """The IQM of independent samples and its 95% percentile-bootstrap interval (`IQM_RESAMPLES` resamples
    of the samples, a fixed generator so a summary re-derives exactly; rliable's interval for one task).
    Unlike a t interval it stays within the samples' range when seeds either learn or do not."""
    values = np.asarray(values, np.float64)
    value = float(iqm(values))
    if len(values) < 2:
        return value, value, value
    interval = scipy_stats.bootstrap(
        (values,),
        iqm,
        n_resamples=IQM_RESAMPLES,
        method="percentile",
        rng=np.random.default_rng(0),
    ).confidence_interval
    return value, float(interval.low), float(interval.high)


def summary(values: list[float]) -> dict[str, Any]:
    """{'final_returns': per-seed values, 'mean', 'ci95': [lo, hi] (Student t over seeds), 'iqm',
    'iqm_ci95': [lo, hi] (bootstrap over seeds)}; the statistics skip non-finite values."""
    finite = np.array([v for v in values if np.isfinite(v)], np.float64)
    if not len(finite):
        return {"final_returns": values, "mean": None, "ci95": None, "iqm": None, "iqm_ci95": None}
    mean, lo, hi = mean_ci95(finite)
    middle, iqm_lo, iqm_hi = iqm_ci95(finite)
    return {
        "final_returns": [round(v, 4) for v in values],
        "mean": round(mean, 4),
        "ci95": [round(lo, 4), round(hi, 4)],
        "iqm": round(middle, 4),
        "iqm_ci95": [round(iqm_lo, 4), round(iqm_hi, 4)],
    }


# ----------------------------------------------------------------------------------------------------------
# Learned-seed counts
# ----------------------------------------------------------------------------------------------------------

ALTERNATIVES = ("greater", "less", "two-sided")
"""The alternatives a test of one arm against another takes: the first arm greater, less, or either."""
TESTS = ("fisher-greater", "boschloo-greater")
"""The one-sided tests (a learned more often than b) a design can name."""


def _table(learned_a: int, n_a: int, learned_b: int, n_b: int) -> list[list[int]]:
    """scipy's 2x2 layout: one column per condition, learned in the first row."""
    return [[learned_a, learned_b], [n_a - learned_a, n_b - learned_b]]


def fisher(learned_a: int, n_a: int, learned_b: int, n_b: int, alternative: str = "greater") -> float:
    """Fisher's exact test; 'greater': the probability, if learning did not depend on the condition, that a's
    seeds hold at least `learned_a` of the `learned_a + learned_b` learned seeds."""
    table = _table(learned_a, n_a, learned_b, n_b)
    return float(scipy_stats.fisher_exact(table, alternative=alternative).pvalue)


def boschloo(learned_a: int, n_a: int, learned_b: int, n_b: int, alternative: str = "greater") -> float:
    """Boschloo's exact test: the largest probability, over the common success rate, of a table whose Fisher
    p-value is at most the observed one."""
    table = _table(learned_a, n_a, learned_b, n_b)
    return float(scipy_stats.boschloo_exact(table, alternative=alternative).pvalue)


def _binomial(n: int, rate: float) -> np.ndarray:
    """float64[n + 1] binomial probabilities of k = 0..n successes."""
    return np.array([math.comb(n, k) * rate**k * (1 - rate) ** (n - k) for k in range(n + 1)])


def p_value(test: str, learned_a: int, n_a: int, learned_b: int, n_b: int) -> float:
    """The one-sided p-value of `test` (one of `TESTS`)."""
    if test == "fisher-greater":
        return fisher(learned_a, n_a, learned_b, n_b)
    if test == "boschloo-greater":
        return boschloo(learned_a, n_a, learned_b, n_b)
    raise ValueError(f"unknown test {test!r}; choose from {TESTS}")


def holm(p_values: dict[str, float]) -> dict[str, float]:
    """Holm's step-down adjustment of a family of p-values: the k-th smallest (from 0) is multiplied by
    (m - k), kept at least the previous adjusted value, and capped at 1."""
    ordered = sorted(p_values, key=p_values.get)
    adjusted, running = {}, 0.0
    for k, name in enumerate(ordered):
        running = max(running, min(1.0, (len(ordered) - k) * p_values[name]))
        adjusted[name] = running
    return {name: adjusted[name] for name in p_values}


def holm_rejects(p: np.ndarray, alpha: float) -> np.ndarray:
    """bool[m] which of the p-values float64[m] Holm's step-down procedure rejects at family level `alpha`
    (those whose `holm` adjustment is at most `alpha`)."""
    adjusted = holm(dict(enumerate(p)))
    return np.array([adjusted[i] <= alpha for i in range(len(p))], bool)


def power(test: str, n_a: int, rate_a: float, n_b: int, rate_b: float, alpha: float) -> float:
    """The probability that `test` rejects at level `alpha` when each seed of a learns with probability
    `rate_a` and each of b with `rate_b`, independently (exact: a sum over every table)."""
    prob_a, prob_b = _binomial(n_a, rate_a), _binomial(n_b, rate_b)
    return float(prob_a @ rejection_region(test, n_a, n_b, alpha).astype(np.float64) @ prob_b)


@functools.cache
def rejection_region(test: str, n_a: int, n_b: int, alpha: float) -> np.ndarray:
    """bool[n_a + 1, n_b + 1], read-only: whether `test` rejects at level `alpha` when i of a's `n_a` seeds
    and j of b's `n_b` learned. Cached: every power at the same arm sizes and level sums over the same tables
    (Boschloo's test takes about 10 ms a table, and 40 seeds an arm make 1,681)."""
    region = np.array(
        [[p_value(test, i, n_a, j, n_b) <= alpha for j in range(n_b + 1)] for i in range(n_a + 1)]
    )
    region.flags.writeable = False
    return region


def learned_by(hazard_per_million: float, env_steps: float) -> float:
    """The probability that a seed has learned by `env_steps` under a constant hazard (per million
    env-steps): 1 - exp(-hazard * env_steps / 1e6)."""
    return 1.0 - math.exp(-hazard_per_million * env_steps / 1e6)


# ----------------------------------------------------------------------------------------------------------
# Time to takeoff
# ----------------------------------------------------------------------------------------------------------


def fraction_learned(takeoffs: list[int | None], at: np.ndarray) -> np.ndarray:
    """float64[T] the fraction of the seeds whose takeoff (iteration or env-step, as `at`) is at or before
    each point of `at`; seeds that never took off count as not yet."""
    times = np.array([t for t in takeoffs if t is not None], np.float64)
    return np.array([(times <= x).sum() / len(takeoffs) for x in np.asarray(at)], np.float64)


def censored(takeoffs: Sequence[float | None], ends: Sequence[float]) -> scipy_stats.CensoredData:
    """scipy's right-censored sample: each seed's takeoff, or its run's end where it never took off."""
    observed = [float(t) for t in takeoffs if t is not None]
    right = [float(e) for t, e in zip(takeoffs, ends, strict=True) if t is None]
    return scipy_stats.CensoredData(uncensored=observed, right=right)


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
    result = scipy_stats.logrank(censored(*a), censored(*b), alternative=alternative)
    return {"statistic": float(result.statistic), "p": float(result.pvalue)}


BAND_DECIMALS = 12
"""Decimals of a Kaplan-Meier band: its log and exp run in numpy's SIMD code, whose last bits differ between
CPU kinds (the experts summary's bands: up to 1.1e-16 apart between an Intel AVX-512 kind and the AMD Zen 3
it was made on), so a summary keeps the band to 1e-12 and re-derives alike on both."""


def kaplan_meier(
    takeoffs: Sequence[float | None], ends: Sequence[float], confidence: float = 0.95
) -> dict[str, list[float]]:
    """The Kaplan-Meier estimate of the fraction of seeds past the plateau against time, 1 - S(t), with its
    pointwise `confidence` band (scipy's log-log interval of S, to `BAND_DECIMALS`): 'time' (0 first, then
    each distinct takeoff), 'learned', 'low', 'high'. A step function, constant after each time until the
    next."""
    times, learned, low, high = [0.0], [0.0], [0.0], [0.0]
    if any(t is not None for t in takeoffs):
        fit = scipy_stats.ecdf(censored(takeoffs, ends))
        with warnings.catch_warnings():  # undefined where S is 0 or 1: the band is the estimate there
            warnings.simplefilter("ignore", RuntimeWarning)
            band = fit.sf.confidence_interval(confidence, method="log-log")
        at = np.asarray(fit.sf.quantiles, np.float64)
        estimate = 1.0 - fit.sf.evaluate(at)
        lows, highs = 1.0 - band.high.evaluate(at), 1.0 - band.low.evaluate(at)  # 1 - S swaps the bounds
        times += at.tolist()
        learned += estimate.tolist()
        low += np.where(np.isnan(lows), estimate, lows).round(BAND_DECIMALS).tolist()
        high += np.where(np.isnan(highs), estimate, highs).round(BAND_DECIMALS).tolist()
    return {"time": times, "learned": learned, "low": low, "high": high}


# ----------------------------------------------------------------------------------------------------------
# Per-seed scores
# ----------------------------------------------------------------------------------------------------------


def mann_whitney(a: list[float], b: list[float], alternative: str) -> dict[str, Any]:
    """The Mann-Whitney U test of a's scores against b's ('greater': a's tend to be larger): the statistic,
    the p-value and the sample sizes [len(a), len(b)]; p None (and no statistic) if either is empty."""
    if not a or not b:
        return {"p": None, "n": [len(a), len(b)]}
    result = scipy_stats.mannwhitneyu(a, b, alternative=alternative)
    return {"statistic": float(result.statistic), "p": float(result.pvalue), "n": [len(a), len(b)]}


def paired_difference(
    before: list[float], after: list[float], alternative: str = "two-sided"
) -> dict[str, Any]:
    """`after` minus `before` per seed: n, mean, 95% t-interval and the Wilcoxon signed-rank p (`alternative`
    'greater': after tends to exceed before; None under 2 pairs or when every difference is 0); mean and
    interval None without pairs."""
    diff = np.asarray(after, np.float64) - np.asarray(before, np.float64)
    if not len(diff):
        return {"n": 0, "mean": None, "ci95": None, "wilcoxon_p": None}
    mean, low, high = mean_ci95(diff)
    p = None
    if len(diff) >= 2 and np.any(diff != 0):
        p = float(scipy_stats.wilcoxon(diff, alternative=alternative).pvalue)
    return {"n": int(len(diff)), "mean": mean, "ci95": [low, high], "wilcoxon_p": p}


# ----------------------------------------------------------------------------------------------------------
# A summary's conditions (`summary` of each, with 'seeds_above_one_tile')
# ----------------------------------------------------------------------------------------------------------


def separations(conditions: dict[str, dict[str, Any]]) -> dict[str, bool]:
    """For each ordered pair of conditions by mean, 'a > b': whether a's 95% CI lies entirely above b's."""
    out = {}
    for a, b in itertools.permutations(conditions, 2):
        sa, sb = conditions[a], conditions[b]
        if sa.get("ci95") and sb.get("ci95") and sa["mean"] > sb["mean"]:
            out[f"{a} > {b}"] = sa["ci95"][0] > sb["ci95"][1]
    return out


def ct_score(condition: dict[str, Any], score: str) -> dict[str, Any]:
    """A ct recipe condition's stats of `score`: 'final' (the training return), 'ct' or 'recall'."""
    return condition if score == "final" else condition[score]


LEARNED_TESTS_METHOD = (
    "stated: the recipe's hypotheses, each 'a > b' one-sided (a's seeds learned more often), uncorrected; "
    "exploratory: every other pair, two-sided, *_holm adjusted over the exploratory pairs (Holm)"
)


def learned_seed_tests(
    conditions: dict[str, dict[str, Any]], stated: tuple[tuple[str, str], ...]
) -> dict[str, Any]:
    """Fisher and Boschloo exact tests of the learned-seed counts (`seeds_above_one_tile` of each condition's
    finite seeds). 'stated': each hypothesis (a, b) of `stated` whose conditions are both present, 'a > b',
    one-sided in that direction. 'exploratory': every other pair, 'a vs b', two-sided, with p-values
    Holm-adjusted over the exploratory family (`_holm` keys). Each test also gives the counts
    [learned_a, seeds_a, learned_b, seeds_b]."""
    table = {c: (conditions[c]["seeds_above_one_tile"], _seeds(conditions[c])) for c in conditions}
    stated = tuple((a, b) for a, b in stated if a in table and b in table)
    out: dict[str, Any] = {"method": LEARNED_TESTS_METHOD}
    out["stated"] = {f"{a} > {b}": _count_tests(table[a], table[b], "greater") for a, b in stated}
    explored = {
        f"{a} vs {b}": _count_tests(table[a], table[b], "two-sided")
        for a, b in itertools.combinations(conditions, 2)
        if (a, b) not in stated and (b, a) not in stated
    }
    for test in ("fisher_p", "boschloo_p"):
        adjusted = holm({pair: entry[test] for pair, entry in explored.items()})
        for pair, entry in explored.items():
            entry[f"{test}_holm"] = adjusted[pair]
    out["exploratory"] = explored
    for entry in (*out["stated"].values(), *explored.values()):
        entry.update({k: round_p(v, 4) for k, v in entry.items() if k != "learned"})
    return out


def round_p(value: float, decimals: int) -> float:
    """`value` to `decimals` decimals, or to 3 significant digits below 10**-decimals, so that a positive
    p-value never reads 0."""
    return round(value, decimals) if abs(value) >= 10.0**-decimals else float(f"{value:.3g}")


def _count_tests(a: tuple[int, int], b: tuple[int, int], alternative: str) -> dict[str, Any]:
    return {
        "learned": [a[0], a[1], b[0], b[1]],
        "fisher_p": fisher(*a, *b, alternative=alternative),
        "boschloo_p": boschloo(*a, *b, alternative=alternative),
    }


def _seeds(condition: dict[str, Any]) -> int:
    return sum(np.isfinite(v) for v in condition["final_returns"] if v is not None)
