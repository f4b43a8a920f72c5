"""The training driver's steps on their own, without compiling: chunk planning, checkpoint and evaluation
cadence, the non-finite checks of a chunk, the stage switch on the seeds' returns, and the write-rows step."""

import dataclasses

import numpy as np
import pytest
from conftest import TINY

from jaxsocial.run import loggers, metrics, nonfinite, outputs, rundir, schedule, startup
from jaxsocial.run.chunks import Check, Chunk, check_chunk, checkpoint_due, evaluates, plan_chunk, pool_seeds
from jaxsocial.run.driver import Driver


def planned(cfg, stages=()):
    """(first iteration, iterations, stage) of each chunk the loop plans, no stage triggered by a return."""
    it, stage, chunks = 0, schedule.initial_index(stages), []
    while it < cfg.iterations:
        n = plan_chunk(cfg.driver, cfg.chunk_iterations, stages, stage, it)
        chunks.append((it, n, stage))
        it += n
        stage = schedule.advance(stages, stage, it, None)
    return chunks


def test_chunks_are_chunk_iterations_long_but_the_last():
    cfg = dataclasses.replace(TINY, iterations=25, chunk_iterations=10)
    assert planned(cfg) == [(0, 10, -1), (10, 10, -1), (20, 5, -1)]


def test_chunks_end_where_iteration_stages_start():
    cfg = dataclasses.replace(TINY, iterations=12, chunk_iterations=4)
    assert planned(cfg, schedule.parse_stages("0:penalty=0.5;5:penalty=1.0")) == [
        (0, 4, 0), (4, 1, 0), (5, 4, 1), (9, 3, 1),
    ]  # fmt: skip
    assert planned(cfg, schedule.parse_stages("3:penalty=1.0")) == [
        (0, 3, -1),
        (3, 4, 0),
        (7, 4, 0),
        (11, 1, 0),
    ]
    returns = schedule.parse_stages("return>=5:penalty=1.0")  # no iteration to land on
    assert plan_chunk(cfg.driver, cfg.chunk_iterations, returns, -1, 0) == 4
    passed = schedule.parse_stages("3:penalty=1.0")  # a start already passed
    assert plan_chunk(cfg.driver, cfg.chunk_iterations, passed, -1, 5) == 4


def test_chunks_end_on_evaluation_iterations():
    cfg = dataclasses.replace(
        TINY, iterations=10, chunk_iterations=3, eval_envs=("goalcycle3",), eval_every=4
    )
    assert [(it, n) for it, n, _ in planned(cfg)] == [(0, 3), (3, 1), (4, 3), (7, 1), (8, 2)]
    assert [evaluates(cfg.driver, end) for end in (3, 4, 7, 8, 10)] == [
        False,
        True,
        False,
        True,
        True,
    ]  # and the last
    assert not evaluates(dataclasses.replace(cfg, eval_envs=()).driver, 8)


def test_checkpoints_every_checkpoint_every_iterations_and_at_the_end():
    cfg = dataclasses.replace(TINY, iterations=10, checkpoint_every=4)
    last_saved, saved = 0, []
    for it in (3, 6, 9, 10):  # the ends of 3-iteration chunks
        if checkpoint_due(cfg.driver, it, last_saved):
            saved.append(it)
            last_saved = it
    assert saved == [6, 10]
    assert checkpoint_due(cfg.driver, 9, 4)  # an iteration not saved (non-finite): the next chunk's is


def flags(*iterations):
    """One learner's checks of a chunk with one quantity per iteration: bool[n, 1]."""
    return np.array([[ok] for ok in iterations])


def test_a_finite_chunk_is_kept_whole():
    assert check_chunk({"params": flags(True, True, True)}, (0,), 1, "stop") == Check(
        None, False, 3, [], True
    )


@pytest.mark.parametrize("on_nonfinite", ["stop", "warn"])
def test_a_non_finite_iteration_stops_the_chunk_or_is_marked(on_nonfinite):
    finite = {"policy_loss": flags(True, False, True, False), "params": flags(True, True, True, False)}
    check = check_chunk(finite, (0,), 1, on_nonfinite)
    assert check.failure == nonfinite.Failure(offset=1, seed=0, by_slot={0: ["policy_loss"]})
    assert not check.healthy_end  # the last iteration is non-finite: neither saved nor evaluated
    if on_nonfinite == "stop":
        assert (check.stop, check.kept, check.failed) == (True, 2, [1])  # rows up to the failure
    else:
        assert (check.stop, check.kept, check.failed) == (False, 4, [1, 3])


def test_an_iteration_non_finite_in_any_seed_counts():
    finite = {"params": np.array([flags(True, True, False), flags(False, True, True)])}  # bool[K, n, S_l]
    check = check_chunk(finite, (0,), 2, "warn")
    assert (check.failure.offset, check.failure.seed, check.failed, check.healthy_end) == (
        0,
        1,
        [0, 2],
        False,
    )


def chunk_metrics(returns, episodes):
    """Metrics of a chunk with TINY's three slots: every slot's return and episodes as given."""
    returns, episodes = np.asarray(returns, float), np.asarray(episodes)
    return {"return": np.repeat(returns[..., None], 3, -1), "episodes": np.repeat(episodes[..., None], 3, -1)}


def test_a_stage_starts_at_its_iteration_or_once_the_learners_return_reaches_it():
    cfg = dataclasses.replace(TINY, iterations=8, stages="2:penalty=0.5;return>=5:penalty=1.0")
    static = startup.setup(cfg)
    driver = Driver(cfg.program, cfg.driver, static, None, [], "", None, stage=-1, frozen=None, it=2)
    driver.switch_stage(None)  # iteration 2, whatever the return
    assert driver.stage == 0
    low = chunk_metrics([4.0, 9.0], [1, 0])  # the second episode did not finish
    driver.switch_stage(metrics.learner_return(low, static.pop))
    assert driver.stage == 0
    met = chunk_metrics([4.0, 7.0], [1, 2])  # (4 + 2 * 7) / 3 episodes = 6
    driver.switch_stage(metrics.learner_return(met, static.pop))
    assert driver.stage == 1
    driver.switch_stage(99.0)  # no later stage
    assert driver.stage == 1


def test_pooled_seeds_read_as_one_seeds_iterations():
    metrics = chunk_metrics([[4.0, 0.0], [0.0, 7.0]], [[1, 0], [0, 2]])  # [K=2, n=2, slots]
    pooled = pool_seeds(metrics, 2)
    assert pooled["return"][:, 0].tolist() == [4.0, 0.0, 0.0, 7.0] and pooled["episodes"].shape == (4, 3)
    assert pool_seeds(metrics, 1) is metrics


def test_write_rows_keeps_rows_and_warns_at_the_first_non_finite_iteration(tmp_path, capsys):
    cfg = dataclasses.replace(TINY, iterations=6, on_nonfinite="warn")
    static = startup.setup(cfg)
    metrics_log = rundir.MetricsLog(tmp_path)
    out = outputs.Outputs(
        cfg,
        static,
        outputs.seed_runs(cfg, tmp_path),
        "x",
        [metrics_log],
        [loggers.make_logger(None, tmp_path, {})],
    )
    losses = {"policy_loss": np.zeros((3, 1))}
    for first, finite, compile_s in [
        (0, flags(True, False, True), 1.234),
        (3, flags(False, True, True), None),
    ]:
        chunk = Chunk(first, 3, 0, {**chunk_metrics([1.0] * 3, [1] * 3), **losses}, {"params": finite}, 99.6)
        out.write_rows(chunk, check_chunk(chunk.finite, static.pop.learners, 1, "warn"), compile_s, None)
    rows = metrics_log.read()
    assert [row["iteration"] for row in rows] == [1, 2, 3, 4, 5, 6]
    assert [row.get(nonfinite.ROW_KEY) for row in rows] == [
        None,
        ["params/0"],
        None,
        ["params/0"],
        None,
        None,
    ]
    assert rows[0]["compile_s"] == 1.23 and "compile_s" not in rows[3]
    assert rows[0]["env_steps_per_s"] == 100 and rows[0]["stage"] == 0 and rows[0]["policy_loss/0"] == 0.0
    assert capsys.readouterr().err.count("warning: non-finite values at iteration 2 in slot 0: params") == 1
    out.report(tmp_path, 6)
    assert "2 iterations had non-finite values (the first: 2)" in capsys.readouterr().err

    stopping = check_chunk({"params": flags(True, False, True)}, static.pop.learners, 1, "stop")
    out.write_rows(chunk._replace(first=6, finite={"params": flags(True, False, True)}), stopping, None, None)
    assert [row["iteration"] for row in metrics_log.read()[6:]] == [7, 8]  # none after the stop
    assert capsys.readouterr().err == ""  # the stop's message is the error's
