"""A trained learner's predicted next frames (paper Fig. 2): at a step of an episode beside the experts,
the decoder's prediction of the next observation for each movement action, beside the observed frame and
the frame that followed."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxsocial.agents import network, population
from jaxsocial.env import core, render
from jaxsocial.env.types import FORWARD, LEFT, RIGHT
from jaxsocial.evaluate import parse_env_spec

MOVES = {"left": LEFT, "right": RIGHT, "forward": FORWARD}
WARM_UP = 8
"""`predicted_frames` picks a step after this many by default."""


def learner_episode(run_dir: str, env_spec: str, steps: int = 40, seed: int = 0) -> dict[str, Any]:
    """Play `steps` steps of one episode (no auto-reset) with the learner saved in `run_dir` in slot 0 of
    `env_spec` (NAME[:field=value,...]) beside the environment's default companions.

    Returns numpy arrays with a leading step axis T: 'states' (EnvState before each step), 'obs'
    uint8[T, N, 21, 21, 3] (the views the agents acted on), 'next_obs' (the views after the step), 'hidden'
    float32[T, H] the learner's LSTM output at each step, 'actions' int32[T, N], 'rewards' float32[T, N]; and
    'net', 'params', 'env_params'.
    """
    net = population.saved_net(run_dir)
    params = population.load_policy(run_dir, net)
    env_params = parse_env_spec(env_spec)
    pop = population.default_population(env_params)
    stacked = jax.tree.map(lambda x: x[None], params)

    @jax.jit
    def play(key):
        k_reset, k_run = jax.random.split(key)
        obs, state = core.reset(k_reset, env_params)
        slots = population.init_slot_state(pop, net, env_params, 1)

        def body(carry, key):
            obs, state, slots, first = carry
            batched = jax.tree.map(lambda x: x[None], state)
            actions, slots, _, _ = population.act(
                key, pop, net, env_params, stacked, slots, obs[None], batched, first
            )
            new_obs, new_state, reward, _, _ = core.step_env(state, actions[0], env_params)
            slots = population.record_rewards(slots, reward[None])
            out = {"states": state, "obs": obs, "next_obs": new_obs, "hidden": slots.carry.h[0, 0],
                   "actions": actions[0], "rewards": reward}  # fmt: skip
            return (new_obs, new_state, slots, jnp.zeros(1, bool)), out

        _, out = jax.lax.scan(body, (obs, state, slots, jnp.ones(1, bool)), jax.random.split(k_run, steps))
        return out

    episode = jax.device_get(play(jax.random.key(seed)))
    return {**episode, "net": net, "params": params, "env_params": env_params}


def predicted_frames(episode: dict[str, Any], step: int | None = None) -> dict[str, Any]:
    """The learner's predicted next views at one step of a `learner_episode`: by default the step at which
    its view shows the most agent pixels (after `WARM_UP` steps).

    Returns {'step': t, 'observed': uint8[21, 21, 3] its view at t, 'next': its view after the step,
    'action': the action it took, 'predicted': {move: float32[21, 21, 3] in [0, 1]} the decoder's prediction
    for each movement action}. Raises ValueError if the network has no decoder (aux='none').
    """
    views = episode["obs"][:, 0]
    if step is None:  # after the LSTM has seen a few steps
        warm = min(WARM_UP, len(views) - 1)
        step = warm + int(np.argmax([_agent_pixels(v) for v in views[warm:]]))
    moves = jnp.asarray(list(MOVES.values()))
    hidden = jnp.broadcast_to(episode["hidden"][step], (len(MOVES), episode["hidden"].shape[-1]))
    frames = np.clip(np.asarray(network.decode(episode["params"], episode["net"], hidden, moves)), 0.0, 1.0)
    return {
        "step": step,
        "observed": views[step],
        "next": episode["next_obs"][step, 0],
        "action": int(episode["actions"][step, 0]),
        "predicted": dict(zip(MOVES, frames, strict=True)),
    }


def episode_video(episode: dict[str, Any], tile: int = 12) -> list[np.ndarray]:
    """uint8 frames of a `learner_episode` (the map and every agent's view; `env.render.render_frame`)."""
    frames = []
    for t in range(len(episode["actions"])):
        state = jax.tree.map(lambda x, t=t: x[t], episode["states"])
        reward = episode["rewards"][t - 1] if t else None
        frames.append(render.render_frame(state, episode["obs"][t], episode["env_params"], reward, tile))
    return frames


def _agent_pixels(frame: np.ndarray) -> int:
    """Pixels that are saturated in red or blue and not yellow (agents are drawn red to blue)."""
    r, g, b = (frame[..., i].astype(int) for i in range(3))
    return int(np.sum((np.maximum(r, b) > 150) & (g < 100)))


def draw(runs, path: Path) -> None:
    """The figure for the `predictions` recipe: the first seed of its first condition."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxsocial.experiments.recipes import goalcycle_spec

    condition = runs.recipe.conditions[0]
    run_dir = runs.seed_dirs[condition][0]
    out = predicted_frames(learner_episode(str(run_dir), goalcycle_spec("goalcycle3", runs.scale)))
    names = {v: k for k, v in MOVES.items()}
    panels = [("observed (t)", out["observed"])]
    panels += [(f"predicted: {m}", f) for m, f in out["predicted"].items()]
    panels += [(f"observed (t+1), took {names.get(out['action'], out['action'])}", out["next"])]
    fig, axes = plt.subplots(1, len(panels), figsize=(2.4 * len(panels), 2.8))
    for ax, (title, frame) in zip(axes, panels, strict=True):
        ax.imshow(frame, interpolation="nearest")
        ax.set_title(title, fontsize=8)
        ax.axis("off")
    fig.suptitle(f"{run_dir}, step {out['step']}", fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
