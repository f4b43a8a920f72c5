"""A design's power, simulated: one table for every family of per-seed score tests (an evaluation design's,
a branch design's and its amendment's), the power of a 'zero_shot' training design's test, and a design's
stated power recomputed from its pilot as its file says (`stated_power`). A 'takeoff' design's log-rank
power is `takeoff_power`'s."""

from __future__ import annotations

from typing import Any

import numpy as np

from jaxsocial import stats
from jaxsocial.experiments.analyse import branch_results, evaluation_results
from jaxsocial.experiments.plan import catalogue
from jaxsocial.stats import scipy_stats


def power_table(
    pilot: dict[str, dict[str, list[float]]],
    seeds: int,
    alpha: float,
    discounts: tuple[float, ...] = (1.0, 0.75, 0.5),
    reps: int = 2000,
    rng_seed: int = 0,
) -> dict[str, dict[str, float]]:
    """The power of a family of one-sided tests, Holm-corrected at `alpha`, with `seeds` seeds an arm.

    pilot: per test, its evidence with the effect it looks for oriented positive: `differences` (paired:
    Wilcoxon's signed-rank test on `seeds` differences, each with probability d, the discount, a pilot
    difference, else one of the pilot's magnitudes with a random sign: no effect) or `treatment` and
    `control` per-seed scores (Mann-Whitney U on `seeds` scores an arm; a simulated control seed is a pilot
    control seed drawn with replacement, a treatment seed with probability d a pilot treatment seed, else a
    control one). Either way the effect is diluted to a fraction d of the pilot's while every value stays
    one the pilot had. Returns per discount each test's probability of rejection, and that of rejecting all
    of them and any of them (3 decimals)."""
    rng = np.random.default_rng(rng_seed)
    names = list(pilot)
    evidence = [{k: np.asarray(v, np.float64) for k, v in pilot[n].items()} for n in names]
    table = {}
    for d in discounts:
        rejected = np.zeros((reps, len(names)), bool)
        for r in range(reps):
            p = []
            for found in evidence:
                keep = rng.random(seeds) < d
                if "differences" in found:
                    diff = rng.choice(found["differences"], seeds)
                    diff = np.where(keep, diff, np.abs(diff) * rng.choice([-1.0, 1.0], seeds))
                    stat = scipy_stats.wilcoxon(diff, alternative="greater") if np.any(diff) else None
                    p.append(1.0 if stat is None else stat.pvalue)
                else:
                    t, c = found["treatment"], found["control"]
                    drawn = np.where(keep, rng.choice(t, seeds), rng.choice(c, seeds))
                    p.append(
                        scipy_stats.mannwhitneyu(drawn, rng.choice(c, seeds), alternative="greater").pvalue
                    )
            rejected[r] = stats.holm_rejects(np.array(p), alpha)
        row = {n: round(float(rejected[:, i].mean()), 3) for i, n in enumerate(names)}
        table[f"discount {d:g}"] = row | {
            "all": round(float(rejected.all(axis=1).mean()), 3),
            "any": round(float(rejected.any(axis=1).mean()), 3),
        }
    return table


def stated_power(design: catalogue.Design, amendment: bool = False) -> dict[str, dict[str, float]]:
    """The power table of an evaluation or branch design (or of a branch design's `amendment`), recomputed
    from its pilot as its `power_simulation` says."""
    planned: Any = design.amendment if amendment else design
    sim = planned.power_simulation
    if design.KIND == "evaluation":
        pilot = evaluation_results.pilot_scores(design)
    else:
        pilot = branch_results.pilot_scores(design, planned.tests if amendment else design.primary, sim)
    return power_table(pilot, design.seeds, planned.alpha, tuple(sim["discounts"]), sim["reps"])


def zero_shot_power(
    n_treatment: int, n_control: int, p_above: float, alpha: float, reps: int = 4000, rng_seed: int = 0
) -> float:
    """The power of the one-sided Mann-Whitney U test (treatment greater) at `alpha` with these seeds an arm,
    when a treatment seed's score beats a control seed's with probability `p_above`: scores drawn from two
    unit normal distributions `sqrt(2) * Phi^-1(p_above)` apart, `reps` simulated designs (numpy `rng_seed`);
    rounded to 3 decimals."""
    rng = np.random.default_rng(rng_seed)
    shift = np.sqrt(2) * scipy_stats.norm.ppf(p_above)
    rejected = [
        scipy_stats.mannwhitneyu(
            rng.normal(shift, 1, n_treatment), rng.normal(0, 1, n_control), alternative="greater"
        ).pvalue
        <= alpha
        for _ in range(reps)
    ]
    return round(float(np.mean(rejected)), 3)
