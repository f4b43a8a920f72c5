"""Training runs: the chunked driver (`run`: stages, seeds, resume, checkpoints, metrics rows, progress) and
the CLI. The configuration and its validation are in `jaxsocial.config`, the compiled loop in
`jaxsocial.loop`.

    python -m jaxsocial.train --env goalcycle3            # small default, a few minutes on 2 CPU cores
    python -m jaxsocial.train --preset paper --env goalcycle3
"""

from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np

import jaxsocial
from jaxsocial import (
    checkpoint,
    compile_cache,
    config,
    distributed,
    evaluate,
    init_from,
    logs,
    loop,
    nonfinite,
    runlock,
    schedule,
)
from jaxsocial.agents import policy_io, population
from jaxsocial.config import PRESETS, TrainConfig, config_dict, config_from_dict
from jaxsocial.loop import Program, RunnerState


def metric_rows(
    metrics: dict[str, np.ndarray], first_iteration: int, sps: float, pop
) -> list[dict[str, Any]]:
    """One JSON row per iteration: per-slot returns and episode counts, per-learner losses."""
    rows = []
    n = len(next(iter(metrics.values())))
    for i in range(n):
        row: dict[str, Any] = {"iteration": first_iteration + i + 1, "env_steps_per_s": sps}
        for slot in range(len(pop.slots)):
            row[f"return/{slot}"] = float(metrics["return"][i][slot])
            row[f"episodes/{slot}"] = int(metrics["episodes"][i][slot])
        for name, value in metrics.items():
            if name in ("return", "episodes"):
                continue
            for j, slot in enumerate(pop.learners):
                row[f"{name}/{slot}"] = float(value[i][j])
        rows.append(row)
    return rows


def progress_fields(metrics: dict[str, np.ndarray], sps: float, pop: population.Population) -> dict[str, Any]:
    """What the progress line shows for a chunk: speed and each slot's mean return over the episodes that
    finished in the chunk ('-' where none did), named `return[<slot> <kind>]`, e.g. 'return[1 explorer]'."""
    episodes = metrics["episodes"].sum(0)
    returns = (metrics["return"] * metrics["episodes"]).sum(0) / np.maximum(episodes, 1)
    shown: dict[str, Any] = {"env-steps/s": int(sps)}
    for s, (r, n) in enumerate(zip(returns, episodes, strict=True)):
        shown[f"return[{s} {pop.slots[s].label.split(':')[-1]}]"] = float(r) if n else "-"
    return shown


def learner_return(metrics: dict[str, np.ndarray], pop: population.Population) -> float | None:
    """The learners' mean episode return over a chunk's finished episodes (None if none finished)."""
    learners = list(pop.learners)
    episodes = metrics["episodes"][:, learners]
    if episodes.sum() == 0:
        return None
    return float((metrics["return"][:, learners] * episodes).sum() / episodes.sum())


def run_name(cfg: TrainConfig) -> str:
    """`cfg.run_name`, or '<env>-s<seed>' ('<env>-s<first>-<last>' for several seeds)."""
    if cfg.run_name:
        return cfg.run_name
    last = f"-{cfg.seed + cfg.seeds - 1}" if cfg.seeds > 1 else ""
    return f"{cfg.env}-s{cfg.seed}{last}"


def seed_runs(cfg: TrainConfig, run_dir: Path) -> list[tuple[TrainConfig, Path]]:
    """(config, directory) of each seed: the run itself for one seed; for several, `run_dir/s<seed>/` with
    the config of a one-seed run of that seed (so it reads like one, e.g. for `frozen:RUN_DIR/s1`)."""
    if cfg.seeds == 1:
        return [(cfg, run_dir)]
    runs = []
    for seed in range(cfg.seed, cfg.seed + cfg.seeds):
        name = f"{run_name(cfg)}/s{seed}"
        runs.append((dataclasses.replace(cfg, seed=seed, seeds=1, run_name=name), run_dir / f"s{seed}"))
    return runs


def run(cfg: TrainConfig) -> Path:
    """Train with logging and checkpoints in `runs_dir/run_name`; returns the run directory.

    The run goes through the stages of `cfg.stages` (one compiled program each, switched between chunks);
    metrics rows record the stage, and checkpoints the stage to resume in. The run directory is locked
    (`runlock`) from before it is written until the run ends; a live run's directory raises RunLockedError.
    A non-finite iteration raises `nonfinite.NonFiniteError` (see `train_chunks`). Several seeds train in one
    program; each seed's config, metrics, checkpoints and policy go to its own directory (`seed_runs`). In a
    multi-process run every process calls this with the same config (and its own process_id); only process 0
    writes logs, metrics and progress.
    """
    distributed.initialize(cfg.coordinator, cfg.num_processes, cfg.process_id)
    if cfg.compile_cache:
        compile_cache.enable(cfg.compile_cache)
    static = config.setup(cfg)  # validate before touching the disk or compiling; once per run
    pop = static.pop
    mesh = loop.data_mesh(cfg)

    def program_of(stage: int) -> Program:
        return loop.compiled(cfg, mesh, env_params=static.stage(stage), pop=pop)

    name = run_name(cfg)
    run_dir = Path(cfg.runs_dir).expanduser() / name
    cfg = init_from.pin(cfg, run_dir)  # RUN_DIR@ITERATION in config.json
    seeds = seed_runs(cfg, run_dir)
    saved = config_dict(cfg)

    def prepare() -> None:
        logs.prepare_run_dir(cfg.runs_dir, name, resume=cfg.resume, overwrite=cfg.overwrite)
        if cfg.resume and (run_dir / "config.json").exists():
            diff = config.resume_conflicts(logs.read_config(run_dir), saved)
            if diff:
                raise ValueError(f"cannot resume {run_dir}: the config differs in {diff}")
        for _, seed_dir in seeds:
            for sub in ("checkpoints", policy_io.POLICY_DIR):  # made here, before any process looks
                (seed_dir / sub).mkdir(parents=True, exist_ok=True)
        if not cfg.resume:  # a resumed run's config is rewritten once it has succeeded
            write_configs()

    def write_configs() -> None:
        logs.write_config(run_dir, saved)
        for seed_cfg, seed_dir in seeds:
            if seed_cfg is not cfg:
                logs.write_config(seed_dir, config_dict(seed_cfg))

    lock = runlock.RunLock(run_dir)
    distributed.on_main(lock.acquire)  # before anything in the run directory is deleted or written
    try:
        distributed.on_main(prepare)
        train_chunks(cfg, static, mesh, run_dir, seeds, program_of)
        if cfg.resume:
            distributed.on_main(write_configs)
    finally:
        if distributed.is_main():
            lock.release()
    return run_dir


def train_chunks(
    cfg: TrainConfig,
    static: config.Setup,
    mesh: jax.sharding.Mesh,
    run_dir: Path,
    seeds: list[tuple[TrainConfig, Path]],
    program_of: Any,
) -> None:
    """The training loop of `run` in its prepared (and locked) run directory: chunk after chunk, with
    metrics rows, evaluations, stage switches, checkpoints and progress. Stops at the first non-finite
    iteration (`NonFiniteError`) unless `cfg.on_nonfinite` is 'warn'; nothing non-finite is ever saved."""
    pop, stages, frozen = static.pop, static.stages, static.frozen_params
    main = distributed.is_main()
    stage = schedule.initial_index(stages)
    program = program_of(stage)
    state = program.init(np.asarray([c.seed for c, _ in seeds] if cfg.seeds > 1 else cfg.seed, np.int32))
    if frozen is not None:
        frozen = distributed.put(frozen, jax.tree.map(lambda _: distributed.replicated(mesh), frozen))
    if cfg.resume:
        state, stage = restore_seeds(cfg, [d / "checkpoints" for _, d in seeds], state, program, stage)
    start = int(np.asarray(state.iteration).reshape(-1)[0])
    if start == 0:  # a new run, or a resumed one that saved nothing yet: from the source's learners
        state = init_from.apply(cfg, state, program)
    if start >= cfg.iterations:
        if main:
            print(nothing_to_train(start, cfg.iterations))
        return
    metrics_logs = [logs.MetricsLog(d) for _, d in seeds] if main else []
    for metrics_log in metrics_logs:
        metrics_log.truncate_after(start)
    extras = [logs.make_logger(cfg.logger, d, config_dict(c)) for c, d in seeds] if main else []
    progress = None
    parts = [f"{cfg.seeds} seeds"] if cfg.seeds > 1 else []
    parts += [distributed.describe(list(mesh.devices.flat))] if mesh.size > 1 else []
    name = run_name(cfg)
    desc = f"{name} ({', '.join(parts)})" if parts else name
    executables: dict[tuple[int, int], Any] = {}  # (stage, n) -> compiled chunk of n iterations
    steps_per_iteration = cfg.num_envs * cfg.rollout_steps
    learner_eval = evaluate.make_learner_eval(cfg.eval_envs, cfg.net, cfg.eval_episodes) if main else None
    last_saved = start
    nonfinite_iterations: list[int] = []
    it = start
    try:
        while it < cfg.iterations:
            n = min(cfg.chunk_iterations, cfg.iterations - it)
            switch = schedule.next_start(stages, stage)
            if switch is not None and switch > it:
                n = min(n, switch - it)  # land exactly on the next stage's first iteration
            if cfg.eval_envs:
                n = min(n, cfg.eval_every - it % cfg.eval_every)  # end chunks on evaluation iterations
            compile_s = None
            if (stage, n) not in executables:  # compiled ahead of time, so the speed below excludes it
                if cfg.progress and main:
                    print(f"{desc}: compiling {chunk_description(n, stages, stage)} ...", flush=True)
                t0 = time.perf_counter()
                program = program_of(stage)
                executables[stage, n] = program.run_chunk.lower(state, frozen, n).compile()
                compile_s = time.perf_counter() - t0
            if progress is None and cfg.progress and main:
                progress = logs.Progress(cfg.iterations, desc=desc, initial=it)
            t0 = time.perf_counter()
            state, metrics = executables[stage, n](state, frozen)
            metrics = jax.device_get(metrics)
            sps = n * steps_per_iteration / (time.perf_counter() - t0)  # per seed
            finite = metrics.pop(nonfinite.KEY)
            failed = nonfinite.failures(finite).reshape(cfg.seeds, n).any(axis=0)  # bool[n], over seeds
            failure = nonfinite.first_failure(finite, pop.learners, cfg.seeds)
            stop = failure is not None and cfg.on_nonfinite == "stop"
            kept = failure.offset + 1 if stop else n  # rows after a stop are not written
            nonfinite_iterations += [it + 1 + i for i in np.flatnonzero(failed[:kept])]
            healthy_end = not failed[-1]  # the chunk's last iteration passed every check: save, evaluate it
            for k, (metrics_log, extra) in enumerate(zip(metrics_logs, extras, strict=True)):
                seed_metrics, seed_finite = seed_part((metrics, finite), k, cfg.seeds)
                rows = chunk_rows(seed_metrics, seed_finite, it, round(sps), stage, pop)[:kept]
                if compile_s is not None:
                    rows[0]["compile_s"] = round(compile_s, 2)
                end = it + n
                evaluating = cfg.eval_envs and (end % cfg.eval_every == 0 or end == cfg.iterations)
                if evaluating and healthy_end and not stop:
                    seed = seeds[k][0].seed
                    host_params = jax.device_get(seed_part(state.params, k, cfg.seeds))  # replicated: local
                    params = jax.tree.map(lambda x: x[0], host_params)  # the first learner
                    key = jax.random.fold_in(jax.random.key(seed), end)
                    rows[-1].update({f"eval/{s}": r for s, r in learner_eval(key, params).items()})
                metrics_log.append(rows)
                for row in rows:
                    extra.log(row, row["iteration"])
            if stop:
                raise nonfinite.NonFiniteError(stop_message(cfg, it, failure, last_saved))
            if failure is not None and main and nonfinite_iterations[0] > it:  # the run's first one
                print(f"warning: {failure_text(cfg, it, failure)}; training on (--on-nonfinite warn)",
                      file=sys.stderr)  # fmt: skip
            it += n
            all_seeds = (
                jax.tree.map(lambda m: m.reshape(-1, *m.shape[2:]), metrics) if cfg.seeds > 1 else metrics
            )
            stage = schedule.advance(stages, stage, it, learner_return(all_seeds, pop))
            if it - last_saved >= cfg.checkpoint_every or it == cfg.iterations:
                if healthy_end:
                    save_seeds(cfg, seeds, it, state, stage)
                    last_saved = it
                elif main:
                    print(f"warning: iteration {it} is not finite: not saved as a checkpoint or policy",
                          file=sys.stderr)  # fmt: skip
            if progress is not None:
                shown = {"stage": f"{stage + 1}/{len(stages)}"} if stages else {}
                progress.update(it, **shown, **progress_fields(all_seeds, sps * cfg.seeds, pop))
    finally:
        if progress is not None:
            progress.close()
        for extra in extras:
            extra.close()
    if main:
        where = f" ({len(seeds)} seeds: s{cfg.seed}/ ...)" if len(seeds) > 1 else ""
        print(f"wrote {run_dir}{where} ({it} iterations)")
        if nonfinite_iterations:
            count, first = len(nonfinite_iterations), nonfinite_iterations[0]
            print(f"warning: {count} iterations had non-finite values (the first: {first}), marked "
                  f"'{nonfinite.ROW_KEY}' in metrics.jsonl", file=sys.stderr)  # fmt: skip


def chunk_rows(
    metrics: dict[str, np.ndarray],
    finite: dict[str, np.ndarray],
    first_iteration: int,
    sps: float,
    stage: int,
    pop: population.Population,
) -> list[dict[str, Any]]:
    """One seed's metrics rows of a chunk (`metric_rows`) with the stage and, in a non-finite iteration,
    its non-finite quantities (`nonfinite.ROW_KEY`)."""
    rows = metric_rows(metrics, first_iteration, sps, pop)
    for i, row in enumerate(rows):
        row["stage"] = stage
        bad = nonfinite.names(finite, i, pop.learners)
        if bad:
            row[nonfinite.ROW_KEY] = bad
    return rows


def nothing_to_train(done: int, iterations: int) -> str:
    """What a resumed run that has already reached `iterations` says (it trains nothing)."""
    where = f"{done} of {iterations}" if done == iterations else f"{done} (--iterations is {iterations})"
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
    changes = schedule.format_assignments(dict(stages[stage].overrides))
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


def seed_part(tree: Any, k: int, seeds: int) -> Any:
    """Seed k's part of `tree`, whose leaves have a leading seed axis when there are several `seeds`."""
    return tree if seeds == 1 else jax.tree.map(lambda x: x[k], tree)


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
        ckpt_dir = seed_dir / "checkpoints"
        if it not in checkpoint.all_steps(ckpt_dir):  # else saved before an interruption: the same state
            metadata = {**config_dict(seed_cfg), "stage": stage}
            checkpoint.save(ckpt_dir, it, seed_state, metadata=metadata, keep=cfg.keep_checkpoints)


def export_policy(cfg: TrainConfig, seed_dir: Path, it: int, params: Any) -> None:
    """Write the learners' params (stacked [S_l, ...]) to `seed_dir/policy/<it>` unless that step exists."""
    policy_io.export_policy(seed_dir, it, params, cfg.net, slots=cfg.slots, keep=cfg.keep_checkpoints)


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


USAGE = """Train independent conv-LSTM PPO learners (or behaviour cloning) beside experts in a jaxsocial
environment. Every option below is a flag; `--preset small|paper|expert` picks the defaults first.

  python -m jaxsocial.train --env goalcycle3                  # the small default, minutes on 2 CPU cores
  python -m jaxsocial.train --preset paper --env goalcycle3   # the paper's network and PPO (for GPUs)
  python -m jaxsocial.train --resume runs/goalcycle3-s0       # continue a run with its own config

Environments: {envs}. Results go to runs_dir/run_name: config.json, metrics.jsonl, checkpoints/, policy/."""


def _resume_from(argv: list[str]) -> tuple[TrainConfig | None, list[str]]:
    """`--resume RUN_DIR`: the run's saved config (to resume with) and argv without the path."""
    for i, arg in enumerate(argv[:-1]):
        if arg == "--resume" and not argv[i + 1].startswith("-"):
            run_dir = Path(argv[i + 1])
            if not (run_dir / logs.CONFIG_FILE).is_file():
                raise SystemExit(
                    f"error: --resume {run_dir}: no {logs.CONFIG_FILE} there (not a run directory)"
                )
            saved = config_from_dict(logs.read_config(run_dir))
            saved = dataclasses.replace(saved, runs_dir=str(run_dir.parent), run_name=run_dir.name)
            return saved, argv[:i] + argv[i + 2 :]
    return None, argv


def parse_args(argv: list[str]) -> TrainConfig:
    """Parse the CLI: `--preset NAME` picks the defaults, every TrainConfig field is a flag; `--resume
    RUN_DIR` starts from the run's saved config instead (flags given with it still apply)."""
    import tyro

    saved, argv = _resume_from(argv)
    default = saved
    if saved is None:
        preset = "small"
        for i, arg in enumerate(argv):  # '--preset NAME' or '--preset=NAME' (the last one counts)
            if arg == "--preset":
                preset = argv[i + 1] if i + 1 < len(argv) else ""
            elif arg.startswith("--preset="):
                preset = arg.removeprefix("--preset=")
        if preset not in PRESETS:
            raise SystemExit(f"unknown --preset {preset!r}; choose one of {sorted(PRESETS)}")
        default = PRESETS[preset]
    usage = USAGE.format(envs=", ".join(jaxsocial.registered_envs()))
    cfg = tyro.cli(
        TrainConfig, default=default, args=argv, description=usage, prog="python -m jaxsocial.train"
    )
    if not any(arg.partition("=")[0] == "--net.obs" for arg in argv):  # the network takes the env's views
        cfg = config.with_env_observation(cfg)
    return cfg if saved is None else dataclasses.replace(cfg, resume=True, overwrite=False)


def main(argv: list[str] | None = None) -> None:
    cfg = parse_args(sys.argv[1:] if argv is None else argv)
    try:
        run(cfg)
    except (ValueError, FileExistsError, FileNotFoundError, nonfinite.NonFiniteError) as err:
        raise SystemExit(f"error: {err}") from err
    except OSError as err:  # e.g. an unwritable runs_dir or a full disk while checkpointing
        where = f" ({err.filename})" if err.filename else ""
        raise SystemExit(
            f"error: cannot write the run{where}: {err.strerror or err}. Checkpoints and metrics written "
            "before this are kept; fix the cause and continue with --resume."
        ) from err


if __name__ == "__main__":
    main()
