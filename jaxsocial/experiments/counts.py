"""Exact tests of learned-seed counts, their power, and the Holm correction.

Counts are k_a of n_a seeds against k_b of n_b. The tests are scipy's: Fisher's exact test conditions on the
total learned; Boschloo's ranks tables by Fisher's p-value and takes the supremum over the common success
rate, so it is never less powerful than Fisher's. `power` enumerates every table, which scipy does not offer.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import stats

TESTS = ("fisher-greater", "boschloo-greater")
"""The one-sided tests (a learned more often than b) a design can name."""
ALTERNATIVES = ("greater", "two-sided")


def _table(learned_a: int, n_a: int, learned_b: int, n_b: int) -> list[list[int]]:
    """scipy's 2x2 layout: one column per condition, learned in the first row."""
    return [[learned_a, learned_b], [n_a - learned_a, n_b - learned_b]]


def fisher(learned_a: int, n_a: int, learned_b: int, n_b: int, alternative: str = "greater") -> float:
    """Fisher's exact test; 'greater': the probability, if learning did not depend on the condition, that a's
    seeds hold at least `learned_a` of the `learned_a + learned_b` learned seeds."""
    return float(stats.fisher_exact(_table(learned_a, n_a, learned_b, n_b), alternative=alternative).pvalue)


def boschloo(learned_a: int, n_a: int, learned_b: int, n_b: int, alternative: str = "greater") -> float:
    """Boschloo's exact test: the largest probability, over the common success rate, of a table whose Fisher
    p-value is at most the observed one."""
    return float(stats.boschloo_exact(_table(learned_a, n_a, learned_b, n_b), alternative=alternative).pvalue)


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


def power(test: str, n_a: int, rate_a: float, n_b: int, rate_b: float, alpha: float) -> float:
    """The probability that `test` rejects at level `alpha` when each seed of a learns with probability
    `rate_a` and each of b with `rate_b`, independently (exact: a sum over every table)."""
    rejects = np.array(
        [[p_value(test, i, n_a, j, n_b) <= alpha for j in range(n_b + 1)] for i in range(n_a + 1)]
    )
    prob_a, prob_b = _binomial(n_a, rate_a), _binomial(n_b, rate_b)
    return float(prob_a @ rejects.astype(np.float64) @ prob_b)


def learned_by(hazard_per_million: float, env_steps: float) -> float:
    """The probability that a seed has learned by `env_steps` under a constant hazard (per million
    env-steps): 1 - exp(-hazard * env_steps / 1e6)."""
    return 1.0 - math.exp(-hazard_per_million * env_steps / 1e6)
