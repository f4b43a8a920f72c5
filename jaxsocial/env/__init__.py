"""Pure-functional multi-agent gridworlds (Goal Cycle, Four Rooms, Maze) in JAX."""

from jaxsocial.env.core import Env, reset, state_from_layout, step, step_batch, step_env
from jaxsocial.env.registry import PRESETS, make, registered_envs
from jaxsocial.env.types import EnvParams, EnvState

__all__ = [
    "PRESETS",
    "Env",
    "EnvParams",
    "EnvState",
    "make",
    "registered_envs",
    "reset",
    "state_from_layout",
    "step",
    "step_batch",
    "step_env",
]
