"""The kinds of recipe (`Recipe.kind`) and, for each, how it is summarised, drawn and evaluated after
training: one registry, `KINDS`, read by `runner` (the evaluation) and `summaries` (the summary and figure).

    curves       return through training, final-return CIs, learned-seed tests
    mixing       the same, with the evaluations during training and where each seed switched stage
    predictions  the curves' summary; the figure is a trained learner's predicted next frames
    transfer     zero-shot returns in other environments after training (`Recipe.transfer_envs`)
    ct           the cultural-transmission protocol after training (`jaxsocial.evaluate --protocol ct`)
    takeoff      a time-to-takeoff design: the curves, then the zero-shot returns and the CT protocol

Also here: the time to learning every kind's summary holds (`takeoffs`) and where the evaluations after
training are written (`eval_path`, `ct_path`). The statistics are `stats`'s, the figures `plot_figures`'.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from jaxsocial.experiments.analyse import plot_figures, records, takeoff
from jaxsocial.experiments.plan import paths, recipes
from jaxsocial.experiments.plan.recipes import Recipe, Scale
from jaxsocial.run import jsonio, metrics, rundir, startup
from jaxsocial.run.metrics import LEARNED_RETURN, final_return
from jaxsocial.stats import ct_score, kaplan_meier, learned_seed_tests, separations, summary

CT_SCORES = ("ct", "recall")
"""The cultural-transmission protocol's scores (`jaxsocial.evaluate.cultural_transmission`)."""

# ----------------------------------------------------------------------------------------------------------
# Evaluations after training: what is played and where the results go
# ----------------------------------------------------------------------------------------------------------


def eval_path(seed_dir: Path, spec: str) -> Path:
    """A seed's evaluation in the environment `spec`: `<seed_dir>/eval/<env tag>.json` (`rundir.EVAL_DIR`)."""
    return seed_dir / rundir.EVAL_DIR / f"{paths.env_tag(spec)}.json"


def transfer_specs(recipe: Recipe, scale: Scale) -> list[str]:
    return [str(recipes.goalcycle_spec(name, scale)) for name in recipe.transfer_envs]


def ct_spec(scale: Scale) -> str:
    """The environment of the cultural-transmission evaluation: the scale's 3-goal Goal Cycle."""
    return str(recipes.goalcycle_spec("goalcycle3", scale))


def ct_path(seed_dir: Path, scale: Scale) -> Path:
    """Where a seed's cultural-transmission evaluation is written."""
    return eval_path(seed_dir, "ct-" + ct_spec(scale))


@dataclasses.dataclass(frozen=True)
class Evaluation:
    """An evaluation of every trained seed after training (`runner.run`)."""

    protocol: str
    """`python -m jaxsocial.evaluate --protocol`."""
    specs: Callable[[Recipe, Scale], list[str]]
    """The environment specs it plays (none: nothing to evaluate)."""
    path: Callable[[Path, str, Scale], Path]
    """Where a seed's result in a spec is written."""
    score: Callable[[dict[str, Any]], float]
    """The number `runner.run` prints for a result."""


RETURNS = Evaluation(
    "returns",
    transfer_specs,
    lambda seed_dir, spec, scale: eval_path(seed_dir, spec),
    lambda result: result["results"][0]["mean_return"],
)
"""Each slot's return in the recipe's `transfer_envs` (none for most recipes)."""
CT = Evaluation(
    "ct",
    lambda recipe, scale: [ct_spec(scale)],
    lambda seed_dir, spec, scale: ct_path(seed_dir, scale),
    lambda result: result["ct"]["mean"],
)
"""The cultural-transmission protocol in the scale's 3-goal Goal Cycle."""


def _read_json(path: Path) -> dict[str, Any]:
    if not path.exists():
        raise FileNotFoundError(f"no evaluation {path}: run the recipe first")
    return jsonio.read_json(path)


def _read_eval(seed_dir: Path, spec: str) -> list[dict[str, Any]]:
    return _read_json(eval_path(seed_dir, spec))["results"]


def read_eval_file(seed_dir: Path, spec: str) -> dict[str, Any] | None:
    """A seed's whole evaluation in `spec` (`jaxsocial.evaluate`'s result), None if it has none yet."""
    path = eval_path(seed_dir, spec)
    return jsonio.read_json(path) if path.is_file() else None


def borrowed_evaluation(runs, condition: str, spec: str) -> dict[str, Any] | None:
    """The evaluation in `spec` of a borrowed condition's seeds (`jaxsocial.evaluate`'s result, one score a
    seed in `per_seed_mean`) by the evaluation design whose results the recipe's design names
    (`runs.borrowed_scores`, `<folder>/<env tag>-<condition>.json`); None where it names none or has no such
    file."""
    if runs.borrowed_scores is None:
        return None
    path = runs.borrowed_scores / f"{paths.env_tag(spec)}-{condition}.json"
    return jsonio.read_json(path) if path.is_file() else None


# ----------------------------------------------------------------------------------------------------------
# Shared measures
# ----------------------------------------------------------------------------------------------------------


def takeoffs(runs) -> dict[str, dict[str, Any]]:
    """Each condition's time to learning (`takeoff.seed_takeoff`): every seed's takeoff iteration, env-step
    and CPU-minutes (training seconds to the takeoff times the cores its record says it had; None where it
    has no record of them), how many seeds took off by the end, and every seed's CPU-minutes of training in
    all (compilation excluded)."""
    out = {}
    for c, seed_rows in runs.rows.items():
        cfg = runs.configs[c]
        per_iteration = cfg.num_envs * cfg.rollout_steps
        iterations = [takeoff.seed_takeoff(rows, per_iteration) for rows in seed_rows]
        cores = [records.run_field(d, "cores") for d in runs.seed_dirs[c]]
        minutes = [
            None if i is None or k is None else round(metrics.cpu_minutes(rows, per_iteration, k, i), 2)
            for i, k, rows in zip(iterations, cores, seed_rows, strict=True)
        ]
        run_minutes = [
            None if k is None else round(metrics.cpu_minutes(rows, per_iteration, k), 2)
            for k, rows in zip(cores, seed_rows, strict=True)
        ]
        out[c] = {
            "takeoff_iterations": iterations,
            "takeoff_env_steps": [None if i is None else i * per_iteration for i in iterations],
            "takeoff_cpu_minutes": minutes,
            "cores": cores,
            "took_off": sum(i is not None for i in iterations),
            "seeds": len(iterations),
            "cpu_minutes": run_minutes,
        }
    return out


# ----------------------------------------------------------------------------------------------------------
# Summaries: each returns the kind's part of the summary, its 'conditions' last
# ----------------------------------------------------------------------------------------------------------


def experts_of(cfg) -> tuple[tuple[int, ...], Any]:
    """A run's scripted-expert slots, and what decides their returns: their specs and every stage's
    environment (`startup.setup`)."""
    setup = startup.setup(cfg, load_frozen=False)
    experts = setup.pop.experts
    return experts, (tuple(setup.pop.slots[k] for k in experts), setup.stage_envs)


def summarise_curves(runs, mixing: bool = False) -> dict[str, Any]:
    """Per condition the final return's stats and learned seeds (`mixing`: also each seed's stage switch
    and the final evaluations during training); the experts' final return; CI separations and learned-seed
    tests; where the recipe names `transfer_envs`, the zero-shot returns there (`zero_shot_returns`)."""
    out: dict[str, Any] = {}
    conditions: dict[str, Any] = {}
    for c, seed_rows in runs.rows.items():
        finals = [final_return(rows) for rows in seed_rows]
        conditions[c] = summary(finals)
        conditions[c]["seeds_above_one_tile"] = sum(v > LEARNED_RETURN for v in finals)
        if mixing:
            conditions[c]["switch_iterations"] = [metrics.switch_iteration(rows) for rows in seed_rows]
            for key in metrics.eval_keys(seed_rows):
                conditions[c][key] = summary([metrics.final_eval(rows, key) for rows in seed_rows])
    # Scripted experts do not react to the learner, and all conditions of a seed share the environment's
    # random numbers, so the experts' returns are the same in every condition with the same experts in the
    # same environments: the first social condition's are the recipe's `experts`; a condition with other
    # experts or environments (imperfect experts, distractors, dropout, solo episodes) has its own.
    seen = set()
    for c, seed_rows in runs.rows.items():
        slots, setting = experts_of(runs.configs[c])
        reported = metrics.slots(seed_rows[0][0])
        slots = [k for k in slots if k in reported]  # those its metrics report
        if not slots or setting in seen:
            continue
        finals = summary([float(np.mean([final_return(rows, k) for k in slots])) for rows in seed_rows])
        (conditions[c] if seen else out)["experts"] = finals
        seen.add(setting)
    out["separated_ci95"] = separations(conditions)
    out["learned_seed_tests"] = learned_seed_tests(conditions, runs.recipe.hypotheses)
    if runs.recipe.transfer_envs:
        out["zero_shot"] = zero_shot_returns(runs)
    out["conditions"] = conditions
    return out


def summarise_mixing(runs) -> dict[str, Any]:
    return summarise_curves(runs, mixing=True)


def summarise_ct(runs) -> dict[str, Any]:
    """The training return, and the CT protocol's scores after training, per condition."""
    conditions: dict[str, Any] = {}
    for c, seed_rows in runs.rows.items():
        conditions[c] = summary([final_return(rows) for rows in seed_rows])
        results = [_read_json(ct_path(d, runs.scale)) for d in runs.seed_dirs[c]]
        for score in CT_SCORES:
            conditions[c][score] = summary([r[score]["mean"] for r in results])
        conditions[c]["expert_return"] = summary([r["expert_return"]["episode"] for r in results])
    separated = {
        score: separations({c: ct_score(v, score) for c, v in conditions.items()})
        for score in ("final", *CT_SCORES)
    }
    return {"separated_ci95": separated, "conditions": conditions}


def _rounded(values: list[float]) -> list[float]:
    return [round(v, 4) for v in values]


def summarise_transfer(runs) -> dict[str, Any]:
    """Learner and expert returns in each evaluation environment, and the training returns."""
    training = {c: summary([final_return(rows) for rows in r]) for c, r in runs.rows.items()}
    return {"training": training, "conditions": zero_shot_returns(runs)}


def zero_shot_returns(runs) -> dict[str, Any]:
    """Per environment spec of the recipe's `transfer_envs`: each condition's learner return after training
    (stats over its seeds of each seed's mean episode return) and, as 'experts', the environment's scripted
    experts' (per slot, over episodes; random distractors are not experts). A condition the design borrows
    (`runs.lenders`) has the scores of the evaluation design it names (`borrowed_evaluation`), or is left
    out."""
    conditions: dict[str, Any] = {}
    evaluated = {c: dirs for c, dirs in runs.seed_dirs.items() if c not in runs.lenders}
    for spec in transfer_specs(runs.recipe, runs.scale):
        per_cond: dict[str, Any] = {
            c: summary([_read_eval(d, spec)[0]["mean_return"] for d in dirs]) for c, dirs in evaluated.items()
        }
        for c in runs.lenders:
            lent = borrowed_evaluation(runs, c, spec)
            if lent is not None:
                per_cond[c] = summary(lent["results"][0]["per_seed_mean"])
        # The environment's own experts, from one evaluation (every evaluation plays the same episodes).
        first = _read_eval(next(iter(evaluated.values()))[0], spec)
        experts = [s for s in first if s["kind"] == "expert"]
        per_cond["experts"] = {
            "per_slot": [{"mean": round(s["mean_return"], 4), "ci95": _rounded(s["ci95"])} for s in experts],
            "mean": round(float(np.mean([s["mean_return"] for s in experts])), 4) if experts else None,
            "ci_over": "episodes, each slot its own",
        }
        conditions[spec] = per_cond
    return conditions


ZERO_SHOT = {"goalcycle4": "goalcycle4", "solo3": "goalcycle3-solo"}
"""A takeoff design's zero-shot evaluations: its name of each -> the environment (the scale's grid)."""


def zero_shot_scores(runs, seed_dir: Path) -> dict[str, float | None]:
    """A seed's zero-shot scores (`ZERO_SHOT`: its mean learner return per episode) and its CT score; None
    for an evaluation it does not have yet (e.g. a seed still training)."""
    out: dict[str, float | None] = {}
    for name, env in ZERO_SHOT.items():
        path = eval_path(seed_dir, str(recipes.goalcycle_spec(env, runs.scale)))
        out[name] = RETURNS.score(jsonio.read_json(path)) if path.exists() else None
    path = ct_path(seed_dir, runs.scale)
    out["ct"] = CT.score(jsonio.read_json(path)) if path.exists() else None
    return out


def summarise_takeoff(runs) -> dict[str, Any]:
    """The curves' summary (`summarise_curves`) with, per condition, every seed's zero-shot scores and CT
    score (with their stats over the seeds that have them) and the Kaplan-Meier curve of its takeoffs in
    env-steps, each seed censored at the end of its run (`stats.kaplan_meier`)."""
    out = summarise_curves(runs)
    lifts = takeoffs(runs)
    for c, seed_rows in runs.rows.items():
        per_iteration = runs.configs[c].num_envs * runs.configs[c].rollout_steps
        ends = [len(rows) * per_iteration for rows in seed_rows]
        scores = [zero_shot_scores(runs, d) for d in runs.seed_dirs[c]]
        entry = out["conditions"][c]
        for name in (*ZERO_SHOT, "ct"):
            values = [s[name] for s in scores]
            entry[name] = summary([v for v in values if v is not None]) | {"per_seed": values}
        entry["kaplan_meier"] = kaplan_meier(lifts[c]["takeoff_env_steps"], ends)
        entry["run_env_steps"] = ends
    return out


def draw_predictions(runs, summary: dict[str, Any], path: Path) -> None:
    """A trained learner's predicted next frames in the scale's 3-goal Goal Cycle (`predictions.draw`)."""
    from jaxsocial.experiments.analyse import predictions  # JAX: imported to draw, not to summarise or refuse

    predictions.draw(runs, path, ct_spec(runs.scale))


# ----------------------------------------------------------------------------------------------------------
# The registry
# ----------------------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Kind:
    """How a kind of recipe is summarised, drawn and evaluated after training."""

    summarise: Callable[[Any], dict[str, Any]]
    """`summarise(runs)`: the kind's part of the summary (`summaries.summarize`), 'conditions' last."""
    draw: Callable[[Any, dict[str, Any], Path], None]
    """`draw(runs, summary, path)`: the recipe's figure as a PNG."""
    evaluations: tuple[Evaluation, ...]
    """What `runner.run` evaluates after training, in order."""


KINDS: dict[str, Kind] = {
    "curves": Kind(summarise_curves, plot_figures.draw_curves, (RETURNS,)),
    "mixing": Kind(summarise_mixing, plot_figures.draw_mixing, (RETURNS,)),
    "predictions": Kind(summarise_curves, draw_predictions, (RETURNS,)),
    "transfer": Kind(summarise_transfer, plot_figures.draw_transfer, (RETURNS,)),
    "ct": Kind(summarise_ct, plot_figures.draw_ct, (CT,)),
    "takeoff": Kind(summarise_takeoff, plot_figures.draw_takeoff, (RETURNS, CT)),
}


def kind_of(recipe: Recipe) -> Kind:
    """The `Kind` of a recipe (ValueError for an unknown kind)."""
    if recipe.kind not in KINDS:
        raise ValueError(f"recipe {recipe.name}: unknown kind {recipe.kind!r}; choose one of {sorted(KINDS)}")
    return KINDS[recipe.kind]


def evaluation_outputs(recipe: Recipe, scale: Scale, seed_dir: Path) -> list[tuple[Evaluation, str, Path]]:
    """What the recipe's kind evaluates of a finished seed: (evaluation, environment spec, its output file)
    for each, in order."""
    return [
        (evaluation, spec, evaluation.path(seed_dir, spec, scale))
        for evaluation in kind_of(recipe).evaluations
        for spec in evaluation.specs(recipe, scale)
    ]
