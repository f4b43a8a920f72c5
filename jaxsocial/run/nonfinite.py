"""Non-finite detection: the check inside the compiled iteration (`check`) and what the driver reads from it
(`failures`, `first_failure`, `NonFiniteError`).

Every iteration, for every learner, each loss metric of its update, its parameters and its optimiser state
are checked with one `isfinite` reduction each. The optimiser state stands for the gradient: Adam's moments
take in every applied gradient (after clipping), so a non-finite gradient norm makes them non-finite. The
result travels with the metrics as `metrics[KEY]`, {quantity: bool[S_l]} per iteration. Only `check` imports
JAX, inside the program: the training command names `NonFiniteError` before JAX is imported.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

if TYPE_CHECKING:
    import jax

KEY = "finite"
"""The metrics entry holding the checks (the driver takes it out before writing rows)."""
ROW_KEY = "nonfinite"
"""The metrics row entry listing a non-finite iteration's quantities ('<quantity>/<slot>')."""
PARAMS = "params"
OPTIMIZER = "optimizer_state"


class NonFiniteError(RuntimeError):
    """A learner's losses, gradient or parameters became non-finite (the run stopped; see `describe`)."""


def _all_finite(tree: Any, n_learners: int) -> jax.Array:
    """bool[S_l]: whether every floating-point value of learner l's part of `tree` (leaves [S_l, ...])."""
    import jax
    import jax.numpy as jnp

    leaves = [x for x in jax.tree.leaves(tree) if jnp.issubdtype(x.dtype, jnp.inexact)]
    flags = [jnp.all(jnp.isfinite(x.reshape(n_learners, -1)), axis=1) for x in leaves]
    return jnp.all(jnp.stack(flags), axis=0) if flags else jnp.ones(n_learners, bool)


def check(losses: dict[str, jax.Array], params: Any, opt_state: Any) -> dict[str, jax.Array]:
    """Inside the program: {loss name: bool[S_l], PARAMS: bool[S_l], OPTIMIZER: bool[S_l]}, whether each
    learner's quantity is finite. losses: float32[S_l] each; params, opt_state: pytrees of [S_l, ...]."""
    import jax
    import jax.numpy as jnp

    n_learners = jax.tree.leaves(params)[0].shape[0]
    flags = {name: jnp.isfinite(value) for name, value in losses.items()}
    return {**flags, PARAMS: _all_finite(params, n_learners), OPTIMIZER: _all_finite(opt_state, n_learners)}


def failures(finite: dict[str, np.ndarray]) -> np.ndarray:
    """bool[..., n]: iterations (leading axes: seeds) in which some learner's quantity was non-finite, from
    a chunk's checks {quantity: bool[..., n, S_l]}."""
    return ~np.all(np.stack([np.all(flags, axis=-1) for flags in finite.values()]), axis=0)


def names(finite: dict[str, np.ndarray], index: int, learners: tuple[int, ...]) -> list[str]:
    """The non-finite quantities of iteration `index` of one seed's checks {quantity: bool[n, S_l]}, named
    as in the metrics rows ('<quantity>/<slot>', e.g. ['policy_loss/0', 'params/0'])."""
    return [
        f"{quantity}/{slot}"
        for quantity, flags in finite.items()
        for slot, ok in zip(learners, flags[index], strict=True)
        if not ok
    ]


class Failure(NamedTuple):
    """The first non-finite iteration of a chunk: its offset in the chunk, the seed's index in the program,
    and the non-finite quantities of each learner slot that has some."""

    offset: int
    seed: int
    by_slot: dict[int, list[str]]

    def describe(self, first_iteration: int, seed: int | None = None) -> str:
        """'non-finite values at iteration 7 in slot 0: policy_loss, params' (`first_iteration`: the
        chunk's first; `seed`: the seed's number, named when the program trains several)."""
        where = f" (seed {seed})" if seed is not None else ""
        slots = "; ".join(f"slot {slot}: {', '.join(q)}" for slot, q in self.by_slot.items())
        return f"non-finite values at iteration {first_iteration + self.offset}{where} in {slots}"


def first_failure(finite: dict[str, np.ndarray], learners: tuple[int, ...], seeds: int) -> Failure | None:
    """The chunk's earliest non-finite iteration (the lowest seed index among seeds failing there), or None.
    finite: {quantity: bool[n, S_l]}, or bool[K, n, S_l] for `seeds` K > 1."""
    failed = failures(finite).reshape(seeds, -1)  # [K, n]
    if not failed.any():
        return None
    offset = int(np.flatnonzero(failed.any(axis=0))[0])
    seed = int(np.flatnonzero(failed[:, offset])[0])
    by_slot: dict[int, list[str]] = {}
    for quantity, flags in finite.items():
        at = flags[seed, offset] if seeds > 1 else flags[offset]
        for slot, ok in zip(learners, at, strict=True):
            if not ok:
                by_slot.setdefault(slot, []).append(quantity)
    return Failure(offset, seed, dict(sorted(by_slot.items())))
