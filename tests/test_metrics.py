"""The metrics format (`jaxsocial.run.metrics`): rows written from a chunk's metrics read back as the right
curves, final returns and keys; the tools that read runs import no training or experiment code."""

import dataclasses
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from jaxsocial import stats
from jaxsocial.run import metrics, rundir


def fake_pop(labels=("learner", "expert:explorer", "expert:explorer"), learners=(0,)):
    """What the writer reads of a `population.Population`: slot labels and the learner slots."""
    return SimpleNamespace(slots=[SimpleNamespace(label=label) for label in labels], learners=learners)


def chunk(n=4):
    """A hand-built chunk of `n` iterations for 3 slots, one learner (slot 0)."""
    returns = np.array([[1.0, 10.0, 20.0], [0.0, 12.0, 0.0], [3.0, 14.0, 22.0], [5.0, 16.0, 24.0]])[:n]
    episodes = np.array([[2, 1, 1], [0, 1, 0], [1, 1, 1], [3, 1, 1]])[:n]
    return {
        "return": returns,
        "episodes": episodes,
        "aux_loss": np.arange(n, dtype=np.float64)[:, None] / 10,
        "kl": np.full((n, 1), 0.01),
    }


def test_writer_rows_and_round_trip_through_the_log(tmp_path):
    rows = metrics.metric_rows(chunk(), 10, 1234.0, fake_pop())
    assert [r["iteration"] for r in rows] == [11, 12, 13, 14]
    assert rows[0] == {
        "iteration": 11,
        "env_steps_per_s": 1234.0,
        "return/0": 1.0,
        "episodes/0": 2,
        "return/1": 10.0,
        "episodes/1": 1,
        "return/2": 20.0,
        "episodes/2": 1,
        "aux_loss/0": 0.0,
        "kl/0": 0.01,
    }
    rows[-1].update(metrics.eval_fields({"goalcycle4:width=9": 2.5}))
    rundir.MetricsLog(tmp_path).append(rows)
    back = rundir.read_metrics(tmp_path)
    assert back == rows
    assert metrics.slots(back[0]) == [0, 1, 2] and metrics.learners(back[0]) == [0]
    assert metrics.learner_metrics(back[-1]) == {"aux_loss": [0], "kl": [0]}
    assert metrics.eval_keys([back]) == ["eval/goalcycle4:width=9"]
    assert metrics.eval_spec("eval/goalcycle4:width=9") == "goalcycle4:width=9"
    assert metrics.split_key("eval/goalcycle4:width=9") == ("eval", "goalcycle4:width=9")
    assert metrics.split_key("aux_loss/0") == ("aux_loss", "0") and metrics.split_key("iteration") is None
    assert metrics.logged(back[0], "aux_loss", 0) and not metrics.logged(back[0], "aux_loss", 1)


def test_readers_give_the_right_curves():
    rows = metrics.metric_rows(chunk(), 0, 1.0, fake_pop())
    returns, episodes = metrics.slot_returns(rows, 0)
    np.testing.assert_array_equal(returns, [2.0, 0.0, 3.0, 15.0])
    np.testing.assert_array_equal(episodes, [2, 0, 1, 3])
    x, y = metrics.curve(rows, 0, points=2)  # blocks [1, 2] and [3, 4], episode-weighted
    np.testing.assert_array_equal(x, [2, 4])
    np.testing.assert_allclose(y, [2.0 / 2, 18.0 / 4])
    x, y = metrics.curve(rows, 1)  # more points than rows: one per iteration
    np.testing.assert_array_equal(x, [1, 2, 3, 4])
    np.testing.assert_allclose(y, [10, 12, 14, 16])
    assert metrics.final_return(rows, 0) == 5.0  # the last 10%: one row
    assert np.isnan(metrics.final_return(rows[1:2], 2))  # no episode ended
    x, y = metrics.metric_curve([*rows[:2], {"iteration": 3, "aux_loss/0": None}], "aux_loss/0")
    np.testing.assert_array_equal(x, [1, 2, 3])
    np.testing.assert_allclose(y, [0.0, 0.1, np.nan])
    rows[1]["eval/x"], rows[3]["eval/x"] = 1.0, 3.0
    x, y = metrics.eval_curve(rows, "eval/x")
    np.testing.assert_array_equal(x, [2, 4])
    np.testing.assert_array_equal(y, [1.0, 3.0])
    assert metrics.final_eval(rows, "eval/x") == 3.0 and np.isnan(metrics.final_eval(rows, "eval/y"))
    assert metrics.switch_iteration(rows) is None
    rows[2]["stage"] = 0
    assert metrics.switch_iteration(rows) == 3
    s = stats.summary([1.0, 2.0, 3.0, float("nan")])
    assert s["mean"] == 2.0 and s["ci95"][0] < 2.0 < s["ci95"][1] and len(s["final_returns"]) == 4
    assert stats.summary([float("nan")])["mean"] is None


def test_progress_fields_and_learner_return():
    m = chunk()
    pop = fake_pop()
    shown = metrics.progress_fields(m, 999.7, pop)
    assert list(shown) == ["env-steps/s", "return[0 learner]", "return[1 explorer]", "return[2 explorer]"]
    assert shown["env-steps/s"] == 999 and shown["return[0 learner]"] == pytest.approx(20.0 / 6)
    assert metrics.learner_return(m, pop) == pytest.approx(20.0 / 6)
    nothing = {**m, "episodes": np.zeros_like(m["episodes"])}
    assert metrics.learner_return(nothing, pop) is None
    assert metrics.progress_fields(nothing, 1.0, pop)["return[0 learner]"] == "-"
    assert metrics.progress_fields(m, 999.7, pop, returns_shown=False) == {"env-steps/s": 999}  # blind


def test_seed_dirs_as_training_writes_them(tmp_path):
    from jaxsocial.run import outputs
    from jaxsocial.run.config import TrainConfig

    for seed, seeds in ((0, 1), (3, 2)):
        cfg = dataclasses.replace(TrainConfig(), seed=seed, seeds=seeds)
        expected = [s.dir for s in outputs.seed_runs(cfg, tmp_path)]
        names = rundir.seed_dir_names(seed, seeds)
        assert [tmp_path / n if n else tmp_path for n in names] == expected
        configs = [s.config for s in outputs.seed_runs(cfg, tmp_path)]
        assert [rundir.one_seed_of_many(c) for c in configs] == [seeds > 1] * seeds


def test_plot_groups_seeds_over_the_driver_fields():
    from jaxsocial import plot
    from jaxsocial.run.config import DriverConfig

    driver = {f.name for f in dataclasses.fields(DriverConfig)}
    assert driver | {"seed", "seeds", "seed_batching"} == plot.NOT_GROUPED


def test_every_recipe_kind_is_registered():
    from jaxsocial.experiments.analyse import kinds
    from jaxsocial.experiments.plan import recipes

    for recipe in recipes.RECIPES.values():
        assert kinds.kind_of(recipe) is kinds.KINDS[recipe.kind]
    with pytest.raises(ValueError, match="unknown kind 'nope'"):
        kinds.kind_of(dataclasses.replace(recipes.RECIPES["h1"], kind="nope"))


@pytest.mark.parametrize("module", ["jaxsocial.render", "jaxsocial.plot", "jaxsocial.run.metrics"])
def test_tools_import_no_training_or_experiments(module):
    code = (
        f"import {module}, sys; bad = [m for m in sys.modules if m.startswith(('jaxsocial.experiments', "
        "'jaxsocial.train', 'jaxsocial.run.config', 'jaxsocial.run.startup', 'jaxsocial.run.loop', "
        "'jaxsocial.evaluate'))]; "
        "assert not bad, bad"
    )
    root = Path(__file__).resolve().parents[1]
    subprocess.run([sys.executable, "-c", code], check=True, cwd=root, timeout=120)


def test_config_imports_no_evaluation_code():
    code = "import jaxsocial.run.config, sys; assert 'jaxsocial.evaluate' not in sys.modules"
    root = Path(__file__).resolve().parents[1]
    subprocess.run([sys.executable, "-c", code], check=True, cwd=root, timeout=120)
