"""Egocentric crop, occlusion, sprites, blending, prestige colours and draw order
(docs/environment.md, sections 4 and 5)."""

import jax
import numpy as np
import pytest

import jaxsocial
from jaxsocial.env import sprites, state_from_layout
from jaxsocial.env.observe import attention_targets, observe, visibility
from jaxsocial.env.types import SHADOW

OPEN = ["#########", *["#.......#"] * 7, "#########"]


def scene(rows, pos, dirs, **kw):
    params = jaxsocial.make("goalcycle3", width=len(rows[0]), height=len(rows), clutter_density=0.0, **kw)[1]
    return state_from_layout(params, rows, pos, dirs), params


def cell(obs, row, col):
    """uint8[3, 3, 3] pixels of view cell (row, col)."""
    return np.asarray(obs)[3 * row : 3 * row + 3, 3 * col : 3 * col + 3]


def reference_visibility(transparent, view_offset):
    """The sweep of docs/environment.md 4.4, literally (M and T indexed [x, y] like the original)."""
    v = transparent.shape[0]
    t = transparent.T
    m = np.zeros((v, v), bool)
    ax, ay = v // 2, v - 1 - view_offset
    m[ax, ay] = True
    for y in range(ay, 0, -1):
        for x in range(ax, v):
            if m[x, y] and t[x, y]:
                if x < v - 1:
                    m[x + 1, y] = m[x + 1, y - 1] = True
                m[x, y - 1] = True
        for x in range(ax + 1, 0, -1):
            if m[x, y] and t[x, y]:
                m[x - 1, y] = m[x, y - 1] = m[x - 1, y - 1] = True
    for y in range(ay, v):
        for x in range(ax, v):
            if m[x, y] and t[x, y]:
                if x < v - 1:
                    m[x + 1, y] = True
                if y < v - 1:
                    m[x, y + 1] = True
                    if x < v - 1:
                        m[x + 1, y + 1] = True
        for x in range(ax + 1, 0, -1):
            if m[x, y] and t[x, y]:
                m[x - 1, y] = True
                if y < v - 1:
                    m[x, y + 1] = m[x - 1, y + 1] = True
    return m.T


def visible(transparent, view_offset=1):
    return np.asarray(visibility(np.asarray(transparent, bool), view_offset))


def test_occlusion_nothing_blocks_everything_visible():
    assert visible(np.ones((7, 7))).all()


def test_single_wall_hides_nothing():
    t = np.ones((7, 7), bool)
    t[3, 3] = False  # two cells ahead of the agent (row 5, col 3)
    assert visible(t).all()


def test_wall_line_casts_shadow():
    t = np.ones((7, 7), bool)
    t[3, :] = False
    m = visible(t)
    assert not m[:3].any() and m[3:].all()  # the wall row itself is visible


def test_row_zero_never_spreads_sideways():
    t = np.ones((7, 7), bool)
    t[1, :] = False
    t[1, 3] = True  # one gap in a wall row just below row 0
    m = visible(t)
    np.testing.assert_array_equal(m[0], [False, False, True, True, True, False, False])
    assert m[1:].all()


def test_column_zero_never_spreads():
    t = np.ones((7, 7), bool)
    t[:5, 1] = False  # wall column right of column 0
    t[:5, 5] = False  # and its mirror left of column 6
    m = visible(t)
    np.testing.assert_array_equal(m[:, 0], [False, False, False, False, True, True, True])
    assert m[:, 6].all()  # the mirrored column does spread upwards: the view is asymmetric


@pytest.mark.parametrize("view_offset", [0, 1, 2])
def test_occlusion_matches_reference_on_random_masks(view_offset):
    rng = np.random.default_rng(view_offset)
    masks = rng.random((300, 7, 7)) > 0.35
    got = np.asarray(jax.jit(visibility, static_argnums=1)(masks, view_offset))
    for t, m in zip(masks, got, strict=True):
        np.testing.assert_array_equal(m, reference_visibility(t, view_offset))


def test_sprite_tables_match_spec():
    counts = sprites.triangle_masks().reshape(4, 3, 3, 3, 3).sum(axis=(2, 4))
    np.testing.assert_array_equal(counts[0], [[2, 0, 0], [6, 7, 2], [2, 0, 0]])  # right
    np.testing.assert_array_equal(counts[1], [[2, 6, 2], [0, 7, 0], [0, 2, 0]])  # down
    np.testing.assert_array_equal(counts[2], [[0, 0, 2], [2, 7, 6], [0, 0, 2]])  # left
    np.testing.assert_array_equal(counts[3], [[0, 2, 0], [0, 7, 0], [2, 6, 2]])  # up
    np.testing.assert_array_equal(sprites.white_alpha()[0], [[56, 0, 0], [170, 198, 56], [56, 0, 0]])


def test_crop_geometry_and_view_offset(observe_fn):
    rows = [r for r in OPEN]
    rows[2] = "#.....0.#"  # bonus tile at (6, 2)
    # (agent position, direction, view offset, view cell [row, col] of the tile at (6, 2))
    cases = [((4, 6), 3, 1, (1, 5)), ((4, 6), 3, 2, (0, 5)), ((2, 4), 0, 1, (1, 1)), ((6, 3), 1, 1, (6, 3))]
    cases.append(((6, 3), 1, 0, None))
    for pos, d, offset, expected in cases:
        state, params = scene(rows, [pos], [d], n_agents=1, view_offset=offset, observation="symbolic")
        tiles = np.asarray(observe_fn(state, params))[0, ..., 0]
        where = np.argwhere(tiles == 2)
        if expected is None:
            assert len(where) == 0  # behind the agent, beyond its view_offset
        else:
            np.testing.assert_array_equal(where, [expected])
        ay = params.view_size - 1 - offset
        assert np.asarray(observe_fn(state, params))[0, ay, 3, 1] == 1  # the observer sits at (ay, 3)


def test_hidden_cells_are_shadow_and_walls_visible(observe_fn):
    rows = ["#########", "#.......#", "#.......#", "#########", "#.......#", "#.......#", "#########"]
    state, params = scene(rows, [(4, 5)], [3], n_agents=1, n_goals=1)
    obs = np.asarray(observe_fn(state, params))[0]
    # The wall row y=3 is 2 cells ahead (view row 3): visible wall colour; rows beyond it are shadow.
    np.testing.assert_array_equal(cell(obs, 3, 3), np.broadcast_to((74, 65, 42), (3, 3, 3)))
    np.testing.assert_array_equal(obs[:9], np.broadcast_to(SHADOW, (9, 21, 3)))


def test_blending_example_red_agent_on_yellow(observe_fn):
    """docs/environment.md 4.6: a red east-facing agent on a bonus tile, seen by an observer facing north."""
    rows = [r for r in OPEN]
    rows[4] = "#...0...#"
    state, params = scene(rows, [(4, 4), (4, 6)], [0, 3], n_agents=2, agent_colors="fixed")
    expected = [
        [[198, 182, 0], [255, 255, 0], [255, 255, 0]],
        [[182, 36, 0], [198, 0, 0], [198, 182, 0]],
        [[198, 182, 0], [255, 255, 0], [255, 255, 0]],
    ]
    np.testing.assert_array_equal(cell(observe_fn(state, params)[1], 3, 3), expected)


def test_prestige_colours_and_relative_headings(observe_fn):
    state, params = scene(OPEN, [(4, 4), (4, 6)], [0, 3], n_agents=2)
    state = state.replace(prestige=state.prestige.at[0].set(0.99))
    obs = np.asarray(observe_fn(state, params))
    s = np.tanh(0.99 / 2.0)
    red, blue = int((1 - s) * 255), int(s * 255)
    alpha = sprites.white_alpha().astype(int)
    # Agent 0 (east) seen by agent 1 (north) points right, in its prestige colour.
    other = cell(obs[1], 3, 3)
    np.testing.assert_array_equal(other[..., 0], (alpha[0] * red) >> 8)
    np.testing.assert_array_equal(other[..., 2], (alpha[0] * blue) >> 8)
    # Agent 1 sees itself pointing up in pure red (prestige 0): centre pixel 197, not 198
    # (docs/environment.md section 5).
    own = cell(obs[1], 5, 3)
    np.testing.assert_array_equal(own[..., 0], (alpha[3] * 255) >> 8)
    assert own[1, 1, 0] == 197 and not own[..., 1:].any()
    # Agent 0 faces east and sees agent 1 (north, a left turn from east) pointing left: (3 - 0 + 3) % 4.
    sym_params = params.replace(observation="symbolic")
    sym = np.asarray(observe_fn(state, sym_params))
    assert sym[0, 5, 5, 1] == 2 and sym[0, 5, 5, 2] == 2  # agent index 1 (+1), sprite direction 2 (left)


def test_draw_order_observer_first_then_earliest_arrival(observe_fn):
    params_kw = dict(n_agents=4, observation="symbolic")
    # Agents 1, 2, 3 share the cell two ahead of observer 0; arrivals 5, 3, 3: agent 2 (earliest, lowest).
    state, params = scene(OPEN, [(4, 6), (4, 4), (4, 4), (4, 4)], [3, 0, 1, 2], **params_kw)
    state = state.replace(arrival=np.array([0, 5, 3, 3], np.int32))
    sym = np.asarray(observe_fn(state, params))
    assert sym[0, 3, 3, 1] == 3
    # Each of agents 1-3 sees itself on the shared cell.
    for i in (1, 2, 3):
        assert sym[i, 5, 3, 1] == i + 1


def test_done_observer_sees_only_shadow(observe_fn):
    state, params = scene(OPEN, [(4, 6), (4, 4)], [3, 3], n_agents=2)
    state = state.replace(active=np.array([False, True]))
    obs = np.asarray(observe_fn(state, params))
    np.testing.assert_array_equal(obs[0], np.broadcast_to(SHADOW, obs[0].shape))
    assert cell(obs[1], 5, 3)[1, 1, 0] == 197  # active agents still see normally


def test_attention_targets_are_view_cells_of_the_other_agents():
    """Observer 0 at (4, 6) facing north sits at view (row 5, col 3): agent 1 at (4, 2) is 4 ahead (row 1,
    col 3) even behind the wall at (4, 4); agent 2 at (7, 7) is 1 behind, 3 right (row 6, col 6); agent 3
    at (1, 1) is 5 ahead, 3 left (the corner, row 0, col 0); agent 4 is absent."""
    rows = [*OPEN[:4], "#...#...#", *OPEN[5:]]
    params = jaxsocial.make("goalcycle3", width=9, height=9, clutter_density=0.0, n_agents=5)[1]
    state = state_from_layout(
        params, rows, [[4, 6], [4, 2], [7, 7], [1, 1], [4, 5]], [3, 0, 0, 0, 0], present=[1, 1, 1, 1, 0]
    )
    targets = np.asarray(attention_targets(state, params))
    assert targets.shape == (5, 4)
    np.testing.assert_array_equal(targets[0], [1 * 7 + 3, 6 * 7 + 6, 0, 49])
    # Agent 1 at (4, 2) facing east sees observer 0 (2 right, 4 behind: outside) and agent 4 is absent.
    assert targets[1, 0] == 49 and targets[1, 3] == 49
    # Seen from agent 2 at (7, 7) facing east, agent 0 at (4, 6) is 3 behind (outside: only 1 row behind).
    assert targets[2, 0] == 49


@pytest.mark.parametrize("observation", ["rgb", "symbolic"])
def test_views_of_some_observers_are_their_rows_of_every_view(observation):
    """`observe(state, params, observers)` renders only those agents' views, each exactly its row of the
    views of every agent, in the observers' order; here with shared cells, arrival order, an inactive and
    an absent agent in view."""
    state, params = scene(
        OPEN, [(4, 6), (4, 4), (4, 4), (4, 5), (3, 4)], [3, 0, 1, 2, 3], n_agents=5, observation=observation
    )
    state = state.replace(
        arrival=np.array([0, 5, 3, 3, 0], np.int32),
        active=np.array([True, True, False, True, False]),
        present=np.array([True, True, True, True, False]),
        prestige=np.array([0.0, 2.0, -1.0, 0.5, 0.0], np.float32),
    )
    render = jax.jit(observe, static_argnums=(1, 2))
    every = np.asarray(render(state, params, None))
    for observers in [(0,), (2,), (3, 1), (1, 2, 3), (4, 0), ()]:
        some = np.asarray(render(state, params, observers))
        np.testing.assert_array_equal(some, every[list(observers)], err_msg=str(observers))


@pytest.mark.parametrize("observers", [(5,), (-1,), (0, 2)])
def test_observers_outside_the_agents_are_refused(observers):
    state, params = scene(OPEN, [(4, 6), (4, 4)], [3, 3], n_agents=2)
    with pytest.raises(ValueError, match="observers must be agent indices"):
        observe(state, params, observers)
