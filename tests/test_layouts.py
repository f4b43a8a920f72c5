"""Layout generators: Goal Cycle placement, Four Rooms doors and goals, maze reachability
(docs/environment.md 1.2, 6)."""

from collections import deque

import jax
import numpy as np
import pytest

import jaxsocial
from jaxsocial.env.layouts import four_rooms_static, generate, parse_ascii
from jaxsocial.env.types import BONUS, EMPTY, GOAL, WALL


def layouts(name, n, **overrides):
    params = jaxsocial.make(name, **overrides)[1]
    batch = jax.jit(jax.vmap(generate, in_axes=(0, None)))(jax.random.split(jax.random.key(7), n), params)
    return jax.tree.map(np.asarray, batch), params


def reachable(grid, start):
    """bool[H, W] cells reachable from (x, y) `start` through non-wall cells."""
    seen = np.zeros(grid.shape, bool)
    queue = deque([start])
    seen[start[1], start[0]] = True
    while queue:
        x, y = queue.popleft()
        for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            nx, ny = x + dx, y + dy
            if grid[ny, nx] != WALL and not seen[ny, nx]:
                seen[ny, nx] = True
                queue.append((nx, ny))
    return seen


@pytest.mark.parametrize("n_goals", [3, 4])
def test_goal_cycle_counts_and_ids(n_goals):
    batch, params = layouts("goalcycle3", 64, n_goals=n_goals)
    for grid, goal_id, spawn in zip(batch.grid, batch.goal_id, batch.spawn_mask, strict=True):
        assert (grid == WALL).sum() == 48 + 12  # border + int(0.1 * 121) clutter
        assert (grid[0] == WALL).all() and (grid[:, 0] == WALL).all()
        assert sorted(goal_id[grid == BONUS].tolist()) == list(range(n_goals))
        assert (goal_id[grid != BONUS] == -1).all()
        # Agents may spawn on bonus tiles (docs/environment.md 1.3).
        np.testing.assert_array_equal(spawn, grid != WALL)
    # goal positions vary and every interior cell can hold a goal
    assert len({tuple(np.argwhere(g == BONUS)[0]) for g in batch.grid}) > 20


def test_four_rooms_doors_goal_candidates_and_spawn_box():
    fixed = four_rooms_static(17, 17)
    np.testing.assert_array_equal(fixed["doors"], [(4, 8), (8, 4), (12, 8), (8, 12)])
    expected = {(x, y) for x in (7, 9, 15) for y in (7, 9, 15)}
    assert {tuple(c) for c in fixed["goal_candidates"]} == expected
    batch, _ = layouts("fourrooms", 200)
    goals = {tuple(np.argwhere(g == GOAL)[0][::-1]) for g in batch.grid}
    assert goals == expected  # every candidate is drawn
    for grid, spawn in zip(batch.grid, batch.spawn_mask, strict=True):
        for x, y in fixed["doors"]:
            assert grid[y, x] == EMPTY
        assert (grid[8, 1:16] != EMPTY).sum() == 13 and (grid[1:16, 8] != EMPTY).sum() == 13
        ys, xs = np.nonzero(spawn)
        assert set(xs) <= {1, 2, 3} and set(ys) <= {1, 2, 3}
        assert reachable(grid, (1, 1))[grid == GOAL].all()


def test_maze_goal_reachable_from_every_spawn_cell():
    batch, params = layouts("maze", 200)
    wall_fractions = []
    for grid, spawn in zip(batch.grid, batch.spawn_mask, strict=True):
        assert grid.shape == (19, 19) and (grid[0] == WALL).all() and (grid[:, -1] == WALL).all()
        assert (grid == GOAL).sum() == 1
        assert spawn.any() and (grid[spawn] == EMPTY).all()
        ys, xs = np.nonzero(spawn)
        assert xs.max() - xs.min() <= 2 and ys.max() - ys.min() <= 2  # a 3x3 spawn box
        seen = reachable(grid, (xs[0], ys[0]))
        assert seen[grid == GOAL].all()
        assert seen[grid != WALL].all()  # the maze is connected
        wall_fractions.append((grid[1:-1, 1:-1] == WALL).mean())
    assert 0.25 < np.mean(wall_fractions) < 0.6  # a maze, not an open room
    assert len({g.tobytes() for g in batch.grid}) == 200


def test_parse_ascii():
    grid, goal_id = parse_ascii(["#####", "#0G1#", "#####"])
    np.testing.assert_array_equal(grid[1], [WALL, BONUS, GOAL, BONUS, WALL])
    np.testing.assert_array_equal(goal_id[1], [-1, 0, -1, 1, -1])
    with pytest.raises(ValueError, match="unknown map character"):
        parse_ascii(["#x#"])
    with pytest.raises(ValueError, match="equal length"):
        parse_ascii(["###", "##"])
