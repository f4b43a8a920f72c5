"""Behaviour cloning's hyperparameters (`BCConfig`), apart from the algorithm (`bc`): a run's config is read
and checked without it."""

import dataclasses


@dataclasses.dataclass(frozen=True)
class BCConfig:
    """Behaviour-cloning hyperparameters."""

    lr: float = 3e-4
    """Adam learning rate."""
    epochs: int = 4
    """Gradient steps on each iteration's demonstrations (the whole batch each time)."""
    max_grad_norm: float = 0.5
    """Global gradient-norm clip."""

    def __post_init__(self):
        if self.epochs < 1 or self.lr <= 0:
            raise ValueError(f"BCConfig: need epochs >= 1 and lr > 0, got {self.epochs} and {self.lr}")
