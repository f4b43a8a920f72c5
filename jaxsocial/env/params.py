"""The environment's static parameters (`EnvParams`) and the constants they name: tile types, actions, agent
colours, layouts. Plain Python, no JAX: a command checks its environment before it imports JAX.
`jaxsocial.env.types` registers `EnvParams` with JAX and adds the state pytree.
"""

from __future__ import annotations

import dataclasses
from typing import NoReturn

# Tile types (docs/environment.md 1.1). Agents are not tiles: they live in `EnvState.pos` and overlap freely.
EMPTY, WALL, BONUS, GOAL = 0, 1, 2, 3
NUM_TILE_TYPES = 4

# Actions (docs/environment.md 2.1). 3-6 are no-ops in every environment here.
LEFT, RIGHT, FORWARD, PICKUP, DROP, TOGGLE, DONE = range(7)
NUM_ACTIONS = 7

# Default fixed agent colours (marlgrid register_marl_env; `types.COLORS`); also bounds the number of agents.
AGENT_COLOR_NAMES = ("red", "blue", "purple", "orange", "olive", "pink")
MAX_AGENTS = len(AGENT_COLOR_NAMES)

LAYOUTS = ("goalcycle", "fourrooms", "maze")


def _fail(msg: str) -> NoReturn:
    """Raise the ValueError of an invalid `EnvParams`."""
    raise ValueError(f"EnvParams: {msg}")


@dataclasses.dataclass(frozen=True)
class EnvParams:
    """Static environment parameters (hashable; a change recompiles).

    Registered as a pytree without leaves (by `jaxsocial.env.types`), so it can be passed to jitted functions
    like any argument (gymnax style, `in_axes=None` under vmap) and is hashed into the compiled program.

    Every field the paper or docs/environment.md names is here; `jaxsocial.make(name, **overrides)` fills
    them from a preset. Validation happens in `__post_init__`, before anything is compiled.
    """

    layout: str = "goalcycle"
    """Layout generator: 'goalcycle', 'fourrooms' or 'maze'."""
    width: int = 13
    """Grid width in cells, border included."""
    height: int = 13
    """Grid height in cells, border included."""
    n_agents: int = 3
    """Agent slots (1-6)."""
    n_goals: int = 3
    """Goal Cycle bonus tiles (ignored by fourrooms and maze, which have one terminal goal)."""
    clutter_density: float = 0.1
    """Random wall density: `int(density * (W-2) * (H-2))` clutter walls (docs/environment.md 1.2)."""
    goal_reward: float = 1.0
    """Reward for a correct bonus tile or for reaching the goal."""
    penalty: float = 1.5
    """Goal Cycle penalty magnitude (>= 0): a wrong bonus tile pays -penalty."""
    initial_reward: bool = True
    """The first bonus tile of an episode pays `goal_reward` (else 0)."""
    reset_on_mistake: bool = False
    """After a wrong tile the cycle restarts from that tile (master semantics)."""
    reward_decay: bool = False
    """Multiply every tile reward by `1 - 0.9 t / max_steps` (t is the 1-based step)."""
    max_steps: int = 250
    """Episode length limit; the episode is truncated at this step."""
    view_size: int = 7
    """Egocentric view width in cells (odd)."""
    view_offset: int = 1
    """Rows of the view behind the agent; it sees `view_size - 1 - view_offset` rows ahead."""
    tile_size: int = 3
    """Pixels per view cell; only 3 is supported (21x21 observations, docs/environment.md 4.2)."""
    agent_colors: str = "prestige"
    """'prestige' (red to blue with prestige) or 'fixed' (red, blue, purple, orange, olive, pink)."""
    prestige_beta: float = 0.99
    """Prestige decay constant (alpha_c in the paper)."""
    prestige_scale: float = 2.0
    """Colour blend `tanh(prestige / scale)` (code formula)."""
    prestige_formula: str = "code"
    """'code': c = beta (c + r), colour tanh(c / scale); 'paper': c = beta c + r, colour sigmoid(c)."""
    random_spawn_dir: bool = True
    """Draw each agent's initial direction uniformly (docs/environment.md 9.6); else all face east."""
    observation: str = "rgb"
    """'rgb' (uint8[N, 21, 21, 3]) or 'symbolic' (int8[N, V, V, 4])."""
    solo_prob: float = 0.0
    """Probability that an episode is solo: only the first `solo_agents` slots take part; the others are
    absent for the whole episode (never drawn, never act, no reward). 0 = every episode is social."""
    solo_agents: int = 1
    """Agent slots present in a solo episode (the first ones)."""
    dropout_prob: float = 0.0
    """Expert dropout (docs/environment.md 10.4): in each episode, each slot from `solo_agents` on leaves with
    this probability at a step drawn uniformly from [dropout_min_step, dropout_max_step], and is absent from
    then on. 0 = nobody leaves."""
    dropin_prob: float = 0.0
    """Expert drop-in: each slot from `solo_agents` on is absent at the start with this probability and joins
    at a step drawn as for dropout (a slot either leaves, joins or stays: dropout_prob + dropin_prob <= 1)."""
    dropout_min_step: int = 1
    """First step at which a slot may leave or join."""
    dropout_max_step: int = 0
    """Last step at which a slot may leave or join (0: max_steps - 1)."""

    def __post_init__(self):
        """Raise ValueError for the first invalid field found: types first, then values."""
        self._check_types()
        self._check_settings()
        self._check_presence()
        self._check_grid()

    def _check_types(self) -> None:
        """ValueError unless every field has its annotated type (ints are accepted for floats and stored as
        floats; bools are not ints here)."""
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            kind = {"int": int, "float": float, "bool": bool, "str": str}[field.type]
            if kind is float and isinstance(value, int) and not isinstance(value, bool):
                object.__setattr__(self, field.name, float(value))
            elif not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
                _fail(f"{field.name}={value!r} must be of type {field.type}, not {type(value).__name__}")

    def _check_settings(self) -> None:
        """ValueError unless the layout name, agent count, view, rewards, episode length, colours,
        observation, solo episodes and prestige are valid."""
        if self.layout not in LAYOUTS:
            _fail(f"unknown layout {self.layout!r}; choose one of {LAYOUTS}")
        if not 1 <= self.n_agents <= MAX_AGENTS:
            _fail(
                f"n_agents={self.n_agents} but there are {MAX_AGENTS} agent colours (1-{MAX_AGENTS} agents)"
            )
        if self.view_size < 3 or self.view_size % 2 == 0:
            _fail(f"view_size={self.view_size} must be odd and >= 3")
        if not 0 <= self.view_offset < self.view_size:
            _fail(f"view_offset={self.view_offset} must be in [0, view_size)")
        if self.tile_size != 3:
            _fail(f"tile_size={self.tile_size}: only 3 is supported (the paper's 21x21 observations)")
        if self.penalty < 0.0:
            _fail(f"penalty={self.penalty} is a magnitude and must be >= 0 (a wrong tile pays -penalty)")
        if self.max_steps < 1:
            _fail(f"max_steps={self.max_steps} must be >= 1")
        if self.agent_colors not in ("prestige", "fixed"):
            _fail(f"agent_colors={self.agent_colors!r} must be 'prestige' or 'fixed'")
        if self.prestige_formula not in ("code", "paper"):
            _fail(f"prestige_formula={self.prestige_formula!r} must be 'code' or 'paper'")
        if self.observation not in ("rgb", "symbolic"):
            _fail(f"observation={self.observation!r} must be 'rgb' or 'symbolic'")
        if not 0.0 <= self.solo_prob <= 1.0:
            _fail(f"solo_prob={self.solo_prob} must be a probability in [0, 1]")
        if not 1 <= self.solo_agents <= self.n_agents:
            _fail(f"solo_agents={self.solo_agents} must be in [1, n_agents={self.n_agents}]")
        if not 0.0 <= self.prestige_beta <= 1.0:
            _fail(f"prestige_beta={self.prestige_beta} must be in [0, 1]")
        if self.prestige_scale <= 0.0:
            _fail(f"prestige_scale={self.prestige_scale} must be > 0")

    def _check_presence(self) -> None:
        """ValueError unless the dropout and drop-in probabilities and steps are valid."""
        if not 0.0 <= self.dropout_prob <= 1.0 or not 0.0 <= self.dropin_prob <= 1.0:
            _fail(f"dropout_prob={self.dropout_prob} and dropin_prob={self.dropin_prob} must be in [0, 1]")
        if self.dropout_prob + self.dropin_prob > 1.0:
            _fail(f"dropout_prob + dropin_prob = {self.dropout_prob + self.dropin_prob} must be <= 1")
        steps_ok = 1 <= self.dropout_min_step <= self.dropout_last_step < self.max_steps
        if self.changes_presence and not steps_ok:
            _fail(
                f"need 1 <= dropout_min_step ({self.dropout_min_step}) <= dropout_max_step "
                f"({self.dropout_last_step}) < max_steps ({self.max_steps})"
            )

    def _check_grid(self) -> None:
        """ValueError unless the clutter density is valid and the grid fits the layout (and its goals)."""
        if not 0.0 <= self.clutter_density < 1.0:
            _fail(f"clutter_density={self.clutter_density} must be in [0, 1)")
        if self.layout == "goalcycle":
            if not 1 <= self.n_goals <= 127:
                _fail(f"n_goals={self.n_goals} must be in [1, 127]")
            if self.width < 3 or self.height < 3:
                _fail("a goal-cycle grid needs at least 3x3 cells")
            if self.n_goals + self.n_clutter >= self.interior_cells:
                _fail(
                    f"a {self.width}x{self.height} grid has {self.interior_cells} free cells, too few for "
                    f"{self.n_goals} goals + {self.n_clutter} clutter walls + a spawn cell"
                )
        elif self.layout == "fourrooms":
            if self.width < 9 or self.height < 9:
                _fail("four rooms needs at least 9x9 cells")
        elif self.layout == "maze" and (
            self.width < 7 or self.height < 7 or self.width % 2 == 0 or self.height % 2 == 0
        ):
            _fail("a maze needs odd width and height >= 7")

    @property
    def dropout_last_step(self) -> int:
        """`dropout_max_step`, with 0 resolved to `max_steps - 1`."""
        return self.dropout_max_step or self.max_steps - 1

    @property
    def changes_presence(self) -> bool:
        """Slots may leave or join during an episode (expert dropout or drop-in)."""
        return self.dropout_prob > 0.0 or self.dropin_prob > 0.0

    @property
    def interior_cells(self) -> int:
        return (self.width - 2) * (self.height - 2)

    @property
    def n_clutter(self) -> int:
        """Number of clutter walls (docs/environment.md 1.2)."""
        return int(self.clutter_density * self.interior_cells)

    @property
    def obs_shape(self) -> tuple[int, ...]:
        """Per-agent observation shape."""
        if self.observation == "rgb":
            side = self.view_size * self.tile_size
            return (side, side, 3)
        return (self.view_size, self.view_size, 4)

    def replace(self, **changes) -> EnvParams:
        """A copy with some fields changed (validated)."""
        return dataclasses.replace(self, **changes)
