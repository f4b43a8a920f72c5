"""The network's gradient step under variants that compute the same values, timed side by side in one process:
frame batches, what the frame-batch scan saves for the backward pass, and the Winograd layers' transformed
pixels saved instead of recomputed.

    python benchmarks/gradient_variants.py --config laptop --cpu 1 --repeats 40 \
        --variants base,saved=transforms,saved=nothing,saved=everything,frame_batch=256,frame_batch=128 \
        --out benchmarks/results/gradient_variants.json

Each variant is one jitted ``value_and_grad`` of `train_sps.loss_fn` (value, policy and auxiliary terms) on
one PPO minibatch of the recipe (``--seq 16 --batch 64``: 1,024 samples), compiled first, then timed in turn
for ``--repeats`` rounds, so drifts of a shared machine reach every variant alike. It prints each variant's
median and best, samples/s and the ratio of medians to the first variant, and the largest difference of its
loss and gradients from the first variant's (0 where the arithmetic is the same, float rounding where the
frames are grouped otherwise).

Variants: ``base`` (the config as it is), or '+'-joined changes: ``frame_batch=N``; ``saved=nothing`` (the
backward pass recomputes a frame batch's whole forward pass), ``saved=everything`` (no recomputation),
``saved=transforms`` (the Winograd layers' transformed pixels saved beside the activations;
`conv.transformed_pixels`).

``--profile`` also traces 20 calls of the first variant (`jax.profiler`) and splits its time by layer: XLA's
leaf operations grouped by the network module their HLO metadata names, forward and backward apart (the
backward's share includes the forward a frame batch recomputes).

``--cpu K`` pins the process to core K with XLA:CPU single-threaded, the layout the science runs its seeds in;
two processes started together (``--cpu 0`` and ``--cpu 1``, each with its own ``--out``) measure it with both
cores busy.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import os
import statistics
import sys
import time


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", default="laptop", help="a network of train_sps.CONFIGS")
    parser.add_argument("--variants", default="base,saved=transforms,saved=nothing,frame_batch=256")
    parser.add_argument("--seq", type=int, default=16, help="steps per segment (the recipe: 16)")
    parser.add_argument("--batch", type=int, default=64, help="segments per minibatch (laptop: 64)")
    parser.add_argument("--repeats", type=int, default=30)
    parser.add_argument("--cpu", type=int, help="pin to this core, XLA:CPU single-threaded")
    parser.add_argument("--profile", action="store_true", help="split the first variant's time by layer")
    parser.add_argument("--out", help="JSON results path")
    args = parser.parse_args(argv)
    for variant in args.variants.split(","):
        try:
            parse_variant(variant)
        except ValueError as err:
            parser.error(str(err))
    return args


SAVED_VARIANTS = ("nothing", "everything", "transforms")


def parse_variant(text: str) -> dict[str, int | str]:
    """'base', or '+'-joined 'frame_batch=N' and 'saved=WHAT' -> {"frame_batch": N, "saved": WHAT} (those
    given). ValueError otherwise."""
    if text == "base":
        return {}
    out: dict[str, int | str] = {}
    for part in text.split("+"):
        kind, _, value = part.partition("=")
        if kind == "saved" and value in SAVED_VARIANTS:
            out["saved"] = value
        elif kind == "frame_batch" and value.isdigit() and int(value) > 0:
            out["frame_batch"] = int(value)
        else:
            choices = f"base, or '+'-joined saved={'|'.join(SAVED_VARIANTS)} and frame_batch=N"
            raise ValueError(f"unknown variant {text!r}: {choices}")
    return out


@contextlib.contextmanager
def saving(what: str):
    """While tracing: the frame-batch scan saves `what` (one of `SAVED_VARIANTS`) for the backward pass."""
    import jax
    from jax.ad_checkpoint import checkpoint_name

    from jaxsocial.agents.fast import conv, frame_batches

    policies = jax.checkpoint_policies
    only_these, pixels = policies.save_only_these_names, conv.transformed_pixels
    if what == "transforms":
        conv.transformed_pixels = lambda t, x: checkpoint_name(pixels(t, x), frame_batches.SAVED)
    else:
        policy = policies.nothing_saveable if what == "nothing" else policies.everything_saveable
        policies.save_only_these_names = lambda *names: policy
    try:
        yield
    finally:
        policies.save_only_these_names, conv.transformed_pixels = only_these, pixels


LAYERS = (
    "aux_fc",
    "deconv1",
    "deconv2",
    "deconv3",
    "conv1",
    "conv2",
    "conv3",
    "fc",
    "lstm",
    "value",
    "policy",
)
"""The network's layers as their names appear in HLO metadata (a name inside another comes after it)."""
PROFILED_CALLS = 20


def layer_times(fn, inputs: tuple, hlo: str) -> dict[str, float]:
    """Seconds per call of `fn(*inputs)` in each layer's operations, "<layer> forward" and "<layer> backward"
    (the rest of the decoder, i.e. the loss, counts as "decoder"; what no layer names as "other"), from a
    `jax.profiler` trace of `PROFILED_CALLS` calls; `hlo` is the compiled program's text (its metadata names
    each operation's source)."""
    import gzip
    import json
    import re
    import tempfile
    from collections import Counter
    from pathlib import Path

    import jax

    sources = dict(re.findall(r"%?([\w.\-]+) = [^\n]*?metadata=\{[^}\n]*?op_name=\"([^\"]*)\"", hlo))
    with tempfile.TemporaryDirectory() as directory:
        with jax.profiler.trace(directory, create_perfetto_trace=True):
            for _ in range(PROFILED_CALLS):
                jax.block_until_ready(fn(*inputs))
        trace = json.loads(
            gzip.decompress(next(Path(directory).rglob("*perfetto_trace.json.gz")).read_bytes())
        )
    spans = Counter()
    for event in trace["traceEvents"]:
        source = sources.get(event.get("name"))
        if event.get("ph") != "X" or source is None or event["name"].startswith("while"):
            continue  # not one of the program's leaf operations
        layer = next(
            (name for name in LAYERS if name in source), "decoder" if "Decoder" in source else "other"
        )
        direction = "backward" if "transpose(" in source else "forward"
        spans[f"{layer} {direction}"] += event["dur"] * 1e-6 / PROFILED_CALLS
    return dict(spans.most_common())


def main() -> None:
    args = parse_args()
    if args.cpu is not None:  # before XLA starts its backend (importing jaxsocial starts none)
        from jaxsocial.experiments.launch.pinned import process_xla_flags

        os.environ["XLA_FLAGS"] = process_xla_flags()
        os.sched_setaffinity(0, {args.cpu})
    import jax
    import jax.numpy as jnp
    import train_sps
    from run_info import metadata, write_results

    if args.config not in train_sps.CONFIGS:
        sys.exit(f"unknown --config {args.config!r}; choose from {list(train_sps.CONFIGS)}")
    meta = metadata(args)
    base = train_sps.CONFIGS[args.config]
    samples = args.seq * args.batch
    compiled, inputs = {}, {}
    for variant in args.variants.split(","):
        parts = parse_variant(variant)
        cfg = dataclasses.replace(base, frame_batch=parts.get("frame_batch", base.frame_batch))
        inputs[variant] = train_sps.make_inputs(cfg, args.seq, args.batch, seed=0)
        with saving(parts["saved"]) if "saved" in parts else contextlib.nullcontext():
            lowered = jax.jit(jax.value_and_grad(train_sps.loss_fn(cfg))).lower(*inputs[variant])
        t0 = time.perf_counter()
        compiled[variant] = (lowered.compile(), time.perf_counter() - t0)
    first = next(iter(compiled))
    reference = compiled[first][0](*inputs[first])
    times = {variant: [] for variant in compiled}
    for _ in range(args.repeats):
        for variant, (fn, _) in compiled.items():
            t0 = time.perf_counter()
            jax.block_until_ready(fn(*inputs[variant]))
            times[variant].append(time.perf_counter() - t0)
    rows = {}
    for variant, (fn, compile_s) in compiled.items():
        out = fn(*inputs[variant])
        pairs = zip(jax.tree.leaves(out), jax.tree.leaves(reference), strict=True)
        diff = max(float(jnp.max(jnp.abs(a - b))) for a, b in pairs)
        median = statistics.median(times[variant])
        rows[variant] = {
            "times_s": times[variant],
            "median_s": median,
            "best_s": min(times[variant]),
            "samples_per_s": samples / median,
            "ratio_to_first": statistics.median(times[first]) / median,
            "max_abs_diff_to_first": diff,
            "compile_s": compile_s,
        }
        print(
            f"{variant:30s} median {median * 1e3:7.2f} ms, best {min(times[variant]) * 1e3:7.2f} ms, "
            f"{samples / median:9,.0f} samples/s (x{rows[variant]['ratio_to_first']:.2f}); "
            f"loss and gradients within {diff:.1e} of {first}'s"
        )
    sections = {"gradient_variants": {"config": args.config, "samples": samples, **rows}}
    if args.profile:
        fn = compiled[first][0]
        spans = layer_times(fn, inputs[first], fn.as_text())
        print(
            f"\n{first}, by layer (ms per call; leaf operations, {sum(spans.values()) * 1e3:.1f} ms in all):"
        )
        for name, seconds in spans.items():
            print(f"  {name:20s} {seconds * 1e3:7.2f}")
        sections["layer_times_s"] = {"variant": first, **spans}
    if args.out:
        write_results(args.out, meta, sections)


if __name__ == "__main__":
    sys.exit(main())
