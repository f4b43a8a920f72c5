"""What the driver decides chunk by chunk, as plain functions of its settings and a chunk's results: how
long the next chunk is (`plan_chunk`), whether to evaluate or save after it (`evaluates`, `checkpoint_due`),
what a chunk that ran holds (`Chunk`) and what its non-finite checks decide (`Check`, `check_chunk`), and the
seed axis of its results (`pool_seeds`, `seed_part`). `jaxsocial.run.driver` takes these steps and
`jaxsocial.run.outputs` writes their results."""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import numpy as np

from jaxsocial.run import nonfinite, schedule
from jaxsocial.run.config import DriverConfig


def plan_chunk(
    driver_cfg: DriverConfig, chunk_iterations: int, stages: tuple[schedule.Stage, ...], stage: int, it: int
) -> int:
    """The iterations of the chunk after iteration `it` in `stage`: `chunk_iterations`, or fewer so that it
    ends on the run's last iteration, the iteration before the next iteration-triggered stage and (with
    `driver_cfg.eval_envs`) an evaluation iteration."""
    n = min(chunk_iterations, driver_cfg.iterations - it)
    switch = schedule.next_start(stages, stage)
    if switch is not None and switch > it:
        n = min(n, switch - it)  # land exactly on the next stage's first iteration
    if driver_cfg.eval_envs:
        n = min(n, driver_cfg.eval_every - it % driver_cfg.eval_every)
    return n


def evaluates(driver_cfg: DriverConfig, end: int) -> bool:
    """Whether the learner is evaluated after iteration `end`: every `driver_cfg.eval_every`-th and the
    last."""
    return bool(driver_cfg.eval_envs) and (end % driver_cfg.eval_every == 0 or end == driver_cfg.iterations)


def checkpoint_due(driver_cfg: DriverConfig, it: int, last_saved: int) -> bool:
    """Whether iteration `it` is saved: `driver_cfg.checkpoint_every` after the last save, and the run's
    last."""
    return it - last_saved >= driver_cfg.checkpoint_every or it == driver_cfg.iterations


class Chunk(NamedTuple):
    """A chunk that ran: iterations `first` + 1 ... `first` + `n` in `stage`, its metrics (host arrays with a
    leading seed axis for several seeds), its non-finite checks (`nonfinite.KEY`, taken out of the metrics)
    and its speed in env steps per second and seed."""

    first: int
    n: int
    stage: int
    metrics: dict[str, np.ndarray]
    finite: dict[str, np.ndarray]
    sps: float


class Check(NamedTuple):
    """What a chunk's non-finite checks decide (`check_chunk`)."""

    failure: nonfinite.Failure | None  # the chunk's first non-finite iteration, if any
    stop: bool  # a failure with --on-nonfinite stop: the run stops without saving
    kept: int  # the iterations whose rows are written: up to the failure when stopping, else all
    failed: list[int]  # offsets in the chunk of the kept iterations that had non-finite values
    healthy_end: bool  # the chunk's last iteration passed every check: it may be saved and evaluated


def check_chunk(
    finite: dict[str, np.ndarray], learners: tuple[int, ...], seeds: int, on_nonfinite: str
) -> Check:
    """`Check` of a chunk's checks {quantity: bool[n, S_l]} (bool[K, n, S_l] for `seeds` K > 1); an
    iteration counts as non-finite when it is in any seed."""
    failed = nonfinite.failures(finite).reshape(seeds, -1).any(axis=0)  # bool[n], over seeds
    failure = nonfinite.first_failure(finite, learners, seeds)
    stop = failure is not None and on_nonfinite == "stop"
    kept = failure.offset + 1 if stop else len(failed)
    return Check(failure, stop, kept, np.flatnonzero(failed[:kept]).tolist(), not failed[-1])


def pool_seeds(metrics: dict[str, np.ndarray], seeds: int) -> dict[str, np.ndarray]:
    """A chunk's metrics with the seeds' iterations as one axis ([K * n, ...]), as one seed's read."""
    return jax.tree.map(lambda m: m.reshape(-1, *m.shape[2:]), metrics) if seeds > 1 else metrics


def seed_part(tree: Any, k: int, seeds: int) -> Any:
    """Seed k's part of `tree`, whose leaves have a leading seed axis when there are several `seeds`."""
    return tree if seeds == 1 else jax.tree.map(lambda x: x[k], tree)
