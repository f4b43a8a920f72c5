"""A diverging run stops at its first non-finite iteration, saves nothing of it and says where; with
`--on-nonfinite warn` it trains on, marking the rows and saving no non-finite checkpoint."""

import dataclasses
import json
import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import TINY

from jaxsocial import train
from jaxsocial.run import checkpoint, nonfinite, policy_io, rundir

HUGE_LR = 1e30  # one Adam step moves every param by ~1e30: the next minibatch's logits overflow


def test_check_names_each_learners_non_finite_quantities():
    params = {"w": jnp.array([[1.0, 2.0], [jnp.nan, 0.0]]), "b": jnp.zeros((2, 3))}  # learner 1's w is NaN
    opt_state = ({"mu": jnp.array([[0.0], [jnp.inf]])}, jnp.array([1, 1], jnp.int32))  # and its moment
    losses = {"policy_loss": jnp.array([jnp.nan, 0.5]), "kl": jnp.array([0.0, 0.1])}
    finite = jax.tree.map(np.asarray, nonfinite.check(losses, params, opt_state))
    assert {k: v.tolist() for k, v in finite.items()} == {
        "policy_loss": [False, True],
        "kl": [True, True],
        nonfinite.PARAMS: [True, False],
        nonfinite.OPTIMIZER: [True, False],
    }
    # A chunk of 3 iterations of 2 seeds, learners in slots 0 and 2: seed 1 fails first, at iteration 2.
    chunk = {q: np.ones((2, 3, 2), bool) for q in finite}
    chunk["kl"][1, 1, 1] = False
    chunk[nonfinite.PARAMS][0, 2, 0] = False
    assert nonfinite.failures(chunk).tolist() == [[False, False, True], [False, True, False]]
    failure = nonfinite.first_failure(chunk, (0, 2), seeds=2)
    assert (failure.offset, failure.seed, failure.by_slot) == (1, 1, {2: ["kl"]})
    assert failure.describe(11, seed=6) == "non-finite values at iteration 12 (seed 6) in slot 2: kl"
    assert nonfinite.names(jax.tree.map(lambda x: x[0], chunk), 2, (0, 2)) == ["params/0"]
    assert nonfinite.first_failure(jax.tree.map(lambda x: x[0, :2], chunk), (0, 2), seeds=1) is None


@pytest.fixture(scope="module")
def healthy(tmp_path_factory):
    """TINY trained for 2 of its 4 iterations (checkpoint and policy at 2)."""
    cfg = dataclasses.replace(TINY, runs_dir=str(tmp_path_factory.mktemp("runs")), run_name="healthy")
    return train.run(dataclasses.replace(cfg, iterations=2))


def with_lr(run_dir, lr):
    config = json.loads((run_dir / rundir.CONFIG_FILE).read_text())
    config["ppo"]["lr"] = lr
    rundir.write_config(run_dir, config)


def checkpoint_is_finite(run_dir, step):
    template = jax.eval_shape(train.compiled_program(TINY).init, np.int32(0))
    state = checkpoint.restore(run_dir / "checkpoints", template, step)
    return all(np.isfinite(x).all() for x in jax.tree.leaves(state) if jnp.issubdtype(x.dtype, jnp.inexact))


@pytest.mark.slow  # three short runs, one of them a program of its own (the learning rate is compiled in)
def test_diverging_run_stops_keeping_the_last_finite_checkpoint(healthy, tmp_path):
    """The run diverges in iteration 3 (from the checkpoint of iteration 2, with a huge learning rate):
    one error line names iteration, slot and quantity; nothing of iteration 3 is saved; its row is marked
    and no row follows; --resume (with a sane learning rate again) continues from iteration 2."""
    run_dir = tmp_path / "diverging"
    shutil.copytree(healthy, run_dir)
    with_lr(run_dir, HUGE_LR)
    with pytest.raises(SystemExit) as exc:
        train.main(["--resume", str(run_dir), "--iterations", "4"])
    message = str(exc.value.code)  # a string: the interpreter prints it and exits with status 1
    assert message.startswith("error: non-finite values at iteration 3 in slot 0: ") and "\n" not in message
    assert "loss" in message and "iteration 2's" in message, message
    assert checkpoint.all_steps(run_dir / "checkpoints") == [2]
    assert policy_io.policy_iteration(str(run_dir)) == 2 and checkpoint_is_finite(run_dir, 2)
    rows = rundir.read_metrics(run_dir)
    assert [r["iteration"] for r in rows] == [1, 2, 3]
    assert "nonfinite" not in rows[1] and any(q.endswith("loss/0") for q in rows[2]["nonfinite"])

    with_lr(run_dir, TINY.ppo.lr)
    train.main(["--resume", str(run_dir), "--iterations", "4"])
    rows = rundir.read_metrics(run_dir)
    assert [r["iteration"] for r in rows] == [1, 2, 3, 4] and not any("nonfinite" in r for r in rows)
    assert checkpoint.all_steps(run_dir / "checkpoints") == [2, 4]


def test_warn_trains_on_and_saves_nothing_non_finite(healthy, tmp_path, capsys):
    """Params of ~1e30 in the checkpoint of iteration 2 (TINY's own program: no compile of its own) overflow
    in iteration 3; with --on-nonfinite warn the run trains on to 4, marks both rows, warns once and saves
    no checkpoint or policy at 4."""
    run_dir = tmp_path / "warned"
    shutil.copytree(healthy, run_dir)
    ckpt = run_dir / "checkpoints"
    state = checkpoint.restore(ckpt, jax.eval_shape(train.compiled_program(TINY).init, np.int32(0)), 2)
    metadata = checkpoint.read_metadata(ckpt, 2)
    shutil.rmtree(ckpt / "2")
    huge = state._replace(params=jax.tree.map(lambda x: x * np.float32(1e30), state.params))
    checkpoint.save(ckpt, 2, huge, metadata=metadata)
    train.main(["--resume", str(run_dir), "--iterations", "4", "--on-nonfinite", "warn"])
    rows = rundir.read_metrics(run_dir)
    assert [r["iteration"] for r in rows] == [1, 2, 3, 4]
    assert [bool(r.get("nonfinite")) for r in rows] == [False, False, True, True]
    assert checkpoint.all_steps(ckpt) == [2] and policy_io.policy_iteration(str(run_dir)) == 2
    err = capsys.readouterr().err
    assert err.count("warning: non-finite values at iteration 3 in slot 0") == 1, err
    assert "2 iterations had non-finite values (the first: 3)" in err
