"""Learning tests: on small, easy configurations the learner's return rises clearly within a CI budget."""

import dataclasses
import functools

import jax
import numpy as np
import pytest
from conftest import RUN_FAST, SOLO_LEARNING, mean_return

from jaxsocial.agents.bc_config import BCConfig
from jaxsocial.agents.fast import options
from jaxsocial.agents.network import NetworkConfig
from jaxsocial.run.config import TrainConfig
from jaxsocial.train import make_train


@functools.cache
def solo_learning(dtype: str) -> tuple[float, float]:
    """`SOLO_LEARNING` in `dtype` from key 0 (trained once per test process, compiled to run fast): the mean
    returns of its first and last 20 iterations."""
    cfg = dataclasses.replace(SOLO_LEARNING, net=dataclasses.replace(SOLO_LEARNING.net, dtype=dtype))
    _, _, train = make_train(cfg)
    _, metrics = jax.jit(train, compiler_options=RUN_FAST)(jax.random.key(0))
    returns, episodes = np.asarray(metrics["return"])[:, 0], np.asarray(metrics["episodes"])[:, 0]
    return mean_return(returns[:20], episodes[:20]), mean_return(returns[-20:], episodes[-20:])


@pytest.mark.slow
def test_return_rises_on_small_goal_cycle():
    """`SOLO_LEARNING`: a random policy collects about 0.2 per episode; 200 iterations reach well above 2."""
    first, last = solo_learning("float32")
    assert first < 1.0, first
    assert last > 2.0 and last > first + 1.5, (first, last)


@pytest.mark.slow
def test_bfloat16_learns_like_float32():
    """`SOLO_LEARNING` in both dtypes from the same seed: bfloat16 also learns (first 20 iterations below 1,
    last 20 above 2) and ends within 1.0 of float32's final return (half the rise the learning test demands;
    rounding makes the two runs' trajectories diverge, so their returns agree in distribution, not step by
    step). The float32 run is `test_return_rises_on_small_goal_cycle`'s."""
    finals = {}
    for dtype in options.DTYPES:
        first, finals[dtype] = solo_learning(dtype)
        assert first < 1.0 and finals[dtype] > 2.0, (dtype, first, finals[dtype])
    assert abs(finals["bfloat16"] - finals["float32"]) < 1.0, finals


@pytest.mark.slow
def test_behaviour_cloning_of_navigators_beats_random():
    """BC from two scripted navigators' views and actions on a 9x9 Four Rooms: the cloned policy, acting
    in the learner slot, starts near the random return (about 0.03) and reaches ten times it. After 200
    iterations keys 0-3 end at 0.56-0.61 (accuracy 0.97) under LLVM levels 1 and 3 alike; after 120 they
    were still rising, anywhere from 0.09 to 0.58, so the bits of one compiler setting decided the test."""
    cfg = TrainConfig(
        env="fourrooms",
        env_args="width=9,height=9,max_steps=30",
        slots="learner,expert:navigator,expert:navigator",
        algo="bc",
        num_envs=16,
        rollout_steps=16,
        iterations=200,
        net=NetworkConfig(conv_channels=(8, 16, 16), hidden=32, mlp=32),
        bc=BCConfig(lr=3e-3, epochs=4),
    )
    _, _, train = make_train(cfg)
    _, metrics = jax.jit(train, compiler_options=RUN_FAST)(jax.random.key(0))
    returns, episodes = np.asarray(metrics["return"])[:, 0], np.asarray(metrics["episodes"])[:, 0]
    first, last = mean_return(returns[:20], episodes[:20]), mean_return(returns[-20:], episodes[-20:])
    assert first < 0.06, first
    assert last > 0.3, (first, last)
    accuracy = np.asarray(metrics["bc_accuracy"])[:, 0]
    assert accuracy[-20:].mean() > accuracy[:20].mean() + 0.1
