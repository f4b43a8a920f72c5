"""Shared, compiled-once helpers for the test suite (jit compile time dominates on CPU)."""

import jax
import pytest

from jaxsocial.env import core
from jaxsocial.env.observe import observe


@pytest.fixture(scope="session")
def step_env():
    """Jitted `core.step_env(state, actions, params)`."""
    return jax.jit(core.step_env)


@pytest.fixture(scope="session")
def observe_fn():
    """Jitted `observe(state, params)`."""
    return jax.jit(observe)


@pytest.fixture(scope="session")
def rollout():
    """Jitted `rollout(state, actions int32[T, N], params)`: T steps of `step_env` (no auto-reset) in one
    scan. Returns (obs, states, rewards, terminated, truncated), each stacked on a leading T axis."""

    def run(state, actions, params):
        def body(s, a):
            obs, s, reward, terminated, truncated = core.step_env(s, a, params)
            return s, (obs, s, reward, terminated, truncated)

        return jax.lax.scan(body, state, actions)[1]

    return jax.jit(run)
