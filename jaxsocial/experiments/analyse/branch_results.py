"""A branch design's results (`plan.branch_design`): each branch's final scores and where it started, the
tests (paired or not) and the checks that make its summary valid, an amendment's tests, the verdict and the
figure; and its power, simulated from a pilot."""

from __future__ import annotations

import dataclasses
import datetime
from pathlib import Path
from typing import Any

import numpy as np

from jaxsocial import stats
from jaxsocial.experiments.analyse import kinds, plot_figures, records, verdicts
from jaxsocial.experiments.plan import catalogue
from jaxsocial.experiments.plan.branch_design import START, BranchDesign, start_row
from jaxsocial.experiments.plan.catalogue import Test
from jaxsocial.run import jsonio, metrics, rundir
from jaxsocial.specs import EnvSpec


def final_scores(design: BranchDesign, records_root: Path) -> dict[str, dict[str, list]]:
    """Per arm, per evaluation environment, every source seed's final evaluation (None: not recorded); and
    where the branches started (`start_scores`)."""
    out: dict[str, dict[str, list]] = {arm: {env: [] for env in design.eval_envs} for arm in design.arms}
    keys = {env: metrics.eval_key(str(EnvSpec.parse(env))) for env in design.eval_envs}  # as `train` logs
    for arm in design.arms:
        for seed in design.seed_range:
            record_dir = records_root / design.run_name(arm, seed)
            rows = rundir.read_metrics(record_dir) if rundir.has_metrics(record_dir) else None
            for env in design.eval_envs:
                value = None if rows is None else metrics.final_eval(rows, keys[env])
                out[arm][env].append(None if value is None or np.isnan(value) else round(value, 4))
    return out | start_scores(design, records_root)


def start_scores(design: BranchDesign, records_root: Path) -> dict[str, dict[str, list]]:
    """Per source condition (`start_row`), per evaluation environment, each source record's own evaluation
    there (`<record>/eval/<env>.json`, the learner's mean return), where its branches started; None where
    the design that made the records did not evaluate them there."""
    out = {}
    for source in design.sources():
        started = [design.record_of(source, seed, records_root) for seed in design.seed_range]
        out[start_row(source)] = {
            env: [
                round(kinds.RETURNS.score(jsonio.read_json(path)), 4) if path.is_file() else None
                for path in (kinds.eval_path(record_dir, env) for record_dir in started)
            ]
            for env in design.eval_envs
        }
    return out


def compare_arms(
    test: Test, paired: bool, scores: dict[str, dict[str, list]], control: str
) -> dict[str, Any]:
    """One test on the seeds both rows have, `test`'s treatment arm against the row `control` (paired: by
    source seed): its p-value (None without data)."""
    a, b = scores[test.treatment][test.env], scores[control][test.env]
    if paired:
        pairs = [(x, y) for x, y in zip(a, b, strict=True) if x is not None and y is not None]
        d = stats.paired_difference([y for _, y in pairs], [x for x, _ in pairs], test.alternative)
        return {"test": "wilcoxon", "n": d["n"], "p": d["wilcoxon_p"], "mean_difference": d["mean"]}
    kept = [[v for v in values if v is not None] for values in (a, b)]
    return {"test": "mann-whitney"} | stats.mann_whitney(kept[0], kept[1], test.alternative)


def _tested(
    design: BranchDesign, family: dict[str, Test], scores: dict[str, dict[str, list]], alpha: float
) -> dict:
    """Each test of `family`, Holm-corrected among themselves at `alpha`."""
    out = {
        name: {"env": t.env, "arms": [t.treatment, design.control_row(t)], "alternative": t.alternative}
        | compare_arms(t, design.paired(t), scores, design.control_row(t))
        for name, t in family.items()
    }
    return catalogue.holm_family(out, alpha)


def as_designed(design: BranchDesign, records_root: Path) -> dict[str, Any]:
    """Which recorded branches differ from the design (iterations, seed, environment, source) and whether
    every branch is recorded."""
    differing, recorded = [], 0
    for seed in design.seed_range:
        for arm in design.arms:
            record_dir = records_root / design.run_name(arm, seed)
            if not (record_dir / rundir.CONFIG_FILE).is_file():
                continue
            recorded += 1
            got = rundir.read_config(record_dir)
            spec = EnvSpec.parse(design.arms[arm].env)
            want = {
                "iterations": design.iterations,
                "seed": design.branch_seed + seed - design.seed,
                "env": spec.name,
                "env_args": spec.env_args,
                "source": design.source_dir(arm, seed, Path()).name,
            }
            have = {k: got.get(k) for k in want if k != "source"}
            have["source"] = Path(str(got.get("init_from", "")).rpartition("@")[0]).name
            if have != want:
                differing.append(record_dir.name)
    every = design.seeds * len(design.arms)
    return {"every_branch_recorded": recorded == every, "recorded": recorded, "differing": differing}


def summarise(design: BranchDesign, records_root: Path) -> dict[str, Any]:
    """The design's summary: per environment each arm's per-seed scores (`stats.summary`), the tests, and the
    checks that make it valid (the design committed before every run, every branch recorded as designed)."""
    scores = final_scores(design, records_root)
    per_env = {
        env: {
            arm: stats.summary([v for v in scores[arm][env] if v is not None])
            | {"per_seed": scores[arm][env]}
            for arm in scores
        }
        for env in design.eval_envs
    }
    recorded = [records_root / design.run_name(a, s) for a in design.arms for s in design.seed_range]
    provenance = {
        str(d.relative_to(records_root)): jsonio.read_json(d / records.PROVENANCE_FILE)
        for d in recorded
        if (d / records.PROVENANCE_FILE).is_file()
    }
    commit = catalogue.design_commit(design.name)
    checks = catalogue.commit_checks(commit, {name: p["run"]["commit"] for name, p in provenance.items()})
    designed = as_designed(design, records_root)
    checks |= {"every_branch_recorded": designed["every_branch_recorded"], "differing": designed["differing"]}
    checks["branches_as_designed"] = not designed["differing"]
    block = {
        "commit": commit,
        "alpha": design.alpha,
        "primary": _tested(design, design.primary, scores, design.alpha),
        "secondary": _tested(design, design.secondary, scores, design.alpha),
        "checks": checks,
        "valid": all(v for v in checks.values() if isinstance(v, bool)),
    }
    if design.amendment:
        ended = [p["run"].get("ended") for p in provenance.values()]
        block["amendment"] = amended(design, scores, ended)
    return {
        "design": design.name,
        "material": {"records": design.records, "seeds": [design.seed, design.seed + design.seeds - 1]},
        "arms": {name: dataclasses.asdict(arm) for name, arm in design.arms.items()},
        "iterations": design.iterations,
        "episodes": design.episodes,
        "recorded": designed["recorded"],
        "environments": per_env,
        "preregistered": block,
        "machines": sorted({p["run"].get("device") or "unknown" for p in provenance.values()}),
        "command": f"python -m jaxsocial.experiments figure {design.name}",
    }


def amended(
    design: BranchDesign, scores: dict[str, dict[str, list]], ended: list[str | None]
) -> dict[str, Any]:
    """The amendment's tests, Holm-corrected among themselves, and its checks: committed, and before the
    last of the design's runs ended (how many had: `ended`, the recorded runs' end times), every branch's
    start scored."""
    amendment = design.amendment
    commit = catalogue.file_commit(catalogue.amendment_path(design.name))
    when = catalogue.commit_time(commit)
    at = datetime.datetime.fromisoformat(when) if when else None
    before = sum(at is not None and e is not None and datetime.datetime.fromisoformat(e) < at for e in ended)
    checks = {
        "amendment_committed": commit is not None,
        "runs_ended_before_the_amendment": before,
        "amendment_before_the_last_run_ended": at is not None and before < design.seeds * len(design.arms),
        "every_start_scored": all(
            v is not None
            for t in amendment.tests.values()
            if t.control == START
            for v in scores[design.control_row(t)][t.env]
        ),
    }
    return {
        "commit": commit,
        "committed": when,
        "added": amendment.added,
        "alpha": amendment.alpha,
        "tests": _tested(design, amendment.tests, scores, amendment.alpha),
        "checks": checks,
        "valid": all(v for v in checks.values() if isinstance(v, bool)),
    }


def draw(summary: dict[str, Any], path: Path) -> None:
    """One panel per evaluation environment: each arm's mean (and each source's where it started, if
    scored there) with its 95% interval over seeds and a cross per seed; titled with the tests there."""
    plt = plot_figures.pyplot()
    per_env, block = summary["environments"], summary["preregistered"]
    families = verdicts.tested_families(block)
    families += [("amendment", block["amendment"]["tests"])] if "amendment" in block else []
    fig, axes = plt.subplots(1, len(per_env), figsize=(4.0 * len(per_env), 3.8), squeeze=False)
    for ax, (env, rows) in zip(axes[0], per_env.items(), strict=True):
        colours = {arm: f"C{j}" for j, arm in enumerate(rows)}  # one colour a row in every panel
        arms = [arm for arm, s in rows.items() if s["mean"] is not None]
        for j, arm in enumerate(arms):
            s = rows[arm]
            whisker = plot_figures.whisker(s["mean"], s["ci95"])
            ax.bar(j, s["mean"], color=colours[arm], yerr=whisker, capsize=3)
            values = [v for v in s["per_seed"] if v is not None]
            ax.scatter([j] * len(values), values, color="k", marker="x", s=8, zorder=3)
        tests = [
            f"{name}: Holm p = {e['p_holm']:.3g}" if e["p"] is not None else f"{name}: no data"
            for _, entries in families
            for name, e in entries.items()
            if e["env"] == env
        ]
        ax.set_xticks(range(len(arms)), arms, rotation=20, ha="right", fontsize=8)
        ax.set_title("\n".join([plot_figures.env_title(env), *tests]), fontsize=8)
        ax.set_ylabel("learner return per episode")
    fig.suptitle(
        f"{summary['design']}: {summary['iterations']} iterations from each record's policy, "
        f"{summary['episodes']} episodes an evaluation",
        fontsize=10,
    )
    plot_figures.save_png(fig, path)
