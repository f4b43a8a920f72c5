"""The experiments' figures, drawn with matplotlib from the runs and their summaries (which hold every
number): a recipe's figure per kind (`draw_curves`, `draw_mixing`, `draw_ct`, `draw_transfer`,
`draw_takeoff`; `kinds.KINDS` names which), the exploratory sweep and its map (`draw_sweep`, `draw_map`) and
a design's follow-ups (`draw_followup`). A learner's predicted next frames are `predictions.draw`'s, a run's
own curves `jaxsocial.plot`'s; both share `jaxsocial.plot_parts.band` with this module.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from jaxsocial.experiments.analyse import takeoff
from jaxsocial.experiments.plan.conditions import CONDITIONS
from jaxsocial.plot_parts import band, format_steps, steps_axis, zoom_to_means
from jaxsocial.run import metrics
from jaxsocial.run.metrics import LEARNED_RETURN, curve, eval_curve, metric_curve
from jaxsocial.specs import EnvSpec
from jaxsocial.stats import ct_score, fraction_learned


def pyplot():
    """matplotlib.pyplot with the file-only Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_png(fig, path: Path, dpi: int = 110, rect: tuple[float, float, float, float] = (0, 0, 1, 1)) -> None:
    """Lay out a matplotlib figure within `rect` (of the figure; the rest is left to a figure legend), write
    it to `path` (without the software version, so the bytes depend only on what is drawn) and close it."""
    import matplotlib.pyplot as plt

    fig.tight_layout(rect=rect)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi, metadata={"Software": None})
    plt.close(fig)


# ----------------------------------------------------------------------------------------------------------
# Time to takeoff, on one panel
# ----------------------------------------------------------------------------------------------------------


def takeoff_curve(ax, takeoffs: list[int | None], end: float, label: str, color, ls: str = "-") -> None:
    """The survival-style step curve of one condition on `ax`, from 0 to `end` (same units as takeoffs), in
    `color` and line style `ls`."""
    times = sorted(t for t in takeoffs if t is not None)
    x = np.array([0.0, *times, end], np.float64)
    ax.step(
        x,
        fraction_learned(takeoffs, x),
        where="post",
        color=color,
        ls=ls,
        lw=2,
        label=f"{label} (n={len(takeoffs)})",
    )


def kaplan_meier_curve(ax, curve: dict[str, list[float]], end: float, label: str, color) -> None:
    """A `stats.kaplan_meier` curve on `ax` as a step line with its shaded band, carried on to `end`."""
    x = np.array([*curve["time"], end], np.float64)
    learned, low, high = (np.array([*curve[k], curve[k][-1]], np.float64) for k in ("learned", "low", "high"))
    ax.step(x, learned, where="post", color=color, lw=2, label=label)
    ax.fill_between(x, low, high, step="post", color=color, alpha=0.15)


# ----------------------------------------------------------------------------------------------------------
# A recipe's figure, one function per kind
# ----------------------------------------------------------------------------------------------------------

LOSS_PANEL = {"aux_loss": "auxiliary loss (MAE)", "bc_loss": "behaviour-cloning loss (cross-entropy)"}
"""The learner's (slot 0) loss drawn beside the returns: each condition's first of these metrics."""


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
    """Returns through training (and zoomed), the learner's loss, the time to learning, each seed's final
    return with the mean and IQM intervals, and the zero-shot returns where the summary has them."""
    plt = pyplot()
    colors = plt.get_cmap("tab10").colors
    steps_per_iteration = {c: cfg.num_envs * cfg.rollout_steps for c, cfg in runs.configs.items()}
    zero_shot = summary.get("zero_shot", {})
    fig, (returns_ax, zoom_ax, loss_ax, takeoff_ax, final_ax, *zero_shot_axes) = _panels(
        plt, 5 + len(zero_shot)
    )
    used = set()
    for i, (c, seed_rows) in enumerate(runs.rows.items()):
        xs, ys = zip(*(curve(rows) for rows in seed_rows), strict=True)
        xs = [x * steps_per_iteration[c] for x in xs]
        for ax in (returns_ax, zoom_ax):
            band(ax, xs, list(ys), CONDITIONS[c].label, colors[i])
        name = next((n for n in LOSS_PANEL if metrics.logged(seed_rows[0][-1], n, 0)), None)
        if name is not None:
            used.add(name)
            its, losses = zip(*(metric_curve(rows, metrics.key(name, 0)) for rows in seed_rows), strict=True)
            its = [x * steps_per_iteration[c] for x in its]
            band(loss_ax, its, list(losses), CONDITIONS[c].label, colors[i])
    if "experts" in summary and summary["experts"]["mean"] is not None:
        returns_ax.axhline(summary["experts"]["mean"], color="k", ls="--", lw=1, label="experts")
    returns_ax.set(ylabel="learner episode return", title="the learners' returns")
    zoom_to_means(zoom_ax)
    zoom_ax.set(title="the learners' mean returns, zoomed (seeds and bands cut)")
    names = " / ".join(LOSS_PANEL[n] for n in LOSS_PANEL if n in used)
    loss_ax.set(ylabel=names, title="training loss")
    for ax in (returns_ax, zoom_ax, loss_ax):
        steps_axis(ax)
    returns_ax.legend(fontsize=8)
    draw_takeoffs(takeoff_ax, runs, summary, colors)
    draw_finals(final_ax, runs, summary, colors)
    draw_zero_shot(zero_shot_axes, zero_shot, list(runs.rows), colors)
    _save(plt, fig, path, runs)


def draw_finals(ax, runs, summary: dict[str, Any], colors) -> None:
    """The final-return panel: per condition (and the experts, and a condition's own experts) each seed, the
    mean and the IQM (`bars`)."""
    finals = {c: summary["conditions"][c] for c in runs.rows}
    shades = list(colors[: len(runs.rows)])
    if summary.get("experts", {}).get("mean") is not None:
        finals["experts"] = summary["experts"]
        shades.append("0.3")
    for c in runs.rows:  # a condition's own experts (imperfect ones, beside distractors, ...)
        if "experts" in summary["conditions"][c]:
            finals[f"experts:{c}"] = summary["conditions"][c]["experts"]
            shades.append("0.55")
    bars(ax, finals, shades)
    ax.set(title="final return, per seed", ylabel="learner episode return")


def draw_mixing(runs, summary: dict[str, Any], path: Path) -> None:
    """Returns through training and in each evaluation environment, with each seed's switch; the time to
    learning; the final returns (`draw_finals`)."""
    plt = pyplot()
    colors = plt.get_cmap("tab10").colors
    keys = metrics.eval_keys(r for rows in runs.rows.values() for r in rows)
    fig, axes = _panels(plt, 3 + len(keys))
    draw_finals(axes[-1], runs, summary, colors)
    draw_takeoffs(axes[-2], runs, summary, colors)
    axes = axes[:-2]
    for i, (c, seed_rows) in enumerate(runs.rows.items()):
        label = CONDITIONS[c].label
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
    plt = pyplot()
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
    plt = pyplot()
    colors = plt.get_cmap("tab10").colors
    fig, axes = _panels(plt, len(summary["conditions"]) + 1)
    draw_takeoffs(axes[-1], runs, summary, colors)
    draw_zero_shot(axes[:-1], summary["conditions"], list(runs.rows), colors)
    _save(plt, fig, path, runs)


def draw_zero_shot(axes, per_spec: dict[str, dict[str, Any]], conditions: list[str], colors) -> None:
    """One panel per evaluation environment (`kinds.zero_shot_returns`): each condition's and the experts'
    return there (`bars`), a condition in its colour of the figure's other panels (its place in
    `conditions`), the experts grey."""
    for ax, (spec, per_cond) in zip(axes, per_spec.items(), strict=True):
        shades = [colors[conditions.index(n)] if n in conditions else "0.3" for n in per_cond]
        bars(ax, per_cond, shades)
        ax.set(title=env_title(spec), ylabel="mean episode return")


def draw_takeoffs(ax, runs, summary: dict[str, Any], colors) -> None:
    """The time-to-learning panel: per condition, the fraction of seeds past the one-tile plateau against
    env-steps (`summary['time_to_learning']`)."""
    for i, (c, entry) in enumerate(summary["time_to_learning"]["conditions"].items()):
        cfg = runs.configs[c]
        end = max(len(rows) for rows in runs.rows[c]) * cfg.num_envs * cfg.rollout_steps
        steps = entry["takeoff_env_steps"]
        takeoff_curve(ax, steps, end, CONDITIONS[c].label, colors[i])
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
    plt = pyplot()
    colors = plt.get_cmap("tab10").colors
    fig, axes = _panels(plt, 2 + len(TAKEOFF_PANELS))
    km_ax, returns_ax, *score_axes = axes
    for i, (c, seed_rows) in enumerate(runs.rows.items()):
        entry, label = summary["conditions"][c], CONDITIONS[c].label
        per_iteration = runs.configs[c].num_envs * runs.configs[c].rollout_steps
        end = max(entry["run_env_steps"])
        took = summary["time_to_learning"]["conditions"][c]["took_off"]
        km_label = f"{label} ({took} of {len(seed_rows)} took off)"
        kaplan_meier_curve(km_ax, entry["kaplan_meier"], end, km_label, colors[i])
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
        ax.bar(j, s["mean"], color=colors[j], yerr=whisker(s["mean"], s.get("ci95")), capsize=4)
        if s.get("iqm") is not None:
            iqm_whisker = whisker(s["iqm"], s["iqm_ci95"])
            ax.errorbar(j + 0.25, s["iqm"], iqm_whisker, fmt="D", color="k", ms=4, capsize=3)
        marks = s.get("final_returns") or [slot["mean"] for slot in s.get("per_slot", [])]
        ax.scatter([j] * len(marks), marks, color="k", marker="x", zorder=3)
    labels = [bar_label(n) for n in names]
    ax.set_xticks(range(len(names)), labels, rotation=30, ha="right", fontsize=8)
    ax.legend(handles=_bar_key(), fontsize=7)


def bar_label(name: str) -> str:
    """A bar's label: a condition's, 'its scripted experts' (the recipe's), or 'experts: <condition>' for a
    condition's own experts ('experts:<condition>')."""
    if name in CONDITIONS:
        return CONDITIONS[name].label
    _, _, condition = name.partition(":")
    return f"experts: {CONDITIONS[condition].label}" if condition else "its scripted experts"


def whisker(centre: float, interval: list[float] | None) -> list[list[float]] | None:
    """A 95% interval as matplotlib's `yerr` for one bar at `centre` (None: no interval)."""
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
# The exploratory sweep and its map
# ----------------------------------------------------------------------------------------------------------


def draw_sweep(summary: dict[str, Any], path: Path) -> None:
    """The fraction of seeds past the plateau against env-steps and against CPU-minutes, per setting, and
    each seed's learning curve."""
    plt = pyplot()

    fig, axes = plt.subplots(1, 3, figsize=(15, 5.2))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, (name, s) in enumerate(summary["settings"].items()):
        color, ls = colors[i % len(colors)], ("-", "--", ":")[i // len(colors) % 3]  # a style per setting
        for ax, unit, scale in ((axes[0], "env_steps", 1e6), (axes[1], "cpu_minutes", 1.0)):
            lifts = [
                None if x[f"takeoff_{unit}"] is None else x[f"takeoff_{unit}"] / scale for x in s["seeds"]
            ]
            end = max(x[unit] for x in s["seeds"]) / scale
            takeoff_curve(ax, lifts, end, name, color, ls)
        for j, seed in enumerate(s["seeds"]):
            axes[2].plot(
                np.array(seed["curve"]["env_steps"]) / 1e6,
                seed["curve"]["return"],
                color=color,
                ls=ls,
                lw=1,
                label=name if j == 0 else None,
            )
    axes[0].set(xlabel="env-steps (M)", ylabel="fraction of seeds past the plateau", ylim=(-0.02, 1.02))
    axes[1].set(xlabel="CPU-minutes (1 core per seed)", ylim=(-0.02, 1.02))
    axes[2].axhline(LEARNED_RETURN, color="grey", ls=":", lw=1)
    axes[2].set(xlabel="env-steps (M)", ylabel="learner return (per 200k-step window)")
    handles, labels = axes[0].get_legend_handles_labels()  # one legend for the three panels, below them
    fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=8, frameon=False)
    fig.suptitle(f"Exploratory sweep (seeds < 100): takeoff = return > {LEARNED_RETURN:g} in a window")
    save_png(fig, path, rect=(0, 0.12, 1, 1))


def draw_map(summary: dict[str, Any], path: Path) -> None:
    """One panel per map setting: the fraction of its social and solo seeds past the plateau against
    env-steps (a seed stopped early at return 5 stays counted past the plateau)."""
    plt = pyplot()

    cells = summary["cells"]
    cols = min(4, len(cells))
    rows = -(-len(cells) // cols)
    fig, grid = plt.subplots(rows, cols, figsize=(4.4 * cols, 3.6 * rows + 0.8), squeeze=False)
    for ax in list(grid.flat)[len(cells) :]:
        fig.delaxes(ax)
    for ax, (label, cell) in zip(grid.flat, cells.items(), strict=False):
        end = max(max(cell[who]["env_steps"]) for who in ("social", "solo")) / 1e6
        for who, color, ls in (("social", "C0", "-"), ("solo", "C1", "--")):
            lifts = [None if t is None else t / 1e6 for t in cell[who]["takeoff_env_steps"]]
            name = f"{who}: {cell[who]['took_off']} of {cell[who]['n']}"
            takeoff_curve(ax, lifts, end, name, color, ls)
        ax.set(title=label, xlabel="env-steps (M)", ylim=(-0.03, 1.03))
        ax.legend(fontsize=7, loc="upper left")
    grid[0, 0].set_ylabel("fraction of seeds past the plateau")
    fig.suptitle("Where solo learners fail (exploratory, seeds < 100): social (beside experts) against solo, "
                 f"takeoff = return > {summary['learned_return']:g} in a window")  # fmt: skip
    save_png(fig, path)


# ----------------------------------------------------------------------------------------------------------
# A design's follow-ups
# ----------------------------------------------------------------------------------------------------------


def draw_followup(
    summary: dict[str, Any], path: Path, arms: tuple[str, ...], ct_scores: tuple[str, ...]
) -> None:
    """Three panels, one point per learned seed, coloured by its condition: zero-shot returns per
    environment (experts' mean as a bar), CT score and recall, and the branches (social against mixed, one
    line per seed) in each evaluation environment."""
    plt = pyplot()

    seeds = summary["seeds"]
    colours = {c: f"C{i}" for i, c in enumerate(summary.get("conditions", {}))}
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.4))
    specs = list(summary.get("zero_shot", {}))
    for i, spec in enumerate(specs):
        experts = [s["zero_shot"][spec]["experts"] for s in seeds.values() if s["zero_shot"][spec]["experts"]]
        if experts:
            axes[0].bar(i, np.mean(experts), color="0.85", label="experts (mean)" if i == 1 else None)
    for k, (condition, colour) in enumerate(colours.items()):
        group = [s for s in seeds.values() if s["condition"] == condition]
        offset = (k - (len(colours) - 1) / 2) * 0.12  # conditions side by side in each column
        for i, spec in enumerate(specs):
            learner = [s["zero_shot"][spec]["learner"] for s in group]
            label = f"{CONDITIONS[condition].label} ({len(group)})" if i == 0 else None
            axes[0].scatter(
                np.full(len(learner), i + offset), learner, color=colour, s=14, zorder=3, label=label
            )
        for i, score in enumerate(ct_scores):
            values = [s["ct"][score] for s in group]
            axes[1].scatter(np.full(len(values), i + offset), values, color=colour, s=14, zorder=3)
        for j, spec in enumerate(summary.get("mixing", {})):
            for s in group:
                values = [s["branches"][arm][spec] for arm in arms]
                axes[2].plot([2 * j, 2 * j + 1], values, color=colour, marker="o", ms=3, lw=0.8, alpha=0.8)
    axes[0].set_xticks(range(len(specs)), [env_title(s) for s in specs], fontsize=7, rotation=15)
    axes[0].set(ylabel=f"mean return ({summary['eval_episodes']} episodes)", title="zero-shot")
    axes[1].axhline(0, color="grey", lw=0.8)
    axes[1].set_xticks(range(len(ct_scores)), ["CT score", "recall"])
    axes[1].set(title="cultural transmission", xlim=(-0.5, len(ct_scores) - 0.5))
    mixing = list(summary.get("mixing", {}))
    axes[2].set_xticks(range(2 * len(mixing)), [arm for _ in mixing for arm in arms], fontsize=7)
    for j, spec in enumerate(mixing):  # each pair's environment, once, under its two ticks
        axes[2].annotate(
            env_title(spec), (2 * j + 0.5, 0), xycoords=("data", "axes fraction"), xytext=(0, -24),
            textcoords="offset points", ha="center", fontsize=7,
        )  # fmt: skip
    axes[2].set(
        title=f"branches: social vs {summary['mixed_solo_prob']:.0%} solo, "
        f"{summary['branch_iterations']} iterations",
        ylabel="mean return at the branch's end",
    )
    axes[0].legend(fontsize=7)
    fig.suptitle(
        f"Follow-ups of {summary['design']}'s {len(seeds)} learned seeds ({summary['scale']} scale; "
        "exploratory)"
    )
    save_png(fig, path)
