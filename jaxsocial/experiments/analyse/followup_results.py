"""A design's follow-ups summarised from their records: per learned seed its zero-shot returns, CT scores
and branches' evaluations, and each measure's mean over seeds (`summarise`, `measures`); the plan is
`plan.followup_plan`'s."""

from __future__ import annotations

from typing import Any

import numpy as np

from jaxsocial import stats
from jaxsocial.experiments.analyse import kinds
from jaxsocial.experiments.plan import recipes
from jaxsocial.experiments.plan.followup_plan import (
    ARMS,
    MIXED_SOLO_PROB,
    Plan,
    Source,
    branch_specs,
    zero_shot_specs,
)
from jaxsocial.run import jsonio, metrics, rundir


def _experts_return(result: dict[str, Any]) -> float | None:
    others = [r["mean_return"] for r in result["results"][1:] if r.get("episodes")]
    return float(np.mean(others)) if others else None


def summarise(plan: Plan, records_dir: str) -> dict[str, Any]:
    """Each learned seed's follow-ups (zero-shot returns, CT, the branches' evaluations) and, per measure,
    the mean over seeds (`measures`): over every learned seed, and over each condition's apart
    (`conditions`), since learners trained alone and beside the experts differ."""
    scale, base = plan.scale, plan.root(records_dir)
    seeds: dict[str, Any] = {}
    for eval_dir in sorted(base.glob(f"*/{rundir.EVAL_DIR}")):
        name, seed_dir = eval_dir.parent.name, eval_dir.parent
        results = {spec: jsonio.read_json(kinds.eval_path(seed_dir, spec)) for spec in zero_shot_specs(scale)}
        zero_shot = {
            spec: {"learner": kinds.RETURNS.score(r), "experts": _experts_return(r)}
            for spec, r in results.items()
        }
        ct = jsonio.read_json(kinds.ct_path(seed_dir, scale))
        branches = {}
        for arm in ARMS:
            rows = rundir.read_metrics(base / f"{name}-{arm}")
            branches[arm] = {
                spec: metrics.final_eval(rows, metrics.eval_key(spec)) for spec in branch_specs(scale)
            }
        seeds[name] = {
            "condition": Source.condition_of(name),
            "source": next(iter(results.values()))["checkpoints"][0],
            "zero_shot": zero_shot,
            "ct": {score: ct[score]["mean"] for score in kinds.CT_SCORES},
            "branches": branches,
        }
    learned = list(seeds.values())
    summary: dict[str, Any] = {
        "design": plan.design.name,
        "scale": scale.name,
        "exploratory": "follow-ups of the seeds that learned, chosen after the design's runs: no "
        "confirmatory test",
        "eval_episodes": plan.episodes,
        "branch_iterations": plan.branch_iterations,
        "mixed_solo_prob": MIXED_SOLO_PROB,
        "seeds": seeds,
    }
    if learned:
        summary.update(measures(learned, scale))
        summary["conditions"] = {}
        for condition in plan.recipe.conditions:
            group = [s for s in learned if s["condition"] == condition]
            if group:
                summary["conditions"][condition] = {"seeds": len(group), **measures(group, scale)}
    return summary


def measures(learned: list[dict[str, Any]], scale: recipes.Scale) -> dict[str, Any]:
    """Over some learned seeds (`summarise`'s entries): each zero-shot return's and CT score's mean and
    interval (`stats.summary`), and each branch evaluation's, with the paired mixed-minus-social
    difference."""
    return {
        "zero_shot": {
            spec: stats.summary([s["zero_shot"][spec]["learner"] for s in learned])
            for spec in zero_shot_specs(scale)
        },
        "ct": {score: stats.summary([s["ct"][score] for s in learned]) for score in kinds.CT_SCORES},
        "mixing": {
            spec: {
                **{arm: stats.summary([s["branches"][arm][spec] for s in learned]) for arm in ARMS},
                "mixed_minus_social": stats.paired_difference(
                    [s["branches"]["social"][spec] for s in learned],
                    [s["branches"]["mixed"][spec] for s in learned],
                ),
            }
            for spec in branch_specs(scale)
        },
    }
