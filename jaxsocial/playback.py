"""A saved learner's episode beside its companions, frame by frame: the set-up (`episode_setup`), the episode
(`play_episode`), its decoder's output at each step (`predicted_views`) and the video frames
(`episode_video`). Used by `jaxsocial.render --ckpt` and the experiments' predictions figure
(`jaxsocial.experiments.analyse.predictions`)."""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxsocial.agents import acting, network, population
from jaxsocial.env import core, pictures, registry
from jaxsocial.env.types import EnvParams
from jaxsocial.run import policy_io
from jaxsocial.specs import EnvSpec, PolicyRef


class EpisodeSetup(NamedTuple):
    """A saved learner and its companions, ready to play: `params` are the neural slots' stacked [S, ...]
    in `pop.neural` order (the run's learners, then frozen policies)."""

    net_cfg: network.NetworkConfig
    params: Any
    env_params: EnvParams
    pop: population.Population


def episode_setup(run_dir: str, env_spec: str, slots: str | None = None) -> EpisodeSetup:
    """Load the policy saved in `run_dir` (RUN_DIR or RUN_DIR#k, `specs.PolicyRef`) to play in `env_spec`
    (NAME[:field=value,...]) and validate everything: ValueError, before anything compiles, if it cannot
    act there.

    `slots`: one entry per agent as in training ('learner' slots play the run's learners in order, RUN_DIR#0,
    #1, ...); default: the learner in slot 0 beside the environment's default companions.
    """
    policy = PolicyRef.parse(run_dir)
    net_cfg = policy_io.saved_net(policy)
    spec = EnvSpec.parse(env_spec)
    env_params = registry.env_params(spec.name, spec.args)
    net_cfg.check_env(env_params, f"env {env_spec!r} with the policy {run_dir}")
    population.require_rgb(env_params, f"env {env_spec!r}")
    if slots is None:
        pop = population.default_population(env_params)
    else:
        pop = population.Population(population.parse_slots(slots, env_params.n_agents))
        pop.validate(env_params)
    if len(pop.learners) > 1 and policy.learner:
        raise ValueError(f"{run_dir} is one learner, but the slots have {len(pop.learners)}")
    learners = (
        [PolicyRef(policy.run, k) for k in range(len(pop.learners))] if len(pop.learners) > 1 else [policy]
    )
    frozen = [pop.slots[i].policy for i in pop.frozen]
    params = population.stack([policy_io.load_policy(p, net_cfg) for p in learners + frozen])
    return EpisodeSetup(net_cfg, params, env_params, pop)


def play_episode(setup: EpisodeSetup, steps: int = 40, seed: int = 0) -> dict[str, Any]:
    """Play one episode (no auto-reset) for at most `steps` steps; it stops early where the episode ends.

    Returns numpy arrays with a leading step axis T: 'states' (EnvState before each step), 'obs'
    uint8[T, N, 21, 21, 3] (the views the agents acted on), 'next_obs' (the views after the step), 'hidden'
    float32[T, H] the first learner's LSTM output at each step, 'actions' int32[T, N], 'rewards'
    float32[T, N], 'terminated' bool[T, N], 'truncated' bool[T]; and 'learner' (the first learner's slot),
    'net', 'params' (its params), 'env_params', 'pop'.
    """
    net_cfg, params, env_params, pop = setup
    steps = min(steps, env_params.max_steps)
    episode = jax.device_get(_play(jax.random.key(seed), pop, net_cfg, env_params, params, steps))
    ended = np.flatnonzero(episode["terminated"].all(-1) | episode["truncated"])
    end = int(ended[0]) + 1 if len(ended) else steps
    return {
        **jax.tree.map(lambda x: x[:end], episode),
        "learner": pop.learners[0],
        "net": net_cfg,
        "params": jax.tree.map(lambda x: x[0], params),
        "env_params": env_params,
        "pop": pop,
    }


@functools.partial(jax.jit, static_argnums=(1, 2, 3, 5))
def _play(key, pop, net_cfg, env_params, params, steps: int) -> dict[str, Any]:
    """The scan of `play_episode`: `steps` steps without auto-reset (static: pop, net_cfg, env_params,
    steps)."""
    k_reset, k_run = jax.random.split(key)
    obs, state = core.reset(k_reset, env_params)
    slots = acting.init_slot_state(pop, net_cfg, env_params, 1)

    def body(carry, key):
        obs, state, slots, first = carry
        batched = jax.tree.map(lambda x: x[None], state)
        actions, slots, _, _ = acting.act(
            key, pop, net_cfg, env_params, params, slots, obs[None], batched, first
        )
        new_obs, new_state, reward, terminated, truncated = core.step_env(state, actions[0], env_params)
        slots = acting.with_rewards(slots, reward[None])
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


def predicted_views(episode: dict[str, Any]) -> np.ndarray:
    """uint8[T, 21, 21, 3] the learner's decoder output at each step of a `learner_episode`, for the action it
    took: its prediction of its next view (aux='pred') or its reconstruction of its view (aux='rec').
    Raises ValueError if the network has no decoder (aux='none')."""
    actions = episode["actions"][:, episode["learner"]]
    frames = _decode(episode["params"], episode["net"], jnp.asarray(episode["hidden"]), jnp.asarray(actions))
    return np.round(np.clip(np.asarray(frames), 0.0, 1.0) * 255).astype(np.uint8)


_decode = jax.jit(network.decode, static_argnums=1)


def episode_video(
    episode: dict[str, Any],
    tile: int = 12,
    predicted: np.ndarray | None = None,
    title: str = pictures.PREDICTED_TITLE,
) -> list[np.ndarray]:
    """uint8 frames of a `learner_episode`, one per step (the map and every agent's view;
    `pictures.render_frame`), each view titled with its slot's kind ('learner 0', 'expert 1', ...) and return
    so far, with `predicted` uint8[T, 21, 21, 3] (`predicted_views`) beside the learner's view under `title`
    (`pictures.DECODER_TITLES` by the network's frame loss); the learner is framed in white on the map."""
    names = [f"{slot.kind} {i}" for i, slot in enumerate(episode["pop"].slots)]
    frames = []
    for t in range(len(episode["actions"])):
        state = jax.tree.map(lambda x, t=t: x[t], episode["states"])
        reward = episode["rewards"][t - 1] if t else None
        extra = None if predicted is None else {episode["learner"]: predicted[t]}
        titles = pictures.agent_titles(names, episode["rewards"][:t])
        frames.append(
            pictures.render_frame(
                state,
                episode["obs"][t],
                episode["env_params"],
                reward,
                tile,
                extra,
                titles,
                title,
                marked=(episode["learner"],),
            )
        )
    return frames
