"""The kinds of recipe (`Recipe.kind`) and, for each, how it is summarised, drawn and evaluated after
training: one registry, `KINDS`, read by `runner` (the evaluation) and `figures` (the summary and figure).

    curves       return through training, final-return CIs, learned-seed tests
    mixing       the same, with the evaluations during training and where each seed switched stage
    predictions  the curves' summary; the figure is a trained learner's predicted next frames
    transfer     zero-shot returns in other environments after training (`Recipe.transfer_envs`)
    ct           the cultural-transmission protocol after training (`jaxsocial.evaluate --protocol ct`)
    takeoff      a time-to-takeoff design: the curves, then the zero-shot returns and the CT protocol

Also here: the measures the kinds share (learned seeds, CI separations, time to learning) and where the
evaluations after training are written (`eval_path`, `ct_path`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from jaxsocial.axes import format_steps, steps_axis
from jaxsocial.curves import band
from jaxsocial.experiments import predictions, recipes, records, takeoff
from jaxsocial.experiments.recipes import Recipe, Scale
from jaxsocial.experiments.stats import kaplan_meier, learned_seed_tests, separations
from jaxsocial.run import logs, metrics
from jaxsocial.run.metrics import LEARNED_RETURN, curve, eval_curve, final_return, metric_curve, stats
from jaxsocial.specs import EnvSpec

LOSS_PANEL = {"aux_loss": "auxiliary loss (MAE)", "bc_loss": "behaviour-cloning loss (cross-entropy)"}
"""The learner's (slot 0) loss drawn beside the returns: each condition's first of these metrics."""

CT_SCORES = ("ct", "recall")
"""The cultural-transmission protocol's scores (`jaxsocial.evaluate.cultural_transmission`)."""

# ----------------------------------------------------------------------------------------------------------
# Evaluations after training: what is played and where the results go
# ----------------------------------------------------------------------------------------------------------

EVAL_DIR = logs.EVAL_DIR
"""Sub-directory of a seed's run directory holding its post-training evaluations, one JSON per env spec."""


def eval_path(seed_dir: Path, spec: str) -> Path:
    return seed_dir / EVAL_DIR / f"{spec.replace(':', '_').replace(',', '_')}.json"


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
    return logs.read_json(path)


def _read_eval(seed_dir: Path, spec: str) -> list[dict[str, Any]]:
    return _read_json(eval_path(seed_dir, spec))["results"]


# ----------------------------------------------------------------------------------------------------------
# Shared measures
# ----------------------------------------------------------------------------------------------------------


def ct_score(condition: dict[str, Any], score: str) -> dict[str, Any]:
    """A ct recipe condition's stats of `score`: 'final' (the training return), 'ct' or 'recall'."""
    return condition if score == "final" else condition[score]


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


def summarise_curves(runs, mixing: bool = False) -> dict[str, Any]:
    """Per condition the final return's stats and learned seeds (`mixing`: also each seed's stage switch
    and the final evaluations during training); the experts' final return; CI separations and learned-seed
    tests."""
    out: dict[str, Any] = {}
    conditions: dict[str, Any] = {}
    for c, seed_rows in runs.rows.items():
        finals = [final_return(rows) for rows in seed_rows]
        conditions[c] = stats(finals)
        conditions[c]["seeds_above_one_tile"] = sum(v > LEARNED_RETURN for v in finals)
        if mixing:
            conditions[c]["switch_iterations"] = [metrics.switch_iteration(rows) for rows in seed_rows]
            for key in metrics.eval_keys(seed_rows):
                conditions[c][key] = stats([metrics.final_eval(rows, key) for rows in seed_rows])
    # Scripted experts do not react to the learner, and all conditions of a seed share the environment's
    # random numbers, so the experts' returns are the same in every social condition: take the first's.
    social = [c for c in runs.rows if recipes.CONDITIONS[c].env == "goalcycle3"]
    if social:
        seed_rows = runs.rows[social[0]]
        slots = metrics.slots(seed_rows[0][0])[1:]  # the learner is in slot 0
        out["experts"] = stats([float(np.mean([final_return(rows, k) for k in slots])) for rows in seed_rows])
    out["separated_ci95"] = separations(conditions)
    out["learned_seed_tests"] = learned_seed_tests(conditions, runs.recipe.hypotheses)
    out["conditions"] = conditions
    return out


def summarise_mixing(runs) -> dict[str, Any]:
    return summarise_curves(runs, mixing=True)


def summarise_ct(runs) -> dict[str, Any]:
    """The training return, and the CT protocol's scores after training, per condition."""
    conditions: dict[str, Any] = {}
    for c, seed_rows in runs.rows.items():
        conditions[c] = stats([final_return(rows) for rows in seed_rows])
        results = [_read_json(ct_path(d, runs.scale)) for d in runs.seed_dirs[c]]
        for score in CT_SCORES:
            conditions[c][score] = stats([r[score]["mean"] for r in results])
        conditions[c]["expert_return"] = stats([r["expert_return"]["episode"] for r in results])
    separated = {
        score: separations({c: ct_score(v, score) for c, v in conditions.items()})
        for score in ("final", *CT_SCORES)
    }
    return {"separated_ci95": separated, "conditions": conditions}


def _rounded(values: list[float]) -> list[float]:
    return [round(v, 4) for v in values]


def summarise_transfer(runs) -> dict[str, Any]:
    """Learner and expert returns in each evaluation environment, and the training returns."""
    training = {c: stats([final_return(rows) for rows in r]) for c, r in runs.rows.items()}
    conditions: dict[str, Any] = {}
    for spec in transfer_specs(runs.recipe, runs.scale):
        per_cond: dict[str, Any] = {
            c: stats([_read_eval(d, spec)[0]["mean_return"] for d in dirs])
            for c, dirs in runs.seed_dirs.items()
        }
        # The environment's own experts, from one evaluation (every evaluation plays the same episodes).
        first = _read_eval(next(iter(runs.seed_dirs.values()))[0], spec)
        experts = [s for s in first if s["kind"] == "expert"]
        per_cond["experts"] = {
            "per_slot": [{"mean": round(s["mean_return"], 4), "ci95": _rounded(s["ci95"])} for s in experts],
            "mean": round(float(np.mean([s["mean_return"] for s in experts])), 4),
            "ci_over": "episodes, each slot its own",
        }
        conditions[spec] = per_cond
    return {"training": training, "conditions": conditions}


ZERO_SHOT = {"goalcycle4": "goalcycle4", "solo3": "goalcycle3-solo"}
"""A takeoff design's zero-shot evaluations: its name of each -> the environment (the scale's grid)."""


def zero_shot_scores(runs, seed_dir: Path) -> dict[str, float | None]:
    """A seed's zero-shot scores (`ZERO_SHOT`: its mean learner return per episode) and its CT score; None
    for an evaluation it does not have yet (e.g. a seed still training)."""
    out: dict[str, float | None] = {}
    for name, env in ZERO_SHOT.items():
        path = eval_path(seed_dir, str(recipes.goalcycle_spec(env, runs.scale)))
        out[name] = RETURNS.score(logs.read_json(path)) if path.exists() else None
    path = ct_path(seed_dir, runs.scale)
    out["ct"] = CT.score(logs.read_json(path)) if path.exists() else None
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
            entry[name] = stats([v for v in values if v is not None]) | {"per_seed": values}
        entry["kaplan_meier"] = kaplan_meier(lifts[c]["takeoff_env_steps"], ends)
        entry["run_env_steps"] = ends
    return out


# ----------------------------------------------------------------------------------------------------------
# Figures: each draws a recipe's PNG at `path`
# ----------------------------------------------------------------------------------------------------------


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


ENV_NAMES = {"goalcycle3": "3-goal Goal Cycle", "goalcycle4": "4-goal Goal Cycle", "fourrooms": "Four Rooms",
             "maze": "Maze"}  # fmt: skip
VARIANTS = {"solo": "alone", "distractors": "with distractors"}


def env_title(spec: str) -> str:
    """A reader's name for an environment spec: 'goalcycle4:width=9,height=9' -> '4-goal Goal Cycle, 9x9',
    'goalcycle3-solo:penalty=0' -> '3-goal Goal Cycle alone, penalty 0'."""
    env = EnvSpec.parse(spec)
    base, _, variant = env.name.partition("-")
    fields = {k: str(v) for k, v in env.args}
    title = " ".join(t for t in (ENV_NAMES.get(base, base), VARIANTS.get(variant, variant)) if t)
    size = [f"{fields.pop('width')}x{fields.pop('height')}"] if {"width", "height"} <= set(fields) else []
    return ", ".join([title, *size, *(f"{k.replace('_', ' ')} {v}" for k, v in fields.items())])


def scale_title(runs) -> str:
    """What a figure was trained at: the scale, env-steps per seed and seeds (and the scale's caveat)."""
    steps = max(cfg.iterations * cfg.num_envs * cfg.rollout_steps for cfg in runs.configs.values())
    seeds = f"seed {runs.seed}" if runs.seeds == 1 else f"seeds {runs.seed}-{runs.seed + runs.seeds - 1}"
    caveat = f" ({runs.scale.caveat})" if runs.scale.caveat else ""
    return f"{runs.scale.name} scale{caveat}: {format_steps(steps)} env-steps per seed, {seeds}"


PANEL_COLUMNS = 3
"""Panels per row of a recipe's figure: wider figures wrap into rows, so the text reads at 100%."""


def _panels(plt, n: int, width: float = 5.6, height: float = 4.4):
    """A figure of `n` panels in rows of at most `PANEL_COLUMNS`: (fig, the n axes in reading order); the
    grid's unused cells are removed."""
    cols = min(n, PANEL_COLUMNS)
    rows = -(-n // cols)
    fig, grid = plt.subplots(rows, cols, figsize=(width * cols, height * rows + 0.8), squeeze=False)
    axes = list(grid.flat)
    for ax in axes[n:]:
        fig.delaxes(ax)
    return fig, axes[:n]


def _save(plt, fig, path: Path, runs) -> None:
    fig.suptitle(f"{runs.recipe.title}\n{scale_title(runs)}", fontsize=11)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def draw_curves(runs, summary: dict[str, Any], path: Path) -> None:
    """Returns through training (and zoomed), the learner's loss, the time to learning, and each seed's final
    return with the mean and IQM intervals."""
    plt = _pyplot()
    colors = plt.get_cmap("tab10").colors
    steps_per_iteration = {c: cfg.num_envs * cfg.rollout_steps for c, cfg in runs.configs.items()}
    fig, (returns_ax, zoom_ax, loss_ax, takeoff_ax, final_ax) = _panels(plt, 5)
    used = set()
    for i, (c, seed_rows) in enumerate(runs.rows.items()):
        xs, ys = zip(*(curve(rows) for rows in seed_rows), strict=True)
        xs = [x * steps_per_iteration[c] for x in xs]
        for ax in (returns_ax, zoom_ax):
            band(ax, xs, list(ys), recipes.CONDITIONS[c].label, colors[i])
        name = next((n for n in LOSS_PANEL if metrics.logged(seed_rows[0][-1], n, 0)), None)
        if name is not None:
            used.add(name)
            its, losses = zip(*(metric_curve(rows, metrics.key(name, 0)) for rows in seed_rows), strict=True)
            its = [x * steps_per_iteration[c] for x in its]
            band(loss_ax, its, list(losses), recipes.CONDITIONS[c].label, colors[i])
    if "experts" in summary and summary["experts"]["mean"] is not None:
        returns_ax.axhline(summary["experts"]["mean"], color="k", ls="--", lw=1, label="experts")
    returns_ax.set(ylabel="learner episode return", title="the learners' returns")
    zoom_ax.set(title="the learners' returns, zoomed")
    names = " / ".join(LOSS_PANEL[n] for n in LOSS_PANEL if n in used)
    loss_ax.set(ylabel=names, title="training loss")
    for ax in (returns_ax, zoom_ax, loss_ax):
        steps_axis(ax)
    returns_ax.legend(fontsize=8)
    draw_takeoffs(takeoff_ax, runs, summary, colors)
    draw_finals(final_ax, runs, summary, colors)
    _save(plt, fig, path, runs)


def draw_finals(ax, runs, summary: dict[str, Any], colors) -> None:
    """The final-return panel: per condition (and the experts) each seed, the mean and the IQM (`bars`)."""
    finals = {c: summary["conditions"][c] for c in runs.rows}
    if summary.get("experts", {}).get("mean") is not None:
        finals["experts"] = summary["experts"]
    bars(ax, finals, [*colors[: len(runs.rows)], "0.3"])
    ax.set(title="final return, per seed", ylabel="learner episode return")


def draw_mixing(runs, summary: dict[str, Any], path: Path) -> None:
    """Returns through training and in each evaluation environment, with each seed's switch; the time to
    learning; the final returns (`draw_finals`)."""
    plt = _pyplot()
    colors = plt.get_cmap("tab10").colors
    keys = metrics.eval_keys(r for rows in runs.rows.values() for r in rows)
    fig, axes = _panels(plt, 3 + len(keys))
    draw_finals(axes[-1], runs, summary, colors)
    draw_takeoffs(axes[-2], runs, summary, colors)
    axes = axes[:-2]
    for i, (c, seed_rows) in enumerate(runs.rows.items()):
        label = recipes.CONDITIONS[c].label
        xs, ys = zip(*(curve(rows) for rows in seed_rows), strict=True)
        band(axes[0], list(xs), list(ys), label, colors[i])
        for ax, key in zip(axes[1:], keys, strict=True):
            xs, ys = zip(*(eval_curve(rows, key) for rows in seed_rows), strict=True)
            band(ax, list(xs), list(ys), label, colors[i])
    for i, seed_rows in enumerate(runs.rows.values()):  # where each seed switched to solo episodes
        for switch in {metrics.switch_iteration(rows) for rows in seed_rows} - {None}:
            for ax in axes:
                ax.axvline(switch, color=colors[i], ls=":")
    axes[0].set(title="training environment (with experts)", xlabel="iteration", ylabel="learner return")
    for ax, key in zip(axes[1:], keys, strict=True):
        ax.set(title=env_title(metrics.eval_spec(key)), xlabel="iteration")
    axes[0].legend(fontsize=8)
    _save(plt, fig, path, runs)


def draw_ct(runs, summary: dict[str, Any], path: Path) -> None:
    """Bars of the final training return, the CT score and recall per condition."""
    plt = _pyplot()
    colors = plt.get_cmap("tab10").colors
    panels = {
        "final": "final training return",
        "ct": "CT score: (R_with - R_solo) / R_experts",
        "recall": "recall: 2nd half after the experts left",
    }
    fig, axes = _panels(plt, len(panels))
    for ax, (score, title) in zip(axes, panels.items(), strict=True):
        per_cond = {c: ct_score(v, score) for c, v in summary["conditions"].items()}
        bars(ax, per_cond, colors)
        ax.axhline(0, color="k", lw=0.5)
        ax.set(title=title)
    _save(plt, fig, path, runs)


def draw_transfer(runs, summary: dict[str, Any], path: Path) -> None:
    """Bars of the returns in each evaluation environment, and the time to learning."""
    plt = _pyplot()
    colors = plt.get_cmap("tab10").colors
    specs = list(summary["conditions"])
    fig, axes = _panels(plt, len(specs) + 1)
    draw_takeoffs(axes[-1], runs, summary, colors)
    for ax, spec in zip(axes[:-1], specs, strict=True):
        bars(ax, summary["conditions"][spec], colors)
        ax.set(title=env_title(spec), ylabel="mean episode return")
    _save(plt, fig, path, runs)


def draw_predictions(runs, summary: dict[str, Any], path: Path) -> None:
    """A trained learner's predicted next frames in the scale's 3-goal Goal Cycle (`predictions.draw`)."""
    predictions.draw(runs, path, ct_spec(runs.scale))


def draw_takeoffs(ax, runs, summary: dict[str, Any], colors) -> None:
    """The time-to-learning panel: per condition, the fraction of seeds past the one-tile plateau against
    env-steps (`summary['time_to_learning']`)."""
    for i, (c, entry) in enumerate(summary["time_to_learning"]["conditions"].items()):
        cfg = runs.configs[c]
        end = max(len(rows) for rows in runs.rows[c]) * cfg.num_envs * cfg.rollout_steps
        steps = entry["takeoff_env_steps"]
        takeoff.draw(ax, steps, end, recipes.CONDITIONS[c].label, colors[i])
    steps_axis(ax)
    ax.set(
        ylabel="fraction of seeds",
        ylim=(-0.03, 1.03),
        title=f"seeds past the one-tile plateau (return > {LEARNED_RETURN:g})",
    )
    ax.legend(fontsize=7)


TAKEOFF_PANELS = {
    "goalcycle4": "zero-shot beside experts, 4-goal Goal Cycle",
    "solo3": "zero-shot alone, 3-goal Goal Cycle",
    "ct": "CT score: (R_with - R_solo) / R_experts",
}


def draw_takeoff(runs, summary: dict[str, Any], path: Path) -> None:
    """The Kaplan-Meier curves of the takeoffs with their 95% bands, the learners' returns through training,
    and per condition each seed's zero-shot scores and CT score (`TAKEOFF_PANELS`)."""
    plt = _pyplot()
    colors = plt.get_cmap("tab10").colors
    fig, axes = _panels(plt, 2 + len(TAKEOFF_PANELS))
    km_ax, returns_ax, *score_axes = axes
    for i, (c, seed_rows) in enumerate(runs.rows.items()):
        entry, label = summary["conditions"][c], recipes.CONDITIONS[c].label
        per_iteration = runs.configs[c].num_envs * runs.configs[c].rollout_steps
        end = max(entry["run_env_steps"])
        took = summary["time_to_learning"]["conditions"][c]["took_off"]
        km_label = f"{label} ({took} of {len(seed_rows)} took off)"
        takeoff.draw_kaplan_meier(km_ax, entry["kaplan_meier"], end, km_label, colors[i])
        xs, ys = zip(*(takeoff.window_curve(rows, per_iteration) for rows in seed_rows), strict=True)
        band(returns_ax, [x * per_iteration for x in xs], list(ys), label, colors[i])
    km_ax.set(
        ylabel="fraction of seeds past the plateau",
        ylim=(-0.03, 1.03),
        title=f"time to takeoff (Kaplan-Meier, 95% band): return > {LEARNED_RETURN:g} in a window",
    )
    returns_ax.axhline(LEARNED_RETURN, color="grey", ls=":", lw=1)
    returns_ax.set(ylabel="learner return per window", title="the learners' returns")
    for ax in (km_ax, returns_ax):
        steps_axis(ax)
    km_ax.legend(fontsize=7, loc="upper left")
    for ax, (name, title) in zip(score_axes, TAKEOFF_PANELS.items(), strict=True):
        bars(ax, {c: summary["conditions"][c][name] for c in runs.rows}, colors)
        ax.axhline(0, color="k", lw=0.5)
        ax.set(title=title, ylabel="per seed" if name == "ct" else "mean episode return, per seed")
    _save(plt, fig, path, runs)


def bars(ax, per_cond: dict[str, dict[str, Any]], colors) -> None:
    """One bar per condition: the mean with its t interval (where there is one), the IQM (a diamond) with its
    bootstrap interval, a cross per seed (per slot for the experts); labelled below, explained in a legend."""
    names = list(per_cond)
    for j, name in enumerate(names):
        s = per_cond[name]
        if s["mean"] is None:
            continue
        ax.bar(j, s["mean"], color=colors[j], yerr=_whisker(s["mean"], s.get("ci95")), capsize=4)
        if s.get("iqm") is not None:
            iqm_whisker = _whisker(s["iqm"], s["iqm_ci95"])
            ax.errorbar(j + 0.25, s["iqm"], iqm_whisker, fmt="D", color="k", ms=4, capsize=3)
        marks = s.get("final_returns") or [slot["mean"] for slot in s.get("per_slot", [])]
        ax.scatter([j] * len(marks), marks, color="k", marker="x", zorder=3)
    labels = [
        recipes.CONDITIONS[n].label if n in recipes.CONDITIONS else "its scripted experts" for n in names
    ]
    ax.set_xticks(range(len(names)), labels, rotation=30, ha="right", fontsize=8)
    ax.legend(handles=_bar_key(), fontsize=7)


def _whisker(centre: float, interval: list[float] | None) -> list[list[float]] | None:
    return None if interval is None else [[centre - interval[0]], [interval[1] - centre]]


def _bar_key() -> list:
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    return [
        Patch(color="0.6", label="mean, t 95% CI"),
        Line2D([], [], color="k", marker="D", ms=4, label="IQM, bootstrap 95% CI"),
        Line2D([], [], color="k", marker="x", ls="", label="one seed (or expert slot)"),
    ]


# ----------------------------------------------------------------------------------------------------------
# The registry
# ----------------------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Kind:
    """How a kind of recipe is summarised, drawn and evaluated after training."""

    summarise: Callable[[Any], dict[str, Any]]
    """`summarise(runs)`: the kind's part of the summary (`figures.summarize`), 'conditions' last."""
    draw: Callable[[Any, dict[str, Any], Path], None]
    """`draw(runs, summary, path)`: the recipe's figure as a PNG."""
    evaluations: tuple[Evaluation, ...]
    """What `runner.run` evaluates after training, in order."""


KINDS: dict[str, Kind] = {
    "curves": Kind(summarise_curves, draw_curves, (RETURNS,)),
    "mixing": Kind(summarise_mixing, draw_mixing, (RETURNS,)),
    "predictions": Kind(summarise_curves, draw_predictions, (RETURNS,)),
    "transfer": Kind(summarise_transfer, draw_transfer, (RETURNS,)),
    "ct": Kind(summarise_ct, draw_ct, (CT,)),
    "takeoff": Kind(summarise_takeoff, draw_takeoff, (RETURNS, CT)),
}


def kind_of(recipe: Recipe) -> Kind:
    """The `Kind` of a recipe (ValueError for an unknown kind)."""
    if recipe.kind not in KINDS:
        raise ValueError(f"recipe {recipe.name}: unknown kind {recipe.kind!r}; choose one of {sorted(KINDS)}")
    return KINDS[recipe.kind]
