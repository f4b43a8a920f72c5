"""A pre-registered training design's results: the `preregistered` block that `figure` writes into a design
recipe's summary (`preregistered`). The design's analysis makes its tests: 'counts' one exact test of the
arms' learned-seed counts (`counts_block`, with `secondary_tests` where the design states them), 'takeoff'
the log-rank and Mann-Whitney pair (`takeoff_block`), 'zero_shot' one Mann-Whitney test of scores
(`zero_shot_block`). The block's checks: the design's commit (`catalogue.design_commit`) is an ancestor of
every run's recorded commit, its scale and seeds are the design's; and what keeps a seed from counting
(`seed_problems`, of the design's own runs and of those it borrows). `runs` is always the recipe's
`summaries.RecipeRuns`, which imports this module. A 'counts' design's block:

    "preregistered": {"commit": ..., "primary": {"treatment": [...], "control": [...], "learned_threshold": x,
                      "test": ..., "alpha": a}, "result": {"treatment_learned": k, "treatment_seeds": n,
                      "control_learned": k, "control_seeds": n, "p": p}, "checks": {...}, "problems": [...],
                      "deviations": [...], "valid": ...}
"""

from __future__ import annotations

import dataclasses
import json
from typing import Any

from jaxsocial import stats
from jaxsocial.experiments.analyse import kinds, records, rundirs, takeoff
from jaxsocial.experiments.plan import catalogue, paths, prereg, recipes, xla_flags
from jaxsocial.run import config, metrics, rundir
from jaxsocial.run.metrics import final_return


def preregistered(runs, summary: dict[str, Any]) -> dict[str, Any]:
    """The `preregistered` block of the design that `runs`' recipe carries, from the recipe's summary so far
    (`summary`: its kind's part and `time_to_learning`); `valid` where no check fails and no seed has a
    problem."""
    design = prereg.TrainingDesign.read(runs.recipe.design)
    if design.analysis == "takeoff":
        block = takeoff_block(design, summary, runs.commits())
    elif design.analysis == "zero_shot":
        block = zero_shot_block(design, runs)
    else:
        block = counts_block(design, learned_flags(design, runs), runs.commits())
        if design.secondary:
            block["secondary"] = secondary_tests(design, runs)
    checks = block["checks"]
    checks["scale_as_designed"] = runs.scale.name == design.scale
    checks["seeds_as_designed"] &= (runs.seed, runs.seeds) == (design.seed, design.seeds)
    block["problems"] = design_problems(runs, design) + lent_problems(runs)
    block["deviations"] = prereg.deviations(design.name, paths.DEVIATIONS)
    block["valid"] = not block["problems"] and all(v for v in checks.values() if isinstance(v, bool))
    return block


def counts_block(
    design: prereg.TrainingDesign, learned: dict[str, list[bool]], run_commits: dict[str, str | None]
) -> dict[str, Any]:
    """A 'counts' design's `preregistered` block: one exact test of the arms' learned-seed counts.

    learned: each condition's per-seed learned flags (final return above the design's threshold);
    run_commits: each seed directory's recorded commit (None: no record of it).
    """
    commit = catalogue.design_commit(design.name)
    arms = {
        arm: [x for c in getattr(design, arm) for x in learned.get(c, [])] for arm in ("treatment", "control")
    }
    k = {arm: sum(v) for arm, v in arms.items()}
    n = {arm: len(v) for arm, v in arms.items()}
    p = stats.p_value(design.test, k["treatment"], n["treatment"], k["control"], n["control"])
    return {
        "commit": commit,
        "primary": {
            "treatment": list(design.treatment),
            "control": list(design.control),
            "learned_threshold": design.learned_threshold,
            "test": design.test,
            "alpha": design.alpha,
        },
        "result": {
            "treatment_learned": k["treatment"],
            "treatment_seeds": n["treatment"],
            "control_learned": k["control"],
            "control_seeds": n["control"],
            "p": stats.round_p(p, catalogue.P_DECIMALS),
        },
        "checks": catalogue.commit_checks(commit, run_commits) | {"seeds_as_designed": n == design.arm_seeds},
    }


def secondary_tests(design: prereg.TrainingDesign, runs) -> dict[str, dict[str, Any]]:
    """A counts design's secondary tests (`Design.secondary`): per test, the counts of this design's arm and
    of the other design's arm (read from its records under the same runs folder), Boschloo's p-value with
    the stated alternative, Holm-corrected among themselves at the design's alpha."""
    entries = {}
    for name, test in design.secondary.items():
        own = seed_measure(design, runs, getattr(design, test["arm"]), test["measure"])
        other, _, other_arm = test["against"].partition(":")
        theirs = seed_measure(
            design,
            runs.of_design(other),
            getattr(prereg.TrainingDesign.read(other), other_arm),
            test["measure"],
        )
        counts = [sum(own), len(own), sum(theirs), len(theirs)]
        p = stats.boschloo(*counts, test["alternative"]) if own and theirs else None
        entries[name] = {
            "counts": counts,
            "measure": test["measure"],
            "alternative": test["alternative"],
            "p": p,
        }
    return catalogue.holm_family(entries, design.alpha)


def seed_measure(design: prereg.TrainingDesign, runs, conditions: tuple[str, ...], name: str) -> list[bool]:
    """The pooled per-seed flags of `conditions` for a secondary test's measure: 'learned' (as `design`
    counts it) or 'above_experts'."""
    flags = (
        learned_flags(design, runs) if name == "learned" else {c: above_experts(runs, c) for c in conditions}
    )
    return [flag for c in conditions for flag in flags[c]]


def learned_flags(design: prereg.TrainingDesign, runs) -> dict[str, list[bool]]:
    """Per condition of `runs`, each seed's learned flag as the design counts it (`Design.learned_by`): its
    final return above the threshold, or its takeoff (`takeoff.seed_takeoff` at the threshold) within the
    design's iterations."""
    out = {}
    for c, seed_rows in runs.rows.items():
        if design.learned_by == "final_return":
            out[c] = [final_return(rows) > design.learned_threshold for rows in seed_rows]
            continue
        per_iteration = runs.configs[c].num_envs * runs.configs[c].rollout_steps
        lifts = [takeoff.seed_takeoff(rows, per_iteration, design.learned_threshold) for rows in seed_rows]
        out[c] = [lift is not None and lift <= design.iterations for lift in lifts]
    return out


def above_experts(runs, condition: str) -> list[bool]:
    """Per seed of `condition`: whether its learner's final return exceeds the mean final return of the
    scripted experts in its own run."""
    slots, _ = kinds.experts_of(runs.configs[condition])
    out = []
    for rows in runs.rows[condition]:
        experts = [final_return(rows, k) for k in slots if k in metrics.slots(rows[0])]
        out.append(bool(experts) and final_return(rows) > sum(experts) / len(experts))
    return out


def takeoff_block(
    design: prereg.TrainingDesign, summary: dict[str, Any], run_commits: dict[str, str | None]
) -> dict[str, Any]:
    """The `preregistered` block of a 'takeoff' design from a recipe summary (`kinds.summarise_takeoff` and
    its `time_to_learning`): each arm's takeoffs (censored at its seeds' run ends) and scores, the primary
    tests Holm-corrected at the design's alpha, the secondary ones Holm-corrected among themselves.

    Seeds without a score (not evaluated yet) are left out of that score's test; `seeds_as_designed` then
    fails, so an interim block is never valid."""
    arms: dict[str, dict[str, list]] = {}
    for arm in ("treatment", "control"):
        lifts, ends, scores = [], [], {name: [] for name in ("goalcycle4", "solo3", "ct")}
        for c in getattr(design, arm):
            if c not in summary["conditions"]:
                continue
            lifts += summary["time_to_learning"]["conditions"][c]["takeoff_env_steps"]
            ends += summary["conditions"][c]["run_env_steps"]
            for name, values in scores.items():
                values += [v for v in summary["conditions"][c][name]["per_seed"] if v is not None]
        arms[arm] = {"takeoffs": lifts, "ends": ends, **scores}
    t, c = arms["treatment"], arms["control"]
    budget = summary["env_steps_per_run"]  # the design's iterations at its scale

    def learned_by_budget(arm: dict[str, list]) -> int:
        return sum(x is not None and x <= budget for x in arm["takeoffs"])

    primary = {
        "takeoff": stats.logrank((t["takeoffs"], t["ends"]), (c["takeoffs"], c["ends"]))
        | {"n": [len(t["takeoffs"]), len(c["takeoffs"])]},
        "goalcycle4": stats.mann_whitney(t["goalcycle4"], c["goalcycle4"], "greater"),
    }
    k = [learned_by_budget(t), learned_by_budget(c)]
    n = [len(t["takeoffs"]), len(c["takeoffs"])]
    secondary = {
        "solo3": stats.mann_whitney(t["solo3"], c["solo3"], "two-sided"),
        "ct": stats.mann_whitney(t["ct"], c["ct"], "greater"),
        "counts": {"learned": [k[0], n[0], k[1], n[1]], "p": stats.boschloo(k[0], n[0], k[1], n[1])},
    }
    for family in (primary, secondary):
        catalogue.holm_family(family, design.alpha)
    designed = {arm: design.seeds * len(getattr(design, arm)) for arm in ("treatment", "control")}
    scored = all(
        len(arm[name]) == designed[key] for key, arm in arms.items() for name in ("goalcycle4", "solo3", "ct")
    )
    commit = catalogue.design_commit(design.name)
    return {
        "commit": commit,
        "primary": {"treatment": list(design.treatment), "control": list(design.control), "test": design.test,
                    "alpha": design.alpha, "tests": design.tests},
        "result": {"primary": primary, "secondary": secondary, "seeds": {"treatment": n[0], "control": n[1]}},
        "checks": catalogue.commit_checks(commit, run_commits)
        | {"seeds_as_designed": n == [designed["treatment"], designed["control"]] and scored},
    }  # fmt: skip


def zero_shot_block(design: prereg.TrainingDesign, runs) -> dict[str, Any]:
    """A 'zero_shot' design's `preregistered` block: its primary environment's per-seed scores (mean learner
    return per episode), the borrowed arm's from the evaluation design `tests['borrowed_scores']`
    (`kinds.borrowed_evaluation`), the trained arm's from each seed's own evaluation;
    the one-sided Mann-Whitney test; and the checks (both arms evaluated with the design's episodes and
    evaluation seed 0, the design before every run it trains)."""
    ((name, test),) = design.tests["primary"].items()
    scores, protocols = {}, []
    for arm in ("treatment", "control"):
        scores[arm] = []
        for c in getattr(design, arm):
            if c in runs.lenders:
                result = kinds.borrowed_evaluation(runs, c, test["env"])
                scores[arm] += (
                    [] if result is None else [float(v) for v in result["results"][0]["per_seed_mean"]]
                )
                results = [result]
            else:
                results = [kinds.read_eval_file(d, test["env"]) for d in runs.seed_dirs.get(c, [])]
                scores[arm] += [r["results"][0]["mean_return"] for r in results if r is not None]
            protocols += [None if r is None else (r["episodes_per_checkpoint"], r["seed"]) for r in results]
    result = stats.mann_whitney(scores["treatment"], scores["control"], test["alternative"])
    commit = catalogue.design_commit(design.name)
    checks = catalogue.commit_checks(commit, runs.commits())
    checks["seeds_as_designed"] = [len(scores["treatment"]), len(scores["control"])] == [
        design.arm_seeds["treatment"],
        design.arm_seeds["control"],
    ]
    checks["evaluated_as_designed"] = all(p == (design.eval_episodes, 0) for p in protocols)
    return {
        "commit": commit,
        "primary": {name: test, "treatment": list(design.treatment), "control": list(design.control),
                    "test": design.test, "alpha": design.alpha},
        "result": {name: result | {"rejected": result["p"] is not None and result["p"] <= design.alpha},
                   "scores": {arm: stats.summary(v) if v else None for arm, v in scores.items()}},
        "checks": checks,
    }  # fmt: skip


def design_problems(runs, design: prereg.TrainingDesign) -> list[str]:
    """`seed_problems` of the design's seeds as `runs` found them (seeds read where they are)."""
    fields = {f.name for kind in (config.RunConfig, config.ProgramConfig) for f in dataclasses.fields(kind)}
    fields -= {"seed", "seeds", "seed_batching"}

    def settings(cfg) -> dict[str, Any]:
        values = json.loads(json.dumps(config.config_dict(cfg)))  # as config.json holds them
        return {k: values[k] for k in sorted(fields)}

    conditions, expected = {}, {}
    design_seeds = range(design.seed, design.seed + design.seeds)
    for c in design.trained_conditions:
        expected[c] = settings(
            recipes.condition_config(runs.scale, c, design.seed, design.seeds, runs.runs_dir)
        )
        read = runs.dirs_by_seed.get(c, [])  # seeds runs.seed, runs.seed + 1, ...
        dirs = [read[i] if 0 <= (i := s - runs.seed) < len(read) else None for s in design_seeds]
        conditions[c] = [
            None
            if d is None
            else {
                "config": rundir.read_config(d) if (d / rundir.CONFIG_FILE).is_file() else {},
                "rows": len(rundir.read_metrics(d)),
                "finished": rundirs.finished(d, design.iterations),
                "commit": records.run_field(d, "commit"),
                "xla_flags": records.run_field(d, "xla_flags"),
            }
            for d in dirs
        ]
    return seed_problems(design, conditions, expected)


def lent_problems(runs) -> list[str]:
    """What keeps a borrowed seed from counting in the design that trained it (`design_problems` of the
    lender's own runs under the same runs folder), each line naming the lender."""
    out = []
    for name in sorted({lender.name for lender in runs.lenders.values()}):
        lent = runs.of_design(name)
        out += [f"borrowed from {name}: {p}" for p in design_problems(lent, prereg.TrainingDesign.read(name))]
    return out


def seed_problems(
    design: prereg.TrainingDesign,
    conditions: dict[str, list[dict[str, Any] | None]],
    expected: dict[str, dict[str, Any]],
) -> list[str]:
    """What keeps each design seed it trains from counting: missing, unfinished (short of its iterations and
    not ended by the design's early stop), trained for other iterations, another early stop or with other run
    or program settings than `expected` (each condition's config.json values of the design's command), at
    another commit than `design.training_commit`, or without the design's `xla_flags`.

    conditions: per condition the seeds design.seed.. in order, each None (no run holds it) or
    {'config': its config.json, 'rows': metrics rows logged, 'finished': whether its run is over
    (`rundirs.finished`), 'commit' and 'xla_flags': its record's, or None}; a config.json with fields
    renamed since is read under today's names (`config.modern_keys`)."""
    problems = []
    for c in design.trained_conditions:
        seeds = conditions.get(c, [])
        for offset in range(design.seeds):
            s, run = design.seed + offset, seeds[offset] if offset < len(seeds) else None
            if run is None:
                problems.append(f"{c} seed {s}: missing")
                continue
            if run["rows"] < design.iterations and not (design.stop_at_return and run.get("finished")):
                problems.append(f"{c} seed {s}: unfinished ({run['rows']} of {design.iterations} iterations)")
            if run["config"].get("stop_at_return") != design.stop_at_return:
                problems.append(
                    f"{c} seed {s}: trained with stop_at_return {run['config'].get('stop_at_return')}"
                )
            if run["config"].get("iterations") != design.iterations:
                problems.append(f"{c} seed {s}: trained for {run['config'].get('iterations')} iterations")
            saved = config.modern_keys(run["config"])
            differ = sorted(k for k, v in expected[c].items() if saved.get(k) != v)
            if differ:
                problems.append(f"{c} seed {s}: trained with other settings ({', '.join(differ)})")
            if design.training_commit and run["commit"] != design.training_commit:
                problems.append(f"{c} seed {s}: trained at {run['commit']}, not {design.training_commit}")
            if design.xla_flags and not xla_flags.hold(run.get("xla_flags"), design.xla_flags):
                problems.append(
                    f"{c} seed {s}: trained with $XLA_FLAGS {run.get('xla_flags')!r}, not the design's"
                )
    return problems
