"""What acts in each environment slot: a learner, a frozen policy (loaded from a checkpoint) or a random
distractor. Neural slots share one architecture; their parameters are stacked on a leading slot axis and
applied with `jax.vmap`, so nothing is shared between agents but the code.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import jax
import jax.numpy as jnp

from jaxsocial import checkpoint
from jaxsocial.agents import network
from jaxsocial.env.types import NUM_ACTIONS

SLOT_KINDS = ("learner", "frozen", "random")


@dataclasses.dataclass(frozen=True)
class Slot:
    """One environment slot: `kind` in SLOT_KINDS; `path` the run directory of a frozen policy."""

    kind: str
    path: str | None = None

    @property
    def neural(self) -> bool:
        return self.kind in ("learner", "frozen")


def parse_slots(text: str, n_agents: int) -> tuple[Slot, ...]:
    """Parse 'learner,random,frozen:PATH' (one entry per agent slot). Raises ValueError on bad input."""
    entries = [e.strip() for e in text.split(",") if e.strip()]
    if len(entries) != n_agents:
        raise ValueError(
            f"--slots lists {len(entries)} slots ({text!r}) but the environment has {n_agents} agents"
        )
    slots = []
    for entry in entries:
        kind, _, path = entry.partition(":")
        if kind == "expert":
            raise ValueError(
                f"slot {entry!r}: scripted and trained experts are not available yet (use frozen:PATH)"
            )
        if kind not in SLOT_KINDS:
            raise ValueError(f"unknown slot kind {kind!r} in {entry!r}; choose from {SLOT_KINDS}")
        if (kind == "frozen") != bool(path):
            raise ValueError(f"slot {entry!r}: 'frozen:PATH' needs a checkpoint path; other kinds take none")
        slots.append(Slot(kind, path or None))
    if not any(s.kind == "learner" for s in slots):
        raise ValueError(f"--slots {text!r} has no learner: nothing would be trained")
    return tuple(slots)


@dataclasses.dataclass(frozen=True)
class Population:
    """Static slot bookkeeping: indices of learner, frozen and neural (learner then frozen) slots."""

    slots: tuple[Slot, ...]

    @property
    def learners(self) -> tuple[int, ...]:
        return tuple(i for i, s in enumerate(self.slots) if s.kind == "learner")

    @property
    def frozen(self) -> tuple[int, ...]:
        return tuple(i for i, s in enumerate(self.slots) if s.kind == "frozen")

    @property
    def neural(self) -> tuple[int, ...]:
        """Neural slots in stacking order: learners first, then frozen policies."""
        return self.learners + self.frozen


def stack(trees: list) -> object:
    """Stack a list of equally shaped pytrees on a new leading axis."""
    return jax.tree.map(lambda *xs: jnp.stack(xs), *trees)


def _step_neural(pop: Population, net: network.NetworkConfig, params, carry, obs, resets):
    """One network step of every neural slot (vmapped over slots), each on its own view of obs [E, N, ...]."""
    neural_obs = jnp.moveaxis(obs[:, jnp.asarray(pop.neural)], 1, 0)
    return jax.vmap(network.step, in_axes=(0, None, 0, 0, None))(params, net, carry, neural_obs, resets)


def act(
    key: jax.Array,
    pop: Population,
    net: network.NetworkConfig,
    params,
    carry: network.Carry,
    obs: jax.Array,
    resets: jax.Array,
) -> tuple[jax.Array, network.Carry, jax.Array, jax.Array]:
    """Every slot's action for a batch of environments.

    Args:
        params: neural-slot params stacked [S, ...] in `pop.neural` order; carry: Carry of float32[S, E, H];
        obs: uint8[E, N, 21, 21, 3]; resets: bool[E] (the step starts an episode: zero the LSTM state).
    Returns:
        actions int32[E, N], the new carry, log-probabilities and values float32[S, E] of the neural slots.
    """
    n_envs, n_agents = obs.shape[:2]
    k_neural, k_random = jax.random.split(key)
    actions = jax.random.randint(k_random, (n_envs, n_agents), 0, NUM_ACTIONS)
    neural = jnp.asarray(pop.neural)
    carry, out = _step_neural(pop, net, params, carry, obs, resets)
    chosen = jax.random.categorical(k_neural, out.logits)
    logp = jnp.take_along_axis(jax.nn.log_softmax(out.logits), chosen[..., None], -1)[..., 0]
    actions = actions.at[:, neural].set(chosen.T.astype(actions.dtype))
    return actions, carry, logp, out.value


def values(
    pop: Population, net: network.NetworkConfig, params, carry: network.Carry, obs: jax.Array
) -> jax.Array:
    """float32[S, E] neural slots' values of `obs` (uint8[E, N, ...]) continuing from `carry` (no reset)."""
    _, out = _step_neural(pop, net, params, carry, obs, jnp.zeros(obs.shape[0], bool))
    return out.value


POLICY_DIR = "policy"
"""Sub-directory of a run directory holding the learners' params (stacked [S_l, ...]) for frozen slots."""


def load_policy(path: str, net: network.NetworkConfig):
    """Params of one learner from a run directory's `policy/` checkpoints, for a frozen slot.

    `path` is `RUN_DIR` (its first learner) or `RUN_DIR@k` (its k-th learner). Raises ValueError if the
    saved network differs from `net` (a checkpoint of another architecture) or the path has no policy.
    """
    run_dir, _, index = path.partition("@")
    directory = Path(run_dir) / POLICY_DIR
    if checkpoint.latest_step(directory) is None:
        raise ValueError(f"frozen slot: no saved policy under {directory}")
    meta = checkpoint.read_metadata(directory)
    saved_net = meta.get("net")
    if saved_net != json_net(net):
        raise ValueError(
            f"frozen slot {path}: the checkpoint's network {saved_net} differs from this run's network "
            f"{json_net(net)} (a checkpoint of another architecture)"
        )
    n_saved = int(meta["n_learners"])
    k = int(index or 0)
    if not 0 <= k < n_saved:
        raise ValueError(f"frozen slot {path}: learner index {k} out of range (the run had {n_saved})")
    template = jax.eval_shape(
        jax.vmap(lambda k: network.init(k, net)), jax.random.split(jax.random.key(0), n_saved)
    )
    params = checkpoint.restore(directory, {"params": template})["params"]
    return jax.tree.map(lambda x: x[k], params)


def json_net(net: network.NetworkConfig) -> dict:
    """The network config as plain JSON types (for checkpoint metadata)."""
    return json.loads(json.dumps(dataclasses.asdict(net)))
