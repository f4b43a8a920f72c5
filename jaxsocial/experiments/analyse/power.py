"""A design's power, simulated: one table for every family of per-seed score tests (an evaluation design's,
a branch design's and its amendment's), the power of a 'zero_shot' training design's test, and a design's
stated power recomputed from its pilot as its file says (`pilot_scores`, `stated_power`). A 'takeoff'
design's log-rank power is `takeoff_power`'s."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from jaxsocial import stats
from jaxsocial.experiments.analyse import evaluation_results, takeoff_power
from jaxsocial.experiments.plan import catalogue, paths
from jaxsocial.experiments.plan.branch_design import START, BranchDesign
from jaxsocial.experiments.plan.catalogue import Test
from jaxsocial.experiments.plan.evaluation_design import EvaluationDesign
from jaxsocial.run import jsonio
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
        drawn: list[list[tuple[np.ndarray, ...]]] = [[] for _ in names]  # per test, per design: its samples
        for _ in range(reps):
            for found, samples in zip(evidence, drawn, strict=True):
                keep = rng.random(seeds) < d
                if "differences" in found:
                    diff = rng.choice(found["differences"], seeds)
                    samples.append((np.where(keep, diff, np.abs(diff) * rng.choice([-1.0, 1.0], seeds)),))
                else:
                    t, c = found["treatment"], found["control"]
                    samples.append(
                        (np.where(keep, rng.choice(t, seeds), rng.choice(c, seeds)), rng.choice(c, seeds))
                    )
        p = np.column_stack([_one_sided_p(np.array(samples)) for samples in drawn])
        rejected = np.array([stats.holm_rejects(row, alpha) for row in p])
        row = {n: round(float(rejected[:, i].mean()), 3) for i, n in enumerate(names)}
        table[f"discount {d:g}"] = row | {
            "all": round(float(rejected.all(axis=1).mean()), 3),
            "any": round(float(rejected.any(axis=1).mean()), 3),
        }
    return table


def _one_sided_p(samples: np.ndarray) -> np.ndarray:
    """float64[reps] the one-sided p-value of each simulated design's test, from its samples float64[reps, 1,
    seeds] (paired differences: Wilcoxon's signed-rank test, 1.0 where every difference is 0) or float64[reps,
    2, seeds] (treatment and control: Mann-Whitney U); the same values as one call a design."""
    if samples.shape[1] == 2:
        return scipy_stats.mannwhitneyu(samples[:, 0], samples[:, 1], alternative="greater", axis=1).pvalue
    diff = samples[:, 0]
    p = np.ones(len(diff))
    some = np.any(diff, axis=1)
    if some.any():
        p[some] = scipy_stats.wilcoxon(diff[some], alternative="greater", axis=1).pvalue
    return p


def pilot_scores(design: catalogue.Design, amendment: bool = False) -> dict[str, dict[str, list[float]]]:
    """Per test of an evaluation or branch design (or of a branch design's `amendment`), the pilot's
    evidence `power_table` takes, read as its `power_simulation` says."""
    if design.KIND == "evaluation":
        return _evaluation_pilot(design)
    planned: Any = design.amendment if amendment else design
    return _branch_pilot(design, planned.tests if amendment else design.primary, planned.power_simulation)


def stated_power(design: catalogue.Design, amendment: bool = False) -> dict[str, dict[str, float]]:
    """The power table of an evaluation or branch design (or of a branch design's `amendment`), recomputed
    from its pilot as its `power_simulation` says."""
    planned: Any = design.amendment if amendment else design
    sim = planned.power_simulation
    pilot = pilot_scores(design, amendment)
    return power_table(pilot, design.seeds, planned.alpha, tuple(sim["discounts"]), sim["reps"])


def _evaluation_pilot(design: EvaluationDesign) -> dict[str, dict[str, list[float]]]:
    """Per primary test, the pilot's `treatment` and `control` per-seed scores in its environment, each arm
    weighted to the material's known fraction of seeds past the one-tile plateau.

    The pilot (`power_simulation['pilot']`, a folder of `<env tag>-<condition>.json` evaluations of other
    records) splits each arm into its seeds that took off (`takeoff_power.seed_lift`) and those that did not;
    a simulated seed of the arm is one that took off with the probability `material_took_off[arm]` (what
    the material's own design found before any of this design's evaluations), then a uniform draw among
    the pilot's seeds of that kind: of its own arm, or, where `power_simulation['plateau_from_both_arms']`
    holds, for a seed that did not take off, of both arms (a pilot arm in which every seed took off has no
    plateau seeds of its own). Returned as one pool per arm whose uniform draws have those weights."""
    sim = design.power_simulation
    arms = (("treatment", sim["pilot_treatment"]), ("control", sim["pilot_control"]))
    out = {}
    for name, test in design.primary.items():
        split = {}
        for arm, condition in arms:
            result = jsonio.read_json(Path(sim["pilot"]) / f"{paths.env_tag(test.env)}-{condition}.json")
            took_off = np.array(
                [takeoff_power.seed_lift(Path(c))["takeoff"] is not None for c in result["checkpoints"]]
            )
            values = np.array(evaluation_results.scores(result))
            split[arm] = (values[took_off], values[~took_off])
        plateau_of_both = np.concatenate([split[arm][1] for arm, _ in arms])
        pools = []
        for arm, _ in arms:
            lifted, plateau = split[arm]
            if sim.get("plateau_from_both_arms", False):
                plateau = plateau_of_both
            rate = sim["material_took_off"][arm]
            pools.append(weighted_pool([(lifted, rate), (plateau, 1.0 - rate)]))
        out[name] = {"treatment": pools[0], "control": pools[1]}
    return out


def weighted_pool(groups: list[tuple[np.ndarray, float]]) -> list[float]:
    """One list whose uniform draws pick group g with probability weight_g, then a uniform member of it:
    every member of g repeated in proportion to weight_g / len(g) (weights are rounded to 1/1000; a group
    with weight 0 or no members is left out)."""
    kept = [(np.asarray(v), round(w * 1000)) for v, w in groups if len(v) and round(w * 1000)]
    size = int(np.prod([len(v) for v, _ in kept]))  # each group's share, as whole repeats
    return [float(x) for v, w in kept for x in np.repeat(v, w * size // len(v))]


def _branch_pilot(
    design: BranchDesign, tests: dict[str, Test], sim: dict[str, Any]
) -> dict[str, dict[str, list[float]]]:
    """Per test of `tests`, the pilot's evidence, each oriented so that the effect the test looks for is
    positive: for a paired test the per-seed differences of the exploratory follow-up's branches of its
    social seeds (`pilot_branches`), against the other branch or against where the branch started (the
    follow-up's zero-shot score of its source); otherwise the treatment's per-seed scores there and the
    control's from a committed summary (`pilot_control`: where the arm's source records ended, before any
    further training)."""
    branches = jsonio.read_json(Path(sim["pilot_branches"]))
    sources = [s for s in branches["seeds"].values() if s["condition"].startswith(sim["pilot_sources"])]
    out = {}
    for name, test in tests.items():
        if test.alternative == "two-sided":
            raise ValueError(
                f"design {design.name}, test {name}: power is simulated for one-sided tests only"
            )
        sign = -1.0 if test.alternative == "less" else 1.0  # scores negated: a fall is a rise
        treatment = [sign * s["branches"][test.treatment][test.env] for s in sources]
        if test.control == START:
            control = [sign * s["zero_shot"][test.env]["learner"] for s in sources]
        elif design.paired(test):
            control = [sign * s["branches"][test.control][test.env] for s in sources]
        else:
            where = sim["pilot_control"]
            summary = jsonio.read_json(Path(where["summary"]))
            per_seed = summary["conditions"][where["condition"]][where["measure"]]["per_seed"]
            out[name] = {"treatment": treatment, "control": [sign * c for c in per_seed]}
            continue
        out[name] = {"differences": [t - c for t, c in zip(treatment, control, strict=True)]}
    return out


def zero_shot_power(
    n_treatment: int, n_control: int, p_above: float, alpha: float, reps: int = 4000, rng_seed: int = 0
) -> float:
    """The power of the one-sided Mann-Whitney U test (treatment greater) at `alpha` with these seeds an arm,
    when a treatment seed's score beats a control seed's with probability `p_above`: scores drawn from two
    unit normal distributions `sqrt(2) * Phi^-1(p_above)` apart, `reps` simulated designs (numpy `rng_seed`);
    rounded to 3 decimals."""
    shift = np.sqrt(2) * scipy_stats.norm.ppf(p_above)
    # Each design's draws in one row: its treatment's, then its control's (numpy's normal(loc, 1) is loc plus
    # a standard normal, drawn in this order design after design).
    z = np.random.default_rng(rng_seed).standard_normal((reps, n_treatment + n_control))
    treatment, control = shift + z[:, :n_treatment], z[:, n_treatment:]
    p = scipy_stats.mannwhitneyu(treatment, control, alternative="greater", axis=1).pvalue
    return round(float(np.mean(p <= alpha)), 3)
