"""A design's follow-ups planned: which learned seed they start from (`Source`), the design and scale
(`Plan`), the environments a learned policy and a branch are played in, and each branch's training config
(`arm_config`). Launched by `launch.followup_runs`, summarised by `analyse.followup_results`; the command is
`python -m jaxsocial.experiments followup` (`jaxsocial.experiments.followup`)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from jaxsocial.experiments.plan import catalogue, conditions, recipes
from jaxsocial.run.config import TrainConfig
from jaxsocial.specs import CheckpointRef, EnvSpec

EVAL_EPISODES = 256
"""Episodes per evaluation (the issue asks for at least 256)."""
BRANCH_FRACTION = 0.25
"""The branches' length, as a fraction of the design's iterations (5.0M env-steps at the laptop scale)."""
MIXED_SOLO_PROB = 0.75
"""The share of solo episodes in the mixed branch (the paper's 75%)."""
ARMS = {"social": 0.0, "mixed": MIXED_SOLO_PROB}
"""Branch name -> its share of solo episodes."""
BRANCH_ENV = conditions.LEARNERS["social"]
"""Every branch trains beside the experts, whatever the source's condition: a seed that learned alone
(solo PPO + aux pred) meets them there for the first time."""


@dataclasses.dataclass(frozen=True)
class Source:
    """A design seed that learned: its condition, seed and run (or record) directory."""

    condition: str
    seed: int
    seed_dir: Path

    @property
    def name(self) -> str:
        """`<condition>-s<seed>`: the follow-ups' directory of this seed (`condition_of` reads it back)."""
        return f"{self.condition}-s{self.seed}"

    @staticmethod
    def condition_of(name: str) -> str:
        """The condition in a `name`."""
        return name.rsplit("-s", 1)[0]


@dataclasses.dataclass(frozen=True)
class Plan:
    """A design's follow-ups: the recipe that carries it, the scale it runs at and the design (the command
    makes one from a recipe's name: `jaxsocial.experiments.followup.plan_of`)."""

    recipe: recipes.Recipe
    scale: recipes.Scale
    design: catalogue.Design
    """A training design (`prereg.TrainingDesign`): its seeds, iterations and learned threshold are read."""
    episodes: int = EVAL_EPISODES
    """Episodes per evaluation."""

    def root(self, runs_dir: str | Path) -> Path:
        """Where the follow-ups go under a runs (or records) root."""
        return Path(runs_dir) / self.scale.name / f"followup-{self.design.name}"

    @property
    def branch_iterations(self) -> int:
        return max(1, round(self.design.iterations * BRANCH_FRACTION))


def zero_shot_specs(scale: recipes.Scale) -> list[str]:
    """The environments a learned policy is played in unchanged: alone in 3-goal Goal Cycle, beside the
    default experts in 4-goal Goal Cycle, Four Rooms and Maze (Goal Cycle with the scale's grid)."""
    names = ("goalcycle3-solo", "goalcycle4", "fourrooms", "maze")
    return [str(recipes.goalcycle_spec(name, scale)) for name in names]


def branch_specs(scale: recipes.Scale) -> list[str]:
    """The environments a branch is evaluated in at its end (the paper's Fig. 6)."""
    return zero_shot_specs(scale)[:2]


def arm_config(plan: Plan, source: Source, arm: str, runs_dir: str) -> TrainConfig:
    """The training config of one branch: the source's condition, beside the experts (`BRANCH_ENV`) with the
    arm's share of solo episodes, from the source's final checkpoint, evaluated at its end."""
    scale, iterations = plan.scale, plan.branch_iterations
    cfg = recipes.condition_config(scale, source.condition, source.seed, 1, runs_dir)
    return dataclasses.replace(
        cfg,
        env=BRANCH_ENV,
        env_args=recipes.with_env_args(cfg.env_args, (("solo_prob", ARMS[arm]),)),
        iterations=iterations,
        init_from=CheckpointRef(source.seed_dir),
        eval_envs=tuple(EnvSpec.parse(spec) for spec in branch_specs(scale)),
        eval_every=iterations,
        eval_episodes=plan.episodes,
        run_name=str(branch_dir(plan, source, arm, "")),
    )


def branch_dir(plan: Plan, source: Source, arm: str, runs_dir: str | Path) -> Path:
    """The run directory of one branch of a learned seed."""
    return plan.root(runs_dir) / f"{source.name}-{arm}"
