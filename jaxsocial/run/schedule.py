"""Training stages: environment settings that change during a run (the paper's penalty curriculum for
experts, the switch from social to mixed solo/social training).

A schedule is a ';'-separated list of stages `WHEN:FIELD=VALUE,...`, where WHEN is

- an iteration `N`: the stage starts at iteration N;
- `return>=X`: the stage starts after the first logged chunk of the previous stage in which the learners'
  mean episode return reached X.

Overrides accumulate: a stage changes only the fields it names. Before the first stage the run uses
`--env-args` alone, so a schedule that does not start at iteration 0 begins with the plain environment.

    "0:penalty=0.5;return>=20:penalty=1.0;return>=20:penalty=1.5"   # penalty curriculum
    "5000:solo_prob=0.75"                                             # 100% social, then 75% solo

Each stage is its own compiled program (`EnvParams` are static); the training state carries over, so a
stage may not change what sets array shapes (see `STRUCTURAL_FIELDS`).
"""

from __future__ import annotations

import dataclasses
from typing import Any

from jaxsocial import syntax
from jaxsocial.specs import ENV_ARGS

STRUCTURAL_FIELDS = ("layout", "width", "height", "n_agents", "n_goals", "view_size", "observation")
"""EnvParams fields that set array shapes (a stage may not change them)."""


@dataclasses.dataclass(frozen=True)
class Stage:
    """One stage: it starts at iteration `start`, or once the learners' return reaches `threshold`."""

    overrides: tuple[tuple[str, Any], ...]
    start: int | None = None
    threshold: float | None = None

    def __str__(self) -> str:
        """The stage as `parse_stages` reads it: 'N:field=value,...' or 'return>=X:field=value,...'."""
        when = str(self.start) if self.start is not None else f"return>={self.threshold!r}"
        return f"{when}:{ENV_ARGS.format(self.overrides)}"


def parse_stages(text: str) -> tuple[Stage, ...]:
    """Parse a schedule (see the module docstring). Raises ValueError on bad input."""
    stages: list[Stage] = []
    for item in syntax.split_entries(text, ";"):
        when, rest = syntax.split_name(item)
        when = when.replace(" ", "")
        try:
            overrides = ENV_ARGS.parse(rest)
        except ValueError:
            overrides = ()
        if not overrides:
            raise ValueError(f"stage {item!r} must be 'WHEN:field=value,...' (WHEN: iteration or return>=X)")
        if when.startswith("return>="):
            try:
                stages.append(Stage(overrides, threshold=float(when.removeprefix("return>="))))
            except ValueError:
                raise ValueError(f"stage {item!r}: bad return threshold") from None
            continue
        if not when.isdigit():
            raise ValueError(f"stage {item!r}: WHEN must be an iteration number or return>=X, not {when!r}")
        start = int(when)
        previous = [s.start for s in stages if s.start is not None]
        if stages and (stages[-1].start is None or start <= previous[-1]):
            raise ValueError(
                f"stage {item!r}: iteration stages must come in increasing order, and not after a "
                "return-triggered stage"
            )
        stages.append(Stage(overrides, start=start))
    return tuple(stages)


def format_stages(stages: tuple[Stage, ...]) -> str:
    """The inverse of `parse_stages`."""
    return ";".join(map(str, stages))


def overrides_at(stages: tuple[Stage, ...], index: int) -> dict[str, Any]:
    """The accumulated overrides of stages 0..index (index -1: none)."""
    out: dict[str, Any] = {}
    for stage in stages[: index + 1]:
        out.update(stage.overrides)
    return out


def initial_index(stages: tuple[Stage, ...]) -> int:
    """The stage a fresh run starts in (-1: before the first)."""
    return 0 if stages and stages[0].start == 0 else -1


def next_start(stages: tuple[Stage, ...], index: int) -> int | None:
    """The iteration at which the next stage starts, if it is iteration-triggered."""
    return stages[index + 1].start if index + 1 < len(stages) else None


def advance(stages: tuple[Stage, ...], index: int, iteration: int, learner_return: float | None) -> int:
    """The stage after a chunk that ended at `iteration` with the learners' mean return (None: no episode
    finished). Advances at most one stage per chunk."""
    if index + 1 >= len(stages):
        return index
    following = stages[index + 1]
    if following.start is not None:
        return index + 1 if iteration >= following.start else index
    reached = learner_return is not None and learner_return >= following.threshold
    return index + 1 if reached else index
