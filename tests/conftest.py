"""Shared, compiled-once helpers for the test suite (jit compile time dominates on CPU)."""

import tempfile
from pathlib import Path

import jax
import pytest

from jaxsocial import compile_cache
from jaxsocial.env import core
from jaxsocial.env.observe import observe


def pytest_configure(config):
    """One persistent XLA cache for every test process: the pytest-xdist workers (and later runs) load the
    programs another one compiled (the same training programs recur across test files) instead of
    compiling them again. Keyed by program, JAX version and devices, so it is safe to share."""
    compile_cache.enable(Path(tempfile.gettempdir()) / "jaxsocial-tests-xla-cache", min_compile_seconds=1.0)


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
