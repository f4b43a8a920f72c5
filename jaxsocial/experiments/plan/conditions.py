"""The training conditions the recipes compare: each one's label (for figures and summaries) and what it
changes in a scale's config (`recipes.condition_config` applies it). Plain data, so the figures and
summaries read the labels without the recipes' configs."""

from __future__ import annotations

import dataclasses

from jaxsocial.agents.expert_spec import ExpertSpec
from jaxsocial.agents.network_config import Aux
from jaxsocial.agents.population import Slot
from jaxsocial.specs import EnvArgsFlag


@dataclasses.dataclass(frozen=True)
class Condition:
    """One training condition: a label for figures and what it changes in the scale's config."""

    label: str
    aux: Aux
    """The learner's auxiliary loss (`NetworkConfig.aux`)."""
    env: str = "goalcycle3"
    algo: str = "ppo"
    n_actions: int | None = None
    """The learner's actions (None: the scale's)."""
    slots: tuple[Slot, ...] = ()
    """The agent slots (empty: the environment's default, a learner beside its experts)."""
    env_args: EnvArgsFlag = ()
    """Extra EnvParams overrides (after the scale's)."""
    eval_during_training: bool = False
    """Evaluate in solo 3-goal and in 4-goal with experts during training (the mixing figure)."""
    mixed_from: float | None = None
    """Switch to 75% solo episodes after this fraction of the iterations, every seed at once."""
    mixed_at_return: float | None = None
    """Switch to 75% solo episodes once the seed's own learner has learned: the first logged chunk whose mean
    episode return reaches this (a `return>=X` stage). A stage switches every seed of a program together, so
    such a condition trains one program per seed (`condition_programs`)."""
    penalty_curriculum: bool = False
    """The experts' penalty curriculum 0.5 -> 1.0 -> 1.5, each for a third of the iterations (iteration
    stages, so seeds can share a program; the paper switched on the return)."""

    @property
    def program_per_seed(self) -> bool:
        """Its seeds train one program each: its stage switches on each seed's own return."""
        return self.mixed_at_return is not None


MIXING_RETURN = 10.0
"""The return at which `social_pred_mixed_learned` switches to mixed episodes: far above the one-tile
plateau (about 1; `metrics.LEARNED_RETURN` is 2) and below the experts' 26-39, so the learner has learned
from them, as the paper's social agent had when it was switched (its Fig. 6)."""
IMPERFECT_EXPERT = Slot("expert", expert=ExpertSpec("explorer", epsilon=0.2, forget=0.01))
HALF_EXPERT = Slot("expert", expert=ExpertSpec("explorer", epsilon=0.4, forget=0.02))
"""`IMPERFECT_EXPERT`'s imperfection doubled: in 8x8 Goal Cycle it scores about half the near-optimal
explorer's return (`benchmarks/results/expert_returns_8x8.json`), so a learner can beat it (`imperfect8`)."""
EXPERT_DROPOUT = (("dropout_prob", 0.5), ("dropin_prob", 0.25))
"""Cultural-transmission training (not in the paper): each expert leaves half the episodes and joins a quarter
of them, at a uniform random step (`EnvParams.dropout_prob`, `dropin_prob`)."""

PENALTIES = {"nopenalty": ("no penalty", 0), "halfpenalty": ("penalty 0.5", 0.5)}
"""Exploration penalties other than the environment's 1.5: condition-name suffix -> (label, `penalty`)."""
LEARNERS = {"social": "goalcycle3", "solo": "goalcycle3-solo"}
"""Learners beside the experts and alone: condition-name prefix -> environment."""


def penalty_conditions() -> dict[str, Condition]:
    """The PPO + aux pred learner, social and solo, at each of the other `PENALTIES`:
    '<social|solo>_pred_<suffix>', e.g. 'solo_pred_halfpenalty'."""
    return {
        f"{who}_pred_{suffix}": Condition(
            f"{who} PPO + aux pred, {label}", "pred", env=env, env_args=(("penalty", value),)
        )
        for suffix, (label, value) in PENALTIES.items()
        for who, env in LEARNERS.items()
    }


PENALTY_CONDITIONS = penalty_conditions()

CONDITIONS = {
    "solo_pred": Condition("solo PPO + aux pred", "pred", env="goalcycle3-solo"),
    "social_none": Condition("social PPO (vanilla)", "none"),
    "social_rec": Condition("social PPO + aux rec", "rec"),
    "solo_rec": Condition("solo PPO + aux rec", "rec", env="goalcycle3-solo"),
    "social_pred": Condition("social PPO + aux pred", "pred", eval_during_training=True),
    "social_pred_mixed": Condition(
        "social PPO + aux pred, then 75% solo", "pred", eval_during_training=True, mixed_from=1 / 3
    ),
    "social_pred_mixed_learned": Condition(
        f"social PPO + aux pred, 75% solo once its return reaches {MIXING_RETURN:g}",
        "pred",
        eval_during_training=True,
        mixed_at_return=MIXING_RETURN,
    ),
    "social_pred_imperfect": Condition(
        "social PPO + aux pred, imperfect experts",
        "pred",
        slots=(Slot("learner"), IMPERFECT_EXPERT, IMPERFECT_EXPERT),
    ),
    "social_pred_imperfect_half": Condition(
        "social PPO + aux pred, experts at half strength",
        "pred",
        slots=(Slot("learner"), HALF_EXPERT, HALF_EXPERT),
    ),
    "bc": Condition("behaviour cloning", "none", algo="bc", n_actions=7),  # the experts' 7 (they idle)
    **PENALTY_CONDITIONS,
    "expert_curriculum": Condition(
        "solo PPO + aux pred, penalty curriculum", "pred", env="goalcycle3-solo", penalty_curriculum=True
    ),
    "social_pred_dropout": Condition(
        "social PPO + aux pred, expert dropout", "pred", env_args=EXPERT_DROPOUT
    ),
    "social_pred_attention": Condition("social PPO + aux pred + attention", "pred+attention"),
    "social_medal": Condition(
        "social PPO + aux pred + attention, expert dropout (MEDAL without ADR)",
        "pred+attention",
        env_args=EXPERT_DROPOUT,
    ),
    "social_pred_distractors": Condition(
        "social PPO + aux pred, 2 random distractors", "pred", env="goalcycle3-distractors"
    ),
}
