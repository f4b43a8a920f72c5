"""Pre-registered designs: what a recipe will compare, fixed in a committed file before any of its runs.

A design is `designs/<name>.json` beside this module: the arms (conditions pooled per arm), the seeds and
the budget, the "learned" threshold on a seed's final return, the test, alpha, and the power under a stated
success rate. A design whose `analysis` is 'takeoff' states instead two primary tests, Holm-corrected: the
time to takeoff (`takeoff`, one-sided log-rank) and the per-seed zero-shot return beside the experts in
4-goal Goal Cycle (one-sided Mann-Whitney U), with secondary tests, the episodes of every evaluation after
training, and its power by simulation from committed seeds (`takeoff_power`).

The design's commit is the last commit that changed that file (`catalogue.design_commit`); `figure` checks
that it is an ancestor of every run's recorded commit and writes what its tests found into the summary
(`jaxsocial.experiments.analyse.design_results`).

    python -m jaxsocial.experiments power h1_prereg      # the design's power, and how it was computed
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from jaxsocial import stats
from jaxsocial.experiments.plan import catalogue, recipes, xla_flags
from jaxsocial.run import jsonio

ANALYSES = ("counts", "takeoff", "zero_shot")
ZERO_SHOT_TEST = "mannwhitney-greater"
"""A 'zero_shot' design's primary test: one-sided Mann-Whitney U of the arms' per-seed zero-shot returns."""
LEARNED_BY = ("final_return", "takeoff")
SECONDARY_MEASURES = ("learned", "above_experts")
TAKEOFF_TEST = "holm(logrank-greater, mannwhitney-greater)"
"""A 'takeoff' design's primary family: the one-sided log-rank test of the takeoffs and the one-sided
Mann-Whitney U test of the per-seed 4-goal returns, Holm-corrected at the design's alpha."""


@dataclasses.dataclass(frozen=True, kw_only=True)
class TrainingDesign(catalogue.Design):
    """A pre-registered comparison of conditions a recipe trains (see the module docstring); `seed` and
    `seeds` are each trained condition's; `power` is the test's under `hazard_per_million` (`power_of`), or
    for a 'takeoff' design the takeoff test's at the planning discount (`power_simulation`)."""

    KIND = "training"
    scale: str
    """The scale the design runs at (`recipes.SCALES`)."""
    iterations: int
    """Training iterations of every run (replaces the scale's)."""
    treatment: tuple[str, ...]
    """Conditions pooled into the treatment arm."""
    control: tuple[str, ...]
    """Conditions pooled into the control arm."""
    learned_threshold: float
    """A seed has learned if its final return exceeds this."""
    test: str
    hazard_per_million: dict[str, float]
    """Assumed constant hazard of learning per million env-steps, per arm ('treatment', 'control'); empty
    for a 'takeoff' design."""
    analysis: str = "counts"
    """'counts': one exact test of learned-seed counts (`test`); 'takeoff': the tests of `tests`; 'zero_shot':
    one Mann-Whitney test of the arms' per-seed returns in `tests['primary']`'s environment."""
    tests: dict[str, Any] = dataclasses.field(default_factory=dict)
    """A 'takeoff' design's tests: {'primary': {name: statement}, 'secondary': {...}, 'correction': ...}. A
    'zero_shot' design's: {'primary': {name: {'env', 'alternative', 'statement'}}, 'borrowed_scores': the
    evaluation design whose evaluation of that environment scores the borrowed arm, with the same episodes
    and evaluation seed as this design's own evaluations}."""
    eval_episodes: int | None = None
    """Episodes of every evaluation after training (None: the scale's)."""
    seeds_per_program: int | None = None
    """How its seeds run: 1, each seed a one-seed program in a single-core process of its own (`run
    --cores`); K > 1, each K consecutive seeds of a condition one vmapped program (`run --vmap-seeds K`,
    e.g. on a GPU); None (designs before this field): as their rationale says. Either way each seed is
    recorded on its own."""
    training_commit: str | None = None
    """The commit every run is trained at (from a worktree of it): `figure` requires each record's commit to
    be this one. None (designs before this field): each run's commit must follow the design's."""
    xla_flags: str | None = None
    """XLA flags every training process of the design adds after the single-core ones, and every seed's
    recorded flags must hold (`design_results.seed_problems`): `pinned.CROSS_CPU_XLA_FLAGS` for designs
    since 2026-11-28, so that a seed trains bit for bit alike on the CPU kinds measured. None (designs
    before this field): XLA's defaults, whose bits differ between CPU models."""
    borrowed: dict[str, str] = dataclasses.field(default_factory=dict)
    """Arms whose seeds an earlier design trained: arm ('treatment' or 'control') -> that design's name. Such
    an arm's conditions are read from the other design's records at its seeds, budget and folder, and are
    never trained by this design; they must be conditions of the same arm there."""
    learned_by: str = "final_return"
    """What makes a seed count as learned: 'final_return' (its final return exceeds `learned_threshold`) or
    'takeoff' (it took off, `takeoff.seed_takeoff` at `learned_threshold`, within the design's iterations;
    borrowed arms are counted the same way)."""
    secondary: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)
    """A 'counts' design's secondary tests, Holm-corrected among themselves at `alpha`: name -> {'statement',
    'arm' (this design's 'treatment' or 'control'), 'against' ('DESIGN:ARM', an arm of a finished design,
    read from its records), 'measure' ('learned', as `learned_by` counts; or 'above_experts', the seeds whose
    final return exceeds their own experts' final return in the same run), 'alternative' (Boschloo's
    'greater', 'less' or 'two-sided')}."""
    stop_at_return: float | None = None
    """Each seed's run ends early at the first chunk whose learner return reaches this
    (`DriverConfig.stop_at_return`; None: every run trains all its iterations). Only with
    `learned_by` 'takeoff', which an early stop cannot change once the seed has taken off."""

    @property
    def arm_seeds(self) -> dict[str, int]:
        """Each arm's seeds: its conditions times the seeds of the design that trains them."""
        return {
            arm: len(getattr(self, arm))
            * (TrainingDesign.read(self.borrowed[arm]).seeds if arm in self.borrowed else self.seeds)
            for arm in ("treatment", "control")
        }

    @property
    def recipe(self) -> recipes.Recipe:
        """The recipe that carries the design (of its name)."""
        return recipes.RECIPES[self.name]

    @property
    def env_steps_per_run(self) -> int:
        """Env-steps of each run: its iterations at its scale, in its recipe's first condition."""
        scale = recipe_scale(self.recipe, recipes.SCALES[self.scale])
        cfg = recipes.condition_config(scale, self.recipe.conditions[0], self.seed, self.seeds, "runs")
        return scale.iterations * cfg.num_envs * cfg.rollout_steps

    def describe(self) -> str:
        describe = {"takeoff": _describe_takeoff, "zero_shot": _describe_zero_shot}
        return describe.get(self.analysis, _describe_counts)(self, self.env_steps_per_run)

    @property
    def trained_conditions(self) -> tuple[str, ...]:
        """The conditions this design trains: those of its arms that are not `borrowed`."""
        return tuple(
            c for arm in ("treatment", "control") if arm not in self.borrowed for c in getattr(self, arm)
        )

    @classmethod
    def checked(cls, raw: dict[str, Any]) -> TrainingDesign:
        """A training design from its file's fields (`designs.load`; ValueError if it is invalid)."""
        for arm in ("treatment", "control"):
            raw[arm] = tuple(raw[arm])
        design = cls(**raw)
        name = design.name
        if design.analysis not in ANALYSES:
            raise ValueError(f"design {name}: unknown analysis {design.analysis!r}; choose from {ANALYSES}")
        tests = {"counts": stats.TESTS, "takeoff": (TAKEOFF_TEST,), "zero_shot": (ZERO_SHOT_TEST,)}[
            design.analysis
        ]
        if design.test not in tests:
            raise ValueError(f"design {name}: unknown test {design.test!r}; choose from {tests}")
        if set(design.treatment) & set(design.control) or not design.treatment or not design.control:
            raise ValueError(f"design {name}: the arms must be disjoint and non-empty")
        if design.xla_flags is not None:
            xla_flags.normalised(design.xla_flags, f"design {name}'s xla_flags")
        if design.learned_by not in LEARNED_BY:
            raise ValueError(
                f"design {name}: unknown learned_by {design.learned_by!r}; choose from {LEARNED_BY}"
            )
        if design.stop_at_return is not None and design.learned_by != "takeoff":
            raise ValueError(f"design {name}: an early stop (stop_at_return) needs learned_by 'takeoff'")
        if len(design.borrowed) > 1:
            raise ValueError(f"design {name}: at most one arm may be borrowed (it trains the other)")
        for arm, source in design.borrowed.items():
            if arm not in ("treatment", "control") or source == name:
                raise ValueError(
                    f"design {name}: borrowed arm {arm!r} from {source!r}: name the other arm's design"
                )
            lender = TrainingDesign.read(source)
            if not set(getattr(design, arm)) <= set(getattr(lender, arm)):
                raise ValueError(
                    f"design {name}: its {arm} {getattr(design, arm)} is not among {source}'s {arm}"
                )
        for test_name, test in design.secondary.items():
            other, _, other_arm = test["against"].partition(":")
            if test["arm"] not in ("treatment", "control") or other_arm not in ("treatment", "control"):
                raise ValueError(f"design {name}: secondary {test_name} names an unknown arm")
            if test["measure"] not in SECONDARY_MEASURES or test["alternative"] not in stats.ALTERNATIVES:
                raise ValueError(
                    f"design {name}: secondary {test_name}: a measure of {SECONDARY_MEASURES} and an "
                    "alternative"
                )
            TrainingDesign.read(other)
        return design


def deviations(name: str, directory: Path) -> list[dict[str, str]]:
    """The recorded deviations of design `name` ([] where there are none): `directory/<name>.json`, what
    happened to its runs that its rules did not foresee ({"deviations": [{"date", "what"}, ...]}), carried
    into its summary's `preregistered` block and verdict."""
    path = directory / f"{name}.json"
    return jsonio.read_json(path)["deviations"] if path.is_file() else []


def recipe_scale(recipe: recipes.Recipe, scale: recipes.Scale) -> recipes.Scale:
    """The scale `recipe` runs at: `scale`, with the design's iterations, early stop and its own runs folder
    (`Scale.runs_subdir`) where the recipe carries a design for this scale."""
    if recipe.design is None:
        return scale
    design = TrainingDesign.read(recipe.design)
    if design.scale != scale.name:
        return scale
    budget = {"iterations": design.iterations, "stop_at_return": design.stop_at_return}
    return dataclasses.replace(
        scale,
        config=dataclasses.replace(scale.config, **budget),
        eval_episodes=design.eval_episodes or scale.eval_episodes,
        runs_subdir=f"prereg-{design.name}",
    )


def success_rates(design: TrainingDesign, env_steps_per_run: int) -> dict[str, float]:
    """Each arm's assumed probability that a seed has learned by the end of its run."""
    return {arm: stats.learned_by(h, env_steps_per_run) for arm, h in design.hazard_per_million.items()}


def power_of(design: TrainingDesign, env_steps_per_run: int) -> float:
    """The design's power: the probability that its test rejects at its alpha under its assumed rates."""
    rates = success_rates(design, env_steps_per_run)
    n = design.arm_seeds
    return stats.power(design.test, n["treatment"], rates["treatment"], n["control"], rates["control"],
                        design.alpha)  # fmt: skip


def _describe_counts(design: TrainingDesign, env_steps_per_run: int) -> str:
    """A 'counts' design and its power, for people."""
    rates = success_rates(design, env_steps_per_run)
    n = design.arm_seeds
    last = design.seed + design.seeds - 1
    learned = {
        "final_return": f"final return > {design.learned_threshold:g}",
        "takeoff": f"took off (a window's return > {design.learned_threshold:g}) within the budget",
    }[design.learned_by]
    stop = "" if design.stop_at_return is None else f", each run stopping at return {design.stop_at_return:g}"

    def arm(name: str) -> str:
        lender = design.borrowed.get(name)
        source = "" if lender is None else f", borrowed: {lender}'s records, not trained again"
        return f"  {name} ({n[name]} seeds): {', '.join(getattr(design, name))}{source}"

    lines = [
        f"{_budget(design, env_steps_per_run)}{stop}), seeds {design.seed}..{last} per condition trained",
        arm("treatment"),
        arm("control"),
        f"  learned: {learned}; {design.test} at alpha {design.alpha:g}",
        "  assumed P(learned by the end): "
        + ", ".join(
            f"{arm} {rates[arm]:.3f} (hazard {h:g} per 1M env-steps)"
            for arm, h in design.hazard_per_million.items()
        ),  # fmt: skip
        f"  power: {power_of(design, env_steps_per_run):.3f} (the design file says {design.power:.3f})",
    ]
    for test in stats.TESTS:
        power = stats.power(
            test, n["treatment"], rates["treatment"], n["control"], rates["control"], design.alpha
        )
        lines.append(f"    with {test}: {power:.3f}")
    if design.secondary:
        lines.append(f"  secondary (Boschloo, Holm among themselves at {design.alpha:g}):")
    for name, test in design.secondary.items():
        lines.append(
            f"    {name}: {test['measure']}, {test['arm']} against {test['against']}, {test['alternative']}"
        )
    return "\n".join(lines)


def _budget(design: TrainingDesign, env_steps_per_run: int, digits: int = 1) -> str:
    """The first words of a design's description: its name, scale and budget, up to the parenthesis."""
    return (
        f"{design.name}: {design.scale} scale, {design.iterations} iterations "
        f"({env_steps_per_run / 1e6:.{digits}f}M env-steps per seed"
    )


def _describe_takeoff(design: TrainingDesign, env_steps_per_run: int) -> str:
    """A 'takeoff' design, its tests and its simulated power, for people."""
    last = design.seed + design.seeds - 1
    sim = design.power_simulation
    lines = [
        f"{_budget(design, env_steps_per_run, digits=2)}), seeds {design.seed}..{last} per condition",
        f"  treatment: {', '.join(design.treatment)}; control: {', '.join(design.control)}",
        f"  primary ({design.tests.get('correction', '')}, alpha {design.alpha:g}):",
        *(f"    {name}: {text}" for name, text in design.tests.get("primary", {}).items()),
        "  secondary:",
        *(f"    {name}: {text}" for name, text in design.tests.get("secondary", {}).items()),
        f"  power by simulation ({sim.get('reps')} simulated designs each, evidence seeds "
        f"{sim.get('evidence_seeds')}):",
        *(
            f"    {case}: takeoff {p['takeoff']:.3f}, 4-goal {p['goalcycle4']:.3f}, both {p['both']:.3f}"
            for case, p in sim.get("power", {}).items()
        ),
        f"  power: {design.power:.3f} (the takeoff test at {design.seeds} seeds an arm, discount "
        f"{sim.get('planning_discount')})",
    ]
    return "\n".join(lines)


def _describe_zero_shot(design: TrainingDesign, env_steps_per_run: int) -> str:
    """A 'zero_shot' design, its test and its power, for people."""
    last = design.seed + design.seeds - 1
    sim = design.power_simulation
    lines = [
        f"{_budget(design, env_steps_per_run)}), seeds {design.seed}..{last} trained",
        *(
            f"  {arm}: {', '.join(getattr(design, arm))}"
            + (f", borrowed: {design.borrowed[arm]}'s records" if arm in design.borrowed else "")
            for arm in ("treatment", "control")
        ),
        *(
            f"  primary: {name}, {t['env']}, Mann-Whitney {t['alternative']} at alpha {design.alpha:g}, "
            f"{design.eval_episodes} episodes a policy"
            for name, t in design.tests["primary"].items()
        ),
        f"  the borrowed arm's scores: the evaluation design {design.tests['borrowed_scores']}",
        f"  power ({sim['method']}): " + ", ".join(f"{k} {v:.3f}" for k, v in sim["power"].items()),
        f"  power: {design.power:.3f}",
    ]
    return "\n".join(lines)
