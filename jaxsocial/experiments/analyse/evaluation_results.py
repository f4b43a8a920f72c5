"""An evaluation design's results (`plan.evaluation_design`): scores, the tests and the checks that make its
summary valid, the verdict and the figure; and its power, simulated from a pilot.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from jaxsocial import stats
from jaxsocial.experiments.plan import catalogue
from jaxsocial.experiments.plan.catalogue import Test
from jaxsocial.experiments.plan.evaluation_design import (
    PROVENANCE,
    EvaluationDesign,
    Play,
    envs,
    evaluations,
    out_dir,
)
from jaxsocial.run import jsonio, rundir


def absent_records(design: EvaluationDesign, records_root: Path) -> list[str]:
    """The design's records (and reference records) that hold no final policy."""
    wanted = [d for c in (design.treatment, design.control) for d in design.record_dirs(c, records_root)]
    wanted += [records_root / r.ckpt for r in design.references.values() if r.ckpt]
    return [str(d) for d in wanted if not (d / rundir.POLICY_DIR).is_dir()]


def scores(result: dict[str, Any]) -> list[float]:
    """Each policy's mean learner (slot 0) return per episode in an evaluation's result."""
    return [float(v) for v in result["results"][0]["per_seed_mean"]]


def experts_return(result: dict[str, Any]) -> float | None:
    """The mean return of the evaluation's scripted experts over their slots (None: there are none)."""
    experts = [s["mean_return"] for s in result["results"] if s["kind"] == "expert"]
    return round(float(np.mean(experts)), 4) if experts else None


def tested(
    design: EvaluationDesign, family: dict[str, Test], by_player: dict[tuple[str, str], list[float] | None]
) -> dict[str, dict[str, Any]]:
    """Each test of `family` on the per-policy scores `by_player[env, player]` (None: not played),
    Holm-corrected among themselves at the design's alpha."""
    out = {}
    for name, test in family.items():
        t, c = by_player[test.env, design.treatment], by_player[test.env, design.control]
        out[name] = stats.mann_whitney(t or [], c or [], test.alternative) | {"env": test.env}
    return catalogue.holm_family(out, design.alpha)


def read_results(
    design: EvaluationDesign, out: Path, records_root: Path
) -> dict[Play, dict[str, Any] | None]:
    """Every evaluation of the design and its result (None: not played yet)."""
    return {
        e: jsonio.read_json(e.path(out)) if e.path(out).exists() else None
        for e in evaluations(design, records_root)
    }


def read_play_log(out: Path) -> list[dict[str, Any]]:
    """The processes that played the design's evaluations (`run`), oldest first."""
    path = out / PROVENANCE
    return [json.loads(line) for line in path.read_text().splitlines()] if path.is_file() else []


def played_as_designed(design: EvaluationDesign, results: dict[Play, dict[str, Any] | None]) -> bool:
    """Whether every evaluation was played, with the design's episodes and evaluation seed, by its records in
    order (compared by record name, wherever the records root was)."""
    return all(
        r is not None
        and r["episodes_per_checkpoint"] == design.episodes
        and r["seed"] == design.eval_seed
        and [Path(c).name for c in r["checkpoints"]] == [Path(c).name for c in e.ckpts]
        for e, r in results.items()
    )


def summarise(design: EvaluationDesign, records_root: Path, science: Path) -> dict[str, Any]:
    """The design's summary: per environment each arm's and reference's scores (`stats.summary` over
    policies, with every seed's) and the experts' return there; the tests; and the checks that make it
    valid (the design committed before every evaluation, every evaluation played as designed)."""
    out = out_dir(design, science)
    results = read_results(design, out, records_root)
    by_player = {(e.env, e.player): None if r is None else scores(r) for e, r in results.items()}
    per_env = {}
    for env in envs(design):
        players = (design.treatment, design.control, *design.references)
        per_env[env] = {
            p: None if by_player[env, p] is None else stats.summary(by_player[env, p]) for p in players
        }
        played = [r for e, r in results.items() if e.env == env and r is not None]
        per_env[env]["experts"] = experts_return(played[0]) if played else None
    commit, evaluated = catalogue.design_commit(design.name), read_play_log(out)
    checks = catalogue.commit_checks(commit, {line["file"]: line["commit"] for line in evaluated})
    checks["played_as_designed"] = played_as_designed(design, results)
    block = {
        "commit": commit,
        "alpha": design.alpha,
        "primary": tested(design, design.primary, by_player),
        "secondary": tested(design, design.secondary, by_player),
        "checks": checks,
        "valid": all(v for v in checks.values() if isinstance(v, bool)),
    }
    material = {"records": design.records, "treatment": design.treatment, "control": design.control}
    return {
        "design": design.name,
        "material": material | {"seeds": [design.seed, design.seed + design.seeds - 1]},
        "episodes": design.episodes,
        "environments": per_env,
        "preregistered": block,
        "machines": sorted({line["cpu"] for line in evaluated}),
        "command": f"python -m jaxsocial.experiments figure {design.name}",
    }


def draw(summary: dict[str, Any], path: Path) -> None:
    """One panel per environment, four to a row: a bar per arm and reference (mean, t 95% interval over
    policies), a cross per policy, and the environment's experts as a dashed line; each panel titled with its
    test's family and Holm p-value."""
    from jaxsocial.experiments.analyse import plot_figures

    plt = plot_figures.pyplot()
    block = summary["preregistered"]
    test_of = {
        e["env"]: (family, name, e)
        for family in ("primary", "secondary")
        for name, e in block[family].items()
    }
    per_env = summary["environments"]
    columns = min(4, len(per_env))
    panel_rows = -(-len(per_env) // columns)
    fig, axes = plt.subplots(panel_rows, columns, figsize=(3.6 * columns, 3.6 * panel_rows), squeeze=False)
    for ax in axes.flat[len(per_env) :]:
        ax.set_visible(False)
    colors = plt.get_cmap("tab10").colors
    for ax, (env, rows) in zip(axes.flat[: len(per_env)], per_env.items(), strict=True):
        players = [p for p in rows if p != "experts" and rows[p] is not None]
        for j, p in enumerate(players):
            s = rows[p]
            ax.bar(j, s["mean"], color=colors[j], yerr=plot_figures.whisker(s["mean"], s["ci95"]), capsize=3)
            ax.scatter(
                [j] * len(s["final_returns"]), s["final_returns"], color="k", marker="x", s=10, zorder=3
            )
        if rows["experts"] is not None:
            ax.axhline(rows["experts"], color="k", ls="--", lw=1, label=f"its experts {rows['experts']:.2f}")
            ax.legend(fontsize=7)
        ax.set_xticks(range(len(players)), players, rotation=30, ha="right", fontsize=8)
        family, name, entry = test_of[env]
        p = "not played" if entry["p"] is None else f"Holm p = {entry['p_holm']:.3g}"
        ax.set_title(f"{env}\n{family}: {p}", fontsize=9)
        ax.set_ylabel("learner return per episode")
    fig.suptitle(f"{summary['design']}: zero-shot, {summary['episodes']} episodes a policy", fontsize=10)
    plot_figures.save_png(fig, path)
