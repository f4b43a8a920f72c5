"""`autotune.resolve`: "auto" conv implementations (measured per layer, cached) and dtypes (from the machine);
the per-layer `conv_impl` strings they produce."""

import dataclasses
import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from float_bounds import assert_trees_within, gamma, network_error

from jaxsocial.agents import network as net
from jaxsocial.agents.network_config import CONV_LAYERS
from jaxsocial.run import autotune, config, cpuinfo

TINY = net.NetworkConfig(conv_channels=(4, 6, 5), hidden=8, mlp=6, aux="pred")
BATCH = 4  # frames per call (tiny shapes: every candidate compiles and runs in milliseconds)


@pytest.fixture
def counted(monkeypatch):
    """`autotune.measure` and `measure_step` counted (`calls` lists each measured layer, and "step" for each
    gradient-step comparison); the timings made up (`FAKE_TIMES`: deterministic choices, and no compiling).
    `calls.steps_faster`: whether a trial step is faster than the one it is compared with."""
    calls = Calls()

    def measure(spec, impls, dtype, reps=autotune.REPS):
        calls.append(spec.layer)
        return {impl: FAKE_TIMES[spec.layer].get(impl, 1.0) for impl in impls}

    def measure_step(nets, frames, reps=autotune.REPS):
        calls.append("step")
        return (1.0, 0.5) if calls.steps_faster else (1.0, 1.0)

    monkeypatch.setattr(autotune, "measure", measure)
    monkeypatch.setattr(autotune, "measure_step", measure_step)
    return calls


class Calls(list):
    steps_faster = True


# choices alone: conv1 xla, conv2 matmul (im2col is not below PREFER times matmul), deconv2 im2col
FAKE_TIMES = {
    "conv1": {"matmul": 1.0, "xla": 0.5},
    "conv2": {"matmul": 1.0, "im2col": 0.9, "xla": 2.0},
    "conv3": {"matmul": 1.0},
    "deconv1": {"matmul": 1.0},
    "deconv2": {"matmul": 1.0, "im2col": 0.5},
    "deconv3": {"matmul": 1.0},
}


def test_nothing_auto_is_the_identity(tmp_path, counted):
    for cfg in (TINY, dataclasses.replace(TINY, conv_impl="xla", dtype="bfloat16")):
        assert autotune.resolve(cfg, BATCH, path=tmp_path / "a.json") is cfg
    per_layer = dataclasses.replace(TINY, conv_impl="conv1=xla,conv2=im2col")
    assert autotune.resolve(per_layer, BATCH, path=tmp_path / "a.json") is per_layer
    assert not counted and not (tmp_path / "a.json").exists()


def test_auto_resolves_every_layer_and_caches(tmp_path, counted, capsys):
    path = tmp_path / "cache" / "autotune.json"
    cfg = dataclasses.replace(TINY, conv_impl="auto")
    resolved = autotune.resolve(cfg, BATCH, path=path)
    said = capsys.readouterr().err
    assert f"autotune: measuring the {len(CONV_LAYERS)} 'auto' layers" in said  # says so, and where
    assert f"the choice is cached in {path}" in said
    expected = "conv1=xla,conv2=matmul,conv3=matmul,deconv1=matmul,deconv2=im2col,deconv3=matmul"
    assert resolved.conv_impl == expected and not resolved.unresolved
    assert dataclasses.replace(resolved, conv_impl="auto") == cfg  # nothing else changed
    assert counted == [*CONV_LAYERS, "step", "step"]  # conv1 and deconv2 confirmed in the step
    entries = json.loads(path.read_text())["entries"]
    assert len(entries) == len(CONV_LAYERS) + 1  # the layers' timings, the network's choice
    network_entry = next(e for k, e in entries.items() if "|network " in k)
    assert network_entry["conv_impl"] == expected
    # stride 3: "im2col" computes as "matmul" (measured once); float32 stride 1: all three differ
    conv1 = next(e for k, e in entries.items() if "stride 3 in 21x21" in k)
    assert set(conv1["times_s"]) == {"matmul", "xla"}
    assert all(f"x{BATCH}x" in k for k in entries if "|network " not in k)

    counted.clear()  # a second resolve reads the cache and measures nothing (and says nothing)
    assert autotune.resolve(cfg, BATCH, path=path) == resolved
    assert "measuring" not in capsys.readouterr().err
    tuning = autotune.tune(cfg, BATCH, path=path)
    assert not counted and tuning.cached and set(tuning.choices) == set(CONV_LAYERS)
    assert tuning.choices["conv1"].alone == "xla" and tuning.choices["conv1"].times_s == FAKE_TIMES["conv1"]

    # only the "auto" layers are measured, from their cached timings where the layer was seen before
    partial = dataclasses.replace(TINY, conv_impl="xla,conv2=auto,conv3=auto", aux="none")
    assert autotune.resolve(partial, BATCH, path=path).conv_impl == "conv1=xla,conv2=matmul,conv3=matmul"
    assert not counted  # conv2's and conv3's choices alone are "matmul": nothing to confirm
    # another batch (frame count) is another key; frames are min(batch, frame_batch)
    assert autotune.resolve(partial, BATCH + 1, path=path).conv_impl == "conv1=xla,conv2=matmul,conv3=matmul"
    assert counted == ["conv2", "conv3"]
    counted.clear()
    batched = dataclasses.replace(cfg, frame_batch=BATCH)
    assert autotune.resolve(batched, 1000, path=path) == dataclasses.replace(resolved, frame_batch=BATCH)
    assert not counted


def test_a_choice_alone_is_kept_only_if_the_step_is_faster(tmp_path, counted):
    counted.steps_faster = False
    resolved = autotune.resolve(dataclasses.replace(TINY, conv_impl="auto"), BATCH, path=tmp_path / "a.json")
    assert resolved.conv_impl == ",".join(f"{layer}=matmul" for layer in CONV_LAYERS)
    assert counted.count("step") == 2


def test_real_measurements(tmp_path):
    """The real `measure` and `measure_step` on tiny shapes (1 rep): valid choices, a timing per candidate."""
    cfg = dataclasses.replace(TINY, conv_impl="conv1=auto,deconv2=auto")
    tuning = autotune.tune(cfg, BATCH, path=tmp_path / "a.json", reps=1)
    assert set(tuning.choices) == {"conv1", "deconv2"} and not tuning.cached
    for layer, choice in tuning.choices.items():
        assert choice.impl in net.CONV_IMPLS and choice.alone in net.CONV_IMPLS
        assert set(choice.times_s) == ({"matmul", "xla"} if layer == "conv1" else set(net.CONV_IMPLS))
        assert all(0 < t < 10 for t in choice.times_s.values())
    assert all(0 < t < 10 for t in tuning.step_s.values())
    assert autotune.tune(cfg, BATCH, path=tmp_path / "a.json").cached


@pytest.mark.parametrize(
    "content", ["{not json", "[]", '{"version": 1, "entries": 3}', '{"version": 0, "entries": {}}']
)
def test_corrupt_cache_warns_and_measures_again(tmp_path, counted, content):
    path = tmp_path / "autotune.json"
    path.write_text(content)
    cfg = dataclasses.replace(TINY, conv_impl="deconv2=auto")
    with pytest.warns(UserWarning, match="autotune cache .* unusable"):
        resolved = autotune.resolve(cfg, BATCH, path=path)
    assert counted == ["deconv2", "step"] and not resolved.unresolved
    assert resolved.layer_impls["deconv2"] == "im2col"
    assert len(json.loads(path.read_text())["entries"]) == 2  # rewritten whole: the layer, the network


def test_bad_cache_entries_are_measured_again(tmp_path, counted):
    path = tmp_path / "autotune.json"
    cfg = dataclasses.replace(TINY, conv_impl="conv2=auto", aux="none")
    autotune.resolve(cfg, BATCH, path=path)
    data = json.loads(path.read_text())
    for entry in data["entries"].values():
        entry.update(conv_impl="conv2=cudnn", times_s={"matmul": "fast", "im2col": 1, "xla": 1})
    path.write_text(json.dumps(data))
    with pytest.warns(UserWarning, match="unusable"):
        assert autotune.resolve(cfg, BATCH, path=path).conv_impl == "conv1=matmul,conv2=matmul,conv3=matmul"
    assert counted == ["conv2", "conv2"]


def test_unwritable_cache_warns_and_resolves(tmp_path, counted):
    blocker = tmp_path / "file"
    blocker.write_text("")
    cfg = dataclasses.replace(TINY, conv_impl="conv3=auto", aux="none")
    with pytest.warns(UserWarning) as record:  # (its reading fails too)
        resolved = autotune.resolve(cfg, BATCH, path=blocker / "autotune.json")
    assert any("cannot be written" in str(w.message) for w in record)
    assert not resolved.unresolved


def test_default_cache_path(monkeypatch, tmp_path):
    monkeypatch.setenv("JAXSOCIAL_CACHE", str(tmp_path))
    assert autotune.cache_path() == tmp_path / "autotune.json"
    monkeypatch.delenv("JAXSOCIAL_CACHE")
    assert autotune.cache_path().name == "autotune.json"
    assert autotune.cache_path().parent.name == "jaxsocial"


def test_per_layer_strings_round_trip_and_validate():
    cfg = dataclasses.replace(
        TINY, conv_impl="conv1=xla,conv2=matmul,conv3=im2col,deconv1=xla,deconv3=im2col"
    )
    assert cfg.layer_impls == {
        "conv1": "xla", "conv2": "matmul", "conv3": "im2col", "deconv1": "xla", "deconv2": "matmul",
        "deconv3": "im2col",
    }  # fmt: skip
    assert [cfg.impl_for(layer) for layer in ("conv2", "deconv2")] == ["matmul", "matmul"]
    assert dataclasses.replace(TINY, conv_impl="xla,conv2=auto").layer_impls["conv3"] == "xla"
    assert dataclasses.replace(TINY, conv_impl="auto").impl_for("conv2") == "matmul"  # unresolved: matmul
    symbolic = dataclasses.replace(TINY, obs="symbolic", conv_impl="auto")
    assert tuple(symbolic.layer_impls) == ("conv2", "conv3", "deconv1", "deconv2")
    train = dataclasses.replace(config.TrainConfig(), net=cfg)
    assert config.config_from_dict(json.loads(json.dumps(config.config_dict(train)))) == train


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"conv_impl": "cudnn"}, "unknown implementation 'cudnn'"),
        ({"conv_impl": "conv2=cudnn"}, "unknown implementation 'cudnn'"),
        ({"conv_impl": "conv4=xla"}, "unknown layer 'conv4'"),
        ({"conv_impl": "conv2=xla,conv2=matmul"}, "named twice"),
        ({"conv_impl": "xla,matmul"}, "two defaults"),
        ({"conv_impl": ""}, "unknown implementation ''"),
        ({"conv_impl": "conv1=xla,"}, "unknown implementation ''"),
        ({"dtype": "float16"}, "unknown dtype 'float16'"),
    ],
)
def test_invalid_values_raise(kwargs, match):
    with pytest.raises(ValueError, match=match):
        dataclasses.replace(TINY, **kwargs)


def test_bad_batch_raises(tmp_path):
    with pytest.raises(ValueError, match="batch"):
        autotune.resolve(dataclasses.replace(TINY, conv_impl="auto"), 0, path=tmp_path / "a.json")


@pytest.mark.parametrize(
    "backend, flags, dtype",
    [
        ("cpu", {"avx512f", "avx512_bf16"}, "float32"),
        ("cpu", {"avx512_bf16", "amx_tile", "amx_bf16"}, "bfloat16"),
        ("cpu", set(), "float32"),
        ("gpu", set(), "bfloat16"),
    ],
)
def test_auto_dtype(monkeypatch, tmp_path, counted, backend, flags, dtype):
    monkeypatch.setattr(autotune, "backend", lambda: backend)
    monkeypatch.setattr(cpuinfo, "flags", lambda: frozenset(flags))
    assert autotune.auto_dtype() == dtype
    cfg = dataclasses.replace(TINY, dtype="auto")
    with pytest.raises(ValueError, match="autotune.resolve"):
        cfg.compute_dtype  # noqa: B018 - the network refuses an unresolved dtype
    assert autotune.resolve(cfg, BATCH, path=tmp_path / "a.json") == dataclasses.replace(TINY, dtype=dtype)
    assert not counted


def test_dtype_resolves_before_the_conv_autotune(monkeypatch, tmp_path, counted):
    """The layers are measured (and keyed) in the resolved dtype."""
    monkeypatch.setattr(autotune, "backend", lambda: "gpu")
    path = tmp_path / "a.json"
    resolved = autotune.resolve(
        dataclasses.replace(TINY, dtype="auto", conv_impl="conv2=auto"), BATCH, path=path
    )
    assert resolved.dtype == "bfloat16" and not resolved.unresolved
    entries = json.loads(path.read_text())["entries"]
    assert len(entries) == 2 and all("|bfloat16|" in key for key in entries)
    layer = next(e for k, e in entries.items() if "|network " not in k)
    assert set(layer["times_s"]) == {"matmul", "xla"}  # bfloat16 stride 1: "im2col" computes as "matmul"


def test_mixed_layers_compute_what_xla_computes():
    """A per-layer mix (every implementation, and Winograd on a stride-1 layer in each of the encoder and the
    decoder) against all-"xla": outputs, decoded frames and gradients within the two computations' float32
    error bounds (`float_bounds`, layer by layer)."""
    mixed = dataclasses.replace(
        TINY, conv_impl="conv1=im2col,conv2=matmul,conv3=xla,deconv1=im2col,deconv2=matmul"
    )
    reference = dataclasses.replace(TINY, conv_impl="xla")
    t, b = 3, 2
    rng = np.random.default_rng(0)
    params = jax.tree_util.tree_map(
        lambda x: jnp.asarray(0.3 * rng.normal(size=x.shape), jnp.float32),
        jax.eval_shape(lambda k: net.init(k, TINY), jax.random.key(0)),
    )
    obs = jnp.asarray(rng.integers(0, 256, (t, b, *net.OBS_SHAPE), dtype=np.uint8))
    actions = jnp.asarray(rng.integers(0, TINY.n_actions, (t, b)), jnp.int32)
    resets = jnp.zeros((t, b), bool)

    def loss(params, cfg):
        _, out = net.unroll(params, cfg, net.initial_carry(cfg, (b,)), obs, resets)
        pred = net.decode(params, cfg, out.hidden, actions)
        return (out.value**2).mean() + jnp.abs(pred - obs / 255.0).mean(), (out, pred)

    grad = jax.jit(jax.value_and_grad(loss, has_aux=True), static_argnums=1)
    (l_mix, aux_mix), g_mix = grad(params, mixed)
    (l_ref, aux_ref), g_ref = grad(params, reference)
    outputs = network_error(mixed, t) + network_error(reference, t)
    pixels = t * b * math.prod(net.OBS_SHAPE)
    np.testing.assert_allclose(l_mix, l_ref, rtol=outputs + 2 * gamma(pixels))
    assert_trees_within(aux_mix, aux_ref, outputs)
    assert_trees_within(g_mix, g_ref, 2 * outputs + 2 * gamma(pixels))


def test_a_training_run_records_what_auto_chose(tmp_path, monkeypatch, counted):
    """The trainer resolves "auto" at start-up (`startup.resolve_network`): config.json names every layer, as
    the tuning it cached chose (timings made up by `counted`; `test_real_measurements` measures)."""
    from conftest import TINY as TINY_RUN

    from jaxsocial import train
    from jaxsocial.run import rundir

    monkeypatch.setenv("JAXSOCIAL_CACHE", str(tmp_path / "cache"))
    auto = dataclasses.replace(TINY_RUN.net, conv_impl="auto", dtype="auto")
    run_dir = train.run(dataclasses.replace(TINY_RUN, net=auto, iterations=2, runs_dir=str(tmp_path)))
    saved = rundir.read_config(run_dir)["net"]
    assert saved["dtype"] == autotune.auto_dtype()
    assert all(f"{layer}=" in saved["conv_impl"] for layer in CONV_LAYERS)  # RGB with a decoder: all six
    assert set(CONV_LAYERS) <= set(counted)  # every layer measured (made-up times), then the steps
    entries = json.loads((tmp_path / "cache" / "autotune.json").read_text())["entries"].values()
    (tuned,) = [entry for entry in entries if "conv_impl" in entry]  # the network's (beside its layers')
    assert saved["conv_impl"] == tuned["conv_impl"] and "auto" not in saved["conv_impl"]
