"""Scale-out: seeds in one program, data parallelism over devices and processes, bad input, compile cache.

Runs with several devices or processes are subprocesses (XLA_FLAGS must be set before JAX starts; this
process keeps one device); their metrics are compared with one-device runs made here.
"""

import dataclasses
import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest
from conftest import TINY, TINY_RUN_FLAGS, metrics_without_speed

from jaxsocial.run import checkpoint, compile_cache, cpuinfo, distributed, policy_io
from jaxsocial.train import run

REPO = Path(__file__).resolve().parent.parent


def assert_same_metrics(a: Path, b: Path) -> None:
    """Equal episode counts; other metrics equal up to floating-point summation order."""
    rows_a, rows_b = metrics_without_speed(a), metrics_without_speed(b)
    assert len(rows_a) == len(rows_b) == TINY.iterations
    for row_a, row_b in zip(rows_a, rows_b, strict=True):
        assert row_a.keys() == row_b.keys()
        for key in row_a:
            if key.startswith(("episodes/", "iteration")):
                assert row_a[key] == row_b[key], key
            else:
                np.testing.assert_allclose(row_a[key], row_b[key], rtol=1e-4, atol=1e-5, err_msg=key)


def env_with(**extra: str) -> dict[str, str]:
    env = dict(
        os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))
    )
    return {**env, **extra}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def single_runs(tmp_path_factory):
    """One-device, one-seed runs of TINY with seeds 0 and 1."""
    root = tmp_path_factory.mktemp("single")
    return [run(dataclasses.replace(TINY, runs_dir=str(root), run_name=f"s{s}", seed=s)) for s in (0, 1)]


def test_seeds_in_one_program_equal_separate_runs(tmp_path, single_runs, two_seed_run):
    run_dir = two_seed_run  # TINY's two seeds, vmapped
    cfg = dataclasses.replace(TINY, runs_dir=str(tmp_path), seeds=2, seed_batching="vmap")
    assert json.loads((run_dir / "config.json").read_text())["seeds"] == 2
    for seed, single in enumerate(single_runs):
        seed_dir = run_dir / f"s{seed}"
        config = json.loads((seed_dir / "config.json").read_text())
        assert config["seed"] == seed and config["seeds"] == 1
        assert checkpoint.all_steps(seed_dir / "checkpoints") == [2, 4]
        assert_same_metrics(seed_dir, single)
    # Each seed directory is a run of its own: its policy plays in a frozen slot.
    policies = [policy_io.load_policy(str(run_dir / f"s{s}"), TINY.net) for s in (0, 1)]
    assert not np.array_equal(*(jax.tree.leaves(p)[0] for p in policies))
    # An interrupted run of several seeds resumes to the same metrics.
    run(dataclasses.replace(cfg, run_name="cut", iterations=2))
    resumed = run(dataclasses.replace(cfg, run_name="cut", resume=True))
    for seed in (0, 1):
        assert metrics_without_speed(resumed / f"s{seed}") == metrics_without_speed(run_dir / f"s{seed}")


def _train(cli: list[str], processes: int = 1, **env: str) -> None:
    """Run the training command `cli` in `processes` processes at once (process ids 0.. through a local
    coordinator when more than one), with `env` added; each must exit 0."""
    if processes > 1:
        coordinator = ["--coordinator", f"127.0.0.1:{free_port()}", "--num-processes", str(processes)]
        commands = [[*cli, *coordinator, "--process-id", str(i)] for i in range(processes)]
    else:
        commands = [cli]
    pipes = {"stdout": subprocess.PIPE, "stderr": subprocess.PIPE, "text": True}
    started = [subprocess.Popen(command, env=env_with(**env), **pipes) for command in commands]
    for proc in started:
        _, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, err[-3000:]


@pytest.mark.slow  # a subprocess with two host devices compiles programs of its own
def test_two_devices_match_one_device_and_fill_a_compile_cache(tmp_path, single_runs):
    """Two host devices in one process (two seeds, seeds mapped) give the metrics of one device; the run
    fills a compilation cache, which the cache's command clears."""
    cli = [sys.executable, "-m", "jaxsocial.train", *TINY_RUN_FLAGS, "--runs-dir", str(tmp_path)]
    cli += ["--run-name", "d2", "--devices", "2", "--seeds", "2", "--seed-batching", "map"]
    flags = f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count=2"
    _train([*cli, "--compile-cache", str(tmp_path / "cache")], XLA_FLAGS=flags)
    for seed, single in enumerate(single_runs):
        assert_same_metrics(tmp_path / "d2" / f"s{seed}", single)
    assert compile_cache.entries(tmp_path / "cache")
    cleared = subprocess.run(
        [sys.executable, "-m", "jaxsocial.run.compile_cache", str(tmp_path / "cache"), "--clear"],
        env=env_with(),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert cleared.returncode == 0 and "cleared" in cleared.stdout, cleared.stderr
    assert not compile_cache.entries(tmp_path / "cache")


@pytest.mark.slow  # two subprocesses compile programs of their own (multi-process equality)
def test_two_processes_match_one_device(tmp_path, single_runs):
    """Two processes with one device each, through a local coordinator, give the metrics of one device."""
    cli = [sys.executable, "-m", "jaxsocial.train", *TINY_RUN_FLAGS, "--runs-dir", str(tmp_path)]
    _train([*cli, "--run-name", "p2"], processes=2)
    assert_same_metrics(tmp_path / "p2", single_runs[0])
    assert checkpoint.all_steps(tmp_path / "p2" / "checkpoints") == [2, 4]


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"seeds": 0}, "seeds must be"),
        ({"seeds": -2}, "seeds must be"),
        ({"seed_batching": "pmap"}, "seed_batching"),
        ({"seeds": 2, "stages": "0:penalty=0.5;return>=1:penalty=1.0"}, "triggered by the return"),
        ({"devices": 2}, "2 devices requested but only 1"),
        ({"devices": -1}, "devices must be"),
        ({"coordinator": "localhost"}, "HOST:PORT"),
        ({"num_processes": 2}, "need a coordinator"),
        ({"coordinator": "localhost:1", "num_processes": 2, "process_id": 2}, "process_id"),
    ],
)
def test_bad_scale_input_fails_before_compiling(tmp_path, changes, message):
    with pytest.raises(ValueError, match=message):
        run(dataclasses.replace(TINY, runs_dir=str(tmp_path), **changes))
    assert not any(tmp_path.iterdir())  # nothing written
    assert not jax.distributed.is_initialized()


def test_batch_must_split_over_devices():
    with pytest.raises(ValueError, match="num_envs=6 does not split evenly over 4 devices"):
        distributed.check_batch(4, num_envs=6, minibatch_segments=8)
    with pytest.raises(ValueError, match="minibatch_segments=3"):
        distributed.check_batch(2, num_envs=4, minibatch_segments=3)
    distributed.check_batch(2, num_envs=4, minibatch_segments=4)


def test_compile_cache_command(tmp_path, capsys):
    compile_cache.main([str(tmp_path / "none")])
    assert "does not exist yet" in capsys.readouterr().out
    (tmp_path / "keep.txt").write_text("not a cache entry")
    (tmp_path / "jit_f-0123-cache").write_bytes(b"x" * 10)
    compile_cache.main([str(tmp_path)])
    assert "1 programs" in capsys.readouterr().out
    compile_cache.main([str(tmp_path), "--clear"])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.txt"]  # only the cache's own files go


ENABLE = "import sys; from jaxsocial.run import compile_cache; print(compile_cache.enable(sys.argv[1]))"
"""A process that enables the cache `argv[1]` and prints the directory its programs go to."""


def test_the_compile_cache_keeps_each_cpu_and_core_count_apart(tmp_path):
    """XLA's CPU code follows the CPU and how many cores the process sees, which JAX's key does not name: a
    process seeing one core and one seeing every core store and load in sub-directories of their own (a
    program compiled seeing two cores, loaded seeing one, trained other numbers than a fresh compile)."""
    cores = sorted(os.sched_getaffinity(0))
    pins = [[], ["taskset", "-c", str(cores[0])]] if len(cores) > 1 else [[]]
    dirs = [
        Path(
            subprocess.run(
                [*pin, sys.executable, "-c", ENABLE, str(tmp_path)],
                capture_output=True,
                text=True,
                timeout=120,
                check=True,
            ).stdout.strip()
        )
        for pin in pins
    ]
    kind = cpuinfo.slug(cpuinfo.model())
    assert [d.name for d in dirs] == [f"{kind}-{len(cores)}-cores", f"{kind}-1-cores"][: len(pins)]
    assert all(d.parent == tmp_path.absolute() and d.is_dir() for d in dirs)
    (dirs[0] / "jit_f-0123-cache").write_bytes(b"x")
    assert compile_cache.entries(tmp_path) == [dirs[0] / "jit_f-0123-cache"]  # the command sees them
