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

The power is simulated from a pilot on other records (`analyse.power`): each arm's per-seed scores in the
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


@dataclasses.dataclass(frozen=True, kw_only=True)
class EvaluationDesign(catalogue.Design):
    """See the module docstring; `seed` and `seeds` are the records' of both conditions."""

    KIND = "evaluation"
    records: str
    """The material: a folder of the records root holding `<condition>-s<k>-<k>` records."""
    treatment: str
    control: str
    episodes: int
    eval_seed: int
    primary: dict[str, Test]
    secondary: dict[str, Test]
    references: dict[str, Reference]

    def record_dirs(self, condition: str, records_root: Path) -> list[Path]:
        """The records of `condition`, seed by seed."""
        folder = records_root / self.records
        return [folder / f"{condition}-s{s}-{s}" for s in self.seed_range]

    @property
    def tests(self) -> dict[str, Test]:
        return {**self.primary, **self.secondary}

    def describe(self) -> str:
        sim = self.power_simulation
        lines = [
            f"{self.name}: the records {self.records}, {self.treatment} against {self.control}, seeds "
            f"{self.seed}..{self.last_seed}; {self.episodes} episodes an evaluation",
            f"  primary (Holm at {self.alpha:g}):",
            *(f"    {n}: {t.env}, Mann-Whitney {t.alternative}" for n, t in self.primary.items()),
            "  secondary (Holm among themselves):",
            *(f"    {n}: {t.env}, Mann-Whitney {t.alternative}" for n, t in self.secondary.items()),
            f"  references: {', '.join(self.references)}",
            f"  power by simulation from {sim['pilot']} ({sim['reps']} simulated designs a discount):",
            *catalogue.power_lines(sim["power"], "    "),
            f"  power: {self.power:.3f} (any primary test rejected, discount {sim['planning_discount']:g})",
        ]
        return "\n".join(lines)

    @classmethod
    def checked(cls, raw: dict[str, Any]) -> EvaluationDesign:
        """An evaluation design from its file's fields (`designs.load`; ValueError if it is invalid)."""
        for family in ("primary", "secondary"):
            raw[family] = {k: Test(**v) for k, v in raw[family].items()}
        raw["references"] = {k: Reference(**v) for k, v in raw["references"].items()}
        design = cls(**raw)
        name = design.name
        for name_, test in design.tests.items():
            spec = EnvSpec.parse(test.env)
            registry.env_params(spec.name, spec.args)  # ValueError for an unknown environment or field
            if test.alternative not in stats.ALTERNATIVES:
                raise ValueError(
                    f"design {name}: test {name_}'s alternative must be one of {stats.ALTERNATIVES}"
                )
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
