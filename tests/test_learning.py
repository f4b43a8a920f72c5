"""Learning tests: on small, easy configurations the learner's return rises clearly within a CI budget."""

import jax
import numpy as np
import pytest
from conftest import SOLO_LEARNING, mean_return

from jaxsocial.agents.bc import BCConfig
from jaxsocial.agents.network import NetworkConfig
from jaxsocial.run.config import TrainConfig
from jaxsocial.train import make_train


@pytest.mark.slow
def test_return_rises_on_small_goal_cycle():
    """`SOLO_LEARNING`: a random policy collects about 0.2 per episode; 200 iterations reach well above 2."""
    cfg = SOLO_LEARNING
    _, _, train = make_train(cfg)
    _, metrics = jax.jit(train)(jax.random.key(0))
    returns, episodes = np.asarray(metrics["return"])[:, 0], np.asarray(metrics["episodes"])[:, 0]
    first, last = mean_return(returns[:20], episodes[:20]), mean_return(returns[-20:], episodes[-20:])
    assert first < 1.0, first
    assert last > 2.0 and last > first + 1.5, (first, last)


@pytest.mark.slow
def test_behaviour_cloning_of_navigators_beats_random():
    """BC from two scripted navigators' views and actions on a 9x9 Four Rooms: the cloned policy, acting
    in the learner slot, starts near the random return (about 0.03) and reaches several times it."""
    cfg = TrainConfig(
        env="fourrooms",
        env_args="width=9,height=9,max_steps=30",
        slots="learner,expert:navigator,expert:navigator",
        algo="bc",
        num_envs=16,
        rollout_steps=16,
        iterations=120,
        net=NetworkConfig(conv_channels=(8, 16, 16), hidden=32, mlp=32),
        bc=BCConfig(lr=3e-3, epochs=4),
    )
    _, _, train = make_train(cfg)
    _, metrics = jax.jit(train)(jax.random.key(0))
    returns, episodes = np.asarray(metrics["return"])[:, 0], np.asarray(metrics["episodes"])[:, 0]
    first, last = mean_return(returns[:20], episodes[:20]), mean_return(returns[-20:], episodes[-20:])
    assert first < 0.06, first
    assert last > 0.12 and last > 3 * first, (first, last)
    accuracy = np.asarray(metrics["bc_accuracy"])[:, 0]
    assert accuracy[-20:].mean() > accuracy[:20].mean() + 0.1
