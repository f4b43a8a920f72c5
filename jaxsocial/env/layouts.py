"""Jittable layout generators (Goal Cycle, Four Rooms, Maze) and an ASCII map parser.

A generator maps `(key, env_params)` to a `Layout`: the tile grid, bonus-tile ids and the cells agents may
spawn on. Every generator keeps the border ring of walls, so agents can never leave the grid.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxsocial.env.types import BONUS, EMPTY, GOAL, WALL, EnvParams

ASCII_TILES = {"#": WALL, ".": EMPTY, " ": EMPTY, "G": GOAL}
"""ASCII map characters: '#' wall, '.' or ' ' empty, 'G' terminal goal, '0'-'9' bonus tile with that id."""


@struct.dataclass
class Layout:
    """A generated map.

    Attributes:
        grid: uint8[H, W] tile types, [y, x].
        goal_id: int8[H, W] bonus-tile id (cycle position) or -1.
        spawn_mask: bool[H, W] cells where agents may spawn (each agent independently, uniformly).
    """

    grid: jax.Array
    goal_id: jax.Array
    spawn_mask: jax.Array


def parse_ascii(rows: list[str] | str) -> tuple[np.ndarray, np.ndarray]:
    """Parse an ASCII map (one string per row y, characters along x) into `(grid, goal_id)`.

    Returns uint8[H, W] tile types and int8[H, W] bonus ids (-1 where there is no bonus tile).
    """
    if isinstance(rows, str):
        rows = [r for r in rows.strip("\n").splitlines()]
    if not rows or len({len(r) for r in rows}) != 1:
        raise ValueError("an ASCII map needs one or more rows of equal length")
    grid = np.zeros((len(rows), len(rows[0])), np.uint8)
    goal_id = np.full(grid.shape, -1, np.int8)
    for y, row in enumerate(rows):
        for x, ch in enumerate(row):
            if ch.isdigit():
                grid[y, x], goal_id[y, x] = BONUS, int(ch)
            elif ch in ASCII_TILES:
                grid[y, x] = ASCII_TILES[ch]
            else:
                raise ValueError(f"unknown map character {ch!r} at (x={x}, y={y}); use # . G or 0-9")
    return grid, goal_id


def _border(height: int, width: int) -> np.ndarray:
    """uint8[H, W]: walls on the outer ring, empty inside."""
    grid = np.full((height, width), WALL, np.uint8)
    grid[1:-1, 1:-1] = EMPTY
    return grid


def _sample_cells(key: jax.Array, valid: jax.Array, k: int) -> jax.Array:
    """k distinct flat indices drawn uniformly (in random order) among the True cells of `valid`."""
    scores = jnp.where(valid.ravel(), jax.random.uniform(key, (valid.size,)), -1.0)
    return jax.lax.top_k(scores, k)[1]


def _place(grid: jax.Array, flat_idx: jax.Array, tile: int) -> jax.Array:
    return grid.ravel().at[flat_idx].set(tile).reshape(grid.shape)


def goal_cycle(key: jax.Array, env_params: EnvParams) -> Layout:
    """Goal Cycle (docs/environment.md 1.2): border, `n_goals` bonus tiles (ids in placement order), then
    clutter; no connectivity check."""
    base = jnp.asarray(_border(env_params.height, env_params.width))
    n_goals, n_clutter = env_params.n_goals, env_params.n_clutter
    cells = _sample_cells(key, base == EMPTY, n_goals + n_clutter)
    grid = _place(_place(base, cells[:n_goals], BONUS), cells[n_goals:], WALL)
    goal_id = jnp.full(base.size, -1, jnp.int8).at[cells[:n_goals]].set(jnp.arange(n_goals, dtype=jnp.int8))
    return Layout(grid, goal_id.reshape(base.shape), grid != WALL)


def four_rooms_static(width: int, height: int) -> dict[str, np.ndarray]:
    """The fixed parts of a Four Rooms map (docs/environment.md 6.2): walls with closed doors, door cells,
    goal candidates, spawn box. Arrays are numpy; positions are (x, y)."""
    grid = _border(height, width)
    grid[height // 2, :] = WALL
    grid[:, width // 2] = WALL
    doors = np.array(
        [
            (width // 4, height // 2),
            (width // 2, height // 4),
            ((3 * width - 1) // 4, height // 2),
            (width // 2, (3 * height - 1) // 4),
        ]
    )
    candidates = np.array(
        [
            (x0 + dx, y0 + dy)
            for x0 in (0, width // 2, width - 1)
            for y0 in (0, height // 2, height - 1)
            for dx in (-1, 1)
            for dy in (-1, 1)
            if 1 < x0 + dx < width - 1 and 1 < y0 + dy < height - 1
        ]
    )
    candidates = np.unique(candidates, axis=0)
    spawn = np.zeros((height, width), bool)
    spawn[1 : height // 4, 1 : width // 4] = True
    return {"grid": grid, "doors": doors, "goal_candidates": candidates, "spawn_box": spawn}


def four_rooms(key: jax.Array, env_params: EnvParams) -> Layout:
    """Four Rooms (docs/environment.md 6.2): goal among 9 candidates, clutter on empty cells, then the 4
    doorways open; agents spawn in the top-left box."""
    fixed = four_rooms_static(env_params.width, env_params.height)
    k_goal, k_clutter = jax.random.split(key)
    cand = jnp.asarray(fixed["goal_candidates"])
    gx, gy = cand[jax.random.randint(k_goal, (), 0, len(cand))]
    grid = jnp.asarray(fixed["grid"]).at[gy, gx].set(GOAL)
    if env_params.n_clutter:
        cells = _sample_cells(k_clutter, grid == EMPTY, env_params.n_clutter)
        grid = _place(grid, cells, WALL)
    doors = fixed["doors"]
    grid = grid.at[doors[:, 1], doors[:, 0]].set(EMPTY)
    goal_id = jnp.full(grid.shape, -1, jnp.int8)
    return Layout(grid, goal_id, jnp.asarray(fixed["spawn_box"]) & (grid != WALL))


def _lattice_edges(nx: int, ny: int) -> tuple[np.ndarray, ...]:
    """The edges between neighbouring cells of an nx x ny lattice (node y * nx + x at grid cell (2x+1, 2y+1)):
    int[E] endpoints `u` and `v`, and the grid row and column of the wall cell between them."""
    node = np.arange(nx * ny).reshape(ny, nx)
    edges_u = np.concatenate([node[:, :-1].ravel(), node[:-1, :].ravel()])
    edges_v = np.concatenate([node[:, 1:].ravel(), node[1:, :].ravel()])
    uy, ux = np.divmod(edges_u, nx)
    vy, vx = np.divmod(edges_v, nx)
    return edges_u, edges_v, uy + vy + 1, ux + vx + 1


def _open_edges(k_w, k_start, k_extra, edges_u: np.ndarray, edges_v: np.ndarray, n_nodes: int) -> jax.Array:
    """bool[E] the lattice edges opened: a random spanning tree (Prim's algorithm on random edge weights
    from a random start node), then each other edge with probability 0.05."""
    weights = jax.random.uniform(k_w, (len(edges_u),))
    eu, ev = jnp.asarray(edges_u), jnp.asarray(edges_v)

    def grow(_, carry):
        in_tree, opened = carry
        frontier = in_tree[eu] != in_tree[ev]
        e = jnp.argmin(jnp.where(frontier, weights, jnp.inf))
        in_tree = in_tree.at[eu[e]].set(True).at[ev[e]].set(True)
        return in_tree, opened.at[e].set(True)

    start = jax.random.randint(k_start, (), 0, n_nodes)
    in_tree = jnp.zeros(n_nodes, bool).at[start].set(True)
    _, opened = jax.lax.fori_loop(0, n_nodes - 1, grow, (in_tree, jnp.zeros(len(edges_u), bool)))
    return opened | jax.random.bernoulli(k_extra, 0.05, opened.shape)


def _carve_rooms(k_rooms, grid: jax.Array, nx: int, ny: int, ys: np.ndarray, xs: np.ndarray) -> jax.Array:
    """uint8[H, W] `grid` with up to 4 odd-sized (3 or 5) square rooms, aligned on the lattice, emptied
    (each kept with probability 0.75; the border stays). `ys`, `xs`: int[H, W] each cell's row and column."""
    height, width = grid.shape
    for k in jax.random.split(k_rooms, 4):
        k_keep, k_size, k_x, k_y = jax.random.split(k, 4)
        size = jnp.where(jax.random.bernoulli(k_size), 5, 3)
        half_cells = (size - 1) // 2
        x0 = 1 + 2 * jax.random.randint(k_x, (), 0, jnp.maximum(nx - half_cells, 1))
        y0 = 1 + 2 * jax.random.randint(k_y, (), 0, jnp.maximum(ny - half_cells, 1))
        room = (
            (xs >= x0) & (xs < x0 + size) & (ys >= y0) & (ys < y0 + size) & jax.random.bernoulli(k_keep, 0.75)
        )
        room &= (xs < width - 1) & (ys < height - 1)
        grid = jnp.where(room, EMPTY, grid).astype(jnp.uint8)
    return grid


def _place_goal_and_spawn(
    k_goal, k_spawn, grid: jax.Array, ys: np.ndarray, xs: np.ndarray
) -> tuple[jax.Array, jax.Array]:
    """uint8[H, W] `grid` with the goal on a uniform free cell, and bool[H, W] the spawn cells: the free cells
    of the 3x3 box around the one of 5 uniform free cells farthest (L1) from the goal. `ys`, `xs`: int[H, W]
    each cell's row and column."""
    width = grid.shape[1]
    free = grid == EMPTY
    goal_cell = _sample_cells(k_goal, free, 1)[0]
    gy, gx = jnp.divmod(goal_cell, width)
    grid = grid.at[gy, gx].set(GOAL)
    free = grid == EMPTY
    cand = jax.random.categorical(k_spawn, jnp.where(free.ravel(), 0.0, -jnp.inf), shape=(5,))
    cy, cx = jnp.divmod(cand, width)
    best = jnp.argmax(jnp.abs(cx - gx) + jnp.abs(cy - gy))
    spawn = free & (jnp.abs(xs - cx[best]) <= 1) & (jnp.abs(ys - cy[best]) <= 1)
    return grid, spawn


def maze(key: jax.Array, env_params: EnvParams) -> Layout:
    """A random maze on the odd lattice, like labmaze's RandomMaze (docs/environment.md 6.3, 9.10).

    A random spanning tree (Prim's algorithm on random edge weights) connects every lattice cell; up to four
    rooms of 3x3 or 5x5 cells are carved; every remaining inner wall between two lattice cells opens with
    probability 0.05. Carving only removes walls, so all free cells stay connected and the goal is always
    reachable. The goal is uniform over free cells; the spawn point is the one of 5 uniform free cells
    farthest (L1) from it, and agents spawn in the free cells of the 3x3 box around that point.
    """
    nx, ny = (env_params.width - 1) // 2, (env_params.height - 1) // 2
    edges_u, edges_v, wall_y, wall_x = _lattice_edges(nx, ny)
    k_w, k_start, k_extra, k_rooms, k_goal, k_spawn = jax.random.split(key, 6)
    opened = _open_edges(k_w, k_start, k_extra, edges_u, edges_v, nx * ny)
    grid = jnp.full((env_params.height, env_params.width), WALL, jnp.uint8)
    grid = grid.at[1::2, 1::2].set(EMPTY)
    grid = grid.at[wall_y, wall_x].set(jnp.where(opened, EMPTY, WALL).astype(jnp.uint8))
    ys, xs = np.mgrid[0 : env_params.height, 0 : env_params.width]  # one array: one constant in the program
    grid = _carve_rooms(k_rooms, grid, nx, ny, ys, xs)
    grid, spawn = _place_goal_and_spawn(k_goal, k_spawn, grid, ys, xs)
    return Layout(grid, jnp.full(grid.shape, -1, jnp.int8), spawn)


GENERATORS = {"goalcycle": goal_cycle, "fourrooms": four_rooms, "maze": maze}


def generate(key: jax.Array, env_params: EnvParams) -> Layout:
    """The layout for `env_params.layout`."""
    return GENERATORS[env_params.layout](key, env_params)
