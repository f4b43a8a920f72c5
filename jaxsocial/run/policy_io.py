"""Saved policies: the learners' params a training run exports to `RUN_DIR/policy/<iteration>` with the
network they were trained with, and loading one learner's params back for a frozen slot, evaluation or
prediction pictures (`specs.PolicyRef`: `RUN_DIR` for its first learner, `RUN_DIR#k` for its k-th; each
function takes one parsed or as text).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import jax

from jaxsocial.agents import network, network_config, population
from jaxsocial.run import checkpoint, jsonio
from jaxsocial.run.rundir import POLICY_DIR
from jaxsocial.specs import PolicyRef

SPEED_FIELDS = ("conv_impl", "frame_batch", "dtype")
"""NetworkConfig fields that change how the network is computed, not what it computes (params are float32
whatever `dtype` computes them: a bfloat16 run's policy plays in a float32 run, and the other way round)."""


def json_net(net_cfg: network.NetworkConfig) -> dict:
    """The network config as plain JSON types (for checkpoint metadata)."""
    return jsonio.to_json(dataclasses.asdict(net_cfg))


def architecture(net_cfg: network.NetworkConfig) -> dict:
    """The fields that decide the params and the function (JSON types): what a loaded policy must match."""
    return {k: v for k, v in json_net(net_cfg).items() if k not in SPEED_FIELDS}


def export_policy(
    run_dir: str | Path,
    step: int,
    params: Any,
    net_cfg: network.NetworkConfig,
    *,
    slots: str = "",
    keep: int | None = None,
) -> None:
    """Write learners' params (stacked [S_l, ...]) trained with `net_cfg` to `run_dir/policy/<step>`, with the
    network and the run's `slots` as metadata, unless that step exists; keep the latest `keep` (None: all)."""
    directory = Path(run_dir) / POLICY_DIR
    if step in checkpoint.all_steps(directory):
        return
    n_learners = int(jax.tree.leaves(params)[0].shape[0])
    meta = {"net": json_net(net_cfg), "n_learners": n_learners, "slots": slots}
    checkpoint.save(directory, step, {"params": params}, metadata=meta, keep=keep)


def _policy_dir(policy: PolicyRef) -> Path:
    directory = policy.run / POLICY_DIR
    if not policy.run.is_dir():
        raise ValueError(f"{policy.run} does not exist")
    if checkpoint.latest_step(directory) is None:
        inside = sorted(d.name for d in policy.run.iterdir() if (d / POLICY_DIR).is_dir())
        more = " ..." if len(inside) > 8 else ""
        hint = (
            f": it holds the runs {', '.join(inside[:8])}{more}; give one of them"
            if inside
            else f" (is {policy.run} a training run directory?)"
        )
        raise ValueError(f"no saved policy under {directory}{hint}")
    return directory


def policy_iteration(policy: PolicyRef | str | Path) -> int:
    """The training iteration of the policy `RUN_DIR[#k]` loads (its latest export)."""
    return int(checkpoint.latest_step(_policy_dir(PolicyRef.of(policy))))


def saved_net(policy: PolicyRef | str | Path) -> network.NetworkConfig:
    """The network config a policy (`RUN_DIR[#k]`) was trained with (fields added since take defaults)."""
    return _meta_net(checkpoint.read_metadata(_policy_dir(PolicyRef.of(policy))))


def _meta_net(meta: dict[str, Any]) -> network.NetworkConfig:
    """The `NetworkConfig` of a policy's metadata (old field names read as today's:
    `network_config.modern_net_keys`)."""
    return network.NetworkConfig(**network_config.modern_net_keys(meta["net"]))


def load_policy(policy: PolicyRef | str | Path, net_cfg: network.NetworkConfig):
    """Params of one learner from a run directory's `policy/` checkpoints, for a frozen slot.

    `policy` is `RUN_DIR` (its first learner) or `RUN_DIR#k` (its k-th learner). Raises ValueError if the
    saved network's architecture differs from `net_cfg` (a checkpoint of another architecture; `SPEED_FIELDS`
    may differ) or the run has no policy.
    """
    policy = PolicyRef.of(policy)
    directory, k = _policy_dir(policy), policy.learner
    meta = checkpoint.read_metadata(directory)
    saved = architecture(_meta_net(meta))
    if saved != architecture(net_cfg):
        raise ValueError(
            f"frozen slot {policy}: the checkpoint's network {saved} differs from this run's network "
            f"{architecture(net_cfg)} (a checkpoint of another architecture)"
        )
    n_saved = int(meta["n_learners"])
    if not 0 <= k < n_saved:
        raise ValueError(f"frozen slot {policy}: learner index {k} out of range (the run had {n_saved})")
    template = jax.eval_shape(
        jax.vmap(lambda k: network.init(k, net_cfg)), jax.random.split(jax.random.key(0), n_saved)
    )
    return jax.tree.map(lambda x: x[k], load_learners(policy.run, template))


def load_learners(run_dir: str | Path, template: Any, step: int | None = None) -> Any:
    """Every learner's params (stacked [S_l, ...], like `template`: arrays or `jax.ShapeDtypeStruct`s) of
    the policy export `step` (None: the latest) in `run_dir`. ValueError if it has no policy;
    FileNotFoundError if not that step."""
    directory = _policy_dir(PolicyRef.of(run_dir))
    return checkpoint.restore(directory, {"params": template}, step)["params"]


def load_frozen(pop: population.Population, net_cfg: network.NetworkConfig) -> Any:
    """The frozen slots' params stacked [S_f, ...] in slot order, or None if `pop` has no frozen slot."""
    if not pop.frozen:
        return None
    policies = [load_policy(pop.slots[i].policy, net_cfg) for i in pop.frozen]
    return population.stack(policies)
