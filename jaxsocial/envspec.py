"""Environment specs 'NAME' or 'NAME:field=value,...' (evaluation environments, `--env` of the tools) and
the check of a training run's evaluation environments, without the evaluation code (`jaxsocial.evaluate`)."""

from __future__ import annotations

import jaxsocial
from jaxsocial import schedule
from jaxsocial.env.types import EnvParams


def parse_env_spec(spec: str) -> EnvParams:
    """The parameters of an environment 'NAME' or 'NAME:field=value,...' (ValueError if bad)."""
    name, _, args = spec.partition(":")
    return jaxsocial.make(name.strip(), **schedule.parse_assignments(args))[1]


def check_eval_envs(specs: tuple[str, ...], net, episodes: int) -> list[tuple[str, EnvParams]]:
    """(spec, parameters) of each evaluation environment of a training run (`TrainConfig.eval_envs`), checked
    for a network `net` (`NetworkConfig`) to act in and `episodes` >= 1: ValueError otherwise."""
    if episodes < 1:
        raise ValueError(f"eval_episodes={episodes} must be >= 1")
    parsed = []
    for spec in specs:
        env_params = parse_env_spec(spec)
        net.check_env(env_params, f"eval env {spec!r}")
        parsed.append((spec, env_params))
    return parsed
