"""Pure-functional multi-agent gridworlds (Goal Cycle, Four Rooms, Maze) in JAX."""

from jaxsocial.lazy import exports

SOURCES = {
    "Env": "jaxsocial.env.core",
    "reset": "jaxsocial.env.core",
    "state_from_layout": "jaxsocial.env.core",
    "step": "jaxsocial.env.core",
    "step_batch": "jaxsocial.env.core",
    "step_env": "jaxsocial.env.core",
    "PRESETS": "jaxsocial.env.registry",
    "make": "jaxsocial.env.registry",
    "registered_envs": "jaxsocial.env.registry",
    "EnvParams": "jaxsocial.env.types",
    "EnvState": "jaxsocial.env.types",
}
"""Each name -> the module it comes from, imported at the name's first use (`jaxsocial.lazy`)."""
__all__ = sorted(SOURCES)
__getattr__ = exports(__name__, SOURCES)
