"""A `TrainConfig` written as the `python -m jaxsocial.train` command line that gives it back
(`train.parse_args(config_flags(cfg)) == cfg`): how the experiments derive a run's command from the config
they build with `dataclasses.replace`.

The line is `--preset P --env E --iterations N --seed S --seeds K`, then every other field that differs
from the preset, in the config's field order (nested ones as `--net.hidden 64`); `net.obs` only where
it differs from the observations of the run's environment, which the parser derives
(`with_env_observation`).

The flags of fields renamed since (`LEGACY_FLAGS`, e.g. `--net.chunk` for `--net.frame-batch`) still work,
deprecated: `modern_flags` rewrites them before parsing.
"""

from __future__ import annotations

import dataclasses
import sys
from typing import Any

from jaxsocial.env import registry
from jaxsocial.run import config
from jaxsocial.run.config import PRESETS, TrainConfig

ALWAYS = ("preset", "env", "iterations", "seed", "seeds")
"""Fields written first, even at the preset's value: what a reader of the line looks for first."""


def flag_name(path: str) -> str:
    """'net.conv_channels' -> '--net.conv-channels'."""
    return "--" + path.replace("_", "-")


LEGACY_FLAGS = {
    flag_name(f"{section}.{old}"): flag_name(f"{section}.{new}")
    for section, renames in config.LEGACY_KEYS.items()
    for old, new in renames.items()
}
"""The old flags of fields renamed since (`config.LEGACY_KEYS`) -> today's, e.g. '--ppo.chunk-length' ->
'--ppo.segment-length': still accepted (command lines in older summaries and scripts), deprecated."""


def modern_flags(argv: list[str]) -> list[str]:
    """`argv` with each old flag of `LEGACY_FLAGS` (also as '--flag=value', or with underscores) under its
    name now, and a deprecation message on stderr for each."""
    out = []
    for arg in argv:
        name, eq, value = arg.partition("=")
        new = LEGACY_FLAGS.get(name.replace("_", "-")) if name.startswith("--") else None
        if new is not None:
            print(f"warning: {name} is deprecated (a renamed field); use {new}", file=sys.stderr)
        out.append(arg if new is None else new + eq + value)
    return out


def flag_values(name: str, value: Any) -> list[str]:
    """A field's value as the flag's arguments (text fields by their formatter, tuples one argument per
    entry, None as 'None')."""
    if name in config.TEXT_FIELDS and value is not None:
        return [config.TEXT_FIELDS[name].format(value)]
    if name in config.TEXT_TUPLE_FIELDS:
        return [config.TEXT_TUPLE_FIELDS[name].format(v) for v in value]
    if isinstance(value, tuple):
        return [str(v) for v in value]
    return [str(value)]


def _field_flags(path: str, name: str, value: Any, default: Any, always: bool) -> list[str]:
    """The flags of the field at `path` (a nested config: its own fields'), where `value` differs from
    `default` or `always`."""
    if dataclasses.is_dataclass(value) and name not in config.TEXT_FIELDS:
        out = []
        for field in dataclasses.fields(value):
            inner, inner_default = getattr(value, field.name), getattr(default, field.name)
            out += _field_flags(f"{path}.{field.name}", field.name, inner, inner_default, False)
        return out
    if value == default and not always:
        return []
    if isinstance(value, bool):
        return [flag_name(path if value else _negated(path))]
    return [flag_name(path), *flag_values(name, value)]


def _negated(path: str) -> str:
    head, _, last = path.rpartition(".")
    return f"{head}.no_{last}" if head else f"no_{path}"


def with_env_observation(cfg: TrainConfig) -> TrainConfig:
    """`cfg` with `net.obs` the observations its environment gives (`--env` with `--env-args`: "rgb" or
    "symbolic"); `cfg` itself if that environment cannot be built (`startup.setup` then says why)."""
    try:
        env_params = registry.env_params(cfg.env, cfg.env_args)
    except ValueError:
        return cfg
    return dataclasses.replace(cfg, net=dataclasses.replace(cfg.net, obs=env_params.observation))


def config_flags(cfg: TrainConfig) -> list[str]:
    """The command line of `cfg` (see the module docstring); ValueError for a preset that does not exist."""
    if cfg.preset not in PRESETS:
        raise ValueError(f"unknown preset {cfg.preset!r}; choose one of {sorted(PRESETS)}")
    preset = PRESETS[cfg.preset]
    derived_obs = with_env_observation(dataclasses.replace(cfg, net=preset.net)).net.obs  # as parsed
    reference = dataclasses.replace(preset, net=dataclasses.replace(preset.net, obs=derived_obs))
    names = [*ALWAYS, *(f.name for f in dataclasses.fields(cfg) if f.name not in ALWAYS)]
    flags = []
    for name in names:
        value, default = getattr(cfg, name), getattr(reference, name)
        flags += _field_flags(name, name, value, default, name in ALWAYS)
    return flags
