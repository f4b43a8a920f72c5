"""jaxsocial: emergent social learning (Ndousse et al., ICML 2021) in JAX."""

from jaxsocial.env import EnvParams, EnvState, make, registered_envs, state_from_layout

__version__ = "0.1.0"
__all__ = ["EnvParams", "EnvState", "make", "registered_envs", "state_from_layout"]
