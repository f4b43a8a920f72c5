"""PPO's hyperparameters (`PPOConfig`, the paper's appendix by default) and the check that they fit a
rollout (`validate`), apart from the algorithm (`ppo`): a run's config is read and checked without it."""

import dataclasses


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """PPO hyperparameters (defaults: the paper's appendix)."""

    gamma: float = 0.993
    """Discount."""
    gae_lambda: float = 0.97
    """GAE lambda."""
    clip: float = 0.2
    """PPO clip ratio."""
    value_coef: float = 0.1
    """Weight of the value loss (the paper's c_V)."""
    entropy_coef: float = 1e-5
    """Weight of the entropy bonus (the paper's c_ent)."""
    aux_coef: float = 3.0
    """Weight of the auxiliary frame loss, with --net.aux rec or pred (the paper's c_aux)."""
    attention_coef: float = 1.0
    """Weight of the attention loss, with an --net.aux that includes attention (not in the paper)."""
    lr: float = 1e-4
    """Adam learning rate (the paper's experts used 1e-5)."""
    max_grad_norm: float = 0.5
    """Global gradient-norm clip."""
    num_minibatches: int = 20
    """Sequential minibatch updates per rollout batch."""
    minibatch_segments: int = 512
    """Trajectory segments per minibatch, sampled uniformly without replacement."""
    segment_length: int = 16
    """Steps per trajectory segment."""
    recompute_every: int = 2
    """Recompute hidden states and advantages every this many minibatches."""
    kl_target: float = 0.01
    """Skip the iteration's remaining minibatches once the KL to the rollout policy exceeds this."""
    kl_hard_limit: float = 0.03
    """Undo the iteration's whole update (params and optimiser state) when the KL exceeds this."""
    normalize_advantages: bool = True
    """Normalise advantages per minibatch (zero mean, unit variance over valid steps)."""


def validate(ppo_cfg: PPOConfig, rollout_steps: int, num_envs: int) -> None:
    """Raise ValueError for an impossible configuration (before anything compiles)."""
    if rollout_steps % ppo_cfg.segment_length:
        raise ValueError(
            f"segment_length={ppo_cfg.segment_length} must divide rollout_steps={rollout_steps} "
            "(trajectories are cut into whole segments)"
        )
    n_segments = rollout_steps // ppo_cfg.segment_length * num_envs
    if ppo_cfg.minibatch_segments > n_segments:
        raise ValueError(
            f"minibatch_segments={ppo_cfg.minibatch_segments} is larger than the batch: {num_envs} envs x "
            f"{rollout_steps // ppo_cfg.segment_length} segments = {n_segments} segments"
        )
    if ppo_cfg.num_minibatches < 1 or ppo_cfg.recompute_every < 1:
        raise ValueError("num_minibatches and recompute_every must be >= 1")
    if not 0 < ppo_cfg.kl_target <= ppo_cfg.kl_hard_limit:
        raise ValueError(
            f"need 0 < kl_target ({ppo_cfg.kl_target}) <= kl_hard_limit ({ppo_cfg.kl_hard_limit})"
        )
