"""`--init-from RUN_DIR[@ITERATION]`: validation before anything compiles, loading the source's learners into
a fresh state (`driver.load_source_learners`), and a branched run."""

import dataclasses
import shutil

import jax
import numpy as np
import pytest
from conftest import TINY

from jaxsocial import train
from jaxsocial.agents import ppo
from jaxsocial.experiments.analyse import records
from jaxsocial.run import checkpoint, driver, init_from, jsonio, loop, policy_io, provenance, rundir, startup
from jaxsocial.specs import CheckpointRef


@pytest.fixture(scope="module")
def source(tmp_path_factory):
    """TINY trained for 4 iterations, checkpoints at 2 and 4: its run directory."""
    runs_dir = tmp_path_factory.mktemp("init-from")
    return train.run(dataclasses.replace(TINY, runs_dir=str(runs_dir), run_name="source"))


def _branch(tmp_path, spec, **changes):
    changes = {"runs_dir": str(tmp_path), "run_name": "branch", "init_from": spec, **changes}
    return dataclasses.replace(TINY, **changes)


def _seeds(cfg):
    return list(range(cfg.seed, cfg.seed + cfg.seeds))


def _check(cfg):
    init_from.check_source(cfg.init_from, _seeds(cfg), cfg.net, startup.setup(cfg).pop.learners)


def _pin(cfg, run_dir):
    return init_from.pin_iteration(cfg.init_from, _seeds(cfg), run_dir)


def test_bad_sources_are_refused_before_anything_compiles(source, tmp_path):
    with pytest.raises(FileNotFoundError, match="no directory"):
        train.run(_branch(tmp_path, str(tmp_path / "nowhere")))  # the driver checks before writing
    with pytest.raises(FileNotFoundError, match="no checkpoint of iteration 3"):
        _check(_branch(tmp_path, f"{source}@3"))
    with pytest.raises(ValueError, match="whole number"):
        _check(_branch(tmp_path, f"{source}@last"))
    with pytest.raises(FileNotFoundError, match="hold checkpoints"):
        _check(_branch(tmp_path, str(tmp_path)))
    wider = dataclasses.replace(TINY.net, hidden=TINY.net.hidden * 2)
    with pytest.raises(ValueError, match=r"network differs in \['hidden'\]"):
        _check(_branch(tmp_path, str(source), net=wider))
    with pytest.raises(ValueError, match="learners are in slots"):
        _check(_branch(tmp_path, str(source), slots="random,learner,random"))
    with pytest.raises(ValueError, match="holds the source"):
        _pin(_branch(tmp_path, str(source)), source.parent)
    assert not any(tmp_path.iterdir())  # nothing written


def test_pin_names_the_iteration_it_loads(source, tmp_path):
    latest = _pin(_branch(tmp_path, str(source)), tmp_path / "branch")
    assert latest == CheckpointRef(source, TINY.iterations)
    assert str(_pin(_branch(tmp_path, f"{source}@2"), tmp_path / "b")) == f"{source}@2"


def test_a_resumed_branch_loads_its_own_state_without_the_source(source, tmp_path):
    branch = train.run(_branch(tmp_path, str(source), iterations=2))
    moved = tmp_path / "moved-source"
    source.rename(moved)
    try:
        again = _branch(tmp_path, str(source), iterations=3, resume=True)
        assert train.run(again) == branch  # the source is gone: only a resumed run can go on
    finally:
        moved.rename(source)
    assert [r["iteration"] for r in rundir.read_metrics(branch)] == [1, 2, 3]


def test_apply_loads_the_sources_learners_and_nothing_else(source, tmp_path):
    cfg = _branch(tmp_path, f"{source}@2", seed=7)
    static = startup.setup(cfg)
    program = loop.compiled(cfg.program, loop.program_mesh(cfg.program, 0), static.stage(-1), static.pop)
    fresh = program.init(np.int32(cfg.seed))
    state = driver.load_source_learners(cfg.init_from, [cfg.seed], fresh, program)
    template = jax.eval_shape(lambda: fresh)
    saved = checkpoint.restore(source / "checkpoints", template, 2)
    for got, want in ((state.params, saved.params), (state.opt_state, saved.opt_state)):
        jax.tree.map(np.testing.assert_array_equal, got, want)
    jax.tree.map(np.testing.assert_array_equal, state.env_states, fresh.env_states)  # the new seed's own
    assert int(state.iteration) == 0
    assert driver.load_source_learners(None, [cfg.seed], fresh, program) is fresh


def _adam_count(opt_state) -> int:
    leaves = jax.tree_util.tree_flatten_with_path(opt_state)[0]
    return int(next(np.asarray(x).reshape(-1)[0] for p, x in leaves if "count" in jax.tree_util.keystr(p)))


def test_a_branched_run_continues_the_sources_learners(source, tmp_path):
    """The driver's part (`init_from.pin_iteration`, `driver.load_source_learners`): a new run directory, the
    source and iteration in its config, and the optimiser's step count going on from the source's. The
    branch has the source's config and seed, so without the source's state it would repeat the source's
    first 2 iterations and end with their count (the KL stop makes the step count per iteration vary)."""
    run_dir = train.run(_branch(tmp_path, str(source), iterations=2))
    assert rundir.read_config(run_dir)["init_from"] == f"{source}@{TINY.iterations}"
    assert [r["iteration"] for r in rundir.read_metrics(run_dir)] == [1, 2]
    twig = _branch(tmp_path, str(run_dir), run_name="twig")
    assert str(_pin(twig, tmp_path / "twig")) == f"{run_dir}@2"  # a branch of the branch
    _check(twig)
    target = jax.eval_shape(lambda: train.compiled_program(TINY).init(np.int32(0)))
    first_two = _adam_count(checkpoint.restore(source / "checkpoints", target, 2).opt_state)
    loaded = _adam_count(checkpoint.restore(source / "checkpoints", target, TINY.iterations).opt_state)
    after = _adam_count(checkpoint.restore(run_dir / "checkpoints", target, 2).opt_state)
    assert after >= loaded > first_two  # without the source's state: after == first_two


def test_a_record_with_its_final_checkpoint_is_a_branch_source(source, tmp_path):
    """`records.pack(checkpoint_reason=...)` keeps the checkpoint of the final policy's iteration and says
    why in the provenance, without orbax's notes naming where it was written, so a later sitting branches from
    the committed record as from the run; without it a record has no checkpoint to branch from."""
    run = dict.fromkeys(provenance.RUN_FIELDS)
    plain = records.pack(source, tmp_path / "plain", run, "tiny/source")
    assert jsonio.read_json(plain / records.PROVENANCE_FILE)["record"]["checkpoint_reason"] is None
    assert not (plain / "checkpoints").exists()
    reason = records.checkpoint_reason("all", 0.0, 5.0)
    record = records.pack(source, tmp_path / "record", run, "tiny/source", checkpoint_reason=reason)
    assert checkpoint.all_steps(record / "checkpoints") == [TINY.iterations]
    assert not list(record.rglob(records.ORBAX_COMMIT_NOTE))
    packed = jsonio.read_json(record / records.PROVENANCE_FILE)["record"]
    assert packed["checkpoint_iteration"] == TINY.iterations and packed["checkpoint_reason"] == reason
    cfg = _branch(tmp_path, str(record))
    _check(cfg)
    assert _pin(cfg, tmp_path / "branch") == CheckpointRef(record, TINY.iterations)
    from_record = driver.source_state(record, TINY.iterations)
    from_run = driver.source_state(source, TINY.iterations)
    jax.tree.map(np.testing.assert_array_equal, from_record.params, from_run.params)
    jax.tree.map(np.testing.assert_array_equal, from_record.opt_state, from_run.opt_state)
    partial = tmp_path / "partial"
    shutil.copytree(source, partial)
    shutil.rmtree(partial / "checkpoints" / str(TINY.iterations))
    with pytest.raises(FileNotFoundError, match="no checkpoint of its final iteration"):
        records.pack(partial, tmp_path / "p", run, "tiny/partial", checkpoint_reason=reason)


def test_a_record_without_checkpoints_gives_its_policys_params_and_a_fresh_optimiser(source, tmp_path):
    """A record that kept only its exported policy (no `--final-checkpoint`) is a params-only source: the
    new run starts from the policy's params of the iteration it names, with the optimiser state a fresh run
    has (Adam's moments zero, step 0: what `optimizer.init` gives for the loaded params too)."""
    plain = records.pack(source, tmp_path / "plain", dict.fromkeys(provenance.RUN_FIELDS), "tiny/source")
    cfg = _branch(tmp_path, str(plain), seed=7)
    _check(cfg)
    assert init_from.params_only(cfg.init_from, [7])
    assert _pin(cfg, tmp_path / "branch") == CheckpointRef(plain, TINY.iterations)
    with pytest.raises(FileNotFoundError, match=r"no checkpoint of iteration 3 \(policy exports"):
        _check(_branch(tmp_path, f"{plain}@3"))
    static = startup.setup(cfg)
    program = loop.compiled(cfg.program, loop.program_mesh(cfg.program, 0), static.stage(-1), static.pop)
    fresh = program.init(np.int32(cfg.seed))
    state = driver.load_source_learners(cfg.init_from, [cfg.seed], fresh, program)
    saved = policy_io.load_learners(plain, fresh.params)
    jax.tree.map(np.testing.assert_array_equal, state.params, saved)
    jax.tree.map(np.testing.assert_array_equal, state.opt_state, fresh.opt_state)
    restarted = jax.vmap(ppo.make_optimizer(cfg.ppo).init)(state.params)
    jax.tree.map(np.testing.assert_array_equal, state.opt_state, restarted)
    assert not jax.tree.all(jax.tree.map(np.array_equal, state.params, fresh.params))
    mixed = tmp_path / "mixed"
    shutil.copytree(source, mixed / "s7")
    shutil.copytree(plain, mixed / "s8")
    with pytest.raises(ValueError, match="some seeds hold checkpoints and some only a policy"):
        init_from.params_only(CheckpointRef(mixed), [7, 8])
    branch = train.run(dataclasses.replace(cfg, iterations=1))
    assert rundir.read_config(branch)["init_from"] == f"{plain}@{TINY.iterations}"
    assert [r["iteration"] for r in rundir.read_metrics(branch)] == [1]
