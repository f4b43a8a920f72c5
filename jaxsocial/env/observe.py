"""Egocentric observations: crop by gather, occlusion, agent layer, RGB from the sprite atlas
(docs/environment.md, sections 4 and 5).

View cells are indexed `[row, col]` with row 0 farthest ahead; the observer sits at
`(row, col) = (V - 1 - view_offset, V // 2)` facing up.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from jaxsocial.env import sprites
from jaxsocial.env.types import DIR_VEC, EMPTY, WALL, EnvParams, EnvState


@functools.cache
def view_offsets(view_size: int, view_offset: int) -> np.ndarray:
    """int32[4, V, V, 2]: world (dx, dy) of view cell [row, col] for each facing direction
    (docs/environment.md 4.3)."""
    rows, cols = np.mgrid[0:view_size, 0:view_size]
    ahead = view_size - 1 - view_offset - rows
    side = cols - view_size // 2
    out = np.zeros((4, view_size, view_size, 2), np.int32)
    for d, f in enumerate(DIR_VEC):
        right = np.array([-f[1], f[0]])
        out[d] = ahead[..., None] * f + side[..., None] * right
    return out


Observers = tuple[int, ...] | None
"""The agents whose views are rendered, in this order (a static tuple of agent indices); None: every agent."""


def observer_index(env_params: EnvParams, observers: Observers) -> np.ndarray:
    """int32[K] the agent index of each rendered view (`Observers`; K = N for None, 0 for ())."""
    if observers is None:
        return np.arange(env_params.n_agents, dtype=np.int32)
    who = np.asarray(observers, np.int32).reshape(-1)
    if who.size and (who.min() < 0 or who.max() >= env_params.n_agents):
        raise ValueError(f"observers must be agent indices in [0, {env_params.n_agents}), got {observers}")
    return who


def view_cells(state: EnvState, env_params: EnvParams, who: np.ndarray) -> tuple[jax.Array, jax.Array]:
    """World coordinates and tile types of the views of the observers `who` (int32[K], agent indices).

    Returns int32[K, V, V, 2] (x, y) and uint8[K, V, V] tile types (cells outside the grid are EMPTY).
    """
    offsets = jnp.asarray(view_offsets(env_params.view_size, env_params.view_offset))
    world = state.pos[who][:, None, None, :] + offsets[state.dir[who]]
    height, width = state.grid.shape
    x, y = world[..., 0], world[..., 1]
    inside = (x >= 0) & (x < width) & (y >= 0) & (y < height)
    tiles = state.grid[jnp.clip(y, 0, height - 1), jnp.clip(x, 0, width - 1)]
    return world, jnp.where(inside, tiles, EMPTY).astype(jnp.uint8)


def _or(a, b):
    """OR that keeps Python booleans folded at trace time."""
    if a is False:
        return b
    if b is False:
        return a
    return a | b


def visibility(transparent: jax.Array, view_offset: int) -> jax.Array:
    """The original's occlusion sweep (docs/environment.md 4.4), unrolled at trace time.

    Args:
        transparent: bool[..., V, V] cells that do not block sight (everything but walls).
    Returns:
        bool[..., V, V] visible cells. A single wall hides nothing; contiguous walls cast shadows;
        row 0 and column 0 never spread sight sideways (quirks of the original).
    """
    v = transparent.shape[-1]
    ax, ay = v // 2, v - 1 - view_offset
    t = [[transparent[..., r, c] for c in range(v)] for r in range(v)]
    m = [[False] * v for _ in range(v)]
    m[ay][ax] = True

    def spread(r, c, targets):
        if m[r][c] is False:
            return
        s = m[r][c] & t[r][c]
        for rr, cc in targets:
            m[rr][cc] = _or(m[rr][cc], s)

    for r in range(ay, 0, -1):  # upward pass
        for c in range(ax, v):
            spread(r, c, ([(r, c + 1), (r - 1, c + 1)] if c < v - 1 else []) + [(r - 1, c)])
        for c in range(ax + 1, 0, -1):
            spread(r, c, [(r, c - 1), (r - 1, c), (r - 1, c - 1)])
    for r in range(ay, v):  # downward pass
        below = r < v - 1
        for c in range(ax, v):
            spread(
                r,
                c,
                ([(r, c + 1)] if c < v - 1 else [])
                + ([(r + 1, c)] if below else [])
                + ([(r + 1, c + 1)] if below and c < v - 1 else []),
            )
        for c in range(ax + 1, 0, -1):
            spread(r, c, [(r, c - 1)] + ([(r + 1, c), (r + 1, c - 1)] if below else []))
    shape = transparent.shape[:-2]
    rows = [jnp.stack([jnp.broadcast_to(jnp.asarray(x), shape) for x in row], -1) for row in m]
    return jnp.stack(rows, -2)


def agent_layer(state: EnvState, world: jax.Array, who: np.ndarray) -> tuple[jax.Array, jax.Array]:
    """Which agent each observer `who` (int32[K], agent indices; `world` int32[K, V, V, 2] their view cells)
    sees drawn in each view cell (docs/environment.md 4.6, 9.11).

    Only one agent is drawn per cell: the observer if it is there, otherwise the earliest arrival, ties to
    the lowest index. Inactive (done) agents are still drawn; absent ones (`present` False) are not.
    Returns bool[K, V, V] (an agent is drawn) and int32[K, V, V] its index.
    """
    n = state.pos.shape[0]
    at = jnp.all(world[:, None] == state.pos[None, :, None, None, :], -1)  # [obs, agent, V, V]
    at = at & state.present[None, :, None, None]
    key = state.arrival * n + jnp.arange(n)
    key = jnp.where(who[:, None] == np.arange(n)[None, :], -1, key[None, :])  # observer first
    big = jnp.iinfo(jnp.int32).max
    drawn = jnp.argmin(jnp.where(at, key[:, :, None, None], big), axis=1).astype(jnp.int32)
    return jnp.any(at, axis=1), drawn


def color_index(state: EnvState, env_params: EnvParams) -> jax.Array:
    """int32[N] each agent's palette index (see `sprites.prestige_palette`, `sprites.fixed_palette`)."""
    n = state.pos.shape[0]
    if env_params.agent_colors == "fixed":
        return jnp.arange(n, dtype=jnp.int32)
    c = state.prestige
    s = (
        jnp.tanh(c / env_params.prestige_scale)
        if env_params.prestige_formula == "code"
        else jax.nn.sigmoid(c)
    )
    blue = (s * 255.0).astype(jnp.int32)
    red = ((1.0 - s) * 255.0).astype(jnp.int32)
    return 2 * blue + (red + blue - 254)


def relative_dir(state: EnvState, drawn: jax.Array, who: np.ndarray) -> jax.Array:
    """int32[K, V, V] sprite direction (0 right, 1 down, 2 left, 3 up) of the drawn agent as each observer
    `who` (int32[K]) sees it: `(dir_other - dir_observer + 3) mod 4`."""
    return (state.dir[drawn] - state.dir[who][:, None, None] + 3) % 4


def observation_cells(
    state: EnvState, env_params: EnvParams, observers: Observers = None
) -> dict[str, jax.Array]:
    """Everything the observers' views show, per view cell ([K, V, V] each): tile type, visibility, drawn
    agent."""
    who = observer_index(env_params, observers)
    world, tiles = view_cells(state, env_params, who)
    visible = visibility(tiles != WALL, env_params.view_offset) & state.active[who][:, None, None]
    has_agent, drawn = agent_layer(state, world, who)
    return {
        "tiles": tiles,
        "visible": visible,
        "has_agent": has_agent & visible,
        "agent": drawn,
        "rel_dir": relative_dir(state, drawn, who),
    }


def atlas_index(cells: dict[str, jax.Array], colors: jax.Array, palette: int) -> jax.Array:
    """int32[K, V, V] index into `sprites.atlas` for each view cell."""
    tiles = cells["tiles"].astype(jnp.int32)
    agent_tile = sprites.FIRST_AGENT_TILE + (tiles * 4 + cells["rel_dir"]) * palette + colors[cells["agent"]]
    idx = jnp.where(cells["has_agent"], agent_tile, 1 + tiles)
    return jnp.where(cells["visible"], idx, 0)


def rgb(state: EnvState, env_params: EnvParams, observers: Observers = None) -> jax.Array:
    """uint8[K, V*3, V*3, 3] the observers' egocentric RGB views; hidden cells and done observers are
    shadow."""
    cells = observation_cells(state, env_params, observers)
    idx = atlas_index(cells, color_index(state, env_params), sprites.palette_size(env_params.agent_colors))
    pixels = jnp.asarray(sprites.atlas(env_params.agent_colors).reshape(-1, 3))  # [T * 9, 3]
    side = env_params.view_size * sprites.TILE
    sub = np.arange(side) % sprites.TILE
    sub_offset = jnp.asarray(sub[:, None] * sprites.TILE + sub[None, :])  # [side, side]
    per_pixel = jnp.repeat(jnp.repeat(idx, sprites.TILE, axis=1), sprites.TILE, axis=2)
    return pixels[per_pixel * 9 + sub_offset]


def symbolic(state: EnvState, env_params: EnvParams, observers: Observers = None) -> jax.Array:
    """int8[K, V, V, 4] the observers' symbolic views: tile type (-1 hidden), drawn agent index + 1 (0 none),
    its relative direction (-1 none), its colour (prestige: blue level 0-127; fixed: palette index)."""
    cells = observation_cells(state, env_params, observers)
    colors = color_index(state, env_params)
    if env_params.agent_colors == "prestige":
        colors = colors // 4
    has = cells["has_agent"]
    tile = jnp.where(cells["visible"], cells["tiles"].astype(jnp.int32), -1)
    agent = jnp.where(has, cells["agent"] + 1, 0)
    rel = jnp.where(has, cells["rel_dir"], -1)
    blue = jnp.where(has, colors[cells["agent"]], 0)
    return jnp.stack([tile, agent, rel, blue], -1).astype(jnp.int8)


def attention_targets(state: EnvState, env_params: EnvParams) -> jax.Array:
    """int32[N, N-1] where each agent's view window holds each other agent (slots in order, skipping itself):
    the view cell `row * V + col`, or `V * V` when the other agent is absent or outside the window.

    Geometric: occlusion is ignored, so an agent hidden behind a wall still has its cell (the target of the
    attention auxiliary loss, `network.attention_loss`, which asks the learner to keep track of the others).
    """
    n, v = env_params.n_agents, env_params.view_size
    others = np.array([[j for j in range(n) if j != i] for i in range(n)], np.int32).reshape(n, n - 1)
    delta = state.pos[others] - state.pos[:, None, :]  # [N, N-1, 2]
    forward = jnp.asarray(DIR_VEC)[state.dir][:, None, :]  # [N, 1, 2]
    right = jnp.stack([-forward[..., 1], forward[..., 0]], -1)
    row = v - 1 - env_params.view_offset - jnp.sum(delta * forward, -1)
    col = v // 2 + jnp.sum(delta * right, -1)
    inside = (row >= 0) & (row < v) & (col >= 0) & (col < v) & state.present[others]
    return jnp.where(inside, row * v + col, v * v).astype(jnp.int32)


def observe(state: EnvState, env_params: EnvParams, observers: Observers = None) -> jax.Array:
    """The observers' observations (every agent's for None), of shape `(K, *env_params.obs_shape)`: row k is
    exactly row `observers[k]` of every agent's, and only the K views are computed."""
    render = rgb if env_params.observation == "rgb" else symbolic
    return render(state, env_params, observers)
