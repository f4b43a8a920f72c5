"""The power of a time-to-takeoff design (a `TrainingDesign` with analysis 'takeoff'), by simulation from the
committed laptop seeds of the same learner.

Evidence: every seed of the earlier pre-registered laptop designs (`EVIDENCE_DESIGNS`) in the design's two
conditions: its takeoff (`takeoff.seed_takeoff`, or censored at its run's end) and its per-seed mean return
zero-shot beside the experts in 4-goal Goal Cycle, from one committed evaluation per condition
(`evidence_eval_path`; each seed's final policy, `EVIDENCE_EPISODES` episodes), made by

    python -m jaxsocial.evaluate --ckpt RECORD... --env goalcycle4 --env-args width=7,height=7 \\
        --episodes 128 --out benchmarks/results/science/experts-evidence/goalcycle4-<condition>.json

Model, per arm: the fraction of seeds past the plateau against env-steps is the Kaplan-Meier estimate while
at least `MIN_AT_RISK` of the arm's seeds are still observed, then grows with the arm's constant hazard
(takeoffs after `HAZARD_FROM` env-steps per env-step at risk after it). A simulated seed of the treatment
arm takes off by `control + discount * (treatment - control)`: the effect shrunk toward no effect, since
fresh seeds learned about half as often as the rates read off the runs that chose a budget (`h1_sooner`).
Its 4-goal score is drawn from its arm's seeds that did not learn if it did not take off by the budget;
otherwise from its arm's learned seeds of the longest evidence run not longer than the budget (scores rise
with training beside the experts, so shorter runs understate them), the treatment arm's score again shrunk
by `discount` toward a control learned seed's. The tests are the design's (one-sided log-rank on the
takeoffs, censored at the budget; one-sided Mann-Whitney U on the scores), Holm-corrected as a pair.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from jaxsocial import stats
from jaxsocial.experiments.analyse import takeoff
from jaxsocial.experiments.plan import paths
from jaxsocial.run import jsonio, metrics, rundir
from jaxsocial.stats import scipy_stats

EVIDENCE_DESIGNS = ("h1_laptop", "h1_early", "h1_sooner")
EVIDENCE_EPISODES = 128
MIN_AT_RISK = 3
HAZARD_FROM = 3_000_000
DISCOUNTS = (1.0, 0.75, 0.5)


def evidence_eval_path(condition: str) -> Path:
    return paths.EVIDENCE / f"goalcycle4-{condition}.json"


def seed_lift(seed_dir: Path) -> dict[str, Any]:
    """A trained seed's directory (config and metrics): its seed, takeoff and run end (env-steps; takeoff
    None if it never took off)."""
    config, rows = rundir.read_config(seed_dir), rundir.read_metrics(seed_dir)
    per_iteration = metrics.steps_per_iteration(config)
    lift = takeoff.seed_takeoff(rows, per_iteration)
    return {
        "seed": config["seed"],
        "takeoff": None if lift is None else lift * per_iteration,
        "end": len(rows) * per_iteration,
    }


def lifts_and_ends(seeds: list[dict[str, Any]]) -> tuple[list[float | None], list[float]]:
    """The takeoffs (None: never) and run ends of `seeds` (`seed_lift`'s), as `stats.logrank` and
    `stats.kaplan_meier` take them."""
    return [s["takeoff"] for s in seeds], [s["end"] for s in seeds]


def seed_takeoffs(
    condition: str, designs: tuple[str, ...], records_root: Path
) -> list[tuple[Path, dict[str, Any]]]:
    """Every recorded laptop seed of `condition` in `designs`: its record's '<design folder>/<seed folder>',
    and its design with `seed_lift`."""
    return [
        (Path(*seed_dir.parts[-2:]), {"design": design} | seed_lift(seed_dir))
        for design in designs
        for seed_dir in sorted((records_root / "laptop" / f"prereg-{design}").glob(f"{condition}-s*"))
    ]


def evidence(condition: str, records_root: Path) -> list[dict[str, Any]]:
    """Every evidence seed of `condition` (`EVIDENCE_DESIGNS`): `seed_takeoffs`, with its 4-goal score.
    Refuses an evidence file evaluated with other than `EVIDENCE_EPISODES` episodes a policy."""
    path = evidence_eval_path(condition)
    scores = jsonio.read_json(path)
    if scores["episodes_per_checkpoint"] != EVIDENCE_EPISODES:
        raise ValueError(
            f"{path}: {scores['episodes_per_checkpoint']} episodes a policy; the evidence is "
            f"{EVIDENCE_EPISODES} (the command in this module's docstring)"
        )
    by_dir = {  # keyed by '<design folder>/<seed folder>', wherever the records root is
        Path(*Path(ck).parts[-2:]): score
        for ck, score in zip(scores["checkpoints"], scores["results"][0]["per_seed_mean"], strict=True)
    }
    seeds = seed_takeoffs(condition, EVIDENCE_DESIGNS, records_root)
    return [seed | {"goalcycle4": by_dir[record]} for record, seed in seeds]


def incidence(seeds: list[dict[str, Any]], grid: np.ndarray) -> np.ndarray:
    """float64[G] the modelled fraction of an arm's seeds past the plateau at each env-step of `grid`."""
    lifts, ends = lifts_and_ends(seeds)
    observed = [t if t is not None else e for t, e in zip(lifts, ends, strict=True)]
    horizon = max(g for g in grid if sum(o >= g for o in observed) >= MIN_AT_RISK)
    fit = scipy_stats.ecdf(stats.censored(lifts, ends))
    events = sum(t is not None and t > HAZARD_FROM for t in lifts)
    exposure = sum(max(0.0, o - HAZARD_FROM) for o in observed)
    hazard = events / exposure
    known = 1.0 - fit.sf.evaluate(grid)
    at_horizon = 1.0 - float(fit.sf.evaluate(horizon))
    beyond = 1.0 - (1.0 - at_horizon) * np.exp(-hazard * (grid - horizon))
    return np.where(grid <= horizon, known, beyond)


def _draw_takeoffs(curve: np.ndarray, grid: np.ndarray, n: int, budget: int, rng) -> list[float | None]:
    index = np.searchsorted(curve, rng.random(n), side="left")
    return [None if i >= len(grid) or grid[i] > budget else float(grid[i]) for i in index]


def score_pools(arm: list[dict[str, Any]], budget: int) -> dict[str, list[float]]:
    """An arm's 4-goal scores: 'learned' (its learned seeds of the longest evidence run up to the budget)
    and 'not' (every seed that did not take off)."""
    ends = sorted({s["end"] for s in arm if s["takeoff"] is not None and s["end"] <= budget})
    if not ends:
        raise ValueError(f"no evidence run ends by the budget ({budget} env-steps)")
    learned = [s["goalcycle4"] for s in arm if s["takeoff"] is not None and s["end"] == ends[-1]]
    return {"learned": learned, "not": [s["goalcycle4"] for s in arm if s["takeoff"] is None]}


def simulate(
    treatment: list[dict[str, Any]],
    control: list[dict[str, Any]],
    seeds: int,
    budget: int,
    steps_per_window: int,
    discount: float,
    alpha: float,
    reps: int,
    rng_seed: int = 0,
) -> dict[str, float]:
    """The probability that each primary test rejects under Holm at `alpha` (and both do), over `reps`
    simulated designs of `seeds` seeds an arm."""
    rng = np.random.default_rng(rng_seed)
    grid = np.arange(steps_per_window, budget + steps_per_window, steps_per_window, dtype=np.float64)
    grid = np.concatenate([grid, np.arange(grid[-1] + steps_per_window, 4 * budget, steps_per_window)])
    low, high = incidence(control, grid), incidence(treatment, grid)
    curves = {"treatment": low + discount * (high - low), "control": low}
    pools = {"treatment": score_pools(treatment, budget), "control": score_pools(control, budget)}
    rejected = np.zeros((reps, 2), bool)
    for r in range(reps):
        lifts = {arm: _draw_takeoffs(c, grid, seeds, budget, rng) for arm, c in curves.items()}
        scores = {}
        for arm, arm_lifts in lifts.items():
            scores[arm] = [
                rng.choice(pools[arm]["not"]) if t is None else rng.choice(pools[arm]["learned"])
                for t in arm_lifts
            ]
        learned = [i for i, t in enumerate(lifts["treatment"]) if t is not None]
        for i in learned:  # the treatment's learned scores, shrunk toward a control learned seed's
            toward = rng.choice(pools["control"]["learned"])
            scores["treatment"][i] = toward + discount * (scores["treatment"][i] - toward)
        ends = [budget] * seeds
        p = np.array(
            [
                stats.logrank((lifts["treatment"], ends), (lifts["control"], ends))["p"],
                stats.mann_whitney(scores["treatment"], scores["control"], "greater")["p"],
            ]
        )
        rejected[r] = stats.holm_rejects(p, alpha)
    return {
        "takeoff": float(rejected[:, 0].mean()),
        "goalcycle4": float(rejected[:, 1].mean()),
        "both": float(rejected.all(axis=1).mean()),
    }


def takeoff_power_table(
    design, records_root: Path, steps_per_iteration: int, reps: int, seeds: tuple[int, ...] | None = None
) -> dict[str, Any]:
    """The design's power under each of `DISCOUNTS`, at its seeds an arm and at each of `seeds`."""
    (treatment,), (control,) = design.treatment, design.control
    arms = {"treatment": evidence(treatment, records_root), "control": evidence(control, records_root)}
    budget = design.iterations * steps_per_iteration
    window = takeoff.window_iterations(steps_per_iteration) * steps_per_iteration
    table = {}
    for n in seeds or (design.seeds,):
        for d in DISCOUNTS:
            table[f"{n} seeds, discount {d:g}"] = simulate(
                arms["treatment"], arms["control"], n, budget, window, d, design.alpha, reps
            )
    return {"evidence_seeds": {arm: len(v) for arm, v in arms.items()}, "reps": reps, "power": table}


POOLED_AT = (4_000_000, 6_000_000, 8_000_000, 11_993_088, 20_000_000)
"""Env-steps at which the pooled summaries read the fraction past the plateau (11,993,088: `experts`'
budget)."""
POOLED = {
    paths.POOLED_SUMMARY.name: EVIDENCE_DESIGNS,
    paths.POOLED_ALL_SUMMARY.name: (*EVIDENCE_DESIGNS, "experts"),
}
"""Pooled summary (its file name in `paths.SCIENCE`) -> the laptop designs it pools: the evidence that chose
`experts`, and every fresh seed of the laptop PPO + rec learner (the rate the README quotes)."""


def kaplan_meier_at(curve: dict[str, list[float]], steps: int) -> dict[str, Any]:
    """A `stats.kaplan_meier` curve read at `steps` env-steps: the fraction past the plateau and its 95% band,
    rounded as the summaries print them."""
    index = int(np.searchsorted(curve["time"], steps, side="right")) - 1
    return {
        "kaplan_meier": round(curve["learned"][index], 4),
        "ci95": [round(curve["low"][index], 4), round(curve["high"][index], 4)],
    }


def pooled_summary(records_root: Path, designs: tuple[str, ...]) -> dict[str, Any]:
    """Every fresh laptop seed of `designs`, per condition (social and solo PPO + rec): its takeoff and run
    end; at each of `POOLED_AT`, how many of the seeds whose run reached it had taken off, how many were still
    on the plateau (at risk), and the Kaplan-Meier fraction past the plateau there (every seed, censored at
    its run's end); and the log-rank test of the two conditions (post hoc: it pools designs)."""
    conditions = {}
    for condition in ("social_rec", "solo_rec"):
        seeds = [seed for _, seed in seed_takeoffs(condition, designs, records_root)]
        lifts, ends = lifts_and_ends(seeds)
        curve = stats.kaplan_meier(lifts, ends)
        at = {}
        for steps in POOLED_AT:
            ran = [s for s in seeds if s["end"] >= steps]  # the seeds whose run reached `steps`
            at[str(steps)] = {
                "took_off": sum(s["takeoff"] is not None and s["takeoff"] <= steps for s in ran),
                "seeds_observed": len(ran),
                "at_risk": sum((s["takeoff"] or s["end"]) >= steps for s in seeds if s["end"] >= steps),
                **kaplan_meier_at(curve, steps),
            }
        conditions[condition] = {
            "seeds": len(seeds),
            "took_off_within_budget": sum(t is not None for t in lifts),
            "at": at,
            "seed_list": seeds,
        }
    lift = {c: lifts_and_ends(v["seed_list"]) for c, v in conditions.items()}
    return {
        "designs": list(designs),
        "window_env_steps": takeoff.WINDOW_STEPS,
        "command": "python -m jaxsocial.experiments pooled",
        "conditions": conditions,
        "logrank_social_sooner_post_hoc": stats.logrank(lift["social_rec"], lift["solo_rec"]),
    }


def main(argv: list[str] | None = None) -> None:
    """Write the `POOLED` summaries from the committed records (no arguments)."""
    prog = "python -m jaxsocial.experiments pooled"
    paths.parse_command(lambda: argparse.ArgumentParser(prog=prog, description=main.__doc__), argv)
    for name, designs in POOLED.items():
        path = paths.SCIENCE / name
        summary = pooled_summary(paths.RECORDS, designs)
        jsonio.write_json(path, summary, indent=1)
        print(f"{', '.join(designs)}:")
        for c, v in summary["conditions"].items():
            by = ", ".join(
                f"{a['took_off']} of {a['seeds_observed']} by {int(s) / 1e6:g}M (KM {a['kaplan_meier']:.2f})"
                for s, a in v["at"].items()
                if a["seeds_observed"]
            )
            print(f"  {c}: {v['took_off_within_budget']} of {v['seeds']} took off within their budgets; {by}")
        print(f"wrote {path}")
