"""Training runs from a `TrainConfig`: `run` (validate, prepare and lock the run directory, then
`jaxsocial.run.driver.train_chunks`, the loop over the driver's steps), `make_train` (a whole run as one pure
function), `compiled_program` and the CLI. The configuration is `jaxsocial.run.config`'s, its validation and
static part `jaxsocial.run.startup`'s.

    python -m jaxsocial.train --env goalcycle3            # small default, a few minutes on 2 CPU cores
    python -m jaxsocial.train --preset paper --env goalcycle3
"""

from __future__ import annotations

import dataclasses
import functools
import shlex
import sys
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

from jaxsocial.env import registry
from jaxsocial.run import (
    compile_cache,
    flags,
    interrupt,
    nonfinite,
    processes,
    provenance,
    rundir,
    runlock,
    startup,
    unstarted,
)
from jaxsocial.run.config import PRESETS, TrainConfig, config_from_dict

if TYPE_CHECKING:
    import jax

    from jaxsocial.run import loop


def make_train(cfg: TrainConfig):
    """The pure training functions of `cfg`, a config without stages (a run's driver switches them),
    validated first (`startup.setup`).

    Returns `(init, run_chunk, train)`: `init` and `run_chunk` as `loop.make_program` builds them for
    `cfg.program`; `train(key) -> (state, metrics)` is the whole run of `cfg.iterations` (it loads frozen
    policies when traced).
    """
    from jaxsocial.run import loop, policy_io  # the program's modules, imported when it is built

    if cfg.stages:
        raise ValueError("make_train builds one stage's program; the driver (run) switches stages")
    static = startup.setup(cfg, load_frozen=False)
    init, run_chunk = loop.make_program(cfg.program, static.env_params, static.pop)

    def train(key: jax.Array):
        return run_chunk(init(key), policy_io.load_frozen(static.pop, cfg.net), cfg.iterations)

    return init, run_chunk, train


def compiled_program(cfg: TrainConfig, stage: int = -1) -> loop.Program:
    """The compiled `Program` of `cfg` in `stage` (-1: before the first) on its devices, validated first
    (`startup.setup`; frozen policies are not loaded), as a run's driver compiles it."""
    from jaxsocial.run import loop
    from jaxsocial.run.driver import stage_program

    static = startup.setup(cfg, load_frozen=False)
    return stage_program(cfg.program, static, loop.program_mesh(cfg.program, cfg.devices), stage)


def run(cfg: TrainConfig, command: str | None = None) -> Path:
    """Train with logging and checkpoints in `runs_dir/run_name`; returns the run directory.

    First the config is validated (`startup.setup`), then the run directory is checked (`check_run_dir`:
    RunLockedError where a live run holds it; for a new run, FileExistsError where it holds another run, or
    anything beyond what a run of this config leaves before its first iteration, which does not block it);
    only then are JAX and the modules that train imported, so that a refusal is quick (JAX comes
    first only for several processes or frozen slots to load). The run goes
    through the stages of `cfg.stages` (one compiled program each, switched between chunks); metrics rows
    record the stage, and checkpoints the stage to resume in. The run directory is locked (`runlock`) from
    before the cost line until the run ends. A non-finite iteration raises `nonfinite.NonFiniteError` (see
    `driver.train_chunks`). Several seeds train in one program; each seed's config, metrics, checkpoints and
    policy go to its own directory (`seed_runs`). In a multi-process run every process calls this with the
    same config (and its own process_id); only process 0 writes logs, metrics and progress. Process 0
    records itself in the run directory (`provenance.recorded`: `command`, default the `python -m
    jaxsocial.train` line of the config it trains; the commit and whether the package's files were its; the
    machine), unless a runner records it. Ctrl-C while XLA compiles or runs a chunk raises
    `interrupt.Interrupted` at once.
    """
    processes.initialize(cfg.coordinator, cfg.num_processes, cfg.process_id)
    static = startup.setup(cfg)  # validate before touching the disk or compiling; once per run
    run_dir = rundir.run_path(cfg)
    processes.on_main(functools.partial(check_run_dir, cfg, run_dir))
    from jaxsocial.run import cost, init_from, loop  # orbax, optax and scipy: not imported by a refusal
    from jaxsocial.run.driver import train_chunks
    from jaxsocial.run.outputs import seed_runs, start_run_dir, write_configs

    if cfg.compile_cache:  # JAX's config: after the refusals, before anything compiles
        compile_cache.enable(cfg.compile_cache)
    branching = cfg.init_from is not None and not cfg.resume  # a resumed run loads its own state
    numbers = list(range(cfg.seed, cfg.seed + cfg.seeds))
    if branching:  # checked, then RUN_DIR@ITERATION in config.json
        init_from.check_source(cfg.init_from, numbers, cfg.net, static.pop.learners)
        cfg = dataclasses.replace(cfg, init_from=init_from.pin_iteration(cfg.init_from, numbers, run_dir))
        if processes.is_main() and init_from.params_only(cfg.init_from, numbers):
            print(f"--init-from {cfg.init_from}: the params of its policy (no checkpoint), a fresh optimiser")
    mesh = loop.program_mesh(cfg.program, cfg.devices)
    lock = runlock.RunLock(run_dir)
    processes.on_main(lock.acquire)  # before the cost line, and anything in the run directory is written
    try:
        trained = cost.trained_iterations(cfg, run_dir)
        if processes.is_main() and trained < cfg.iterations:  # before "auto" measures, and compiling
            print(cost.estimate(cfg, trained), flush=True)
        cfg = startup.resolve_network(cfg, static.pop)  # after every check: "auto" measures this machine
        seeds = seed_runs(cfg, run_dir)
        processes.on_main(functools.partial(start_run_dir, cfg, run_dir, seeds))
        command = command or shlex.join(["python", "-m", "jaxsocial.train", *flags.config_flags(cfg)])
        with provenance.recorded(run_dir, command, cfg.resume, processes.is_main()):
            train_chunks(cfg, static, mesh, run_dir, seeds)
            if cfg.resume:  # a resumed run's config is rewritten once it has succeeded
                processes.on_main(functools.partial(write_configs, cfg, run_dir, seeds))
    finally:
        if processes.is_main():
            lock.release()
    return run_dir


def check_run_dir(cfg: TrainConfig, run_dir: Path) -> None:
    """Before a run prints its cost or compiles (on process 0): RunLockedError where a live process holds
    `run_dir` (`runlock.RunLock.check_free`), FileExistsError where a new run may not start in it
    (`unstarted.check_new_run`)."""
    runlock.RunLock(run_dir).check_free()
    unstarted.check_new_run(cfg, run_dir)


USAGE = """Train independent conv-LSTM PPO learners (or behaviour cloning) beside experts in a jaxsocial
environment. Every option below is a flag; `--preset small|laptop|paper|expert` picks the defaults first.

  python -m jaxsocial.train --env goalcycle3                  # the small default, minutes on 2 CPU cores
  python -m jaxsocial.train --preset paper --env goalcycle3   # the paper's network and PPO (for GPUs)
  python -m jaxsocial.train --resume runs/goalcycle3-s0       # continue a run with its own config

Environments: {envs}. Results go to runs_dir/run_name: config.json, metrics.jsonl, checkpoints/, policy/."""


def _resume_from(argv: list[str]) -> tuple[TrainConfig | None, list[str]]:
    """`--resume RUN_DIR`: the run's saved config (to resume with) and argv without the path."""
    for i, arg in enumerate(argv[:-1]):
        if arg == "--resume" and not argv[i + 1].startswith("-"):
            run_dir = Path(argv[i + 1])
            if not run_dir.exists():
                raise SystemExit(f"error: --resume {run_dir}: no such directory")
            if not (run_dir / rundir.CONFIG_FILE).is_file():
                raise SystemExit(
                    f"error: --resume {run_dir}: no {rundir.CONFIG_FILE} there (not a run directory)"
                )
            saved = config_from_dict(rundir.read_config(run_dir))
            saved = dataclasses.replace(saved, runs_dir=str(run_dir.parent), run_name=run_dir.name)
            return saved, argv[:i] + argv[i + 2 :]
    return None, argv


def _flag_value(argv: list[str], flag: str) -> str | None:
    """The value of the last '--flag VALUE' or '--flag=VALUE' in `argv` ('' for a flag ending it), or None."""
    value = None
    for i, arg in enumerate(argv):
        if arg == flag:
            value = argv[i + 1] if i + 1 < len(argv) else ""
        elif arg.startswith(flag + "="):
            value = arg.removeprefix(flag + "=")
    return value


def parse_args(argv: list[str]) -> TrainConfig:
    """Parse the CLI: `--preset NAME` picks the defaults, every TrainConfig field is a flag; `--resume
    RUN_DIR` starts from the run's saved config instead (flags given with it still apply). `--env NAME:ARGS`
    is `--env NAME --env-args ARGS`: its overrides replace the preset's, and join those of `--env-args`. The
    old flags of renamed fields (`flags.LEGACY_FLAGS`) still work, with a deprecation message."""
    import tyro

    saved, argv = _resume_from(flags.modern_flags(argv))
    default = saved
    if saved is None:
        preset = _flag_value(argv, "--preset")
        preset = "small" if preset is None else preset
        if preset not in PRESETS:
            raise SystemExit(f"unknown --preset {preset!r}; choose one of {sorted(PRESETS)}")
        default = PRESETS[preset]
    if ":" in (_flag_value(argv, "--env") or ""):  # NAME:ARGS is NAME with --env-args ARGS, not the preset's
        default = dataclasses.replace(default, env_args=())
    usage = USAGE.format(envs=", ".join(registry.registered_envs()))
    cfg = tyro.cli(
        TrainConfig, default=default, args=argv, description=usage, prog="python -m jaxsocial.train"
    )
    if not any(arg.partition("=")[0] == "--net.obs" for arg in argv):  # the network takes the env's views
        cfg = flags.with_env_observation(cfg)
    return cfg if saved is None else dataclasses.replace(cfg, resume=True, overwrite=False)


def interrupted(err: KeyboardInterrupt, cfg: TrainConfig) -> NoReturn:
    """Ctrl-C: one line on stderr, what was interrupted (`interrupt.Interrupted`) and what the run directory
    holds, then exit status 130 (128 + SIGINT; at once where XLA still works in a worker the interrupt left,
    `interrupt.in_worker`)."""
    run_dir = rundir.run_path(cfg)
    what = f" while {err.what}" if isinstance(err, interrupt.Interrupted) else ""
    if not run_dir.is_dir():
        kept = "nothing was written"
    elif not unstarted.leftovers(run_dir, rundir.seed_dir_names(cfg.seed, cfg.seeds)):
        kept = f"{run_dir} holds no completed iteration, so the same command starts it again"
    else:
        kept = f"{run_dir} keeps what it saved: --resume {run_dir} continues from its latest checkpoint"
    print(f"interrupted{what}; {kept}", file=sys.stderr, flush=True)
    raise SystemExit(interrupt.EXIT_STATUS)


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    cfg = parse_args(argv)
    try:
        run(cfg, shlex.join(["python", "-m", "jaxsocial.train", *argv]))
    except KeyboardInterrupt as err:
        interrupted(err, cfg)
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
