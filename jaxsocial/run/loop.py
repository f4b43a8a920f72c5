"""The compiled training loop: `make_program(program_cfg, env, slots) -> (init, run_chunk)` scans
`jaxsocial.agents.rollout.iteration` over iterations, and `compiled(program_cfg, mesh, env, slots)` jits it
as a `Program` placed on a device mesh (several seeds in one program), cached per program.
`jaxsocial.train.make_train(cfg)` builds the whole run of a `TrainConfig` as one function.

One iteration = a rollout of `rollout_steps` steps in `num_envs` environments followed by one update of
every learner, whose losses, parameters and optimiser state are checked for non-finite values
(`jaxsocial.run.nonfinite`). A chunk of iterations is one `lax.scan` inside one `jit`; the driver
(`jaxsocial.run.driver.train_chunks`) loops over chunks to log, checkpoint and draw progress.
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxsocial.agents import acting, population, rollout
from jaxsocial.agents.rollout import RunnerState
from jaxsocial.env.types import EnvParams
from jaxsocial.run import distributed, nonfinite
from jaxsocial.run.config import ProgramConfig

ENV_AXES = RunnerState(
    params=None,
    opt_state=None,
    env_states=0,
    obs=0,
    resets=0,
    slots=acting.SlotState(carry=1, memory=0, reward=0),
    demo_carry=1,  # the streams are environment-major
    episode_return=0,
    key=None,
    iteration=None,
)
"""The environment axis of the RunnerState's arrays, split over devices (pytree prefix; None: replicated)."""


def make_program(
    program_cfg: ProgramConfig,
    env_params: EnvParams,
    pop: population.Population,
    mesh: jax.sharding.Mesh | None = None,
):
    """The pure training functions of one program: `program_cfg` in the validated environment `env_params`
    with the slots `pop` (see `startup.setup`): `jaxsocial.agents.rollout.iteration` in a scan.

    Returns `(init, run_chunk)`: `init(key) -> RunnerState`; `run_chunk(state, frozen_params, n) ->
    (state, metrics)` runs n iterations (static n) in one scan, with the frozen slots' stacked params (or
    None). Metrics are dicts of arrays with a leading iteration axis; `metrics[nonfinite.KEY]` holds the
    iteration's finiteness checks ({quantity: bool[n, S_l]}). One seed (`program_cfg.seeds` is handled by
    `compiled`); `mesh`: the devices the environments will be split over (the PPO update then splits its
    minibatches over them too).
    """
    devices = distributed.data_parallel(mesh)
    w = rollout.wiring(
        pop,
        env_params,
        program_cfg.net,
        program_cfg.ppo,
        program_cfg.bc,
        program_cfg.algo,
        program_cfg.num_envs,
        program_cfg.rollout_steps,
    )

    def iteration(state: RunnerState, frozen_params):
        state, losses, (return_sum, episodes) = rollout.iteration(w, state, frozen_params, devices)
        episodes_per_slot = jnp.sum(episodes, 0)
        metrics = {
            "episodes": episodes_per_slot,
            "return": jnp.sum(return_sum, 0) / jnp.maximum(episodes_per_slot, 1.0),
            **losses,
            nonfinite.KEY: nonfinite.check(losses, state.params, state.opt_state),
        }
        return state._replace(iteration=state.iteration + 1), metrics

    def run_chunk(state: RunnerState, frozen_params, n: int):
        return jax.lax.scan(lambda s, _: iteration(s, frozen_params), state, None, length=n)

    return functools.partial(rollout.init, w), run_chunk


def over_seeds(run_chunk, batching: str = "vmap"):
    """`run_chunk` of `make_program` over a leading seed axis of the state and the metrics (the frozen params
    are shared): 'vmap' batches the seeds, 'map' runs them one after another (`lax.map`); both give every
    seed the result of a run of its own (vmap up to floating-point summation order)."""

    def run_seeds(state, frozen_params, n: int):
        if batching == "vmap":
            return jax.vmap(lambda s: run_chunk(s, frozen_params, n))(state)
        return jax.lax.map(lambda s: run_chunk(s, frozen_params, n), state)

    return run_seeds


def seed_batching(requested: str, mesh: jax.sharding.Mesh) -> str:
    """How `over_seeds` runs several seeds on `mesh`: `requested` ('vmap' or 'map'), or for 'auto' 'map' on
    CPUs and 'vmap' on accelerators."""
    if requested != "auto":
        return requested
    return "map" if mesh.devices.flat[0].platform == "cpu" else "vmap"


class Program(NamedTuple):
    """A run's compiled functions, placed on a device mesh.

    init(seeds): int32[] (or int32[K] for K seeds) -> RunnerState ([K, ...] for K seeds) on `shardings`;
    run_chunk(state, frozen_params, n) -> (state, metrics) (n static; the state is donated; metrics
    replicated, [K, n, ...] for K seeds); frozen params must be placed with `distributed.put`.
    """

    init: Any
    run_chunk: Any
    shardings: RunnerState
    mesh: jax.sharding.Mesh


@functools.lru_cache(maxsize=8)
def compiled(
    program_cfg: ProgramConfig,
    mesh: jax.sharding.Mesh,
    env_params: EnvParams,
    pop: population.Population,
) -> Program:
    """The `Program` of `program_cfg` in the validated environment `env_params` with the slots `pop`
    (`startup.Setup`) on `mesh` (`program_mesh`), shared between runs whose programs are the same (tests,
    notebooks, sweeps and a run's stages of one environment compile once)."""
    init, run_chunk = make_program(program_cfg, env_params, pop, mesh)
    if program_cfg.seeds > 1:  # each seed's state as in a run of its own, stacked
        run_chunk = over_seeds(run_chunk, seed_batching(program_cfg.seed_batching, mesh))
    replicated = distributed.replicated(mesh)

    def init_from_seed(seed):
        return init(jax.random.key(seed))

    one_seed = jax.eval_shape(init_from_seed, jax.ShapeDtypeStruct((), jnp.int32))
    shardings = distributed.state_shardings(one_seed, mesh, ENV_AXES)
    init_one = jax.jit(init_from_seed, in_shardings=replicated, out_shardings=shardings)
    program_init = init_one
    if program_cfg.seeds > 1:
        stacked = jax.eval_shape(population.stack, [one_seed] * program_cfg.seeds)
        shardings = distributed.state_shardings(stacked, mesh, ENV_AXES, offset=1)
        stack = jax.jit(population.stack, out_shardings=shardings)

        def program_init(seeds):
            return stack([init_one(np.int32(seed)) for seed in seeds])

    return Program(
        program_init,
        jax.jit(
            run_chunk,
            static_argnums=2,
            donate_argnums=0,
            in_shardings=(shardings, replicated),
            out_shardings=(shardings, replicated),
        ),
        shardings,
        mesh,
    )


def program_mesh(program_cfg: ProgramConfig, devices: int) -> jax.sharding.Mesh:
    """The `devices` (0: all) the environments of `program_cfg` are split over (ValueError, before
    compiling, if they do not split)."""
    sizes = {"num_envs": program_cfg.num_envs}
    if program_cfg.algo == "ppo":
        sizes["minibatch_segments"] = program_cfg.ppo.minibatch_segments
    return distributed.data_mesh(devices, **sizes)
