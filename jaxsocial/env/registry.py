"""Named presets, `env_params(name, args)` and `make(name, **overrides)`. Only `make` imports JAX (for the
`Env`): a command checks an environment's name and parameters before JAX is imported.

Goal Cycle follows the paper and the choices of docs/environment.md (sections 6 and 9): 13x13, clutter
density 0.1 (12 walls), +1 / -1.5, first tile always rewarded, 250 steps, view offset 1, prestige colours
with beta 0.99. Four Rooms (17x17) and Maze (19x19) have one terminal goal, no clutter, the original's
reward decay `1 - 0.9 t / T`, and 250 steps (docs/environment.md 9.9). `-solo` variants have one agent;
`-distractors` variants add two agent slots for random distractors (paper appendix; docs/environment.md
10.3).
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any

from jaxsocial.env.params import EnvParams

if TYPE_CHECKING:
    from jaxsocial.env.core import Env

DISTRACTOR_SLOTS = 2

_BASE: dict[str, EnvParams] = {
    "goalcycle3": EnvParams(),
    "goalcycle4": EnvParams(n_goals=4),
    "fourrooms": EnvParams(
        layout="fourrooms", width=17, height=17, clutter_density=0.0, reward_decay=True, n_goals=1
    ),
    "maze": EnvParams(layout="maze", width=19, height=19, clutter_density=0.0, reward_decay=True, n_goals=1),
}


def _presets() -> dict[str, EnvParams]:
    presets = {}
    for name, env_params in _BASE.items():
        presets[name] = env_params
        presets[f"{name}-solo"] = env_params.replace(n_agents=1)
        presets[f"{name}-distractors"] = env_params.replace(n_agents=env_params.n_agents + DISTRACTOR_SLOTS)
    return presets


PRESETS = _presets()
PARAM_FIELDS = tuple(f.name for f in dataclasses.fields(EnvParams))


def registered_envs() -> list[str]:
    """Names accepted by `make`."""
    return sorted(PRESETS)


def make(name: str, **overrides) -> tuple[Env, EnvParams]:
    """The environment and parameters of a preset, with any `EnvParams` field overridden.

    >>> env, env_params = make("goalcycle3", penalty=0.5, n_agents=1)

    Raises ValueError for an unknown name or field, or an impossible combination, before compiling anything.
    """
    from jaxsocial.env.core import Env  # JAX's: imported once the parameters are valid

    params = env_params(name, tuple(overrides.items()))
    return Env(name, params), params


def env_params(name: str, args: tuple[tuple[str, Any], ...] = ()) -> EnvParams:
    """The parameters of preset `name` with the overrides `args`, (field, value) pairs as a `specs.EnvSpec`
    holds them: ``env_params(spec.name, spec.args)``. ValueError as `make`."""
    if name not in PRESETS:
        raise ValueError(
            f"unknown environment {name!r}; choose one of: {', '.join(registered_envs())}. Overrides go "
            "after a ':' (goalcycle3:penalty=1.0,width=7), or in --env-args (--env goalcycle3 --env-args "
            "penalty=1.0,width=7): the two are one"
        )
    overrides = dict(args)
    unknown = sorted(set(overrides) - set(PARAM_FIELDS))
    if unknown:
        raise ValueError(f"unknown EnvParams field(s) {unknown}; valid fields: {', '.join(PARAM_FIELDS)}")
    return PRESETS[name].replace(**overrides)
