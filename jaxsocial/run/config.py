"""A training run's configuration: `TrainConfig` (every field a command-line flag), the presets, and its
config.json form (`config_dict`, `config_from_dict`). Its validation and static part are
`jaxsocial.run.startup`'s.

`TrainConfig` is three configs in one: `RunConfig` (what the run is), `ProgramConfig` (what the compiled
program is built from: with the environment and the slots, the key of the compiled-program cache) and
`DriverConfig` (how the driver runs it; the only fields `--resume` may change). A field belongs to exactly
one of them, so a new field is placed by where it is declared.
"""

from __future__ import annotations

import dataclasses
from typing import Annotated, Any

from jaxsocial import specs
from jaxsocial.agents import network_config, population
from jaxsocial.agents.bc_config import BCConfig
from jaxsocial.agents.network_config import NetworkConfig
from jaxsocial.agents.ppo_config import PPOConfig
from jaxsocial.run import jsonio, rundir, schedule
from jaxsocial.specs import CheckpointRef, EnvFlag, TextField

STAGES = TextField(schedule.parse_stages, schedule.format_stages, "WHEN:FIELD=VALUE,...;...")
INIT_FROM = TextField(CheckpointRef.parse, str, "RUN_DIR[@ITERATION]", CheckpointRef)
TEXT_FIELDS = {
    "env_args": specs.ENV_ARGS,
    "slots": population.SLOTS,
    "stages": STAGES,
    "init_from": INIT_FROM,
}
"""The fields written as text."""
TEXT_TUPLE_FIELDS = {"eval_envs": specs.ENV}
"""The fields written as lists of text, one entry per value."""

StagesFlag = Annotated[tuple[schedule.Stage, ...], STAGES.flag()]
InitFrom = Annotated[CheckpointRef | None, INIT_FROM.flag()]


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """What a run is (its environment, slots, stages, seed and chunk length): fixed for the life of a run, so
    `--resume` refuses to change it; not part of the compiled program, which gets the environment and slots
    validated (`Setup`)."""

    env: str = "goalcycle3"
    """Environment preset (see `registry.registered_envs()`), NAME or NAME:field=value,... (the overrides
    join --env-args: NAME:penalty=0.5 is NAME with --env-args penalty=0.5)."""
    env_args: specs.EnvArgsFlag = ()
    """EnvParams overrides, e.g. 'penalty=0.5,max_steps=100'."""
    slots: population.SlotsFlag = ()
    """One entry per agent slot: learner | random | frozen:RUN_DIR[#k] | expert:ckpt=RUN_DIR[#k] (a trained
    expert) | expert:KIND[:epsilon=E,forget=F] (scripted: explorer, oracle, navigator). Default: a learner in
    slot 0, the environment's scripted expert in the next two (explorer in Goal Cycle, navigator in Four
    Rooms and Maze), random distractors in any others."""
    stages: StagesFlag = ()
    """Environment changes during training, e.g. the penalty curriculum
    '0:penalty=0.5;return>=20:penalty=1.0;return>=20:penalty=1.5' or the switch to mixed solo/social
    training '5000:solo_prob=0.75' (see jaxsocial.run.schedule)."""
    seed: int = 0
    """PRNG seed."""
    chunk_iterations: int = 10
    """Iterations per compiled chunk (the driver logs and may checkpoint between chunks)."""
    preset: str = "small"
    """Hyperparameter preset the other defaults came from: 'small', 'laptop', 'paper' or 'expert'."""

    def __post_init__(self):
        for name, field in TEXT_FIELDS.items():
            if hasattr(self, name):  # a TrainConfig has them all
                field.parse_in(self, name)  # text given to the constructor: parsed here, once
        for name, field in TEXT_TUPLE_FIELDS.items():
            if hasattr(self, name):
                parsed = tuple(field.parse(v) if isinstance(v, str) else v for v in getattr(self, name))
                object.__setattr__(self, name, parsed)
        specs.join_env_in(self)  # NAME:ARGS is NAME with --env-args ARGS


@dataclasses.dataclass(frozen=True)
class ProgramConfig:
    """What the compiled training program is built from, beside the environment and slots: the cache key of
    `loop.compiled`, and fixed for the life of a run."""

    algo: str = "ppo"
    """'ppo' (reinforcement learning) or 'bc' (behaviour cloning of the expert and frozen slots)."""
    num_envs: int = 32
    """Parallel environments per rollout."""
    rollout_steps: int = 32
    """Steps per rollout (a multiple of ppo.segment_length)."""
    net: NetworkConfig = NetworkConfig(conv_channels=(8, 16, 16), hidden=32, mlp=32)
    """Network (the paper's is conv (32, 64, 64), hidden 192, mlp 64)."""
    ppo: PPOConfig = PPOConfig(
        lr=5e-4, num_minibatches=8, minibatch_segments=64, kl_target=0.02, kl_hard_limit=0.05
    )
    """PPO hyperparameters."""
    bc: BCConfig = BCConfig()
    """Behaviour-cloning hyperparameters (with --algo bc)."""
    seeds: int = 1
    """Independent seeds seed, seed + 1, ... trained together in one compiled program; each seed's metrics,
    checkpoints and policy go to run_dir/s<seed>/."""
    seed_batching: str = "auto"
    """How the seeds share the program: 'vmap' (batched), 'map' (one after another, `lax.map`) or 'auto'
    (map on CPUs, where it measured as fast and compiles faster; vmap on GPUs and TPUs)."""


@dataclasses.dataclass(frozen=True)
class DriverConfig:
    """How the driver runs the program (length, logging, checkpoints, devices, evaluation): free to change
    when a run is resumed, and never part of the compiled program."""

    iterations: int = 500
    """PPO iterations (one rollout + one update each)."""
    stop_at_return: float | None = None
    """End the run early, saved as at its end, after the first chunk whose learners' mean return (over its
    episodes and seeds) reaches this (the exploratory sweep's stop for a seed clearly past the plateau)."""
    checkpoint_every: int = 100
    """Save a checkpoint every this many iterations (rounded up to whole chunks) and at the end."""
    keep_checkpoints: int = 3
    """Checkpoints (and exported policies) kept per seed: the latest N; older ones are deleted."""
    run_name: str | None = None
    """Run directory name under runs_dir (default: '<env>-s<seed>')."""
    runs_dir: str = "runs"
    """Where run directories go."""
    resume: bool = False
    """Continue the run in the existing run directory from its latest checkpoint."""
    overwrite: bool = False
    """Delete an existing run directory of the same name and start again."""
    logger: str | None = None
    """Extra metrics sink: 'tensorboard' or 'wandb' (off by default)."""
    progress: bool = True
    """Show a progress line."""
    blind: bool = False
    """Show no returns while training or at the end (progress: iterations and speed only): a pre-registered
    design's runs stay blind until every seed is in."""
    devices: int = 0
    """Devices the environments are split over (data parallel; 0: all devices of all processes)."""
    coordinator: str | None = None
    """Multi-host: HOST:PORT of process 0, the same for every process, or 'auto' (Slurm, Open MPI, TPU);
    default $JAX_COORDINATOR_ADDRESS."""
    num_processes: int | None = None
    """Multi-host: number of processes, one per host (default $JAX_NUM_PROCESSES)."""
    process_id: int | None = None
    """Multi-host: this process's index, 0 to num_processes - 1 (default $JAX_PROCESS_ID)."""
    compile_cache: str | None = None
    """Persistent compilation cache directory: a later run of the same program on the same CPU kind and
    visible-core count skips compiling (off by default; see `python -m jaxsocial.run.compile_cache`)."""
    eval_envs: tuple[EnvFlag, ...] = ()
    """Environments the first learner is evaluated in during training, each NAME or NAME:field=value,...
    (e.g. goalcycle3-solo goalcycle4), beside that environment's default companions; logged in
    metrics.jsonl as 'eval/<spec>' on every eval_every-th iteration and the last."""
    eval_every: int = 100
    """Iterations between evaluations (with eval_envs)."""
    eval_episodes: int = 64
    """Episodes per evaluation environment and evaluation."""
    on_nonfinite: str = "stop"
    """What a non-finite loss, gradient norm or parameter does: 'stop' (exit with an error; the last finite
    checkpoint and policy stay the latest) or 'warn' (report it and train on)."""
    init_from: InitFrom = None
    """Start a new run from another run's learners: RUN_DIR or RUN_DIR@ITERATION (default: its latest
    checkpoint); the source's params and optimiser state, this run's flags and stages."""


@dataclasses.dataclass(frozen=True)
class TrainConfig(DriverConfig, ProgramConfig, RunConfig):
    """A training run. Every field is a command-line flag (`RunConfig`'s first, then `ProgramConfig`'s and
    `DriverConfig`'s)."""

    @property
    def program(self) -> ProgramConfig:
        """The fields the compiled program is built from."""
        return ProgramConfig(**{f.name: getattr(self, f.name) for f in dataclasses.fields(ProgramConfig)})

    @property
    def driver(self) -> DriverConfig:
        """The fields the driver runs the program by."""
        return DriverConfig(**{f.name: getattr(self, f.name) for f in dataclasses.fields(DriverConfig)})

    @property
    def env_overrides(self) -> dict[str, Any]:
        """`env_args` as a dict."""
        return dict(self.env_args)


EXPERT_CURRICULUM = "0:penalty=0.5;return>=10:penalty=1.0;return>=10:penalty=1.5"
"""The penalty curriculum (paper section 3.1): low penalty first, raised once the learner's mean episode
return reaches 10 (a third of what a perfect 250-step Goal Cycle episode collects)."""

PRESETS = {
    "small": TrainConfig(),
    "paper": TrainConfig(
        preset="paper",
        iterations=11445,  # 375M env steps, the paper's budget
        num_envs=128,
        rollout_steps=256,
        chunk_iterations=10,
        checkpoint_every=500,
        net=NetworkConfig(),
        ppo=PPOConfig(),
    ),
}
CPU_NETWORK = dataclasses.replace(
    PRESETS["small"].net, conv_channels=(16, 32, 32), hidden=64, mlp=64, n_actions=3
)
"""The small network of the CPU science (the `cpu` and `laptop` recipe scales): a 16-32-32 conv, a 64-unit
LSTM, the 3 movement actions."""
CPU_PPO = dataclasses.replace(
    PRESETS["small"].ppo,
    lr=1e-3,
    entropy_coef=0.01,
    num_minibatches=16,
    minibatch_segments=64,
    kl_target=0.02,
    kl_hard_limit=0.05,
)
"""The PPO of the CPU science: learning rate 1e-3, entropy bonus 0.01, 16 minibatches of 64 segments, the KL
stop at 0.02 (hard limit 0.05)."""
PRESETS["laptop"] = dataclasses.replace(
    PRESETS["small"],
    preset="laptop",
    env_args=(("width", 7), ("height", 7)),
    iterations=2442,  # 20.0M env-steps
    num_envs=128,
    rollout_steps=64,
    chunk_iterations=10,
    checkpoint_every=100,
    net=dataclasses.replace(CPU_NETWORK, aux="rec"),
    ppo=dataclasses.replace(CPU_PPO, num_minibatches=8, recompute_every=8),
)
"""Social learning on a laptop (the `laptop` recipe scale): a learner with the reconstruction loss beside two
experts in a 7x7 Goal Cycle, the cpu scale's small network, one gradient sample per env-step, 20.0M
env-steps (docs/experiments.md)."""
PRESETS["expert"] = dataclasses.replace(
    PRESETS["paper"],
    preset="expert",
    env="goalcycle3-solo",
    stages=EXPERT_CURRICULUM,
    ppo=PPOConfig(lr=1e-5),
)
"""The paper's expert training: paper network and PPO with the expert learning rate 1e-5, alone, through
the penalty curriculum; later runs load the result with `expert:ckpt=RUN_DIR`."""


ALGOS = ("ppo", "bc")
ON_NONFINITE = ("stop", "warn")
SEED_BATCHING = ("auto", "vmap", "map")

FIXED_FIELDS = frozenset(f.name for f in dataclasses.fields(RunConfig) + dataclasses.fields(ProgramConfig))
"""The fields `--resume` may not change (the others are `DriverConfig`'s)."""


def resume_conflicts(saved: dict[str, Any], new: dict[str, Any]) -> list[str]:
    """The dotted keys (e.g. 'net.hidden') of `FIXED_FIELDS` in which config `new` differs from a run's
    `saved` config (both as config.json holds them; `saved` is read as `config_from_dict` reads it, so text
    written differently, e.g. 'width=9, height=9', and fields added since at their defaults do not differ)."""
    saved = config_dict(config_from_dict(saved))
    return [k for k in rundir.config_diff(saved, new) if k.split(".")[0] in FIXED_FIELDS]


def config_dict(cfg: TrainConfig) -> dict[str, Any]:
    """`cfg` as plain JSON values (what config.json holds; `TEXT_FIELDS` as their text)."""
    values = {}
    for field in dataclasses.fields(cfg):
        value = getattr(cfg, field.name)
        if field.name in TEXT_FIELDS and value is not None:
            value = TEXT_FIELDS[field.name].format(value)
        elif field.name in TEXT_TUPLE_FIELDS:
            value = [TEXT_TUPLE_FIELDS[field.name].format(v) for v in value]
        elif dataclasses.is_dataclass(value):
            value = dataclasses.asdict(value)
        values[field.name] = value
    return jsonio.to_json(values)


LEGACY_KEYS = {
    "ppo": {"chunk_length": "segment_length", "minibatch_chunks": "minibatch_segments"},
    "net": network_config.LEGACY_KEYS,
}
"""config.json's fields renamed since, per section: {section: {old: new}}. Runs, records and policies written
before the renames hold the old names, which every reader maps (`modern_keys`); `flags.LEGACY_FLAGS` are the
same renames as command-line flags."""


def modern_keys(values: dict[str, Any]) -> dict[str, Any]:
    """A config.json's values (a copy) with the fields renamed since (`LEGACY_KEYS`) under today's names."""
    values = dict(values)
    for section, renames in LEGACY_KEYS.items():
        if isinstance(values.get(section), dict):
            values[section] = network_config.renamed_keys(values[section], renames)
    return values


def config_from_dict(values: dict[str, Any]) -> TrainConfig:
    """A TrainConfig from `config_dict` output (config.json): nested configs rebuilt, lists made tuples,
    fields added since the run was written take their defaults, fields renamed since read under their new
    names (`modern_keys`)."""
    values = modern_keys(values)

    def build(cls, raw: dict[str, Any]):
        kwargs, defaults = {}, cls()
        for field in dataclasses.fields(cls):
            if field.name not in raw:
                continue
            value = raw[field.name]
            default = getattr(defaults, field.name)
            if dataclasses.is_dataclass(default):
                value = build(type(default), value)
            elif field.name in TEXT_FIELDS and value is not None:
                value = TEXT_FIELDS[field.name].parse(value)
            elif field.name in TEXT_TUPLE_FIELDS:
                value = tuple(TEXT_TUPLE_FIELDS[field.name].parse(v) for v in value)
            elif isinstance(value, list):
                value = tuple(value)
            kwargs[field.name] = value
        return cls(**kwargs)

    return build(TrainConfig, values)
