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

The power is simulated from a pilot (`analyse.power.pilot_scores`): paired differences and each arm's
scores, the effect diluted by a discount.

Tests added after a design's runs began, blind (no result seen: `figure` refuses until every branch is in),
are an amendment in `designs/amendments/<name>.json`: a family of their own, Holm-corrected among
themselves, the design's own tests untouched. Their control may be `start`: where each branch started, its
source record scored by the evaluation of the design that made it (`<record>/eval/<env>.json`).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from jaxsocial import stats
from jaxsocial.env import registry
from jaxsocial.experiments.plan import catalogue
from jaxsocial.experiments.plan.catalogue import Test
from jaxsocial.run import jsonio
from jaxsocial.specs import EnvSpec

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
class Amendment:
    """Tests added to a design after its runs began and before any result was seen, with their power."""

    added: str
    """The date, and how many of the design's runs had ended."""
    alpha: float
    tests: dict[str, Test]
    power: float
    power_simulation: dict[str, Any]
    rationale: str


@dataclasses.dataclass(frozen=True, kw_only=True)
class BranchDesign(catalogue.Design):
    """See the module docstring; `seed` and `seeds` are the source records', every arm's source's."""

    KIND = "branch"
    records: str
    """The material: a folder of the records root holding `<condition>-s<k>-<k>` records."""
    out: str
    """The design's folder under the runs root and the records root."""
    branch_seed: int
    iterations: int
    arms: dict[str, Arm]
    eval_envs: tuple[str, ...]
    episodes: int
    primary: dict[str, Test]
    secondary: dict[str, Test]
    xla_flags: str
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

    def describe_test(self, name: str, test: Test) -> str:
        """One test of the design, for people."""
        control = f"where each {test.treatment} branch started" if test.control == START else test.control
        kind = "Wilcoxon, paired" if self.paired(test) else "Mann-Whitney"
        return f"    {name}: {test.treatment} against {control} in {test.env}, {kind}, {test.alternative}"

    def describe(self) -> str:
        sim = self.power_simulation
        lines = [
            f"{self.name}: from the records {self.records}, seeds {self.seed}..{self.last_seed}, "
            f"{self.iterations} iterations an arm, branch seeds from {self.branch_seed}, "
            f"$XLA_FLAGS {self.xla_flags!r}",
            *(f"  arm {n}: from {a.source} in {a.env}" for n, a in self.arms.items()),
            f"  evaluated at the end in {', '.join(self.eval_envs)}, {self.episodes} episodes each",
        ]
        for family, tests in (("primary", self.primary), ("secondary", self.secondary)):
            lines.append(f"  {family} (Holm at {self.alpha:g}):")
            lines += [self.describe_test(n, t) for n, t in tests.items()]
        lines.append(f"  power by simulation ({sim['reps']} simulated designs a discount):")
        lines += catalogue.power_lines(sim["power"], "    ")
        lines.append(
            f"  power: {self.power:.3f} ({sim['planning_test']}, discount {sim['planning_discount']:g})"
        )
        if self.amendment:
            added = self.amendment
            lines.append(f"  amendment, {added.added} (Holm among its tests at {added.alpha:g}):")
            lines += [self.describe_test(n, t) for n, t in added.tests.items()]
            lines += catalogue.power_lines(added.power_simulation["power"], "    power, ")
        return "\n".join(lines)

    @classmethod
    def checked(cls, raw: dict[str, Any]) -> BranchDesign:
        """A branch design from its file's fields, with its amendment if it has one (`designs.load`;
        ValueError if it is invalid)."""
        raw["arms"] = {k: Arm(**v) for k, v in raw["arms"].items()}
        for family in ("primary", "secondary"):
            raw[family] = {k: Test(**v) for k, v in raw[family].items()}
        raw["eval_envs"] = tuple(raw["eval_envs"])
        design = cls(**raw)
        name = design.name
        if catalogue.amendment_path(name).is_file():
            added = jsonio.read_json(catalogue.amendment_path(name))
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
            if test.alternative not in stats.ALTERNATIVES:
                problems.append(f"the alternative must be one of {stats.ALTERNATIVES}")
            if problems:
                raise ValueError(f"design {name}, test {test_name}: {'; '.join(problems)}")
        if not design.primary or design.iterations < 1 or design.seeds < 1:
            raise ValueError(f"design {name}: it needs primary tests, iterations and seeds")
        return design


def start_row(source: str) -> str:
    """The scores' name of the `source` condition's records as they were when branched."""
    return f"{source} at the branch"
