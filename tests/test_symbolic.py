"""Training on symbolic views (`NetworkConfig.obs="symbolic"`): the network's shapes, the cross-entropy
auxiliary loss, a tiny end-to-end run with evaluation, and the errors when policy and environment differ."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import TINY, TINY_ENV_ARGS, TINY_SLOTS
from float_bounds import assert_trees_within, decoder_error, gamma

from jaxsocial import evaluate, train
from jaxsocial.agents import network as net
from jaxsocial.run import policy_io, rundir

SMALL = net.NetworkConfig(conv_channels=(4, 6, 5), hidden=8, mlp=6, aux="pred", obs="symbolic")
T, B = 3, 2
SYMBOLIC_ARGS = f"{TINY_ENV_ARGS},observation=symbolic"
SYMBOLIC = dataclasses.replace(
    TINY,
    env_args=SYMBOLIC_ARGS,
    net=dataclasses.replace(TINY.net, obs="symbolic", aux="pred+attention"),  # both auxiliary heads
)
"""TINY on symbolic views."""

init = jax.jit(net.init, static_argnums=1)
unroll = jax.jit(net.unroll, static_argnums=1)
decode = jax.jit(net.decode, static_argnums=1)


def _views(seed, shape):
    """Random symbolic views int8[*shape, 7, 7, 4] within each channel's range (`observe.symbolic`)."""
    rng = np.random.default_rng(seed)
    low = -np.asarray(net.SYMBOLIC_SHIFT)
    high = low + np.asarray(net.SYMBOLIC_CLASSES)
    views = rng.integers(low, high, (*shape, 7, 7, 4))
    views[..., 1] = np.where(rng.random((*shape, 7, 7)) < 0.7, 0, views[..., 1])  # most cells: no agent
    return jnp.asarray(views, jnp.int8)


@pytest.fixture(scope="module")
def params():
    return init(jax.random.key(0), SMALL)


def test_symbolic_network_shapes_and_dtypes(params):
    assert {"embed", "cell_logits"} <= set(params) and not {"conv1", "deconv3"} & set(params)
    assert params["embed"]["kernel"].shape == (net.SYMBOLIC_VOCAB, 4)
    assert SMALL.feature_shape == (3, 3, 5) and SMALL.obs_shape == (7, 7, 4)
    _, out = unroll(params, SMALL, net.initial_carry(SMALL, (B,)), _views(0, (T, B)), jnp.zeros((T, B), bool))
    assert out.logits.shape == (T, B, 7) and out.value.shape == (T, B) and out.hidden.shape == (T, B, 8)
    assert all(x.dtype == jnp.float32 and np.isfinite(x).all() for x in out)
    logits = decode(params, SMALL, out.hidden, jnp.zeros((T, B), jnp.int32))
    assert logits.shape == (T, B, 7, 7, net.PREDICTED_VOCAB) and logits.dtype == jnp.float32
    with pytest.raises(AssertionError):  # RGB frames are not symbolic views
        net.unroll(params, SMALL, net.initial_carry(SMALL, (B,)), jnp.zeros((1, B, 21, 21, 3), jnp.uint8),
                   jnp.zeros((1, B), bool))  # fmt: skip


def _hand_cross_entropy(logits: np.ndarray, target: np.ndarray) -> np.ndarray:
    """f32[N]: per view, the mean over 4 channels x 49 cells of -log softmax(target class) (colour levels
    in bins of 8), heading and colour only where an agent is drawn, computed cell by cell."""
    n = target.shape[0]
    out = np.zeros(n)
    for i in range(n):
        for r in range(7):
            for c in range(7):
                for k in range(4):
                    if k >= 2 and target[i, r, c, 1] == 0:
                        continue
                    lo = net.offsets(net.PREDICTED_CLASSES)[k]
                    z = logits[i, r, c, lo : lo + net.PREDICTED_CLASSES[k]].astype(np.float64)
                    log_p = z - np.log(np.exp(z - z.max()).sum()) - z.max()
                    value = target[i, r, c, k] + net.SYMBOLIC_SHIFT[k]
                    out[i] -= log_p[value // 8 if k == 3 else value]
    return out / (4 * 49)


def test_symbolic_aux_loss_is_the_masked_cross_entropy(params):
    rng = np.random.default_rng(1)
    hidden = jnp.asarray(rng.normal(size=(3, 8)), jnp.float32)
    action = jnp.asarray([0, 3, 6], jnp.int32)
    target = _views(2, (3,))
    weight = jnp.asarray([0.5, 0.25, 0.0], jnp.float32)
    logits = np.asarray(decode(params, SMALL, hidden, action))
    expected = float(np.sum(np.asarray(weight) * _hand_cross_entropy(logits, np.asarray(target))))
    loss = jax.jit(net.aux_loss, static_argnums=1)(params, SMALL, hidden, action, target, weight)
    # float32 error (`float_bounds`): the logits of two decoder computations (the fused loss runs its own),
    # moving each log-likelihood by at most twice a logit's error (logits of order 1 at initialisation, no
    # cancellation), then a log-sum-exp over a channel's classes, the subtraction, the sums over channels and
    # cells and the weighted sum over views, all of positive terms.
    sums = max(net.PREDICTED_CLASSES) + 1 + len(net.PREDICTED_CLASSES) + 49 + len(weight)
    np.testing.assert_allclose(float(loss), expected, rtol=4 * decoder_error(SMALL) + gamma(sums))
    # The fused gradient (custom VJP) equals the gradient of the loss written with `decode`.
    grad = jax.jit(jax.grad(net.aux_loss, argnums=(0, 2)), static_argnums=1)
    fused = grad(params, SMALL, hidden, action, target, weight)

    def plain(p, h):
        logits = net.decode(p, SMALL, h, action)
        errors = net.symbolic_errors(logits.transpose(1, 2, 0, 3), target.transpose(1, 2, 0, 3))
        return jnp.sum(weight * errors)

    reference = jax.jit(jax.grad(plain, argnums=(0, 1)))(params, hidden)
    reference = ({k: reference[0][k] for k in SMALL.decoder_params}, reference[1])
    fused = ({k: fused[0][k] for k in SMALL.decoder_params}, fused[1])
    # Two float32 computations of the decoder and the loss, forward and back (`float_bounds`).
    assert_trees_within(fused, reference, 4 * (decoder_error(SMALL) + gamma(sums)))


@pytest.fixture(scope="module")
def symbolic_run(tmp_path_factory):
    runs_dir = tmp_path_factory.mktemp("runs")
    return train.run(dataclasses.replace(SYMBOLIC, runs_dir=str(runs_dir), run_name="sym")), runs_dir


def test_tiny_symbolic_run_trains_saves_and_evaluates(symbolic_run):
    run_dir, _ = symbolic_run
    rows = rundir.read_metrics(run_dir)
    assert [r["iteration"] for r in rows] == [1, 2, 3, 4]
    for key in ("aux_loss/0", "attention_loss/0", "value_loss/0", "policy_loss/0"):
        assert all(np.isfinite(r[key]) for r in rows), key
    assert policy_io.saved_net(str(run_dir)).obs == "symbolic"
    params = policy_io.load_policy(str(run_dir), SYMBOLIC.net)
    assert params["embed"]["kernel"].shape == (net.SYMBOLIC_VOCAB, 4)
    result = evaluate.evaluate(
        evaluate.EvalConfig(ckpt=(str(run_dir),), env_args=SYMBOLIC_ARGS, slots=TINY_SLOTS, episodes=2)
    )
    assert result  # played


def test_cli_takes_the_network_observations_from_the_environment():
    cfg = train.parse_args(["--env-args", "observation=symbolic"])
    assert cfg.net.obs == "symbolic"
    assert train.parse_args([]).net.obs == "rgb"
    assert train.parse_args(["--env-args", "observation=symbolic", "--net.obs", "rgb"]).net.obs == "rgb"


def test_rgb_network_on_symbolic_views_is_refused_before_compiling(tmp_path):
    with pytest.raises(ValueError, match="'symbolic' observations, but the network takes 'rgb'"):
        train.run(dataclasses.replace(TINY, env_args=SYMBOLIC_ARGS, runs_dir=str(tmp_path)))
    assert not any(tmp_path.iterdir())


def test_policy_of_the_other_observation_kind_is_refused(symbolic_run, tmp_path):
    run_dir, _ = symbolic_run
    with pytest.raises(ValueError, match="'rgb' observations, but the network takes 'symbolic'"):
        evaluate.evaluate(evaluate.EvalConfig(ckpt=(str(run_dir),), env_args=TINY_ENV_ARGS, slots=TINY_SLOTS))
    frozen = dataclasses.replace(TINY, slots=f"learner,frozen:{run_dir},random", runs_dir=str(tmp_path))
    with pytest.raises(ValueError, match="another architecture"):
        train.run(frozen)
