"""Recurrent actor-critic network: parameter count, shapes, conv implementations, unroll/step consistency."""

import dataclasses
import functools
import math

import chex
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from float_bounds import assert_trees_within, assert_within, decoder_error, gamma, network_error
from reference_network import PaperActorCritic

from jaxsocial.agents import network as net
from jaxsocial.run import checkpoint, policy_io

SMALL = net.NetworkConfig(conv_channels=(4, 6, 5), hidden=8, mlp=6, aux="pred")
T, B = 5, 3

# Jitted once for the module (eager op-by-op dispatch compiles every primitive separately and is slower).
init = jax.jit(net.init, static_argnums=1)
unroll = jax.jit(net.unroll, static_argnums=1)
step = jax.jit(net.step, static_argnums=1)
decode = jax.jit(net.decode, static_argnums=1)


def _obs(seed, shape):
    return jnp.asarray(np.random.default_rng(seed).integers(0, 256, shape, dtype=np.uint8))


def _normal(seed, tree, scale=1.0):
    """A tree like `tree` of normal(0, scale) float32 arrays (numpy: no jit compile per shape)."""
    rng = np.random.default_rng(seed)
    return jax.tree_util.tree_map(lambda x: jnp.asarray(scale * rng.normal(size=x.shape), jnp.float32), tree)


@pytest.fixture(scope="module")
def small_params():
    return init(jax.random.key(0), SMALL)


def test_paper_param_count():
    shapes = jax.eval_shape(lambda k: net.init(k, net.NetworkConfig()), jax.random.key(0))
    # PyTorch reference: 668,555, with two LSTM bias vectors (4 * 192 = 768 more).
    assert net.param_count(shapes) == 667_787 == 668_555 - 4 * 192
    no_aux = jax.eval_shape(lambda k: net.init(k, net.NetworkConfig(aux="none")), jax.random.key(0))
    assert net.param_count(no_aux) == 496_328
    assert not {"aux_fc", "deconv1", "deconv2", "deconv3"} & set(no_aux)
    rec = jax.eval_shape(lambda k: net.init(k, net.NetworkConfig(aux="rec")), jax.random.key(0))
    assert net.param_count(rec) == 667_787


@pytest.mark.parametrize(
    ("aux", "frame_aux", "decoder"), [("attention", "none", False), ("pred+attention", "pred", True)]
)
def test_attention_head_adds_one_dense_layer(aux, frame_aux, decoder):
    cfg = net.NetworkConfig(aux=aux, n_others=3)
    assert (cfg.frame_aux, cfg.attention) == (frame_aux, True)
    shapes = jax.eval_shape(lambda k: net.init(k, cfg), jax.random.key(0))
    base = 667_787 if decoder else 496_328
    assert net.param_count(shapes) == base + (192 + 1) * 3 * 50
    assert shapes["attention"]["kernel"].shape == (192, 150)


def test_attention_loss_is_the_weighted_cross_entropy():
    cfg = net.NetworkConfig(conv_channels=(4, 6, 5), hidden=8, mlp=6, aux="attention", n_others=2)
    params = init(jax.random.key(0), cfg)
    hidden = jax.random.normal(jax.random.key(1), (3, 4, 8))
    target = jax.random.randint(jax.random.key(2), (3, 4, 2), 0, 50)
    weight = jax.random.uniform(jax.random.key(3), (3, 4))
    logits = (hidden @ params["attention"]["kernel"] + params["attention"]["bias"]).reshape(3, 4, 2, 50)
    log_probs = np.asarray(jax.nn.log_softmax(logits))
    nll = -np.take_along_axis(log_probs, np.asarray(target)[..., None], -1)[..., 0]
    expected = (np.asarray(weight) * nll.mean(-1)).sum()
    # float32 error (`float_bounds`): a logit's sum, the log-softmax's sum over the classes, the weighted sum;
    # every term of the loss is positive, so relative to the loss itself, once per computation.
    terms = cfg.hidden + 1 + net.ATTENTION_CLASSES + weight.size * cfg.n_others
    actual = net.attention_loss(params, cfg, hidden, target, weight)
    np.testing.assert_allclose(actual, expected, rtol=2 * gamma(terms))
    with pytest.raises(ValueError, match="no attention head"):
        net.attention_loss(params, dataclasses.replace(cfg, aux="pred"), hidden, target, weight)


def test_paper_param_shapes():
    shapes = jax.eval_shape(lambda k: net.init(k, net.NetworkConfig()), jax.random.key(0))
    assert shapes["conv1"]["kernel"].shape == (3, 3, 3, 32)
    assert shapes["conv3"]["kernel"].shape == (3, 3, 64, 64)
    assert shapes["fc"]["kernel"].shape == (576, 192)
    assert shapes["lstm"]["wi"].shape == shapes["lstm"]["wh"].shape == (192, 768)
    assert shapes["aux_fc"]["kernel"].shape == (199, 576)
    assert shapes["deconv3"]["kernel"].shape == (3, 3, 32, 3)
    assert all(leaf.dtype == jnp.float32 for leaf in jax.tree_util.tree_leaves(shapes))


def test_init(small_params):
    """Orthogonal dense and recurrent weights with the documented gains, small policy output, zero biases."""
    wh = np.asarray(small_params["lstm"]["wh"]).reshape(SMALL.hidden, 4, SMALL.hidden)
    for gate in range(4):
        np.testing.assert_allclose(wh[:, gate].T @ wh[:, gate], np.eye(SMALL.hidden), atol=1e-5)
    fc = np.asarray(small_params["fc"]["kernel"])  # [feature_size, hidden]: orthonormal columns, gain sqrt(2)
    np.testing.assert_allclose(fc.T @ fc, 2 * np.eye(SMALL.hidden), atol=1e-5)
    out = np.asarray(small_params["policy"]["out"]["kernel"])  # [mlp=6, n_actions=7]: orthonormal rows * 0.01
    np.testing.assert_allclose(out @ out.T, 1e-4 * np.eye(SMALL.mlp), atol=1e-9)
    assert not np.any(small_params["lstm"]["b"]) and not np.any(small_params["value"]["out"]["bias"])
    bound = 1 / np.sqrt(3 * 9)
    assert 0.5 * bound < np.abs(small_params["conv1"]["kernel"]).max() <= bound
    keys = jax.random.split(jax.random.key(1), 2)
    assert not np.allclose(init(keys[0], SMALL)["conv2"]["kernel"], init(keys[1], SMALL)["conv2"]["kernel"])


def test_output_shapes_and_decode(small_params):
    cfg = SMALL
    obs = _obs(1, (T, B, *net.OBS_SHAPE))
    carry, out = unroll(small_params, cfg, net.initial_carry(cfg, (B,)), obs, jnp.zeros((T, B), bool))
    assert out.logits.shape == (T, B, cfg.n_actions)
    assert out.value.shape == (T, B)
    assert out.hidden.shape == (T, B, cfg.hidden)
    assert carry.c.shape == carry.h.shape == (B, cfg.hidden)
    np.testing.assert_array_equal(carry.h, out.hidden[-1])
    pred = decode(small_params, cfg, out.hidden, jnp.zeros((T, B), jnp.int32))
    assert pred.shape == (T, B, *net.OBS_SHAPE) and pred.dtype == jnp.float32
    assert decode(small_params, cfg, out.hidden[0, 0], jnp.int32(3)).shape == net.OBS_SHAPE
    carry1, out1 = step(small_params, cfg, net.initial_carry(cfg, (B,)), obs[0], jnp.zeros((B,), bool))
    assert out1.logits.shape == (B, cfg.n_actions) and out1.value.shape == (B,)
    assert out1.hidden.shape == carry1.h.shape == (B, cfg.hidden)


def test_params_of_another_shape_are_named(small_params):
    """Applying params whose layer has another shape than the network's says which, before it computes."""
    wide = dataclasses.replace(SMALL, hidden=SMALL.hidden + 1)
    obs = _obs(1, (B, *net.OBS_SHAPE))
    with pytest.raises(ValueError, match=r"^fc/kernel: the params hold \(45, 8\), the network \(45, 9\)"):
        step(small_params, wide, net.initial_carry(wide, (B,)), obs, jnp.zeros((B,), bool))


def test_matmul_equals_xla_conv(small_params):
    """Both conv implementations compute the same function of the same params, and the same gradients.

    The matmul side also runs the encoder and decoder in frame batches of 4 of the T * B = 15 frames (padded
    to 16, with the checkpointing of `frame_batches.map_frame_batches`); the xla side in one piece.
    Tolerances: the two computations' float32 error bounds (`float_bounds.network_error`, dominated by
    Winograd's), plus the loss's sum over every pixel and, for gradients, the path back and a weight
    gradient's sum over frames and pixels.
    """
    cfg_mm = dataclasses.replace(SMALL, frame_batch=4)
    cfg_xla = dataclasses.replace(SMALL, conv_impl="xla")
    assert cfg_mm.frame_batch < T * B <= cfg_xla.frame_batch and (T * B) % cfg_mm.frame_batch
    rng = np.random.default_rng(2)
    obs = _obs(3, (T, B, *net.OBS_SHAPE))
    actions = jnp.asarray(rng.integers(0, SMALL.n_actions, (T, B)), jnp.int32)
    resets = jnp.asarray(rng.random((T, B)) < 0.3)
    carry = _normal(4, net.initial_carry(SMALL, (B,)), 0.5)
    params = _normal(5, small_params, 0.3)  # random (not initial) params: every weight and bias matters

    def loss(params, cfg):
        _, out = net.unroll(params, cfg, carry, obs, resets)
        pred = net.decode(params, cfg, out.hidden, actions)
        terms = (
            (out.value**2).mean(),
            jax.nn.log_softmax(out.logits).mean(),
            jnp.abs(pred - obs / 255.0).mean(),
        )
        return sum(terms), (out, pred)

    (l_mm, aux_mm), g_mm = jax.jit(jax.value_and_grad(loss, has_aux=True), static_argnums=1)(params, cfg_mm)
    (l_xla, aux_xla), g_xla = jax.jit(jax.value_and_grad(loss, has_aux=True), static_argnums=1)(
        params, cfg_xla
    )
    outputs = network_error(cfg_mm, T) + network_error(cfg_xla, T)
    pixels = T * B * math.prod(net.OBS_SHAPE)
    np.testing.assert_allclose(l_mm, l_xla, rtol=outputs + 2 * gamma(pixels))
    assert_trees_within(aux_mm, aux_xla, outputs)
    assert float(jnp.abs(aux_mm[1]).max()) > 0.1  # the decoder output is not trivially zero
    assert_trees_within(g_mm, g_xla, 2 * outputs + 2 * gamma(pixels))
    for path, a in jax.tree_util.tree_leaves_with_path(g_mm):
        assert float(jnp.abs(a).max()) > 0, path


def test_unroll_equals_steps_with_resets(small_params):
    """Tolerance: two float32 computations of the network without the decoder (`float_bounds`); the batch
    shapes differ, so XLA may sum in other orders."""
    cfg = SMALL
    bound = 2 * network_error(cfg, T, decoder=False)
    obs = _obs(6, (T, B, *net.OBS_SHAPE))
    resets = np.zeros((T, B), bool)
    resets[2, 0] = resets[3, 1] = resets[0, 2] = True
    resets = jnp.asarray(resets)
    carry0 = _normal(7, net.initial_carry(cfg, (B,)))

    final, out = unroll(small_params, cfg, carry0, obs, resets)
    carry, outs = carry0, []
    for t in range(T):
        carry, o = step(small_params, cfg, carry, obs[t], resets[t])
        outs.append(o)
    stacked = jax.tree_util.tree_map(lambda *xs: jnp.stack(xs), *outs)
    assert_trees_within((final, out), (carry, stacked), bound)

    # After sequence 0's reset at t=2, its outputs equal a fresh unroll of obs[2:] from a zero carry.
    _, fresh = unroll(
        small_params, cfg, net.initial_carry(cfg, (1,)), obs[2:, :1], jnp.zeros((T - 2, 1), bool)
    )
    assert_within(out.hidden[2:, :1], fresh.hidden, bound)
    assert_within(out.logits[2:, :1], fresh.logits, bound)
    # ... and before it, the (nonzero) initial carry mattered.
    _, no_reset = unroll(small_params, cfg, carry0, obs, jnp.zeros((T, B), bool))
    assert not np.allclose(no_reset.hidden[2:, 0], out.hidden[2:, 0])


def test_vmap_over_agents():
    """Independent agents: params stacked on a leading axis, unroll vmapped over it."""
    cfg = SMALL
    n_agents = 2
    params = jax.jit(jax.vmap(net.init, in_axes=(0, None)), static_argnums=1)(
        jax.random.split(jax.random.key(5), n_agents), cfg
    )
    obs = _obs(8, (n_agents, T, B, *net.OBS_SHAPE))
    carry = net.initial_carry(cfg, (n_agents, B))
    resets = jnp.zeros((n_agents, T, B), bool)
    vmapped = jax.jit(jax.vmap(net.unroll, in_axes=(0, None, 0, 0, 0)), static_argnums=1)
    _, out = vmapped(params, cfg, carry, obs, resets)
    assert out.logits.shape == (n_agents, T, B, cfg.n_actions)
    params1 = jax.tree_util.tree_map(lambda x: x[1], params)
    _, out1 = unroll(params1, cfg, net.initial_carry(cfg, (B,)), obs[1], resets[1])
    assert_within(out.logits[1], out1.logits, 2 * network_error(cfg, T, decoder=False))


def test_aux_loss_equals_decode_error(small_params):
    """`aux_loss` (decoder backward in its forward pass, by frame batches) has the value and the gradients
    (params, hidden, weight) of the weighted error written with `decode`, with and without differentiation;
    15 frames in frame batches of 4 (padded) and weights with zeros. Tolerances: two float32 computations of
    the decoder (`float_bounds.decoder_error`) and of the sums over a frame's pixels and the frames; gradients
    also the path back and the sum over frames and pixels."""
    cfg = dataclasses.replace(SMALL, frame_batch=4)
    rng = np.random.default_rng(7)
    params = _normal(8, small_params, 0.3)
    hidden = jnp.asarray(rng.normal(size=(T, B, cfg.hidden)), jnp.float32)
    actions = jnp.asarray(rng.integers(0, cfg.n_actions, (T, B)), jnp.int32)
    target = _obs(9, (T, B, *net.OBS_SHAPE))
    weight = jnp.asarray(rng.random((T, B)) * (rng.random((T, B)) < 0.7), jnp.float32)

    def with_decode(params, hidden, weight):
        error = jnp.abs(net.decode(params, cfg, hidden, actions) - target / 255.0).mean(axis=(-3, -2, -1))
        return 3.0 * jnp.sum(weight * error)  # x 3 (like c_aux): the backward pass scales by its cotangent

    def fused(params, hidden, weight):
        return 3.0 * net.aux_loss(params, cfg, hidden, actions, target, weight)

    grad = functools.partial(jax.value_and_grad, argnums=(0, 1, 2))
    value, grads = jax.jit(grad(fused))(params, hidden, weight)
    expected_value, expected_grads = jax.jit(grad(with_decode))(params, hidden, weight)
    sums = gamma(math.prod(net.OBS_SHAPE)) + gamma(T * B)
    bound = 2 * (decoder_error(cfg) + sums)
    np.testing.assert_allclose(value, expected_value, rtol=bound)
    np.testing.assert_allclose(jax.jit(fused)(params, hidden, weight), expected_value, rtol=bound)
    assert_trees_within(grads, expected_grads, 2 * bound + 2 * gamma(T * B * math.prod(net.OBS_SHAPE)))
    assert float(jnp.abs(grads[0]["deconv1"]["kernel"]).max()) > 0 and float(jnp.abs(grads[1]).max()) > 0
    assert not np.any(grads[0]["conv1"]["kernel"])  # the encoder is not part of the decoder's loss


def test_no_custom_calls():
    """No LAPACK or other custom calls in init or in the gradient step. A batched (vmapped) LAPACK QR fans out
    into XLA:CPU's intra-op pool and blocks; two at once deadlocked vmap(init) on a 2-core machine."""
    key = jax.random.key(0)
    assert "custom_call" not in jax.jit(net.init, static_argnums=1).lower(key, net.NetworkConfig()).as_text()
    params = jax.eval_shape(lambda k: net.init(k, SMALL), key)
    obs = jax.ShapeDtypeStruct((T, B, *net.OBS_SHAPE), jnp.uint8)

    def loss(params, obs):
        _, out = net.unroll(params, SMALL, net.initial_carry(SMALL, (B,)), obs, jnp.zeros((T, B), bool))
        return out.value.sum() + net.decode(params, SMALL, out.hidden, jnp.zeros((T, B), jnp.int32)).sum()

    assert "custom_call" not in jax.jit(jax.grad(loss)).lower(params, obs).as_text()


def test_decode_without_aux_raises():
    cfg = net.NetworkConfig(conv_channels=(4, 6, 5), hidden=8, mlp=6, aux="none")
    params = jax.eval_shape(lambda k: net.init(k, cfg), jax.random.key(0))
    with pytest.raises(ValueError, match="aux"):
        net.decode(params, cfg, jnp.zeros((2, 8)), jnp.zeros((2,), jnp.int32))


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"aux": "next"}, "aux"),
        ({"conv_impl": "cudnn"}, "conv_impl"),
        ({"hidden": 0}, "hidden"),
        ({"mlp": -1}, "mlp"),
        ({"n_actions": 0}, "n_actions"),
        ({"conv_channels": (32, 0, 64)}, "conv_channels"),
        ({"conv_channels": (32, 64)}, "conv_channels"),
        ({"frame_batch": 0}, "frame_batch"),
        ({"hidden": 1.5}, "hidden"),
        ({"aux": "attention+pred"}, "aux"),
        ({"n_others": 0}, "n_others"),
    ],
)
def test_bad_config_raises(kwargs, match):
    with pytest.raises(ValueError, match=match):
        net.NetworkConfig(**kwargs)


def test_flax_modules_are_the_functional_network(small_params):
    """``ActorCritic(cfg).init`` builds the tree `init` builds (also with more frames than a frame batch:
    batched layers under ``nn.scan``), and ``.apply`` is `unroll` (within two float32 computations' error
    bound: the frame batches differ)."""
    cfg = dataclasses.replace(SMALL, frame_batch=4)
    args = (net.initial_carry(cfg, (B,)), _obs(10, (T, B, *net.OBS_SHAPE)), jnp.zeros((T, B), bool))
    variables = jax.eval_shape(lambda k: net.ActorCritic(cfg).init(k, *args), jax.random.key(0))
    assert set(variables) == {"params"}
    chex.assert_trees_all_equal_shapes_and_dtypes(variables["params"], small_params)
    applied = jax.jit(net.ActorCritic(cfg).apply)({"params": small_params}, *args)
    expected = unroll(small_params, SMALL, *args)
    assert_trees_within(applied, expected, 2 * network_error(cfg, T, decoder=False))


def test_the_paper_network_is_the_network_in_plain_layers(small_params):
    """`PaperActorCritic` (`reference_network`: plain Flax layers, NHWC, float32, in one piece) builds the
    params tree `init` builds and computes `unroll`, `decode` and, weighted and summed, `aux_loss` with the
    same (random) params, frames in batches of 4 on the fast side. Tolerances: two float32 computations'
    error bounds (`float_bounds`), plus the sums over a frame's pixels and the frames for the loss."""
    cfg = dataclasses.replace(SMALL, aux="pred+attention", frame_batch=4)
    plain = PaperActorCritic(cfg)
    rng = np.random.default_rng(11)
    obs, resets = _obs(12, (T, B, *net.OBS_SHAPE)), jnp.asarray(rng.random((T, B)) < 0.3)
    carry = _normal(13, net.initial_carry(cfg, (B,)), 0.5)
    shapes = jax.eval_shape(lambda k: plain.init(k, carry, obs, resets), jax.random.key(0))
    params = _normal(14, jax.eval_shape(lambda k: net.init(k, cfg), jax.random.key(0)), 0.3)
    chex.assert_trees_all_equal_shapes_and_dtypes(shapes["params"], params)

    actions = jnp.asarray(rng.integers(0, cfg.n_actions, (T, B)), jnp.int32)
    weight = jnp.asarray(rng.random((T, B)), jnp.float32)

    @jax.jit
    def run_plain(params):
        variables = {"params": params}
        final, out = plain.apply(variables, carry, obs, resets)
        decoded = plain.apply(variables, out.hidden, actions, method=plain.decode)
        errors = plain.apply(variables, out.hidden, actions, obs, method=plain.frame_errors)
        return final, out, decoded, jnp.sum(weight * errors)

    @jax.jit
    def run_fast(params):
        final, out = net.unroll(params, cfg, carry, obs, resets)
        loss = net.aux_loss(params, cfg, out.hidden, actions, obs, weight)
        return final, out, net.decode(params, cfg, out.hidden, actions), loss

    (*plain_out, plain_loss), (*fast_out, fast_loss) = run_plain(params), run_fast(params)
    outputs = network_error(cfg, T) + network_error(dataclasses.replace(cfg, conv_impl="xla"), T)
    assert_trees_within(plain_out, fast_out, outputs)
    pixels = gamma(math.prod(net.OBS_SHAPE)) + gamma(T * B)
    np.testing.assert_allclose(plain_loss, fast_loss, rtol=outputs + 2 * pixels)
    assert float(jnp.abs(plain_out[2]).max()) > 0.1  # the decoder output is not trivially zero


def test_the_paper_network_draws_the_documented_distributions():
    """``PaperActorCritic.init``: orthogonal dense weights with their gains, zero dense biases, convs uniform
    within PyTorch's bound; symbolic views are refused."""
    args = (net.initial_carry(SMALL, (B,)), _obs(15, (T, B, *net.OBS_SHAPE)), jnp.zeros((T, B), bool))
    params = jax.jit(PaperActorCritic(SMALL).init)(jax.random.key(3), *args)["params"]
    fc = np.asarray(params["fc"]["kernel"])
    np.testing.assert_allclose(fc.T @ fc, 2 * np.eye(SMALL.hidden), atol=1e-5)
    assert not np.any(params["value"]["out"]["bias"]) and not np.any(params["lstm"]["b"])
    for layer, fan_in in (("conv1", 3 * 9), ("deconv3", SMALL.conv_channels[0])):  # deconv3: stride 3
        bound = 1 / np.sqrt(fan_in)
        assert 0.5 * bound < np.abs(params[layer]["kernel"]).max() <= bound
    symbolic = PaperActorCritic(net.NetworkConfig(obs="symbolic"))
    with pytest.raises(ValueError, match="pixel views"):
        symbolic.init(jax.random.key(0), *args)


# The params tree of the pre-Flax network (commit 3f6e052) for SMALL, written out so that a change of layout
# shows here: exported policies and checkpoints of earlier runs hold exactly this tree.
PRE_FLAX_SMALL_LAYOUT = {
    "conv1": {"kernel": (3, 3, 3, 4), "bias": (4,)},
    "conv2": {"kernel": (3, 3, 4, 6), "bias": (6,)},
    "conv3": {"kernel": (3, 3, 6, 5), "bias": (5,)},
    "fc": {"kernel": (45, 8), "bias": (8,)},
    "lstm": {"wi": (8, 32), "wh": (8, 32), "b": (32,)},
    **{
        head: {
            "dense0": {"kernel": (8, 6), "bias": (6,)},
            "dense1": {"kernel": (6, 6), "bias": (6,)},
            "out": {"kernel": (6, n_out), "bias": (n_out,)},
        }
        for head, n_out in (("policy", 7), ("value", 1))
    },
    "aux_fc": {"kernel": (15, 45), "bias": (45,)},
    "deconv1": {"kernel": (3, 3, 5, 6), "bias": (6,)},
    "deconv2": {"kernel": (3, 3, 6, 4), "bias": (4,)},
    "deconv3": {"kernel": (3, 3, 4, 3), "bias": (3,)},
}


def test_pre_flax_policy_exports_load(tmp_path):
    """A policy exported with the pre-Flax params tree loads unchanged (the tree is the same); one with other
    tree fails with `CheckpointMismatchError` naming the entries that differ."""
    is_shape = lambda x: isinstance(x, tuple) and all(isinstance(d, int) for d in x)  # noqa: E731
    stored = _normal(11, jax.tree.map(np.zeros, PRE_FLAX_SMALL_LAYOUT, is_leaf=is_shape))
    stacked = jax.tree.map(lambda x: x[None], stored)
    policy_io.export_policy(tmp_path / "old", 0, stacked, SMALL)
    chex.assert_trees_all_close(policy_io.load_policy(str(tmp_path / "old"), SMALL), stored)

    nested = {"encoder": {k: stacked.pop(k) for k in ("conv1", "conv2", "conv3", "fc")}, **stacked}
    policy_io.export_policy(tmp_path / "nested", 0, nested, SMALL)
    with pytest.raises(checkpoint.CheckpointMismatchError, match="conv1"):
        policy_io.load_policy(str(tmp_path / "nested"), SMALL)
