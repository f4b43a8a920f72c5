"""What a scripted expert is, as `--slots` names it: its kind and its imperfections (`ExpertSpec`, read by
`parse_expert`), and whether it can play an environment (`check_playable`). Plain Python, no JAX: a run's
slots are read and checked before JAX is imported; `jaxsocial.agents.experts` registers `ExpertSpec` with JAX
and makes the experts act.
"""

from __future__ import annotations

import dataclasses

from jaxsocial import syntax
from jaxsocial.env.params import EnvParams

KINDS = ("explorer", "oracle", "navigator")


@dataclasses.dataclass(frozen=True)
class ExpertSpec:
    """A scripted expert (hashable; static under jit, as `jaxsocial.agents.experts` registers it).

    Attributes:
        kind: 'explorer', 'oracle' or 'navigator'.
        epsilon: per-step probability of a uniformly random action.
        forget: per-step probability of forgetting the cycle order (explorer, oracle; see
            `jaxsocial.agents.experts`).
    """

    kind: str
    epsilon: float = 0.0
    forget: float = 0.0

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"unknown expert kind {self.kind!r}; choose one of {KINDS}")
        for name in ("epsilon", "forget"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float) or not 0.0 <= value <= 1.0:
                raise ValueError(f"expert {name}={value!r} must be a probability in [0, 1]")

    def __str__(self) -> str:
        """'kind' or 'kind:field=value,...' (the fields off their defaults), as `parse_expert` reads it."""
        fields = [f for f in dataclasses.fields(self)[1:] if getattr(self, f.name) != f.default]
        changed = syntax.format_assignments((f.name, getattr(self, f.name)) for f in fields)
        return f"{self.kind}:{changed}" if changed else self.kind


def parse_expert(text: str) -> ExpertSpec:
    """Parse 'kind' or 'kind:field=value,...', e.g. 'explorer:epsilon=0.1,forget=0.02'.

    Raises ValueError for an unknown kind or field, a malformed item or a value outside [0, 1].
    """
    kind, rest = syntax.split_name(text)
    kind = kind.strip()
    if kind not in KINDS:
        raise ValueError(f"unknown expert kind {kind!r} in {text!r}; choose one of {KINDS}")
    fields = [f.name for f in dataclasses.fields(ExpertSpec) if f.name != "kind"]
    values: dict[str, float] = {}
    try:
        assignments = syntax.parse_assignments(rest)
    except ValueError as error:
        raise ValueError(f"expert {text!r}: {error}") from None
    for name, value in assignments:
        if name not in fields:
            raise ValueError(f"unknown expert field {name!r} in {text!r}; valid fields: {', '.join(fields)}")
        if name in values:
            raise ValueError(f"expert field {name!r} given twice in {text!r}")
        try:
            number = float(value)
        except ValueError:
            raise ValueError(f"expert {name}={value!r} in {text!r} is not a number") from None
        if not 0.0 <= number <= 1.0:
            raise ValueError(f"expert {name}={number} in {text!r} must be a probability in [0, 1]")
        values[name] = number
    return ExpertSpec(kind, **values)


def check_playable(spec: ExpertSpec, env_params: EnvParams) -> None:
    """Raise ValueError unless the expert can play the environment."""
    if spec.kind in ("explorer", "oracle"):
        if env_params.layout != "goalcycle" or env_params.n_goals < 2:
            raise ValueError(
                f"the {spec.kind} expert plays Goal Cycle with n_goals >= 2; got layout "
                f"{env_params.layout!r} with n_goals={env_params.n_goals}"
            )
    elif env_params.layout not in ("fourrooms", "maze"):
        raise ValueError(f"the navigator expert plays 'fourrooms' or 'maze', not {env_params.layout!r}")
