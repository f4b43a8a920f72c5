"""What a training run writes and says, on process 0: its directory (`run_path`, `seed_runs`,
`start_run_dir`, `write_configs`), each seed's metrics rows with evaluations, the progress line, and the
lines it ends with (`Outputs`, `outcome`, `stop_message`). `jaxsocial.run.driver.train_chunks` calls them
between the steps of the `Driver`; the file names and layout are `jaxsocial.run.rundir`'s."""

from __future__ import annotations

import dataclasses
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np

from jaxsocial import specs, stats
from jaxsocial.agents import population
from jaxsocial.agents.episodes import play_episodes
from jaxsocial.agents.network_config import NetworkConfig
from jaxsocial.run import (
    config,
    distributed,
    interrupt,
    loggers,
    metrics,
    nonfinite,
    processes,
    rundir,
    schedule,
    startup,
    unstarted,
)
from jaxsocial.run.chunks import Check, Chunk, evaluates, seed_part
from jaxsocial.run.config import TrainConfig, config_dict
from jaxsocial.run.rundir import SeedRun, run_name


def seed_runs(cfg: TrainConfig, run_dir: Path) -> list[SeedRun]:
    """Each seed's number, directory and config: the run itself for one seed; for several,
    `run_dir/s<seed>/` with the config of a one-seed run of that seed (so it reads like one, e.g. for
    `frozen:RUN_DIR/s1`)."""
    if cfg.seeds == 1:
        return [SeedRun(cfg.seed, run_dir, config_dict(cfg))]
    seeds = range(cfg.seed, cfg.seed + cfg.seeds)
    return [
        SeedRun(
            seed,
            run_dir / name,
            config_dict(dataclasses.replace(cfg, seed=seed, seeds=1, run_name=f"{run_name(cfg)}/{name}")),
        )
        for seed, name in zip(seeds, rundir.seed_dir_names(cfg.seed, cfg.seeds), strict=True)
    ]


def start_run_dir(cfg: TrainConfig, run_dir: Path, seeds: list[SeedRun]) -> None:
    """Start-up on process 0: `rundir.prepare_run_dir` (a resumed run's config may differ only in
    `DriverConfig`'s fields; a new run starts again in a directory that a run of its very config left
    before its first iteration, `unstarted.restarts`), each seed's checkpoint and policy directories, and a
    new run's configs."""
    restart = unstarted.restarts(cfg, run_dir)
    if restart:
        print(f"{run_dir} holds only what a run of this config wrote before its first iteration (it was "
              "interrupted or killed): starting it again", flush=True)  # fmt: skip
    rundir.prepare_run_dir(cfg.runs_dir, run_name(cfg), resume=cfg.resume, overwrite=cfg.overwrite or restart)
    if cfg.resume and (run_dir / rundir.CONFIG_FILE).exists():
        diff = config.resume_conflicts(rundir.read_config(run_dir), config_dict(cfg))
        if diff:
            raise ValueError(f"cannot resume {run_dir}: the config differs in {diff}")
    for seed in seeds:
        for sub in (rundir.CHECKPOINTS_DIR, rundir.POLICY_DIR):  # made here, before any process looks
            (seed.dir / sub).mkdir(parents=True, exist_ok=True)
    if not cfg.resume:
        write_configs(cfg, run_dir, seeds)


def write_configs(cfg: TrainConfig, run_dir: Path, seeds: list[SeedRun]) -> None:
    """The run's config.json and, with several seeds, each seed's (that of its one-seed run)."""
    rundir.write_config(run_dir, config_dict(cfg))
    for seed in seeds:
        if seed.dir != run_dir:
            rundir.write_config(seed.dir, seed.config)


def reached(threshold: float | None, learner_return: float | None) -> bool:
    """Whether a chunk's learner return ends the run early (`TrainConfig.stop_at_return`)."""
    return threshold is not None and learner_return is not None and learner_return >= threshold


def learner_returns(
    key: jax.Array, params: Any, eval_envs: tuple[startup.EvalEnv, ...], net_cfg: NetworkConfig, episodes: int
) -> dict[str, float]:
    """Evaluation during training: one learner's `params` (unstacked) in slot 0 of each evaluation
    environment (`startup.Setup.eval_envs`), beside that environment's default companions, for `episodes`
    episodes (`episodes.play_episodes`): {spec text: the learner's mean return over the episodes it took part
    in}."""
    stacked = jax.tree.map(lambda x: x[None], params)
    returns = {}
    for env, k in zip(eval_envs, jax.random.split(key, len(eval_envs)), strict=True):
        played = jax.device_get(play_episodes(k, env.pop, net_cfg, env.env_params, stacked, episodes))
        returns[str(env.spec)] = float(played.returns[played.present[:, 0], 0].mean())
    return returns


@dataclasses.dataclass
class Outputs:
    """What process 0 writes while training: each seed's metrics rows (`metrics.jsonl` and its logger's)
    with evaluations, the progress line and messages. Empty on the other processes, where it does nothing."""

    cfg: TrainConfig
    static: startup.Setup
    seeds: list[SeedRun]
    desc: str  # the run, as progress lines name it
    metrics_logs: list[rundir.MetricsLog]  # each seed's
    extras: list[loggers.Logger]  # each seed's `cfg.logger`
    progress: loggers.Progress | None = None  # from the first chunk on, with `cfg.progress`
    nonfinite_iterations: list[int] = dataclasses.field(default_factory=list)
    evaluated: bool = False  # an evaluation (and its compile) has run

    @classmethod
    def open(
        cls,
        cfg: TrainConfig,
        static: startup.Setup,
        mesh: jax.sharding.Mesh,
        seeds: list[SeedRun],
        start: int,
    ) -> Outputs:
        """The outputs of a run that continues after iteration `start` (later metrics rows are dropped)."""
        parts = [f"{cfg.seeds} seeds"] if cfg.seeds > 1 else []
        parts += [distributed.describe(list(mesh.devices.flat))] if mesh.size > 1 else []
        name = run_name(cfg)
        desc = f"{name} ({', '.join(parts)})" if parts else name
        if not processes.is_main():
            return cls(cfg, static, seeds, desc, [], [])
        metrics_logs = [rundir.MetricsLog(s.dir) for s in seeds]
        for metrics_log in metrics_logs:
            metrics_log.truncate_after(start)
        extras = [loggers.make_logger(cfg.logger, s.dir, s.config) for s in seeds]
        return cls(cfg, static, seeds, desc, metrics_logs, extras)

    @property
    def shows_progress(self) -> bool:
        return self.cfg.progress and processes.is_main()

    def compiling(self, n: int, stage: int) -> None:
        """The line before compiling the chunk of `n` iterations in `stage`."""
        if self.shows_progress:
            print(f"{self.desc}: compiling {chunk_description(n, self.static.stages, stage)} ...", flush=True)

    def start_progress(self, it: int, compile_s: float | None) -> None:
        """Starts the progress line at iteration `it` unless started (after the first compile line); a later
        chunk's compile time `compile_s` is left out of its rate and ETA."""
        if self.progress is None and self.shows_progress:
            self.progress = loggers.Progress(self.cfg.iterations, desc=self.desc, initial=it)
        elif self.progress is not None and compile_s is not None:
            self.progress.exclude(compile_s)

    def write_rows(self, chunk: Chunk, check: Check, compile_s: float | None, params: Any) -> None:
        """Write step: each seed's metrics rows of `chunk` (`chunk_rows`, those `check` keeps) with the
        compile time on the first and, after an evaluation iteration that is finite, the evaluation of the
        seed's first learner (`params`: the state's after the chunk) on the last; then a warning at the
        run's first non-finite iteration unless the run stops there."""
        first_nonfinite = not self.nonfinite_iterations
        self.nonfinite_iterations += [chunk.first + 1 + i for i in check.failed]
        end = chunk.first + chunk.n
        evaluating = evaluates(self.cfg.driver, end) and check.healthy_end and not check.stop
        for k, (metrics_log, extra) in enumerate(zip(self.metrics_logs, self.extras, strict=True)):
            seed_metrics, seed_finite = seed_part((chunk.metrics, chunk.finite), k, self.cfg.seeds)
            rows = chunk_rows(
                seed_metrics, seed_finite, chunk.first, round(chunk.sps), chunk.stage, self.static.pop
            )
            rows = rows[: check.kept]  # rows after a stop are not written
            if compile_s is not None:
                rows[0][metrics.COMPILE_S] = round(compile_s, 2)
            if evaluating:
                t0 = time.perf_counter()
                what = f"evaluating after iteration {end}"
                rows[-1].update(interrupt.in_worker(what, self.evaluation, k, end, params))
                if self.progress is not None and not self.evaluated:  # it compiled the evaluation
                    self.progress.exclude(time.perf_counter() - t0)
            metrics_log.append(rows)
            for row in rows:
                extra.log(row, row[metrics.ITERATION])
        self.evaluated = self.evaluated or evaluating
        if check.failure is not None and not check.stop and first_nonfinite and processes.is_main():
            print(f"warning: {failure_text(self.cfg, chunk.first, check.failure)}; training on "
                  "(--on-nonfinite warn)", file=sys.stderr)  # fmt: skip

    def evaluation(self, k: int, end: int, params: Any) -> dict[str, float]:
        """{'eval/<spec>': mean return} of seed k's first learner in `params` after iteration `end`."""
        host_params = jax.device_get(seed_part(params, k, self.cfg.seeds))  # replicated: local
        first = jax.tree.map(lambda x: x[0], host_params)
        key = jax.random.fold_in(jax.random.key(self.seeds[k].seed), end)
        returns = learner_returns(key, first, self.static.eval_envs, self.cfg.net, self.cfg.eval_episodes)
        return metrics.eval_fields(returns)

    def show_progress(self, it: int, stage: int, pooled: dict[str, np.ndarray], sps: float) -> None:
        """The progress line after iteration `it`, now in `stage`, with the chunk's metrics over all seeds
        (`pooled`) and speed `sps` per seed."""
        if self.progress is not None:
            stages = self.static.stages
            shown = {"stage": f"{stage + 1}/{len(stages)}"} if stages else {}
            fields = metrics.progress_fields(
                pooled, sps * self.cfg.seeds, self.static.pop, returns_shown=not self.cfg.blind
            )
            self.progress.update(it, **shown, **fields)

    def close(self) -> None:
        if self.progress is not None:
            self.progress.close()
        for extra in self.extras:
            extra.close()

    def report(self, run_dir: Path, it: int, stopped_at: float | None = None) -> None:
        """The lines a run that trained up to iteration `it` ends with (`stopped_at`: the learners' return
        that stopped it early, `--stop-at-return`)."""
        if not processes.is_main():
            return
        where = f" ({len(self.seeds)} seeds: s{self.cfg.seed}/ ...)" if len(self.seeds) > 1 else ""
        print(f"wrote {run_dir}{where} ({it} iterations)")
        print(reproduce_line(run_dir))
        if self.cfg.blind:
            print("blind run (a pre-registered design's): no return is shown until every seed is in")
            return
        rows = rundir.read_metrics(self.seeds[0].dir)
        env_steps = len(rows) * self.cfg.num_envs * self.cfg.rollout_steps
        if len(self.seeds) > 1:
            print(seeds_summary([rundir.read_metrics(s.dir) for s in self.seeds], self.seeds, self.static))
            print(f"seed {self.seeds[0].seed} (s{self.seeds[0].seed}/), the first:")
        print(outcome(rows, self.static, env_steps, stopped_at))
        first = self.seeds[0].dir
        grid = {k: v for k, v in self.cfg.env_overrides.items() if k in ("width", "height")}
        grid_args = f" --env-args {specs.ENV_ARGS.format(tuple(grid.items()))}" if grid else ""
        print(f"next: python -m jaxsocial.plot {first}                # writes {first / 'curves.png'}\n"
              f"      python -m jaxsocial.render --ckpt {first}       # writes {first / 'learner.gif'}\n"
              f"      python -m jaxsocial.evaluate --ckpt {first} --env goalcycle4{grid_args}")  # fmt: skip
        if self.nonfinite_iterations:
            count, first = len(self.nonfinite_iterations), self.nonfinite_iterations[0]
            print(f"warning: {count} iterations had non-finite values (the first: {first}), marked "
                  f"'{nonfinite.ROW_KEY}' in metrics.jsonl", file=sys.stderr)  # fmt: skip


def reproduce_line(run_dir: Path) -> str:
    """How the run re-trains bit for bit (docs/reproducibility.md, "Does the training re-run?"): the same
    commit and package versions, a CPU of a kind that agrees with this one, this process's $XLA_FLAGS and as
    many visible cores; `experiments verify` re-trains it so and says whether it is exact."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return (
        f"bit for bit it re-trains from this commit on this CPU kind, with $XLA_FLAGS "
        f"'{os.environ.get('XLA_FLAGS', '')}', in a process that sees {cores} core(s): python -m "
        f"jaxsocial.experiments verify {run_dir} checks it "
        "(docs/reproducibility.md names the kinds that agree)"
    )


def seeds_summary(seed_rows: list[list[dict[str, Any]]], seeds: list[SeedRun], static: startup.Setup) -> str:
    """The first learner's final return over a run's seeds: their mean and each seed's value."""
    learner = static.pop.learners[0]
    finals = [metrics.final_return(rows, learner) for rows in seed_rows]
    each = ", ".join(f"s{s.seed} {v:.3g}" for s, v in zip(seeds, finals, strict=True))
    mean = stats.summary(finals)["mean"]
    shown = "no episode ended" if mean is None else f"mean {mean:.3g}"
    return f"learner final return over the {len(seeds)} seeds (last 10% of the iterations): {shown} ({each})"


SMALL_BUDGET = 2_000_000
"""Env-steps below which a learner beside experts is expected on the one-tile plateau: the sweep's first
takeoffs came after 4.5M (docs/reproducibility.md)."""


def outcome(
    rows: list[dict[str, Any]], static: startup.Setup, env_steps: int, stopped_at: float | None = None
) -> str:
    """What a run's metrics `rows` (its first seed's, `env_steps` of them) show: each slot's final return
    (the last 10% of the iterations) and, for the first learner, whether it left the one-tile plateau, and
    whether that is what this budget leads one to expect. A run stopped early at the learners' return
    `stopped_at` (`--stop-at-return`) is judged by that return: its final window mostly precedes the stop."""
    if not rows:
        return "no iteration was logged"
    if stopped_at is not None:
        left = "left" if stopped_at > metrics.LEARNED_RETURN else "did not leave"
        return (
            f"stopped early: the learners' return reached {stopped_at:.3g} after {env_steps:,} env-steps, so "
            f"the learner {left} the one-tile plateau (return > {metrics.LEARNED_RETURN:g}); the final "
            "return over the last 10% of the iterations (mostly before the stop) is not the measure here"
        )
    finals = ", ".join(
        f"{slot.label} {metrics.final_return(rows, i):.3g}" for i, slot in enumerate(static.pop.slots)
    )
    text = f"final return (last 10% of the iterations): {finals}"
    learner = static.pop.learners[0]
    ret, env = metrics.final_return(rows, learner), static.env_params
    if math.isnan(ret):
        return text + (
            f"\nno episode of the learner ended in the last 10% of the iterations ({env_steps:,} env-steps "
            f"in all; an episode lasts {env.max_steps} steps), so there is no final return to judge: train "
            "more iterations"
        )
    if env.layout != "goalcycle" or env.penalty == 0:
        return text
    if ret > metrics.LEARNED_RETURN:
        return text + f"\nthe learner left the one-tile plateau (return > {metrics.LEARNED_RETURN:g})"
    text += (
        f"\nthe learner is on the one-tile plateau (return <= {metrics.LEARNED_RETURN:g}: the free first "
        f"tile, then no more)"
    )
    if env_steps < SMALL_BUDGET and static.pop.experts:
        return text + (
            f": expected at this budget ({env_steps:,} env-steps) under the {env.penalty:g} penalty; "
            "learners that leave it beside experts take millions of env-steps (docs/reproducibility.md)"
        )
    return text + f" after {env_steps:,} env-steps under the {env.penalty:g} penalty"


def chunk_rows(
    chunk_metrics: dict[str, np.ndarray],
    finite: dict[str, np.ndarray],
    first_iteration: int,
    sps: float,
    stage: int,
    pop: population.Population,
) -> list[dict[str, Any]]:
    """One seed's metrics rows of a chunk (`metrics.metric_rows`) with the stage and, in a non-finite
    iteration, its non-finite quantities (`nonfinite.ROW_KEY`)."""
    rows = metrics.metric_rows(chunk_metrics, first_iteration, sps, pop)
    for i, row in enumerate(rows):
        row[metrics.STAGE] = stage
        bad = nonfinite.names(finite, i, pop.learners)
        if bad:
            row[nonfinite.ROW_KEY] = bad
    return rows


def nothing_to_train(trained: int, iterations: int) -> str:
    """What a resumed run that has already reached `iterations` says (it trains nothing)."""
    given = f"(--iterations is {iterations})"
    where = f"{trained} of {iterations}" if trained == iterations else f"{trained} {given}"
    return (
        f"Run already at {where} iterations; nothing to train. Pass a larger --iterations (the total) to "
        "continue."
    )


def chunk_description(n: int, stages: tuple[schedule.Stage, ...], stage: int) -> str:
    """The chunk being compiled, e.g. 'the 10-iteration chunk', 'the 10-iteration chunk of stage 2 of 3
    (penalty=1.0)' or '... before stage 1 of 3' (stages counted from 1, as in --stages)."""
    text = f"the {n}-iteration chunk"
    if not stages:
        return text
    if stage < 0:
        return f"{text} before stage 1 of {len(stages)}"
    changes = specs.ENV_ARGS.format(stages[stage].overrides)
    return f"{text} of stage {stage + 1} of {len(stages)} ({changes})"


def failure_text(cfg: TrainConfig, it: int, failure: nonfinite.Failure) -> str:
    """`failure` of the chunk after iteration `it`, its seed named when the program trains several."""
    return failure.describe(it + 1, cfg.seed + failure.seed if cfg.seeds > 1 else None)


def stop_message(cfg: TrainConfig, it: int, failure: nonfinite.Failure, last_saved: int) -> str:
    """The one line a run stopped by a non-finite value ends with (`it`: the iteration before the chunk)."""
    if last_saved > 0:
        kept = f"the latest checkpoint and policy stay iteration {last_saved}'s, where --resume continues"
    else:
        kept = "no checkpoint had been saved, so --resume starts again"
    return (
        f"{failure_text(cfg, it, failure)}; the run stopped without saving it: {kept} "
        "(--on-nonfinite warn trains on regardless)"
    )
