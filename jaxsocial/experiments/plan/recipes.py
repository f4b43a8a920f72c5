"""The paper's experiments as named recipes: conditions x seeds x scale.

A *scale* holds the `TrainConfig` every condition starts from; a *condition* says, as typed values, what it
changes (the auxiliary loss, the environment, slots, stages, ...), and `condition_config` applies that with
`dataclasses.replace`; its command line is derived from the result (`flags.config_flags`). A *recipe* names
the conditions one figure compares, what is evaluated after training, and how the figure is drawn.
Conditions are shared between recipes (`mixing` reuses `h1`'s social PPO + pred runs), so each is trained once
per scale and seed range.

Scales:
  * `cpu`: the paper's mechanism sized for 2 CPU cores, every condition's seeds within a session (see
    `CPU.note` for what differs from the paper and why; the README's Results say what it showed);
  * `laptop`: the science's home on 2 CPU cores, chosen by the exploratory sweep: a 7x7 grid, one gradient
    sample per env-step, 20.0M env-steps a seed, each seed on one core (`run --cores 0 1`; `LAPTOP.note`);
  * `paper`: the paper's settings (`--preset paper`: 13x13 Goal Cycle, the paper's network and PPO, 375M
    env-steps per run); meant for GPUs;
  * `tiny`: under a minute a run, most of it compiling, for tests and the notebook's smoke run (learns
    nothing).
"""

from __future__ import annotations

import dataclasses

from jaxsocial.experiments.plan.conditions import CONDITIONS, PENALTY_CONDITIONS, Condition
from jaxsocial.run import config, flags, schedule
from jaxsocial.run.config import PRESETS, TrainConfig
from jaxsocial.run.cost import MEASURED, Measured, read_rate
from jaxsocial.specs import EnvArgsFlag, EnvSpec


@dataclasses.dataclass(frozen=True)
class Scale:
    """A size of every recipe: the training config every condition starts from and the evaluation budget."""

    name: str
    config: TrainConfig
    """What every condition starts from: its network, PPO, rollout, iterations and `env_args` (which also
    size the Goal Cycle evaluation environments, e.g. the grid)."""
    eval_every: int
    """Iterations between evaluations during training (conditions with `eval_during_training`)."""
    eval_episodes: int
    """Episodes per seed of every evaluation (during and after training)."""
    note: str = ""
    caveat: str = ""
    """What a reader of its figures must know first (written on every figure), e.g. that it learns nothing."""
    runs_subdir: str = ""
    """A folder of the scale's runs the recipe's runs go in ('prereg-<design>' for a pre-registered design's,
    so that no ordinary recipe run can share their directories)."""
    rate: Measured | None = None
    """Where a committed benchmark measured the speed of one of its runs alone in a single-core process
    (`run --cores`), for the cost `experiments run` states before training (None: not measured on a CPU)."""
    for_gpus: bool = False
    """Sized for GPUs (the gpu and paper scales): too slow on CPU cores to plan on them."""

    @property
    def iterations(self) -> int:
        """Training iterations of every condition."""
        return self.config.iterations

    @property
    def runs_root(self) -> str:
        """Where this scale's runs go under the runs root: '<name>' or '<name>/<runs_subdir>'."""
        return f"{self.name}/{self.runs_subdir}" if self.runs_subdir else self.name


SMALL = PRESETS["small"]

CPU = Scale(
    name="cpu",
    config=dataclasses.replace(
        SMALL,
        env_args=(("width", 9), ("height", 9)),
        iterations=200,
        num_envs=128,
        rollout_steps=64,
        chunk_iterations=10,
        checkpoint_every=100,
        net=config.CPU_NETWORK,
        ppo=config.CPU_PPO,
    ),
    eval_every=50,
    eval_episodes=64,
    rate=Measured("benchmarks/results/recipe_sps.json", "recipe", "recipe", "cpu_rec"),
    note=(
        "9x9 Goal Cycle (7x7 interior, 4 clutter walls) instead of 13x13, so the experts are in view more "
        "often; the learner chooses among the 3 movement actions (the paper's other 4 do nothing in Goal "
        "Cycle; behaviour cloning keeps all 7, which the experts use to idle); a 16-32-32 conv, 64-unit LSTM "
        "network instead of 32-64-64 and 192; 128 envs x 64 steps per iteration, two passes of 16 "
        "minibatches (2 gradient samples per env-step); learning rate 1e-3 and entropy bonus 0.01 (the "
        "paper: 1e-4 and 1e-5); 200 iterations (1.6M env-steps) per run, 80x fewer than the paper's 125M "
        "steps before social learning appeared. Kept: independent learners beside two scripted experts, 7x7 "
        "partial views in RGB, the -1.5 penalty, prestige colours, the auxiliary loss (coefficient 3)."
    ),
)

GPU = Scale(
    name="gpu",
    for_gpus=True,
    config=dataclasses.replace(
        CPU.config,
        iterations=600,
        num_envs=1024,
        net=dataclasses.replace(CPU.config.net, frame_batch=16384),
        ppo=dataclasses.replace(CPU.config.ppo, minibatch_segments=512),
    ),
    eval_every=100,
    eval_episodes=64,
    note=(
        "The cpu scale's environment, network and PPO settings with 8x the environments (1,024 per seed) and "
        "8x larger minibatches (the same 2 gradient samples per env-step), for 600 iterations: 39M env-steps "
        "per seed, 25x the cpu scale and about a third of the paper's 125M. On one H100 the 3 seeds of a "
        "condition train in one program, two conditions side by side, each pair in under 9 minutes."
    ),
)

LAPTOP = Scale(
    name="laptop",
    config=PRESETS["laptop"],
    eval_every=250,
    eval_episodes=64,
    rate=MEASURED["laptop"],
    note=(
        "The cpu scale's network and learning rates in a 7x7 Goal Cycle (5x5 interior) instead of 9x9, with "
        "one pass of 8 minibatches (1 gradient sample per env-step, the rollout's own value targets: no "
        "recompute) instead of two passes of 16, for 2,442 iterations (20.0M env-steps, about 25-30 minutes "
        "a seed on one core of a 2-core AMD EPYC; `run --cores 0 1` trains two seeds at once). The 7x7 view "
        "covers most of the grid, so the experts and the tiles they visit are nearly always in view. Chosen "
        "by the exploratory sweep (docs/experiments.md, `mb8k8_rec_7x7` and its baselines), the first "
        "setting at which social learners with an auxiliary loss left the one-tile plateau within 20M "
        "env-steps under the 1.5 penalty while solo learners did not. Kept from the paper: independent "
        "learners beside two scripted experts, 7x7 partial RGB views, the -1.5 penalty, prestige colours, "
        "the auxiliary loss (coefficient 3); the rest as the cpu scale's note says. `--preset laptop` is its "
        "social PPO + rec run."
    ),
)

PAPER = Scale(
    name="paper",
    for_gpus=True,
    config=PRESETS["paper"],
    eval_every=200,
    eval_episodes=100,
    note="The paper's settings (13x13 Goal Cycle, paper network and PPO, 375M env-steps per run).",
)

TINY = Scale(
    name="tiny",
    config=dataclasses.replace(
        SMALL,
        env_args=(("width", 7), ("height", 7), ("max_steps", 20)),
        iterations=4,
        num_envs=4,
        rollout_steps=16,
        chunk_iterations=2,
        checkpoint_every=2,
        net=dataclasses.replace(SMALL.net, conv_channels=(4, 4, 4), hidden=8, mlp=8),
        ppo=dataclasses.replace(SMALL.ppo, num_minibatches=1, minibatch_segments=4),
    ),
    eval_every=2,
    eval_episodes=2,
    note="Plumbing only: seconds per run, learns nothing.",
    caveat="plumbing only: it learns nothing",
)


def laptop_in_grid(size: int, note: str) -> Scale:
    """The laptop scale in a `size` x `size` Goal Cycle, named `laptop<size>`, with its own `note`."""
    return Scale(
        name=f"laptop{size}",
        config=dataclasses.replace(LAPTOP.config, env_args=(("width", size), ("height", size))),
        eval_every=LAPTOP.eval_every,
        eval_episodes=LAPTOP.eval_episodes,
        note=note,
    )


LAPTOP8 = laptop_in_grid(
    8,
    "The laptop scale in an 8x8 Goal Cycle (6x6 interior), as the sweep's `mb8k8_*_8x8` settings without "
    "their early stop: there, with the prediction loss, 3 of 7 social seeds and none of 7 solo seeds left "
    "the one-tile plateau within 20.0M env-steps (docs/experiments.md). The scale of the `pred8` design.",
)

LAPTOP10 = laptop_in_grid(
    10,
    "The laptop scale in a 10x10 Goal Cycle (8x8 interior; the paper's is 13x13 with 11x11), as the sweep's "
    "`map_g3_*pred_10x10_50m` settings without their early stop: there, with the prediction loss, 2 of 4 "
    "social seeds left the one-tile plateau within 20.0M env-steps (3 of 4 within 50.0M) and none of 2 solo "
    "seeds within 50.0M (docs/experiments.md). The scale of the `pred10` design.",
)

SCALES = {s.name: s for s in (CPU, LAPTOP, LAPTOP8, LAPTOP10, GPU, PAPER, TINY)}


@dataclasses.dataclass(frozen=True)
class Recipe:
    """A figure of the paper: the conditions it compares and how it is drawn."""

    name: str
    title: str
    conditions: tuple[str, ...]
    kind: str
    """'curves' (return through training, final-return CIs), 'transfer' (zero-shot bars), 'mixing'
    (return through training in three environments), 'predictions' (a trained learner's next frames), 'ct'
    (the cultural-transmission evaluation, `jaxsocial.evaluate --protocol ct`, after training) or 'takeoff'
    (a time-to-takeoff design: the curves, then the zero-shot returns and the CT protocol)."""
    transfer_envs: tuple[str, ...] = ()
    """Evaluation environments after training, zero-shot (a 'transfer' recipe's bars; a 'curves' recipe
    summarises them beside its curves); Goal Cycle ones take the scale's env_args."""
    hypotheses: tuple[tuple[str, str], ...] = ()
    """The comparisons the recipe states in advance: (a, b) says a's seeds learn more often than b's. Its
    summary tests these one-sided and every other pair as exploratory (`kinds.learned_seed_tests`)."""
    design: str | None = None
    """The pre-registered design it carries: its seeds and, at its scale, its budget
    (`prereg.recipe_scale`)."""


AUX_OVER_BASELINES = tuple(
    (aux, baseline) for aux in ("social_rec", "social_pred") for baseline in ("solo_pred", "social_none")
)
"""H1 (the paper's Fig. 3): each social learner with an auxiliary loss learns more often than each
baseline."""

RECIPES = {
    r.name: r
    for r in (
        Recipe("h1", "H1: social learning with an auxiliary loss (paper Fig. 3)",
               ("solo_pred", "social_none", "social_rec", "social_pred"), "curves",
               hypotheses=AUX_OVER_BASELINES),
        Recipe("h1_prereg", "H1, pre-registered: auxiliary-loss learners against the baselines",
               ("solo_pred", "social_none", "social_rec", "social_pred"), "curves",
               hypotheses=AUX_OVER_BASELINES, design="h1_prereg"),
        Recipe("h1_laptop", "H1 on two CPU cores, pre-registered: auxiliary-loss learners against baselines",
               ("solo_pred", "social_none", "social_rec", "social_pred"), "curves",
               hypotheses=AUX_OVER_BASELINES, design="h1_laptop"),
        Recipe("h1_early", "H1 early, pre-registered: PPO + aux rec beside the experts and alone",
               ("solo_rec", "social_rec"), "curves", hypotheses=(("social_rec", "solo_rec"),),
               design="h1_early"),
        Recipe("h1_sooner", "H1 sooner, pre-registered: PPO + aux rec beside the experts and alone, by 6.0M",
               ("solo_rec", "social_rec"), "curves", hypotheses=(("social_rec", "solo_rec"),),
               design="h1_sooner"),
        Recipe("experts", "Experts, pre-registered: PPO + aux rec beside the experts and alone, time to "
               "takeoff and zero-shot returns beside new experts", ("solo_rec", "social_rec"), "takeoff",
               ("goalcycle4", "goalcycle3-solo"), hypotheses=(("social_rec", "solo_rec"),), design="experts"),
        Recipe("pred8", "The prediction loss in 8x8, pre-registered: PPO + pred beside the experts and alone",
               ("solo_pred", "social_pred"), "curves", hypotheses=(("social_pred", "solo_pred"),),
               design="pred8"),
        Recipe("pred10", "The prediction loss in 10x10, pre-registered: PPO + pred beside the experts and "
               "alone", ("solo_pred", "social_pred"), "curves", hypotheses=(("social_pred", "solo_pred"),),
               design="pred10"),
        Recipe("nopenalty8", "No penalty in 8x8, pre-registered: solo PPO + pred without the penalty against "
               "pred8's solo learners under it", ("solo_pred_nopenalty",), "curves", ("goalcycle3-solo",),
               design="nopenalty8"),
        Recipe("imperfect8", "Experts at half strength in 8x8, pre-registered (paper Fig. 4): social PPO + "
               "pred beside them against pred8's solo learners", ("social_pred_imperfect_half",), "curves",
               design="imperfect8"),
        Recipe("imitation8", "Imitation in 8x8, pre-registered (paper Fig. 5): behaviour cloning of the "
               "experts against pred8's social learners, zero-shot", ("bc",), "curves",
               ("goalcycle4", "fourrooms:width=9,height=9", "maze:width=7,height=7"), design="imitation8"),
        Recipe("imperfect", "Near-optimal vs imperfect experts (paper Fig. 4)",
               ("solo_pred", "social_pred", "social_pred_imperfect"), "curves",
               hypotheses=(("social_pred", "solo_pred"), ("social_pred_imperfect", "solo_pred"))),
        Recipe("fig5_transfer", "H2: zero-shot transfer with new experts (paper Fig. 5)",
               ("social_pred", "solo_pred", "bc"), "transfer", ("goalcycle4", "fourrooms", "maze")),
        Recipe("fig6_mixing", "Solo/social mixing (paper Fig. 6)",
               ("social_pred", "social_pred_mixed", "social_pred_mixed_learned"), "mixing"),
        Recipe("no_penalty", "Appendix: no exploration penalty",
               ("social_pred_nopenalty", "solo_pred_nopenalty"), "transfer", ("goalcycle4",)),
        Recipe("penalty", "Beyond the paper: social and solo learners at penalties 0, 0.5 and 1.5",
               (*PENALTY_CONDITIONS, "social_pred", "solo_pred"), "curves"),
        Recipe("distractors", "Appendix: random distractors beside the experts, in training and zero-shot",
               ("solo_pred", "social_pred", "social_pred_distractors"), "curves",
               ("goalcycle4", "goalcycle4-distractors", "goalcycle3-distractors")),
        Recipe("bc", "Appendix: behaviour cloning training curve", ("bc",), "curves"),
        Recipe("curriculum", "Appendix: expert training through the penalty curriculum",
               ("expert_curriculum", "solo_pred"), "curves",
               hypotheses=(("expert_curriculum", "solo_pred"),)),
        Recipe("predictions", "A trained learner's predicted next frames (paper Fig. 2)", ("social_pred",),
               "predictions"),
        Recipe("ct", "Beyond the paper: cultural transmission (expert dropout, attention loss)",
               ("social_pred", "social_pred_dropout", "social_pred_attention", "social_medal"), "ct"),
    )
}  # fmt: skip


def goalcycle_spec(name: str, scale: Scale) -> EnvSpec:
    """The environment `name` with the scale's Goal Cycle overrides (other layouts keep their own grids)."""
    return EnvSpec(name, scale.config.env_args if name.startswith("goalcycle") else ())


def with_env_args(base: EnvArgsFlag, extra: EnvArgsFlag) -> EnvArgsFlag:
    """EnvParams overrides `base`, then `extra` (which wins where both set a field)."""
    return tuple({**dict(base), **dict(extra)}.items())


def mixing_switch(scale: Scale, cond: Condition) -> int:
    """The iteration at which a mixed condition switches to 75% solo episodes."""
    return max(1, round(scale.iterations * cond.mixed_from))


def condition_run_name(scale: Scale, condition: str, seed: int, seeds: int) -> str:
    """The run directory of a condition under the runs root:
    `<scale>[/<runs_subdir>]/<condition>-s<first>-<last>` (`Scale.runs_root`)."""
    return f"{scale.runs_root}/{condition}-s{seed}-{seed + seeds - 1}"


def _stages(scale: Scale, cond: Condition) -> tuple[schedule.Stage, ...]:
    solo = (("solo_prob", 0.75),)
    if cond.penalty_curriculum:
        third = max(1, scale.iterations // 3)
        return tuple(
            schedule.Stage((("penalty", penalty),), start=start)
            for start, penalty in ((0, 0.5), (third, 1.0), (2 * third, 1.5))
        )
    if cond.mixed_from is not None:
        return (schedule.Stage(solo, start=mixing_switch(scale, cond)),)
    if cond.mixed_at_return is not None:
        return (schedule.Stage(solo, threshold=float(cond.mixed_at_return)),)
    return ()


def condition_config(scale: Scale, condition: str, seed: int, seeds: int, runs_dir: str) -> TrainConfig:
    """The `TrainConfig` of a condition: the scale's with the condition's changes (validated by
    `startup.setup` when it runs)."""
    cond, base = CONDITIONS[condition], scale.config
    net = dataclasses.replace(base.net, aux=cond.aux, n_actions=cond.n_actions or base.net.n_actions)
    evaluation = {}
    if cond.eval_during_training:
        evaluation = {
            "eval_envs": (goalcycle_spec("goalcycle3-solo", scale), goalcycle_spec("goalcycle4", scale)),
            "eval_every": scale.eval_every,
            "eval_episodes": scale.eval_episodes,
        }
    cfg = dataclasses.replace(
        base,
        env=cond.env,
        env_args=with_env_args(base.env_args, cond.env_args),
        slots=cond.slots,
        stages=_stages(scale, cond),
        algo=cond.algo,
        net=net,
        seed=seed,
        seeds=seeds,
        runs_dir=runs_dir,
        run_name=condition_run_name(scale, condition, seed, seeds),
        **evaluation,
    )
    return flags.with_env_observation(cfg)


def condition_flags(scale: Scale, condition: str, seed: int, seeds: int, runs_dir: str) -> list[str]:
    """The `python -m jaxsocial.train` command line of a condition at a scale (`flags.config_flags`)."""
    return flags.config_flags(condition_config(scale, condition, seed, seeds, runs_dir))


def condition_programs(
    scale: Scale, condition: str, seed: int, seeds: int, runs_dir: str, per_program: int | None = None
) -> list[TrainConfig]:
    """The training programs of a condition's seeds seed..seed+seeds-1: one for all of them, or (with
    `per_program` K) one for each K consecutive seeds (run `<condition>-s<first>-<last>`), vmapped where
    K > 1; one per seed whatever K when the condition switches stage on each seed's own return."""
    if CONDITIONS[condition].program_per_seed:
        per_program = 1
    if per_program is None:
        return [condition_config(scale, condition, seed, seeds, runs_dir)]
    programs = []
    for first in range(seed, seed + seeds, per_program):
        cfg = condition_config(scale, condition, first, min(per_program, seed + seeds - first), runs_dir)
        programs.append(dataclasses.replace(cfg, seed_batching="vmap") if cfg.seeds > 1 else cfg)
    return programs


def cost(scale: Scale, runs: int, env_steps_per_run: int, processes: int) -> str | None:
    """What `runs` runs of `env_steps_per_run` each cost at the scale's measured rate, `processes` at a time
    (None where the scale has no rate, or the checkout lacks its benchmark): CPU-minutes and wall-clock
    minutes, with the rate's CPU."""
    r = None if scale.rate is None else read_rate(scale.rate)
    if r is None:
        return None
    minutes = runs * (env_steps_per_run / r.env_steps_per_s + r.compile_s) / 60
    return (
        f"{runs} runs x {env_steps_per_run / 1e6:.2f}M env-steps: about {minutes:.0f} CPU-minutes, "
        f"{minutes / max(1, min(processes, runs)):.0f} minutes on {processes} core(s) at "
        f"{r.env_steps_per_s:,.0f} env-steps/s a single-core run ({r.machine}; {r.source}); machines differ "
        "up to about 4x"
    )
