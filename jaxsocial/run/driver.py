"""The training driver's state between chunks (`Driver`), its steps (start-up from scratch, a checkpoint or
`--init-from`; compiling a chunk, running it, saving every seed's checkpoint and policy) and `train_chunks`,
the loop over them. What it decides from its `DriverConfig` (`driver_cfg`) and a chunk's results (planning,
non-finite checks) is `jaxsocial.run.chunks`; what process 0 writes (metrics rows, evaluations, progress) is
`jaxsocial.run.outputs.Outputs`.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import numpy as np

from jaxsocial.agents import population, rollout
from jaxsocial.agents.rollout import RunnerState
from jaxsocial.run import (
    checkpoint,
    distributed,
    init_from,
    interrupt,
    loop,
    metrics,
    nonfinite,
    policy_io,
    processes,
    rundir,
    schedule,
    startup,
)
from jaxsocial.run.chunks import Chunk, check_chunk, checkpoint_due, plan_chunk, pool_seeds, seed_part
from jaxsocial.run.config import DriverConfig, ProgramConfig, TrainConfig
from jaxsocial.run.loop import Program
from jaxsocial.run.outputs import Outputs, chunk_description, nothing_to_train, reached, stop_message
from jaxsocial.run.rundir import SeedRun
from jaxsocial.specs import CheckpointRef


def stage_program(
    program_cfg: ProgramConfig, static: startup.Setup, mesh: jax.sharding.Mesh, stage: int
) -> Program:
    """The compiled program of `program_cfg` in `stage` (-1: before the first), cached by `loop.compiled`
    (stages with the same environment share one)."""
    return loop.compiled(program_cfg, mesh, static.stage(stage), static.pop)


def ahead_of_time(jitted: Any, *args: Any) -> Any:
    """`jitted` traced and compiled for `args`, ahead of time: the executable."""
    return jitted.lower(*args).compile()


def restore_state(
    ckpt_dir: Path, template: RunnerState, step: int | None, observers: tuple[int, ...]
) -> RunnerState:
    """`checkpoint.restore` of one seed's RunnerState like `template`. A checkpoint written before programs
    rendered only the views they read holds every slot's views (obs [E, N, ...]); it is restored with the
    rows of the slots `observers` (`rollout.program_observers`), exactly the views the program renders."""
    stored = checkpoint.leaf_shapes(ckpt_dir, step).get(".obs")
    want = template.obs.shape
    n_slots = template.env_states.pos.shape[1]
    if stored is None or stored == want or stored != (want[0], n_slots, *want[2:]):
        return checkpoint.restore(ckpt_dir, template, step)
    every_view = template._replace(obs=jax.ShapeDtypeStruct(stored, template.obs.dtype))
    state = checkpoint.restore(ckpt_dir, every_view, step)
    return state._replace(obs=state.obs[:, np.asarray(observers)])


def source_state(seed_dir: Path, iteration: int) -> RunnerState:
    """The RunnerState of the source's checkpoint `iteration` (host arrays)."""
    source = init_from.source_config(seed_dir)
    static = startup.setup(source, load_frozen=False)
    init, _ = loop.make_program(source.program, static.stage(-1), static.pop)
    template = jax.eval_shape(init, jax.random.key(0))
    observers = rollout.program_observers(static.pop, source.program.algo)
    return restore_state(rundir.checkpoints(seed_dir), template, iteration, observers)


def load_source_learners(
    source: CheckpointRef | None, seeds: list[int], state: RunnerState, program: Program
) -> RunnerState:
    """The freshly initialised `state` of the run's `seeds` ([K, ...] for K > 1 seeds) with the learners'
    params and optimiser state of `source` (`--init-from`, `jaxsocial.run.init_from`; of a `params_only`
    source its policy's params and `state`'s own fresh optimiser state), placed as `program` places its
    state; `state` itself without a source. Called only for a state at iteration 0 (a resumed run with a
    checkpoint keeps its own)."""
    if not source:
        return state
    iteration, dirs = init_from.source_iteration(source, seeds), init_from.source_dirs(source, seeds)
    if init_from.params_only(source, seeds):  # the policy's params; the optimiser as `state` starts it
        seed_axis = 1 if len(seeds) > 1 else 0
        template = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape[seed_axis:], x.dtype), state.params)
        loaded = [policy_io.load_learners(d, template, iteration) for d in dirs]
        params, opt_state = loaded[0] if len(seeds) == 1 else population.stack(loaded), state.opt_state
    else:
        learned: Any = [(s.params, s.opt_state) for s in (source_state(d, iteration) for d in dirs)]
        params, opt_state = learned[0] if len(seeds) == 1 else population.stack(learned)
    ours = jax.tree.map(lambda x: (x.shape, x.dtype), (state.params, state.opt_state))
    theirs = jax.tree.map(lambda x: (x.shape, x.dtype), (params, opt_state))
    if ours != theirs:
        raise ValueError(f"--init-from {source}: the learners' params or optimiser state differ in shape")
    placed = distributed.put((params, opt_state), (program.shardings.params, program.shardings.opt_state))
    return state._replace(params=placed[0], opt_state=placed[1])


@dataclasses.dataclass
class Driver:
    """The training state between chunks, which every process holds and steps alike: the runner state and
    stage, the iterations done (`it`), the latest saved iteration and the chunks compiled so far; built
    from the run's parts (`TrainConfig.program` and `.driver`) by `start`."""

    program: ProgramConfig
    driver_cfg: DriverConfig
    static: startup.Setup
    mesh: jax.sharding.Mesh
    seeds: list[SeedRun]
    slots: str  # the run's slots as text (`population.format_slots`), in every exported policy
    state: RunnerState
    stage: int
    frozen: Any  # the frozen slots' params on the mesh, or None
    it: int = 0
    last_saved: int = 0  # the latest checkpoint's iteration (the start when none was saved since)
    executables: dict[tuple[int, int], Any] = dataclasses.field(default_factory=dict)  # (stage, n) -> chunk

    @classmethod
    def start(
        cls,
        program: ProgramConfig,
        driver_cfg: DriverConfig,
        static: startup.Setup,
        mesh: jax.sharding.Mesh,
        seeds: list[SeedRun],
        slots: str,
    ) -> Driver:
        """Start-up: every seed's initial state in the stage a new run starts in or, with
        `driver_cfg.resume`, the state and stage of the latest checkpoint (`restore`); at iteration 0, the
        learners of `driver_cfg.init_from`."""
        stage = schedule.initial_index(static.stages)
        compiled = stage_program(program, static, mesh, stage)
        numbers = [s.seed for s in seeds]
        seed_numbers = np.asarray(numbers if program.seeds > 1 else numbers[0], np.int32)
        state = interrupt.in_worker("compiling the initial state", compiled.init, seed_numbers)
        frozen = static.frozen_params
        if frozen is not None:
            frozen = distributed.put(frozen, jax.tree.map(lambda _: distributed.replicated(mesh), frozen))
        driver = cls(program, driver_cfg, static, mesh, seeds, slots, state, stage, frozen)
        if driver_cfg.resume:
            driver.restore(compiled)
        driver.it = driver.last_saved = int(np.asarray(driver.state.iteration).reshape(-1)[0])
        if driver.it == 0:  # a new run, or a resumed one that saved nothing yet: from the source's learners
            driver.state = load_source_learners(driver_cfg.init_from, numbers, driver.state, compiled)
        return driver

    def compile(self, n: int, announce: Callable[[int, int], None]) -> float | None:
        """Compile step: the chunk of `n` iterations in the current stage, ahead of time (so that its speed
        excludes compiling), after `announce(n, stage)`; the seconds it took, or None if compiled before. It
        is traced and compiled in a worker thread (`interrupt.in_worker`), so a Ctrl-C stops the run at once.
        """
        if (self.stage, n) in self.executables:
            return None
        announce(n, self.stage)
        t0 = time.perf_counter()
        program = stage_program(self.program, self.static, self.mesh, self.stage)
        what = f"compiling {chunk_description(n, self.static.stages, self.stage)}"
        self.executables[self.stage, n] = interrupt.in_worker(
            what, ahead_of_time, program.run_chunk, self.state, self.frozen, n
        )
        return time.perf_counter() - t0

    def run_chunk(self, n: int) -> Chunk:
        """Run step: the compiled chunk of `n` iterations (`compile` first) from the current state, which
        it replaces (`it` stays the chunk's first, until the loop moves it on); in a worker thread until its
        metrics are on the host (`interrupt.in_worker`), so a Ctrl-C stops the run at once."""
        executable = self.executables[self.stage, n]

        def chunk() -> tuple[RunnerState, dict[str, Any]]:
            state, metrics = executable(self.state, self.frozen)
            return state, jax.device_get(metrics)

        what = f"training iterations {self.it + 1} to {self.it + n}"
        t0 = time.perf_counter()
        self.state, metrics = interrupt.in_worker(what, chunk)
        sps = n * self.program.num_envs * self.program.rollout_steps / (time.perf_counter() - t0)  # per seed
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
            self.save_seeds()
            self.last_saved = self.it
        elif processes.is_main():
            print(f"warning: iteration {self.it} is not finite: not saved as a checkpoint or policy",
                  file=sys.stderr)  # fmt: skip

    def save_seeds(self) -> None:
        """Policy, then checkpoint (with the stage to resume in), of every seed at iteration `it` (every
        process takes part). The policy goes first, so a checkpoint always has its policy: an interruption
        between the two leaves a policy ahead of the checkpoints, which the resumed run reaches again (and
        skips)."""
        host = distributed.to_host(self.state)
        for k, seed in enumerate(self.seeds):
            seed_state = seed_part(host, k, self.program.seeds)
            self.export_policy(seed.dir, self.it, seed_state.params)
            ckpt_dir = rundir.checkpoints(seed.dir)
            if self.it not in checkpoint.all_steps(ckpt_dir):  # else saved before an interruption: the same
                metadata = {**seed.config, "stage": self.stage}
                keep = self.driver_cfg.keep_checkpoints
                checkpoint.save(ckpt_dir, self.it, seed_state, metadata=metadata, keep=keep)

    def export_policy(self, seed_dir: Path, it: int, params: Any) -> None:
        """Write the learners' params (stacked [S_l, ...]) to `seed_dir/policy/<it>` unless that step
        exists."""
        keep = self.driver_cfg.keep_checkpoints
        policy_io.export_policy(seed_dir, it, params, self.program.net, slots=self.slots, keep=keep)

    def restore(self, program: Program) -> None:
        """The state and stage from the latest checkpoint that every seed has and can read (unchanged if
        none has one), placed as `program` places its state. An unreadable checkpoint (a truncated or
        emptied file) is skipped with a warning naming it, for the one before; a checkpoint of another
        config raises. A seed whose policy export is missing at that step (an interruption between the two
        writes of an older version) gets it re-exported."""
        ckpt_dirs = [rundir.checkpoints(s.dir) for s in self.seeds]
        steps = [checkpoint.all_steps(d) for d in ckpt_dirs]
        if not any(steps):
            return
        if not all(steps):
            missing = [str(d.parent) for d, s in zip(ckpt_dirs, steps, strict=True) if not s]
            raise ValueError(f"cannot resume: no checkpoint in {missing}; start again with --overwrite")
        lead = int(self.program.seeds > 1)
        template = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape[lead:], x.dtype), self.state)
        observers = rollout.program_observers(self.static.pop, self.program.algo)
        for step in sorted(set.intersection(*map(set, steps)), reverse=True):
            try:
                restored = [restore_state(d, template, step, observers) for d in ckpt_dirs]
                stage = int(checkpoint.read_metadata(ckpt_dirs[0], step).get("stage", self.stage))
            except checkpoint.CheckpointMismatchError:
                raise
            except Exception as err:  # noqa: BLE001 - orbax, json and OS errors of a damaged checkpoint
                where = [str(d / str(step)) for d in ckpt_dirs]
                print(f"warning: {where} unreadable ({type(err).__name__}: {err}); trying the checkpoint "
                      "before", file=sys.stderr)  # fmt: skip
                continue
            for restored_state, ckpt_dir in zip(restored, ckpt_dirs, strict=True):
                self.export_policy(ckpt_dir.parent, step, restored_state.params)
            host = restored[0] if self.program.seeds == 1 else population.stack(restored)
            self.state, self.stage = distributed.put(host, program.shardings), stage
            return
        raise ValueError(f"cannot resume: no readable checkpoint in {[str(d) for d in ckpt_dirs]}")


def train_chunks(
    cfg: TrainConfig,
    static: startup.Setup,
    mesh: jax.sharding.Mesh,
    run_dir: Path,
    seeds: list[SeedRun],
) -> None:
    """The training loop of `jaxsocial.train.run` in its prepared (and locked) run directory, over the steps
    of `Driver` and `Outputs`: chunk after chunk, plan, compile, run, write rows (with evaluations, on
    process 0), switch stage, save and show progress. Here a whole `TrainConfig` is taken apart: the
    driver gets its `ProgramConfig` and `DriverConfig`, `Outputs` keeps it whole.
    Stops at the first non-finite iteration (`NonFiniteError`) unless `cfg.on_nonfinite` is 'warn';
    nothing non-finite is ever saved."""
    driver = Driver.start(cfg.program, cfg.driver, static, mesh, seeds, population.format_slots(cfg.slots))
    if driver.it >= cfg.iterations:
        if processes.is_main():
            print(nothing_to_train(driver.it, cfg.iterations))
        return
    out = Outputs.open(cfg, static, mesh, seeds, driver.it)
    try:
        while driver.it < cfg.iterations:
            n = plan_chunk(driver.driver_cfg, cfg.chunk_iterations, static.stages, driver.stage, driver.it)
            compile_s = driver.compile(n, announce=out.compiling)
            out.start_progress(driver.it, compile_s)
            chunk = driver.run_chunk(n)
            check = check_chunk(chunk.finite, static.pop.learners, cfg.seeds, cfg.on_nonfinite)
            out.write_rows(chunk, check, compile_s, driver.state.params)
            if check.stop:
                raise nonfinite.NonFiniteError(stop_message(cfg, driver.it, check.failure, driver.last_saved))
            driver.it += n
            pooled = pool_seeds(chunk.metrics, cfg.seeds)
            learner_return = metrics.learner_return(pooled, static.pop)
            driver.switch_stage(learner_return)
            stop = reached(cfg.stop_at_return, learner_return)
            if stop or checkpoint_due(driver.driver_cfg, driver.it, driver.last_saved):
                driver.save(check.healthy_end)
            out.show_progress(driver.it, driver.stage, pooled, chunk.sps)
            if stop:
                if processes.is_main():
                    shown = "" if cfg.blind else f" {learner_return:.3g}"  # a blind run shows no return
                    print(f"stopped after iteration {driver.it}: the learners' return{shown} "
                          f"reached --stop-at-return {cfg.stop_at_return:g}")  # fmt: skip
                break
    finally:
        out.close()
    out.report(run_dir, driver.it, learner_return if stop else None)
