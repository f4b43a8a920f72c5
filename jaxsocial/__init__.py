"""jaxsocial: emergent social learning (Ndousse et al., ICML 2021) in JAX."""

from jaxsocial.lazy import exports

__version__ = "0.1.0"
__all__ = ["EnvParams", "EnvState", "make", "registered_envs", "state_from_layout"]
__getattr__ = exports(__name__, dict.fromkeys(__all__, "jaxsocial.env"))
