"""Scripted experts that read the full environment state (not observations); jittable and vmappable.

Kinds:

- `explorer` (Goal Cycle): does not know the cycle order. It uses bonus-tile ids only as opaque labels and
  infers the order from its rewards: it remembers the last correctly visited tile, the known successor of
  each tile and the (from, to) pairs that were mistakes. While the successor of its last correct tile is
  unknown it walks to the nearest tile that can still be the successor (not the tile itself, not a tile
  already known to follow another one, not a known mistake, not the start of its known chain unless the
  chain covers every tile); once known it cycles. Where every tile can be reached without stepping on
  another one, this costs at most (n-1)(n-2)/2 wrong entries per episode (1 for 3 tiles, 3 for 4), after
  which it never errs. It reads `cycle_state` only at an episode start (-1 in a fresh episode), as its
  last correct tile. A reward > 0 marks a correct entry, so penalty=0 (mistakes pay 0) works too.
- `oracle` (Goal Cycle): knows the order (reads `goal_id` and its `cycle_state`); nearest tile first, then
  always the successor.
- `navigator` (Four Rooms, Maze): shortest path to the goal.

Imperfect variants: `epsilon` is the per-step probability of a uniformly random action (all kinds);
`forget` is the per-step probability of forgetting the order: the explorer clears what it has learned
(keeping its last correct tile), the oracle heads for a uniformly random reachable bonus tile other than
the successor until it next enters a bonus tile; the navigator has nothing to forget and ignores it.

Paths come from cost-to-go fields, one per target (a bonus tile, or the goal), computed at episode start by
min-relaxation to convergence and cached in `Memory`. Entering a cell costs 1, entering another bonus
tile costs 1 + H*W (so paths avoid stepping on other bonus tiles, and go through them only when nothing
else reaches the target); walls cannot be entered. An agent on its target steps off and comes back.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from jaxsocial.agents.expert_spec import ExpertSpec
from jaxsocial.env.batching import any_in_batch
from jaxsocial.env.types import (
    BONUS,
    DIR_VEC,
    DONE,
    FORWARD,
    GOAL,
    LEFT,
    NUM_ACTIONS,
    RIGHT,
    WALL,
    EnvParams,
    EnvState,
)

IDLE = DONE
"""The action (a no-op) of an expert with nowhere to go."""


jax.tree_util.register_static(ExpertSpec)  # static under jit


def _n_targets(env_params: EnvParams) -> int:
    return env_params.n_goals if env_params.layout == "goalcycle" else 1


def _inf(env_params: EnvParams) -> int:
    """Larger than any finite path cost (at most H*W cells, each crossing costs 1 + H*W)."""
    cells = env_params.width * env_params.height
    return (_n_targets(env_params) + 1) * (cells + 1) + 1


def _cost_dtype(env_params: EnvParams):
    return jnp.int16 if _inf(env_params) < np.iinfo(np.int16).max else jnp.int32


@struct.dataclass
class Memory:
    """One expert's memory in one environment (T = n_goals targets in Goal Cycle, else 1).

    Attributes:
        cost: int16[T, H, W] (int32 for huge grids) cost of a shortest path to target t that starts by
            entering cell [y, x]; 1 on the target, `_inf` where unreachable (walls).
        pos: int32[2] the agent's (x, y) at the previous call.
        target: int32[] the target being walked to (a bonus-tile label, 0 for the goal), -1 for none.
        last: int32[] label of the last correctly visited tile, -1 before the first (explorer).
        chain_start: int32[] label where the known chain of successors starts (explorer).
        succ: int32[T] known successor label of each tile, -1 if unknown (explorer).
        mistake: bool[T, T] entering tile j right after correct tile i was a mistake (explorer).
    """

    cost: jax.Array
    pos: jax.Array
    target: jax.Array
    last: jax.Array
    chain_start: jax.Array
    succ: jax.Array
    mistake: jax.Array


def init_memory(env_params: EnvParams) -> Memory:
    """An empty memory with the shapes `env_params` implies (call `act_one` or `act_batch` with `reset=True`
    first)."""
    n = _n_targets(env_params)
    minus_one = jnp.full((), -1, jnp.int32)
    return Memory(
        cost=jnp.full((n, env_params.height, env_params.width), _inf(env_params), _cost_dtype(env_params)),
        pos=jnp.zeros(2, jnp.int32),
        target=minus_one,
        last=minus_one,
        chain_start=minus_one,
        succ=jnp.full(n, -1, jnp.int32),
        mistake=jnp.zeros((n, n), bool),
    )


def cost_fields(env_params: EnvParams, state: EnvState) -> jax.Array:
    """Cost-to-go fields of one environment, `Memory.cost` (int16/int32[T, H, W])."""
    inf = _inf(env_params)
    grid = state.grid
    height, width = grid.shape
    free = grid != WALL
    if env_params.layout == "goalcycle":
        labels = jnp.arange(env_params.n_goals, dtype=jnp.int32)
        is_target = state.goal_id.astype(jnp.int32)[None] == labels[:, None, None]
        crossing = (grid == BONUS)[None] & ~is_target
        weight = jnp.where(crossing, 1 + height * width, 1)
    else:
        is_target = (grid == GOAL)[None]
        weight = jnp.ones((1, height, width), jnp.int32)
    weight = jnp.where(free[None], weight, inf)
    start = jnp.where(is_target & free[None], 1, inf).astype(jnp.int32)

    def relax(carry):
        cost, _ = carry
        padded = jnp.pad(cost, ((0, 0), (1, 1), (1, 1)), constant_values=inf)
        best = jnp.minimum(
            jnp.minimum(padded[:, :-2, 1:-1], padded[:, 2:, 1:-1]),
            jnp.minimum(padded[:, 1:-1, :-2], padded[:, 1:-1, 2:]),
        )
        new = jnp.minimum(jnp.minimum(weight + best, inf), cost)
        return new, jnp.any(new != cost)

    cost, _ = jax.lax.while_loop(lambda c: c[1], relax, (start, jnp.array(True)))
    return cost.astype(_cost_dtype(env_params))


def _neighbour_costs(cost: jax.Array, pos: jax.Array, inf: int) -> jax.Array:
    """int32[T, 4]: cost of reaching each target by first stepping in direction 0-3."""
    height, width = cost.shape[1:]
    nxt = pos[None] + jnp.asarray(DIR_VEC)
    x, y = nxt[:, 0], nxt[:, 1]
    inside = (x >= 0) & (x < width) & (y >= 0) & (y < height)
    values = cost[:, jnp.clip(y, 0, height - 1), jnp.clip(x, 0, width - 1)].astype(jnp.int32)
    return jnp.where(inside[None], values, inf)


def _steer(q: jax.Array, direction: jax.Array, inf: int) -> jax.Array:
    """Action towards the cheapest neighbour (costs q int32[4]): FORWARD if in front, else turn."""
    best = q.min()
    action = jnp.where(
        q[direction] == best,
        FORWARD,
        jnp.where(
            q[(direction + 1) % 4] == best, RIGHT, jnp.where(q[(direction + 3) % 4] == best, LEFT, RIGHT)
        ),
    )
    return jnp.where(best >= inf, IDLE, action).astype(jnp.int32)


def _nearest(reach: jax.Array, allowed: jax.Array, inf: int) -> jax.Array:
    """Label of the cheapest allowed reachable target, -1 if none."""
    ok = allowed & (reach < inf)
    return jnp.where(ok.any(), jnp.argmin(jnp.where(ok, reach, inf)), -1).astype(jnp.int32)


def _learn_order(labels, entered, label, reward, forgot, last, chain_start, succ, mistake):
    """The explorer's `Memory` fields (last, chain_start, succ, mistake) after a step: what entering tile
    `label` (when `entered`) with `reward` taught it, then cleared (but `last`) if it `forgot`. `labels`:
    int32[T] the tile labels 0..T-1."""
    first = last < 0
    correct = entered & (first | (reward > 0))
    wrong = entered & ~correct
    succ = jnp.where(correct & ~first & (labels == last), label, succ)
    mistake |= wrong & (labels[:, None] == last) & (labels[None, :] == label)
    chain_start = jnp.where(correct & first, label, chain_start)
    last = jnp.where(correct, label, last)
    succ = jnp.where(forgot, -1, succ)
    mistake &= ~forgot
    chain_start = jnp.where(forgot, last, chain_start)
    return last, chain_start, succ, mistake


def _explorer_target(labels, best_reach, last, chain_start, succ, mistake, inf: int) -> jax.Array:
    """The explorer's new target: the known successor of `last`, else the nearest reachable tile (costs
    `best_reach` int32[T]) that can still follow it (the successor map is a single T-cycle)."""
    n = labels.shape[0]
    has_pred = jnp.any(succ[:, None] == labels[None, :], axis=0)
    closes_early = (labels == chain_start) & (jnp.sum(succ >= 0) < n - 1)
    known = succ[jnp.maximum(last, 0)]
    candidates = (labels != last) & ~has_pred & ~mistake[jnp.maximum(last, 0)] & ~closes_early
    guess = _nearest(best_reach, jnp.where(last < 0, True, candidates), inf)
    return jnp.where((last >= 0) & (known >= 0), known, guess)


def _oracle_target(labels, best_reach, cycle, forgot, u, inf: int) -> jax.Array:
    """The oracle's new target: the successor of its `cycle_state` (before the first tile, the nearest
    reachable one); if it `forgot`, a uniformly random other reachable tile (by `u[3]`)."""
    n = labels.shape[0]
    successor = (cycle + 1) % n
    fresh = jnp.where(cycle >= 0, successor, _nearest(best_reach, jnp.ones(n, bool), inf))
    others = (best_reach < inf) & ((labels != successor) | (cycle < 0))
    rank = jnp.floor(u[3] * others.sum()) if u is not None else 0.0
    wrong_pick = jnp.argmax(others & (jnp.cumsum(others) > rank))
    return jnp.where(forgot & others.any(), wrong_pick, fresh).astype(jnp.int32)


def _decide(key, spec, env_params, state, agent, memory, reward, reset, cost):
    """`act_one` given the (already refreshed) cost fields."""
    inf = _inf(env_params)
    n = cost.shape[0]
    labels = jnp.arange(n, dtype=jnp.int32)
    # One draw serves every random choice (threefry is slow to compile): explore, random action, forget,
    # the oracle's wrong tile.
    u = jax.random.uniform(key, (4,)) if spec.epsilon > 0 or spec.forget > 0 else None
    pos, direction = state.pos[agent], state.dir[agent]
    x, y = pos[0], pos[1]
    entered = ~reset & jnp.any(pos != memory.pos) & (state.grid[y, x] == BONUS)
    label = state.goal_id[y, x].astype(jnp.int32)
    start_last = state.cycle_state[agent] if env_params.layout == "goalcycle" else jnp.int32(-1)
    last = jnp.where(reset, start_last, memory.last)
    chain_start = jnp.where(reset, start_last, memory.chain_start)
    succ = jnp.where(reset, -1, memory.succ)
    mistake = memory.mistake & ~reset
    forgot = jnp.array(False)
    if spec.forget > 0 and spec.kind != "navigator":
        forgot = u[2] < spec.forget

    reach = _neighbour_costs(cost, pos, inf)  # [T, 4]
    best_reach = reach.min(-1)
    if spec.kind == "explorer":
        last, chain_start, succ, mistake = _learn_order(
            labels, entered, label, reward, forgot, last, chain_start, succ, mistake
        )
        fresh = _explorer_target(labels, best_reach, last, chain_start, succ, mistake, inf)
    elif spec.kind == "oracle":
        fresh = _oracle_target(labels, best_reach, state.cycle_state[agent], forgot, u, inf)
    else:
        fresh = jnp.int32(0)
    event = reset | entered | forgot | (memory.target < 0)
    target = jnp.where(event, fresh, memory.target).astype(jnp.int32)

    action = _steer(reach[jnp.maximum(target, 0)], direction, inf)
    action = jnp.where(target < 0, IDLE, action)
    if spec.epsilon > 0:
        random_action = jnp.minimum(jnp.floor(u[1] * NUM_ACTIONS), NUM_ACTIONS - 1).astype(jnp.int32)
        action = jnp.where(u[0] < spec.epsilon, random_action, action)
    new_memory = Memory(
        cost=cost,
        pos=pos,
        target=target,
        last=last.astype(jnp.int32),
        chain_start=chain_start.astype(jnp.int32),
        succ=succ.astype(jnp.int32),
        mistake=mistake,
    )
    return action.astype(jnp.int32), new_memory


def act_one(
    key: jax.Array,
    spec: ExpertSpec,
    env_params: EnvParams,
    state: EnvState,
    agent: int,
    memory: Memory,
    reward: jax.Array,
    reset: jax.Array,
) -> tuple[jax.Array, Memory]:
    """One expert step in one environment.

    Args:
        key: PRNG key (used by epsilon and forget).
        spec, env_params: static.
        state: the environment state the action is for.
        agent: static agent slot index.
        memory: this expert's memory from the previous call.
        reward: float32[] this agent's reward from the previous step (ignored when `reset`).
        reset: bool[] this step starts a new episode: the memory is re-initialised from `state` and the
            cost fields recomputed.
    Returns:
        int32[] action and the new memory.
    """
    reset = jnp.asarray(reset, bool)
    cost = jax.lax.cond(reset, lambda: cost_fields(env_params, state), lambda: memory.cost)
    return _decide(key, spec, env_params, state, agent, memory, jnp.asarray(reward, jnp.float32), reset, cost)


def act_batch(
    keys: jax.Array,
    spec: ExpertSpec,
    env_params: EnvParams,
    states: EnvState,
    agent: int,
    memory: Memory,
    reward: jax.Array,
    reset: jax.Array,
) -> tuple[jax.Array, Memory]:
    """`jax.vmap(act)` over a leading batch axis E of keys, states, memory, reward float32[E] and reset
    bool[E]; cost fields are computed (for every environment, kept where `reset`) only on steps where some
    environment resets. Returns int32[E] actions and the new memories."""
    reset = jnp.asarray(reset, bool)

    def recompute():
        fresh = jax.vmap(lambda s: cost_fields(env_params, s))(states)
        return jnp.where(reset[:, None, None, None], fresh, memory.cost)

    cost = jax.lax.cond(any_in_batch(reset), recompute, lambda: memory.cost)  # a cond under vmap too

    def one(key, state, mem, r, rs, c):
        return _decide(key, spec, env_params, state, agent, mem, r, rs, c)

    return jax.vmap(one)(keys, states, memory, jnp.asarray(reward, jnp.float32), reset, cost)
