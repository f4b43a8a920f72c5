"""A run's static part, validated and built once before anything is written or compiled: `setup(cfg) ->
Setup` (the environment of every stage and evaluation, the slots, the frozen policies); and
`resolve_network`, which makes the network's "auto" choices for this machine. What a run is, its
`TrainConfig`, is `jaxsocial.run.config`'s. Validating imports no JAX (a bad command is refused at once);
loading frozen policies and the "auto" choices do.
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

from jaxsocial import specs
from jaxsocial.agents import population, ppo_config
from jaxsocial.env import registry
from jaxsocial.env.params import NUM_ACTIONS, EnvParams
from jaxsocial.run import schedule
from jaxsocial.run.config import ALGOS, ON_NONFINITE, SEED_BATCHING, TrainConfig


class EvalEnv(NamedTuple):
    """An environment the first learner is evaluated in during training (`TrainConfig.eval_envs`): its spec,
    its default companions (`population.default_population`) and its parameters."""

    spec: specs.EnvSpec
    pop: population.Population
    env_params: EnvParams


class Setup(NamedTuple):
    """Everything static about a run, validated (`setup`)."""

    env_params: EnvParams  # before the first stage (`--env` with `--env-args`)
    pop: population.Population
    stages: tuple[schedule.Stage, ...]
    frozen_params: Any  # stacked params of frozen slots, or None (also None when not loaded)
    stage_envs: tuple[EnvParams, ...]  # the environment of stages -1, 0, 1, ...
    eval_envs: tuple[EvalEnv, ...]  # `TrainConfig.eval_envs`, built

    def stage(self, index: int) -> EnvParams:
        """The environment of stage `index` (-1: before the first stage)."""
        return self.stage_envs[index + 1]


def setup(cfg: TrainConfig, load_frozen: bool = True) -> Setup:
    """Validate the config and load frozen policies; raises ValueError before anything compiles. First the
    settings alone, then the environments are built (`environments`: each stage's, each evaluation's) and
    the slots, and each part checks what it owns: the network the environments it sees, the population its
    experts and solo episodes, PPO its batch. A run calls this once."""
    _check_settings(cfg)
    stage_envs, eval_envs = environments(cfg)
    env_params = stage_envs[0]
    pop = population.Population(population.run_slots(cfg.slots, env_params))
    wheres = ["--env-args", *(f"stage {i}" for i in range(len(cfg.stages)))]
    for where, stage_params in zip(wheres, stage_envs, strict=True):
        cfg.net.check_env(stage_params, where)
        pop.check_solo_learners(stage_params, where)
        pop.validate(stage_params)
    for spec, eval_env in eval_envs:
        cfg.net.check_env(eval_env, f"eval env {str(spec)!r}")
    cfg.net.check_others(env_params.n_agents)
    if cfg.algo == "ppo":
        ppo_config.validate(cfg.ppo, cfg.rollout_steps, cfg.num_envs)
    elif not pop.demonstrators:
        raise ValueError("--algo bc clones expert or frozen slots, and --slots has none")
    evals = tuple(EvalEnv(spec, population.default_population(e), e) for spec, e in eval_envs)
    frozen = None
    if load_frozen and pop.frozen:
        from jaxsocial.run import policy_io  # orbax: not imported where no policy is read

        frozen = policy_io.load_frozen(pop, cfg.net)
    return Setup(env_params, pop, cfg.stages, frozen, stage_envs, evals)


def environments(cfg: TrainConfig) -> tuple[tuple[EnvParams, ...], list[tuple[specs.EnvSpec, EnvParams]]]:
    """The environment before the stages and of each stage (`Setup.stage_envs`; ValueError where a stage
    changes what sets array shapes, `schedule.STRUCTURAL_FIELDS`), and each evaluation environment's
    (spec, parameters)."""
    stages = range(len(cfg.stages))
    overrides = [
        cfg.env_overrides,
        *({**cfg.env_overrides, **schedule.overrides_at(cfg.stages, i)} for i in stages),
    ]
    # before the stages, then each
    stage_envs = tuple(registry.env_params(cfg.env, tuple(o.items())) for o in overrides)
    first = stage_envs[0]
    for i, stage_params in zip(stages, stage_envs[1:], strict=True):
        if changed := [
            f for f in schedule.STRUCTURAL_FIELDS if getattr(stage_params, f) != getattr(first, f)
        ]:
            raise ValueError(
                f"stage {i} changes {changed}, which set array shapes; a stage may not change them"
            )
    return stage_envs, [(spec, registry.env_params(spec.name, spec.args)) for spec in cfg.eval_envs]


def _check_settings(cfg: TrainConfig) -> None:
    """ValueError for a setting out of range, or settings that do not go together, checked without building
    anything."""
    if cfg.algo not in ALGOS:
        raise ValueError(f"unknown --algo {cfg.algo!r}; choose one of {ALGOS}")
    for name in ("num_envs", "rollout_steps", "keep_checkpoints"):
        value = getattr(cfg, name)
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ValueError(f"{name}={value!r} must be a whole number >= 1 (for every --algo)")
    for name in ("iterations", "chunk_iterations", "checkpoint_every"):
        if getattr(cfg, name) < 1:
            raise ValueError(f"{name}={getattr(cfg, name)} must be >= 1")
    if isinstance(cfg.seeds, bool) or not isinstance(cfg.seeds, int) or cfg.seeds < 1:
        raise ValueError(f"seeds must be a whole number >= 1, got {cfg.seeds!r}")
    if cfg.on_nonfinite not in ON_NONFINITE:
        raise ValueError(f"unknown on_nonfinite {cfg.on_nonfinite!r}; choose from {ON_NONFINITE}")
    if cfg.seed_batching not in SEED_BATCHING:
        raise ValueError(f"unknown seed_batching {cfg.seed_batching!r}; choose from {SEED_BATCHING}")
    if cfg.eval_envs and cfg.eval_every < 1:
        raise ValueError(f"eval_every={cfg.eval_every} must be >= 1")
    if cfg.eval_envs and cfg.eval_episodes < 1:
        raise ValueError(f"eval_episodes={cfg.eval_episodes} must be >= 1")
    if cfg.seeds > 1 and any(stage.threshold is not None for stage in cfg.stages):
        raise ValueError(
            "--seeds > 1 trains the seeds in one program, which is in one stage at a time; a stage "
            "triggered by the return would start at another iteration for each seed: train them one by one"
        )
    if cfg.algo == "bc" and cfg.net.n_actions != NUM_ACTIONS:
        raise ValueError(
            f"--algo bc clones demonstrators that use all {NUM_ACTIONS} actions (scripted experts idle with "
            f"'done' and act at random with epsilon), so net.n_actions must be {NUM_ACTIONS}, not "
            f"{cfg.net.n_actions}"
        )
    if cfg.net.attention and cfg.algo != "ppo":
        raise ValueError(
            f"net.aux={cfg.net.aux!r}: the attention loss trains PPO learners, so it needs --algo ppo (got "
            f"--algo {cfg.algo})"
        )


def resolve_network(cfg: TrainConfig, pop: population.Population) -> TrainConfig:
    """`cfg` with its network's "auto" choices (`--net.dtype auto`, `--net.conv-impl auto`) made for this
    machine (`autotune.resolve`: measured once, then cached) at the frames of one gradient step (PPO: a
    minibatch; BC: every demonstrator slot of `pop`'s rollout), so that config.json and saved policies name
    what ran; `cfg` itself when nothing is "auto". ValueError in a multi-process run, whose processes could
    measure differently."""
    if not cfg.net.unresolved:
        return cfg
    import jax

    if jax.process_count() > 1:
        raise ValueError("--net.dtype/--net.conv-impl 'auto' are chosen per machine: give them concretely")
    frames = (
        cfg.ppo.minibatch_segments * cfg.ppo.segment_length
        if cfg.algo == "ppo"
        else cfg.num_envs * cfg.rollout_steps * len(pop.demonstrators)
    )
    from jaxsocial.run import autotune  # its network and kernels: only where something is "auto"

    return dataclasses.replace(cfg, net=autotune.resolve(cfg.net, frames))
