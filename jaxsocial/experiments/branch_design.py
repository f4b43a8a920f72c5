"""Pre-registered designs that train on from committed records: every source seed's final policy starts one
run per arm, each arm for the same iterations in its own environment, fixed in `designs/<name>.json`
before any of its runs.

    python -m jaxsocial.experiments power mixing              # the design and its power
    python -m jaxsocial.experiments run mixing --cores 0 1    # train what is missing (blind)
    python -m jaxsocial.experiments record mixing             # pack the finished runs
    python -m jaxsocial.experiments figure mixing             # summary, tests and figure

Run k of an arm starts from the record `<records>/<source>-s<seed+k>-<seed+k>` of the arm's source condition
(`--init-from`: a record keeps its policy, not its optimiser, so every arm starts with the policy's params
and a fresh optimiser state), trains with the source's config in the arm's environment for `iterations`
with seed `branch_seed + k` (every arm of one source seed the same seed: paired arms differ only in their
environment), blind, one process pinned to each core with the design's `xla_flags`, and is evaluated at its
end in every environment of `eval_envs` (`episodes` each). Its run directory is `<runs>/<out>/<arm>-s<seed+k>`
and its record mirrors it. A test compares two arms' per-seed final evaluations in one environment: the
Wilcoxon signed-rank test where both arms branch the same records (paired by source seed), Mann-Whitney U
otherwise; the primary tests are Holm-corrected at `alpha` as a family, the secondary ones among themselves.

The power is simulated from a pilot (`pilot_scores`): paired differences and each arm's scores, the effect
diluted by a discount (`power_table`).

Tests added after a design's runs began, blind (no result seen: `figure` refuses until every branch is in),
are an amendment in `designs/amendments/<name>.json`: a family of their own, Holm-corrected among
themselves, the design's own tests untouched. Their control may be `start`: where each branch started, its
source record scored by the evaluation of the design that made it (`<record>/eval/<env>.json`).
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
from pathlib import Path
from typing import Any

import numpy as np

from jaxsocial import stats
from jaxsocial.env import registry
from jaxsocial.experiments.analyse import kinds, plot_figures, records, run_times, rundirs
from jaxsocial.experiments.launch import pinned
from jaxsocial.experiments.plan import catalogue, paths, prereg
from jaxsocial.run import config, logs, metrics
from jaxsocial.run.config import TrainConfig
from jaxsocial.run.flags import config_flags
from jaxsocial.specs import CheckpointRef, EnvSpec

ALTERNATIVES = ("greater", "less", "two-sided")
VERBS = ("power", "run", "record", "figure")
"""What `python -m jaxsocial.experiments VERB NAME` does to a branch design (`main`)."""
START = "start"
"""A test's control that is no arm: the treatment arm's source records, as they were when branched."""


@dataclasses.dataclass(frozen=True)
class Arm:
    """Where one arm trains on: the records of condition `source`, in the environment `env`
    (NAME[:field=value,...])."""

    source: str
    env: str
    statement: str = ""


@dataclasses.dataclass(frozen=True)
class Test:
    """One comparison: `treatment`'s per-seed final evaluation in `env` against `control`'s."""

    env: str
    treatment: str
    control: str
    alternative: str
    statement: str = ""


@dataclasses.dataclass(frozen=True)
class Amendment:
    """Tests added to a design after its runs began and before any result was seen, with their power."""

    added: str
    """The date, and how many of the design's runs had ended."""
    alpha: float
    tests: dict[str, Test]
    power: float
    power_simulation: dict[str, Any]
    rationale: str


@dataclasses.dataclass(frozen=True)
class BranchDesign:
    """See the module docstring."""

    name: str
    records: str
    """The material: a folder of the records root holding `<condition>-s<k>-<k>` records."""
    out: str
    """The design's folder under the runs root and the records root."""
    seed: int
    seeds: int
    """Every source seed seed..seed+seeds-1 of every arm's source, none left out."""
    branch_seed: int
    iterations: int
    arms: dict[str, Arm]
    eval_envs: tuple[str, ...]
    episodes: int
    alpha: float
    primary: dict[str, Test]
    secondary: dict[str, Test]
    xla_flags: str
    power: float
    power_simulation: dict[str, Any]
    rationale: str
    amendment: Amendment | None = None

    @property
    def tests(self) -> dict[str, Test]:
        return {**self.primary, **self.secondary, **(self.amendment.tests if self.amendment else {})}

    def paired(self, test: Test) -> bool:
        """Whether `test`'s arms branch the same records (seed k of one pairs with seed k of the other), as
        a branch pairs with its own start."""
        return test.control == START or self.arms[test.treatment].source == self.arms[test.control].source

    def control_row(self, test: Test) -> str:
        """The name of `test`'s control among the scores: an arm, or the treatment's `start_row`."""
        return start_row(self.arms[test.treatment].source) if test.control == START else test.control

    def source_seeds(self) -> range:
        return range(self.seed, self.seed + self.seeds)

    def source_dir(self, arm: str, seed: int, records_root: Path) -> Path:
        """The record run `seed` of `arm` starts from."""
        return self.record_of(self.arms[arm].source, seed, records_root)

    def record_of(self, source: str, seed: int, records_root: Path) -> Path:
        """The material's record of condition `source`, seed `seed`."""
        return records_root / self.records / f"{source}-s{seed}-{seed}"

    def sources(self) -> tuple[str, ...]:
        """The source conditions of the arms, each once, in the arms' order."""
        return tuple(dict.fromkeys(a.source for a in self.arms.values()))

    def run_name(self, arm: str, seed: int) -> str:
        """The run name of `arm`'s branch of source seed `seed` (under a runs root or a records root)."""
        return f"{self.out}/{arm}-s{seed}"


def start_row(source: str) -> str:
    """The scores' name of the `source` condition's records as they were when branched."""
    return f"{source} at the branch"


def load(name: str) -> BranchDesign:
    """The branch design `designs/<name>.json` with its amendment, if any (FileNotFoundError if none;
    ValueError if invalid or of another kind)."""
    raw = catalogue.read(name, "branch")
    raw["arms"] = {k: Arm(**v) for k, v in raw["arms"].items()}
    for family in ("primary", "secondary"):
        raw[family] = {k: Test(**v) for k, v in raw[family].items()}
    raw["eval_envs"] = tuple(raw["eval_envs"])
    design = BranchDesign(**raw)
    if catalogue.amendment_path(name).is_file():
        added = logs.read_json(catalogue.amendment_path(name))
        added["tests"] = {k: Test(**v) for k, v in added["tests"].items()}
        design = dataclasses.replace(design, amendment=Amendment(**added))
    for env in (*(arm.env for arm in design.arms.values()), *design.eval_envs):
        spec = EnvSpec.parse(env)
        registry.env_params(spec.name, spec.args)  # ValueError for an unknown environment or field
    for test_name, test in design.tests.items():
        problems = [
            f"arm {a!r} is not one of {sorted(allowed)}"
            for a, allowed in ((test.treatment, design.arms), (test.control, {*design.arms, START}))
            if a not in allowed
        ]
        if test.env not in design.eval_envs:
            problems.append(f"{test.env} is not among eval_envs")
        if test.alternative not in ALTERNATIVES:
            problems.append(f"the alternative must be one of {ALTERNATIVES}")
        if problems:
            raise ValueError(f"design {name}, test {test_name}: {'; '.join(problems)}")
    if not design.primary or design.iterations < 1 or design.seeds < 1:
        raise ValueError(f"design {name}: it needs primary tests, iterations and seeds")
    return design


# ----------------------------------------------------------------------------------------------------------
# Launch: train what is missing, record what finished
# ----------------------------------------------------------------------------------------------------------


def branch_config(
    design: BranchDesign, arm: str, seed: int, runs_root: Path, records_root: Path
) -> TrainConfig:
    """The training config of `arm`'s branch of source seed `seed`: the source record's own config in the
    arm's environment, from the record's policy, for the design's iterations with its branch seed, evaluated
    at its end, blind."""
    source = design.source_dir(arm, seed, records_root)
    cfg = config.config_from_dict(logs.read_config(source))
    spec = EnvSpec.parse(design.arms[arm].env)
    return dataclasses.replace(
        cfg,
        env=spec.name,
        env_args=spec.args,
        iterations=design.iterations,
        seed=design.branch_seed + seed - design.seed,
        seeds=1,
        init_from=CheckpointRef(source),
        eval_envs=tuple(EnvSpec.parse(e) for e in design.eval_envs),
        eval_every=design.iterations,
        eval_episodes=design.episodes,
        run_name=design.run_name(arm, seed),
        runs_dir=str(runs_root),
        resume=False,
        overwrite=False,
        blind=True,
    )


def missing_sources(design: BranchDesign, records_root: Path) -> list[str]:
    """The design's source records that hold no final policy."""
    wanted = {design.source_dir(a, s, records_root) for a in design.arms for s in design.source_seeds()}
    return sorted(str(d) for d in wanted if not (d / "policy").is_dir())


def run(
    design: BranchDesign,
    runs_root: Path,
    cores: list[int],
    records_root: Path,
    dry_run: bool = False,
    max_runs: int | None = None,
) -> list[int]:
    """Train every branch not finished yet, seed by seed (each source seed's arms before the next seed), one
    process a core; a begun branch resumes; only the first `max_runs` start (`pinned.first_runs`). Nothing
    starts if a source record is missing. Returns the exit codes of those started."""
    missing = missing_sources(design, records_root)
    if missing:
        raise FileNotFoundError(f"the design's material is incomplete: {', '.join(missing)}")
    jobs, counts = [], dict.fromkeys((rundirs.FINISHED, rundirs.PARTIAL, rundirs.MISSING), 0)
    for seed in design.source_seeds():
        for arm in design.arms:
            cfg = branch_config(design, arm, seed, runs_root, records_root)
            run_dir = runs_root / cfg.run_name
            state = rundirs.branch_state(run_dir, design.iterations)
            counts[state] += 1
            flags = config_flags(cfg) + rundirs.resume_flags(state)
            if dry_run:
                print(f"  {cfg.run_name}: {state}\n    python -m jaxsocial.train {' '.join(flags)}")
            elif state != rundirs.FINISHED:
                jobs.append(pinned.Job(cfg.run_name, pinned.train_command(flags), run_dir))
    print(f"[{design.name}] branches: " + ", ".join(f"{n} {state}" for state, n in counts.items()))
    pending = counts[rundirs.PARTIAL] + counts[rundirs.MISSING]
    starting = min(pending, max_runs or pending)
    pace = run_times.recorded_pace(records_root / design.out, starting, len(cores)) if pending else None
    if pace:
        print(f"[{design.name}] at the pace of its records: {pace}")
    if dry_run or not jobs:
        return []
    return pinned.run(pinned.first_runs(jobs, max_runs), cores, design.xla_flags)


def record(design: BranchDesign, runs_root: Path, records_root: Path) -> list[Path]:
    """Pack every finished branch under `runs_root` that has no record yet into the records root, with its
    process's provenance (the machine it measured); every one is checked before the first is written."""
    packing, not_started = [], 0
    for seed in design.source_seeds():
        for arm in design.arms:
            name = design.run_name(arm, seed)
            run_dir, target = runs_root / name, records_root / name
            if target.exists():
                continue
            state = rundirs.branch_state(run_dir, design.iterations)
            not_started += state == rundirs.MISSING
            if state == rundirs.PARTIAL:
                print(f"  {name}: not finished, not recorded")
            if state != rundirs.FINISHED:
                continue
            try:
                run_info = pinned.run_provenance(run_dir, None, None)
            except pinned.RunNotEnded as err:
                print(f"  {name}: {err}; not recorded")
                continue
            records.packable(run_dir)
            packing.append((run_dir, target, pinned.with_measured(run_info, None, None, run_dir), name))
    if not_started:
        print(f"  {not_started} branches not started under {runs_root}")
    for run_dir, _, run_info, _ in packing:
        if run_info["rc"] != 0:
            raise ValueError(f"{run_dir}: its process exited with {run_info['rc']}; not a result to record")
    for run_dir, target, run_info, name in packing:
        records.pack(run_dir, target, run_info, name)
        print(f"recorded {run_dir} -> {target}")
    return [target for _, target, _, _ in packing]


# ----------------------------------------------------------------------------------------------------------
# Analyse: scores, tests, checks
# ----------------------------------------------------------------------------------------------------------


def final_scores(design: BranchDesign, records_root: Path) -> dict[str, dict[str, list]]:
    """Per arm, per evaluation environment, every source seed's final evaluation (None: not recorded); and
    where the branches started (`start_scores`)."""
    out: dict[str, dict[str, list]] = {arm: {env: [] for env in design.eval_envs} for arm in design.arms}
    keys = {env: metrics.eval_key(str(EnvSpec.parse(env))) for env in design.eval_envs}  # as `train` logs
    for arm in design.arms:
        for seed in design.source_seeds():
            record_dir = records_root / design.run_name(arm, seed)
            rows = logs.read_metrics(record_dir) if logs.has_metrics(record_dir) else None
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
        started = [design.record_of(source, seed, records_root) for seed in design.source_seeds()]
        out[start_row(source)] = {
            env: [
                round(kinds.RETURNS.score(logs.read_json(path)), 4) if path.is_file() else None
                for path in (kinds.eval_path(record_dir, env) for record_dir in started)
            ]
            for env in design.eval_envs
        }
    return out


def compare(test: Test, paired: bool, scores: dict[str, dict[str, list]], control: str) -> dict[str, Any]:
    """One test on the seeds both rows have, `test`'s treatment arm against the row `control` (paired: by
    source seed): its p-value (None without data)."""
    a, b = scores[test.treatment][test.env], scores[control][test.env]
    if paired:
        pairs = [(x, y) for x, y in zip(a, b, strict=True) if x is not None and y is not None]
        d = stats.paired_difference([y for _, y in pairs], [x for x, _ in pairs], test.alternative)
        return {"test": "wilcoxon", "n": d["n"], "p": d["wilcoxon_p"], "mean_difference": d["mean"]}
    kept = [[v for v in values if v is not None] for values in (a, b)]
    return {"test": "mann-whitney"} | stats.mann_whitney(kept[0], kept[1], test.alternative)


def tested(
    design: BranchDesign, family: dict[str, Test], scores: dict[str, dict[str, list]], alpha: float
) -> dict:
    """Each test of `family`, Holm-corrected among themselves at `alpha`."""
    out = {
        name: {"env": t.env, "arms": [t.treatment, design.control_row(t)], "alternative": t.alternative}
        | compare(t, design.paired(t), scores, design.control_row(t))
        for name, t in family.items()
    }
    return prereg.holm_family(out, alpha)


def as_designed(design: BranchDesign, records_root: Path) -> dict[str, Any]:
    """Which recorded branches differ from the design (iterations, seed, environment, source) and whether
    every branch is recorded."""
    differing, recorded = [], 0
    for seed in design.source_seeds():
        for arm in design.arms:
            record_dir = records_root / design.run_name(arm, seed)
            if not (record_dir / logs.CONFIG_FILE).is_file():
                continue
            recorded += 1
            got = logs.read_config(record_dir)
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
    recorded = [records_root / design.run_name(a, s) for a in design.arms for s in design.source_seeds()]
    provenance = {
        str(d.relative_to(records_root)): logs.read_json(d / records.PROVENANCE_FILE)
        for d in recorded
        if (d / records.PROVENANCE_FILE).is_file()
    }
    commit = catalogue.design_commit(design.name)
    checks = prereg.commit_checks(commit, {name: p["run"]["commit"] for name, p in provenance.items()})
    designed = as_designed(design, records_root)
    checks |= {"every_branch_recorded": designed["every_branch_recorded"], "differing": designed["differing"]}
    checks["branches_as_designed"] = not designed["differing"]
    block = {
        "commit": commit,
        "alpha": design.alpha,
        "primary": tested(design, design.primary, scores, design.alpha),
        "secondary": tested(design, design.secondary, scores, design.alpha),
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
    when = prereg.commit_time(commit)
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
        "tests": tested(design, amendment.tests, scores, amendment.alpha),
        "checks": checks,
        "valid": all(v for v in checks.values() if isinstance(v, bool)),
    }


def families(block: dict[str, Any]) -> list[tuple[str, dict[str, Any]]]:
    """The tested families of a summary's `preregistered` block: primary, secondary and any amendment's."""
    out = [("primary", block["primary"]), ("secondary", block["secondary"])]
    return out + ([("amendment", block["amendment"]["tests"])] if "amendment" in block else [])


def family_lines(family: str, entries: dict[str, Any], environments: dict[str, Any]) -> list[str]:
    """One line a test of a tested family: its rows' means, p-values and whether it is rejected."""
    lines = []
    for name, entry in entries.items():
        rows = environments[entry["env"]]
        means = ", ".join(f"{a} {rows[a]['mean']}" for a in entry["arms"])
        p = "no data" if entry["p"] is None else f"p = {entry['p']:.4g} (Holm {entry['p_holm']:.4g})"
        rejected = ", rejected" if entry["rejected"] else ""
        lines.append(f"  {family} {name} ({entry['test']}, {entry['env']}): mean {means}; {p}{rejected}")
    return lines


def check_lines(checks: dict[str, Any], indent: str = "  ") -> list[str]:
    """One line a check: yes or NO, or its count."""
    return [f"{indent}{k}: {('yes' if v else 'NO') if isinstance(v, bool) else v}" for k, v in checks.items()]


def verdict(summary: dict[str, Any]) -> str:
    """The summary's tests and checks, for people."""
    block, environments = summary["preregistered"], summary["environments"]
    lines = [f"{summary['design']}: {summary['recorded']} branches recorded; alpha {block['alpha']:g}, Holm"]
    lines += family_lines("primary", block["primary"], environments)
    lines += family_lines("secondary", block["secondary"], environments)
    lines += check_lines({k: v for k, v in block["checks"].items() if isinstance(v, bool)})
    if not block["valid"]:
        lines.append("NOT VALID: the result above does not test the design (see the checks)")
    if "amendment" in block:
        added = block["amendment"]
        lines.append(f"amendment, {added['added']} (Holm among its tests at {added['alpha']:g}):")
        lines += family_lines("amendment", added["tests"], environments) + check_lines(added["checks"])
        if not added["valid"]:
            lines.append("NOT VALID: the amendment's tests do not test it (see its checks)")
    return "\n".join(lines)


def draw(summary: dict[str, Any], path: Path) -> None:
    """One panel per evaluation environment: each arm's mean (and each source's where it started, if
    scored there) with its 95% interval over seeds and a cross per seed; titled with the tests there."""
    plt = plot_figures.pyplot()
    per_env, block = summary["environments"], summary["preregistered"]
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
            for _, entries in families(block)
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


# ----------------------------------------------------------------------------------------------------------
# Plan: the power, simulated from a pilot
# ----------------------------------------------------------------------------------------------------------


def pilot_scores(
    design: BranchDesign, tests: dict[str, Test], sim: dict[str, Any]
) -> dict[str, dict[str, list[float]]]:
    """Per test of `tests`, the pilot's evidence, each oriented so that the effect the test looks for is
    positive: for a paired test the per-seed differences of the exploratory follow-up's branches of its
    social seeds (`pilot_branches`), against the other branch or against where the branch started (the
    follow-up's zero-shot score of its source); otherwise the treatment's per-seed scores there and the
    control's from a committed summary (`pilot_control`: where the arm's source records ended, before any
    further training)."""
    branches = logs.read_json(Path(sim["pilot_branches"]))
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
            summary = logs.read_json(Path(where["summary"]))
            per_seed = summary["conditions"][where["condition"]][where["measure"]]["per_seed"]
            out[name] = {"treatment": treatment, "control": [sign * c for c in per_seed]}
            continue
        out[name] = {"differences": [t - c for t, c in zip(treatment, control, strict=True)]}
    return out


def power_table(
    pilot: dict[str, dict[str, list[float]]],
    seeds: int,
    alpha: float,
    discounts: tuple[float, ...],
    reps: int,
    rng_seed: int = 0,
) -> dict[str, dict[str, float]]:
    """The power of a family of one-sided tests (`pilot_scores`: each effect oriented positive),
    Holm-corrected at `alpha`, with `seeds` source seeds. A paired test (`differences`) is Wilcoxon's on
    `seeds` differences, each with probability d (the discount) a pilot difference, else one of the pilot's
    magnitudes with a random sign (no effect); an unpaired one is Mann-Whitney's on `seeds` scores an arm,
    a treatment score with probability d a pilot treatment score, else a control one. Returns per discount
    each test's probability of rejection, and that of rejecting all and any of them."""
    from scipy import stats as scipy_stats

    rng = np.random.default_rng(rng_seed)
    names = list(pilot)
    table = {}
    for d in discounts:
        rejected = np.zeros((reps, len(names)), bool)
        for r in range(reps):
            p = []
            for name in names:
                evidence = {k: np.asarray(v, np.float64) for k, v in pilot[name].items()}
                keep = rng.random(seeds) < d
                if "differences" in evidence:
                    diff = rng.choice(evidence["differences"], seeds)
                    diff = np.where(keep, diff, np.abs(diff) * rng.choice([-1.0, 1.0], seeds))
                    stat = scipy_stats.wilcoxon(diff, alternative="greater") if np.any(diff) else None
                    p.append(1.0 if stat is None else stat.pvalue)
                else:
                    t, c = evidence["treatment"], evidence["control"]
                    drawn = np.where(keep, rng.choice(t, seeds), rng.choice(c, seeds))
                    p.append(
                        scipy_stats.mannwhitneyu(drawn, rng.choice(c, seeds), alternative="greater").pvalue
                    )
            rejected[r] = stats.holm_rejects(np.array(p), alpha)
        row = {n: round(float(rejected[:, i].mean()), 3) for i, n in enumerate(names)}
        table[f"discount {d:g}"] = row | {
            "all": round(float(rejected.all(axis=1).mean()), 3),
            "any": round(float(rejected.any(axis=1).mean()), 3),
        }
    return table


def stated_power(design: BranchDesign) -> dict[str, dict[str, float]]:
    """The design's power table, recomputed from its pilot as its `power_simulation` says."""
    sim = design.power_simulation
    pilot = pilot_scores(design, design.primary, sim)
    return power_table(pilot, design.seeds, design.alpha, tuple(sim["discounts"]), sim["reps"])


def amendment_power(design: BranchDesign) -> dict[str, dict[str, float]]:
    """The amendment's power table, recomputed from its pilot as its `power_simulation` says."""
    added = design.amendment
    sim = added.power_simulation
    pilot = pilot_scores(design, added.tests, sim)
    return power_table(pilot, design.seeds, added.alpha, tuple(sim["discounts"]), sim["reps"])


def describe_test(design: BranchDesign, name: str, test: Test) -> str:
    """One test of the design, for people."""
    control = f"where each {test.treatment} branch started" if test.control == START else test.control
    kind = "Wilcoxon, paired" if design.paired(test) else "Mann-Whitney"
    return f"    {name}: {test.treatment} against {control} in {test.env}, {kind}, {test.alternative}"


def power_lines(power: dict[str, dict[str, float]], prefix: str) -> list[str]:
    """One line a discount of a power table, each test's power and that of all and any of them."""
    return [
        f"{prefix}{case}: " + ", ".join(f"{k} {v:.3f}" for k, v in row.items()) for case, row in power.items()
    ]


def describe(design: BranchDesign) -> str:
    """The design, its tests and its power, for people."""
    sim = design.power_simulation
    last = design.seed + design.seeds - 1
    lines = [
        f"{design.name}: from the records {design.records}, seeds {design.seed}..{last}, "
        f"{design.iterations} iterations an arm, branch seeds from {design.branch_seed}, "
        f"$XLA_FLAGS {design.xla_flags!r}",
        *(f"  arm {n}: from {a.source} in {a.env}" for n, a in design.arms.items()),
        f"  evaluated at the end in {', '.join(design.eval_envs)}, {design.episodes} episodes each",
    ]
    for family, tests in (("primary", design.primary), ("secondary", design.secondary)):
        lines.append(f"  {family} (Holm at {design.alpha:g}):")
        lines += [describe_test(design, n, t) for n, t in tests.items()]
    lines.append(f"  power by simulation ({sim['reps']} simulated designs a discount):")
    lines += power_lines(sim["power"], "    ")
    lines.append(
        f"  power: {design.power:.3f} ({sim['planning_test']}, discount {sim['planning_discount']:g})"
    )
    if design.amendment:
        added = design.amendment
        lines.append(f"  amendment, {added.added} (Holm among its tests at {added.alpha:g}):")
        lines += [describe_test(design, n, t) for n, t in added.tests.items()]
        lines += power_lines(added.power_simulation["power"], "    power, ")
    return "\n".join(lines)


def make_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m jaxsocial.experiments", description=__doc__)
    parser.add_argument("action", choices=VERBS)
    parser.add_argument("design", help="a branch design (e.g. mixing)")
    parser.add_argument("--records", default=str(paths.RECORDS), help="root of the records")
    parser.add_argument("--runs-dir", default=str(paths.EXPERIMENT_RUNS), help="root of the run directories")
    parser.add_argument("--science", default=str(paths.SCIENCE), help="where the summary and figure go")
    parser.add_argument("--cores", type=int, nargs="+", default=[0], help="one training process a core")
    parser.add_argument("--dry-run", action="store_true", help="print each branch's state and command")
    parser.add_argument(
        "--max-runs",
        type=pinned.positive_int,
        default=None,
        metavar="N",
        help="run: start only the first N pending branches (those that can end within a sitting)",
    )
    parser.add_argument(
        "--interim", action="store_true", help="figure: summarise before every branch is recorded (unblinds)"
    )
    return parser


def main(argv: list[str] | None = None) -> None:
    args = paths.parse_command(make_parser, argv)
    try:
        design = load(args.design)
        records_root, runs_root, science = Path(args.records), Path(args.runs_dir), Path(args.science)
        if args.action == "power":
            print(describe(design))
        elif args.action == "run":
            codes = run(design, runs_root, args.cores, records_root, args.dry_run, args.max_runs)
            raise SystemExit(max(codes, default=0))
        elif args.action == "record":
            record(design, runs_root, records_root)
        else:
            recorded = as_designed(design, records_root)
            if not recorded["every_branch_recorded"] and not args.interim:
                print(
                    f"[{design.name}] {recorded['recorded']} of {design.seeds * len(design.arms)} branches "
                    "recorded; the results stay blind until every branch is in (--interim shows them now)"
                )
                return
            summary = summarise(design, records_root)
            science.mkdir(parents=True, exist_ok=True)
            logs.write_json(science / f"{design.name}.json", summary)
            draw(summary, science / f"{design.name}.png")
            print(verdict(summary))
            print(f"wrote {science / design.name}.json and .png")
    except (ValueError, FileNotFoundError) as err:
        raise SystemExit(f"error: {err}") from err
