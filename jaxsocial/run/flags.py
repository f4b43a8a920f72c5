"""A `TrainConfig` written as the `python -m jaxsocial.train` command line that gives it back
(`train.parse_args(config_flags(cfg)) == cfg`): how the experiments derive a run's command from the config
they build with `dataclasses.replace`.

The line is `--preset P --env E --iterations N --seed S --seeds K`, then every other field that differs
from the preset, in the config's field order (nested ones as `--net.hidden 64`); `net.obs` only where
it differs from the observations of the run's environment, which the parser derives.
"""

from __future__ import annotations

import dataclasses
from typing import Any

from jaxsocial.run import config
from jaxsocial.run.config import PRESETS, TrainConfig

ALWAYS = ("preset", "env", "iterations", "seed", "seeds")
"""Fields written first, even at the preset's value: what a reader of the line looks for first."""


def flag_name(path: str) -> str:
    """'net.conv_channels' -> '--net.conv-channels'."""
    return "--" + path.replace("_", "-")


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


def config_flags(cfg: TrainConfig) -> list[str]:
    """The command line of `cfg` (see the module docstring); ValueError for a preset that does not exist."""
    if cfg.preset not in PRESETS:
        raise ValueError(f"unknown preset {cfg.preset!r}; choose one of {sorted(PRESETS)}")
    preset = PRESETS[cfg.preset]
    derived_obs = config.with_env_observation(dataclasses.replace(cfg, net=preset.net)).net.obs  # as parsed
    reference = dataclasses.replace(preset, net=dataclasses.replace(preset.net, obs=derived_obs))
    names = [*ALWAYS, *(f.name for f in dataclasses.fields(cfg) if f.name not in ALWAYS)]
    flags = []
    for name in names:
        value, default = getattr(cfg, name), getattr(reference, name)
        flags += _field_flags(name, name, value, default, name in ALWAYS)
    return flags
