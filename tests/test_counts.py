"""Learned-seed statistics: the exact count tests and their power, time to learning, and pre-registered
designs (their power, their seeds, their commit before the runs')."""

import dataclasses
import json
import math
import types

import numpy as np
import pytest
from conftest import needs_records

from jaxsocial import stats
from jaxsocial.experiments import __main__ as cli
from jaxsocial.experiments.analyse import (
    design_results,
    kinds,
    power,
    summaries,
    takeoff,
    takeoff_power,
    verdicts,
)
from jaxsocial.experiments.launch import pinned
from jaxsocial.experiments.plan import catalogue, commits, designs, paths, prereg, recipes
from jaxsocial.run import config, jsonio, rundir


def test_boschloo_most_extreme_table_has_a_closed_form():
    """When the observed table is the only most extreme one (every seed of a learned, none of b), the tail is
    p^n_a (1 - p)^n_b, largest at p = n_a / (n_a + n_b)."""
    for n_a, n_b in ((6, 6), (8, 8), (4, 7)):
        p = n_a / (n_a + n_b)
        assert stats.boschloo(n_a, n_a, 0, n_b) == pytest.approx(p**n_a * (1 - p) ** n_b, rel=1e-9)


def test_boschloo_is_never_above_fisher():
    for table in ((3, 12, 0, 9), (2, 6, 0, 6), (5, 20, 1, 20), (0, 4, 0, 4), (2, 3, 1, 3)):
        assert stats.boschloo(*table) <= stats.fisher(*table) * (1 + 1e-9)
    assert stats.boschloo(0, 5, 0, 5) == 1.0  # no evidence


def test_fisher_exact_by_hand():
    # one-sided: 2 of 6 against 0 of 6, the learned pair lands in a's 6 seeds in C(6,2) of the C(12,2) ways
    assert stats.fisher(2, 6, 0, 6) == pytest.approx(math.comb(6, 2) / math.comb(12, 2))
    assert stats.fisher(6, 6, 0, 6) == pytest.approx(1 / math.comb(12, 6))
    assert stats.fisher(0, 3, 0, 3) == 1.0  # nothing learned: no evidence
    # one-sided tail: 2 of 3 against 1 of 3 sums P(2 in a) + P(3 in a) = (9 + 1) / 20
    assert stats.fisher(2, 3, 1, 3) == pytest.approx(0.5)
    # two-sided: 3 of 3 against 0 of 3 and its mirror, each 1 / C(6,3)
    assert stats.fisher(3, 3, 0, 3, "two-sided") == pytest.approx(2 / math.comb(6, 3))


def test_holm_adjusts_step_down():
    # sorted 0.01, 0.03, 0.04 -> 3 x 0.01, 2 x 0.03, then max(0.06, 1 x 0.04)
    adjusted = stats.holm({"a": 0.01, "b": 0.04, "c": 0.03})
    assert adjusted == pytest.approx({"a": 0.03, "b": 0.06, "c": 0.06})
    assert stats.holm({"a": 0.6, "b": 0.7}) == {"a": 1.0, "b": 1.0}  # capped at 1
    assert stats.holm({}) == {}


def test_power():
    for test in stats.TESTS:  # exact tests hold their level whatever the common rate
        for rate in (0.1, 0.5, 0.9):
            assert stats.power(test, 6, rate, 6, rate, 0.05) <= 0.05
    # every a seed learns, no b seed does: power 1 exactly when that table is significant
    assert stats.power("fisher-greater", 4, 1.0, 4, 0.0, 0.05) == float(1 / math.comb(8, 4) <= 0.05)
    # with b never learning, Fisher rejects 8 vs 8 from 4 learned seeds (70/1820 < 0.05, 56/560 > 0.05)
    rate = 0.6
    at_least_4 = sum(math.comb(8, k) * rate**k * (1 - rate) ** (8 - k) for k in range(4, 9))
    assert stats.power("fisher-greater", 8, rate, 8, 0.0, 0.05) == pytest.approx(at_least_4)
    assert stats.learned_by(0.0074, 39e6) == pytest.approx(1 - math.exp(-0.0074 * 39))


def test_takeoff_and_the_fraction_learned():
    iterations = np.array([10, 20, 30, 40], np.float64)
    assert takeoff.takeoff(iterations, np.array([0.5, 1.9, 2.5, 1.0]), 2.0) == 30
    assert takeoff.takeoff(iterations, np.array([0.5, 1.9, 2.0, 1.0]), 2.0) is None  # not above
    fraction = stats.fraction_learned([30, None, 10, None], np.array([0, 10, 29, 30, 1000]))
    np.testing.assert_array_equal(fraction, [0, 0.25, 0.25, 0.5, 0.5])


DESIGNED = sorted(r.name for r in recipes.RECIPES.values() if r.design)
COUNT_DESIGNS = [name for name in DESIGNED if designs.load(recipes.RECIPES[name].design).analysis == "counts"]
TAKEOFF_DESIGNS = [
    name for name in DESIGNED if designs.load(recipes.RECIPES[name].design).analysis == "takeoff"
]
ZERO_SHOT_DESIGNS = [
    name for name in DESIGNED if designs.load(recipes.RECIPES[name].design).analysis == "zero_shot"
]
LARGE_ARMS = 20
"""Count designs with more seeds an arm are tested in the slow suite only: Boschloo's p-value of each of the
(n + 1)^2 tables is a scipy optimisation, 1,681 of them at pred8's 40 seeds an arm."""


@pytest.mark.parametrize(
    "name",
    [
        pytest.param(name, marks=pytest.mark.slow)
        if max(designs.load(recipes.RECIPES[name].design).arm_seeds.values()) > LARGE_ARMS
        else name
        for name in COUNT_DESIGNS
    ],
)
def test_the_committed_design_has_the_power_it_states(name, capsys):
    """The stored power recomputed exactly, and printed by `power` (which sums over the same tables again:
    `stats.rejection_region` computes them once a process)."""
    recipe = recipes.RECIPES[name]
    design = designs.load(recipe.design)
    scale = prereg.recipe_scale(recipe, recipes.SCALES[design.scale])
    assert scale.iterations == design.iterations and scale.runs_subdir == f"prereg-{design.name}"

    assert prereg.recipe_scale(recipe, recipes.TINY) == recipes.TINY  # the budget is the design scale's
    assert set(design.trained_conditions) == set(recipe.conditions)  # a borrowed arm is not trained again
    assert design.seed >= 100 and design.training_commit is None  # fresh seeds; runs follow the design
    cfg = recipes.condition_config(scale, recipe.conditions[0], design.seed, design.seeds, "r")
    assert prereg.power_of(design, scale.iterations * cfg.num_envs * cfg.rollout_steps) == pytest.approx(
        design.power, abs=5e-4
    )  # stored to 3 decimals
    assert design.power >= 0.8
    cli.main(["power", name])
    assert f"power: {design.power:.3f}" in capsys.readouterr().out


def test_the_takeoff_design_states_its_tests_budget_and_evaluations():
    design = designs.load("experts")
    assert design.analysis == "takeoff" and design.test == prereg.TAKEOFF_TEST
    assert set(design.tests["primary"]) == {"takeoff", "goalcycle4"}
    assert set(design.tests["secondary"]) == {"solo3", "ct", "counts"}
    assert design.seed >= 300 and design.seeds == 40 and design.eval_episodes >= 128
    scale = prereg.recipe_scale(recipes.RECIPES["experts"], recipes.LAPTOP)
    assert scale.eval_episodes == design.eval_episodes and scale.iterations == design.iterations
    assert design.iterations % takeoff.window_iterations(8192) == 0  # whole takeoff windows to the budget
    planning = f"{design.seeds} seeds, discount {design.power_simulation['planning_discount']:g}"
    assert design.power == round(design.power_simulation["power"][planning]["takeoff"], 3)


@pytest.mark.slow
@pytest.mark.parametrize("name", TAKEOFF_DESIGNS)
@needs_records(*(f"records/laptop/prereg-{d}" for d in takeoff_power.EVIDENCE_DESIGNS))
def test_the_takeoff_design_has_the_power_it_states(name, capsys):
    """The stored power re-simulated from the committed evidence with fewer simulated designs: within the
    two estimates' Monte Carlo error (4 standard errors)."""
    design = designs.load(recipes.RECIPES[name].design)
    planning = design.power_simulation["planning_discount"]
    reps = 300
    table = takeoff_power.takeoff_power_table(
        dataclasses.replace(design, power_simulation={}), paths.RECORDS, 8192, reps
    )
    again = table["power"][f"{design.seeds} seeds, discount {planning:g}"]
    stored = design.power_simulation["power"][f"{design.seeds} seeds, discount {planning:g}"]
    for test in ("takeoff", "goalcycle4"):
        p = stored[test]
        se = math.sqrt(p * (1 - p) / reps + p * (1 - p) / design.power_simulation["reps"])
        assert abs(again[test] - p) <= 4 * se + 1e-9
    cli.main(["power", name])
    assert f"power: {design.power:.3f}" in capsys.readouterr().out


@pytest.mark.parametrize("name", ZERO_SHOT_DESIGNS)
def test_the_zero_shot_design_has_the_power_it_states(name, capsys):
    """Every stated power re-simulated exactly (`power.zero_shot_power`), and printed by `power`."""
    design = designs.load(recipes.RECIPES[name].design)
    sim = design.power_simulation
    n = design.arm_seeds
    for case, stated in sim["power"].items():
        p_above = float(case.removeprefix("P "))
        assert power.zero_shot_power(n["treatment"], n["control"], p_above, design.alpha) == stated
    assert design.power == sim["power"][f"P {sim['assumed_p_social_above_cloner']:g}"]
    cli.main(["power", name])
    assert f"power: {design.power:.3f}" in capsys.readouterr().out


@pytest.mark.parametrize("name", DESIGNED)
def test_a_design_fixes_its_seeds(name, tmp_path, capsys):
    recipe = recipes.RECIPES[name]
    design = designs.load(recipe.design)
    with pytest.raises(SystemExit):
        cli.main(["run", name, "--scale", design.scale, "--seeds", "3", "--dry-run"])
    assert f"fixes {design.seeds}" in capsys.readouterr().err
    cli.main(["run", name, "--scale", design.scale, "--runs-dir", str(tmp_path), "--dry-run"])
    out = capsys.readouterr().out
    last = design.seed + design.seeds - 1
    assert f"--iterations {design.iterations} " in out
    assert all("--blind" in line.split() for line in out.splitlines() if "jaxsocial.train" in line)  # blind
    # in a folder of their own: no ordinary `run h1 --seed 100 --seeds 4` can share their directories; each
    # program as many seeds as the design says, with --cores or without
    condition, k = recipe.conditions[-1], design.seeds_per_program or design.seeds
    programs = [(first, min(first + k, last + 1) - 1) for first in range(design.seed, last + 1, k)]
    for first, end in programs:
        assert f"--run-name {design.scale}/prereg-{design.name}/{condition}-s{first}-{end} " in out


def test_preregistered_block():
    design = designs.load("h1_prereg")
    learned = {"social_pred": [True, True, False, True], "social_rec": [True, False, False, False]}
    learned |= {"solo_pred": [False] * 4, "social_none": [False, True, False, False]}
    head = commits.head_commit()
    block = design_results.counts_block(design, learned, {"a/s0": head, "a/s1": None})
    assert block["primary"] == {
        "treatment": list(design.treatment),
        "control": list(design.control),
        "learned_threshold": design.learned_threshold,
        "test": design.test,
        "alpha": design.alpha,
    }
    p = stats.p_value(design.test, 4, 8, 1, 8)
    assert block["result"] == {
        "treatment_learned": 4,
        "treatment_seeds": 8,
        "control_learned": 1,
        "control_seeds": 8,
        "p": round(p, 6),
    }
    assert block["commit"] == catalogue.design_commit("h1_prereg")
    checks = block["checks"]
    after = catalogue.precedes(block["commit"], head)  # True once the design is committed
    assert checks["runs_not_after_design"] == ["a/s1"] if after else ["a/s0", "a/s1"]  # a/s1 has no commit
    assert not checks["design_precedes_every_run"] and checks["seeds_as_designed"]
    said = verdicts.verdict({"preregistered": block})
    assert f"treatment 4/8 learned, control 1/8, p = {round(p, 6):.4g}" in said
    assert "design_precedes_every_run: NO" in said and "a/s1" in said


def test_design_seeds_that_do_not_count_are_named():
    design = dataclasses.replace(designs.load("h1_prereg"), seeds=2, training_commit="a" * 40)
    settings = {"env": "goalcycle3", "num_envs": 1024}
    good = {
        "config": {**settings, "iterations": design.iterations},
        "rows": design.iterations,
        "commit": "a" * 40,
    }
    conditions = {c: [good, good] for c in (*design.treatment, *design.control)}
    conditions["social_rec"] = [None, {**good, "rows": 7}]
    conditions["social_pred"] = [
        {**good, "config": {**settings, "iterations": 9}},
        {**good, "commit": "b" * 40},
    ]
    conditions["solo_pred"] = [good, {**good, "config": {**good["config"], "num_envs": 128}}]
    expected = dict.fromkeys(conditions, settings)
    s0, s1 = design.seed, design.seed + 1
    assert design_results.seed_problems(design, conditions, expected) == [
        f"social_rec seed {s0}: missing",
        f"social_rec seed {s1}: unfinished (7 of {design.iterations} iterations)",
        f"social_pred seed {s0}: trained for 9 iterations",
        f"social_pred seed {s1}: trained at {'b' * 40}, not {'a' * 40}",
        f"solo_pred seed {s1}: trained with other settings (num_envs)",
    ]
    assert design_results.seed_problems(design, {c: [good, good] for c in conditions}, expected) == []


def test_a_design_seed_must_train_with_the_designs_xla_flags_last(tmp_path, monkeypatch):
    """A later value of one of the design's flags would override it, so the flags must end the process's."""
    wanted = f"{pinned.CROSS_CPU_XLA_FLAGS} --xla_cpu_max_isa=AVX2"  # two flags, as `run` appends them
    design = dataclasses.replace(designs.load("h1_prereg"), seeds=1, training_commit=None, xla_flags=wanted)
    good = {"config": {"iterations": design.iterations}, "rows": design.iterations, "commit": None}
    runs = {
        f"{pinned.SINGLE_CORE_XLA_FLAGS} {wanted}": [],
        wanted: [],
        None: ["trained with $XLA_FLAGS None"],
        pinned.SINGLE_CORE_XLA_FLAGS: ["trained with $XLA_FLAGS '--xla_cpu_multi_thread_eigen=false'"],
        f"{wanted} --xla_cpu_max_isa=AVX512": ["trained with $XLA_FLAGS"],
        f"--xla_cpu_max_isa=AVX2 {pinned.CROSS_CPU_XLA_FLAGS}": ["trained with $XLA_FLAGS"],
    }
    for flags, problems in runs.items():
        conditions = {c: [good | {"xla_flags": flags}] for c in (*design.treatment, *design.control)}
        found = design_results.seed_problems(design, conditions, dict.fromkeys(conditions, {}))
        assert len(found) == len(problems) * len(conditions)
        assert all(want in got for want, got in zip(problems * len(conditions), found, strict=True))
    bad = tmp_path / "h1_bad.json"
    raw = jsonio.read_json(catalogue.path_of("h1_prereg"))
    bad.write_text(json.dumps(raw | {"name": "h1_bad", "xla_flags": "--a=1 b=2"}))
    monkeypatch.setattr(catalogue, "DESIGNS_DIR", tmp_path)
    with pytest.raises(ValueError, match="design h1_bad's xla_flags: 'b=2' is not an XLA flag"):
        designs.load("h1_bad")


def test_a_design_may_borrow_an_arm_of_a_finished_design(tmp_path, monkeypatch):
    """nopenalty8 trains only its treatment; its control is pred8's solo arm. A borrowed arm must be the
    same arm of another design, one arm at most, and an early stop needs the takeoff count."""
    design = designs.load("nopenalty8")
    assert design.borrowed == {"control": "pred8"} and design.trained_conditions == ("solo_pred_nopenalty",)
    assert design.learned_by == "takeoff" and design.stop_at_return == 5.0
    assert designs.load("imperfect8").trained_conditions == ("social_pred_imperfect_half",)
    for name in ("pred8", "nopenalty8"):
        (tmp_path / f"{name}.json").write_text(catalogue.path_of(name).read_text())
    monkeypatch.setattr(catalogue, "DESIGNS_DIR", tmp_path)
    base = jsonio.read_json(tmp_path / "nopenalty8.json")
    bad = {
        "not among pred8's treatment": {"borrowed": {"treatment": "pred8"}},
        "name the other arm's design": {"borrowed": {"control": "bad"}},
        "at most one arm may be borrowed": {"borrowed": {"control": "pred8", "treatment": "pred8"}},
        "an early stop .* needs learned_by 'takeoff'": {"learned_by": "final_return"},
        "unknown learned_by": {"learned_by": "never"},
    }
    for message, change in bad.items():
        (tmp_path / "bad.json").write_text(json.dumps({**base, "name": "bad", **change}))
        with pytest.raises(ValueError, match=message):
            designs.load("bad")


def test_a_seed_its_early_stop_ended_counts_as_finished():
    """A design with `stop_at_return` accepts a seed that stopped before its iterations, and no other."""
    design = dataclasses.replace(designs.load("nopenalty8"), seeds=1)
    config_ = {"iterations": design.iterations, "stop_at_return": design.stop_at_return}
    stopped = {"config": config_, "rows": 20, "finished": True, "commit": None}
    settings = {"solo_pred_nopenalty": {}}
    flags = {"xla_flags": f"{pinned.SINGLE_CORE_XLA_FLAGS} {design.xla_flags}"}
    assert design_results.seed_problems(design, {"solo_pred_nopenalty": [stopped | flags]}, settings) == []
    cut = stopped | flags | {"finished": False}
    assert design_results.seed_problems(design, {"solo_pred_nopenalty": [cut]}, settings) == [
        f"solo_pred_nopenalty seed 500: unfinished (20 of {design.iterations} iterations)"
    ]
    other = stopped | flags | {"config": {**config_, "stop_at_return": None}}
    assert design_results.seed_problems(design, {"solo_pred_nopenalty": [other]}, settings) == [
        "solo_pred_nopenalty seed 500: trained with stop_at_return None"
    ]


def test_designs_since_the_cross_cpu_flags_name_them():
    """A new design trains with `pinned.CROSS_CPU_XLA_FLAGS`, under which the AVX-512 kinds measured
    (`pinned.CROSS_CPU_KINDS`) agree bit for bit, though not with the Zen 3; the designs committed before the
    field keep XLA's defaults (their files may not change)."""
    before = {"experts", "h1_early", "h1_laptop", "h1_prereg", "h1_sooner"}
    names = catalogue.design_names("training")
    assert before <= set(names)
    for name in names:
        flags = designs.load(name).xla_flags
        assert flags is None if name in before else flags == pinned.CROSS_CPU_XLA_FLAGS, name


def test_a_config_with_the_old_field_names_counts_as_the_design_expects():
    """A seed whose config.json was written before `ppo.chunk_length`, `ppo.minibatch_chunks` and
    `net.chunk` were renamed (committed records hold such files) compares equal to the design's expected
    config of today's names, and differs where the old-named values differ."""
    design = dataclasses.replace(designs.load("h1_prereg"), seeds=1, training_commit=None)
    scale = prereg.recipe_scale(recipes.RECIPES["h1_prereg"], recipes.SCALES[design.scale])
    expected, conditions = {}, {}
    for c in (*design.treatment, *design.control):
        values = config.config_dict(recipes.condition_config(scale, c, design.seed, 1, "runs"))
        expected[c] = {k: values[k] for k in ("net", "ppo", "num_envs")}
        old = {**values, "net": dict(values["net"]), "ppo": dict(values["ppo"])}
        old["net"]["chunk"] = old["net"].pop("frame_batch")
        old["ppo"]["chunk_length"] = old["ppo"].pop("segment_length")
        old["ppo"]["minibatch_chunks"] = old["ppo"].pop("minibatch_segments")
        conditions[c] = [{"config": old, "rows": design.iterations, "commit": None}]
    assert design_results.seed_problems(design, conditions, expected) == []
    first = design.treatment[0]
    conditions[first][0]["config"]["ppo"]["minibatch_chunks"] += 1
    assert design_results.seed_problems(design, conditions, expected) == [
        f"{first} seed {design.seed}: trained with other settings (ppo)"
    ]


def test_commit_order():
    head, parent = commits.head_commit(), commits.git("rev-parse", "HEAD~1").stdout.strip()
    if head is None or not parent:
        pytest.skip("needs a git checkout with history")
    assert catalogue.precedes(parent, head) and catalogue.precedes(head, head)
    assert catalogue.precedes(head, parent) is False
    assert catalogue.precedes(None, head) is None and catalogue.precedes("0" * 40, head) is None


def test_figure_writes_and_says_the_preregistered_result(tmp_path, capsys):
    """At another scale than the design's the block is still written, and says that the scale differs."""

    for condition in recipes.RECIPES["h1_prereg"].conditions:
        seed_dir = tmp_path / "runs" / "tiny" / f"{condition}-s0-0"
        seed_dir.mkdir(parents=True)
        learned = 5.0 if condition == "social_pred" else 0.5
        row = {"return/0": learned, "episodes/0": 1, "return/1": 30.0, "episodes/1": 1}  # slot 1: an expert
        rows = [{"iteration": i + 1, **row} for i in range(recipes.TINY.iterations)]
        rundir.MetricsLog(seed_dir).append(rows)
    cli.main(["figure", "h1_prereg", "--scale", "tiny", "--seeds", "1", "--runs-dir", str(tmp_path / "runs"),
              "--out-dir", str(tmp_path / "out")])  # fmt: skip
    block = jsonio.read_json(tmp_path / "out" / "h1_prereg-tiny.json")["preregistered"]
    assert block["result"]["treatment_learned"] == 1 and block["result"]["control_learned"] == 0
    assert block["result"]["treatment_seeds"] == block["result"]["control_seeds"] == 2
    assert not block["checks"]["scale_as_designed"] and not block["checks"]["seeds_as_designed"]
    assert (
        not block["valid"]
        and f"social_pred seed {designs.load('h1_prereg').seed}: missing" in block["problems"]
    )
    said = capsys.readouterr().out
    assert said.endswith(verdicts.verdict({"preregistered": block}) + "\n") and said.rstrip().endswith(
        "NOT VALID: the result above does not test the design (see its checks and problems)"
    )


@pytest.mark.slow
@needs_records("records/laptop8/prereg-pred8")
def test_secondary_tests_count_each_arm_as_the_design_says():
    """imperfect8's secondary tests on pred8's social arm standing in for its own: the counts are pred8's
    (30 of 40 learned; no learner ended above its experts), so each arm equals the other."""
    runs = summaries.design_runs("pred8", str(paths.RECORDS))
    design = dataclasses.replace(designs.load("imperfect8"), treatment=("social_pred",), borrowed={})
    tests = design_results.secondary_tests(design, runs)
    assert tests["fewer_than_good_experts"]["counts"] == [30, 40, 30, 40]
    assert tests["fewer_than_good_experts"]["p"] == 1.0 and not tests["fewer_than_good_experts"]["rejected"]
    assert tests["above_own_experts"]["counts"] == [0, 40, 0, 40]
    assert set(tests["above_own_experts"]) >= {"p", "p_holm", "rejected", "measure", "alternative"}


@pytest.mark.slow
@needs_records("records/laptop8/prereg-pred8")
def test_pred10_counts_pred8_s_arms_by_takeoff_as_pred8_counted_them():
    """pred10's secondary tests read pred8's arms from pred8's own scale (laptop8) and count them as pred10
    does, by takeoff within 2,442 iterations. With pred8's runs standing in for pred10's own, each arm meets
    itself with pred8's final-return counts (30 and 6 of 40), as the design's rationale says they would."""
    runs = summaries.design_runs("pred8", str(paths.RECORDS))
    design = designs.load("pred10")
    assert (design.learned_by, design.scale) == ("takeoff", "laptop10")
    tests = design_results.secondary_tests(design, runs)
    assert tests["social_against_8x8"]["counts"] == [30, 40, 30, 40]
    assert tests["solo_against_8x8"]["counts"] == [6, 40, 6, 40]
    assert tests["social_against_8x8"]["p"] == 1.0 and not tests["solo_against_8x8"]["rejected"]


def test_a_zero_shot_design_compares_the_borrowed_scores_with_its_own_seeds(tmp_path, monkeypatch):
    """imitation8's block from hand-written evaluations: the borrowed arm's from the evaluation design's
    file, the trained arm's from each seed's own; a protocol other than the design's fails its check."""
    design = designs.load("imitation8")
    env = design.tests["primary"]["goalcycle4_8x8"]["env"]

    def result(scores, episodes=128):
        return {"episodes_per_checkpoint": episodes, "seed": 0,
                "results": [{"per_seed_mean": scores, "mean_return": scores[0]}]}  # fmt: skip

    science = tmp_path / "science"
    (science / "transfer8").mkdir(parents=True)
    jsonio.write_json(science / "transfer8" / f"{paths.env_tag(env)}-social_pred.json", result([5.0] * 40))
    monkeypatch.setattr(paths, "SCIENCE", science)
    seed_dirs = [tmp_path / f"bc-s{s}" for s in range(580, 590)]
    for k, d in enumerate(seed_dirs):
        kinds.eval_path(d, env).parent.mkdir(parents=True)
        jsonio.write_json(kinds.eval_path(d, env), result([-1.0 - k], episodes=128 if k else 64))
    runs = types.SimpleNamespace(
        lenders={"social_pred": "pred8"},
        borrowed_scores=summaries.borrowed_scores(summaries.design_recipe("imitation8")),
        seed_dirs={"bc": seed_dirs},
        commits=dict,
    )
    assert runs.borrowed_scores == science / "transfer8"
    assert summaries.borrowed_scores(summaries.design_recipe("imperfect8")) is None  # a counts design
    block = design_results.zero_shot_block(design, runs)
    assert (
        block["result"]["goalcycle4_8x8"]["n"] == [40, 10] and block["result"]["goalcycle4_8x8"]["rejected"]
    )
    assert block["result"]["scores"]["control"]["mean"] == pytest.approx(-5.5)
    assert (
        block["checks"]["seeds_as_designed"] and not block["checks"]["evaluated_as_designed"]
    )  # seed 580: 64
