"""The follow-ups of a design's learned seeds (`jaxsocial.experiments.followup`), end to end at the tiny
scale: which seeds count as learned, the branches' configs (the source's checkpoint, the same seed, social
against 75% solo), the evaluations, the records and the summary read back from them."""

import dataclasses

import jax
import numpy as np
import pytest

from jaxsocial import train
from jaxsocial.experiments.analyse import followup_results, kinds, plot_figures, records
from jaxsocial.experiments.launch import followup_runs
from jaxsocial.experiments.plan import designs, followup_plan, recipes
from jaxsocial.run import checkpoint, jsonio, metrics, provenance, rundir

pytestmark = pytest.mark.slow

CONDITION = "social_rec"


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """A tiny 'design' whose every finished seed has learned (threshold below any return), and one trained
    seed of it: (plan, runs root, source seed directory)."""
    runs = tmp_path_factory.mktemp("design")
    design = dataclasses.replace(
        designs.load("h1_laptop"), scale="tiny", iterations=recipes.TINY.iterations, seed=0, seeds=1,
        learned_threshold=-1e9,
    )  # fmt: skip
    plan = followup_plan.Plan(recipes.RECIPES["h1_laptop"], recipes.TINY, design, episodes=4)
    source = train.run(recipes.condition_config(recipes.TINY, CONDITION, 0, 1, str(runs)))
    return plan, runs, source


def test_follow_ups_branch_evaluate_record_and_summarise(tiny, tmp_path):
    plan, runs, source = tiny
    found = followup_runs.sources(plan, str(runs))
    assert found == [followup_plan.Source(CONDITION, 0, source)]  # the other conditions have no seed
    out, recs = tmp_path / "runs", tmp_path / "records"
    cores = (provenance.visible_cores() or [0])[:2]  # both branches at once where two cores are seen
    assert followup_runs.run(plan, str(runs), str(out), cores, "test command") == [0, 0]
    for arm, solo_prob in followup_plan.ARMS.items():
        branch = plan.root(out) / f"{CONDITION}-s0-{arm}"
        config = rundir.read_config(branch)
        assert config["init_from"] == f"{source}@{recipes.TINY.iterations}" and config["seed"] == 0
        # beside the experts, whatever the source's condition
        assert config["env"] == followup_plan.BRANCH_ENV
        assert dict(pair.split("=") for pair in config["env_args"].split(","))["solo_prob"] == repr(solo_prob)
        rows = rundir.read_metrics(branch)
        assert len(rows) == plan.branch_iterations == 1
        assert config["eval_episodes"] == plan.episodes
        assert set(metrics.eval_keys([rows])) == {
            metrics.eval_key(s) for s in followup_plan.branch_specs(plan.scale)
        }
    evals = plan.root(out) / f"{CONDITION}-s0"
    for spec in followup_plan.zero_shot_specs(plan.scale):
        result = jsonio.read_json(kinds.eval_path(evals, spec))
        assert result["checkpoints"] == [str(source)] and result["episodes_per_checkpoint"] == plan.episodes
    assert jsonio.read_json(kinds.ct_path(evals, plan.scale))["protocol"] == "ct"
    assert jsonio.read_json(evals / provenance.RUN_FILE)["command"] == "test command"
    assert followup_runs.run(plan, str(runs), str(out), [0], "again") == []  # everything done is kept
    assert jsonio.read_json(evals / provenance.RUN_FILE)["command"] == "test command"

    recorded = followup_runs.record(plan, str(out), str(recs), None)
    assert sorted(d.name for d in recorded) == [
        f"{CONDITION}-s0",
        f"{CONDITION}-s0-mixed",
        f"{CONDITION}-s0-social",
    ]
    evaluations = jsonio.read_json(plan.root(recs) / f"{CONDITION}-s0" / records.PROVENANCE_FILE)["run"]
    assert evaluations["jax"] == jax.__version__  # what the process that played them ran with
    assert evaluations["device"] == jsonio.read_json(evals / provenance.RUN_FILE)["cpu"]
    assert followup_runs.record(plan, str(out), str(recs), "a CPU") == []
    summary = followup_results.summarise(plan, str(recs))
    seed = summary["seeds"][f"{CONDITION}-s0"]
    assert seed["source"] == str(source)
    for arm in followup_plan.ARMS:
        rows = rundir.read_metrics(plan.root(recs) / f"{CONDITION}-s0-{arm}")
        for spec in followup_plan.branch_specs(plan.scale):
            assert seed["branches"][arm][spec] == rows[-1][metrics.eval_key(spec)]
    spec = followup_plan.zero_shot_specs(plan.scale)[1]  # 4-goal Goal Cycle, beside the experts
    result = jsonio.read_json(kinds.eval_path(evals, spec))
    assert seed["zero_shot"][spec] == {
        "learner": result["results"][0]["mean_return"],
        "experts": float(np.mean([r["mean_return"] for r in result["results"][1:]])),
    }
    paired = summary["mixing"][followup_plan.branch_specs(plan.scale)[0]]["mixed_minus_social"]
    assert paired["n"] == 1 and paired["wilcoxon_p"] is None
    assert seed["condition"] == CONDITION
    assert summary["conditions"] == {CONDITION: {"seeds": 1, **followup_results.measures([seed], plan.scale)}}
    assert summary["zero_shot"] == summary["conditions"][CONDITION]["zero_shot"]  # one condition: the same
    plot_figures.draw_followup(summary, tmp_path / "f.png", tuple(followup_plan.ARMS), kinds.CT_SCORES)
    assert (tmp_path / "f.png").stat().st_size > 1000


def test_a_learned_seed_without_its_final_checkpoint_is_refused(tiny, tmp_path):
    plan, runs, source = tiny
    record = tmp_path / source.relative_to(runs)
    records.pack(source, record, dict.fromkeys(provenance.RUN_FIELDS), "tiny")
    assert checkpoint.all_steps(record / "checkpoints") == []
    with pytest.raises(FileNotFoundError, match="--final-checkpoint learned"):
        followup_runs.sources(plan, str(tmp_path))
    above = dataclasses.replace(plan, design=dataclasses.replace(plan.design, learned_threshold=1e9))
    assert followup_runs.sources(above, str(tmp_path)) == []  # a seed that did not learn needs none
