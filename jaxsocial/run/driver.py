"""The training driver's state between chunks (`Driver`) and its steps: start-up (from scratch, a checkpoint
or `--init-from`), planning a chunk (`plan_chunk`), compiling it, running it, checking it for non-finite
values (`check_chunk`) and saving every seed's checkpoint and policy. `jaxsocial.train.train_chunks` loops
over them; what process 0 writes (metrics rows, evaluations, progress) is `jaxsocial.train.Outputs`.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import jax
import numpy as np

from jaxsocial.agents import policy_io, population
from jaxsocial.run import checkpoint, config, distributed, init_from, loop, nonfinite, rundir, schedule
from jaxsocial.run.config import TrainConfig, config_dict
from jaxsocial.run.loop import Program, RunnerState


def plan_chunk(cfg: TrainConfig, stages: tuple[schedule.Stage, ...], stage: int, it: int) -> int:
    """The iterations of the chunk after iteration `it` in `stage`: `cfg.chunk_iterations`, or fewer so that
    it ends on the run's last iteration, the iteration before the next iteration-triggered stage and (with
    `cfg.eval_envs`) an evaluation iteration."""
    n = min(cfg.chunk_iterations, cfg.iterations - it)
    switch = schedule.next_start(stages, stage)
    if switch is not None and switch > it:
        n = min(n, switch - it)  # land exactly on the next stage's first iteration
    if cfg.eval_envs:
        n = min(n, cfg.eval_every - it % cfg.eval_every)
    return n


def evaluates(cfg: TrainConfig, end: int) -> bool:
    """Whether the learner is evaluated after iteration `end`: every `cfg.eval_every`-th and the last."""
    return bool(cfg.eval_envs) and (end % cfg.eval_every == 0 or end == cfg.iterations)


def checkpoint_due(cfg: TrainConfig, it: int, last_saved: int) -> bool:
    """Whether iteration `it` is saved: `cfg.checkpoint_every` after the last save, and the run's last."""
    return it - last_saved >= cfg.checkpoint_every or it == cfg.iterations


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


def stage_program(cfg: TrainConfig, static: config.Setup, mesh: jax.sharding.Mesh, stage: int) -> Program:
    """The compiled program of `cfg` in `stage` (-1: before the first), cached by `loop.compiled` (stages
    with the same environment share one)."""
    return loop.compiled(cfg, mesh, env_params=static.stage(stage), pop=static.pop)


def source_state(seed_dir: Path, iteration: int) -> RunnerState:
    """The RunnerState of the source's checkpoint `iteration` (host arrays)."""
    source = init_from.source_config(seed_dir)
    static = config.setup(source, load_frozen=False)
    init, _ = loop.make_program(source.program, static.stage(-1), static.pop)
    template = jax.eval_shape(init, jax.random.key(0))
    return checkpoint.restore(rundir.checkpoints(seed_dir), template, iteration)


def load_source_learners(cfg: TrainConfig, state: RunnerState, program: Program) -> RunnerState:
    """The freshly initialised `state` ([K, ...] for K seeds) with the learners' params and optimiser state
    of `cfg.init_from` (`jaxsocial.run.init_from`), placed as `program` places its state; `state` itself
    without `init_from`. Called only for a state at iteration 0 (a resumed run with a checkpoint keeps its
    own)."""
    if not cfg.init_from:
        return state
    iteration = init_from.source_iteration(cfg)
    loaded = [source_state(d, iteration) for d in init_from.source_dirs(cfg)]
    learned: Any = [(s.params, s.opt_state) for s in loaded]
    params, opt_state = learned[0] if cfg.seeds == 1 else population.stack(learned)
    ours = jax.tree.map(lambda x: (x.shape, x.dtype), (state.params, state.opt_state))
    theirs = jax.tree.map(lambda x: (x.shape, x.dtype), (params, opt_state))
    if ours != theirs:
        raise ValueError(
            f"--init-from {cfg.init_from}: the learners' params or optimiser state differ in shape"
        )
    placed = distributed.put((params, opt_state), (program.shardings.params, program.shardings.opt_state))
    return state._replace(params=placed[0], opt_state=placed[1])


@dataclasses.dataclass
class Driver:
    """The training state between chunks, which every process holds and steps alike: the runner state and
    stage, the iterations done (`it`), the latest saved iteration and the chunks compiled so far."""

    cfg: TrainConfig
    static: config.Setup
    mesh: jax.sharding.Mesh
    seeds: list[tuple[TrainConfig, Path]]  # (config, directory) of each seed (`train.seed_runs`)
    state: RunnerState
    stage: int
    frozen: Any  # the frozen slots' params on the mesh, or None
    it: int
    last_saved: int  # the latest checkpoint's iteration (the start when none was saved since)
    executables: dict[tuple[int, int], Any] = dataclasses.field(default_factory=dict)  # (stage, n) -> chunk

    @classmethod
    def start(
        cls,
        cfg: TrainConfig,
        static: config.Setup,
        mesh: jax.sharding.Mesh,
        seeds: list[tuple[TrainConfig, Path]],
    ) -> Driver:
        """Start-up: every seed's initial state in the stage a new run starts in or, with `cfg.resume`,
        the state and stage of the latest checkpoint (`restore_seeds`); at iteration 0, `--init-from`'s
        learners."""
        stage = schedule.initial_index(static.stages)
        program = stage_program(cfg, static, mesh, stage)
        state = program.init(np.asarray([c.seed for c, _ in seeds] if cfg.seeds > 1 else cfg.seed, np.int32))
        frozen = static.frozen_params
        if frozen is not None:
            frozen = distributed.put(frozen, jax.tree.map(lambda _: distributed.replicated(mesh), frozen))
        if cfg.resume:
            state, stage = restore_seeds(
                cfg, [rundir.checkpoints(d) for _, d in seeds], state, program, stage
            )
        it = int(np.asarray(state.iteration).reshape(-1)[0])
        if it == 0:  # a new run, or a resumed one that saved nothing yet: from the source's learners
            state = load_source_learners(cfg, state, program)
        return cls(cfg, static, mesh, seeds, state, stage, frozen, it, last_saved=it)

    def compile(self, n: int, announce: Callable[[int, int], None]) -> float | None:
        """Compile step: the chunk of `n` iterations in the current stage, ahead of time (so that its speed
        excludes compiling), after `announce(n, stage)`; the seconds it took, or None if compiled before."""
        if (self.stage, n) in self.executables:
            return None
        announce(n, self.stage)
        t0 = time.perf_counter()
        program = stage_program(self.cfg, self.static, self.mesh, self.stage)
        self.executables[self.stage, n] = program.run_chunk.lower(self.state, self.frozen, n).compile()
        return time.perf_counter() - t0

    def run_chunk(self, n: int) -> Chunk:
        """Run step: the compiled chunk of `n` iterations (`compile` first) from the current state, which
        it replaces (`it` stays the chunk's first, until the loop moves it on)."""
        t0 = time.perf_counter()
        self.state, metrics = self.executables[self.stage, n](self.state, self.frozen)
        metrics = jax.device_get(metrics)
        sps = n * self.cfg.num_envs * self.cfg.rollout_steps / (time.perf_counter() - t0)  # per seed
        finite = metrics.pop(nonfinite.KEY)
        return Chunk(self.it, n, self.stage, metrics, finite, sps)

    def switch_stage(self, learner_return: float | None) -> None:
        """Switch-stage step after the chunk that ended at `it`, with the learners' mean return in it over
        all seeds (None: no episode finished): into the next stage if it starts now (`schedule.advance`)."""
        self.stage = schedule.advance(self.static.stages, self.stage, self.it, learner_return)

    def save(self, healthy: bool) -> None:
        """Save step: every seed's policy and checkpoint at iteration `it` (`save_seeds`) if the chunk that
        ended there was `healthy` (its last iteration finite); otherwise a warning that it is not saved."""
        if healthy:
            save_seeds(self.cfg, self.seeds, self.it, self.state, self.stage)
            self.last_saved = self.it
        elif distributed.is_main():
            print(f"warning: iteration {self.it} is not finite: not saved as a checkpoint or policy",
                  file=sys.stderr)  # fmt: skip


def save_seeds(
    cfg: TrainConfig, seeds: list[tuple[TrainConfig, Path]], it: int, state: RunnerState, stage: int
) -> None:
    """Policy, then checkpoint (with the stage to resume in), of every seed at iteration `it` (every process
    takes part). The policy goes first, so a checkpoint always has its policy: an interruption between the
    two leaves a policy ahead of the checkpoints, which the resumed run reaches again (and skips)."""
    host = distributed.to_host(state)
    for k, (seed_cfg, seed_dir) in enumerate(seeds):
        seed_state = seed_part(host, k, cfg.seeds)
        export_policy(cfg, seed_dir, it, seed_state.params)
        ckpt_dir = rundir.checkpoints(seed_dir)
        if it not in checkpoint.all_steps(ckpt_dir):  # else saved before an interruption: the same state
            metadata = {**config_dict(seed_cfg), "stage": stage}
            checkpoint.save(ckpt_dir, it, seed_state, metadata=metadata, keep=cfg.keep_checkpoints)


def export_policy(cfg: TrainConfig, seed_dir: Path, it: int, params: Any) -> None:
    """Write the learners' params (stacked [S_l, ...]) to `seed_dir/policy/<it>` unless that step exists."""
    policy_io.export_policy(
        seed_dir, it, params, cfg.net, slots=population.format_slots(cfg.slots), keep=cfg.keep_checkpoints
    )


def restore_seeds(
    cfg: TrainConfig, ckpt_dirs: list[Path], state: RunnerState, program: Program, stage: int
) -> tuple[RunnerState, int]:
    """The state and stage from the latest checkpoint that every seed has and can read (unchanged if none
    has one). An unreadable checkpoint (a truncated or emptied file) is skipped with a warning naming it, for
    the one before; a checkpoint of another config raises. A seed whose policy export is missing at that
    step (an interruption between the two writes of an older version) gets it re-exported."""
    steps = [checkpoint.all_steps(d) for d in ckpt_dirs]
    if not any(steps):
        return state, stage
    if not all(steps):
        missing = [str(d.parent) for d, s in zip(ckpt_dirs, steps, strict=True) if not s]
        raise ValueError(f"cannot resume: no checkpoint in {missing}; start again with --overwrite")
    lead = int(cfg.seeds > 1)
    template = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape[lead:], x.dtype), state)
    for step in sorted(set.intersection(*map(set, steps)), reverse=True):
        try:
            restored = [checkpoint.restore(d, template, step) for d in ckpt_dirs]
            stage = int(checkpoint.read_metadata(ckpt_dirs[0], step).get("stage", stage))
        except checkpoint.CheckpointMismatchError:
            raise
        except Exception as err:  # noqa: BLE001 - orbax, json and OS errors of a damaged checkpoint
            where = [str(d / str(step)) for d in ckpt_dirs]
            print(f"warning: {where} unreadable ({type(err).__name__}: {err}); trying the checkpoint before",
                  file=sys.stderr)  # fmt: skip
            continue
        for restored_state, ckpt_dir in zip(restored, ckpt_dirs, strict=True):
            export_policy(cfg, ckpt_dir.parent, step, restored_state.params)
        host = restored[0] if cfg.seeds == 1 else population.stack(restored)
        return distributed.put(host, program.shardings), stage
    raise ValueError(f"cannot resume: no readable checkpoint in {[str(d) for d in ckpt_dirs]}")
