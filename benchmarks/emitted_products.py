"""What would it cost to keep every matrix product out of the kernel libraries? (issue 85, item 2)

`op_fingerprints.py` finds that the operations separating CPU kinds are the library kernels XLA calls for
matrix products (YNNPACK's `dot_k<K>`, Eigen's `dot_t_k<K>`), while the products XLA emits itself (the
matrix-vector products `gemv_k<K>`, `vecmat_k1024`, `dot_n1_k64`) and its elementwise code agree on every
kind measured. A candidate setting under which every kind could agree is therefore: no library product at
all. This measures its price on the laptop recipe, side by side, before anyone builds it.

One iteration of the reference record's config (`reproducibility.REFERENCE`, the laptop recipe) is traced to
a jaxpr, and every matrix product in it (a `dot_general` whose operands both have a free axis of more than
one element) is replaced, recursively inside scans, loops and branches, by a formulation XLA emits itself:

- `rows`: a loop (`lax.map`) over the product's rows (and its batch axis), each row a matrix-vector product;
- `taps`: a loop (`lax.scan`, unrolled 8) over the contracted axis, each step an elementwise multiply-add of
  the outer product into the whole output;

each product taking whichever of the two runs fewer loop steps (rows, or columns by transposing). The
iteration then runs with the products as traced (`library`) and as replaced (`emitted`), alternately in one
process pinned to one core, under the portable flags (`reproducibility.SETTINGS["portable"]`: AVX2, no
XNNPACK or YNNPACK, strict dot and convolution math, no fast or platform-dependent math) and under the
designs' flags (`pinned.CROSS_CPU_XLA_FLAGS`). Printed and written: each variant's median seconds an
iteration (compile time apart), its ratio to the designs' library program, how many library products (`dot`
instructions of two matrices) and YNNPACK fusions each compiled program still holds, and how far the
rewritten iteration's first metrics are from the library's (each from the same state: the same function,
up to rounding).

    taskset -c 1 python benchmarks/emitted_products.py --repeats 5 \
        --out benchmarks/results/emitted_products.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import re
import statistics
import subprocess
import sys
import time

from reproducibility import REFERENCE, SETTINGS
from run_info import REPO, metadata, write_json

from jaxsocial.experiments.launch import pinned

VARIANTS = {
    "designs_library": (pinned.SINGLE_CORE_XLA_FLAGS + " " + pinned.CROSS_CPU_XLA_FLAGS, False),
    "portable_library": (pinned.SINGLE_CORE_XLA_FLAGS + " " + SETTINGS["portable"], False),
    "portable_emitted": (pinned.SINGLE_CORE_XLA_FLAGS + " " + SETTINGS["portable"], True),
}
"""Variant -> (its $XLA_FLAGS, whether its matrix products are replaced by emitted loops)."""
TAPS_UNROLL = 8
INLINED = {
    "pjit": "jaxpr",
    "jit": "jaxpr",
    "closed_call": "call_jaxpr",
    "custom_jvp_call": "call_jaxpr",
    "custom_vjp_call": "call_jaxpr",
    "custom_vjp_call_jaxpr": "fun_jaxpr",
    "custom_vmap_call": "call",
}
"""Primitives whose sub-program is evaluated in place (the parameter holding it): nested jits, and custom
derivatives and batching rules, which the traced iteration no longer needs (it is differentiated already)."""


def emitted_dot(lhs, rhs, *, dimension_numbers, precision=None, preferred_element_type=None, **_):
    """`lax.dot_general(lhs, rhs, dimension_numbers)` with no library product: matrix-vector products in a
    loop over rows (or columns), or the outer products of the contracted axis accumulated in a loop, which
    ever runs fewer steps; a product with no free axis longer than one element on a side is left as it is
    (XLA emits those itself)."""
    import jax.numpy as jnp
    from jax import lax

    (lc, rc), (lb, rb) = dimension_numbers
    lf = [a for a in range(lhs.ndim) if a not in lc and a not in lb]
    rf = [a for a in range(rhs.ndim) if a not in rc and a not in rb]
    b, m, k = (math.prod(lhs.shape[a] for a in axes) for axes in (lb, lf, lc))
    n = math.prod(rhs.shape[a] for a in rf)
    if m == 1 or n == 1:
        return lax.dot_general(lhs, rhs, dimension_numbers, precision, preferred_element_type)
    out_shape = [lhs.shape[a] for a in lb] + [lhs.shape[a] for a in lf] + [rhs.shape[a] for a in rf]
    a = lhs.transpose(*lb, *lf, *lc).reshape(b, m, k)
    w = rhs.transpose(*rb, *rc, *rf).reshape(b, k, n)
    if k <= b * min(m, n):
        terms = (a.transpose(2, 0, 1), w.transpose(1, 0, 2))  # [k, b, m], [k, b, n]

        def tap(acc, term):
            column, row = term
            return acc + column[:, :, None] * row[:, None, :], None

        out = lax.scan(tap, jnp.zeros((b, m, n), lhs.dtype), terms, unroll=TAPS_UNROLL)[0]
    elif m <= n:
        out = lax.map(lambda pair: lax.map(lambda row: row @ pair[1], pair[0]), (a, w))
    else:
        out = lax.map(lambda pair: lax.map(lambda col: pair[0] @ col, pair[1].T), (a, w)).transpose(0, 2, 1)
    return out.reshape(out_shape)


def with_emitted_products(fun):
    """`fun` (of array arguments, returning a pytree) with every matrix product replaced (`emitted_dot`),
    inside scans, while loops and conds too; nested jits and custom derivatives are inlined, remat kept."""
    import jax
    from jax.extend import core

    def evaluate(jaxpr, consts, *args):
        env = {}
        read = lambda v: v.val if isinstance(v, core.Literal) else env[v]  # noqa: E731
        env.update(zip(jaxpr.constvars, consts, strict=True))
        env.update(zip(jaxpr.invars, args, strict=True))
        for eqn in jaxpr.eqns:
            outs = apply(eqn, [read(v) for v in eqn.invars])
            env.update(zip(eqn.outvars, outs, strict=True))
        return [read(v) for v in jaxpr.outvars]

    def closed(sub):
        """A ClosedJaxpr with its products replaced, of the same signature."""
        avals = [jax.ShapeDtypeStruct(v.aval.shape, v.aval.dtype) for v in sub.jaxpr.invars]
        return jax.make_jaxpr(lambda *a: evaluate(sub.jaxpr, sub.consts, *a))(*avals)

    def apply(eqn, invals):
        name, params = eqn.primitive.name, eqn.params
        if name == "dot_general":
            return [emitted_dot(*invals, **params)]
        inline = {
            "pjit": "jaxpr",
            "jit": "jaxpr",
            "closed_call": "call_jaxpr",
            "custom_jvp_call": "call_jaxpr",
        }
        inline |= {
            "custom_vjp_call": "call_jaxpr",
            "custom_vjp_call_jaxpr": "fun_jaxpr",
            "custom_vmap_call": "call",
        }
        if name in inline:
            sub = params[inline[name]]
            consts = getattr(sub, "consts", [])
            return evaluate(getattr(sub, "jaxpr", sub), consts, *invals)
        new = dict(params)
        if name == "scan":
            new["jaxpr"] = closed(params["jaxpr"])
        elif name == "while":
            new["cond_jaxpr"], new["body_jaxpr"] = closed(params["cond_jaxpr"]), closed(params["body_jaxpr"])
        elif name == "remat2":  # kept, so the backward pass still recomputes what it recomputed
            rewritten = closed(core.ClosedJaxpr(params["jaxpr"], ()))
            if rewritten.consts:
                raise NotImplementedError("remat2: its rewritten program has constants")
            new["jaxpr"] = rewritten.jaxpr
        elif name == "cond":
            new["branches"] = tuple(closed(b) for b in params["branches"])
        outs = eqn.primitive.bind(*invals, **new)
        return outs if eqn.primitive.multiple_results else [outs]

    def rewritten(*args):
        flat, tree = jax.tree.flatten(args)
        traced, shape = jax.make_jaxpr(
            lambda *leaves: fun(*jax.tree.unflatten(tree, leaves)), return_shape=True
        )(*flat)
        outs = evaluate(traced.jaxpr, traced.consts, *flat)
        return jax.tree.unflatten(jax.tree.structure(shape), outs)

    return rewritten


def library_products(hlo: str) -> int:
    """The compiled program's `dot` instructions of two matrices: those whose result has at least two axes
    longer than one besides its batch axes (a matrix-vector product has one), inside fusions too."""
    count = 0
    for line in hlo.splitlines():
        found = re.search(r"= f32\[([\d,]*)\]\S* dot\(", line)
        if found:
            dims = [int(d) for d in found[1].split(",") if d]
            batch = re.search(r"lhs_batch_dims=\{([\d,]*)\}", line)
            free = dims[len(batch[1].split(",")) if batch and batch[1] else 0 :]
            count += sum(d > 1 for d in free) >= 2
    return count


def child(variant: str, repeats: int) -> None:
    """Print one JSON line: the variant's compile seconds, seconds an iteration (each repeat), products, and
    the first iteration's metrics (each leaf's mean), by which the rewritten program is checked."""
    import jax

    from jaxsocial import train
    from jaxsocial.run import config, policy_io, rundir, startup

    cfg = config.config_from_dict(rundir.read_config(REFERENCE))
    cfg = dataclasses.replace(cfg, iterations=1, chunk_iterations=1, compile_cache=None)
    init, run_chunk, _ = train.make_train(cfg)
    frozen = policy_io.load_frozen(startup.setup(cfg, load_frozen=False).pop, cfg.net)
    state = jax.jit(init)(jax.random.key(cfg.seed))

    def iteration(state):
        return run_chunk(state, frozen, 1)

    fun = with_emitted_products(iteration) if VARIANTS[variant][1] else iteration
    start = time.perf_counter()
    compiled = jax.jit(fun).lower(state).compile()
    compile_s = time.perf_counter() - start
    seconds, first = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        state, metrics = jax.block_until_ready(compiled(state))
        seconds.append(time.perf_counter() - start)
        first = first or {
            jax.tree_util.keystr(k): float(v.mean()) for k, v in jax.tree.leaves_with_path(metrics)
        }
    hlo = compiled.as_text()
    found = {"compile_s": compile_s, "seconds": seconds, "library_products": library_products(hlo)}
    found["first_metrics"] = first
    found["ynn_fusions"] = hlo.count('"kind":"__ynn_fusion"')
    print(json.dumps(found))


def measured(variant: str, repeats: int) -> dict:
    env = os.environ | {"XLA_FLAGS": VARIANTS[variant][0], "JAX_PLATFORMS": "cpu"}
    argv = [sys.executable, __file__, "--child", variant, "--repeats", str(repeats)]
    done = subprocess.run(argv, env=env, capture_output=True, text=True, check=False, cwd=REPO)
    if done.returncode != 0:
        raise RuntimeError(f"{variant}: its process failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=5, help="iterations timed per round, after the first")
    parser.add_argument("--rounds", type=int, default=2, help="rounds, each running every variant once")
    parser.add_argument("--out", default=None, help="write the results here as JSON")
    parser.add_argument("--child", choices=list(VARIANTS), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.child, args.repeats + 1)
        return
    runs = {v: [] for v in VARIANTS}
    for _ in range(args.rounds):
        for variant in VARIANTS:
            runs[variant].append(measured(variant, args.repeats))
    results = {}
    for variant, found in runs.items():
        seconds = [s for run in found for s in run["seconds"][1:]]
        results[variant] = {
            "xla_flags": VARIANTS[variant][0],
            "emitted": VARIANTS[variant][1],
            "median_s": statistics.median(seconds),
            "seconds": seconds,
            "compile_s": [run["compile_s"] for run in found],
            "library_products": found[0]["library_products"],
            "ynn_fusions": found[0]["ynn_fusions"],
        }
    reference, rewritten = (
        runs["portable_library"][0]["first_metrics"],
        runs["portable_emitted"][0]["first_metrics"],
    )
    results["portable_emitted"]["metrics_max_relative_difference"] = max(
        abs(rewritten[k] - v) / max(abs(v), 1e-3) for k, v in reference.items()
    )
    base = results["designs_library"]["median_s"]
    for variant, r in results.items():
        r["ratio"] = r["median_s"] / base
        print(
            f"{variant:18s} {r['median_s']:.3f} s an iteration (x{r['ratio']:.2f}), compile "
            f"{statistics.median(r['compile_s']):.1f} s, library products {r['library_products']}, "
            f"YNNPACK fusions {r['ynn_fusions']}"
        )
    print(
        "the rewritten iteration's first metrics against the portable library's: largest difference, "
        "relative to the larger of the value and 1e-3: "
        f"{results['portable_emitted']['metrics_max_relative_difference']:.1e}"
    )
    if args.out:
        write_json(args.out, {"results": results, "metadata": metadata(args)})


if __name__ == "__main__":
    main()
