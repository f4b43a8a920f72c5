"""Pre-registered designs over committed records: which records' final policies play which environments,
zero-shot, and how the arms are compared, fixed in `designs/<name>.json` before any of its
evaluations runs. Nothing trains: the material is a finished design's records, every seed of its two arms.

    python -m jaxsocial.experiments power transfer      # the design and its power
    python -m jaxsocial.experiments run transfer        # play what is missing (blind)
    python -m jaxsocial.experiments figure transfer     # summary, tests and figure

Every evaluation plays all of an arm's records in one `jaxsocial.evaluate` call (the same `episodes`
episodes, evaluation seed `eval_seed`, for each record); its result, whose slot 0 holds each record's mean
learner return per episode (`per_seed_mean`), is written to `<out>/<env tag>-<arm or reference>.json` and
the process that made it to `<out>/provenance.jsonl` (commit, date, machine). A test is a one-sided (or
two-sided) Mann-Whitney U test of the treatment's per-seed scores against the control's in one environment;
the primary tests are Holm-corrected at `alpha` as a family, the secondary ones among themselves. References
(e.g. a random walker, behaviour cloning) are played in every tested environment and only reported.

The power is simulated from a pilot on other records (`power_table`): each arm's per-seed scores in the
primary environments, resampled per seed, the treatment's effect diluted by a discount.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from jaxsocial import stats
from jaxsocial.env import registry
from jaxsocial.experiments.plan import catalogue, paths
from jaxsocial.experiments.plan.catalogue import Test
from jaxsocial.specs import EnvSpec

PROVENANCE = "provenance.jsonl"
"""The log of the processes that played a design's evaluations, one JSON line each, in its `out_dir`."""


@dataclasses.dataclass(frozen=True)
class Reference:
    """A row played in every tested environment and only reported: a record's policy (`ckpt`, relative to
    the records root) in the learner slot, or a scripted slot in its place (`slot`, e.g. 'random'), the
    environment's other slots as they are."""

    ckpt: str | None = None
    slot: str | None = None
    label: str = ""


@dataclasses.dataclass(frozen=True)
class EvaluationDesign:
    """See the module docstring."""

    name: str
    records: str
    """The material: a folder of the records root holding `<condition>-s<k>-<k>` records."""
    treatment: str
    control: str
    seed: int
    seeds: int
    """Every seed seed..seed+seeds-1 of both conditions, none left out."""
    episodes: int
    eval_seed: int
    alpha: float
    primary: dict[str, Test]
    secondary: dict[str, Test]
    references: dict[str, Reference]
    power: float
    power_simulation: dict[str, Any]
    rationale: str

    def record_dirs(self, condition: str, records_root: Path) -> list[Path]:
        """The records of `condition`, seed by seed."""
        folder = records_root / self.records
        return [folder / f"{condition}-s{s}-{s}" for s in range(self.seed, self.seed + self.seeds)]

    @property
    def tests(self) -> dict[str, Test]:
        return {**self.primary, **self.secondary}


def load(name: str) -> EvaluationDesign:
    """The evaluation design `designs/<name>.json` (FileNotFoundError if none; ValueError if invalid or of
    another kind)."""
    raw = catalogue.read(name, "evaluation")
    for family in ("primary", "secondary"):
        raw[family] = {k: Test(**v) for k, v in raw[family].items()}
    raw["references"] = {k: Reference(**v) for k, v in raw["references"].items()}
    design = EvaluationDesign(**raw)
    for name_, test in design.tests.items():
        spec = EnvSpec.parse(test.env)
        registry.env_params(spec.name, spec.args)  # ValueError for an unknown environment or field
        if test.alternative not in stats.ALTERNATIVES:
            raise ValueError(f"design {name}: test {name_}'s alternative must be one of {stats.ALTERNATIVES}")
        if test.treatment or test.control:
            raise ValueError(f"design {name}: test {name_} compares the design's treatment and control")
    for name_, ref in design.references.items():
        if (ref.ckpt is None) == (ref.slot is None):
            raise ValueError(f"design {name}: reference {name_} needs exactly one of ckpt and slot")
    if not design.primary or design.treatment == design.control:
        raise ValueError(f"design {name}: it needs primary tests and two different arms")
    return design


def out_dir(design: EvaluationDesign, science: Path) -> Path:
    return science / design.name


def envs(design: EvaluationDesign) -> list[str]:
    """Every environment the design plays, once each, in the order its tests name them."""
    return list(dict.fromkeys(t.env for t in design.tests.values()))


@dataclasses.dataclass(frozen=True)
class Play:
    """A play: one `jaxsocial.evaluate` call: who (`ckpts`, or a scripted `slot`) plays where."""

    env: str
    player: str
    """The arm's condition or the reference's name."""
    ckpts: tuple[str, ...]
    slot: str | None

    def path(self, out: Path) -> Path:
        return out / f"{paths.env_tag(self.env)}-{self.player}.json"


def evaluations(design: EvaluationDesign, records_root: Path) -> list[Play]:
    """What the design plays: both arms and every reference in every environment its tests name."""
    out = []
    for env in envs(design):
        for condition in (design.treatment, design.control):
            ckpts = tuple(str(d) for d in design.record_dirs(condition, records_root))
            out.append(Play(env, condition, ckpts, None))
        for name, ref in design.references.items():
            ckpts = (str(records_root / ref.ckpt),) if ref.ckpt else ()
            out.append(Play(env, name, ckpts, ref.slot))
    return out


def describe(design: EvaluationDesign) -> str:
    """The design, its tests and its power, for people."""
    sim = design.power_simulation
    lines = [
        f"{design.name}: the records {design.records}, {design.treatment} against {design.control}, seeds "
        f"{design.seed}..{design.seed + design.seeds - 1}; {design.episodes} episodes an evaluation",
        f"  primary (Holm at {design.alpha:g}):",
        *(f"    {n}: {t.env}, Mann-Whitney {t.alternative}" for n, t in design.primary.items()),
        "  secondary (Holm among themselves):",
        *(f"    {n}: {t.env}, Mann-Whitney {t.alternative}" for n, t in design.secondary.items()),
        f"  references: {', '.join(design.references)}",
        f"  power by simulation from {sim['pilot']} ({sim['reps']} simulated designs a discount):",
        *(
            f"    {case}: " + ", ".join(f"{k} {v:.3f}" for k, v in p.items())
            for case, p in sim["power"].items()
        ),
        f"  power: {design.power:.3f} (any primary test rejected, discount {sim['planning_discount']:g})",
    ]
    return "\n".join(lines)
