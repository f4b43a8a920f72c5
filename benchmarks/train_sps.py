"""Learner throughput: gradient and forward samples/s of the recurrent actor-critic network on this machine.

Section `network` (the default): for the paper network and a small one, with both convolution
implementations (`NetworkConfig.conv_impl` "matmul" and "xla"), one jitted call processes a minibatch of
`--batch` sequences x `--seq` steps of uint8 21x21x3 observations (paper: 512 x 16 = 8,192 samples):

  grad     ``jax.value_and_grad`` of
           mean(value^2) - mean(log_softmax(logits)) + mean(|decode(hidden, actions) - obs / 255|)
           (value, policy and auxiliary heads, like the PyTorch reference benchmarks/pytorch_paper_net.py;
           the last term through `network.aux_loss`, as the PPO loss computes it);
  forward  `unroll` + `decode`, no gradient.

Reported: samples/s (best and median of `--repeats` timed calls after one untimed warm-up), compile
seconds (``jit(f).lower(...).compile()``, measured separately), achieved GFLOP/s from an analytic count of
the matrix-product FLOPs the implementation performs (2 per multiply-add; Winograd layers: channel products
and pixel transforms, `forward_flops`; the gradient is the forward plus input and weight gradients, without
the unneeded ones, `grad_flops`; recomputation in the backward pass is not counted), and the peak of a large
float32 ``jnp.dot`` measured in the same run. XLA's ``cost_analysis`` counts a loop body once rather than
once per iteration, so it only cross-checks the forward count on a loop-free call (T=1, B=64).

``--impls auto`` (and ``--dtypes auto``) resolves the config first
(`jaxsocial.run.autotune.resolve`, at the minibatch's ``--seq * --batch`` frames: per-layer choices
measured, or read from the autotune cache, ``--autotune-cache``); the row records the resolved per-layer
`conv_impl` and dtype, what was asked for (`requested`) and each layer's measured candidates (`autotune`).

``--dtypes float32,bfloat16`` measures each `NetworkConfig.dtype` (bfloat16: product inputs in bfloat16,
float32 accumulation; the "matmul" implementation's stride-1 layers then run as im2col products, whose FLOPs
are counted as direct convolutions). With ``--torch PYTHON`` (a python with torch installed; torch is not a
dependency of jaxsocial) the PyTorch reference benchmarks/pytorch_paper_net.py (the same network in stock
PyTorch layers) runs in a subprocess with ``--threads <cpu count>``, once per dtype (bfloat16 under
``torch.autocast``), and its JSON line is reported beside ours in the same dtype. The results record the
CPU's model and vector flags (`cpu_flags`: AVX512, AVX512-BF16, AMX), which decide what bfloat16 gains.

Memory: XLA:CPU allocates its large temporary buffers afresh on every call; glibc's malloc mmaps them, and
the page faults on first touch cost ~10% of a gradient step. ``--hugepages`` re-runs this script with
``GLIBC_TUNABLES=glibc.malloc.hugetlb=1`` (transparent huge pages for malloc: ~300x fewer faults), and
the section `network_hugepages` runs the network section that way in a subprocess. No XLA flag is set:
none helped (see the docstring of jaxsocial.agents.network).

Section `products`: GFLOP/s of the paper network's matrix-product shapes in each of ``--dtypes`` (what
bfloat16 can gain on this machine, layer by layer).

Section `train`: end-to-end training throughput of the `small` (CLI default) and `paper` presets of
`python -m jaxsocial.train` (rollout of every slot + PPO update) and the README's symbolic-views command
(`TRAIN_RUNS`, chosen with ``--presets``), in joint env-steps/s, for each of ``--dtypes``.

`SECTIONS` maps a section name to ``fn(args) -> dict``. Run from the repository root (~6 minutes, most
of it the "xla" implementation's gradient and one paper-preset iteration; ``~/torchref`` is a virtual
environment with torch, see benchmarks/pytorch_paper_net.py):

    python benchmarks/train_sps.py --torch ~/torchref/bin/python
    python benchmarks/train_sps.py --sections network,network_hugepages --torch ~/torchref/bin/python
    python benchmarks/train_sps.py --configs paper --impls matmul --repeats 10 --hugepages
    python benchmarks/train_sps.py --sections network,train --configs paper --impls matmul \
        --dtypes float32,bfloat16 --presets paper,symbolic --torch PYTHON
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import itertools
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from run_info import REPO, metadata, write_results

from jaxsocial.agents import network
from jaxsocial.agents.fast import conv
from jaxsocial.run import autotune, cpuinfo
from jaxsocial.run.config import PRESETS

TORCH_SCRIPT = Path(__file__).resolve().parent / "pytorch_paper_net.py"
"""The PyTorch reference (run with the `--torch` python; the only file that imports torch)."""
HUGEPAGES_TUNABLE = "glibc.malloc.hugetlb=1"
CONFIGS = {
    "paper": network.NetworkConfig(),
    "small": network.NetworkConfig(conv_channels=(16, 32, 32), hidden=64, mlp=32),
    "laptop": PRESETS["laptop"].net,  # the science's network (its minibatch: --seq 16 --batch 64)
}
CPU_FLAGS = ("avx2", "avx512f", "avx512_bf16", "amx_tile", "amx_bf16")
"""The /proc/cpuinfo flags that decide bfloat16's speed: XLA:CPU widens bfloat16 to float32 without
AVX512-BF16 (or AMX, whose tiles multiply bfloat16 matrices)."""


def cpu_flags() -> dict[str, bool]:
    """Which of `CPU_FLAGS` this machine's CPU has (all False where /proc/cpuinfo is missing)."""
    flags = cpuinfo.flags()
    return {flag: flag in flags for flag in CPU_FLAGS}


# ---------------------------------------------------------------------------------------------- FLOPs


def forward_flops(cfg: network.NetworkConfig) -> dict[str, int]:
    """Matrix-product FLOPs (2 per multiply-add) of one sample's forward pass, per layer, as `cfg.conv_impl`
    computes them (per layer): the "matmul" implementation's stride-1 layers (Winograd in float32, see
    jaxsocial.agents.fast.conv) count their channel products under the layer's name and their pixel transforms
    (products with constant matrices) under "<layer>.transforms"; the others count direct convolutions. The
    Winograd kernel transforms (once per frame batch, not per sample) are left out."""
    c1, c2, c3 = cfg.conv_channels
    hid, mlp, k2 = cfg.hidden, cfg.mlp, network.KERNEL**2
    s1, s2, s3 = 7 * 7, 5 * 5, 3 * 3  # output positions of conv1..3 (and input positions of the deconvs)
    layers = {
        "conv1": s1 * k2 * 3 * c1,
        "fc": s3 * c3 * hid,
        "lstm": 2 * hid * 4 * hid,
        "value": hid * mlp + mlp * mlp + mlp,
        "policy": hid * mlp + mlp * mlp + mlp * cfg.n_actions,
    }
    stride1 = {"conv2": (s1, s2, c1, c2), "conv3": (s2, s3, c2, c3)}  # (in pixels, out pixels, c_in, c_out)
    if cfg.frame_aux != "none":
        layers |= {"aux_fc": (hid + cfg.n_actions) * s3 * c3, "deconv3": s1 * c1 * k2 * 3}
        stride1 |= {"deconv1": (s3, s2, c3, c2), "deconv2": (s2, s1, c2, c1)}
    for name, (p_in, p_out, c_in, c_out) in stride1.items():
        # (bfloat16: im2col, direct FLOPs)
        if conv.formulation(cfg.impl_for(name), 1, cfg.compute_dtype) == "winograd":
            tile = max(p_in, p_out)  # transformed pixels: (m + 2)^2
            layers[name] = tile * c_in * c_out
            layers[f"{name}.transforms"] = tile * (p_in * c_in + p_out * c_out)
        else:  # direct: 9 products per pixel of the smaller map
            layers[name] = min(p_in, p_out) * k2 * c_in * c_out
    return {name: 2 * macs for name, macs in layers.items()}


def grad_flops(cfg: network.NetworkConfig) -> int:
    """Forward + weight gradients + input gradients, except the gradients nothing needs: conv1's and the
    one-hot action columns' input gradients, and the (constant) Winograd transforms' weight gradients."""
    fwd = forward_flops(cfg)
    no_weight_grad = sum(flops for name, flops in fwd.items() if name.endswith(".transforms"))
    total = 3 * sum(fwd.values()) - fwd["conv1"] - no_weight_grad
    if cfg.frame_aux != "none":
        total -= 2 * cfg.n_actions * cfg.feature_size
    return total


def xla_forward_flops(cfg: network.NetworkConfig, batch: int = 64) -> float:
    """XLA's cost_analysis FLOPs per sample of a loop-free forward call (T=1; elementwise ops included)."""
    params = jax.eval_shape(lambda k: network.init(k, cfg), jax.random.key(0))
    fn = jax.jit(forward_fn(cfg))
    args = make_inputs(cfg, 1, batch, seed=0)[1:]
    cost = fn.lower(params, *args).compile().cost_analysis()
    cost = cost[0] if isinstance(cost, list) else cost
    return float(cost["flops"]) / batch


# ------------------------------------------------------------------------------------------ network


def make_inputs(cfg: network.NetworkConfig, seq: int, batch: int, seed: int):
    rng = np.random.default_rng(seed)
    params = jax.jit(network.init, static_argnums=1)(jax.random.key(seed), cfg)
    carry = network.initial_carry(cfg, (batch,))
    obs = jnp.asarray(rng.integers(0, 256, (seq, batch, *network.OBS_SHAPE), dtype=np.uint8))
    resets = jnp.zeros((seq, batch), bool)
    actions = jnp.asarray(rng.integers(0, cfg.n_actions, (seq, batch)), jnp.int32)
    return params, carry, obs, resets, actions


def loss_fn(cfg: network.NetworkConfig):
    def loss(params, carry, obs, resets, actions):
        _, out = network.unroll(params, cfg, carry, obs, resets)
        value_loss = jnp.mean(out.value**2)
        policy_term = -jnp.mean(jax.nn.log_softmax(out.logits))
        weight = jnp.full(actions.shape, 1.0 / actions.size)  # mean |decode(hidden, actions) - obs / 255|
        aux_loss = network.aux_loss(params, cfg, out.hidden, actions, obs, weight)
        return value_loss + policy_term + aux_loss

    return loss


def forward_fn(cfg: network.NetworkConfig):
    def forward(params, carry, obs, resets, actions):
        carry, out = network.unroll(params, cfg, carry, obs, resets)
        return carry, out, network.decode(params, cfg, out.hidden, actions)

    return forward


def time_calls(fn: Callable, args: tuple, repeats: int) -> list[float]:
    jax.block_until_ready(fn(*args))  # warm-up, untimed
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - t0)
    return times


def bench_network(name: str, cfg: network.NetworkConfig, seq: int, batch: int, repeats: int) -> dict:
    inputs = make_inputs(cfg, seq, batch, seed=0)
    samples = seq * batch
    row = {
        "config": name,
        "network_config": dataclasses.asdict(cfg),
        "params": network.param_count(inputs[0]),
        "samples": samples,
        "seq": seq,
        "batch": batch,
        "frame_batch": cfg.frame_batch,
        "dtype": cfg.dtype,
    }
    flops = {"grad": grad_flops(cfg), "forward": sum(forward_flops(cfg).values())}
    for kind, fn in [("grad", jax.value_and_grad(loss_fn(cfg))), ("forward", forward_fn(cfg))]:
        t0 = time.perf_counter()
        compiled = jax.jit(fn).lower(*inputs).compile()
        compile_s = time.perf_counter() - t0
        times = time_calls(compiled, inputs, repeats)
        best, median = min(times), statistics.median(times)
        row[kind] = {
            "compile_s": compile_s,
            "times_s": times,
            "best_samples_per_s": samples / best,
            "median_samples_per_s": samples / median,
            "flops_per_sample": flops[kind],
            "best_gflops_per_s": flops[kind] * samples / best / 1e9,
            "temp_bytes": compiled.memory_analysis().temp_size_in_bytes,
        }
    return row


def matmul_peak(n: int = 2048, repeats: int = 5) -> dict:
    """float32 GFLOP/s of a large square jnp.dot (best of `repeats`)."""
    a = jnp.asarray(np.random.default_rng(0).normal(size=(n, n)), jnp.float32)
    fn = jax.jit(jnp.dot).lower(a, a).compile()
    times = time_calls(fn, (a, a), repeats)
    return {"n": n, "times_s": times, "best_gflops_per_s": 2 * n**3 / min(times) / 1e9}


def run_torch(python: str, seq: int, batch: int, repeats: int, dtype: str) -> dict:
    cmd = [python, str(TORCH_SCRIPT), "--threads", str(os.cpu_count()), "--dtype", dtype]
    cmd += ["--seq", str(seq), "--batch", str(batch), "--reps", str(repeats)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=1800)
    if proc.returncode != 0:
        return {"command": cmd, "error": proc.stderr[-2000:]}
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    result["command"] = [python, str(TORCH_SCRIPT.relative_to(REPO)), *cmd[2:]]
    direct = dataclasses.replace(CONFIGS["paper"], conv_impl="xla")  # torch: direct convolutions
    flops = grad_flops(direct), sum(forward_flops(direct).values())
    result["grad_gflops_per_s"] = result["grad_samples_per_s"] * flops[0] / 1e9
    result["forward_gflops_per_s"] = result["forward_samples_per_s"] * flops[1] / 1e9
    return result


def resolved(cfg: network.NetworkConfig, batch: int, cache: str | None) -> tuple[network.NetworkConfig, dict]:
    """`cfg` with its "auto" fields resolved (`autotune.resolve` at `batch` frames) and what to report of it:
    {} when nothing was "auto", else what was asked for and each tuned layer's candidates and choice."""
    if not cfg.unresolved:
        return cfg, {}
    requested = {"conv_impl": cfg.conv_impl, "dtype": cfg.dtype}
    if cfg.dtype == "auto":
        cfg = dataclasses.replace(cfg, dtype=autotune.auto_dtype())
    t0 = time.perf_counter()
    tuning = autotune.tune(cfg, batch, path=cache)
    seconds = time.perf_counter() - t0
    layers = {layer: dataclasses.asdict(c) for layer, c in tuning.choices.items()}
    print(f"  autotune ({'cached' if tuning.cached else 'measured'}, {seconds:.1f} s):", flush=True)
    for layer, c in tuning.choices.items():
        times = ", ".join(f"{impl} {t * 1e3:.2f} ms" for impl, t in sorted(c.times_s.items()))
        print(f"    {layer:7s} {c.impl:6s} (alone: {c.alone}; {times})", flush=True)
    for impls, t in tuning.step_s.items():
        print(f"    gradient step {t * 1e3:.1f} ms with {impls}", flush=True)
    cfg = autotune.resolve(cfg, batch, path=cache)  # (from the cache tune filled)
    report = {"autotune": layers, "autotune_step_s": tuning.step_s, "autotune_cached": tuning.cached}
    return cfg, {"requested": requested, **report, "autotune_s": seconds}


def section_network(args: argparse.Namespace) -> dict:
    peak = matmul_peak()
    print(f"matmul peak (float32 {peak['n']}^2 jnp.dot): {peak['best_gflops_per_s']:.0f} GFLOP/s", flush=True)
    rows = []
    for name in args.configs:
        cfg = CONFIGS[name]
        print(
            f"{name}: forward {sum(forward_flops(cfg).values()) / 1e6:.2f} MFLOP/sample analytic, "
            f"{xla_forward_flops(cfg) / 1e6:.2f} by XLA cost_analysis (incl. elementwise)",
            flush=True,
        )
        for dtype, impl, frames in itertools.product(
            args.dtypes, args.impls, args.frame_batches or [cfg.frame_batch]
        ):
            cfg_impl = dataclasses.replace(cfg, conv_impl=impl, frame_batch=frames, dtype=dtype)
            cfg_impl, tuned = resolved(cfg_impl, args.seq * args.batch, args.autotune_cache)
            repeats = args.repeats if impl != "xla" else max(2, args.repeats // 3)  # xla: ~13 s per call
            row = bench_network(name, cfg_impl, args.seq, args.batch, repeats)
            row["conv_impl"] = impl
            row["layer_impls"] = cfg_impl.layer_impls
            row |= tuned
            row["loadavg_after"] = os.getloadavg()
            rows.append(row)
            g, f = row["grad"], row["forward"]
            print(
                f"  {dtype:8s} {impl:6s} frames {frames:5d} grad {g['best_samples_per_s']:8,.0f} samples/s "
                f"({g['best_gflops_per_s']:.0f} GFLOP/s, compile {g['compile_s']:.1f}s) | "
                f"forward {f['best_samples_per_s']:8,.0f} samples/s "
                f"({f['best_gflops_per_s']:.0f} GFLOP/s, compile {f['compile_s']:.1f}s), "
                f"load {row['loadavg_after'][0]:.1f}",
                flush=True,
            )
    result = {"matmul_peak": peak, "rows": rows}
    if args.torch:
        result["torch"] = []
        for dtype in dict.fromkeys(autotune.auto_dtype() if d == "auto" else d for d in args.dtypes):
            print(f"running the PyTorch reference in {dtype} ...", flush=True)
            torch_row = run_torch(args.torch, args.seq, args.batch, max(3, args.repeats // 2), dtype)
            torch_row["loadavg_after"] = os.getloadavg()
            result["torch"].append(torch_row)
            print(f"  {json.dumps(torch_row)}", flush=True)
    return result


def section_network_hugepages(args: argparse.Namespace) -> dict:
    """The network section again in a subprocess with GLIBC_TUNABLES=glibc.malloc.hugetlb=1."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "out.json"
        cmd = [sys.executable, __file__, "--sections", "network", "--hugepages", "--out", str(out)]
        cmd += ["--configs", ",".join(args.configs), "--impls", ",".join(args.impls)]
        cmd += ["--dtypes", ",".join(args.dtypes)]
        cmd += ["--autotune-cache", args.autotune_cache] if args.autotune_cache else []
        cmd += ["--frame-batches", ",".join(map(str, args.frame_batches))] if args.frame_batches else []
        cmd += ["--seq", str(args.seq), "--batch", str(args.batch), "--repeats", str(args.repeats)]
        subprocess.run(cmd, check=True, timeout=3600)
        return json.loads(out.read_text())["sections"]["network"]


SYMBOLIC_FLAGS = [
    "--env", "goalcycle3", "--env-args", "observation=symbolic", "--num-envs", "1024",
    "--rollout-steps", "64", "--ppo.num-minibatches", "4", "--ppo.minibatch-segments", "1024",
    "--net.hidden", "64", "--net.mlp", "64",
]  # fmt: skip
"""The README's symbolic-views training command (`python -m jaxsocial.train` flags but its iterations)."""
TRAIN_RUNS = ("small", "small-random", "paper", "symbolic")
"""Section `train`'s runs (``--presets``): the CLI default, it with random slots, the paper preset, and
`SYMBOLIC_FLAGS`."""


def train_run(name: str):
    """(TrainConfig, iterations per timed call) of one of `TRAIN_RUNS`."""
    from jaxsocial import train
    from jaxsocial.run.config import PRESETS

    return {
        "small": lambda: (PRESETS["small"], 10),
        "small-random": lambda: (dataclasses.replace(PRESETS["small"], slots="learner,random,random"), 10),
        "paper": lambda: (PRESETS["paper"], 1),
        "symbolic": lambda: (train.parse_args(SYMBOLIC_FLAGS), 1),
    }[name]()


def section_train(args: argparse.Namespace) -> dict:
    """End-to-end training throughput of `TRAIN_RUNS` (``--presets``) in each of ``--dtypes``: one compiled
    chunk of iterations (rollout of every slot + PPO update of every learner), joint env-steps/s."""
    from jaxsocial.run.startup import setup
    from jaxsocial.train import make_train

    rows = []
    for preset, dtype in itertools.product(args.presets, args.dtypes):
        cfg, n_iter = train_run(preset)
        minibatch = cfg.ppo.minibatch_segments * cfg.ppo.segment_length
        net, tuned = resolved(dataclasses.replace(cfg.net, dtype=dtype), minibatch, args.autotune_cache)
        cfg = dataclasses.replace(cfg, net=net)
        init, run_chunk, _ = make_train(cfg)
        state = jax.jit(init)(jax.random.key(0))
        fn = jax.jit(run_chunk, static_argnums=2)
        t0 = time.perf_counter()
        compiled = fn.lower(state, None, n_iter).compile()
        compile_s = time.perf_counter() - t0
        state, metrics = compiled(state, None)  # warm-up (also moves past the first, all-reset, rollout)
        jax.block_until_ready(metrics)
        times = []
        for _ in range(max(1, args.repeats // 2)):
            t0 = time.perf_counter()
            state, metrics = compiled(state, None)
            jax.block_until_ready(metrics)
            times.append(time.perf_counter() - t0)
        steps = n_iter * cfg.num_envs * cfg.rollout_steps
        n_agents = state.obs.shape[1]
        best = steps / min(times)
        row = {
            "preset": preset,
            "dtype": dtype,
            "net_dtype": net.dtype,
            "net_conv_impl": net.conv_impl,
            **tuned,
            "env": cfg.env,
            "slots": ",".join(slot.label for slot in setup(cfg).pop.slots),
            "iterations_per_call": n_iter,
            "env_steps_per_call": steps,
            "grad_samples_per_call": n_iter
            * cfg.ppo.num_minibatches
            * cfg.ppo.minibatch_segments
            * cfg.ppo.segment_length,
            "times_s": times,
            "compile_s": compile_s,
            "best_env_steps_per_s": best,
            "best_agent_steps_per_s": best * n_agents,
            "loadavg_after": os.getloadavg(),
        }
        rows.append(row)
        print(
            f"  {preset:12s} {dtype:8s} {best:9,.0f} joint env-steps/s "
            f"({best * n_agents:,.0f} agent-steps/s), {min(times) / n_iter:.2f} s/iteration, "
            f"compile {compile_s:.1f}s, load {row['loadavg_after'][0]:.1f}",
            flush=True,
        )
    return {"rows": rows}


def synthetic_rollout(cfg: network.NetworkConfig, steps: int, envs: int, seed: int = 0):
    """A `ppo.Batch` of random frames whose log-probabilities are the initial params' own (so the KL to the
    rollout policy starts at 0, as after a real rollout), with episodes of 100 steps."""
    from jaxsocial.agents import ppo

    params, _, obs, _, actions = make_inputs(cfg, steps + 1, envs, seed)
    resets = jnp.broadcast_to((jnp.arange(steps + 1) % 100 == 0)[:, None], (steps + 1, envs))
    carry0 = network.initial_carry(cfg, (envs,))
    _, out = jax.jit(network.unroll, static_argnums=1)(params, cfg, carry0, obs, resets)
    logp = jnp.take_along_axis(jax.nn.log_softmax(out.logits), actions[..., None], -1)[:steps, :, 0]
    rng = np.random.default_rng(seed)
    return params, ppo.Batch(
        obs=obs,
        resets=resets,
        actions=actions[:steps],
        logp=logp,
        rewards=jnp.asarray(rng.normal(size=(steps, envs)), jnp.float32),
        terminated=resets[1:],
        agent_done=resets[1:],
        final_values=jnp.zeros((steps, envs)),
        valid=jnp.ones((steps, envs), bool),
        carry0=carry0,
    )


def section_kl_stop(args: argparse.Namespace) -> dict:
    """Seconds per PPO update (the paper's PPOConfig: 20 minibatches of 512 segments x 16 steps) on a
    256-step x 128-env rollout (the paper preset's), when every minibatch runs, when the KL early stop fires
    at minibatch 1, and the latter with the stopped minibatches still computed (the code before they were
    skipped, by replacing `ppo.any_in_batch` with a constant True)."""
    from jaxsocial.agents import ppo
    from jaxsocial.agents.ppo_config import PPOConfig

    rows = []
    for name in args.configs:
        cfg = dataclasses.replace(CONFIGS[name], conv_impl="matmul")
        params, batch = synthetic_rollout(cfg, steps=256, envs=128)
        cases = {
            "every minibatch": (PPOConfig(kl_target=1e9, kl_hard_limit=1e9), ppo.any_in_batch),
            "stop at minibatch 1": (PPOConfig(kl_target=1e-12, kl_hard_limit=1e9), ppo.any_in_batch),
            "stop at minibatch 1, no skip": (
                PPOConfig(kl_target=1e-12, kl_hard_limit=1e9),
                lambda running: jnp.array(True),
            ),
        }
        for case, (ppo_cfg, predicate) in cases.items():
            ppo.any_in_batch = predicate
            try:
                opt_state = ppo.make_optimizer(ppo_cfg).init(params)
                # A new function each time: jit's cache does not see the patched predicate.
                fn = jax.jit(lambda *a: ppo.update(*a), static_argnums=(3, 4))
                t0 = time.perf_counter()
                compiled = fn.lower(jax.random.key(0), params, opt_state, cfg, ppo_cfg, batch).compile()
                compile_s = time.perf_counter() - t0
            finally:
                ppo.any_in_batch = cases["every minibatch"][1]
            call = (jax.random.key(0), params, opt_state, batch)
            times = time_calls(compiled, call, args.repeats)
            applied = float(compiled(*call)[2]["minibatches"])
            rows.append({"config": name, "case": case, "minibatches_applied": applied, "times_s": times,
                         "best_s": min(times), "compile_s": compile_s})  # fmt: skip
            print(f"  {name:5s} {case:30s} {min(times):7.2f} s/update ({applied:.0f} applied), "
                  f"compile {compile_s:.1f}s", flush=True)  # fmt: skip
    return {"rows": rows}


PRODUCTS = {
    "2048^3": (1, 2048, 2048, 2048),
    "FC 8192x576 . 576x192": (1, 8192, 576, 192),
    "LSTM 8192x192 . 192x768": (1, 8192, 192, 768),
    "decoder FC 8192x199 . 199x576": (1, 8192, 199, 576),
    "im2col conv2 50176x288 . 288x64": (1, 50176, 288, 64),
    "Winograd conv2 36x(8192x32 . 32x64)": (36, 8192, 32, 64),
}
"""The paper network's matrix-product shapes at a minibatch of 8,192 samples: (batch, m, k, n)."""


def section_products(args: argparse.Namespace) -> dict:
    """GFLOP/s of the network's product shapes (`PRODUCTS`), jitted, best of ``--repeats``, in each of
    ``--dtypes`` (`precision.matmul`: bfloat16 inputs cast inside the call, float32 accumulation)."""
    from jaxsocial.agents.fast.precision import matmul

    rng = np.random.default_rng(0)
    rows = []
    for name, (batch, m, k, n) in PRODUCTS.items():
        lead = (batch,) if batch > 1 else ()
        x = jnp.asarray(rng.normal(size=(*lead, m, k)), jnp.float32)
        w = jnp.asarray(rng.normal(size=(*lead, k, n)), jnp.float32)
        row = {"product": name, "shape": [batch, m, k, n]}
        for dtype in args.dtypes:
            if batch > 1:  # batched: cast and contract like precision.matmul, per batch member
                fn = jax.vmap(lambda a, b, d=dtype: matmul(a, b, d))
            else:
                fn = functools.partial(matmul, dtype=dtype)
            times = time_calls(jax.jit(fn), (x, w), args.repeats)
            row[dtype] = 2 * batch * m * k * n / min(times) / 1e9
        row["loadavg_after"] = os.getloadavg()
        rows.append(row)
        print(f"  {name:38s} " + " ".join(f"{d} {row[d]:6.0f}" for d in args.dtypes) + " GFLOP/s, "
              f"load {row['loadavg_after'][0]:.1f}", flush=True)  # fmt: skip
    return {"rows": rows}


SECTIONS: dict[str, Callable[[argparse.Namespace], dict]] = {
    "network": section_network,
    "train": section_train,
    "kl_stop": section_kl_stop,
    "network_hugepages": section_network_hugepages,
    "products": section_products,
}


# --------------------------------------------------------------------------------------------- report


def print_table(net: dict) -> None:
    peak = net["matmul_peak"]["best_gflops_per_s"]
    print(f"\nsamples/s (best of repeats); GFLOP/s vs matmul peak {peak:.0f}")
    header = (
        f"{'config':>6} {'dtype':>8} {'impl':>6} {'frames':>6} | {'grad/s':>8} {'GFLOP/s':>7} "
        f"{'compile':>7} | {'fwd/s':>8} {'GFLOP/s':>7} {'compile':>7}"
    )
    print(header)
    print("-" * len(header))
    for r in net["rows"]:
        g, f = r["grad"], r["forward"]
        print(
            f"{r['config']:>6} {r.get('dtype', 'float32'):>8} {r['conv_impl']:>6} {r['frame_batch']:>6} | "
            f"{g['best_samples_per_s']:>8,.0f} {g['best_gflops_per_s']:>7.0f} {g['compile_s']:>6.1f}s | "
            f"{f['best_samples_per_s']:>8,.0f} {f['best_gflops_per_s']:>7.0f} {f['compile_s']:>6.1f}s"
        )
        if "autotune" in r:
            print(f"{'':>6} {'':>8} {'':>6} {'':>6} | {r['network_config']['conv_impl']}")
    for t in net.get("torch", []):
        if "error" not in t:
            print(
                f"{'paper':>6} {t['dtype']:>8} {'torch':>6} {'':>6} | {t['grad_samples_per_s']:>8,.0f} "
                f"{t['grad_gflops_per_s']:>7.0f} {'':>7} | {t['forward_samples_per_s']:>8,.0f} "
                f"{t['forward_gflops_per_s']:>7.0f}"
                f"   ({t['framework']}, {t['threads']} threads)"
            )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sections", default="network,train", help=f"comma-separated: {', '.join(SECTIONS)}")
    parser.add_argument("--configs", default="paper,small", help=f"comma-separated: {', '.join(CONFIGS)}")
    parser.add_argument(
        "--impls", default="matmul,xla", help="comma-separated conv_impl values (auto: autotuned per layer)"
    )
    parser.add_argument(
        "--dtypes", default="float32", help="comma-separated NetworkConfig.dtype values (auto: the machine's)"
    )
    parser.add_argument(
        "--autotune-cache",
        help="the autotune's cache file (default: jaxsocial.run.autotune.cache_path())",
    )
    parser.add_argument(
        "--presets", default="small,small-random,paper", help=f"section train: {', '.join(TRAIN_RUNS)}"
    )
    parser.add_argument(
        "--frame-batches",
        default="",
        help="comma-separated NetworkConfig.frame_batch values (default: the config's)",
    )
    parser.add_argument("--seq", type=int, default=16, help="steps per sequence (paper: 16)")
    parser.add_argument("--batch", type=int, default=512, help="sequences per minibatch (paper: 512)")
    parser.add_argument("--repeats", type=int, default=5, help="timed calls per measurement (best, median)")
    parser.add_argument("--torch", metavar="PYTHON", help="python with torch: run the PyTorch reference too")
    parser.add_argument(
        "--hugepages", action="store_true", help=f"run with GLIBC_TUNABLES={HUGEPAGES_TUNABLE}"
    )
    parser.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "train_sps.json"))
    args = parser.parse_args()
    args.sections = [s.strip() for s in args.sections.split(",") if s.strip()]
    args.configs = [c.strip() for c in args.configs.split(",") if c.strip()]
    args.impls = [i.strip() for i in args.impls.split(",") if i.strip()]
    args.dtypes = [d.strip() for d in args.dtypes.split(",") if d.strip()]
    args.presets = [p.strip() for p in args.presets.split(",") if p.strip()]
    args.frame_batches = [int(c) for c in args.frame_batches.split(",") if c.strip()]
    for kind, values, known in [
        ("section", args.sections, SECTIONS),
        ("config", args.configs, CONFIGS),
        ("impl", args.impls, (*network.CONV_IMPLS, "auto")),
        ("dtype", args.dtypes, (*network.DTYPES, "auto")),
        ("preset", args.presets, TRAIN_RUNS),
    ]:
        if unknown := sorted(set(values) - set(known)):
            parser.error(f"unknown {kind}(s) {unknown}; choose from {', '.join(known)}")

    tunables = os.environ.get("GLIBC_TUNABLES", "")
    if args.hugepages and HUGEPAGES_TUNABLE not in tunables:
        env = dict(os.environ, GLIBC_TUNABLES=":".join(filter(None, [tunables, HUGEPAGES_TUNABLE])))
        os.execve(sys.executable, [sys.executable, *sys.argv], env)  # glibc reads its tunables at start-up

    print(f"devices: {jax.devices()}  cpu_count: {os.cpu_count()}  GLIBC_TUNABLES={tunables!r}", flush=True)
    meta = metadata(args) | {"cpu_flags": cpu_flags()}
    sections = {}
    for name in args.sections:
        print(f"\n== section {name}", flush=True)
        sections[name] = SECTIONS[name](args)
        if name.startswith("network"):
            print_table(sections[name])
    write_results(args.out, meta, sections)


if __name__ == "__main__":
    main()
