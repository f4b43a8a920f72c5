"""Tests of jaxsocial.run.checkpoint: round trips, step bookkeeping, mismatch errors, metadata."""

from typing import NamedTuple

import flax.struct
import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from jaxsocial.run import checkpoint as ckpt
from jaxsocial.run import jsonio


class Rollout(NamedTuple):
    obs: jax.Array
    done: jax.Array
    gamma: float


@flax.struct.dataclass
class TrainState:
    params: dict
    opt_state: optax.OptState
    key: jax.Array
    step: jax.Array
    name: str = flax.struct.field(pytree_node=False, default="ppo")


def make_state(hidden: int = 4, seed: int = 0):
    params = {"dense": {"w": jnp.full((3, hidden), seed + 0.5, jnp.float32), "b": jnp.zeros(hidden)}}
    return {
        "train": TrainState(
            params=params,
            opt_state=optax.adam(1e-3).init(params),
            key=jax.random.split(jax.random.key(seed), 2),
            step=jnp.int32(7 + seed),
        ),
        "rollout": Rollout(
            obs=jnp.arange(6, dtype=jnp.int32).reshape(2, 3) + seed, done=jnp.array([True, False]), gamma=0.99
        ),
        "np": np.linspace(0, 1, 5, dtype=np.float32),
        "key": jax.random.key(seed + 1),
    }


def assert_trees_equal(a, b):
    unwrap = lambda x: jax.random.key_data(x) if ckpt._is_prng_key(x) else x  # noqa: E731
    assert jax.tree_util.tree_structure(a) == jax.tree_util.tree_structure(b)
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        assert type(x) is type(y) or (isinstance(x, jax.Array) and isinstance(y, jax.Array))
        assert getattr(x, "dtype", None) == getattr(y, "dtype", None)
        np.testing.assert_array_equal(np.asarray(unwrap(x)), np.asarray(unwrap(y)))


def test_round_trip_concrete_and_abstract_targets(tmp_path):
    state = make_state()
    path = ckpt.save(tmp_path, 10, state)
    assert path == tmp_path / "10" and path.is_dir()

    restored = ckpt.restore(tmp_path, make_state(seed=1))  # concrete target with other values
    assert_trees_equal(restored, state)
    assert isinstance(restored["np"], np.ndarray) and isinstance(restored["rollout"].gamma, float)
    assert jax.dtypes.issubdtype(restored["key"].dtype, jax.dtypes.prng_key)
    # the restored key generates the same numbers as the saved one
    np.testing.assert_array_equal(
        jax.random.uniform(restored["key"], (3,)), jax.random.uniform(state["key"], (3,))
    )

    abstract = jax.eval_shape(make_state)  # ShapeDtypeStructs; python float becomes a float32 leaf
    restored = ckpt.restore(tmp_path, abstract)
    assert restored["train"].opt_state[0].mu["dense"]["w"].shape == (3, 4)
    np.testing.assert_array_equal(
        jax.random.key_data(restored["train"].key), jax.random.key_data(state["train"].key)
    )
    assert restored["rollout"].gamma.dtype == jnp.float32


def test_steps_keep_and_no_overwrite(tmp_path):
    assert ckpt.all_steps(tmp_path / "missing") == [] and ckpt.latest_step(tmp_path / "missing") is None
    state = {"x": jnp.zeros(2)}
    for step in (1, 2, 3, 4):
        ckpt.save(tmp_path, step, {"x": jnp.full(2, float(step))}, keep=2)
    assert ckpt.all_steps(tmp_path) == [3, 4] and ckpt.latest_step(tmp_path) == 4
    assert float(ckpt.restore(tmp_path, state)["x"][0]) == 4.0
    assert float(ckpt.restore(tmp_path, state, step=3)["x"][0]) == 3.0

    with pytest.raises(FileExistsError, match="already exists"):
        ckpt.save(tmp_path, 4, {"x": jnp.ones(2)})
    with pytest.raises(ValueError, match="below the latest"):
        ckpt.save(tmp_path, 2, {"x": jnp.ones(2)})
    assert float(ckpt.restore(tmp_path, state)["x"][0]) == 4.0  # untouched

    with pytest.raises(FileNotFoundError, match="step 1"):
        ckpt.restore(tmp_path, state, step=1)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        ckpt.restore(tmp_path / "missing", state)
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError, match="no checkpoint"):
        ckpt.restore(tmp_path / "empty", state)


def test_mismatch_errors_name_the_leaves(tmp_path):
    ckpt.save(tmp_path, 0, make_state(hidden=4))

    with pytest.raises(ckpt.CheckpointMismatchError) as err:  # other architecture: different shapes
        ckpt.restore(tmp_path, jax.eval_shape(lambda: make_state(hidden=8)))
    msg = str(err.value)
    assert "['train'].params['dense']['w']: expected float32[3, 8], stored float32[3, 4]" in msg
    assert "another architecture/config" in msg and "more" in msg  # 6 differing leaves, 5 shown
    assert isinstance(err.value, ValueError)

    other = make_state()
    other["extra"] = jnp.zeros(3)
    del other["np"]
    with pytest.raises(ckpt.CheckpointMismatchError) as err:  # different structure
        ckpt.restore(tmp_path, other)
    msg = str(err.value)
    assert "['extra']: expected float32[3], not in checkpoint" in msg
    assert "['np']: stored float32[5], not in target" in msg

    other = make_state()
    other["rollout"] = other["rollout"]._replace(obs=other["rollout"].obs.astype(jnp.float32))
    with pytest.raises(
        ckpt.CheckpointMismatchError, match=r"\['rollout'\]\.obs: expected float32\[2, 3\], stored int32"
    ):
        ckpt.restore(tmp_path, other)


def test_metadata_round_trip_and_edge_trees(tmp_path):
    meta = {
        "config": {"lr": 3e-4, "layers": (64, 64), "env": "goal_cycle"},
        "nan": float("nan"),
        "n": np.int64(5),
    }
    with pytest.raises(TypeError, match="plain JSON values"):
        ckpt.save(tmp_path, 5, {"a": jnp.ones(1)}, metadata=meta)  # NaN and numpy integers: not JSON
    assert ckpt.all_steps(tmp_path) == []  # refused before anything was written
    ckpt.save(tmp_path, 5, {"a": jnp.ones(1)}, metadata=jsonio.to_json(meta))
    ckpt.save(tmp_path, 6, {})  # no leaves at all
    assert ckpt.read_metadata(tmp_path, step=5) == {
        "config": {"lr": 3e-4, "layers": [64, 64], "env": "goal_cycle"},
        "nan": None,
        "n": 5,
    }
    assert ckpt.read_metadata(tmp_path) == {}
    assert ckpt.restore(tmp_path, {}) == {}
    with pytest.raises(FileNotFoundError):
        ckpt.read_metadata(tmp_path / "missing")
