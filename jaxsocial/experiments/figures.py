"""Summaries (JSON) and figures (PNG) of a recipe, read from its run directories or their records.

Every number comes from the runs' metrics and post-training evaluations; nothing is hard-coded. A
condition's *final return* is, per seed, the learner's episode-weighted mean return over the last 10% of
training iterations (the issue's measure); the 95% confidence interval is Student t over seeds. A seed has
*learned* if its final return exceeds `LEARNED_RETURN`; learned counts are compared with one-sided exact
tests (`counts`), and each seed's takeoff (`takeoff`) gives the time-to-learning curve. Every summary says
how it was made (`provenance`: the command that re-creates it, and each seed's recorded training command,
commit, device and jax version; seeds without a record are listed) and, for a recipe with a design, what was
pre-registered (`prereg`).
"""

from __future__ import annotations

import itertools
import shlex
from pathlib import Path
from typing import Any

import numpy as np

from jaxsocial import logs
from jaxsocial.axes import steps_axis
from jaxsocial.evaluate import mean_ci95
from jaxsocial.experiments import counts, prereg, recipes, records, runner, takeoff
from jaxsocial.experiments.recipes import Recipe, Scale

FINAL_FRACTION = 0.1
"""The share of training iterations, at the end, over which the final return is averaged."""

LOSS_PANEL = {"aux_loss/0": "auxiliary loss (MAE)", "bc_loss/0": "behaviour-cloning loss (cross-entropy)"}
"""The loss drawn beside the returns: each condition's first of these metrics."""

LEARNED_RETURN = 2.0
"""A seed whose final return exceeds this has learned more than the cautious individual policy, which collects
the free first tile (+1) and then avoids tiles; the summary counts such seeds per condition."""

CURVE_POINTS = 50
"""Points per learning curve (iterations are averaged in blocks)."""


def slot_returns(rows: list[dict[str, Any]], slot: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-iteration float64[I] summed returns and episode counts of one slot."""
    returns = np.array([r[f"return/{slot}"] * r[f"episodes/{slot}"] for r in rows], np.float64)
    episodes = np.array([r[f"episodes/{slot}"] for r in rows], np.float64)
    return returns, episodes


def final_return(rows: list[dict[str, Any]], slot: int = 0) -> float:
    """Episode-weighted mean return of `slot` over the last `FINAL_FRACTION` of the iterations (nan if no
    episode ended there)."""
    n = max(1, round(len(rows) * FINAL_FRACTION))
    returns, episodes = slot_returns(rows[-n:], slot)
    return float(returns.sum() / episodes.sum()) if episodes.sum() else float("nan")


def curve(
    rows: list[dict[str, Any]], slot: int = 0, points: int = CURVE_POINTS
) -> tuple[np.ndarray, np.ndarray]:
    """(iterations, episode-weighted mean return) in `points` blocks of consecutive iterations."""
    returns, episodes = slot_returns(rows, slot)
    blocks = np.array_split(np.arange(len(rows)), min(points, len(rows)))
    x = np.array([rows[b[-1]]["iteration"] for b in blocks], np.float64)
    y = np.array([returns[b].sum() / max(episodes[b].sum(), 1.0) for b in blocks])
    return x, y


def metric_curve(rows: list[dict[str, Any]], key: str) -> tuple[np.ndarray, np.ndarray]:
    """(iterations, value) float64[I] of every row, e.g. key 'kl/0'; nan where a row has no (finite) value."""
    iterations = np.array([r["iteration"] for r in rows], np.float64)
    return iterations, np.array([np.nan if r.get(key) is None else r[key] for r in rows], np.float64)


def eval_curve(rows: list[dict[str, Any]], key: str) -> tuple[np.ndarray, np.ndarray]:
    """(iterations, value) of the rows that logged the evaluation `key` (e.g. 'eval/goalcycle4')."""
    logged = [r for r in rows if r.get(key) is not None]
    return np.array([r["iteration"] for r in logged], np.float64), np.array([r[key] for r in logged])


def stats(values: list[float]) -> dict[str, Any]:
    """{'final_returns': per-seed values, 'mean', 'ci95': [lo, hi]} (Student t over seeds)."""
    finite = np.array([v for v in values if np.isfinite(v)], np.float64)
    if not len(finite):
        return {"final_returns": values, "mean": None, "ci95": None}
    mean, lo, hi = mean_ci95(finite)
    return {
        "final_returns": [round(v, 4) for v in values],
        "mean": round(mean, 4),
        "ci95": [round(lo, 4), round(hi, 4)],
    }


CT_SCORES = ("ct", "recall")
"""The cultural-transmission protocol's scores (`jaxsocial.evaluate.cultural_transmission`)."""


def ct_score(condition: dict[str, Any], score: str) -> dict[str, Any]:
    """A ct recipe condition's stats of `score`: 'final' (the training return), 'ct' or 'recall'."""
    return condition if score == "final" else condition[score]


def separations(conditions: dict[str, dict[str, Any]]) -> dict[str, bool]:
    """For each ordered pair of conditions by mean, 'a > b': whether a's 95% CI lies entirely above b's."""
    out = {}
    for a, b in itertools.permutations(conditions, 2):
        sa, sb = conditions[a], conditions[b]
        if sa.get("ci95") and sb.get("ci95") and sa["mean"] > sb["mean"]:
            out[f"{a} > {b}"] = sa["ci95"][0] > sb["ci95"][1]
    return out


def learned_seed_tests(
    conditions: dict[str, dict[str, Any]], test: str = "fisher-greater"
) -> dict[str, float]:
    """For each ordered pair with more learned seeds (`seeds_above_one_tile`) in a than in b, 'a > b': the
    one-sided p-value of that difference by `test` (`counts.TESTS`)."""
    out = {}
    for a, b in itertools.permutations(conditions, 2):
        (la, na), (lb, nb) = ((conditions[c]["seeds_above_one_tile"], _seeds(conditions[c])) for c in (a, b))
        if la > lb:
            out[f"{a} > {b}"] = round(counts.p_value(test, la, na, lb, nb), 4)
    return out


def _seeds(condition: dict[str, Any]) -> int:
    return sum(np.isfinite(v) for v in condition["final_returns"] if v is not None)


class RecipeRuns:
    """The run directories of a recipe at a scale and seed range, with their metrics. Seeds without metrics
    are left out of their condition (`missing_seeds`), and conditions without any are left out (`missing`);
    FileNotFoundError if all are."""

    def __init__(self, recipe: Recipe, scale: Scale, seed: int, seeds: int, runs_dir: str):
        self.recipe, self.scale = recipe, scale
        self.configs = {  # the first program's (conditions trained one program per seed: the first seed's)
            c: recipes.condition_programs(scale, c, seed, seeds, runs_dir)[0] for c in recipe.conditions
        }
        self.seed_dirs, self.rows, self.missing_seeds = {}, {}, {}
        for c in recipe.conditions:
            dirs = runner.condition_seed_dirs(scale, c, seed, seeds, runs_dir)
            rows = [logs.read_metrics(d) for d in dirs]
            self.seed_dirs[c] = [d for d, r in zip(dirs, rows, strict=True) if r]
            self.rows[c] = [r for r in rows if r]
            absent = [s for s, r in zip(range(seed, seed + seeds), rows, strict=True) if not r]
            if absent and self.rows[c]:
                self.missing_seeds[c] = absent
        self.missing = [c for c, seed_rows in self.rows.items() if not seed_rows]
        if len(self.missing) == len(self.configs):
            raise FileNotFoundError(
                f"no metrics for any condition of {recipe.name} under {runs_dir}/{scale.name}: "
                f"run `python -m jaxsocial.experiments run {recipe.name} --scale {scale.name} "
                f"--seeds {seeds}` first"
            )
        for c in self.missing:  # drawn without them; the summary lists them
            del self.configs[c], self.seed_dirs[c], self.rows[c]
        self.seed, self.seeds, self.runs_dir = seed, seeds, runs_dir

    def flags(self, condition: str) -> list[str]:
        cfg = self.configs[condition]
        return recipes.condition_flags(self.scale, condition, cfg.seed, cfg.seeds, cfg.runs_dir)

    def command(self, out_dir: str | None = None) -> str:
        """The `figure` command that re-creates this summary (written into `out_dir`, default the CLI's)."""
        argv = ["figure", self.recipe.name, "--scale", self.scale.name, "--seed", str(self.seed)]
        argv += ["--seeds", str(self.seeds), "--runs-dir", self.runs_dir]
        argv += ["--out-dir", out_dir] if out_dir is not None else []
        return "python -m jaxsocial.experiments " + shlex.join(argv)

    def provenance(self) -> dict[str, Any]:
        """How the runs were made: per condition, the recorded training commands (`records.read_provenance`)
        with the seeds each trained, its commit, device, jax version, start, end and exit status; seeds
        without a record are listed under 'unrecorded'."""
        runs: dict[str, list[dict[str, Any]]] = {}
        unrecorded = []
        for c, dirs in self.seed_dirs.items():
            for d in dirs:
                prov = records.read_provenance(d)
                if prov is None:
                    unrecorded.append(str(d))
                    continue
                run = prov.get("run", prov)
                seed = logs.read_config(d).get("seed")
                same = [r for r in runs.setdefault(c, []) if r["command"] == run.get("command")]
                if same:
                    same[0]["seeds"].append(seed)
                    continue
                runs[c].append({"seeds": [seed], **{k: run.get(k) for k in records.RUN_FIELDS}})
        return {"training_runs": runs, "unrecorded": unrecorded}

    def commits(self) -> dict[str, str | None]:
        """Each seed directory's recorded training commit (None: no record)."""
        return {
            str(d): (records.read_provenance(d) or {}).get("run", {}).get("commit")
            for dirs in self.seed_dirs.values()
            for d in dirs
        }

    def header(self, command: str) -> dict[str, Any]:
        unfinished = {
            c: [len(r) for r in rows]
            for c, rows in self.rows.items()
            if any(len(r) < self.configs[c].iterations for r in rows)
        }
        cfg = next(iter(self.configs.values()))
        return {
            "recipe": self.recipe.name,
            "title": self.recipe.title,
            "scale": self.scale.name,
            "scale_note": self.scale.note,
            "command": command,
            "provenance": self.provenance(),
            "config": {
                c: {
                    "flags": shlex.join(self.flags(c)),
                    "label": recipes.CONDITIONS[c].label,
                    "program_per_seed": recipes.CONDITIONS[c].program_per_seed,
                }
                for c in self.configs
            },
            "seed_dirs": {c: [str(d) for d in dirs] for c, dirs in self.seed_dirs.items()},
            "env_steps_per_run": cfg.iterations * cfg.num_envs * cfg.rollout_steps,
            "unfinished_runs": unfinished,
            "missing_conditions": self.missing,
            "missing_seeds": self.missing_seeds,
        }


def takeoffs(runs: RecipeRuns) -> dict[str, dict[str, Any]]:
    """Each condition's time to learning (`takeoff`): every seed's takeoff iteration and env-step, and how
    many seeds took off by the end."""
    out = {}
    for c, seed_rows in runs.rows.items():
        cfg = runs.configs[c]
        iterations = [takeoff.takeoff(*curve(rows), LEARNED_RETURN) for rows in seed_rows]
        steps = [None if i is None else i * cfg.num_envs * cfg.rollout_steps for i in iterations]
        out[c] = {
            "takeoff_iterations": iterations,
            "takeoff_env_steps": steps,
            "took_off": sum(i is not None for i in iterations),
            "seeds": len(iterations),
        }
    return out


def summarize(runs: RecipeRuns, command: str | None = None) -> dict[str, Any]:
    """The JSON summary of a recipe (see the module docstring for the measures); `command` re-creates it
    (default: `runs.command()`)."""
    out = runs.header(runs.command() if command is None else command)
    kind = runs.recipe.kind
    conditions: dict[str, Any] = {}
    if kind in ("curves", "mixing", "predictions"):
        for c, seed_rows in runs.rows.items():
            finals = [final_return(rows) for rows in seed_rows]
            conditions[c] = stats(finals)
            conditions[c]["seeds_above_one_tile"] = sum(v > LEARNED_RETURN for v in finals)
            if kind == "mixing":
                conditions[c]["switch_iterations"] = [switch_iteration(rows) for rows in seed_rows]
                for key in _eval_keys(seed_rows):
                    conditions[c][key] = stats([_final_eval(rows, key) for rows in seed_rows])
        # Scripted experts do not react to the learner, and all conditions of a seed share the environment's
        # random numbers, so the experts' returns are the same in every social condition: take the first's.
        social = [c for c in runs.rows if recipes.CONDITIONS[c].env == "goalcycle3"]
        if social:
            seed_rows = runs.rows[social[0]]
            slots = _slots(seed_rows[0][0])[1:]  # the learner is in slot 0
            out["experts"] = stats(
                [float(np.mean([final_return(rows, k) for k in slots])) for rows in seed_rows]
            )
        out["separated_ci95"] = separations(conditions)
        out["learned_seeds_fisher_p"] = learned_seed_tests(conditions)
        out["learned_seeds_boschloo_p"] = learned_seed_tests(conditions, "boschloo-greater")
    elif kind == "ct":  # the training return, and the CT protocol's scores after training
        for c, seed_rows in runs.rows.items():
            conditions[c] = stats([final_return(rows) for rows in seed_rows])
            results = [_read_json(runner.ct_path(d, runs.scale)) for d in runs.seed_dirs[c]]
            for score in CT_SCORES:
                conditions[c][score] = stats([r[score]["mean"] for r in results])
            conditions[c]["expert_return"] = stats([r["expert_return"]["episode"] for r in results])
        out["separated_ci95"] = {
            score: separations({c: ct_score(v, score) for c, v in conditions.items()})
            for score in ("final", *CT_SCORES)
        }
    else:  # transfer: learner and expert returns in each evaluation environment, and the training returns
        out["training"] = {c: stats([final_return(rows) for rows in r]) for c, r in runs.rows.items()}
        for spec in runner.transfer_specs(runs.recipe, runs.scale):
            per_cond = {
                c: stats([_read_eval(d, spec)[0]["mean_return"] for d in dirs])
                for c, dirs in runs.seed_dirs.items()
            }
            # The environment's own experts, from one evaluation (every evaluation plays the same episodes).
            first = _read_eval(next(iter(runs.seed_dirs.values()))[0], spec)
            experts = [s for s in first if s["kind"] == "expert"]
            per_cond["experts"] = {
                "per_slot": [round(s["mean_return"], 4) for s in experts],
                "mean": round(float(np.mean([s["mean_return"] for s in experts])), 4),
                "ci95": [round(float(np.mean([s["ci95"][i] for s in experts])), 4) for i in (0, 1)],
                "ci_over": "episodes",
            }
            conditions[spec] = per_cond
    out["conditions"] = conditions
    out["time_to_learning"] = {"learned_return": LEARNED_RETURN, "conditions": takeoffs(runs)}
    if runs.recipe.design is not None:
        design = prereg.load(runs.recipe.design)
        learned = {
            c: [final_return(rows) > design.learned_threshold for rows in r] for c, r in runs.rows.items()
        }
        out["preregistered"] = prereg.preregistered(design, learned, runs.commits())
        out["preregistered"]["checks"]["scale_as_designed"] = runs.scale.name == design.scale
        out["preregistered"]["checks"]["seeds_as_designed"] &= (runs.seed, runs.seeds) == (
            design.seed,
            design.seeds,
        )
    return out


def switch_iteration(rows: list[dict[str, Any]]) -> int | None:
    """The first iteration a run trained in a stage of its schedule (None: it never left the plain
    environment), e.g. where a mixed condition switched to solo episodes."""
    return next((row["iteration"] for row in rows if row.get("stage", -1) >= 0), None)


def _slots(row: dict[str, Any]) -> list[int]:
    """The agent slots a metrics row reports."""
    return sorted(int(k.split("/")[1]) for k in row if k.startswith("return/"))


def _eval_keys(seed_rows: list[list[dict[str, Any]]]) -> list[str]:
    return sorted({k for rows in seed_rows for r in rows for k in r if k.startswith("eval/")})


def _final_eval(rows: list[dict[str, Any]], key: str) -> float:
    _, values = eval_curve(rows, key)
    n = max(1, round(len(values) * FINAL_FRACTION))
    return float(values[-n:].mean()) if len(values) else float("nan")


def _read_json(path: Path) -> dict[str, Any]:
    if not path.exists():
        raise FileNotFoundError(f"no evaluation {path}: run the recipe first")
    return logs.read_json(path)


def _read_eval(seed_dir: Path, spec: str) -> list[dict[str, Any]]:
    return _read_json(runner.eval_path(seed_dir, spec))["results"]


def band(ax, xs: list[np.ndarray], ys: list[np.ndarray], label: str, color) -> None:
    """Per-seed faint lines, the mean and a 95% CI band over seeds."""
    n = min(len(x) for x in xs)
    x, y = xs[0][:n], np.stack([v[:n] for v in ys])
    for v in y:
        ax.plot(x, v, color=color, alpha=0.25, lw=0.8)
    stats_ = np.array([mean_ci95(y[:, i]) for i in range(n)])
    ax.plot(x, stats_[:, 0], color=color, lw=2, label=label)
    if len(y) > 1:
        ax.fill_between(x, stats_[:, 1], stats_[:, 2], color=color, alpha=0.2)


def draw(runs: RecipeRuns, summary: dict[str, Any], path: Path) -> None:
    """The recipe's figure as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colors = plt.get_cmap("tab10").colors
    kind = runs.recipe.kind
    steps_per_iteration = {c: cfg.num_envs * cfg.rollout_steps for c, cfg in runs.configs.items()}
    if kind in ("curves", "predictions"):
        fig, (returns_ax, zoom_ax, loss_ax, takeoff_ax) = plt.subplots(1, 4, figsize=(22, 4.2))
        used = set()
        for i, (c, seed_rows) in enumerate(runs.rows.items()):
            xs, ys = zip(*(curve(rows) for rows in seed_rows), strict=True)
            xs = [x * steps_per_iteration[c] for x in xs]
            for ax in (returns_ax, zoom_ax):
                band(ax, xs, list(ys), recipes.CONDITIONS[c].label, colors[i])
            key = next((k for k in LOSS_PANEL if k in seed_rows[0][-1]), None)
            if key is not None:
                used.add(key)
                its, losses = zip(*(metric_curve(rows, key) for rows in seed_rows), strict=True)
                its = [x * steps_per_iteration[c] for x in its]
                band(loss_ax, its, list(losses), recipes.CONDITIONS[c].label, colors[i])
        if "experts" in summary and summary["experts"]["mean"] is not None:
            returns_ax.axhline(summary["experts"]["mean"], color="k", ls="--", lw=1, label="experts")
        returns_ax.set(ylabel="learner episode return", title=runs.recipe.title)
        zoom_ax.set(title="the learners' returns, zoomed")
        names = " / ".join(LOSS_PANEL[k] for k in LOSS_PANEL if k in used)
        loss_ax.set(ylabel=names, title="training loss")
        for ax in (returns_ax, zoom_ax, loss_ax):
            steps_axis(ax)
        returns_ax.legend(fontsize=8)
        draw_takeoffs(takeoff_ax, runs, summary, colors)
    elif kind == "mixing":
        keys = _eval_keys([r for rows in runs.rows.values() for r in rows])
        fig, axes = plt.subplots(1, 2 + len(keys), figsize=(5 * (2 + len(keys)), 4))
        draw_takeoffs(axes[-1], runs, summary, colors)
        axes = axes[:-1]
        for i, (c, seed_rows) in enumerate(runs.rows.items()):
            label = recipes.CONDITIONS[c].label
            xs, ys = zip(*(curve(rows) for rows in seed_rows), strict=True)
            band(axes[0], list(xs), list(ys), label, colors[i])
            for ax, key in zip(axes[1:], keys, strict=True):
                xs, ys = zip(*(eval_curve(rows, key) for rows in seed_rows), strict=True)
                band(ax, list(xs), list(ys), label, colors[i])
        for i, seed_rows in enumerate(runs.rows.values()):  # where each seed switched to solo episodes
            for switch in {switch_iteration(rows) for rows in seed_rows} - {None}:
                for ax in axes:
                    ax.axvline(switch, color=colors[i], ls=":")
        axes[0].set(title="training environment (with experts)", xlabel="iteration", ylabel="learner return")
        for ax, key in zip(axes[1:], keys, strict=True):
            ax.set(title=key.removeprefix("eval/"), xlabel="iteration")
        axes[0].legend(fontsize=8)
    elif runs.recipe.kind == "ct":
        panels = {
            "final": "final training return",
            "ct": "CT score: (R_with - R_solo) / R_experts",
            "recall": "recall: 2nd half after the experts left",
        }
        fig, axes = plt.subplots(1, len(panels), figsize=(4.5 * len(panels), 4.2))
        for ax, (score, title) in zip(axes, panels.items(), strict=True):
            per_cond = {c: ct_score(v, score) for c, v in summary["conditions"].items()}
            _bars(ax, per_cond, colors)
            ax.axhline(0, color="k", lw=0.5)
            ax.set(title=title)
    else:
        specs = list(summary["conditions"])
        fig, axes = plt.subplots(1, len(specs) + 1, figsize=(4.5 * (len(specs) + 1), 4), squeeze=False)
        draw_takeoffs(axes[0, -1], runs, summary, colors)
        for ax, spec in zip(axes[0, :-1], specs, strict=True):
            _bars(ax, summary["conditions"][spec], colors)
            ax.set(title=spec, ylabel="mean episode return")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=70)
    plt.close(fig)


def draw_takeoffs(ax, runs: RecipeRuns, summary: dict[str, Any], colors) -> None:
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


def _bars(ax, per_cond: dict[str, dict[str, Any]], colors) -> None:
    """One bar per condition (mean, 95% CI whiskers, a cross per seed), labelled below."""
    names = list(per_cond)
    for j, name in enumerate(names):
        s = per_cond[name]
        if s["mean"] is None:
            continue
        lo, hi = s["ci95"]
        ax.bar(j, s["mean"], color=colors[j], yerr=[[s["mean"] - lo], [hi - s["mean"]]], capsize=4)
        marks = s.get("final_returns", [])
        ax.scatter([j] * len(marks), marks, color="k", marker="x", zorder=3)
    labels = [
        recipes.CONDITIONS[n].label if n in recipes.CONDITIONS else "its scripted experts" for n in names
    ]
    ax.set_xticks(range(len(names)), labels, rotation=30, ha="right", fontsize=8)


def write(runs: RecipeRuns, out_dir: str) -> tuple[Path, Path]:
    """Write `<recipe>-<scale>.json` and `.png` into `out_dir`; returns their paths. The summary records
    the command that re-creates them (`RecipeRuns.command`)."""
    summary = summarize(runs, runs.command(out_dir))
    out_dir = Path(out_dir)
    stem = out_dir / f"{runs.recipe.name}-{runs.scale.name}"
    json_path, png_path = stem.with_suffix(".json"), stem.with_suffix(".png")
    out_dir.mkdir(parents=True, exist_ok=True)
    logs.write_json(json_path, summary, indent=1)
    if runs.recipe.kind == "predictions":
        from jaxsocial.experiments import predictions

        predictions.draw(runs, png_path)
    else:
        draw(runs, summary, png_path)
    return json_path, png_path
