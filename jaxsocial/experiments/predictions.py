"""A trained learner's predicted next frames (paper Fig. 2): at a step of an episode beside the experts,
the decoder's prediction of the next observation for each movement action, beside the observed frame and
the frame that followed."""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxsocial.agents import network, policy_io, population
from jaxsocial.env import core, pictures
from jaxsocial.env.types import FORWARD, LEFT, RIGHT, EnvParams
from jaxsocial.evaluate import parse_env_spec

MOVES = {"left": LEFT, "right": RIGHT, "forward": FORWARD}
WARM_UP = 8
"""`predicted_frames` picks a step after this many by default."""


class EpisodeSetup(NamedTuple):
    """A saved learner and its companions, ready to play: `params` are the neural slots' stacked [S, ...]
    in `pop.neural` order (the run's learners, then frozen policies)."""

    net: network.NetworkConfig
    params: Any
    env_params: EnvParams
    pop: population.Population


def episode_setup(run_dir: str, env_spec: str, slots: str | None = None) -> EpisodeSetup:
    """Load the policy saved in `run_dir` (RUN_DIR or RUN_DIR@k) to play in `env_spec`
    (NAME[:field=value,...]) and validate everything: ValueError, before anything compiles, if it cannot
    act there.

    `slots`: one entry per agent as in training ('learner' slots play the run's learners in order, RUN_DIR@0,
    @1, ...); default: the learner in slot 0 beside the environment's default companions.
    """
    net = policy_io.saved_net(run_dir)
    env_params = parse_env_spec(env_spec)
    population.require_obs(net, env_params, f"env {env_spec!r} with the policy {run_dir}")
    population.require_rgb(env_params, f"env {env_spec!r}")
    if slots is None:
        pop = population.default_population(env_params)
    else:
        pop = population.Population(population.parse_slots(slots, env_params.n_agents))
        pop.validate(env_params)
    if len(pop.learners) > 1 and "@" in run_dir:
        raise ValueError(f"{run_dir} is one learner, but the slots have {len(pop.learners)}")
    learners = [run_dir] if len(pop.learners) == 1 else [f"{run_dir}@{k}" for k in range(len(pop.learners))]
    frozen = [pop.slots[i].path for i in pop.frozen]
    params = population.stack([policy_io.load_policy(path, net) for path in learners + frozen])
    return EpisodeSetup(net, params, env_params, pop)


def play_episode(setup: EpisodeSetup, steps: int = 40, seed: int = 0) -> dict[str, Any]:
    """Play one episode (no auto-reset) for at most `steps` steps; it stops early where the episode ends.

    Returns numpy arrays with a leading step axis T: 'states' (EnvState before each step), 'obs'
    uint8[T, N, 21, 21, 3] (the views the agents acted on), 'next_obs' (the views after the step), 'hidden'
    float32[T, H] the first learner's LSTM output at each step, 'actions' int32[T, N], 'rewards'
    float32[T, N], 'terminated' bool[T, N], 'truncated' bool[T]; and 'learner' (the first learner's slot),
    'net', 'params' (its params), 'env_params', 'pop'.
    """
    net, params, env_params, pop = setup
    steps = min(steps, env_params.max_steps)
    episode = jax.device_get(_play(jax.random.key(seed), pop, net, env_params, params, steps))
    ended = np.flatnonzero(episode["terminated"].all(-1) | episode["truncated"])
    end = int(ended[0]) + 1 if len(ended) else steps
    return {
        **jax.tree.map(lambda x: x[:end], episode),
        "learner": pop.learners[0],
        "net": net,
        "params": jax.tree.map(lambda x: x[0], params),
        "env_params": env_params,
        "pop": pop,
    }


@functools.partial(jax.jit, static_argnums=(1, 2, 3, 5))
def _play(key, pop, net, env_params, params, steps: int) -> dict[str, Any]:
    """The scan of `play_episode`: `steps` steps without auto-reset (static pop, net, env_params, steps)."""
    k_reset, k_run = jax.random.split(key)
    obs, state = core.reset(k_reset, env_params)
    slots = population.init_slot_state(pop, net, env_params, 1)

    def body(carry, key):
        obs, state, slots, first = carry
        batched = jax.tree.map(lambda x: x[None], state)
        actions, slots, _, _ = population.act(
            key, pop, net, env_params, params, slots, obs[None], batched, first
        )
        new_obs, new_state, reward, terminated, truncated = core.step_env(state, actions[0], env_params)
        slots = population.record_rewards(slots, reward[None])
        out = {
            "states": state,
            "obs": obs,
            "next_obs": new_obs,
            "hidden": slots.carry.h[0, 0],
            "actions": actions[0],
            "rewards": reward,
            "terminated": terminated,
            "truncated": truncated,
        }
        return (new_obs, new_state, slots, jnp.zeros(1, bool)), out

    _, out = jax.lax.scan(body, (obs, state, slots, jnp.ones(1, bool)), jax.random.split(k_run, steps))
    return out


def learner_episode(
    run_dir: str, env_spec: str, steps: int = 40, seed: int = 0, slots: str | None = None
) -> dict[str, Any]:
    """`play_episode` of `episode_setup(run_dir, env_spec, slots)`: by default the learner saved in `run_dir`
    in slot 0 of `env_spec` beside the environment's default companions."""
    return play_episode(episode_setup(run_dir, env_spec, slots), steps, seed)


def predicted_frames(episode: dict[str, Any], step: int | None = None) -> dict[str, Any]:
    """The learner's predicted next views at one step of a `learner_episode`: by default the step at which
    its view shows the most agent pixels (after `WARM_UP` steps).

    Returns {'step': t, 'observed': uint8[21, 21, 3] its view at t, 'next': its view after the step,
    'action': the action it took, 'predicted': {move: float32[21, 21, 3] in [0, 1]} the decoder's prediction
    for each movement action}. Raises ValueError if the network has no decoder (aux='none').
    """
    learner = episode["learner"]
    views = episode["obs"][:, learner]
    if step is None:  # after the LSTM has seen a few steps
        warm = min(WARM_UP, len(views) - 1)
        step = warm + int(np.argmax([_agent_pixels(v) for v in views[warm:]]))
    moves = jnp.asarray(list(MOVES.values()))
    hidden = jnp.broadcast_to(episode["hidden"][step], (len(MOVES), episode["hidden"].shape[-1]))
    frames = np.clip(np.asarray(network.decode(episode["params"], episode["net"], hidden, moves)), 0.0, 1.0)
    return {
        "step": step,
        "observed": views[step],
        "next": episode["next_obs"][step, learner],
        "action": int(episode["actions"][step, learner]),
        "predicted": dict(zip(MOVES, frames, strict=True)),
    }


def predicted_views(episode: dict[str, Any]) -> np.ndarray:
    """uint8[T, 21, 21, 3] the learner's decoder output at each step of a `learner_episode`, for the action it
    took: its prediction of its next view (aux='pred') or its reconstruction of its view (aux='rec').
    Raises ValueError if the network has no decoder (aux='none')."""
    actions = episode["actions"][:, episode["learner"]]
    frames = _decode(episode["params"], episode["net"], jnp.asarray(episode["hidden"]), jnp.asarray(actions))
    return np.round(np.clip(np.asarray(frames), 0.0, 1.0) * 255).astype(np.uint8)


_decode = jax.jit(network.decode, static_argnums=1)


def episode_video(
    episode: dict[str, Any], tile: int = 12, predicted: np.ndarray | None = None
) -> list[np.ndarray]:
    """uint8 frames of a `learner_episode`, one per step (the map and every agent's view;
    `pictures.render_frame`), with `predicted` uint8[T, 21, 21, 3] (`predicted_views`) beside the learner's
    view."""
    frames = []
    for t in range(len(episode["actions"])):
        state = jax.tree.map(lambda x, t=t: x[t], episode["states"])
        reward = episode["rewards"][t - 1] if t else None
        extra = None if predicted is None else {episode["learner"]: predicted[t]}
        frames.append(
            pictures.render_frame(state, episode["obs"][t], episode["env_params"], reward, tile, extra)
        )
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
