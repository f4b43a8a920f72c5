"""Which operations give different bits on two CPU models? (issue 50, item 2)

`reproducibility.py` shows that CPU models disagree from the first iteration of the laptop recipe; this says
where. Fixed inputs (integers from a seeded PCG64 scaled by a power of two, so every CPU builds the same
float32 bits) go through the operations the recipe compiles to, and the first iteration of the recipe
itself runs from a fixed key; each output's SHA-256 (16 hex digits) is recorded:

- `dot_k<K>`: [64, K] @ [K, 64], in YNNPACK by default (which sums K in blocks of 512 here: `dot_blocks`)
  and in Eigen under `no_ynn`, whose heuristic sizes its blocks of K from the caches it reads at run time;
  `dot_t_k<K>`, shaped as the first conv layer's weight gradient (contracting the leading axis, a layout XLA
  leaves to Eigen even by default), with that gradient's K of 25,088 and two shorter ones: a dependence on
  the cache shows as a K that agrees across kinds below the smaller kind's block and differs above it;
- matrix-vector products, which XLA emits itself (`gemv_k<K>`, `vecmat_k1024`, `dot_n1_k64` as in the value
  head), and the orthogonal initialiser built on them (`gram_schmidt_<shape>`: the first fully connected
  layer's shape, a square one, three square ones batched as the LSTM's blocks are);
- reductions, in YNNPACK by default: a long sum (`sum_1m`), `norm`, `log_softmax` (3 actions);
- elementwise functions on a grid: `sqrt`, `rsqrt`, `divide`, `exp`, `log`, `tanh`, `logistic`, `erf_inv`;
  `normal` (`jax.random.normal`, threefry bits through erf_inv);
- `init/<leaf>` and `iteration1/<leaf>`: every leaf of the recipe's training state (params, optimiser and
  environment state, recurrent carries) after `init` and after one iteration, and
  `iteration1/metrics/<field>`; `fixed_iteration1/...`: the same iteration from the same state with params
  built from exact inputs, so that the update's own sensitivity shows apart from the initialiser's.
  Environment leaves agreeing after iteration 1 mean the rollouts sampled the same actions.

Each XLA setting of `reproducibility.SETTINGS` runs in a process of its own with the single-core flags then
its own, pinned to one core as the records trained (`reproducibility.ONE_CORE`). `--all-cores` also runs
the default setting in a process that sees every core of the machine (`all_cores`: what differs from the
pinned default, which is why a record re-trains bit for bit only where the process sees as many cores).
One JSON per machine kind (`benchmarks/results/op_fingerprints/<cpu>.json`, with the CPU's cache sizes): per
setting the hashes, how many operations of one iteration XLA handed to YNNPACK (`ynn_fusions`),
how the `dot_k<K>` products sum (`dot_blocks`: the blocks of K whose emulated FMA chains, added in order,
equal the product bit for bit), the operations that differ from this kind's default, and, against every other
kind's committed file, the operations that differ there. A run on a second kind thus names what disagrees.

`--compare` measures nothing: it reads the committed kinds' files and prints the tables
docs/reproducibility.md quotes ("Does the training re-run?"; `experiments.analyse.cpu_kinds.markdown`): each
kind's instruction sets, caches and settings; per pair of kinds, whether they agree under the designs'
cross-CPU flags (`pinned.CROSS_CPU_XLA_FLAGS` after the single-core ones) and the first operation that
differs; and per pair and setting both measured, how many operations and fingerprints differ. A test checks
the docs against it.

    python benchmarks/op_fingerprints.py                      # every setting
    python benchmarks/op_fingerprints.py --settings default portable
    python benchmarks/op_fingerprints.py --settings default --all-cores
    python benchmarks/op_fingerprints.py --compare            # the committed kinds' tables, nothing measured
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import os
import subprocess
import sys

import numpy as np
from reproducibility import (
    ONE_CORE,
    REFERENCE,
    describe_kind,
    kind_arguments,
    other_kinds,
    seen_one_core,
    setting_flags,
    this_kind,
)
from run_info import REPO, portable, write_json

from jaxsocial.experiments.analyse import cpu_kinds
from jaxsocial.experiments.launch import pinned
from jaxsocial.run import cpuinfo, rundir, startup

OUT_DIR = REPO / "benchmarks/results/op_fingerprints"
DOT_KS = (27, 256, 288, 432, 1024, 8192)
"""Contraction lengths of the synthetic dots: the first conv layer's 27, then lengths that Eigen's and
YNNPACK's blocks of K split differently."""
BLOCKS = (None, 128, 256, 512, 1024)
"""Contraction block sizes `dot_blocks` tries."""


def exact_inputs(shape: tuple[int, ...], seed: int) -> np.ndarray:
    """float32 [shape]: integers in [-4096, 4096] from PCG64(seed) divided by 1024, exact on every CPU."""
    ints = np.random.Generator(np.random.PCG64(seed)).integers(-4096, 4097, size=shape)
    return ints.astype(np.float32) / np.float32(1024)


def digest(array) -> str:
    """16 hex digits of the SHA-256 of an array's bytes (a PRNG key array by its key data)."""
    import jax

    if jax.dtypes.issubdtype(array.dtype, jax.dtypes.prng_key):
        array = jax.random.key_data(array)
    return hashlib.sha256(np.ascontiguousarray(np.asarray(array)).tobytes()).hexdigest()[:16]


def dot_inputs(k: int) -> tuple[np.ndarray, np.ndarray]:
    """The operands of `dot_k<k>`: [64, k] and [k, 64]."""
    return exact_inputs((64, k), k), exact_inputs((k, 64), k + 1)


def fma_chain(a: np.ndarray, b: np.ndarray, block: int | None) -> np.ndarray:
    """float32 a [M, K] @ b [K, N] as FMA chains over K in blocks of `block` (None: one block), the blocks'
    sums added in order; emulated in float64, where these inputs' products are exact."""
    a64, b64 = a.astype(np.float64), b.astype(np.float64)
    k = a.shape[1]
    total = np.zeros((a.shape[0], b.shape[1]), np.float32)
    for start in range(0, k, block or k):
        part = np.zeros_like(total)
        for j in range(start, min(k, start + (block or k))):
            part = (part + np.outer(a64[:, j], b64[j])).astype(np.float32)
        total = (total + part).astype(np.float32)
    return total


def dot_blocks() -> dict[str, list[int | None]]:
    """`dot_k<K>` -> the contraction blocks of `BLOCKS` whose `fma_chain` equals the product this process
    computes, bit for bit (None: one chain over all of K; empty: none does)."""
    import jax

    out = {}
    for k in DOT_KS:
        a, b = dot_inputs(k)
        product = np.asarray(jax.jit(lambda a, b: a @ b)(a, b))
        out[f"dot_k{k}"] = [block for block in BLOCKS if np.array_equal(fma_chain(a, b, block), product)]
    return out


def operation_hashes() -> dict[str, str]:
    """Name -> digest of each synthetic operation's output on its fixed inputs."""
    import jax
    import jax.numpy as jnp
    from jax import lax

    from jaxsocial.agents import initialisers

    grid = exact_inputs((1 << 16,), 1)
    ops = {f"dot_k{k}": (lambda a, b: a @ b, *dot_inputs(k)) for k in DOT_KS}
    ops |= {
        f"dot_t_k{k}": (lambda a, b: a.T @ b, exact_inputs((k, 27), k + 2), exact_inputs((k, 16), k + 3))
        for k in (256, 384, 25088)
    }
    ops |= {
        f"gemv_k{k}": (lambda a, b: a @ b, exact_inputs((256, k), k), exact_inputs((k,), k + 1))
        for k in (64, 1024)
    }
    ops |= {
        "vecmat_k1024": (lambda a, b: a @ b, exact_inputs((1024,), 5), exact_inputs((1024, 64), 6)),
        "dot_n1_k64": (lambda a, b: a @ b, exact_inputs((1024, 64), 7), exact_inputs((64, 1), 8)),
        "sqrt": (lambda x: jnp.sqrt(jnp.abs(x)), grid),
        "rsqrt": (lambda x: lax.rsqrt(jnp.abs(x) + 1 / 1024), grid),
        "divide": (lambda x, y: x / (jnp.abs(y) + 1 / 1024), grid, grid[::-1]),
        "norm": (lambda x: jnp.linalg.norm(x, axis=0), exact_inputs((64, 256), 9)),
        "gram_schmidt_288x64": (lambda z: initialisers._orthogonal(z, 1.0), exact_inputs((288, 64), 10)),
        "gram_schmidt_64x64": (lambda z: initialisers._orthogonal(z, 1.0), exact_inputs((64, 64), 11)),
        "gram_schmidt_3x64x64": (lambda z: initialisers._orthogonal(z, 1.0), exact_inputs((3, 64, 64), 12)),
        "exp": (jnp.exp, grid),
        "log": (lambda x: jnp.log(jnp.abs(x) + 1 / 1024), grid),
        "tanh": (jnp.tanh, grid),
        "logistic": (jax.nn.sigmoid, grid),
        "log_softmax": (lambda x: jax.nn.log_softmax(x.reshape(-1, 2, 3), axis=-1), grid[: 6 << 12]),
        "erf_inv": (lambda x: jax.scipy.special.erfinv(x / 4.5), grid),
        "sum_1m": (jnp.sum, exact_inputs((1 << 20,), 4)),
        "normal": (lambda: jax.random.normal(jax.random.key(0), (1 << 16,)),),
    }
    return {name: digest(jax.jit(fn)(*args)) for name, (fn, *args) in ops.items()}


def state_hashes(prefix: str, tree) -> dict[str, str]:
    """`prefix/<leaf path>` -> digest, for every leaf of a pytree."""
    import jax

    leaves = jax.tree_util.tree_flatten_with_path(tree)[0]
    return {
        f"{prefix}/{jax.tree_util.keystr(path, simple=True, separator='/')}": digest(x) for path, x in leaves
    }


def fixed_like(tree, seed: int):
    """A pytree shaped as `tree` whose float32 leaves are `exact_inputs` / 16 (values in [-0.25, 0.25])."""
    import jax

    leaves, treedef = jax.tree_util.tree_flatten(tree)
    return treedef.unflatten([exact_inputs(x.shape, seed + i) / np.float32(16) for i, x in enumerate(leaves)])


def recipe_hashes() -> tuple[dict[str, str], int]:
    """Digests of the reference record's training state after `init` and after one iteration from it, and of
    one iteration from the same state with params that every CPU builds alike (`fixed_like`), so that the
    update's own sensitivity shows apart from the initialiser's; and how many of the iteration's operations
    XLA handed to YNNPACK (its fusions in the compiled program)."""
    import jax

    from jaxsocial import train
    from jaxsocial.run import config, policy_io

    cfg = config.config_from_dict(rundir.read_config(REFERENCE))
    cfg = dataclasses.replace(cfg, iterations=1, chunk_iterations=1, compile_cache=None)
    init, run_chunk, _ = train.make_train(cfg)
    frozen = policy_io.load_frozen(startup.setup(cfg, load_frozen=False).pop, cfg.net)
    state = jax.jit(init)(jax.random.key(cfg.seed))
    one_iteration = jax.jit(lambda state: run_chunk(state, frozen, 1)).lower(state).compile()
    hashes = state_hashes("init", state)
    for name, start in (
        ("iteration1", state),
        ("fixed_iteration1", state._replace(params=fixed_like(state.params, 100))),
    ):
        after, metrics = one_iteration(start)
        hashes |= state_hashes(name, after) | state_hashes(f"{name}/metrics", metrics)
    return hashes, one_iteration.as_text().count('"kind":"__ynn_fusion"')


def child() -> None:
    """Print this process's digests (operations, then the recipe), YNNPACK fusions and `dot_blocks` as one
    JSON line."""
    hashes, ynn_fusions = recipe_hashes()
    print(
        json.dumps(
            {"hashes": operation_hashes() | hashes, "ynn_fusions": ynn_fusions, "dot_blocks": dot_blocks()}
        )
    )


def measured_under(setting: str, cores: list[int] | None = ONE_CORE) -> dict:
    """{"visible_cores", "hashes", "ynn_fusions", "dot_blocks"} (`child`) computed in a process of their own
    under `setting`'s XLA flags, pinned to `cores` (None: seeing every core of this process)."""
    env = os.environ | {"XLA_FLAGS": setting_flags(setting), "JAX_PLATFORMS": "cpu"}
    done = subprocess.run(
        [*pinned.pin(cores), sys.executable, __file__, "--child"],
        env=env,
        capture_output=True,
        text=True,
        check=False,
        cwd=REPO,
    )
    if done.returncode != 0:
        raise RuntimeError(f"{setting}: the fingerprint process failed:\n{done.stderr[-3000:]}")
    return {"visible_cores": pinned.cores_seen(cores), **json.loads(done.stdout.strip().splitlines()[-1])}


def differing(mine: dict[str, str], theirs: dict[str, str]) -> list[str]:
    """The operations both computed whose digests differ, in `mine`'s order."""
    return [name for name, h in mine.items() if name in theirs and theirs[name] != h]


def summary(names: list[str]) -> str:
    return "exact" if not names else f"{len(names)} differ, first {', '.join(names[:4])}"


CROSS_CPU = f"{pinned.SINGLE_CORE_XLA_FLAGS} {pinned.CROSS_CPU_XLA_FLAGS}"
"""The $XLA_FLAGS the designs' seeds train with since 2026-11-28 (the `no_platform_math` setting)."""


def compared(where=OUT_DIR) -> str:
    """The committed kinds' tables (`cpu_kinds.markdown`) under the designs' cross-CPU flags."""
    return cpu_kinds.markdown(cpu_kinds.read_kinds(where), CROSS_CPU)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    kind_arguments(parser, OUT_DIR)
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument(
        "--all-cores", action="store_true", help="also the default setting seeing every core (`all_cores`)"
    )
    parser.add_argument(
        "--compare", action="store_true", help="print the committed kinds' tables (nothing is measured)"
    )
    args = parser.parse_args()
    if args.child:
        return child()
    if args.compare:
        return print(compared())
    path, found = this_kind(args.out_dir)
    for name in ["default", *(s for s in args.settings if s != "default")]:
        if name in args.settings or name not in found["settings"]:
            found["settings"][name] = {"xla_flags": setting_flags(name), **measured_under(name)}
    default = found["settings"]["default"]["hashes"]
    for name, entry in found["settings"].items():
        entry["differ_from_default"] = differing(entry["hashes"], default)
        verdict = summary(entry["differ_from_default"])
        print(f"{name} ({entry['ynn_fusions']} YNNPACK fusions) against this kind's default: {verdict}")
    if args.all_cores:
        entry = {"xla_flags": setting_flags("default"), **measured_under("default", None)}
        entry["differ_from_default"] = differing(entry["hashes"], default)
        found["all_cores"] = entry
        verdict = summary(entry["differ_from_default"])
        print(f"default seeing {entry['visible_cores']} cores against one: {verdict}")
    found["cache_sizes"] = cpuinfo.cache_sizes()
    describe_kind(found, args)
    found["against"] = {}
    for other in other_kinds(path, OUT_DIR):
        found["against"][other["cpu"]] = {
            name: differing(entry["hashes"], other["settings"][name]["hashes"])
            for name, entry in found["settings"].items()
            if name in other["settings"] and seen_one_core(other["settings"][name])
        }
        for name, names in found["against"][other["cpu"]].items():
            print(f"against {other['cpu']}, {name}: {summary(names)}")
    write_json(path, portable(found))


if __name__ == "__main__":
    sys.exit(main())
