"""Exact one-sided tests of learned-seed counts (treatment learned more often than control), and their power.

Counts are k_a of n_a seeds against k_b of n_b. `fisher_greater` conditions on the total learned;
`boschloo_greater` ranks tables by Fisher's p-value and takes the supremum over the common success rate, so
it is never less powerful than Fisher's. Self-contained (numpy only).
"""

from __future__ import annotations

import math

import numpy as np

TESTS = ("fisher-greater", "boschloo-greater")

NUISANCE_GRID = 2001
"""Points of the common success rate at which `boschloo_greater` evaluates the tail (then refined around the
best one, `REFINE` points within one grid step each side)."""
REFINE = 201


def fisher_greater(learned_a: int, n_a: int, learned_b: int, n_b: int) -> float:
    """One-sided Fisher exact test: the probability, if learning did not depend on the condition, that a's
    seeds hold at least `learned_a` of the `learned_a + learned_b` learned seeds (n_a, n_b seeds in all)."""
    learned, total = learned_a + learned_b, n_a + n_b
    tail = range(learned_a, min(n_a, learned) + 1)
    return sum(math.comb(n_a, k) * math.comb(n_b, learned - k) for k in tail) / math.comb(total, learned)


def _binomial(n: int, rates: np.ndarray) -> np.ndarray:
    """float64[R, n + 1] binomial probabilities of k = 0..n successes at each rate."""
    k = np.arange(n + 1)
    comb = np.array([math.comb(n, int(i)) for i in k], np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        log_p = np.where(k > 0, k * np.log(rates[:, None]), 0.0)
        log_q = np.where(n - k > 0, (n - k) * np.log1p(-rates[:, None]), 0.0)
    return comb * np.exp(log_p + log_q)


def _fisher_table(n_a: int, n_b: int) -> np.ndarray:
    """float64[n_a + 1, n_b + 1] `fisher_greater` of every table."""
    return np.array([[fisher_greater(i, n_a, j, n_b) for j in range(n_b + 1)] for i in range(n_a + 1)])


def _tail(extreme: np.ndarray, n_a: int, n_b: int, rates: np.ndarray) -> np.ndarray:
    """float64[R] the probability of the tables in the bool[n_a + 1, n_b + 1] mask at each common rate."""
    return np.einsum("ri,rj,ij->r", _binomial(n_a, rates), _binomial(n_b, rates), extreme.astype(np.float64))


def boschloo_greater(learned_a: int, n_a: int, learned_b: int, n_b: int) -> float:
    """One-sided Boschloo exact test: the largest probability, over the common success rate, of a table whose
    Fisher p-value is at most the observed one."""
    fisher = _fisher_table(n_a, n_b)
    extreme = fisher <= fisher[learned_a, learned_b] * (1 + 1e-9)
    rates = np.linspace(0.0, 1.0, NUISANCE_GRID)
    tail = _tail(extreme, n_a, n_b, rates)
    best = rates[int(np.argmax(tail))]
    step = 1.0 / (NUISANCE_GRID - 1)
    fine = np.clip(np.linspace(best - step, best + step, REFINE), 0.0, 1.0)
    return float(min(1.0, max(tail.max(), _tail(extreme, n_a, n_b, fine).max())))


def p_value(test: str, learned_a: int, n_a: int, learned_b: int, n_b: int) -> float:
    """The one-sided p-value of `test` (one of `TESTS`)."""
    if test == "fisher-greater":
        return fisher_greater(learned_a, n_a, learned_b, n_b)
    if test == "boschloo-greater":
        return boschloo_greater(learned_a, n_a, learned_b, n_b)
    raise ValueError(f"unknown test {test!r}; choose from {TESTS}")


def power(test: str, n_a: int, rate_a: float, n_b: int, rate_b: float, alpha: float) -> float:
    """The probability that `test` rejects at level `alpha` when each seed of a learns with probability
    `rate_a` and each of b with `rate_b`, independently (exact: a sum over every table)."""
    rejects = np.array(
        [[p_value(test, i, n_a, j, n_b) <= alpha for j in range(n_b + 1)] for i in range(n_a + 1)]
    )
    prob_a = _binomial(n_a, np.array([rate_a]))[0]
    prob_b = _binomial(n_b, np.array([rate_b]))[0]
    return float(prob_a @ rejects.astype(np.float64) @ prob_b)


def learned_by(hazard_per_million: float, env_steps: float) -> float:
    """The probability that a seed has learned by `env_steps` under a constant hazard (per million
    env-steps): 1 - exp(-hazard * env_steps / 1e6)."""
    return 1.0 - math.exp(-hazard_per_million * env_steps / 1e6)
