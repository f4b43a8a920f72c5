"""Shared, compiled-once helpers for the test suite (jit compile time dominates on CPU)."""

import dataclasses
import os
import tempfile
from pathlib import Path

import jax
import pytest
from xdist.scheduler import LoadScopeScheduling

from jaxsocial import train
from jaxsocial.agents.network import NetworkConfig
from jaxsocial.agents.ppo_config import PPOConfig
from jaxsocial.env import core
from jaxsocial.env.observe import observe
from jaxsocial.run import compile_cache, rundir
from jaxsocial.run.config import TrainConfig

RESULTS = Path(__file__).resolve().parents[1] / "benchmarks" / "results"


def needs_records(*folders: str) -> pytest.MarkDecorator:
    """Skip a test where this checkout lacks committed results it reads, `folders` under benchmarks/results/
    (`records/tiny`, `inflight/h1_prereg-gpu`): a code-only clone leaves out records/ and inflight/ (README,
    "Set up"). The reason names the folders missing."""
    missing = [f"benchmarks/results/{f}" for f in folders if not (RESULTS / f).is_dir()]
    return pytest.mark.skipif(bool(missing), reason=f"needs {', '.join(missing)} (not in this checkout)")


TINY_ENV_ARGS = "max_steps=6,width=7,height=7"  # an episode ends in every 8-step rollout
TINY_SLOTS = (
    "learner,random,random"  # scripted experts cost compile time; the CLI test runs the default slots
)
TINY = TrainConfig(
    env="goalcycle3",
    env_args=TINY_ENV_ARGS,
    slots=TINY_SLOTS,
    num_envs=4,
    rollout_steps=8,
    iterations=4,
    chunk_iterations=2,
    checkpoint_every=2,
    progress=False,
    net=NetworkConfig(conv_channels=(4, 8, 8), hidden=16, mlp=8),
    ppo=PPOConfig(segment_length=4, minibatch_segments=4, num_minibatches=2, lr=3e-3),
)
"""The tiny training run the test files share (one compiled program, in the persistent cache below)."""

SOLO_LEARNING = TrainConfig(
    env="goalcycle3-solo",
    env_args="width=7,height=7,n_goals=2,penalty=0.0,max_steps=32",
    num_envs=32,
    rollout_steps=32,
    iterations=200,
    net=NetworkConfig(conv_channels=(8, 16, 16), hidden=32, mlp=32),
    ppo=PPOConfig(lr=1e-3, entropy_coef=0.01, num_minibatches=4, minibatch_segments=32, segment_length=8,
                  kl_target=0.02, kl_hard_limit=0.05),
)  # fmt: skip
"""A run whose return rises clearly: solo, 7x7, two tiles, no penalty, 32-step episodes (a random policy
collects about 0.2 per episode; 200 iterations, 205k steps, under a minute on 2 cores, reach well above 2)."""


def mean_return(returns, episodes) -> float:
    """The mean return over the episodes of iterations with `returns` (per-iteration means) and `episodes`."""
    return float((returns * episodes).sum() / episodes.sum())


_TINY_NET_PPO_FLAGS = [
    "--net.conv-channels", "4", "8", "8", "--net.hidden", "16", "--net.mlp", "8",
    "--ppo.segment-length", "4", "--ppo.minibatch-segments", "4", "--ppo.num-minibatches", "2",
]  # fmt: skip
TINY_FLAGS = [
    "--env-args", TINY_ENV_ARGS, "--num-envs", "4", "--rollout-steps", "8", "--iterations", "2",
    "--chunk-iterations", "1", *_TINY_NET_PPO_FLAGS, "--no-progress",
]  # fmt: skip
"""Command-line flags of a 2-iteration run of TINY's sizes with the environment's default slots."""
TINY_RUN_FLAGS = [
    "--env-args", TINY_ENV_ARGS, "--slots", TINY_SLOTS, "--num-envs", "4", "--rollout-steps", "8",
    "--iterations", "4", "--chunk-iterations", "2", "--checkpoint-every", "2", *_TINY_NET_PPO_FLAGS,
    "--ppo.lr", "3e-3", "--no-progress",
]  # fmt: skip
"""TINY itself as command-line flags."""


U32 = 2.0**-24
"""float32's unit roundoff u: one operation's result is within a relative u of the exact one (round to
nearest), on every machine; tolerances below are multiples of it derived from each computation."""


def reordered_tolerance(terms: int, depth: int, scale: float = 1.0) -> float:
    """A bound on the difference of two float32 evaluations of a network that differ only in the order of
    their sums (another blocking of the matrix products, vector width or fusion, as on other CPUs): a dot
    product of `terms` products is within terms * u * sum|products| of the exact value (Higham, Accuracy
    and Stability of Numerical Algorithms, eq. 3.5, to first order), so two orders differ by at most twice
    that per layer, `scale` bounding sum|products|; through `depth` layers with 1-Lipschitz activations
    and weights of norm <= 1, as initialised, the differences add up."""
    return 2 * depth * terms * U32 * scale


def metrics_without_speed(run_dir):
    """A run's metrics rows without the timings (which differ between equal runs)."""
    timing = ("env_steps_per_s", "compile_s")
    return [{k: v for k, v in row.items() if k not in timing} for row in rundir.read_metrics(run_dir)]


TEST_XLA_FLAGS = {"xla_backend_optimization_level": "0", "xla_cpu_use_fusion_emitters": "false"}
"""XLA flags that compile for the tests, not for speed (the programs' HLO is optimised as usual): LLVM at
optimisation level 0, and XLA's loop emitters in place of its fusion emitters. TINY's training chunk compiles
in 5.01 s under them, 8.56 s at level 0 alone, 11.98 s with XLA's defaults (benchmarks/compile_flags.py,
docs/benchmarks.md)."""

RUN_FAST = {"xla_backend_optimization_level": 1, "xla_cpu_use_fusion_emitters": True}
"""`jax.jit(f, compiler_options=RUN_FAST)`: code generation for the programs whose run time outweighs their
compile time under `TEST_XLA_FLAGS` (the learning tests' hundreds of iterations): LLVM at level 1 with XLA's
fusion emitters. Their 10 iterations run about 3x faster than under `TEST_XLA_FLAGS` and a sixth slower than
under XLA's defaults (level 3), and compile in about two thirds of the defaults' time
(`benchmarks/compile_flags.py`, docs/benchmarks.md)."""


def pytest_configure(config):
    """Compile for the tests: `TEST_XLA_FLAGS`, each unless $XLA_FLAGS sets it (set one there to test with
    another value). They apply to this process and the subprocesses the tests start.

    One persistent XLA cache for every test process: the pytest-xdist workers (and later runs) load the
    programs another one compiled (the same training programs recur across test files) instead of
    compiling them again. Keyed by program, JAX version, flags and devices, and kept per CPU kind and
    visible-core count (`compile_cache.enable`), so it is safe to share, also between runs of the suite whose
    processes see different numbers of cores."""
    flags = os.environ.get("XLA_FLAGS", "")
    added = [f"--{name}={value}" for name, value in TEST_XLA_FLAGS.items() if name not in flags]
    os.environ["XLA_FLAGS"] = " ".join([flags, *added]).strip()
    cache = Path(tempfile.gettempdir()) / "jaxsocial-tests-xla-cache"
    os.environ["JAX_COMPILATION_CACHE_DIR"] = str(cache)  # the subprocesses' too (and `experiments` jobs')
    compile_cache.enable(cache, min_compile_seconds=1.0)


SHARED_RUNS = {"test_cli_errors", "test_inflight", "test_init_from", "test_loggers", "test_plot",
               "test_regimes", "test_render", "test_scale", "test_train", "test_verify"}  # fmt: skip
"""Test files that train TINY's programs (`two_seed_run` and single-seed runs of TINY)."""


class FileGroups(LoadScopeScheduling):
    """With `pytest -n N`, each test file runs on one worker, and the files of SHARED_RUNS together on one,
    so that module fixtures and the programs a file compiles are made once (TINY's programs once, in the
    in-process cache). Groups by the file in each test's node id: pytest 9.2 ignores the node-id suffix
    that xdist's own `--dist loadgroup` writes, which spread every file over both workers."""

    def _split_scope(self, nodeid: str) -> str:
        path = nodeid.split("::", 1)[0]
        return "tiny-runs" if Path(path).stem in SHARED_RUNS else path


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    """`FileGroups` schedules the tests over the workers."""
    return FileGroups(config, log)


@pytest.fixture(scope="session")
def two_seed_run(tmp_path_factory):
    """TINY with two seeds in one (vmapped) program, `run_name` 'tiny': the run directory, with one run
    directory per seed (s0, s1). Read only."""
    runs_dir = tmp_path_factory.mktemp("two-seeds")
    cfg = dataclasses.replace(TINY, runs_dir=str(runs_dir), run_name="tiny", seeds=2, seed_batching="vmap")
    return train.run(cfg)


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
