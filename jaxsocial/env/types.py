"""Environment constants, static parameters (`EnvParams`) and the state pytree (`EnvState`). The tile, action,
agent and layout constants and `EnvParams` are `jaxsocial.env.params`' (no JAX), named here too; here
`EnvParams` is registered with JAX.

Conventions (docs/environment.md, section 0): cells are addressed `(x, y)` with x east and y south; grids
are stored row-major as `[y, x]`; directions are 0 east, 1 south, 2 west, 3 north.
"""

from __future__ import annotations

import jax
import numpy as np
from flax import struct

from jaxsocial.env.params import (
    AGENT_COLOR_NAMES,
    BONUS,
    DONE,
    DROP,
    EMPTY,
    FORWARD,
    GOAL,
    LAYOUTS,
    LEFT,
    MAX_AGENTS,
    NUM_ACTIONS,
    NUM_TILE_TYPES,
    PICKUP,
    RIGHT,
    TOGGLE,
    WALL,
    EnvParams,
)

__all__ = [
    "AGENT_COLOR_NAMES",
    "BONUS",
    "COLORS",
    "DIR_VEC",
    "DONE",
    "DROP",
    "EMPTY",
    "FORWARD",
    "GOAL",
    "LAYOUTS",
    "LEFT",
    "MAX_AGENTS",
    "NUM_ACTIONS",
    "NUM_TILE_TYPES",
    "PICKUP",
    "RIGHT",
    "SHADOW",
    "TILE_COLORS",
    "TOGGLE",
    "WALL",
    "EnvParams",
    "EnvState",
]

# Forward vectors (dx, dy) per direction.
DIR_VEC = np.array([[1, 0], [0, 1], [-1, 0], [0, -1]], dtype=np.int32)

# Colours (marlgrid objects.COLORS).
COLORS = {
    "red": (255, 0, 0),
    "orange": (255, 165, 0),
    "green": (0, 255, 0),
    "blue": (0, 0, 255),
    "cyan": (0, 139, 139),
    "purple": (112, 39, 195),
    "yellow": (255, 255, 0),
    "olive": (128, 128, 0),
    "grey": (100, 100, 100),
    "worst": (74, 65, 42),
    "pink": (255, 0, 189),
    "white": (255, 255, 255),
}
SHADOW = (35, 25, 30)
TILE_COLORS = np.array([(0, 0, 0), COLORS["worst"], COLORS["yellow"], COLORS["green"]], dtype=np.uint8)

jax.tree_util.register_static(EnvParams)  # a pytree without leaves: jitted functions take it as any argument


@struct.dataclass
class EnvState:
    """One environment's state; batch it with `jax.vmap`.

    Attributes:
        grid: uint8[H, W] tile types, indexed [y, x]; constant within an episode.
        goal_id: int8[H, W] bonus-tile id (its place in the cycle) or -1.
        pos: int32[N, 2] agent (x, y).
        dir: int32[N] agent direction.
        cycle_state: int32[N] id of the last correctly visited bonus tile, -1 before the first.
        prestige: float32[N] prestige value (docs/environment.md section 5).
        active: bool[N] False once an agent has reached a terminal goal (it then waits on it), and for
            absent agents.
        present: bool[N] the agent takes part in the episode now (False: absent from a solo episode, or
            outside its presence window).
        window: int32[N, 2] steps [join, leave): the agent is present while join <= time < leave (0 and
            `int32 max` unless it drops in or out, docs/environment.md 10.4).
        arrival: int32[N] step at which the agent entered its current cell (0 at spawn); sets draw order.
        time: int32 steps taken in this episode.
    """

    grid: jax.Array
    goal_id: jax.Array
    pos: jax.Array
    dir: jax.Array
    cycle_state: jax.Array
    prestige: jax.Array
    active: jax.Array
    present: jax.Array
    window: jax.Array
    arrival: jax.Array
    time: jax.Array
